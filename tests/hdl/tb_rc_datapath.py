"""cocotb testbench for stereocam/overlays/rtl/rc_datapath.v, the rectify core's pixel side, on its own.

Run by ``tests/hdl/test_rc_datapath.py`` through ``run_cocotb``; not a pytest module. The
testbench stands in for the two other parts of the core: it drives the active set and the
control bits that ``rc_regs`` would, and it is the coordinate engine, answering each
``coord_start`` with one position word per output pixel over a valid/ready handshake with
random gaps. Positions come from ``stereocam/overlays/model/fixed.py`` (random calibrations) or are
drawn at random around the window and the image's edges to reach every case of the tap
logic. The oracle is :func:`model_stream`, a small numpy model written from
RECTIFY_CORE.md ("Malformed input", step 5, "Gray of a tap", edges, "The line buffer"),
independent of the RTL; every output beat (data, TUSER, TLAST) and every pulse
(LB_OVERFLOW, SIZE_ERROR, frame done) is compared.

The build (``MAX_WIDTH, MAX_HEIGHT, LB_ROWS, COLOUR``) comes in ``STEREOCAM_DP_BUILD``;
``STEREOCAM_COSIM_FULL=1`` runs more seeds. The helpers below (streams, model, bus
monitors) are shared with ``tb_rectify_core.py``.
"""
from __future__ import annotations

import logging
import os
import random
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Deque, Iterable, List, Optional, Sequence, Tuple

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, FallingEdge, RisingEdge, with_timeout
from cocotbext.axi import AxiStreamBus, AxiStreamFrame, AxiStreamSink, AxiStreamSource

from ..overlays.test_model import random_frame, random_params  # the model tests' calibrations and frames
from .unit_bench import check_held_beat, pulse_reset

CLOCK_NS = 10
FULL = os.environ.get("STEREOCAM_COSIM_FULL") == "1"
FRAC = 5  # RC_FRAC_BITS


@dataclass(frozen=True)
class BuildParams:
    max_width: int
    max_height: int
    lb_rows: int
    colour: bool

    @classmethod
    def from_env(cls, name: str = "STEREOCAM_DP_BUILD") -> "BuildParams":
        mw, mh, lb, colour = (int(v) for v in os.environ[name].split(","))
        return cls(mw, mh, lb, bool(colour))


@dataclass(frozen=True)
class FrameOptions:
    """What a frame is processed with: the active set's sizes and the control bits."""

    width: int
    height: int
    lb_delay: int = 0
    bypass: bool = False  # CONTROL.BYPASS or no APPLY yet
    gray: bool = False
    debug_row: Optional[int] = None  # DEBUG_ROW when DEBUG_LINE is set


# ---- streams ------------------------------------------------------------------------------------
Beat = Tuple[int, int, int]  # (TDATA, TUSER, TLAST)


def frame_words(frame: np.ndarray) -> np.ndarray:
    """(H, W, 8) uint8 -> (H, W) uint64 TDATA words (byte 0 in bits 7:0)."""
    return np.ascontiguousarray(frame).view("<u8").reshape(frame.shape[:2])


def words_frame(words: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(words.astype("<u8")).view(np.uint8).reshape(words.shape + (8,))


def frame_beats(frame: np.ndarray) -> List[Beat]:
    """A well-formed frame (any size): TUSER on the first beat, TLAST on each line's last."""
    words = frame_words(frame)
    h, w = words.shape
    return [(int(words[y, x]), int(x == 0 and y == 0), int(x == w - 1)) for y in range(h) for x in range(w)]


def beat_packets(beats: Sequence[Beat]) -> List[AxiStreamFrame]:
    """Beats as bus-model packets: each packet ends with a TLAST beat (the stream must end with one)."""
    packets, data, user = [], [], []
    for d, u, last in beats:
        data.append(d)
        user.append(u)
        if last:
            packets.append(AxiStreamFrame(data, tuser=user))
            data, user = [], []
    assert not data, "a stream must end with a TLAST beat"
    return packets


@dataclass
class InputFrame:
    """One frame as the input checker saw it."""

    options: FrameOptions
    rows: np.ndarray  # (H, W) uint64, rows >= r are 0
    r: int  # complete rows received
    error: bool  # the input ended in an error (else all HEIGHT lines came)


@dataclass
class Checker:
    """The input checker's state between streams: after a complete frame, more beats are "frame long"."""

    tail: bool = False


def split_stream(beats: Iterable[Beat], options_at_start: Callable[[int], Optional[FrameOptions]],
                 checker: Optional[Checker] = None) -> Tuple[List[InputFrame], int]:
    """The spec's input checking ("Malformed input") on a beat stream: frames and SIZE_ERROR count.

    ``options_at_start(k)`` gives the k-th accepted frame's options (None: the core accepts
    no further start of frame, e.g. ENABLE 0: the rest of the stream stays unconsumed).
    ``checker`` carries the state from the previous stream (and is updated).
    """
    checker = checker if checker is not None else Checker()
    frames: List[InputFrame] = []
    errors = 0
    seek, tail = True, checker.tail
    cur: Optional[InputFrame] = None
    col = 0
    for d, u, last in beats:
        while True:
            if seek:
                if not u:
                    if tail:
                        errors += 1
                        tail = False
                    break
                opts = options_at_start(len(frames))
                if opts is None:
                    checker.tail = tail
                    return frames, errors
                cur = InputFrame(opts, np.zeros((opts.height, opts.width), np.uint64), 0, False)
                frames.append(cur)
                seek, tail, col = False, False, 0
            assert cur is not None
            if u and (cur.r or col):  # start of frame early: ends this frame, starts the next
                errors += 1
                cur.error = True
                seek = True
                continue
            cur.rows[cur.r, col] = d
            col += 1
            if col == cur.options.width:
                if last:
                    cur.r += 1
                    col = 0
                    if cur.r == cur.options.height:
                        seek, tail = True, True
                else:  # line long
                    errors += 1
                    cur.error, seek = True, True
            elif last:  # line short
                errors += 1
                cur.error, seek = True, True
            break
    checker.tail = tail if seek else False
    return frames, errors


# ---- the datapath model -------------------------------------------------------------------------
@dataclass
class Positions:
    """Source positions of one frame, per camera: iu, iv (1/32 px, int64) and ok, each (H, W)."""

    iu: Tuple[np.ndarray, np.ndarray]
    iv: Tuple[np.ndarray, np.ndarray]
    ok: Tuple[np.ndarray, np.ndarray]

    def words(self) -> List[Tuple[int, int, int, int, int, int]]:
        m = (1 << 21) - 1
        cols = [
            (self.iu[0] & m).ravel().tolist(), (self.iv[0] & m).ravel().tolist(),
            self.ok[0].ravel().astype(int).tolist(),
            (self.iu[1] & m).ravel().tolist(), (self.iv[1] & m).ravel().tolist(),
            self.ok[1].ravel().astype(int).tolist(),
        ]
        return list(zip(*cols, strict=True))


def gray_of(rgb: np.ndarray) -> np.ndarray:
    r, g, b = (rgb[..., i].astype(np.int64) for i in range(3))
    return (77 * r + 150 * g + 29 * b + 128) >> 8


def e_of(options: FrameOptions) -> np.ndarray:
    y = np.arange(options.height, dtype=np.int64)
    if options.bypass:
        return y
    return np.minimum(y + options.lb_delay, options.height - 1)


def interpolate(planes: np.ndarray, iu: np.ndarray, iv: np.ndarray, ok: np.ndarray, e: np.ndarray,
                lb_rows: int, rect_rows: np.ndarray) -> Tuple[np.ndarray, bool]:
    """Step 5 with edges and the window, every channel of ``planes`` (H, W, C): (out, overflow)."""
    h, w = planes.shape[:2]
    x0, du = iu >> FRAC, iu & 31
    y0, dv = iv >> FRAC, iv & 31
    weights = ((32 - du) * (32 - dv), du * (32 - dv), (32 - du) * dv, du * dv)
    first = (e - lb_rows + 1)[:, None]
    last = e[:, None]
    use_pixel = ok & rect_rows[:, None]
    acc = np.zeros(planes.shape, np.int64)
    overflow = False
    for (dx, dy), wt in zip(((0, 0), (1, 0), (0, 1), (1, 1)), weights, strict=True):
        xs, ys = x0 + dx, y0 + dy
        inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        window = (ys >= first) & (ys <= last)
        use = use_pixel & inside & window
        overflow |= bool((use_pixel & inside & ~window).any())
        vals = planes[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)].astype(np.int64)
        acc += (wt * use)[..., None] * vals
    return ((acc + 512) >> 10).astype(np.uint8), overflow


def model_frame(
    inp: InputFrame, build: BuildParams, pos: Optional[Positions]
) -> Tuple[Optional[np.ndarray], bool]:
    """One input frame -> (output frame or None when dropped, LB_OVERFLOW raised)."""
    o = inp.options
    e = e_of(o)
    if inp.error and inp.r <= e[0]:
        return None, False
    src = words_frame(inp.rows)
    rect_rows = e < inp.r
    out = np.zeros_like(src)
    overflow = False
    if o.bypass:
        out[rect_rows] = src[rect_rows]
    else:
        assert pos is not None
        for cam in range(2):
            base = 4 * cam
            if build.colour:
                planes = src[..., base:base + 4].astype(np.int64)
                planes[..., 3] = gray_of(src[..., base:base + 3])
            else:
                planes = src[..., base + 3:base + 4].astype(np.int64)
            res, ovf = interpolate(planes, pos.iu[cam], pos.iv[cam], pos.ok[cam], e, build.lb_rows, rect_rows)
            overflow |= ovf
            if build.colour and not o.gray:
                out[..., base:base + 4] = res
            else:
                out[..., base:base + 4] = res[..., -1:]
    if o.debug_row is not None and 0 <= o.debug_row < o.height:
        out[o.debug_row] = 255
    return out, overflow


# ---- positions for tests ------------------------------------------------------------------------
def random_positions(rng: np.random.Generator, options: FrameOptions, lb_rows: int) -> Positions:
    """Positions that reach every case of the tap logic: inside, across the edges, far outside,
    inside and outside the window (rows up to a few beyond it on both sides), invalid pixels,
    and the extremes of the signed 16.5 range."""
    h, w = options.height, options.width
    e = e_of(options)[:, None]
    iu, iv, ok = [], [], []
    for _ in range(2):
        kind = rng.integers(0, 10, (h, w))
        u = rng.integers(-3 * 32, (w + 2) * 32, (h, w))
        lo = (e - lb_rows - 2) * 32
        v = lo + rng.integers(0, (lb_rows + 5) * 32, (h, w))
        far = rng.integers(-(1 << 20) + 1, 1 << 20, (h, w))
        u = np.where(kind == 0, far, u)
        v = np.where(kind == 1, far, v)
        u = np.where(kind == 2, rng.choice([-(1 << 20) + 1, (1 << 20) - 1], (h, w)), u)
        # on a pixel exactly, and the window's own rows exactly
        u = np.where(kind == 3, (u >> 5) << 5, u)
        window_rows = (e - rng.integers(0, lb_rows + 1, (h, w))) * 32 + rng.integers(0, 32, (h, w))
        v = np.where(kind == 4, window_rows, v)
        good = rng.random((h, w)) > 0.1
        iu.append(np.where(good, u, 0).astype(np.int64))
        iv.append(np.where(good, v, 0).astype(np.int64))
        ok.append(good)
    return Positions(tuple(iu), tuple(iv), tuple(ok))


def fixed_positions(regs: Sequence[Any], width: int, height: int) -> Positions:
    """Positions of the fixed-point model (``stereocam/overlays/model/fixed.py``) for both cameras'
    registers."""
    from stereocam.overlays.model import fixed

    y, x = np.mgrid[0:height, 0:width]
    out = [fixed.positions(r, x, y) for r in regs]
    return Positions(tuple(o[0] for o in out), tuple(o[1] for o in out),
                     tuple(o[2].astype(bool) for o in out))


# ---- bus side -----------------------------------------------------------------------------------

def pause_gen(p: float, rng: random.Random) -> Optional[Iterable[bool]]:
    """Random pauses with probability ``p`` (None: no pauses), in bursts now and then."""
    if p <= 0:
        return None

    def gen() -> Iterable[bool]:
        while True:
            if rng.random() < 0.02:
                for _ in range(rng.randint(5, 60)):  # a long stall
                    yield True
            yield rng.random() < p

    return gen()


class StreamBench:
    """Clock, reset, the AXI4-Stream bus models and monitors common to the datapath and the core.

    ``clk``/``rst`` are the design's clock and active-high reset (``rst`` may be a callable that
    drives reset for designs with ``aresetn``).
    """

    def __init__(self, dut: SimHandleBase, clk: Any, reset: Any, reset_active_level: bool = True,
                 watch: bool = True) -> None:
        self.dut = dut
        self.clk = clk
        cocotb.start_soon(Clock(clk, CLOCK_NS, unit="ns").start())
        self.source = AxiStreamSource(AxiStreamBus.from_prefix(dut, "s_axis"), clk, reset,
                                      reset_active_level=reset_active_level, byte_lanes=1)
        self.sink = AxiStreamSink(AxiStreamBus.from_prefix(dut, "m_axis"), clk, reset,
                                  reset_active_level=reset_active_level, byte_lanes=1)
        for bus_model in (self.source, self.sink):
            bus_model.log.setLevel(logging.WARNING)
        self.stall_violations: List[str] = []
        self.cycle = 0
        self.first_out_cycle: Optional[int] = None
        self.out_cycles: List[int] = []
        self.in_cycles: List[int] = []
        self.record_cycles = False
        self.watch_task = cocotb.start_soon(self._watch()) if watch else None

    def set_pauses(self, p_in: float, p_out: float, rng: random.Random) -> None:
        self.source.set_pause_generator(pause_gen(p_in, rng))
        self.sink.set_pause_generator(pause_gen(p_out, rng))

    async def _watch(self) -> None:
        """AXI4-Stream rule on the output (a beat held until taken), and handshake times."""
        dut = self.dut
        held = None
        while True:
            await RisingEdge(self.clk)
            self.cycle += 1
            if self.record_cycles and dut.s_axis_tvalid.value and dut.s_axis_tready.value:
                self.in_cycles.append(self.cycle)
            held = check_held_beat(dut, held, self.stall_violations)
            if self.record_cycles and dut.m_axis_tvalid.value and dut.m_axis_tready.value:
                self.out_cycles.append(self.cycle)

    async def send(self, beats: Sequence[Beat]) -> None:
        for packet in beat_packets(beats):
            await self.source.send(packet)

    async def receive_frame(
        self, height: int, timeout_us: float
    ) -> Tuple[np.ndarray, List[List[int]], List[int]]:
        """``height`` lines: (words (H, W), per-line TUSER lists, line lengths)."""
        lines, users = [], []
        for _ in range(height):
            got = await with_timeout(self.sink.recv(compact=False), timeout_us, "us")
            lines.append([int(v) for v in got.tdata])
            users.append([int(v) for v in got.tuser])
        lengths = [len(line) for line in lines]
        width = max(lengths)
        words = np.zeros((height, width), np.uint64)
        for y, line in enumerate(lines):
            words[y, :len(line)] = line
        return words, users, lengths


class PulseCounter:
    """Counts the pulses (runs of clocks with the signal high) of a 1-bit output.

    frame_done and set_size_error pulse for one clock at a time and never on two clocks in a
    row; set_lb_overflow may stay high for several clocks, and is only asked "any or none".
    """

    def __init__(self, clk: Any, signal: Any) -> None:
        self.count = 0
        self.signal = signal
        cocotb.start_soon(self._run())

    async def _run(self) -> None:
        while True:
            await RisingEdge(self.signal)
            self.count += 1
            await FallingEdge(self.signal)


def compare_frame(
    label: str, words: np.ndarray, users: List[List[int]], lengths: List[int], want: np.ndarray
) -> List[str]:
    """Differences between a received frame and the expected one, as messages (empty: equal)."""
    problems = []
    h, w = want.shape[:2]
    bad_len = [y for y, n in enumerate(lengths) if n != w]
    if bad_len:
        got = [lengths[y] for y in bad_len[:5]]
        problems.append(f"{label}: lines {bad_len[:5]} have {got} beats, want {w}")
        return problems
    want_users = [[int(x == 0 and y == 0) for x in range(w)] for y in range(h)]
    if users != want_users:
        wrong = [(y, x) for y in range(h) for x in range(w) if users[y][x] != want_users[y][x]]
        problems.append(f"{label}: TUSER wrong at {wrong[:5]}")
    want_words = frame_words(want)
    diff = np.argwhere(words != want_words)
    if diff.size:
        y, x = diff[0]
        problems.append(
            f"{label}: {len(diff)} of {h * w} beats differ, first at (x={x}, y={y}): "
            f"got {int(words[y, x]):#018x}, want {int(want_words[y, x]):#018x}"
        )
    return problems


# ---- the datapath on its own ----------------------------------------------------------------------
class DatapathTB(StreamBench):
    """rc_datapath with the testbench as rc_regs (levels) and as the coordinate engine."""

    def __init__(self, dut: SimHandleBase) -> None:
        super().__init__(dut, dut.clk, dut.rst)
        self.build = BuildParams.from_env()
        self.overflow = PulseCounter(dut.clk, dut.set_lb_overflow)
        self.size_error = PulseCounter(dut.clk, dut.set_size_error)
        self.frame_done = PulseCounter(dut.clk, dut.frame_done)
        self.coord_starts = 0
        self.checker = Checker()
        self.positions: Deque[Positions] = deque()
        self.pos_pause = 0.0
        self.pos_rng = random.Random(1)
        self.pos_errors: List[str] = []
        dut.pos_valid.value = 0
        dut.apply_pending.value = 0
        self.set_options(FrameOptions(64, 8), applied=False, enable=True)
        cocotb.start_soon(self._coordinate_engine())

    def set_options(self, o: FrameOptions, *, applied: bool = True, enable: bool = True) -> None:
        """The active set and control bits, as rc_regs would present them."""
        dut = self.dut
        dut.applied.value = int(applied)
        dut.act_width.value = o.width
        dut.act_height.value = o.height
        dut.act_lb_delay.value = o.lb_delay
        dut.ctl_enable.value = int(enable)
        dut.ctl_bypass.value = int(o.bypass and applied)
        dut.ctl_gray.value = int(o.gray)
        dut.ctl_debug_line.value = int(o.debug_row is not None)
        dut.debug_row.value = o.debug_row or 0

    async def reset(self) -> None:
        await pulse_reset(self.dut, 4)

    async def _coordinate_engine(self) -> None:
        """On each coord_start, the next queued frame's positions, one word per valid/ready beat."""
        dut = self.dut
        while True:
            await RisingEdge(dut.coord_start)
            self.coord_starts += 1
            if not self.positions:
                self.pos_errors.append("coord_start with no positions queued (a frame the model drops?)")
                continue
            words = self.positions.popleft().words()
            width, height = int(dut.coord_width.value), int(dut.coord_height.value)
            if width * height != len(words):
                self.pos_errors.append(f"coord_start for {width}x{height}, positions for {len(words)} pixels")
            i, n = 0, len(words)
            while i < n:
                if self.pos_pause and self.pos_rng.random() < self.pos_pause:
                    dut.pos_valid.value = 0
                else:
                    iu_l, iv_l, ok_l, iu_r, iv_r, ok_r = words[i]
                    dut.pos_iu_l.value = iu_l
                    dut.pos_iv_l.value = iv_l
                    dut.pos_ok_l.value = ok_l
                    dut.pos_iu_r.value = iu_r
                    dut.pos_iv_r.value = iv_r
                    dut.pos_ok_r.value = ok_r
                    dut.pos_valid.value = 1
                await RisingEdge(dut.clk)
                if dut.pos_valid.value and dut.pos_ready.value:
                    i += 1
            dut.pos_valid.value = 0


async def run_stream(tb: DatapathTB, beats: Sequence[Beat], frames_in: List[InputFrame],
                     positions: List[Optional[Positions]], expect_errors: int, label: str) -> None:
    """Send ``beats``; compare every output frame, every pulse and the idle state at the end."""
    build = tb.build
    expected = [model_frame(f, build, p) for f, p in zip(frames_in, positions, strict=True)]
    for f, p, (out, _) in zip(frames_in, positions, expected, strict=True):
        if out is not None and not f.options.bypass:
            tb.positions.append(p)
    ovf_before, size_before, done_before = tb.overflow.count, tb.size_error.count, tb.frame_done.count
    starts_before = tb.coord_starts
    sender = cocotb.start_soon(tb.send(beats))
    problems: List[str] = []
    beats_out = sum(o.size // 8 for o, _ in expected if o is not None)
    timeout = int(200 + (len(beats) + beats_out) * 0.2)
    for k, (out, _) in enumerate(expected):
        if out is None:
            continue
        words, users, lengths = await tb.receive_frame(out.shape[0], timeout)
        problems += compare_frame(f"{label} frame {k}", words, users, lengths, out)
    await with_timeout(sender, timeout, "us")
    # let the last pulses and the idle state settle
    for _ in range(200):
        await RisingEdge(tb.dut.clk)
        if tb.dut.idle.value and tb.source.idle():
            break
    await ClockCycles(tb.dut.clk, 10)
    want_ovf = any(o for _, o in expected)
    got_ovf = tb.overflow.count > ovf_before
    if got_ovf != want_ovf:
        problems.append(f"{label}: LB_OVERFLOW pulsed {tb.overflow.count - ovf_before} times, "
                        f"want {'some' if want_ovf else 'none'}")
    if tb.size_error.count - size_before != expect_errors:
        problems.append(f"{label}: SIZE_ERROR pulsed {tb.size_error.count - size_before} times, "
                        f"want {expect_errors}")
    frames_out = sum(o is not None for o, _ in expected)
    if tb.frame_done.count - done_before != frames_out:
        problems.append(f"{label}: frame_done pulsed {tb.frame_done.count - done_before} times, "
                        f"want {frames_out}")
    coord_frames = sum(o is not None and not f.options.bypass
                       for f, (o, _) in zip(frames_in, expected, strict=True))
    if tb.coord_starts - starts_before != coord_frames:
        problems.append(f"{label}: coord_start pulsed {tb.coord_starts - starts_before} times")
    if not tb.sink.empty():
        problems.append(f"{label}: {tb.sink.count()} more output lines than expected")
    if not tb.dut.idle.value:
        problems.append(f"{label}: not idle after the stream")
    problems += tb.pos_errors + tb.stall_violations
    assert not problems, "\n".join(problems)


def pick_options(rng: np.random.Generator, build: BuildParams, w: int, h: int, **fixed: Any) -> FrameOptions:
    values = dict(
        width=w, height=h,
        lb_delay=int(rng.choice([0, 1, 2, rng.integers(0, h + 3), build.lb_rows // 2])),
        gray=bool(rng.random() < 0.3), bypass=False,
        debug_row=int(rng.integers(0, h + 2)) if rng.random() < 0.3 else None,
    )
    values.update(fixed)
    return FrameOptions(**values)


def seeds(ci: int, full: int) -> List[int]:
    return list(range(full if FULL else ci))


async def start(
    dut: SimHandleBase, seed: int, p_in: float = 0.3, p_out: float = 0.3, p_pos: float = 0.2
) -> Tuple[DatapathTB, np.random.Generator]:
    tb = DatapathTB(dut)
    await tb.reset()
    rnd = random.Random(seed)
    tb.set_pauses(p_in, p_out, rnd)
    tb.pos_pause = p_pos
    tb.pos_rng = rnd
    return tb, np.random.default_rng(seed)


def test_size(build: BuildParams) -> Tuple[int, int]:
    return min(64, build.max_width), 40


# ---- tests ----------------------------------------------------------------------------------------
@cocotb.test()
@cocotb.parametrize(seed=seeds(3, 12))
async def random_taps(dut: SimHandleBase, seed: int) -> None:
    """Random positions over edges, window and range limits; two frames back to back."""
    tb, rng = await start(dut, seed)
    w, h = test_size(tb.build)
    opts = pick_options(rng, tb.build, w, h)
    tb.set_options(opts)
    frames = [random_frame(rng, w, h) for _ in range(2)]
    beats = [b for f in frames for b in frame_beats(f)]
    inputs, errors = split_stream(beats, lambda k: opts, tb.checker)
    positions = [random_positions(rng, opts, tb.build.lb_rows) for _ in inputs]
    await run_stream(tb, beats, inputs, positions, errors, f"seed {seed} {opts}")


@cocotb.test()
@cocotb.parametrize(seed=seeds(2, 8))
async def calibrations(dut: SimHandleBase, seed: int) -> None:
    """Positions of random calibrations (the fixed-point model), the delay the calibration needs."""
    from stereocam.overlays.spec.rectify import camera_registers

    tb, rng = await start(dut, 100 + seed)
    w, h = test_size(tb.build)
    regs = [camera_registers(random_params(rng, w, h, strength=2.0), w, h) for _ in range(2)]
    pos = fixed_positions(regs, w, h)
    # the smallest delay that never needs a row not yet received (as linebuffer.py computes it)
    need = []
    for cam in range(2):
        y0 = pos.iv[cam] >> FRAC
        inside = pos.ok[cam] & (y0 + 1 >= 0) & (y0 < h)
        need.append(np.where(inside, np.minimum(y0 + 1, h - 1), -1).max(axis=1) - np.arange(h))
    delay = int(max(0, np.max(need)))
    opts = pick_options(rng, tb.build, w, h, lb_delay=delay)
    tb.set_options(opts)
    frame = random_frame(rng, w, h)
    beats = frame_beats(frame)
    inputs, errors = split_stream(beats, lambda k: opts, tb.checker)
    await run_stream(tb, beats, inputs, [pos], errors, f"seed {seed} {opts}")


@cocotb.test()
@cocotb.parametrize(gray=[False, True])
async def bypass_and_debug_line(dut: SimHandleBase, gray: bool) -> None:
    """BYPASS (and no APPLY yet): output = input beat for beat; DEBUG_LINE paints its row."""
    tb, rng = await start(dut, 7)
    w, h = test_size(tb.build)
    frames = [random_frame(rng, w, h) for _ in range(3)]
    for k, (applied, debug) in enumerate(((False, None), (True, None), (True, 5))):
        opts = FrameOptions(w, h, lb_delay=3, bypass=True, gray=gray, debug_row=debug)
        tb.set_options(opts, applied=applied)
        beats = frame_beats(frames[k])
        inputs, errors = split_stream(beats, lambda _, opts=opts: opts, tb.checker)
        await run_stream(tb, beats, inputs, [None], errors, f"bypass applied={applied} debug={debug}")


def malformed_streams(rng: np.random.Generator, w: int, h: int) -> List[Tuple[str, List[Beat]]]:
    """Streams with each input error of "Malformed input", at rows before and after e(0)."""
    def good() -> List[Beat]:
        return frame_beats(random_frame(rng, w, h))

    def lines(n: int, width: int, first: bool = True) -> List[Beat]:
        return frame_beats(random_frame(rng, width, n)) if first else [
            (d, 0, la) for d, _, la in frame_beats(random_frame(rng, width, n))]

    out = []
    for row in ((0, 2, h // 2, h - 1) if FULL else (0, h // 2)):
        top = lines(row, w) if row else []
        cont = not row
        out.append((f"line short at row {row}", top + lines(1, w - 3, cont) + good()))
        out.append((f"line long at row {row}", top + lines(1, w + 2, cont) + good()))
        partial = lines(1, w, cont)[:5]  # then TUSER in the middle of a line: it starts the next frame
        out.append((f"early TUSER at row {row}", top + partial + good()))
    out.append(("too few lines", lines(h // 2, w) + good()))
    out.append(("too many lines", lines(h + 3, w) + good()))
    out.append(("garbage before the first TUSER", lines(2, w, False) + good()))
    out.append(("a lone start of frame", [(1, 1, 1)] + good()))
    out.append(("wrong width frame", lines(h, w - 1) + good()))
    return out


@cocotb.test()
@cocotb.parametrize(lb_delay=[0, 3])
async def malformed_input(dut: SimHandleBase, lb_delay: int) -> None:
    """Short and long lines, early TUSER, too few/many lines: drop vs complete with zero rows."""
    tb, rng = await start(dut, 11 + lb_delay)
    w, h = test_size(tb.build)
    for label, beats in malformed_streams(rng, w, h):
        for bypass in (False, True):
            opts = FrameOptions(w, h, lb_delay=lb_delay, bypass=bypass, debug_row=h - 2)
            tb.set_options(opts)
            inputs, errors = split_stream(beats, lambda k, opts=opts: opts, tb.checker)
            positions = [random_positions(rng, opts, tb.build.lb_rows) for _ in inputs]
            await run_stream(tb, beats, inputs, positions, errors,
                             f"{label} (bypass {bypass}, delay {lb_delay})")


@cocotb.test()
async def enable_and_apply_pending(dut: SimHandleBase) -> None:
    """ENABLE 0 or APPLY pending: the start of frame waits (TREADY low); beats before it are discarded."""
    tb, rng = await start(dut, 3, 0.0, 0.0, 0.0)
    w, h = test_size(tb.build)
    opts = FrameOptions(w, h, bypass=True)
    tb.set_options(opts, enable=False)
    frame = random_frame(rng, w, h)
    garbage = [(d, 0, la) for d, _, la in frame_beats(random_frame(rng, w, 1))]
    sender = cocotb.start_soon(tb.send(garbage + frame_beats(frame)))
    await ClockCycles(dut.clk, 400)
    assert tb.sink.empty() and dut.idle.value, "a frame started with ENABLE 0"
    assert not dut.s_axis_tready.value, "TREADY must be low at the start of frame while ENABLE is 0"
    tb.set_options(opts, enable=True)
    dut.apply_pending.value = 1
    await ClockCycles(dut.clk, 100)
    assert tb.sink.empty() and dut.idle.value, "a frame started while APPLY was pending"
    dut.apply_pending.value = 0
    words, users, lengths = await tb.receive_frame(h, 500)
    await sender
    assert not compare_frame("after ENABLE", words, users, lengths, frame)
    assert tb.size_error.count == 0


@cocotb.test()
async def rate_and_latency(dut: SimHandleBase) -> None:
    """No pauses: 2 clocks per output beat; the latency from start of frame to the first beat."""
    tb, rng = await start(dut, 5, 0.0, 0.0, 0.0)
    w, h = test_size(tb.build)
    for bypass, delay in ((False, 0), (True, 0), (False, 4)):
        opts = FrameOptions(w, h, lb_delay=delay, bypass=bypass)
        tb.set_options(opts)
        frame = random_frame(rng, w, h)
        beats = frame_beats(frame)
        inputs, _ = split_stream(beats, lambda k, opts=opts: opts, tb.checker)
        pos = random_positions(rng, opts, tb.build.lb_rows)
        want, _ = model_frame(inputs[0], tb.build, pos)
        if not bypass:
            tb.positions.append(pos)
        tb.in_cycles.clear()
        tb.out_cycles.clear()
        tb.record_cycles = True
        sender = cocotb.start_soon(tb.send(beats))
        words, users, lengths = await tb.receive_frame(h, 2000)
        await sender
        tb.record_cycles = False
        assert not compare_frame("rate", words, users, lengths, want)
        outs, ins = tb.out_cycles, tb.in_cycles
        row_e0 = (delay + 1) * w - 1  # the last beat of row e(0)
        steady = (outs[-1] - outs[w]) / (len(outs) - 1 - w)
        dut._log.info(
            f"{'bypass' if bypass else f'LB_DELAY {delay}'}: "
            f"start of frame -> first beat {outs[0] - ins[0]} clocks, "
            f"last beat of row e(0) -> first beat {outs[0] - ins[row_e0]} clocks, "
            f"{steady:.3f} clocks per beat, last input beat -> last output beat {outs[-1] - ins[-1]} clocks"
        )
        assert abs(steady - 2.0) < 0.01, f"{steady} clocks per beat"
