"""cocotb testbench for stereocam/overlays/rtl/rc_interp.v, step 5 of RECTIFY_CORE.md for one channel.

Run by ``tests/hdl/test_rtl_units.py``. The reference is the model's integer interpolation,
``stereocam.overlays.model.reference.interpolate``, on a 2 x 2 plane of the four taps with the source
position (du, dv) inside it: every pair of fractions with random taps, the extreme taps, and random
inputs, one per clock; the output is that of the inputs 6 clocks (rc_interp's LATENCY) before.
"""
from __future__ import annotations

import itertools
import random
from typing import Any

import cocotb
import numpy as np

from stereocam.overlays.model.reference import interpolate
from stereocam.overlays.spec.rectify import FRAC_BITS, FRAC_ONE

from .unit_bench import mismatches, pipeline, start_clock

LATENCY = 6  # rc_interp.v: rc_datapath counts on it
Taps = tuple[int, int, int, int]


def reference(taps: Taps, du: int, dv: int) -> int:
    """The model's value for taps G0..G3 = (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1)."""
    g0, g1, g2, g3 = taps
    plane = np.array([[g0, g1], [g2, g3]], np.uint8)
    value, overflow = interpolate(plane, du, dv, (0, 1))  # iu = du, iv = dv: x0 = y0 = 0
    assert not overflow
    return value


@cocotb.test()
async def interpolates_like_the_model(dut: Any) -> None:
    """All (du, dv) with random taps, extreme taps at every corner fraction, and random inputs."""
    start_clock(dut.clk)
    rng = random.Random(1)

    def taps() -> Taps:
        return rng.randrange(256), rng.randrange(256), rng.randrange(256), rng.randrange(256)

    fracs = range(FRAC_ONE)
    cases = [(taps(), du, dv) for du in fracs for dv in fracs]
    edges = (0, 1, FRAC_ONE // 2, FRAC_ONE - 1)
    for g0, g1, g2, g3 in itertools.product((0, 255), repeat=4):
        cases += [((g0, g1, g2, g3), du, dv) for du in edges for dv in edges]
    cases += [(taps(), rng.randrange(FRAC_ONE), rng.randrange(FRAC_ONE)) for _ in range(3000)]
    vectors = [{"g0": t[0], "g1": t[1], "g2": t[2], "g3": t[3], "du": du, "dv": dv} for t, du, dv in cases]
    got = await pipeline(dut.clk, dut, vectors, lambda: int(dut.out.value), LATENCY)
    want = [reference(t, du, dv) for t, du, dv in cases]
    problems = mismatches(got, want, lambda i: f"taps {cases[i][0]} du {cases[i][1]} dv {cases[i][2]}")
    assert not problems, "\n".join(problems)
    assert len(dut.du) == FRAC_BITS, f"du is {len(dut.du)} bits, the spec's FRAC_BITS {FRAC_BITS}"
