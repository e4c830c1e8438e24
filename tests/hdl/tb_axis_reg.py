"""cocotb testbench for tests/hdl/rtl/axis_reg.v, the register slice that proves the HDL harness.

Run by ``tests/hdl/test_infra.py`` through ``run_cocotb`` under Verilator and Icarus; it
is not a pytest module (cocotb imports it inside the simulator). Video frames travel as
AXI4-Stream packets the way the rectify core's stream does: one 64-bit pixel per beat,
TUSER on a frame's first pixel, TLAST at the end of each line. The bus models send them
with random idle cycles and the sink applies random backpressure; every beat that comes
out (data, TUSER, line boundary) must equal the one that went in, and the output must
hold still while it is stalled.
"""
from __future__ import annotations

import itertools
import random
from typing import Any

import cocotb
from cocotb.clock import Clock
from cocotb.triggers import ClockCycles, FallingEdge, RisingEdge, with_timeout
from cocotbext.axi import (  # type: ignore[import-untyped]  # no py.typed
    AxiStreamBus,
    AxiStreamFrame,
    AxiStreamSink,
    AxiStreamSource,
)

from .unit_bench import check_held_beat, pulse_reset

CLOCK_NS = 10
# A bound on any wait, so a design that stops passing beats fails instead of hanging.
TIMEOUT_US = 200

PAUSES = {
    "none": None,
    "cycle": lambda: itertools.cycle([1, 1, 0, 1, 0, 0, 0]),
    "random": lambda: (random.random() < 0.4 for _ in itertools.count()),
}


class TB:
    """Clock, reset and one bus model per side of the slice, one pixel per beat."""

    def __init__(self, dut: Any) -> None:
        self.dut = dut
        Clock(dut.clk, CLOCK_NS, unit="ns").start()
        # byte_lanes=1: one "byte" per beat, so each TDATA word and TUSER value is one list item.
        self.source = AxiStreamSource(AxiStreamBus.from_prefix(dut, "s_axis"), dut.clk, dut.rst, byte_lanes=1)
        self.sink = AxiStreamSink(AxiStreamBus.from_prefix(dut, "m_axis"), dut.clk, dut.rst, byte_lanes=1)
        self.width = len(dut.s_axis_tdata)
        self.stall_violations: list[str] = []
        cocotb.start_soon(self._check_stall())

    def set_pauses(self, idle: str, backpressure: str) -> None:
        idle_gen, bp_gen = PAUSES[idle], PAUSES[backpressure]
        self.source.set_pause_generator(idle_gen() if idle_gen else None)
        self.sink.set_pause_generator(bp_gen() if bp_gen else None)

    async def reset(self) -> None:
        await pulse_reset(self.dut, 3)

    async def _check_stall(self) -> None:
        """AXI4-Stream rule: once TVALID is up, the beat must not change until TREADY takes it."""
        dut = self.dut
        held = None
        while True:
            await RisingEdge(dut.clk)
            held = check_held_beat(dut, held, self.stall_violations)

    def video_frame(self, width: int, height: int) -> list[AxiStreamFrame]:
        """One packet per line; TUSER marks the frame's first pixel."""
        lines = []
        for row in range(height):
            pixels = [random.getrandbits(self.width) for _ in range(width)]
            tuser = [int(row == 0 and col == 0) for col in range(width)]
            lines.append(AxiStreamFrame(pixels, tuser=tuser))
        return lines


async def _recv(sink: AxiStreamSink) -> AxiStreamFrame:
    """The next packet, or a failure (not a hang) when none comes."""
    return await with_timeout(sink.recv(compact=False), TIMEOUT_US, "us")


@cocotb.test()
@cocotb.parametrize(idle=list(PAUSES), backpressure=list(PAUSES))
async def random_frames(dut: Any, idle: str, backpressure: str) -> None:
    """Random video frames through the slice: every beat arrives, in order, unchanged."""
    tb = TB(dut)
    await tb.reset()
    tb.set_pauses(idle, backpressure)

    sent: list[AxiStreamFrame] = []
    for _ in range(3):
        for line in tb.video_frame(width=random.randint(1, 24), height=random.randint(1, 4)):
            await tb.source.send(line)
            sent.append(line)

    for number, line in enumerate(sent):
        got = await _recv(tb.sink)
        assert len(got.tdata) == len(line.tdata), (
            f"line {number}: TLAST after {len(got.tdata)} beats, sent {len(line.tdata)}"
        )
        for beat, (want_data, got_data, want_user, got_user) in enumerate(
            zip(line.tdata, got.tdata, line.tuser, got.tuser, strict=True)
        ):
            assert (got_data, got_user) == (want_data, want_user), (
                f"line {number} beat {beat}: got TDATA {got_data:#018x} TUSER {got_user}, "
                f"sent TDATA {want_data:#018x} TUSER {want_user}"
            )
    assert tb.sink.empty(), "beats arrived that were never sent"
    assert not tb.stall_violations, f"output changed while stalled: {tb.stall_violations[:5]}"


@cocotb.test()
async def full_rate(dut: Any) -> None:
    """Without pauses the slice passes one beat per clock, one clock after it is accepted."""
    tb = TB(dut)
    await tb.reset()
    line = tb.video_frame(width=64, height=1)[0]

    cycle = 0
    accepted: list[int] = []
    delivered: list[int] = []

    async def count() -> None:
        nonlocal cycle
        while True:
            await RisingEdge(dut.clk)
            cycle += 1
            if dut.s_axis_tvalid.value and dut.s_axis_tready.value:
                accepted.append(cycle)
            if dut.m_axis_tvalid.value and dut.m_axis_tready.value:
                delivered.append(cycle)

    counter = cocotb.start_soon(count())
    await tb.source.send(line)
    got = await _recv(tb.sink)
    await FallingEdge(dut.clk)
    counter.cancel()

    assert got.tdata == line.tdata
    assert len(accepted) == len(delivered) == 64
    clocks = accepted[-1] - accepted[0] + 1
    assert clocks == 64, f"input took {clocks} clocks for 64 beats"
    latencies = {d - a for a, d in zip(accepted, delivered, strict=True)}
    assert latencies == {1}, f"latency {sorted(latencies)} clocks, want 1"


@cocotb.test()
async def valid_through_reset(dut: Any) -> None:
    """A beat offered while TREADY is still low after reset is taken exactly once."""
    Clock(dut.clk, CLOCK_NS, unit="ns").start()
    dut.m_axis_tready.value = 1
    dut.s_axis_tdata.value = 0x0123456789ABCDEF
    dut.s_axis_tlast.value = 1
    dut.s_axis_tuser.value = 1
    dut.s_axis_tvalid.value = 1
    dut.rst.value = 1
    await ClockCycles(dut.clk, 3)
    dut.rst.value = 0

    delivered = 0
    taken = False
    for _ in range(10):
        await RisingEdge(dut.clk)
        if dut.m_axis_tvalid.value and dut.m_axis_tready.value:
            delivered += 1
            assert int(dut.m_axis_tdata.value) == 0x0123456789ABCDEF
        if taken:
            continue
        if dut.s_axis_tvalid.value and dut.s_axis_tready.value:
            taken = True
            await FallingEdge(dut.clk)
            dut.s_axis_tvalid.value = 0
    assert taken, "the slice never raised TREADY after reset"
    assert delivered == 1, f"one beat in, {delivered} out"
