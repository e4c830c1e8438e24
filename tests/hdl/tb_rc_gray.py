"""cocotb testbench for stereocam/overlays/rtl/rc_gray.v, the gray value of one RGB tap.

Run by ``tests/hdl/test_rtl_units.py``. The reference is ``stereocam.overlays.spec.pixel.gray_of``
(the demosaic stage's formula): every corner of the RGB cube and random taps, one per clock; the
output is {Y, B, G, R} of the tap 2 clocks before.
"""
from __future__ import annotations

import itertools
import random
from typing import Any

import cocotb
import numpy as np

from stereocam.overlays.spec.pixel import gray_of

from .unit_bench import mismatches, pipeline, start_clock

LATENCY = 2


@cocotb.test()
async def gray_of_each_tap(dut: Any) -> None:
    """Corners, single channels and 4,000 random taps: Y equals gray_of, R, G and B pass unchanged."""
    start_clock(dut.clk)
    rng = random.Random(1)
    taps = [tuple(c) for c in itertools.product((0, 1, 127, 128, 254, 255), repeat=3)]
    taps += [(v, 0, 0) for v in range(256)] + [(0, v, 0) for v in range(256)]
    taps += [(0, 0, v) for v in range(256)]
    taps += [(rng.randrange(256), rng.randrange(256), rng.randrange(256)) for _ in range(4000)]
    rgb = np.array(taps, np.uint8)
    gray = gray_of(rgb)
    want = [int(y) << 24 | b << 16 | g << 8 | r for (r, g, b), y in zip(taps, gray, strict=True)]
    got = await pipeline(dut.clk, dut, [{"rgb": b << 16 | g << 8 | r} for r, g, b in taps],
                         lambda: int(dut.rgby.value), LATENCY)
    problems = mismatches(got, want, lambda i: f"RGB {taps[i]}")
    assert not problems, "\n".join(problems)
