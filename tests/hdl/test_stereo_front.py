"""The stereo core's front end (stereocam/overlays/rtl/stereo/sc_front.v) against the model's sums.

``tests/hdl/tb_sc_front.py`` writes frames into the front's line buffer, sweeps them slot by slot with
random gaps in ``run``, and compares every real pixel's S(p, d), d < NUM_DISP, with
``stereo_fast.aggregate``. Small builds keep the simulations short (and the depth build itself sees
a 170x8 frame at 128 disparities and a 9x7 at 64); each build runs a list of frames
(odd sizes, the minimum 9x7, taller than the 8-row line buffer, as wide as the build) under several
parameter sets (NUM_DISP of the whole build and less, edge thresholds that always, never and sometimes
lower P2). Every case runs under Icarus, the first under Verilator too (every case with
``STEREOCAM_COSIM_FULL=1``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from stereocam.overlays.rtl import toolchain as hdl

from .cocotb_run import run_cocotb
from .sim_cases import sim_cases

RTL = hdl.rtl_dir()
STEREO = RTL / "stereo"
SOURCES = (*(STEREO / f"{m}.v" for m in ("sc_linebuf", "sc_census", "sc_cost", "sc_min_tree", "sc_path_left",
                                          "sc_path_up", "sc_front")), RTL / "rc_ram.v")


def frame(kind: str, width: int, height: int, seed: int, **params: int) -> dict[str, Any]:
    return {"kind": kind, "width": width, "height": height, "seed": seed, "params": params}


@dataclass(frozen=True)
class Case:
    name: str
    build: dict[str, int]
    frames: tuple[dict[str, Any], ...]
    verilator: bool = False


SMALL = {"MAX_WIDTH": 64, "MAX_DISP": 32, "PARALLEL": 8}
CASES = [
    Case("defaults", SMALL, (
        frame("shifted", 23, 9, 1, num_disp=32),
        frame("random", 9, 7, 2, num_disp=32),
    ), verilator=True),
    Case("fewer-disparities", SMALL, (
        frame("shifted", 40, 12, 3, num_disp=16, p1=8, p2=193, p2_edge=20, edge_thresh=10),
        frame("random", 23, 9, 4, num_disp=8, p1=63, p2=120, p2_edge=63, edge_thresh=0),
        frame("shifted", 17, 11, 5, num_disp=24, p1=3, p2=150, p2_edge=150, edge_thresh=40),
    )),
    Case("edges-and-extremes", SMALL, (
        frame("shifted", 64, 10, 6, num_disp=32, p1=10, p2=193, p2_edge=11, edge_thresh=255),
        frame("shifted", 31, 8, 7, num_disp=32, p1=0, p2=0, p2_edge=0, edge_thresh=1),
        frame("flat", 12, 7, 8, num_disp=16, p1=5, p2=60, p2_edge=30, edge_thresh=24),
        frame("random", 9, 13, 9, num_disp=32, p1=63, p2=193, p2_edge=193, edge_thresh=128),
    )),
    Case("depth-build", {"MAX_WIDTH": 752, "MAX_DISP": 128, "PARALLEL": 32}, (
        frame("shifted", 170, 8, 12, num_disp=128),
        frame("random", 9, 7, 13, num_disp=64, p1=12, p2=80, p2_edge=30, edge_thresh=20),
    )),
    Case("parallel-4", {"MAX_WIDTH": 40, "MAX_DISP": 16, "PARALLEL": 4}, (
        frame("shifted", 40, 9, 10, num_disp=16),
        frame("random", 13, 7, 11, num_disp=12, p1=20, p2=90, p2_edge=45, edge_thresh=60),
    )),
]


@pytest.mark.parametrize(("sim", "case"), sim_cases(CASES, lambda c: c.name, lambda c: c.verilator))
def test_front_sums(sim: str, case: Case, cocotb_dir: Path) -> None:
    """Every real pixel's sums equal the model's, with the header's timing, through gaps in ``run``."""
    env = {"STEREOCAM_UNIT_PARAMS": json.dumps(case.build), "COCOTB_RANDOM_SEED": "1",
           "STEREOCAM_FRONT_FRAMES": json.dumps(list(case.frames))}
    run = run_cocotb("sc_front", SOURCES, "tb_sc_front", sim=sim, parameters=case.build, extra_env=env,
                     test_dir=cocotb_dir)
    print(f"{sim} {case.name}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s")
    assert run.passed


TREES = [  # (N, W, STAGES, OUT_REG, ROOT_LEVELS): the front's trees at the small and depth builds, a
    # padded N, odd widths, runs of levels of either parity between the registers
    (32, 8, 2, 1, 0), (8, 8, 2, 1, 0), (16, 8, 1, 0, 2), (64, 8, 1, 0, 2), (8, 8, 1, 0, 0), (128, 8, 1, 0, 0),
    (13, 5, 3, 1, 0), (6, 3, 2, 0, 0), (64, 8, 1, 0, 1), (64, 8, 1, 0, 3), (100, 7, 1, 0, 4),
]


@pytest.mark.parametrize("tree", TREES, ids=["-".join(map(str, t)) for t in TREES])
def test_min_tree(tree: tuple[int, int, int, int, int], cocotb_dir: Path) -> None:
    """sc_min_tree gives the minimum of the words taken STAGES enabled clocks before (Icarus)."""
    build = dict(zip(("N", "W", "STAGES", "OUT_REG", "ROOT_LEVELS"), tree, strict=True))
    env = {"STEREOCAM_UNIT_PARAMS": json.dumps(build), "COCOTB_RANDOM_SEED": "1"}
    run = run_cocotb("sc_min_tree", [STEREO / "sc_min_tree.v"], "tb_sc_min_tree", sim="icarus",
                     parameters=build, extra_env=env, test_dir=cocotb_dir)
    assert run.passed


def test_input_writes_good_rows_and_flags_bad_frames(cocotb_dir: Path) -> None:
    """sc_input: good frames written whole, short, long and cut rows and stray beats each a SIZE_ERROR,
    with random TVALID gaps and a row limit that holds rows back (Icarus)."""
    run = run_cocotb("sc_input", [STEREO / "sc_input.v"], "tb_sc_input", sim="icarus", includes=[STEREO],
                     extra_env={"COCOTB_RANDOM_SEED": "1"}, test_dir=cocotb_dir)
    assert run.passed
