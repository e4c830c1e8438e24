"""cocotb testbench for stereocam/overlays/rtl/camera/ci_sync.v, the two-flop synchroniser.

Run by ``tests/hdl/test_rtl_units.py``. Its header promises: the flops start at INIT, the output is
the input 2 clocks late, and a gray-coded source in another clock domain arrives value by value, in
order. A simulator has no metastability, so this checks the logic, not the crossing's timing.
"""
from __future__ import annotations

import random
from typing import Any

import cocotb
from cocotb.triggers import ClockCycles, FallingEdge, Timer

from .unit_bench import mismatches, params, pipeline, start_clock


@cocotb.test()
async def starts_at_init_then_delays_two_clocks(dut: Any) -> None:
    """Before any edge the output is INIT; then random words, each 2 clocks later."""
    p = params()
    width, init = p["WIDTH"], p["INIT"]
    await Timer(1, unit="ns")  # Verilator applies the initial values in its first evaluation
    assert int(dut.out.value) == init, f"out {int(dut.out.value)} before the first clock, INIT is {init}"
    start_clock(dut.clk)
    rng = random.Random(1)
    words = [rng.getrandbits(width) for _ in range(2000)]
    got = await pipeline(dut.clk, dut, [{"in": w} for w in words], lambda: int(dut.out.value), 2)
    problems = mismatches(got, words, lambda i: f"word {i}")
    assert not problems, "\n".join(problems)


@cocotb.test()
async def gray_counter_from_another_clock(dut: Any) -> None:
    """A gray counter changing every 27 ns into a 10 ns clock: every output value is one it had, in
    order, none skipped (each is held for over two clocks), and the last arrives within 3 clocks."""
    width = params()["WIDTH"]
    start_clock(dut.clk, 10)
    source = getattr(dut, "in")
    values = [(i ^ (i >> 1)) & ((1 << width) - 1) for i in range(min(1 << width, 200))]
    seen: list[int] = []

    async def watch() -> None:
        while True:
            await FallingEdge(dut.clk)
            v = int(dut.out.value)
            if not seen or seen[-1] != v:
                seen.append(v)

    source.value = values[0]
    await ClockCycles(dut.clk, 4)
    task = cocotb.start_soon(watch())
    for v in values[1:]:
        await Timer(27, unit="ns")
        source.value = v
    await ClockCycles(dut.clk, 3)
    await FallingEdge(dut.clk)
    last = int(dut.out.value)
    task.cancel()
    assert seen and seen == values[:len(seen)], f"values out of order or skipped: {seen[:12]}"
    assert last == values[-1], f"out {last} 3 clocks after the source stopped at {values[-1]}"
