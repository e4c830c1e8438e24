"""cocotb testbench for stereocam/overlays/rtl/rc_skid.v, the rectify core's input register slice.

Run by ``tests/hdl/test_rtl_units.py``. Random words go in with random gaps while the output sees
random backpressure; what the header of rc_skid.v promises is checked clock by clock: every word
leaves once, in order; the output holds while stalled; a word with nothing ahead of it leaves one
clock after it went in; at most two words are held; s_ready is low in reset, high the clock after
it, and high whenever the slice is empty; with no gaps and no backpressure one word passes per clock.
"""
from __future__ import annotations

import random
from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from .unit_bench import first_difference, params, ready_pattern, reset_stream, start_clock


async def reset(dut: Any) -> None:
    """Reset for three clocks: s_ready and m_valid low in it, s_ready high one clock after it."""
    def quiet() -> None:
        assert not dut.s_ready.value and not dut.m_valid.value, "s_ready or m_valid high in reset"

    await reset_stream(dut, quiet)
    assert dut.s_ready.value, "s_ready low the clock after reset"


async def run(dut: Any, rng: random.Random, clocks: int, p_gap: float, p_low: float,
              burst: int) -> tuple[int, int]:
    """``clocks`` clocks of random traffic, then a drain; returns (words sent, clocks with s_ready low)."""
    width = params()["WIDTH"]
    await reset(dut)
    offered = ready_pattern(rng, clocks, p_gap, burst)
    ready = ready_pattern(rng, clocks, p_low, burst)
    sent: list[int] = []
    got: list[int] = []
    offer: int | None = None
    held: int | None = None  # the word on m_data last clock and not taken
    expect_next: int | None = None  # a word that went in with nothing ahead: on m_data now
    not_ready = 0
    for c in range(clocks + 40):
        if c:
            await FallingEdge(dut.clk)
        m_valid = bool(dut.m_valid.value)
        m_data = int(dut.m_data.value) if m_valid else None
        s_ready = bool(dut.s_ready.value)
        if held is not None:
            assert m_data == held, f"clock {c}: output changed while stalled ({m_data} for {held})"
        if expect_next is not None:
            assert m_data == expect_next, f"clock {c}: a word with nothing ahead is not out 1 clock later"
        inside = len(sent) - len(got)
        assert inside <= 2, f"clock {c}: {inside} words held, the slice holds 2"
        assert s_ready or inside > 0, f"clock {c}: s_ready low while empty"
        not_ready += not s_ready
        take = ready[c] if c < clocks else True
        dut.m_ready.value = int(take)
        if m_valid and take:
            assert m_data is not None
            got.append(m_data)
        held = m_data if m_valid and not take else None
        if offer is None and c < clocks and offered[c]:
            offer = rng.getrandbits(width)
        dut.s_valid.value = int(offer is not None)
        dut.s_data.value = offer if offer is not None else rng.getrandbits(width)  # junk when idle
        expect_next = None
        if offer is not None and s_ready:
            if len(sent) == len(got):
                expect_next = offer
            sent.append(offer)
            offer = None
    dut.s_valid.value = 0
    assert got == sent, f"{len(sent)} words in, {len(got)} out; {first_difference(got, sent)}"
    return len(sent), not_ready


@cocotb.test()
async def random_gaps_and_backpressure(dut: Any) -> None:
    """Several mixes of input gaps and output stalls, short and long: nothing lost, doubled or reordered."""
    start_clock(dut.clk)
    rng = random.Random(1)
    total = 0
    for p_gap, p_low, burst in ((0.3, 0.3, 1), (0.1, 0.6, 4), (0.6, 0.1, 3), (0.0, 0.5, 1), (0.2, 0.2, 20)):
        n, _ = await run(dut, rng, 1500, p_gap, p_low, burst)
        total += n
    assert total > 2000, total


@cocotb.test()
async def full_rate(dut: Any) -> None:
    """No gaps and no stalls: one word per clock, s_ready never low."""
    start_clock(dut.clk)
    n, not_ready = await run(dut, random.Random(2), 500, 0.0, 0.0, 1)
    assert n == 500 and not_ready == 0, (n, not_ready)
