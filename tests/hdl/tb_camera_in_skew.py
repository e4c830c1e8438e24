"""cocotb testbench: the camera input IP with skew on every synchronised bus, against its numpy model.

Run by ``tests/hdl/test_camera_in_skew.py`` on a build with ``CI_SKEW_SIM`` defined: then every
``ci_sync`` delays each bit's change by 0 or 1 destination clocks, at random per change (the worst a
bounded-skew crossing can do; zero-skew simulation hides an unsafe crossing). The bench plays
whole frames on two unrelated pixel clocks with random TREADY pauses (``tb_camera_in.Bench``) and
compares every output beat (TDATA, TUSER, TLAST) in order with the model's stream
(``stereocam/overlays/model/camera_in.py: expected_frames``).

``STEREOCAM_SKEW_EXPECT`` says what the build must show: ``exact`` (0 differing beats, the frames
and counters right, every pointer sample a value its source held) or ``slips`` (a build whose
crossings are unsafe: differing beats and pointer samples no source value explains).
``STEREOCAM_SKEW_RESULT`` names a JSON file for the numbers (beats compared, differing beats, frames).
"""
from __future__ import annotations

import json
import os
import random
from typing import Any, Callable, List, Tuple

import cocotb
import numpy as np
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, RisingEdge, SimTimeoutError

from stereocam.overlays.model import camera_in as model

from .tb_camera_in import Bench, Clocks, compare, counters, frame_words, random_frame

FULL = os.environ.get("STEREOCAM_COSIM_FULL") == "1"
MAX_WIDTH = int(os.environ.get("STEREOCAM_CI_MAX_WIDTH", "64"))
EXPECT = os.environ.get("STEREOCAM_SKEW_EXPECT", "exact")
RESULT = os.environ.get("STEREOCAM_SKEW_RESULT", "")

Beat = Tuple[int, int, int]


def model_beats(frames: List[np.ndarray]) -> List[Beat]:
    """The model's frames as the stream's beats (tdata, tuser, tlast), in order."""
    beats: List[Beat] = []
    for frame in frames:
        words = frame_words(frame)
        height, width = words.shape
        for y in range(height):
            for x in range(width):
                beats.append((int(words[y, x]), int(x == 0 and y == 0), int(x == width - 1)))
    return beats


def differing(got: List[Beat], want: List[Beat]) -> int:
    """Beats that differ position by position, plus every beat missing or extra."""
    return sum(g != w for g, w in zip(got, want, strict=False)) + abs(len(got) - len(want))


async def stalls(tb: Bench, rng: random.Random) -> None:
    """TREADY low in random bursts (20-240 clocks, every 50-600 clocks) besides the random 30 %: the
    reader falls behind and is in the middle of a line when the next commit crosses."""
    while True:
        await ClockCycles(tb.dut.aclk, rng.randint(50, 600))
        tb.stall = (len(tb.beats), rng.randint(20, 240))


def gray2bin(g: int) -> int:
    b = 0
    while g:
        b ^= g
        g >>= 1
    return b


class PointerWatch:
    """Counts pointer samples that no crossing may produce: a value the source never held in order.

    Each clock of the destination, the pointer as it arrived must have moved forward from its last
    sample by no more than the source has (modulo the pointer's range): a sample mixing the bits of
    two source values fails this. ``bad`` per crossing: write pointers into aclk, read pointers out.
    """

    def __init__(self, dut: SimHandleBase) -> None:
        self.bad = {"wptr": 0, "rptr": 0}
        self.samples = {"wptr": 0, "rptr": 0}
        for cam in (0, 1):
            fifo = getattr(dut, f"fifo{cam}_inst")
            bits = len(fifo.rptr_reg)
            cocotb.start_soon(self._watch("wptr", dut.aclk, fifo.wptr_r_reg,
                                          lambda f=fifo: gray2bin(int(f.wgray_reg.value)), bits))
            cocotb.start_soon(self._watch("rptr", getattr(dut, f"cam{cam}_pclk"), fifo.w_rptr,
                                          lambda f=fifo: int(f.rptr_reg.value), bits))

    async def _watch(self, kind: str, clk: Any, seen: Any, source: Callable[[], int], bits: int) -> None:
        mask = (1 << bits) - 1
        prev = int(seen.value)
        while True:
            await RisingEdge(clk)
            now, src = int(seen.value), source()
            self.samples[kind] += 1
            if (now - prev) & mask > (src - prev) & mask:
                self.bad[kind] += 1
            prev = now


@cocotb.test()
async def skewed_frames(dut: SimHandleBase) -> None:
    """At least 20 whole frames through skewed crossings with random backpressure (TREADY low 30 % of
    the clocks at random and in random bursts): the stream is the model's, beat for beat. Two batches:
    22 (44 with STEREOCAM_COSIM_FULL=1) frames of 64 x 10 and 40 (80) of 6 x 10, whose short lines
    make a commit cross often."""
    tb = Bench(dut, Clocks(aclk=7_000, pclk0=41_000, pclk1=39_000, phase1=17_300), seed=21)
    rng = np.random.default_rng(22)
    await tb.reset()
    tb.ready_p = 0.3
    cocotb.start_soon(stalls(tb, random.Random(23)))
    watch = PointerWatch(dut)
    scale = 2 if FULL else 1
    left: List[List[np.ndarray]] = []
    right: List[List[np.ndarray]] = []
    start = len(tb.beats)
    out0, cut0 = counters(dut)
    stalled = False
    for n, width, hblank in ((22 * scale, min(64, MAX_WIDTH), 8), (40 * scale, 6, 3)):
        batch_l = [random_frame(rng, width, 10) for _ in range(n)]
        batch_r = [random_frame(rng, width, 10) for _ in range(n)]
        left += batch_l
        right += batch_r
        await tb.send(batch_l, batch_r, model.BusTiming(hblank=hblank, vblank=0))
        try:
            await tb.settle(timeout_us=2000.0)
        except SimTimeoutError:
            stalled = True  # the stream never went quiet
    n = len(left)
    want = model.expected_frames(left, right, MAX_WIDTH)
    got = tb.beats[start:]
    want_beats = model_beats(want)
    bad = differing(got, want_beats)
    frames, problems = tb.frames(start)
    problems += compare(frames, want, "skewed") + tb.violations
    out1, cut1 = counters(dut)
    if (out1 - out0, cut1 - cut0) != (len(want), 0):
        problems.append(f"counters say {out1 - out0} frames out and {cut1 - cut0} cut, "
                        f"want {len(want)} and 0")
    if stalled:
        problems.append("the stream did not settle")
    numbers = {"frames_sent": n, "frames_want": len(want), "frames_got": len(frames),
               "beats_want": len(want_beats), "beats_got": len(got), "differing_beats": bad,
               "tready_low_clocks": tb.tready_low_clocks, "stalled": stalled,
               "bad_pointer_samples": watch.bad, "pointer_samples": watch.samples,
               "first_problems": problems[:5]}
    dut._log.info("SKEW %s", json.dumps(numbers))
    if RESULT:
        with open(RESULT, "w") as f:
            json.dump(numbers, f)
    if EXPECT == "exact":
        assert len(want) == n >= 20 and bad == 0 and not problems, "\n".join(problems[:12])
        assert watch.bad == {"wptr": 0, "rptr": 0}, f"pointer samples no source value explains: {watch.bad}"
    else:
        assert bad > 0 and sum(watch.bad.values()) > 0, f"the skew did not show on this build: {numbers}"
