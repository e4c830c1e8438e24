"""cocotb testbench for the whole rectify core (stereocam/overlays/rtl/rectify_core.v) against the emulated
core.

Run by ``tests/hdl/test_rectify_core_rtl.py`` through ``run_cocotb``; not a pytest module.
The pytest side writes the scenarios (``STEREOCAM_CORE_CASES``: a JSON file of steps and an
``.npz`` of frames); this side replays each one on the RTL, through ``cocotbext-axi``'s
AXI4-Lite master and AXI4-Stream source and sink with random pauses on both streams,
and on ``stereocam.overlays.emulated.rectify.EmulatedRectifyCore`` (the oracle) with the
very same register writes (``write(offset, value)``) and frames (``process(frame)``).
Every output beat (TDATA, TUSER, TLAST) of every frame the emulator emits must come out of
the RTL, in order, and nothing else; at each check point FLAGS, FRAME_COUNT, STATUS and
CONTROL read over AXI4-Lite must equal the emulator's.

Steps:
- ``write`` (offset, value): an AXI4-Lite write, once the frames before it are through (as
  the emulator sees them), and the same write to the emulator;
- ``frame`` (a frame of any size, well formed): sent as lines (TUSER on the first beat);
  the emulator's output, if any, is expected next on the master;
- ``frame_apply`` (frame, writes): the writes happen while the frame is in flight (the
  output stalled, STATUS.BUSY seen 1), so an APPLY among them latches after this frame and
  STATUS.APPLY_PENDING reads 1 meanwhile; the emulator processes the frame, then writes;
- ``check``: wait until every expected beat has come and the core is idle, then compare
  the registers. A frame with too few lines ends only at the next TUSER, so a check never
  follows one directly.

The report (``STEREOCAM_CORE_REPORT``) records beats, wall time and latencies.
"""
from __future__ import annotations

import json
import logging
import os
import random
import time
from collections import deque
from typing import Any, Deque, Dict, List, Tuple

import cocotb
import numpy as np
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, Event, with_timeout
from cocotbext.axi import AxiLiteBus, AxiLiteMaster

from tests.hdl.tb_rc_datapath import (
    PulseCounter,
    StreamBench,
    compare_frame,
    frame_beats,
    pause_gen,
)
from tests.hdl.unit_bench import add_to_report

REG = {"CONTROL": 0x20, "STATUS": 0x24, "FLAGS": 0x28, "FRAME_COUNT": 0x2C}
TIMEOUT_US = 20_000


def build_from_env() -> Tuple[int, int, int, bool]:
    mw, mh, lb, colour = (int(v) for v in os.environ["STEREOCAM_CORE_BUILD"].split(","))
    return mw, mh, lb, bool(colour)


class CoreTB(StreamBench):
    """rectify_core with its bus models and the emulated core beside it."""

    def __init__(self, dut: SimHandleBase) -> None:
        super().__init__(dut, dut.aclk, dut.aresetn, reset_active_level=False,
                         watch=os.environ.get("STEREOCAM_CORE_WATCH", "1") == "1")
        self.axil = AxiLiteMaster(AxiLiteBus.from_prefix(dut, "s_axil"), dut.aclk, dut.aresetn,
                                  reset_active_level=False)
        self.axil.write_if.log.setLevel(logging.WARNING)
        self.axil.read_if.log.setLevel(logging.WARNING)
        self.max_width, self.max_height, self.lb_rows, self.colour = build_from_env()
        self.frame_done = PulseCounter(dut.aclk, dut.datapath_inst.frame_done)
        self.emu: Any = None
        self.expected: Deque[Tuple[str, np.ndarray]] = deque()
        self.problems: List[str] = []
        self.beats_out = 0
        self.p_out = 0.0
        self.rng = random.Random(0)
        self.frame_queued = Event()
        self.receiver = cocotb.start_soon(self._receive())

    def new_emulator(self) -> None:
        from stereocam.overlays.emulated.rectify import EmulatedRectifyCore

        self.emu = EmulatedRectifyCore(max_width=self.max_width, max_height=self.max_height,
                                       lb_rows=self.lb_rows, colour=self.colour)

    async def reset(self) -> None:
        self.dut.aresetn.value = 0
        await ClockCycles(self.dut.aclk, 5)
        self.dut.aresetn.value = 1
        await ClockCycles(self.dut.aclk, 5)
        self.new_emulator()
        self.frame_done.count = 0

    async def _receive(self) -> None:
        """Takes the expected frames in order as the RTL sends them."""
        while True:
            while not self.expected:
                self.frame_queued.clear()
                await self.frame_queued.wait()
            label, want = self.expected[0]
            words, users, lengths = await self.receive_frame(want.shape[0], TIMEOUT_US)
            self.problems += compare_frame(label, words, users, lengths, want)
            self.beats_out += sum(lengths)
            self.expected.popleft()

    def expect(self, label: str, frame: np.ndarray) -> None:
        self.expected.append((label, frame))
        self.frame_queued.set()

    # -- steps ----------------------------------------------------------------------------
    async def write(self, offset: int, value: int) -> None:
        """A register write after every frame sent so far has gone through (the emulator's order:
        control bits are sampled, and an APPLY latches, at a start of frame)."""
        if self.expected or not self.source.idle():
            await self.drain()
        await self.axil.write_dword(offset, value)
        self.emu.write(offset, value)

    async def read(self, offset: int) -> int:
        return int(await self.axil.read_dword(offset))

    async def frame(self, label: str, frame: np.ndarray) -> None:
        out = self.emu.process(frame)
        if out is not None:
            self.expect(label, out)
        for packet in _packets(frame):
            await self.source.send(packet)

    async def drain(self) -> None:
        """Every expected frame received, the input sent, the core idle (STATUS.BUSY 0)."""
        await with_timeout(self.source.wait(), TIMEOUT_US, "us")
        start = self.cycle
        while self.expected or (await self.read(REG["STATUS"])) & 1:
            await ClockCycles(self.dut.aclk, 20)
            if self.cycle - start > TIMEOUT_US * 100:
                self.problems.append(f"no progress: {len(self.expected)} frames still expected")
                raise AssertionError("\n".join(self.problems))

    async def frame_apply(self, label: str, frame: np.ndarray, writes: List[Tuple[int, int]]) -> None:
        await self.drain()
        self.sink.set_pause_generator(None)
        self.sink.pause = True
        out = self.emu.process(frame)
        if out is not None:
            self.expect(label, out)
        sender = cocotb.start_soon(self._send_frame(frame))
        for _ in range(10_000):
            if (await self.read(REG["STATUS"])) & 1:
                break
        else:
            raise AssertionError(f"{label}: STATUS.BUSY never rose")
        applies = False
        for offset, value in writes:
            await self.axil.write_dword(offset, value)
            applies |= offset == REG["CONTROL"] and bool(value & 0x10)
        status = await self.read(REG["STATUS"])
        if applies and status != 0b11:
            self.problems.append(
                f"{label}: STATUS {status:#x} after APPLY during a frame, want BUSY and APPLY_PENDING")
        self.sink.pause = False
        self.sink.set_pause_generator(pause_gen(self.p_out, self.rng))
        await sender
        for offset, value in writes:
            self.emu.write(offset, value)

    async def _send_frame(self, frame: np.ndarray) -> None:
        for packet in _packets(frame):
            await self.source.send(packet)

    async def check(self, label: str) -> None:
        await self.drain()
        await ClockCycles(self.dut.aclk, 10)
        for name in ("FLAGS", "FRAME_COUNT", "STATUS", "CONTROL"):
            got, want = await self.read(REG[name]), self.emu.read(REG[name])
            if got != want:
                self.problems.append(f"{label}: {name} reads {got:#x}, the emulator {want:#x}")
        if not self.sink.empty():
            self.problems.append(f"{label}: {self.sink.count()} output lines the emulator did not emit")
        if self.frame_done.count != self.emu.read(REG["FRAME_COUNT"]):
            self.problems.append(f"{label}: {self.frame_done.count} frame_done pulses")


def _packets(frame: np.ndarray) -> List[Any]:
    from tests.hdl.tb_rc_datapath import beat_packets

    return beat_packets(frame_beats(frame))


def load_cases() -> Tuple[List[Dict[str, Any]], Any]:
    path = os.environ["STEREOCAM_CORE_CASES"]
    with open(path) as f:
        cases = json.load(f)["scenarios"]
    frames = np.load(os.path.splitext(path)[0] + ".npz")
    return cases, frames


def write_report(key: str, value: Any) -> None:
    add_to_report("STEREOCAM_CORE_REPORT", key, value)


async def run_scenario(tb: CoreTB, sc: Dict[str, Any], frames: Any) -> Dict[str, Any]:
    await tb.reset()
    tb.rng = random.Random(sc["seed"])
    p_in, p_out = sc["pauses"]
    tb.p_out = p_out
    tb.set_pauses(p_in, p_out, tb.rng)
    tb.problems = []
    t0, c0, b0 = time.monotonic(), tb.cycle, tb.beats_out
    for k, step in enumerate(sc["steps"]):
        label = f"{sc['name']} step {k}"
        op = step["op"]
        if op == "write":
            await tb.write(step["offset"], step["value"])
        elif op == "frame":
            await tb.frame(f"{label} ({step['frame']})", frames[step["frame"]])
        elif op == "frame_apply":
            writes = [tuple(w) for w in step["writes"]]
            await tb.frame_apply(f"{label} ({step['frame']})", frames[step["frame"]], writes)
        elif op == "check":
            await tb.check(label)
        else:
            raise ValueError(f"unknown step {op}")
    await tb.check(f"{sc['name']} end")
    assert not tb.problems, "\n".join(tb.problems[:20])
    assert not tb.stall_violations, f"output changed while stalled: {tb.stall_violations[:5]}"
    seconds = time.monotonic() - t0
    beats = tb.beats_out - b0
    return {"beats": beats, "clocks": tb.cycle - c0, "seconds": round(seconds, 2),
            "flags": tb.emu.read(REG["FLAGS"]), "frame_count": tb.emu.read(REG["FRAME_COUNT"]),
            "beats_per_second": round(beats / seconds) if seconds else None}


@cocotb.test()
async def scenarios(dut: SimHandleBase) -> None:
    """Every scenario of STEREOCAM_CORE_CASES, the RTL against the emulated core."""
    tb = CoreTB(dut)
    cases, frames = load_cases()
    report = {}
    failures = []
    for sc in cases:
        try:
            report[sc["name"]] = await run_scenario(tb, sc, frames)
            dut._log.info(f"{sc['name']}: {report[sc['name']]}")
        except AssertionError as exc:
            failures.append(f"{sc['name']}: {exc}")
            dut._log.error(f"{sc['name']}: {exc}")
    write_report("scenarios", report)
    assert not failures, "\n".join(failures)


@cocotb.test()
async def identity_and_enable(dut: SimHandleBase) -> None:
    """The build's read-only registers; ENABLE 0 holds a frame at its start (TREADY low) until set."""
    tb = CoreTB(dut)
    await tb.reset()
    for offset in (0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x30, 0x34):
        got, want = await tb.read(offset), tb.emu.read(offset)
        assert got == want, f"register {offset:#x} reads {got:#x}, the emulator {want:#x}"
    # A frame of the reset size while ENABLE is 0: nothing happens; TREADY is low at its start.
    w, h = tb.emu.get_field("WIDTH", "VALUE"), tb.emu.get_field("HEIGHT", "VALUE")
    if w > tb.max_width:
        w, h = tb.max_width, 8  # a small build: the frame is dropped for its size once enabled
    rng = np.random.default_rng(4)
    frame = rng.integers(0, 256, (h, w, 8), dtype=np.uint8)
    sender = cocotb.start_soon(tb._send_frame(frame))
    await ClockCycles(dut.aclk, 300)
    assert not dut.s_axis_tready.value, "TREADY high at a start of frame with ENABLE 0"
    assert tb.sink.empty() and not (await tb.read(REG["STATUS"])) & 1
    await tb.axil.write_dword(REG["CONTROL"], 1)  # while the frame waits at its start
    tb.emu.write(REG["CONTROL"], 1)
    out = tb.emu.process(frame)
    if out is not None:
        tb.expect("after ENABLE", out)
    await sender
    await tb.check("after ENABLE")
    assert not tb.problems, "\n".join(tb.problems)


@cocotb.test()
async def latency(dut: SimHandleBase) -> None:
    """Clocks from the start of frame to the first output beat, per beat, and the drain (no pauses)."""
    tb = CoreTB(dut)
    cases, frames = load_cases()
    lat = [sc for sc in cases if sc["name"].startswith("latency")]
    results = {}
    for sc in lat:
        await tb.reset()
        tb.set_pauses(0.0, 0.0, random.Random(0))
        tb.problems = []
        steps = sc["steps"]
        for step in steps[:-1]:
            await tb.write(step["offset"], step["value"])
        frame = frames[steps[-1]["frame"]]
        tb.in_cycles.clear()
        tb.out_cycles.clear()
        tb.record_cycles = True
        await tb.frame(sc["name"], frame)
        await tb.check(sc["name"])
        tb.record_cycles = False
        assert not tb.problems, "\n".join(tb.problems)
        ins, outs = tb.in_cycles, tb.out_cycles
        h, w = frame.shape[:2]
        e0 = sc["e0"]
        res = {
            "start_of_frame_to_first_beat": outs[0] - ins[0],
            "row_e0_end_to_first_beat": outs[0] - ins[(e0 + 1) * w - 1],
            "clocks_per_beat": round((outs[-1] - outs[w]) / (len(outs) - 1 - w), 4),
            "last_input_to_last_output": outs[-1] - ins[-1],
            "frame_clocks": outs[-1] - ins[0],
            "width": w, "height": h, "e0": e0,
        }
        results[sc["name"]] = res
        dut._log.info(f"{sc['name']}: {res}")
    write_report("latency", results)
