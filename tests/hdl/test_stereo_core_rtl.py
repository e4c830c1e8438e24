"""The stereo core's RTL (stereocam/overlays/rtl/stereo/) against its model, co-simulated.

Each case writes frames and the model's output beats for ``tb_stereo_core.py``, which streams the
frames through the RTL (cocotb, with random pauses on both streams) and compares every beat.
Small builds (64 columns, 32 disparities, 8 a clock) keep the runs short. The back end (winner to
output) is also run behind a double of the front that reads the model's own sums
(tests/hdl/rtl/sc_front_sums.v), so a difference there is the back end's.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import pytest

from stereocam.overlays.model import stereo_fast
from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec import stereo as spec

from .cocotb_run import run_cocotb

RTL = hdl.rtl_dir()
STEREO = RTL / "stereo"
DOUBLE = Path(__file__).parent / "rtl" / "sc_front_sums.v"
BUILD = {"MAX_WIDTH": 64, "MAX_HEIGHT": 64, "MAX_DISP": 32, "PARALLEL": 8}
SMALL = spec.Build("small", 64, 64, 32, 8)


def back_sources() -> List[Path]:
    own = [p for p in sorted(STEREO.glob("*.v")) if not p.name.startswith("sc_front")]
    return [*own, RTL / "rc_ram.v", RTL / "rc_fifo.v", DOUBLE]


def textured_pair(seed: int, h: int, w: int, shift: int) -> Tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h, w + shift), dtype=np.uint8)
    right = base[:, shift:shift + w].astype(int) + rng.integers(-4, 5, (h, w))
    left = base[:, :w].copy()
    left[:, w // 2:] = base[:, w // 2 + 2:w + 2] if w + 2 <= w + shift else left[:, w // 2:]
    return left, right.clip(0, 255).astype(np.uint8)


def writes(p: spec.StereoParams, width: int, height: int) -> List[Tuple[int, int]]:
    words = spec.register_values(p)
    out = [(spec.STEREO_MAP.offset("WIDTH"), width), (spec.STEREO_MAP.offset("HEIGHT"), height)]
    out += [(spec.STEREO_MAP.offset(reg), words[reg]) for reg in spec.PARAM_REGISTERS.values()]
    control = spec.STEREO_MAP["CONTROL"]
    out.append((control.offset, words["CONTROL"] | control.bit("ENABLE") | control.bit("APPLY")))
    return out


def sums_hex(pairs: List[Tuple[np.ndarray, np.ndarray]], p: spec.StereoParams) -> str:
    lanes = BUILD["PARALLEL"]
    groups = BUILD["MAX_DISP"] // lanes
    digits = (lanes * spec.SUM_BITS + 3) // 4
    lines = []
    for left, right in pairs:
        total = stereo_fast.aggregate(stereo_fast.costs(stereo_fast.census(left), stereo_fast.census(right),
                                                        p.num_disp), left, p)
        h, w, nd = total.shape
        for y in range(h):
            for x in range(w):
                for g in range(groups):
                    word = 0
                    for j in range(lanes):
                        d = g * lanes + j
                        value = int(total[y, x, d]) if d < nd else (1 << spec.SUM_BITS) - 1
                        word |= value << (spec.SUM_BITS * j)
                    lines.append(f"{word:0{digits}x}")
    return "\n".join(lines) + "\n"


def model_beats(left: np.ndarray, right: np.ndarray, p: spec.StereoParams) -> np.ndarray:
    """The model's output beats, its steps called directly: the small build takes ranges (16) that
    the depth build's check (a multiple of 32) refuses."""
    f = stereo_fast
    total = f.aggregate(f.costs(f.census(left), f.census(right), p.num_disp), left, p)
    d1, s1, s2, code = f.winners(total, p)
    return f.finish(total, d1, s1, s2, code, f.right_winners(total), p).beats()


def run_case(tmp: Path, sim: str, name: str, pairs: List[Tuple[np.ndarray, np.ndarray]],
             p: spec.StereoParams, *, double: bool, p_in: float = 0.2, p_out: float = 0.2,
             seed: int = 1) -> Dict[str, float]:
    h, w = pairs[0][0].shape
    assert not p.problems(SMALL), p.problems(SMALL)
    want = np.stack([model_beats(left, right, p) for left, right in pairs])
    np.savez(tmp / "frames.npz", left=np.stack([pair[0] for pair in pairs]),
             right=np.stack([pair[1] for pair in pairs]), beats=want)
    report = tmp / "report.json"
    case = {"name": name, "npz": str(tmp / "frames.npz"), "writes": writes(p, w, h), "seed": seed,
            "p_in": p_in, "p_out": p_out, "timeout_us": 20_000}
    (tmp / "case.json").write_text(json.dumps(case))
    run_dir = tmp / "run"
    run_dir.mkdir(exist_ok=True)
    params: Dict[str, object] = dict(BUILD)
    if double:
        (run_dir / "sums.hex").write_text(sums_hex(pairs, p))
    run_cocotb("stereo_core", back_sources() if double else core_sources(), "tb_stereo_core", sim=sim,
               parameters=params, includes=[STEREO], test_dir=run_dir,
               defines={"SC_FRONT_FRAMES": len(pairs)} if double else None,
               extra_env={"STEREOCAM_STEREO_CASE": str(tmp / "case.json"),
                          "STEREOCAM_STEREO_REPORT": str(report)})
    result: Dict[str, float] = json.loads(report.read_text())[name]
    assert result["differing"] == 0
    return result


def core_sources() -> List[Path]:
    return [*sorted(STEREO.glob("*.v")), RTL / "rc_ram.v", RTL / "rc_fifo.v"]


@pytest.mark.parametrize("variant", ["default", "plain", "strict"])
def test_back_end_equals_the_model_behind_the_sums_double(tmp_path: Path, variant: str) -> None:
    base = spec.DEFAULT_PARAMS.with_values(num_disp=32)
    p = {"default": base, "plain": base.with_values(subpixel=False, median=False, lr_check=False),
         "strict": base.with_values(uniqueness=60, lr_tol=0)}[variant]
    pairs = [textured_pair(3, 12, 40, 6), textured_pair(4, 12, 40, 11)]
    result = run_case(tmp_path, "icarus", f"back-{variant}", pairs, p, double=True)
    assert result["frames"] == 2


@pytest.mark.parametrize("variant", ["default", "edges", "narrow"])
def test_whole_core_equals_the_model(tmp_path: Path, variant: str) -> None:
    base = spec.DEFAULT_PARAMS.with_values(num_disp=32)
    p = {"default": base, "edges": base.with_values(edge_thresh=0, p1=5, p2_edge=5, p2=150, lr_tol=1),
         "narrow": base.with_values(num_disp=16)}[variant]
    pairs = [textured_pair(5, 12, 40, 7), textured_pair(6, 12, 40, 3)]
    result = run_case(tmp_path, "icarus", f"core-{variant}", pairs, p, double=False)
    assert result["frames"] == 2
