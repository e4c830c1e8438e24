"""cocotb testbench for rc_fifo.v with OUTPUT_REG = 1, the rectify core's output FIFO (rc_datapath).

Run by ``tests/hdl/test_rtl_units.py``. The writer keeps to the credit rule of rc_datapath (never
more than DEPTH words inside, counting the output register's) with random gaps; the reader stalls
at random. Checked clock by clock: s_ready is high for every such write; every word leaves once,
in order; m_data and m_valid hold while stalled; a word written into an empty FIFO is on m_valid
2 clocks later, not earlier; a FIFO filled to DEPTH words gives them all back; reset empties it.
"""
from __future__ import annotations

import random
from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from .unit_bench import first_difference, params, ready_pattern, reset_stream, start_clock


async def reset(dut: Any) -> None:
    await reset_stream(dut)
    assert not dut.m_valid.value, "m_valid high after reset"


async def run(dut: Any, rng: random.Random, clocks: int, p_gap: float, ready: list[bool],
              burst: int) -> int:
    """``clocks`` clocks of writes (random gaps, credit-limited) against ``ready``; the most words inside."""
    p = params()
    width, capacity = p["WIDTH"], p["DEPTH"]  # rc_datapath's credits: at most DEPTH words inside
    await reset(dut)
    writes = ready_pattern(rng, clocks, p_gap, burst)
    sent: list[int] = []
    got: list[int] = []
    held: int | None = None
    into_empty: list[tuple[int, int]] = []  # (clock, word) of a word written into an empty FIFO
    most = 0
    for c in range(clocks + capacity + 40):
        if c:
            await FallingEdge(dut.clk)
        m_valid = bool(dut.m_valid.value)
        m_data = int(dut.m_data.value) if m_valid else None
        if held is not None:
            assert m_data == held, f"clock {c}: output changed while stalled ({m_data} for {held})"
        for written, word in list(into_empty):
            if c - written == 1:
                assert not m_valid, f"clock {c}: a word is out 1 clock after it went into the empty FIFO"
            elif c - written == 2:
                assert m_valid and m_data == word, \
                    f"clock {c}: a word written into the empty FIFO is not out 2 clocks later"
                into_empty.remove((written, word))
        take = ready[c] if c < len(ready) else True
        dut.m_ready.value = int(take)
        most = max(most, len(sent) - len(got))
        if m_valid and take:
            assert m_data is not None
            got.append(m_data)
        held = m_data if m_valid and not take else None
        inside = len(sent) - len(got)  # after this clock's read
        word = rng.getrandbits(width)
        write = c < clocks and writes[c] and inside < capacity
        if write:  # a writer within the credits is never refused
            assert dut.s_ready.value, f"clock {c}: s_ready low with {inside} words inside"
        dut.s_valid.value = int(write)
        dut.s_data.value = word
        if write:
            if inside == 0:
                into_empty.append((c, word))
            sent.append(word)
    dut.s_valid.value = 0
    assert got == sent, f"{len(sent)} words in, {len(got)} out; {first_difference(got, sent)}"
    return most


@cocotb.test()
async def random_gaps_and_backpressure(dut: Any) -> None:
    """Mixes of write gaps and read stalls: nothing lost, doubled or reordered, the output holds."""
    start_clock(dut.clk)
    rng = random.Random(1)
    for p_gap, p_low, burst in ((0.3, 0.3, 1), (0.1, 0.6, 4), (0.6, 0.1, 3), (0.0, 0.5, 1), (0.2, 0.4, 30)):
        await run(dut, rng, 1500, p_gap, ready_pattern(rng, 1500, p_low, burst), burst)


@cocotb.test()
async def fill_to_capacity(dut: Any) -> None:
    """The reader stalls until DEPTH words are inside, then takes them at random: all come back."""
    start_clock(dut.clk)
    rng = random.Random(2)
    capacity = params()["DEPTH"]
    stall = 3 * capacity
    ready = [False] * stall + ready_pattern(rng, 600, 0.5, 3)
    most = await run(dut, rng, stall + 600, 0.0, ready, 1)
    assert most == capacity, f"at most {most} words inside, expected {capacity}"


@cocotb.test()
async def reset_empties(dut: Any) -> None:
    """Words inside at reset are gone after it: nothing leaves until a new word is written."""
    start_clock(dut.clk)
    await reset(dut)
    for k in range(4):
        dut.s_valid.value = 1
        dut.s_data.value = k + 1
        await FallingEdge(dut.clk)
    dut.s_valid.value = 0
    await reset(dut)
    dut.m_ready.value = 1
    for _ in range(10):
        await FallingEdge(dut.clk)
        assert not dut.m_valid.value, "a word written before reset came out after it"
