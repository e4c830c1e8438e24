"""cocotb testbench for stereocam/overlays/rtl/camera/frame_gate.v against its model, clock by clock.

Run by ``tests/hdl/test_frame_gate_rtl.py`` through ``run_cocotb``; not a pytest module. Each case
builds a schedule: the beat offered on ``s_axis`` in every clock (random 64-bit TDATA, TUSER on a
frame's first beat, TLAST ending each line, idle clocks between) and ``m_axis_tready`` in every
clock. The oracle is ``stereocam/overlays/model/frame_gate.py``: every beat that leaves ``m_axis``
(the clock it leaves in, TDATA, TUSER, TLAST) and the frame counters must equal the model's. Each case
also states what the policy (``stereocam/overlays/spec/frame_gate.py``) makes of its schedule, frame by
frame, and checks the model against that, so the model is tested too. In every clock after reset
``s_axis_tready`` must be high, and an offered beat must hold until it is taken (AXI4-Stream).

The build's DEPTH comes in ``STEREOCAM_FG_DEPTH``: the small cases need a small one (64), the
camera-rate case the default (1024).
"""
from __future__ import annotations

import os
import random
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import cocotb
from cocotb.clock import Clock
from cocotb.handle import SimHandleBase
from cocotb.triggers import FallingEdge

from stereocam.overlays.model import frame_gate as model
from stereocam.overlays.model.frame_gate import Beat
from stereocam.overlays.spec import frame_gate as spec

from .unit_bench import ready_pattern

DEPTH = int(os.environ.get("STEREOCAM_FG_DEPTH", str(spec.PARAMETERS["DEPTH"])))
CLOCK_NS = 10

Frame = List[List[int]]  # rows of TDATA words
Schedule = List[Optional[Beat]]


# ---- schedules ------------------------------------------------------------------------------------

def random_frame(rng: random.Random, width: int, height: int) -> Frame:
    return [[rng.getrandbits(64) for _ in range(width)] for _ in range(height)]


@dataclass
class Builder:
    """Appends frames to a schedule, remembering where each frame and line starts and ends."""

    rng: random.Random
    beats: Schedule = field(default_factory=list)
    frame_start: List[int] = field(default_factory=list)  # clock of each frame's TUSER beat
    line_end: List[List[int]] = field(default_factory=list)  # clock of each line's TLAST beat

    def idle(self, clocks: int) -> None:
        self.beats.extend([None] * clocks)

    def frame(self, frame: Frame, *, pause: float = 0.0, hblank: Tuple[int, int] = (0, 0),
              line_period: int = 0) -> None:
        """One frame: a beat per clock, an idle clock before a beat with probability ``pause``,
        ``hblank`` (lowest, highest) idle clocks after each line, or lines ``line_period`` clocks apart."""
        start = len(self.beats)
        self.frame_start.append(start)
        self.line_end.append([])
        for y, row in enumerate(frame):
            if line_period:
                self.idle(max(0, start + y * line_period - len(self.beats)))
            for x, data in enumerate(row):
                while self.rng.random() < pause:
                    self.beats.append(None)
                if y == 0 and x == 0:
                    self.frame_start[-1] = len(self.beats)
                self.beats.append(Beat(data, y == 0 and x == 0, x == len(row) - 1))
            self.line_end[-1].append(len(self.beats) - 1)
            if not line_period:
                self.idle(self.rng.randint(*hblank))

    def frames(self, frames: Sequence[Frame], idle: int, *, pause: float = 0.0,
               hblank: Tuple[int, int] = (0, 0), line_period: int = 0) -> None:
        """Each of ``frames`` as :meth:`frame` makes it, with ``idle`` idle clocks after each."""
        for f in frames:
            self.frame(f, pause=pause, hblank=hblank, line_period=line_period)
            self.idle(idle)


# ---- the bench ------------------------------------------------------------------------------------

class Bench:
    def __init__(self, dut: SimHandleBase) -> None:
        self.dut = dut
        dut.aresetn.value = 1
        self.idle_inputs()
        dut.m_axis_tready.value = 0
        cocotb.start_soon(Clock(dut.aclk, CLOCK_NS, unit="ns").start())

    def idle_inputs(self) -> None:
        dut = self.dut
        dut.s_axis_tvalid.value = 0
        dut.s_axis_tdata.value = 0
        dut.s_axis_tuser.value = 0
        dut.s_axis_tlast.value = 0

    async def reset(self) -> None:
        await FallingEdge(self.dut.aclk)
        self.dut.aresetn.value = 0
        self.idle_inputs()
        self.dut.m_axis_tready.value = 0
        for _ in range(4):
            await FallingEdge(self.dut.aclk)
        self.dut.aresetn.value = 1
        for _ in range(2):  # the gate's registered reset is over one clock later
            await FallingEdge(self.dut.aclk)

    def counters(self) -> Tuple[int, int, int]:
        d = self.dut
        return int(d.frames_admitted_reg.value), int(d.frames_dropped_reg.value), int(d.frames_cut_reg.value)

    async def play(self, inputs: Sequence[Optional[Beat]], tready: Sequence[bool],
                   problems: List[str]) -> List[Tuple[int, Beat]]:
        """Drive ``inputs`` and ``tready`` clock by clock from the current clock (clock 0): the beats
        that left, by clock. Signals are read and driven at the falling edge, half a clock before the
        rising edge that samples them, so neither simulator's scheduling order matters."""
        dut = self.dut
        out: List[Tuple[int, Beat]] = []
        held: Optional[Beat] = None
        for c, ready in enumerate(tready):
            if c:
                await FallingEdge(dut.aclk)
            if not dut.s_axis_tready.value:
                problems.append(f"clock {c}: s_axis_tready low")
            if dut.m_axis_tvalid.value:
                beat = Beat(int(dut.m_axis_tdata.value), bool(dut.m_axis_tuser.value),
                            bool(dut.m_axis_tlast.value))
                if held is not None and beat != held:
                    problems.append(f"clock {c}: offered beat changed before it was taken")
                if ready:
                    out.append((c, beat))
                held = None if ready else beat
            elif held is not None:
                problems.append(f"clock {c}: TVALID fell before the beat was taken")
                held = None
            b = inputs[c] if c < len(inputs) else None
            if b is None:
                dut.s_axis_tvalid.value = 0
            else:
                dut.s_axis_tvalid.value = 1
                dut.s_axis_tdata.value = b.data
                dut.s_axis_tuser.value = int(b.user)
                dut.s_axis_tlast.value = int(b.last)
            dut.m_axis_tready.value = int(ready)
        await FallingEdge(dut.aclk)
        self.idle_inputs()
        dut.m_axis_tready.value = 0
        return out


def compare(got: Sequence[Tuple[int, Beat]], want: Sequence[Tuple[int, Beat]], label: str) -> List[str]:
    """Every beat and its clock: empty when equal."""
    problems = []
    for i, (g, w) in enumerate(zip(got, want)):  # noqa: B905 - lengths compared below
        if g != w:
            problems.append(f"{label}: beat {i} left in clock {g[0]} as {g[1]}, the model says clock {w[0]}"
                            f" as {w[1]}")
            break
    if len(got) != len(want):
        problems.append(f"{label}: {len(got)} beats left, the model says {len(want)}")
    return problems


async def run_case(tb: Bench, label: str, inputs: Schedule, tready: Sequence[bool],
                   expected_frames: Optional[Sequence[Frame]] = None,
                   counters: Optional[Tuple[int, int, int]] = None) -> model.GateOutput:
    """Reset, play, compare with the model; ``expected_frames`` and ``counters`` (admitted, dropped,
    cut) are what the policy says, checked against the model (and so the RTL)."""
    want = model.run(inputs, tready, depth=DEPTH)
    await tb.reset()
    before = tb.counters()
    problems: List[str] = []
    got = await tb.play(inputs, tready, problems)
    problems += compare(got, want.beats, label)
    after = tb.counters()
    delta = tuple((a - b) & 0xFFFF for a, b in zip(after, before, strict=True))
    if delta != (want.admitted, want.dropped, want.cut):
        problems.append(f"{label}: counters (admitted, dropped, cut) {delta}, the model says "
                        f"{(want.admitted, want.dropped, want.cut)}")
    frames, framing = model.split_frames([b for _, b in want.beats])
    problems += [f"{label}: model: {p}" for p in framing]
    if expected_frames is not None and frames != [list(f) for f in expected_frames]:
        problems.append(f"{label}: the model's frames are {[(len(f), len(f[0]) if f else 0) for f in frames]}"
                        f" (rows, width); the policy says "
                        f"{[(len(f), len(f[0]) if f else 0) for f in expected_frames]} and these beats")
    if counters is not None and counters != (want.admitted, want.dropped, want.cut):
        problems.append(f"{label}: the model counts {(want.admitted, want.dropped, want.cut)}, the policy "
                        f"{counters}")
    assert not problems, "\n".join(problems[:12])
    tb.dut._log.info("BEATS %s %d (%d clocks, %d beats in; admitted, dropped, cut: %s)", label,
                     len(want.beats), len(tready), sum(b is not None for b in inputs), delta)
    return want


def prefix_check(out_frames: Sequence[Frame], sent: Sequence[Frame]) -> List[str]:
    """Each frame out is the first whole lines of a frame sent, in order, none invented or repeated."""
    problems, j = [], 0
    for k, f in enumerate(out_frames):
        while j < len(sent) and not (0 < len(f) <= len(sent[j]) and sent[j][:len(f)] == f):
            j += 1
        if j == len(sent):
            problems.append(f"output frame {k} ({len(f)} lines) is no prefix of a frame sent after the last")
            break
        j += 1
    return problems


# ---- cases (DEPTH 64 build unless said) -----------------------------------------------------------

SIZES = [(16, 4), (1, 1), (3, 5), (24, 2), (7, 3), (2, 9)]


@cocotb.test()
async def always_ready(dut: SimHandleBase) -> None:
    """Downstream always ready, random pauses in the input, blanking after each frame: every frame
    passes whole, each beat LATENCY clocks after its line's TLAST or right behind the beat before."""
    assert DEPTH < 100, "the small cases need a small DEPTH"
    tb = Bench(dut)
    rng = random.Random(1)
    b = Builder(rng)
    frames = [random_frame(rng, w, h) for w, h in SIZES]
    b.frames(frames, spec.LATENCY + 30, pause=0.3, hblank=(0, 4))
    want = await run_case(tb, "always ready", b.beats, [True] * (len(b.beats) + 40), frames,
                          (len(frames), 0, 0))
    first = want.beats[0][0]
    assert first == b.line_end[0][0] + spec.LATENCY, f"first beat left in clock {first}"


@cocotb.test()
async def back_to_back_frames(dut: SimHandleBase) -> None:
    """Downstream always ready, but a frame starts before the last line of the one before has left:
    it is dropped whole (the gate is not empty), and the next one, after a gap, passes."""
    tb = Bench(dut)
    rng = random.Random(2)
    b = Builder(rng)
    frames = [random_frame(rng, 12, 3) for _ in range(3)]
    b.frame(frames[0])
    b.frame(frames[1])  # its TUSER comes the clock after frame 0's last TLAST
    b.idle(spec.LATENCY + 20)
    b.frame(frames[2])
    await run_case(tb, "back to back", b.beats, [True] * (len(b.beats) + 40), [frames[0], frames[2]],
                   (2, 1, 0))


@cocotb.test()
async def never_ready(dut: SimHandleBase) -> None:
    """Downstream never takes anything: nothing leaves, the input is never held. The first frame is
    admitted (the gate is empty after reset), fills the FIFO and is cut; every later one is dropped."""
    tb = Bench(dut)
    rng = random.Random(3)
    b = Builder(rng)
    frames = [random_frame(rng, 20, 6) for _ in range(5)]
    b.frames(frames, 30, pause=0.2, hblank=(2, 6))
    assert 20 * 6 > DEPTH
    await run_case(tb, "never ready", b.beats, [False] * len(b.beats), [], (1, 4, 1))


@cocotb.test()
async def random_tready(dut: SimHandleBase) -> None:
    """Random TREADY pauses (short and long runs) and input pauses, several seeds: whatever leaves is
    the model's, and each frame out is the first whole lines of a frame sent."""
    tb = Bench(dut)
    total = 0
    for seed, p_low, burst in ((10, 0.2, 1), (11, 0.5, 3), (12, 0.3, 40), (13, 0.7, 8), (14, 0.1, 60),
                                (15, 0.4, 2), (16, 0.05, 120), (17, 0.6, 1)):
        rng = random.Random(seed)
        b = Builder(rng)
        frames = [random_frame(rng, rng.randint(1, 24), rng.randint(1, 7)) for _ in range(12)]
        for f in frames:
            b.frame(f, pause=rng.choice((0.0, 0.3, 0.6)), hblank=(0, 8))
            b.idle(rng.randint(0, 80))
        tready = ready_pattern(rng, len(b.beats) + 200, p_low, burst)
        want = await run_case(tb, f"random tready {seed}", b.beats, tready)
        out_frames, _ = model.split_frames([beat for _, beat in want.beats])
        problems = prefix_check(out_frames, frames)
        assert not problems, "\n".join(problems)
        total += len(want.beats)
    assert total > 0


@cocotb.test()
async def overflow_mid_frame(dut: SimHandleBase) -> None:
    """TREADY low from the middle of frame 1 for long enough to fill the FIFO: frame 1 comes out cut
    to its first whole lines, the frames after it whole."""
    tb = Bench(dut)
    rng = random.Random(4)
    b = Builder(rng)
    frames = [random_frame(rng, 20, 6) for _ in range(4)]
    b.frames(frames, 60, hblank=(10, 10))
    stall_from = b.line_end[1][1] + 2  # frame 1's first two lines are in, the first has left
    stall_to = b.line_end[1][5] + 1  # until frame 1's last TLAST: frame 1 overflows before it
    tready = [not (stall_from <= c < stall_to) for c in range(len(b.beats) + 60)]
    want = await run_case(tb, "overflow", b.beats, tready)
    out_frames, _ = model.split_frames([beat for _, beat in want.beats])
    assert len(out_frames) == 4, [len(f) for f in out_frames]
    cut = out_frames[1]
    assert 2 <= len(cut) < 6 and cut == frames[1][:len(cut)], f"frame 1 out with {len(cut)} lines"
    assert [out_frames[0], *out_frames[2:]] == [frames[0], *frames[2:]]
    assert (want.admitted, want.dropped, want.cut) == (4, 0, 1)


@cocotb.test()
async def ready_again_mid_frame(dut: SimHandleBase) -> None:
    """Downstream not ready from reset until the middle of frame 3: the lines of frame 0 held since it
    was cut leave first (a short frame), frame 3 is dropped (it started while they were held), and
    frames 4 and 5 pass whole."""
    tb = Bench(dut)
    rng = random.Random(5)
    b = Builder(rng)
    frames = [random_frame(rng, 20, 6) for _ in range(6)]
    b.frames(frames, 40, pause=0.1, hblank=(8, 12))
    ready_from = b.line_end[3][1]
    tready = [c >= ready_from for c in range(len(b.beats) + 60)]
    held_lines = DEPTH // 20
    await run_case(tb, "ready again", b.beats, tready, [frames[0][:held_lines], frames[4], frames[5]],
                   (3, 3, 1))


@cocotb.test()
async def capacity_boundary(dut: SimHandleBase) -> None:
    """With downstream stalled, DEPTH beats fit and one more does not: four lines of DEPTH / 4 pass
    and a one-beat fifth line cuts the frame; a single line of DEPTH beats passes whole, one of
    DEPTH + 1 is cut before its first line (nothing of it leaves)."""
    tb = Bench(dut)
    rng = random.Random(9)
    b = Builder(rng)
    quarter = random_frame(rng, DEPTH // 4, 4)
    tip = [[rng.getrandbits(64)]]
    b.frame(quarter + tip)
    stalls = [(0, len(b.beats) + 5)]
    b.idle(DEPTH + 40)
    exact, over, last = random_frame(rng, DEPTH, 1), random_frame(rng, DEPTH + 1, 1), random_frame(rng, 3, 2)
    for f in (exact, over):
        b.frame(f)
        stalls.append((b.frame_start[-1], len(b.beats) + 5))
        b.idle(DEPTH + 40)
    b.frame(last)
    b.idle(20)
    tready = [not any(lo <= c < hi for lo, hi in stalls) for c in range(len(b.beats))]
    await run_case(tb, "capacity", b.beats, tready, [quarter, exact, last], (4, 0, 2))


@cocotb.test()
async def malformed_input(dut: SimHandleBase) -> None:
    """Beats before the first TUSER, a TUSER inside a line, one-beat frames, lines of different
    lengths, a line longer than DEPTH: only whole lines of admitted frames leave."""
    tb = Bench(dut)
    rng = random.Random(6)
    b = Builder(rng)
    stray = random_frame(rng, 5, 2)
    for beat in model.frame_beats(stray)[1:]:  # no TUSER: dropped
        b.beats.append(beat)
    b.idle(10)
    one = [[rng.getrandbits(64)]]
    b.frame(one)
    b.idle(10)
    ragged = [[rng.getrandbits(64) for _ in range(n)] for n in (3, 9, 1, 5)]
    b.frame(ragged)
    b.idle(30)
    cut_inside = random_frame(rng, 8, 3)
    b.frame(cut_inside)
    partial = model.frame_beats(random_frame(rng, 6, 1))
    b.beats.extend(Beat(x.data, False, False) for x in partial[1:4])  # a line with no TLAST
    b.idle(30)
    too_long = random_frame(rng, DEPTH + 5, 1)
    b.frame(too_long)
    b.idle(30)
    after = random_frame(rng, 4, 4)
    b.frame(after)
    b.idle(30)
    await run_case(tb, "malformed", b.beats, [True] * (len(b.beats) + 40),
                   [one, ragged, cut_inside, after], (5, 0, 2))


@cocotb.test()
async def reset_mid_frame(dut: SimHandleBase) -> None:
    """aresetn while lines are held and a frame is coming in: they are gone, nothing leaves until the
    next frame, which passes whole."""
    tb = Bench(dut)
    rng = random.Random(7)
    b = Builder(rng)
    frames = [random_frame(rng, 10, 4) for _ in range(2)]
    b.frames(frames, 20)
    cut_at = b.line_end[0][2]
    tready = [c < b.line_end[0][1] for c in range(cut_at + 1)]
    before = model.run(b.beats[:cut_at + 1], tready)
    await tb.reset()
    problems: List[str] = []
    got = await tb.play(b.beats[:cut_at + 1], tready, problems)
    problems += compare(got, before.beats, "before reset")
    assert not problems, "\n".join(problems)
    # reset, then the rest of frame 0 (no TUSER: dropped) and frame 1
    rest = b.beats[cut_at + 1:]
    await run_case(tb, "after reset", rest, [True] * (len(rest) + 30), [frames[1]], (1, 0, 0))


# ---- the default DEPTH at the fabric's rates ---------------------------------------------------------

#: aclk clocks per sensor line: 752 + 94 pixel clocks of the MT9V034 at 26.6 MHz, at 100 MHz.
LINE_CLOCKS = 3181


@cocotb.test()
async def camera_rate(dut: SimHandleBase) -> None:
    """The default build at camera_in's rate (a 752-beat line at one beat per clock every 3,181
    clocks): into the rectify core's rate (TREADY every other clock) a stall right after a line is
    committed is absorbed up to the spec's STALL_CLOCKS_RECTIFY clocks and cuts the frame one clock
    longer; the same into a VDMA (TREADY high) with STALL_CLOCKS_VDMA; the frames after pass whole."""
    assert DEPTH == spec.PARAMETERS["DEPTH"], "camera_rate runs in the default build"
    tb = Bench(dut)
    rng = random.Random(8)
    b = Builder(rng)
    frames = [random_frame(rng, 752, 3) for _ in range(5)]
    b.frames(frames, LINE_CLOCKS, line_period=LINE_CLOCKS)
    vdma_from = b.frame_start[2]
    tready = [c % 2 == 0 or c >= vdma_from for c in range(len(b.beats) + 2000)]
    stalls = (spec.STALL_CLOCKS_RECTIFY, spec.STALL_CLOCKS_RECTIFY + 1, spec.STALL_CLOCKS_VDMA,
              spec.STALL_CLOCKS_VDMA + 1)
    for frame, stall in enumerate(stalls):
        start = b.line_end[frame][1] + 1  # the clock after line 1's TLAST: line 1 is committed
        for c in range(start, start + stall):
            tready[c] = False
    want = [frames[0], frames[1][:2], frames[2], frames[3][:2], frames[4]]
    await run_case(tb, "camera rate", b.beats, tready, want, (5, 0, 2))
