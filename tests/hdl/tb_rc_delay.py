"""cocotb testbench for stereocam/overlays/rtl/rc_delay.v, the fixed delay line of the pixel pipeline.

Run by ``tests/hdl/test_rtl_units.py``. Random words, and random reset pulses, one per clock; the
reference is the header's statement: ``out`` is ``in`` of LATENCY clocks before (LATENCY 0: the same
clock), and with RESET 1 a clock with ``rst`` high clears every stage (with RESET 0 ``rst`` is ignored).
"""
from __future__ import annotations

from typing import Any

import cocotb

from .unit_bench import mismatches, pipeline, start_unit


def model(words: list[int], rst: list[int], latency: int, reset: bool) -> list[int]:
    """The output read in each clock, after driving that clock's word: the stages as the edges
    before it left them (LATENCY 0: the word itself)."""
    if latency == 0:
        return list(words)
    stages = [0] * latency
    out = []
    for word, r in zip(words, rst, strict=True):
        out.append(stages[-1])
        stages = [0] * latency if r and reset else [word, *stages[:-1]]
    return out


@cocotb.test()
async def delays_and_resets(dut: Any) -> None:
    """3,000 random words with a reset pulse now and then: out is the model's in every clock."""
    p, rng = start_unit(dut)
    width, latency, reset = p["WIDTH"], p["LATENCY"], bool(p["RESET"])
    n = 3000
    words = [rng.getrandbits(width) for _ in range(n)]
    # all-ones and all-zeros words, and reset pulses of 1 to LATENCY + 2 clocks
    words[5:10] = [(1 << width) - 1] * 5
    rst = [0] * n
    k = 3 * latency + 20
    while k < n - 10:
        length = rng.randint(1, latency + 2)
        rst[k:k + length] = [1] * length
        k += rng.randint(20, 200)
    got = await pipeline(dut.clk, dut, [{"in": w, "rst": r} for w, r in zip(words, rst, strict=True)],
                         lambda: dut.out.value, 0)
    want = model(words, rst, latency, reset)
    # the first LATENCY + 1 clocks show what the registers held before the first word: not compared
    skip = latency + 1
    problems = mismatches([int(v) for v in got[skip:]], want[skip:], lambda i: f"clock {i + skip}")
    assert not problems, "\n".join(problems)
    assert any(rst)
