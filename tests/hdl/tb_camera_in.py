"""cocotb testbench for stereocam/overlays/rtl/camera/camera_in.v, the camera input IP, against its numpy
model.

Run by ``tests/hdl/test_camera_in_rtl.py`` through ``run_cocotb``; not a pytest module. Two
sensor models play random 10-bit Bayer frames on their own pixel clocks (MT9V034 bus timing from
``stereocam/overlays/model/camera_in.py: pixel_bus``; frame k starts on both at the same moment, as with
hardware-synchronised sensors), aclk runs at another, unrelated frequency, and a sink takes the
AXI4-Stream with random TREADY pauses. The oracle is ``stereocam/overlays/model/camera_in.py``
(``expected_frames``, ``demosaic``): every output beat (TDATA, TUSER, TLAST) is compared with it
bit for bit. Where the test makes a receiver's FIFO overflow, each output frame must be the model
of a prefix of the frame sent (the spec's rule for a frame cut short), in order.

The build's MAX_WIDTH comes in ``STEREOCAM_CI_MAX_WIDTH``; ``STEREOCAM_COSIM_FULL=1`` adds seeds
and a full-size 752 x 480 frame pair.
"""
from __future__ import annotations

import logging
import os
import random
from dataclasses import dataclass
from typing import Any, List, Optional, Sequence, Tuple

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.handle import SimHandleBase
from cocotb.simtime import get_sim_time
from cocotb.triggers import ClockCycles, FallingEdge, RisingEdge, Timer, with_timeout

from stereocam.overlays.model import camera_in as model
from stereocam.overlays.spec import camera_in as spec

FULL = os.environ.get("STEREOCAM_COSIM_FULL") == "1"
MAX_WIDTH = int(os.environ.get("STEREOCAM_CI_MAX_WIDTH", "64"))
log = logging.getLogger("tb_camera_in")

Lines = List[np.ndarray]
DEFAULT_TIMING = model.BusTiming(hblank=6, vblank=0)


@dataclass(frozen=True)
class Clocks:
    """Periods in ps (cocotb's clocks need whole steps) and the right camera's phase offset."""

    aclk: int = 10_000
    pclk0: int = 37_000
    pclk1: int = 37_000
    phase1: int = 11_000


def random_frame(rng: np.random.Generator, width: int, height: int) -> Lines:
    """A raw frame as lines: random samples with the extremes (0, 1023) sprinkled in."""
    raw = rng.integers(0, 1024, (height, width))
    raw[rng.random((height, width)) < 0.05] = 1023
    raw[rng.random((height, width)) < 0.05] = 0
    return [row for row in raw]


def frame_words(frame: np.ndarray) -> np.ndarray:
    """(H, W, 8) uint8 -> (H, W) uint64 TDATA words (byte 0 in bits 7:0)."""
    return np.ascontiguousarray(frame).view("<u8").reshape(frame.shape[:2])


class Bench:
    """Clocks, reset, the two sensors and the stream sink of one camera_in."""

    def __init__(self, dut: SimHandleBase, clocks: Clocks = Clocks(), seed: int = 1) -> None:
        self.dut = dut
        self.clocks = clocks
        self.rng = random.Random(seed)
        self.beats: List[Tuple[int, int, int]] = []  # (tdata, tuser, tlast)
        self.violations: List[str] = []
        self.ready_p = 0.0  # probability of TREADY low per clock
        self.stall: Optional[Tuple[int, int]] = None  # (first beat index, clocks): one long TREADY low
        self.tready_low_clocks = 0
        for cam in ("cam0", "cam1"):
            getattr(dut, f"{cam}_data").value = 0
            getattr(dut, f"{cam}_line_valid").value = 0
            getattr(dut, f"{cam}_frame_valid").value = 0
        dut.m_axis_tready.value = 0
        dut.aresetn.value = 1
        cocotb.start_soon(Clock(dut.aclk, clocks.aclk, unit="ps").start())
        cocotb.start_soon(Clock(dut.cam0_pclk, clocks.pclk0, unit="ps").start())
        cocotb.start_soon(self._late_clock(dut.cam1_pclk, clocks.pclk1, clocks.phase1))
        cocotb.start_soon(self._sink())

    @staticmethod
    async def _late_clock(signal: Any, period: int, phase: int) -> None:
        await Timer(phase, unit="ps")
        await Clock(signal, period, unit="ps").start()

    async def reset(self, clocks: int = 24) -> None:
        self.dut.aresetn.value = 0
        await ClockCycles(self.dut.aclk, clocks)
        self.dut.aresetn.value = 1
        await ClockCycles(self.dut.aclk, 8)

    async def _sink(self) -> None:
        """TREADY with random pauses; records every beat; checks that a beat offered holds until taken."""
        dut = self.dut
        held: Optional[Tuple[int, int, int]] = None
        stall_left = 0
        while True:
            await RisingEdge(dut.aclk)
            valid = bool(dut.m_axis_tvalid.value)
            ready = bool(dut.m_axis_tready.value)
            if valid:
                beat = (int(dut.m_axis_tdata.value), int(dut.m_axis_tuser.value), int(dut.m_axis_tlast.value))
                if held is not None and beat != held:
                    self.violations.append(f"at {get_sim_time('ns')} ns: held {held}, now {beat}")
                if ready:
                    self.beats.append(beat)
                    held = None
                else:
                    held = beat
            elif held is not None:
                self.violations.append(f"at {get_sim_time('ns')} ns: TVALID dropped before the beat left")
                held = None
            # TREADY for the next clock
            if self.stall is not None and len(self.beats) >= self.stall[0]:
                stall_left, self.stall = self.stall[1], None
            if stall_left > 0:
                stall_left -= 1
                low = True
            else:
                low = self.rng.random() < self.ready_p
            self.tready_low_clocks += low
            dut.m_axis_tready.value = 0 if low else 1

    async def _play(self, cam: int, bus: np.ndarray, start_ps: int) -> None:
        """One frame's bus samples on camera ``cam``'s pixel clock, starting at ``start_ps``."""
        dut = self.dut
        pclk = getattr(dut, f"cam{cam}_pclk")
        data = getattr(dut, f"cam{cam}_data")
        lv = getattr(dut, f"cam{cam}_line_valid")
        fv = getattr(dut, f"cam{cam}_frame_valid")
        now = get_sim_time("ps")
        if start_ps > now:
            await Timer(start_ps - now, unit="ps")
        last = (-1, -1, -1)
        for d, line_valid, f in bus.tolist():
            await FallingEdge(pclk)
            if d != last[0]:
                data.value = d
            if line_valid != last[1]:
                lv.value = line_valid
            if f != last[2]:
                fv.value = f
            last = (d, line_valid, f)
        await FallingEdge(pclk)
        data.value, lv.value, fv.value = 0, 0, 0

    async def send(self, left: Sequence[Optional[Lines]], right: Sequence[Optional[Lines]],
                   timing: model.BusTiming = DEFAULT_TIMING) -> None:
        """Frame k of both cameras starts at the same moment (None: that camera sends nothing)."""
        buses = [[model.pixel_bus([f], timing) if f is not None else None for f in frames]
                 for frames in (left, right)]
        slow = max(self.clocks.pclk0, self.clocks.pclk1)
        longest = max(len(b) for cam in buses for b in cam if b is not None)
        period = (longest + 2 + max(spec.MIN_VBLANK_PCLK, 24, timing.vblank)) * slow
        start = int(get_sim_time("ps") // slow + 4) * slow
        for k in range(len(left)):
            tasks = [cocotb.start_soon(self._play(cam, bus, start + k * period))
                     for cam, bus in ((0, buses[0][k]), (1, buses[1][k])) if bus is not None]
            for t in tasks:
                await t
        end = start + len(left) * period
        now = get_sim_time("ps")
        if end > now:
            await Timer(end - now, unit="ps")

    def frames(self, start: int = 0) -> Tuple[List[np.ndarray], List[str]]:
        """The beats since beat ``start`` as frames of TDATA words, and what is wrong with their framing."""
        problems: List[str] = []
        frames: List[np.ndarray] = []
        rows: List[List[int]] = []
        line: List[int] = []
        for i, (d, u, last) in enumerate(self.beats[start:], start):
            if u:
                if line:
                    problems.append(f"beat {i}: TUSER inside a line ({len(rows)} rows, {len(line)} beats)")
                if rows:
                    frames.append(np.array(rows, np.uint64))
                rows, line = [], []
            elif not rows and not line:
                problems.append(f"beat {i}: a frame without TUSER on its first beat")
            line.append(d)
            if last:
                if rows and len(line) != len(rows[0]):
                    problems.append(f"beat {i}: line {len(rows)}: {len(line)} beats, line 0: {len(rows[0])}")
                rows.append(line)
                line = []
        if line:
            problems.append(f"{len(line)} beats after the last TLAST")
        if rows:
            frames.append(np.array(rows, np.uint64))
        return frames, problems

    async def settle(self, timeout_us: float = 200.0) -> None:
        """Wait until the output has been quiet for a while (the last row flushed, FIFOs empty)."""
        quiet, seen = 0, len(self.beats)
        async def wait() -> None:
            nonlocal quiet, seen
            while quiet < 400:
                await RisingEdge(self.dut.aclk)
                if len(self.beats) != seen or self.dut.m_axis_tvalid.value:
                    seen, quiet = len(self.beats), 0
                else:
                    quiet += 1
        await with_timeout(cocotb.start_soon(wait()), timeout_us, "us")


def compare(got: Sequence[np.ndarray], want: Sequence[np.ndarray], label: str) -> List[str]:
    """Every frame, every beat: empty when equal."""
    problems = []
    if len(got) != len(want):
        problems.append(f"{label}: {len(got)} frames out, want {len(want)} "
                        f"(shapes {[g.shape for g in got]} vs {[w.shape[:2] for w in want]})")
    for k, (g, w) in enumerate(zip(got, want)):  # noqa: B905 - counts compared above
        ww = frame_words(w)
        if g.shape != ww.shape:
            problems.append(f"{label} frame {k}: {g.shape[1]}x{g.shape[0]}, want {ww.shape[1]}x{ww.shape[0]}")
            continue
        diff = np.argwhere(g != ww)
        if diff.size:
            y, x = diff[0]
            problems.append(f"{label} frame {k}: {len(diff)} of {ww.size} beats differ, first ({x}, {y}): "
                            f"got {int(g[y, x]):#018x}, want {int(ww[y, x]):#018x}")
    return problems


def counters(dut: SimHandleBase) -> Tuple[int, int]:
    return int(dut.frames_out_reg.value), int(dut.frames_cut_reg.value)


async def run_case(tb: Bench, left: Sequence[Optional[Lines]], right: Sequence[Optional[Lines]],
                   want: Sequence[np.ndarray], label: str, *, cut: int = 0,
                   timing: model.BusTiming = DEFAULT_TIMING) -> None:
    """Send, settle, compare frames, framing, the AXI rule and the internal counters."""
    before = len(tb.beats)
    out0, cut0 = counters(tb.dut)
    await tb.send(left, right, timing)
    await tb.settle()
    frames, framing = tb.frames(before)
    problems = framing + compare(frames, want, label) + tb.violations
    out1, cut1 = counters(tb.dut)
    if (out1 - out0, cut1 - cut0) != (len(want), cut):
        problems.append(f"{label}: counters say {out1 - out0} frames out and {cut1 - cut0} cut, "
                        f"want {len(want)} and {cut}")
    assert not problems, "\n".join(problems[:12])
    beats = sum(w.shape[0] * w.shape[1] for w in want)
    log.info("%s: %d frames, %d beats compared, TREADY low %d clocks", label, len(want), beats,
             tb.tready_low_clocks)
    tb.dut._log.info("BEATS %s %d", label, beats)


def random_pairs(rng: np.random.Generator, sizes: Sequence[Tuple[int, int]]
                 ) -> Tuple[List[Lines], List[Lines]]:
    """A left and a right :func:`random_frame` of each (width, height) in ``sizes``: the left ones first."""
    left = [random_frame(rng, w, h) for w, h in sizes]
    right = [random_frame(rng, w, h) for w, h in sizes]
    return left, right


async def run_random_case(tb: Bench, rng: np.random.Generator, sizes: Sequence[Tuple[int, int]], label: str,
                          timing: model.BusTiming) -> None:
    """:func:`run_case` of :func:`random_pairs` of ``sizes``, each pair expected as the model makes it."""
    left, right = random_pairs(rng, sizes)
    await run_case(tb, left, right, model.expected_frames(left, right, MAX_WIDTH), label, timing=timing)


# ---- tests ------------------------------------------------------------------------------------------

SIZES = [(64, 16), (17, 9), (2, 2), (3, 5), (40, 7)]


@cocotb.test()
async def random_frames(dut: SimHandleBase) -> None:
    """Frames of several sizes (odd, the 2x2 minimum, the widest), random blanking, TREADY pauses."""
    tb = Bench(dut, seed=0)
    await tb.reset()
    for seed in range(3 if FULL else 1):
        rng = np.random.default_rng(100 + seed)
        tb.ready_p = 0.3
        left, right = random_pairs(rng, [(min(w, MAX_WIDTH), h) for w, h in SIZES])
        timing = model.BusTiming(hblank=int(rng.integers(1, 9)), vblank=0, fv_lead=int(rng.integers(0, 4)),
                                 fv_trail=int(rng.integers(0, 4)))
        await run_case(tb, left, right, model.expected_frames(left, right, MAX_WIDTH), f"seed {seed}",
                       timing=timing)


@cocotb.test()
async def unrelated_clocks(dut: SimHandleBase) -> None:
    """Pixel clocks of 24.4 and 25.6 MHz with an odd phase between them, aclk 142.9 MHz."""
    tb = Bench(dut, Clocks(aclk=7_000, pclk0=41_000, pclk1=39_000, phase1=17_300), seed=5)
    rng = np.random.default_rng(7)
    await tb.reset()
    tb.ready_p = 0.1
    await run_random_case(tb, rng, [(min(48, MAX_WIDTH), 12)] * 3, "unrelated clocks",
                          model.BusTiming(hblank=12, vblank=0))


@cocotb.test()
async def slow_aclk(dut: SimHandleBase) -> None:
    """aclk barely faster than the pixel rate needs: (W + 4) clocks per line of W + hblank pixel clocks."""
    tb = Bench(dut, Clocks(aclk=23_000, pclk0=37_000, pclk1=37_000, phase1=3_000), seed=6)
    rng = np.random.default_rng(8)
    await tb.reset()
    await run_random_case(tb, rng, [(min(48, MAX_WIDTH), 10)] * 2, "slow aclk",
                          model.BusTiming(hblank=4, vblank=0))


@cocotb.test()
async def backpressure_within_the_fifos(dut: SimHandleBase) -> None:
    """TREADY low for most of a line time, now and then: absorbed, nothing lost."""
    tb = Bench(dut, seed=2)
    rng = np.random.default_rng(9)
    await tb.reset()
    tb.ready_p = 0.5
    w = MAX_WIDTH
    tb.stall = (w * 2 + 5, int(w * 2.2))  # about 0.8 line times of the pixel clock
    await run_random_case(tb, rng, [(w, 8)] * 3, "backpressure", model.BusTiming(hblank=20, vblank=0))


@cocotb.test()
async def backpressure_overflow_cuts_frames(dut: SimHandleBase) -> None:
    """TREADY low for several line times: the frame in flight is cut (a shorter, still exact frame);
    the frames after it are whole again."""
    tb = Bench(dut, seed=3)
    rng = np.random.default_rng(10)
    await tb.reset()
    w = MAX_WIDTH
    n = 4
    left, right = random_pairs(rng, [(w, 10)] * n)
    tb.stall = (w * 2, 40 * w)  # ~15 line times at 37 ns pixels, 10 ns aclk
    before = len(tb.beats)
    out0, cut0 = counters(dut)
    await tb.send(left, right, model.BusTiming(hblank=4, vblank=0))
    await tb.settle()
    frames, problems = tb.frames(before)
    problems += tb.violations
    # each output frame is the model of a prefix of the next frame sent (in order, none invented)
    j, whole, cut_rows = 0, 0, []
    for k, got in enumerate(frames):
        while j < n:
            rows = got.shape[0]
            want = frame_words(model.demosaic(np.stack(left[j][:rows]), np.stack(right[j][:rows])))
            j += 1
            if got.shape == want.shape and np.array_equal(got, want):
                whole += got.shape[0] == len(left[j - 1])
                if got.shape[0] != len(left[j - 1]):
                    cut_rows.append(got.shape[0])
                break
        else:
            problems.append(f"output frame {k} ({got.shape[1]}x{got.shape[0]}) is no prefix of a frame sent")
    out1, cut1 = counters(dut)
    if out1 - out0 != len(frames) or out1 - out0 + cut1 - cut0 != n:
        problems.append(f"counters: {out1 - out0} out, {cut1 - cut0} cut; {len(frames)} seen of {n} sent")
    if not cut_rows and whole == n:
        problems.append("nothing was cut: the stall did not overflow the FIFOs")
    if whole < 2 or frames[-1].shape != (len(left[-1]), len(left[-1][0])):
        problems.append(f"only {whole} whole frames; the last frame sent must come out whole")
    assert not problems, "\n".join(problems[:12])
    log.info("overflow: %d frames out (%d whole, cut to %s rows), %d cut", len(frames), whole, cut_rows,
             cut1 - cut0)
    dut._log.info("BEATS overflow %d", sum(f.size for f in frames))


@cocotb.test()
async def cameras_that_disagree(dut: SimHandleBase) -> None:
    """Line lengths differ (first line: frame dropped; row 5: frame ends after row 4), a frame cut short
    on one camera, a line cut by FRAME_VALID, a line too long for MAX_WIDTH, a one-row frame, a frame
    only one camera sends: every frame around them is whole and exact."""
    tb = Bench(dut, seed=4)
    rng = np.random.default_rng(11)
    await tb.reset()
    tb.ready_p = 0.2
    w = min(32, MAX_WIDTH)

    def pair(h: int = 9) -> Tuple[Lines, Lines]:
        return random_frame(rng, w, h), random_frame(rng, w, h)

    cases: List[Tuple[str, Optional[Lines], Optional[Lines], int]] = []  # (name, left, right, frames cut)
    good = pair()
    cases.append(("good", good[0], good[1], 0))
    a, b = pair()
    b[0] = b[0][:-1]
    cases.append(("first line shorter on the right", a, b, 1))
    a, b = pair()
    a[5] = np.concatenate([a[5], [7]])
    cases.append(("row 5 longer on the left", a, b, 1))
    a, b = pair()
    cases.append(("left frame cut short after 6 rows", a[:6], b, 1))
    a, b = pair()
    a, b = a[:7], b[:7]
    cases.append(("both frames 7 rows", a, b, 0))
    a, b = pair()
    a[4] = rng.integers(0, 1024, MAX_WIDTH + 3)
    b[4] = rng.integers(0, 1024, MAX_WIDTH + 3)
    cases.append(("row 4 longer than MAX_WIDTH on both", a, b, 1))
    a, b = pair()
    cases.append(("a one-row frame", a[:1], b[:1], 1))
    a, b = pair()
    cases.append(("only the left camera sends", a, None, 1))
    good2 = pair()
    cases.append(("good again", good2[0], good2[1], 0))
    left = [c[1] for c in cases]
    right = [c[2] for c in cases]
    both = [(f, g) for f, g in zip(left, right, strict=True) if f is not None and g is not None]
    want = model.expected_frames([f for f, _ in both], [g for _, g in both], MAX_WIDTH)
    # a lone frame fills its FIFO: the blanking after it must let the receiver write its EOF again
    await run_case(tb, left, right, want, "disagree", cut=sum(c[3] for c in cases),
                   timing=model.BusTiming(hblank=6, vblank=600))
    # a line cut by FRAME_VALID falling: the frame ends with the rows before it
    a, b = pair(6)
    bus = [model.pixel_bus([a], model.BusTiming(hblank=6, vblank=0)),
           model.pixel_bus([b], model.BusTiming(hblank=6, vblank=0))]
    for cam in (0, 1):  # FRAME_VALID falls 3 pixels into row 4, LINE_VALID two clocks later
        lv_rows = np.flatnonzero(bus[cam][:, 1])
        bus[cam] = np.concatenate([bus[cam][:lv_rows[4 * w + 3]], [[5, 1, 0], [6, 1, 0]]])
    before = len(tb.beats)
    out0, cut0 = counters(dut)
    start = int(get_sim_time("ps") // 37_000 + 4) * 37_000
    t0 = cocotb.start_soon(tb._play(0, bus[0], start))
    t1 = cocotb.start_soon(tb._play(1, bus[1], start))
    await t0
    await t1
    await tb.settle()
    frames, problems = tb.frames(before)
    problems += compare(frames, [model.demosaic(np.stack(a[:4]), np.stack(b[:4]))], "line cut by FRAME_VALID")
    if counters(dut) != (out0 + 1, cut0 + 1):
        problems.append(f"counters {counters(dut)}, want {(out0 + 1, cut0 + 1)}")
    assert not problems, "\n".join(problems)


@cocotb.test()
async def reset_in_mid_frame(dut: SimHandleBase) -> None:
    """aresetn in the middle of a frame: nothing half-made comes out, the next frames are exact."""
    tb = Bench(dut, seed=8)
    rng = np.random.default_rng(12)
    await tb.reset()
    w = min(40, MAX_WIDTH)
    left, right = random_pairs(rng, [(w, 12)] * 3)
    sender = cocotb.start_soon(tb.send(left, right))
    await Timer(37_000 * (w + 6) * 5, unit="ps")  # five rows into frame 0
    await FallingEdge(dut.aclk)  # between edges: a beat that leaves at this edge is before the reset
    start = len(tb.beats)
    await tb.reset()
    await sender
    await tb.settle()
    frames, problems = tb.frames(start)
    # beats of frame 0 may have left before the reset; after it, frames 1 and 2 are whole
    problems += compare([f for f in frames if f.shape[0] == 12][-2:],
                        model.expected_frames(left[1:], right[1:], MAX_WIDTH), "after reset")
    assert not problems, "\n".join(problems[:12])


@cocotb.test()
async def full_size(dut: SimHandleBase) -> None:
    """A 752 x 6 frame pair (752 x 480 with STEREOCAM_COSIM_FULL=1) with the MT9V034's default
    horizontal blanking (94 clocks) and 26.6 MHz pixels (selected only in the 752-wide build)."""
    assert MAX_WIDTH >= 752, "full_size runs in the MAX_WIDTH=752 build"
    tb = Bench(dut, Clocks(aclk=10_000, pclk0=37_600, pclk1=37_600, phase1=9_100), seed=9)
    rng = np.random.default_rng(13)
    await tb.reset()
    tb.ready_p = 0.05
    height = 480 if FULL else 6
    await run_random_case(tb, rng, [(752, height)], f"752x{height}", model.BusTiming(hblank=94, vblank=0))
