"""The coordinate engine (stereocam/overlays/rtl/rc_coord.v) in Verilator and Icarus, word for word against
the model.

Parameter sets: random stereo rigs rectified with OpenCV (``cv2.stereoRectify``), OpenCV's
sample calibration, and stress sets that drive every validity check and the wrapping
accumulators; ``tests/hdl/tb_rc_coord.py`` compares every output word with
``stereocam/overlays/model/fixed.py: positions``. ``STEREOCAM_COSIM_FULL=1`` runs the larger sets
(all random rigs under both simulators, the sample calibration at 640x480); by default
both simulators see a subset and Verilator the rest, so the file stays well under two
minutes. Also here: lint, and the engine's resources from yosys against its budget.
"""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import cv2
import numpy as np
import pytest

from stereocam.calibration.stereo import StereoModel, camera_params, rectify
from stereocam.overlays.model import fixed
from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec.rectify import (
    COORD_LIMIT,
    K_FMT,
    P_FMT,
    PARAM_NAMES,
    PARAM_RANGE,
    R2_LIMIT,
    RADIAL_LIMIT,
    SU_SHIFT,
    XD_LIMIT,
    XN_LIMIT,
    CameraParams,
    CameraRegs,
    F,
    camera_registers,
)

from .cocotb_run import run_cocotb

RTL = hdl.rtl_dir()
SOURCES = [RTL / name for name in
           ("rc_coord.v", "rc_div.v", "rc_fifo.v", "rc_coord_mul.v", "rc_coord_delay.v")]
FULL = os.environ.get("STEREOCAM_COSIM_FULL", "") not in ("", "0")

# Budget of the engine alone, yosys 0.23 synth_xilinx (the whole core: 13,800 LUT, 20,200 FF).
BUDGET = {"DSP48E1": 56, "LUT": 7_000, "FF": 8_000}


N_RIGS = 24  # random calibrations
NOMINAL = (752, 480)  # the cameras' sensor; small frames are the same rigs at lower resolution


# --------------------------------------------------------------------------- parameter sets


def random_rig(seed: int, width: int, height: int, alpha: float) -> Tuple[CameraRegs, CameraRegs]:
    """A plausible stereo rig at ``width x height``, rectified by OpenCV, as register values.

    Drawn at the sensor's 752x480 (fx 300-1200 px, k1 in [-0.45, -0.05], small rotations)
    and scaled to the frame, so a small frame sees the whole field of view and distortion.
    """
    rng = np.random.default_rng(seed)
    sx, sy = width / NOMINAL[0], height / NOMINAL[1]

    def intrinsics() -> Tuple[np.ndarray, np.ndarray]:
        fx = rng.uniform(300, 1200)
        fy = fx * rng.uniform(0.98, 1.02)
        cx = NOMINAL[0] / 2 + rng.uniform(-20, 20)
        cy = NOMINAL[1] / 2 + rng.uniform(-15, 15)
        K = np.array([[fx * sx, 0, cx * sx], [0, fy * sy, cy * sy], [0, 0, 1.0]])
        D = np.array([rng.uniform(-0.45, -0.05), rng.uniform(-0.05, 0.25),
                      rng.normal(0, 0.002), rng.normal(0, 0.002)])
        return K, D

    left, right = rectified_pair(rng, intrinsics, width, height, alpha)
    return camera_registers(left, width, height), camera_registers(right, width, height)


def rectified_pair(rng: np.random.Generator, intrinsics: Callable[[], Tuple[np.ndarray, np.ndarray]],
                   width: int, height: int, alpha: float) -> Tuple[CameraParams, CameraParams]:
    """Two cameras of ``intrinsics()`` (left drawn first), a small random rotation and baseline from
    ``rng``, rectified by OpenCV: the part of a random rig this test and test_rectify_core_rtl share."""
    K1, D1 = intrinsics()
    K2, D2 = intrinsics()
    R, _ = cv2.Rodrigues(rng.normal(0, 0.02, 3))
    T = np.array([-rng.uniform(0.05, 0.15), rng.normal(0, 0.003), rng.normal(0, 0.003)])
    model = StereoModel(K1, D1, K2, D2, R, T, (width, height))
    rect = rectify(model, alpha=alpha)
    return camera_params(K1, D1, rect.R1, rect.P1), camera_params(K2, D2, rect.R2, rect.P2)


def rig_sizes(seed: int) -> Tuple[int, int]:
    rng = np.random.default_rng(1000 + seed)
    return int(rng.integers(40, 97)), int(rng.integers(24, 65))


def sample_rig(width: int, height: int) -> Tuple[CameraRegs, CameraRegs]:
    """OpenCV's stereo sample (tests/data/opencv-stereo-calib), calibrated, at ``width x height``."""
    left, right = sample_pair(width, height)
    return camera_registers(left, width, height), camera_registers(right, width, height)


def sample_pair(width: int, height: int) -> Tuple[CameraParams, CameraParams]:
    """OpenCV's stereo sample, calibrated, scaled to ``width x height`` and rectified (alpha 0)."""
    from ..sample import calibrate_sample

    cal = calibrate_sample()
    w0, h0 = cal.model.image_size
    scale = np.diag([width / w0, height / h0, 1.0])
    m = cal.model
    model = StereoModel(scale @ m.K1, m.D1, scale @ m.K2, m.D2, m.R, m.T, (width, height))
    rect = rectify(model, alpha=0.0)
    return (camera_params(model.K1, model.D1, rect.R1, rect.P1),
            camera_params(model.K2, model.D2, rect.R2, rect.P2))


def lens(w: int, h: int, f: float, k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0,
         hinv: Tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
         cx: Optional[float] = None, cy: Optional[float] = None) -> CameraRegs:
    """A camera with the given lens looking through ``hinv`` (default: no rectifying rotation)."""
    cx = (w - 1) / 2 if cx is None else cx
    cy = (h - 1) / 2 if cy is None else cy
    return camera_registers(CameraParams(hinv, f, f, cx, cy, k1, k2, p1, p2), w, h)


def with_values(regs: CameraRegs, **values: int) -> CameraRegs:
    return CameraRegs.from_values({**regs.values(), **values})


def raw_random(rng: np.random.Generator, names=PARAM_NAMES, base: Optional[CameraRegs] = None) -> CameraRegs:
    """Register values drawn uniformly from each one's accepted range (``names``; others from ``base``)."""
    values = dict(base.values()) if base is not None else {}
    for name in names:
        lo, hi = PARAM_RANGE[name]
        values[name] = int(rng.integers(lo, hi, endpoint=True))
    return CameraRegs.from_values(values)


def stress_sets() -> List[Tuple[str, int, int, CameraRegs, CameraRegs]]:
    """Parameter sets that reach every validity limit and the accumulators' wrap."""
    rng = np.random.default_rng(77)
    w, h = 64, 40
    sets = []
    # Strong perspective: Z = 1 - x/40 - 0.3 y/40 crosses 0 inside the frame (and |X| >= 4 Z
    # near it); the right camera tilts the other way through y.
    persp_l = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1 / 40, -0.3 / 40, 1.0)
    persp_r = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.2 / 40, -1 / 24, 1.0)
    sets.append(("perspective", w, h, lens(w, h, 40.0, -0.2, 0.03, hinv=persp_l),
                 lens(w, h, 30.0, 0.1, hinv=persp_r)))
    # Wide field of view (|xn| up to 3.5): r2 >= 8 in the corners; strong radial terms of both
    # signs push |radial| >= 8; in between |xd| >= 16.
    sets.append(("r2-limit", w, h, lens(w, h, w / 7.0), lens(w, h, w / 6.0, -0.02)))
    sets.append(("radial-limit", w, h, lens(w, h, w / 5.0, 2.0, 0.5), lens(w, h, w / 5.0, -3.0, -1.0)))
    sets.append(("xd-limit", w, h, lens(w, h, w / 6.0, 1.2, 0.1, 0.3, -0.4),
                 lens(w, h, w / 6.0, 0.9, 0.3, -0.8, 0.9)))
    # Sources outside +-2**20 / 32 px: a huge focal length, a far principal point.
    far = lens(w, h, 20000.0, cx=-30000.0, cy=31000.0)
    sets.append(("coord-limit", w, h, far, with_values(lens(w, h, 30000.0, 0.2), CX=PARAM_RANGE["CX"][1])))
    # Accumulators that wrap: X steps by almost 2**43 per pixel (wraps every 32 pixels) yet
    # lands in |X| < 4 Z now and then; Y wraps down the rows. Z is a large positive constant.
    z0 = 1 << 41
    wrap_l = CameraRegs((2**43 - 3, 12345, -2**43, 7, 2**43 - 977, 0, 0, 0, z0),
                        fx=600 << 20, fy=600 << 20, cx=32 << 20, cy=20 << 20,
                        k1=int(-0.3 * 2**32), k2=int(0.1 * 2**32),
                        p1=int(0.001 * 2**32), p2=-int(0.002 * 2**32))
    wrap_r = CameraRegs((-(2**43) + 5, 2**42 + 1, 2**43 - 1, -3 * 2**40, -(2**43), 1 << 40, 0, 0, z0),
                        fx=400 << 20, fy=410 << 20, cx=-(5 << 20), cy=50 << 20,
                        k1=int(0.2 * 2**32), k2=0, p1=0, p2=0)
    sets.append(("wrap", w, h, wrap_l, wrap_r))
    # Raw register values anywhere in their ranges: mostly invalid pixels, extreme values everywhere.
    sets.append(("raw", w, h, raw_random(rng), raw_random(rng)))
    # A real homography with raw lens registers (valid pixels with unusual K, P, F, C), and one with
    # moderate random lens values so that most pixels stay valid.
    base_l, base_r = random_rig(5, w, h, 1.0)
    lens_names = ("FX", "FY", "CX", "CY", "K1", "K2", "P1", "P2")
    sets.append(("raw-lens", w, h, raw_random(rng, lens_names, base_l), raw_random(rng, lens_names, base_r)))
    moderate = {}
    for side, base in (("l", base_l), ("r", base_r)):
        moderate[side] = with_values(
            base, K1=int(rng.uniform(-1, 1) * 2**32), K2=int(rng.uniform(-1, 1) * 2**32),
            P1=int(rng.uniform(-0.3, 0.3) * 2**32), P2=int(rng.uniform(-0.3, 0.3) * 2**32),
            FX=int(rng.uniform(1, 5000) * 2**20), FY=int(rng.uniform(1, 5000) * 2**20),
            CX=int(rng.uniform(-3000, 3000) * 2**20), CY=int(rng.uniform(-3000, 3000) * 2**20))
    sets.append(("moderate-lens", w, h, moderate["l"], moderate["r"]))
    # The extremes of every range at once (N at +-2**43, FX at its maximum, ...).
    lo = CameraRegs.from_values({n: PARAM_RANGE[n][0] for n in PARAM_NAMES})
    hi = CameraRegs.from_values({n: PARAM_RANGE[n][1] for n in PARAM_NAMES})
    sets.append(("range-ends", 40, 24, lo, hi))
    return sets


# --------------------------------------------------------------------------- what each set exercises


def first_failure(r: CameraRegs, x: int, y: int) -> str:
    """The first validity check pixel (x, y) fails, or "ok": the model's position() step by step."""
    n = r.n
    X = fixed.wrap_acc(n[0] * x + n[1] * y + n[2])
    Y = fixed.wrap_acc(n[3] * x + n[4] * y + n[5])
    Z = fixed.wrap_acc(n[6] * x + n[7] * y + n[8])
    if Z <= 0:
        return "Z"
    if abs(X) >= XN_LIMIT * Z or abs(Y) >= XN_LIMIT * Z:
        return "XY"
    xn, yn = fixed.divide(X, Z), fixed.divide(Y, Z)
    x2, y2, xy = fixed.rnd(xn * xn, F), fixed.rnd(yn * yn, F), fixed.rnd(xn * yn, F)
    r2 = x2 + y2
    if r2 >= R2_LIMIT << F:
        return "r2"
    s = r.k1 + fixed.rnd(r.k2 * r2, F)
    radial = (1 << F) + fixed.rnd(s * r2, K_FMT.frac)
    if abs(radial) >= RADIAL_LIMIT << F:
        return "radial"
    pf = P_FMT.frac
    xd = fixed.rnd(xn * radial, F) + fixed.rnd(r.p1 * 2 * xy, pf) + fixed.rnd(r.p2 * (r2 + 2 * x2), pf)
    yd = fixed.rnd(yn * radial, F) + fixed.rnd(r.p1 * (r2 + 2 * y2), pf) + fixed.rnd(r.p2 * 2 * xy, pf)
    if abs(xd) >= XD_LIMIT << F or abs(yd) >= XD_LIMIT << F:
        return "xd"
    iu = fixed.rnd(r.fx * xd + (r.cx << F), SU_SHIFT)
    iv = fixed.rnd(r.fy * yd + (r.cy << F), SU_SHIFT)
    if not (-COORD_LIMIT < iu < COORD_LIMIT and -COORD_LIMIT < iv < COORD_LIMIT):
        return "coord"
    return "ok"


def failures(r: CameraRegs, w: int, h: int) -> Dict[str, int]:
    out: Dict[str, int] = {}
    for y in range(h):
        for x in range(w):
            reason = first_failure(r, x, y)
            out[reason] = out.get(reason, 0) + 1
    return out


def wraps(r: CameraRegs, w: int, h: int) -> bool:
    """Some accumulator leaves the signed 48-bit range somewhere in the frame (before wrapping)."""
    limit = 1 << 47
    for row in range(3):
        a, b, c = r.n[3 * row: 3 * row + 3]
        for x, y in ((0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)):
            if not -limit <= a * x + b * y + c < limit:
                return True
    return False


# --------------------------------------------------------------------------- running the testbench


def case(name: str, w: int, h: int, left: CameraRegs, right: CameraRegs, seed: int, ready: float) -> dict:
    for side, regs in (("left", left), ("right", right)):
        assert not regs.problems(), f"{name} {side}: {regs.problems()}"
    return {"name": name, "width": w, "height": h, "left": left.values(), "right": right.values(),
            "seed": seed, "ready": ready}


def rig_cases(seeds) -> List[dict]:
    out = []
    for seed in seeds:
        w, h = rig_sizes(seed)
        alpha = float(seed % 2)
        left, right = random_rig(seed, w, h, alpha)
        ready = (1.0, 0.8, 0.5, 0.25)[seed % 4]
        out.append(case(f"rig{seed} alpha={alpha:g}", w, h, left, right, seed, ready))
    return out


def simulate(sim: str, cases: List[dict], out_dir: Path, tests: str = "frames") -> dict:
    """Run the cocotb tests matching ``tests`` on ``cases``; returns the testbench's report."""
    cases_path = out_dir / "rc_coord_cases.json"
    cases_path.write_text(json.dumps({"cases": cases}))
    report = out_dir / "rc_coord_report.json"
    report.unlink(missing_ok=True)
    run = run_cocotb(
        "rc_coord", SOURCES, "tb_rc_coord", sim=sim, includes=[RTL], test_dir=out_dir,
        extra_env={"RC_COORD_CASES": str(cases_path), "RC_COORD_REPORT": str(report),
                   "COCOTB_TEST_FILTER": rf"tb_rc_coord\.({tests})$"},
    )
    data = json.loads(report.read_text()) if report.is_file() else {}
    frames = data.get("frames")
    speed = f", {frames['positions_per_second']:,.0f} positions/s" if frames else ""
    print(f"{sim}: {len(cases)} sets, build {run.build_seconds:.1f} s "
          f"({'built' if run.built else 'cached'}), run {run.run_seconds:.1f} s{speed}")
    return data


def test_stress_sets_reach_every_limit() -> None:
    """The stress sets make each validity check the first to fail somewhere, and wrap."""
    seen: Dict[str, int] = {}
    wrapped = []
    for name, w, h, left, right in stress_sets():
        for regs in (left, right):
            for reason, count in failures(regs, w, h).items():
                seen[reason] = seen.get(reason, 0) + count
            if wraps(regs, w, h):
                wrapped.append(name)
        # first_failure is the model, step by step: it agrees with position().
        for x, y in ((0, 0), (w // 2, h // 2), (w - 1, h - 1), (5, 31)):
            assert (first_failure(left, x, y) == "ok") == (fixed.position(left, x, y) is not None)
    assert set(seen) == {"Z", "XY", "r2", "radial", "xd", "coord", "ok"}, seen
    assert "wrap" in wrapped
    print("first failing check over the stress sets:", seen)


def quick(sim: str) -> bool:
    """Icarus runs some 25 times slower than Verilator here: by default it gets a subset."""
    return sim == "icarus" and not FULL


def test_random_rigs(sim: str, cocotb_dir: Path) -> None:
    """Random OpenCV-rectified rigs, small frames, random out_ready: every word equals the model's.

    Verilator runs all 24; Icarus every fifth, at a higher out_ready, unless STEREOCAM_COSIM_FULL=1.
    """
    cases = rig_cases(range(0, N_RIGS, 5) if quick(sim) else range(N_RIGS))
    if quick(sim):
        for c in cases:
            c["ready"] = max(c["ready"], 0.7)
    simulate(sim, cases, cocotb_dir)


def test_stress_and_sample(sim: str, cocotb_dir: Path) -> None:
    """Every stress set and OpenCV's sample calibration at 80x60 (Icarus by default: half of them)."""
    cases = [case(name, w, h, left, right, i, (1.0, 0.6, 0.3)[i % 3])
             for i, (name, w, h, left, right) in enumerate(stress_sets())]
    cases.append(case("opencv-sample 80x60", 80, 60, *sample_rig(80, 60), 99, 0.7))
    if quick(sim):
        cases = [dict(c, ready=max(c["ready"], 0.7)) for c in cases[::2]]
    simulate(sim, cases, cocotb_dir)


def test_flow_control_and_frame_boundaries(sim: str, cocotb_dir: Path) -> None:
    """One word per 2 clocks at full rate, long stalls, back-to-back frames, start while busy, reset."""
    cases = rig_cases([1, 2])
    report = simulate(sim, cases, cocotb_dir, tests="timing|stall|restart")
    print(f"{sim}: first word {report['timing']['first_word_clocks']} clocks after start")


@pytest.mark.parametrize("sim", ["verilator"])
def test_full_frame(sim: str, cocotb_dir: Path) -> None:
    """A whole 752x480 frame of a random rig (and with STEREOCAM_COSIM_FULL=1 OpenCV's sample at 640x480)."""
    cases = [case("rig 752x480", 752, 480, *random_rig(4242, 752, 480, 0.0), 4242, 0.8)]
    if FULL:
        cases.append(case("opencv-sample 640x480", 640, 480, *sample_rig(640, 480), 4343, 0.8))
    simulate(sim, cases, cocotb_dir)


# --------------------------------------------------------------------------- the parts on their own

UNIT_SIMS = ["icarus", "verilator"] if FULL else ["icarus"]


def run_unit(sim: str, toplevel: str, source: str, test: str, params: Dict[str, int], out_dir: Path) -> None:
    run_cocotb(toplevel, [RTL / source], "tb_rc_coord", sim=sim, parameters=params, test_dir=out_dir,
               extra_env={"RC_COORD_UNIT": json.dumps(params),
                          "COCOTB_TEST_FILTER": rf"tb_rc_coord\.{test}$"})


DIV_PARAMS = [
    dict(LANES=2, NW=48, DW=47, QB=33, SH=31),   # the engine's
    dict(LANES=3, NW=9, DW=7, QB=5, SH=3),       # small, odd: numerator wider than the divisor
]
MUL_PARAMS = [
    dict(AW=34, BW=34, LO=29, CW=2, SH=1, OW=36),      # x2 = rnd(xn*xn, F)
    dict(AW=40, BW=34, LO=31, CW=33, SH=1, OW=41),     # radial
    dict(AW=36, BW=33, LO=31, CW=37, SH=1, OW=36),     # cx12 = rnd(P2*qx, 32) + cx1
    dict(AW=36, BW=35, LO=30, CW=37, SH=15, OW=26),    # iu
    dict(AW=42, BW=35, LO=17, CW=50, SH=3, OW=60),     # the widest operands, c wider than the sum
    dict(AW=18, BW=18, LO=17, CW=4, SH=2, OW=19),      # the narrowest
]
FIFO_PARAMS = [
    dict(WIDTH=86, DEPTH=32, SHOW_AHEAD=1),   # the engine's output FIFO
    dict(WIDTH=8, DEPTH=5, SHOW_AHEAD=1),
    dict(WIDTH=8, DEPTH=5, SHOW_AHEAD=0),
    dict(WIDTH=8, DEPTH=2, SHOW_AHEAD=0),
]


@pytest.mark.parametrize("sim", UNIT_SIMS)
@pytest.mark.parametrize("params", DIV_PARAMS, ids=["engine", "small"])
def test_divider_is_exact(sim: str, params: Dict[str, int], cocotb_dir: Path) -> None:
    run_unit(sim, "rc_div", "rc_div.v", "div_exact", params, cocotb_dir)


@pytest.mark.parametrize("sim", UNIT_SIMS)
@pytest.mark.parametrize("params", MUL_PARAMS, ids=["x2", "radial", "cx12", "iu", "widest", "narrowest"])
def test_product_is_exact(sim: str, params: Dict[str, int], cocotb_dir: Path) -> None:
    run_unit(sim, "rc_coord_mul", "rc_coord_mul.v", "mul_exact", params, cocotb_dir)


@pytest.mark.parametrize("sim", UNIT_SIMS)
@pytest.mark.parametrize("params", FIFO_PARAMS, ids=["engine", "5-fwft", "5-request", "2-request"])
def test_fifo(sim: str, params: Dict[str, int], cocotb_dir: Path) -> None:
    run_unit(sim, "rc_fifo", "rc_fifo.v", "fifo_order", params, cocotb_dir)


# --------------------------------------------------------------------------- lint and resources


LINT_SETS = [
    ("rc_coord", {}),
    *(("rc_div", p) for p in DIV_PARAMS),
    *(("rc_coord_mul", p) for p in MUL_PARAMS),
    *(("rc_fifo", p) for p in FIFO_PARAMS),
]


@pytest.mark.parametrize("top, params", LINT_SETS, ids=[f"{t}-{i}" for i, (t, _) in enumerate(LINT_SETS)])
def test_lints_clean_with_verilator(top: str, params: Dict[str, int]) -> None:
    out = subprocess.run(
        # -Wall minus PROCASSINIT: initial values on registers are FPGA power-up values here (rc_fifo)
        [str(hdl.verilator_bin()), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{RTL}",
         "--top-module", top, *(f"-G{k}={v}" for k, v in params.items()), *map(str, SOURCES)],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert out.returncode == 0, out.stdout + out.stderr


def yosys_cells() -> Dict[str, int]:
    """rc_coord's cells from yosys 0.23 ``synth_xilinx -family xc7``, hierarchy kept (cached by content)."""
    yosys = hdl.check_tools("yosys")
    key = {"sources": SOURCES, "header": RTL / "rectify_spec.vh",
           "yosys": subprocess.run([str(yosys), "-V"], capture_output=True, text=True).stdout}
    folder = hdl.build_dir("yosys/rc_coord", key)
    result = folder / "cells.json"
    if not result.is_file():
        reads = " ".join(str(p) for p in SOURCES)
        script = (f"read_verilog -sv -I {RTL} {reads}; synth_xilinx -family xc7 -top rc_coord; "
                  f"tee -q -o {folder / 'stat.json'} stat -json")
        out = subprocess.run([str(yosys), "-q", "-l", str(folder / "yosys.log"), "-p", script],
                             capture_output=True, text=True, timeout=1500, check=False)
        assert out.returncode == 0, out.stdout + out.stderr
        from stereocam.overlays.rtl.synth import parse_stat_json

        result.write_text(json.dumps(parse_stat_json((folder / "stat.json").read_text())))
    return json.loads(result.read_text())


def test_resources_within_budget() -> None:
    """yosys synth_xilinx: at most 56 DSP48E1, 7,000 LUT (logic, INV and LUTRAM) and 8,000 FF."""
    from stereocam.overlays.rtl.synth import count_resources

    cells = yosys_cells()
    counts = count_resources(cells)
    lut = counts.lut + cells.get("INV", 0)  # yosys's INV is a LUT1 in Vivado
    got = {"DSP48E1": counts.dsp, "LUT": lut, "FF": counts.ff}
    print(f"rc_coord: {got}, of which LUTRAM {counts.lutram}; {counts.other}")
    over = {k: (v, BUDGET[k]) for k, v in got.items() if v > BUDGET[k]}
    assert not over, f"over budget (count, budget): {over}"
    assert counts.dsp == 52, "13 products of 4 DSP48E1 each"
    assert counts.bram36 == 0
