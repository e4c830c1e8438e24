"""cocotb testbench for stereocam/overlays/rtl/camera/ci_demosaic.v, one pixel of the demosaic.

Run by ``tests/hdl/test_rtl_units.py``. The reference is the model, ``stereocam.overlays.model.camera_in
.demosaic_window``, on a 3 x 3 raw mosaic whose centre is the pixel: the Bayer phase of the mosaic is
the one that puts the centre on the site (R, B, Gr, Gb) that red_row / red_col name. Random windows at
every site, saturating ones (all 1023) and dark ones; the output {Y, B, G, R} is that of the inputs
4 clocks before.
"""
from __future__ import annotations

import random
from typing import Any

import cocotb
import numpy as np

from stereocam.overlays.model.camera_in import demosaic_window
from stereocam.overlays.spec import camera_in as spec

from .unit_bench import mismatches, pipeline, start_clock

LATENCY = 4
RW = spec.RAW_BITS
RAW_MAX = (1 << RW) - 1


def reference(window: list[int], red_row: int, red_col: int) -> int:
    """The model's RGBY of the centre of ``window`` (row by row, a_l first) as {Y, B, G, R}."""
    # phase code: R at column code & 1, row code >> 1 of each 2x2 cell; the centre is at (1, 1)
    phase = spec.CFA_PHASES[2 * red_row + red_col]
    raw = np.array(window, np.uint16).reshape(3, 3)
    r, g, b, y = (int(v) for v in demosaic_window(raw, slice(1, 2), slice(1, 2), phase)[0, 0])
    return y << 24 | b << 16 | g << 8 | r


def pack(window: list[int]) -> int:
    """``win``: a_l in the top RW bits, b_r in the bottom ones."""
    out = 0
    for v in window:
        out = out << RW | v
    return out


@cocotb.test()
async def demosaics_like_the_model(dut: Any) -> None:
    """Every site with random, saturated, dark and single-bright-sample windows."""
    start_clock(dut.clk)
    rng = random.Random(1)
    cases: list[tuple[list[int], int, int]] = []
    for red_row in (0, 1):
        for red_col in (0, 1):
            cases.append(([RAW_MAX] * 9, red_row, red_col))
            cases.append(([0] * 9, red_row, red_col))
            for k in range(9):  # one bright sample: each tap's weight on its own
                cases.append(([RAW_MAX if i == k else 0 for i in range(9)], red_row, red_col))
            cases += [([rng.randrange(RAW_MAX + 1) for _ in range(9)], red_row, red_col) for _ in range(600)]
            cases += [([rng.randrange(RAW_MAX - 16, RAW_MAX + 1) for _ in range(9)], red_row, red_col)
                      for _ in range(50)]  # near saturation: the clamp at 255
    rng.shuffle(cases)
    vectors = [{"win": pack(w), "red_row": rr, "red_col": rc} for w, rr, rc in cases]
    got = await pipeline(dut.clk, dut, vectors, lambda: int(dut.rgby.value), LATENCY)
    want = [reference(w, rr, rc) for w, rr, rc in cases]
    problems = mismatches(got, want, lambda i: f"window {cases[i][0]} red_row {cases[i][1]} "
                                                f"red_col {cases[i][2]}")
    assert not problems, "\n".join(problems)
    assert len(dut.win) == 9 * RW
