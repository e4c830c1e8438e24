"""cocotb testbench for stereocam/overlays/rtl/rc_coord_delay.v, the coordinate engine's SRL delay.

Run by ``tests/hdl/test_rtl_units.py``. Random words, one per clock: ``q`` is ``d`` of N clocks
before (N 0: the same clock), whichever of its four forms (wire, one register, one packed vector,
a chain of registers) the parameters select.
"""
from __future__ import annotations

from typing import Any

import cocotb

from .unit_bench import mismatches, pipeline, start_unit


@cocotb.test()
async def delays(dut: Any) -> None:
    """3,000 random words (all zeros and all ones among them): each leaves exactly N clocks later."""
    p, rng = start_unit(dut)
    width, n = p["W"], p["N"]
    words = [rng.getrandbits(width) for _ in range(3000)]
    words[10:16] = [0, (1 << width) - 1, 0, (1 << width) - 1, (1 << width) - 1, 0]
    # no reset: the N clocks before the first word leaves hold power-up values, so compare from there
    got = await pipeline(dut.clk, dut, [{"d": w} for w in words], lambda: int(dut.q.value), n)
    problems = mismatches(got, words, lambda i: f"word {i}")
    assert not problems, "\n".join(problems)
