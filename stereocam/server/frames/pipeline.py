"""The frame pipeline: processed (and raw) frame pairs out of the VDMA stores, one :class:`FrameSet` each.

:class:`Pipeline` owns one thread. It waits (at most ``wait_s`` at a time)
for the processed S2MM channel to complete a frame, copies the latest
completed processed store (and, when somebody needs it, the raw one) into
fresh arrays, stamps them and hands the :class:`FrameSet` to ``publish``.

Never torn: the driver only hands out *completed* stores, never the one in
flight, and a store stays valid until the channel comes round to it again.
The pipeline reads the core's ``FRAME_COUNT`` before and after copying; if
it moved, the copy may straddle a frame boundary (and the raw and processed
frames may not be a pair), so it copies again from the newer stores (at most
three times, then the frame counts as dropped). Only as many frames are
copied as somebody needs (``copy_rate``: the CPU budget's fastest view, and
every frame while a capture or a snapshot waits for one, or while a consumer
such as a recording holds :meth:`Pipeline.every_frame`); the others are only
seen: numbered, counted, and reported to ``alive`` so the feed knows the
fabric delivers. Never twice: ``wait_processed``
returns only after a new completion, and a store already published is not
published again. Frames the fabric completed that the pipeline never
published (it was late) are counted as drops from ``FRAME_COUNT``.

The thread never blocks on its consumers: ``publish`` must return at once
(the app's feed keeps only the newest set). ``heartbeat`` is called after
every healthy iteration (a frame, or a bounded wait that saw none); a
pipeline stuck in a driver call or failing for good stops calling it, which
is what the systemd watchdog watches.
"""
from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, ContextManager, Deque, Dict, Hashable, Iterator, Optional, Tuple

import numpy as np

from ...overlays.interface import (
    Channel,
    ChannelFault,
    ChannelNotStarted,
    NoFrameYet,
    Overlay,
    RegisterTimeout,
    VDMAError,
)
from ..stores.frame_calibration import FrameCalibration

log = logging.getLogger(__name__)

__all__ = ["FrameSet", "NoSignal", "SourceState", "OnceCache", "RateMeter", "Pipeline"]

COUNT_MOD = 1 << 32  # FRAME_COUNT wraps at 2**32
GRAB_ATTEMPTS = 3
DOZE = 0.7  # share of the frame period the thread sleeps before polling for the next frame


def _no_output(count: int) -> Callable[[], np.ndarray]:
    """The stereo core's output for a frame it emitted none for: reading it says why (ValueError)."""
    def read() -> np.ndarray:
        raise ValueError(f"the stereo core emitted no output for frame {count} (a frame size it does not "
                         "take sets its SIZE_ERROR flag: see /api/status)")

    return read


class OnceCache:
    """Values computed at most once per key, shared by every thread that asks.

    :meth:`get` runs ``compute`` for a missing key while other callers of
    the same key wait for it (other keys proceed); an exception is not
    cached. Used per :class:`FrameSet` for views and encodings.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._values: Dict[Hashable, Any] = {}
        self._busy: Dict[Hashable, threading.Lock] = {}

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        with self._lock:
            if key in self._values:
                return self._values[key]
            lock = self._busy.setdefault(key, threading.Lock())
        with lock:
            with self._lock:
                if key in self._values:
                    return self._values[key]
            value = compute()
            with self._lock:
                self._values[key] = value
                self._busy.pop(key, None)
            return value

    def peek(self, key: Hashable) -> Any:
        with self._lock:
            return self._values.get(key)

    def release(self, keep: Callable[[Hashable], bool]) -> int:
        """Drop the computed values whose key ``keep`` refuses (a later :meth:`get` computes them again);
        returns how many went. Values being computed now are not touched."""
        with self._lock:
            gone = [key for key in self._values if not keep(key)]
            for key in gone:
                del self._values[key]
        return len(gone)


@dataclass(eq=False)
class FrameSet:
    """One synchronised frame: the processed pair and, when it was wanted, the raw pair.

    ``processed`` and ``raw`` are read-only ``(H, W, 8)`` uint8 arrays
    shared by every consumer (never write to them). While the source is
    virtual, ``raw`` is the virtual-camera input that produced
    ``processed``. ``frame`` is the frame number (``FRAME_COUNT``-based,
    increasing, never repeated), ``fabric_count`` the raw ``FRAME_COUNT``
    read at the grab, ``timestamp`` the wall-clock capture time (seconds
    since the epoch), ``monotonic`` the same instant on the monotonic clock.
    """

    seq: int
    frame: int
    fabric_count: int
    timestamp: float
    monotonic: float
    source: str
    processed: np.ndarray
    raw: Optional[np.ndarray]
    cache: OnceCache = field(default_factory=OnceCache, repr=False)
    # The raw store before ``raw``'s, copied with it while a capture asks (:meth:`Pipeline.pairs_wanted`):
    # the raw channel may complete the next frame before the core has finished this one.
    raw_previous: Optional[np.ndarray] = field(default=None, repr=False)
    # The raw channel's frame store ``raw`` was copied from (None: no raw pair, or the virtual input). The
    # raw channel may complete the next frame before the core finishes this one, so two sets in a row
    # can carry the same raw frame: the same store within fewer frames than there are stores.
    raw_store: Optional[int] = field(default=None, repr=False)
    # The overlay has a stereo core (``Overlay.stereo``): its output, not the ARM, is this frame's disparity.
    stereo: bool = field(default=False, repr=False)
    # The core's output for ``processed``, taken while a consumer held :meth:`Pipeline.depth_wanted`
    # (None: not taken, or no core): a call that returns the (H, W) uint32 beats, owned by the caller
    # (``depth.py`` calls it once per set; the emulated core computes them then).
    depth: Optional[Callable[[], np.ndarray]] = field(default=None, repr=False)
    # The calibration this frame ran with, stamped with the depth (``Pipeline.set_calibration``).
    calibration: Optional[FrameCalibration] = field(default=None, repr=False)
    # Where the overlay has no stereo core: the scale the ARM's StereoBM matches this frame at
    # (views.ARM_SCALES; 0.5 within the board's budget), stamped by the pipeline.
    arm_scale: float = field(default=1.0, repr=False)
    signal = True

    @property
    def size(self) -> Tuple[int, int]:
        h, w = self.processed.shape[:2]
        return w, h


@dataclass(frozen=True)
class NoSignal:
    """What the feed publishes instead of a frame when none arrived for a while."""

    seq: int
    timestamp: float
    since: float  # wall-clock time of the last frame (or of the start, if none came)
    last_frame: Optional[int]
    size: Tuple[int, int]
    signal = False


@dataclass(frozen=True)
class SourceState:
    """What feeds the core, as the daemon set it.

    ``virtual_input`` (read-only ``(H, W, 8)``) is the virtual camera's
    frame; processed frames with ``FRAME_COUNT >= effective_count`` come from
    it, so they carry it as their raw pair.
    """

    source: str = "live"
    virtual_input: Optional[np.ndarray] = None
    effective_count: int = 0


class RateMeter:
    """Events per second over the last ``window`` seconds (0 once nothing happened for a window)."""

    def __init__(self, window: float = 2.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.window = window
        self._clock = clock
        self._times: Deque[float] = collections.deque()
        self._lock = threading.Lock()

    def mark(self, t: Optional[float] = None) -> None:
        now = self._clock() if t is None else t
        with self._lock:
            self._times.append(now)
            while self._times and now - self._times[0] > self.window:
                self._times.popleft()

    def rate(self) -> float:
        now = self._clock()
        with self._lock:
            while self._times and now - self._times[0] > self.window:
                self._times.popleft()
            if len(self._times) < 2:
                return 0.0
            span = self._times[-1] - self._times[0]
            return (len(self._times) - 1) / span if span > 0 else 0.0


class Pipeline:
    """The frame thread of one :class:`~...overlays.interface.Overlay`; ``start``/``stop`` are idempotent.

    Start it after the overlay streams and stop it before the overlay stops.
    ``publish(frame_set)`` and ``heartbeat()`` are called on the pipeline
    thread and must not block. Counters and :meth:`stats` may be read from
    any thread.
    """

    def __init__(
        self,
        overlay: Overlay,
        *,
        publish: Callable[[FrameSet], None],
        heartbeat: Optional[Callable[[], None]] = None,
        wait_s: float = 0.25,
        clock: Callable[[], float] = time.time,
        copy_rate: Optional[Callable[[], Optional[float]]] = None,
        alive: Optional[Callable[[], None]] = None,
        charge: Optional[Callable[[str, float], None]] = None,
        channel_ok: Callable[[Channel], bool] = lambda name: True,
        arm_scale: float = 1.0,
    ) -> None:
        self.overlay = overlay
        self.arm_scale = arm_scale  # FrameSet.arm_scale of every set
        self._publish = publish
        self._heartbeat = heartbeat
        # Frames per second somebody needs copied (None: every frame); frames beyond it are only seen:
        # counted and numbered, ``alive`` called instead of ``publish`` (the CPU budget, cpu_budget.py).
        self._copy_rate = copy_rate
        self._alive = alive
        self._charge = charge  # CPU seconds of each copy, by what: "copy" or "raw_copy"
        self._copy_due = 0.0
        self.wait_s = wait_s
        self._clock = clock
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._raw_wanted = 0
        self._pairs_wanted = 0
        self._depth_wanted = 0
        self.has_stereo = overlay.stereo is not None  # fixed by the bitstream
        self._calibration_for: Optional[Callable[[int], Optional[FrameCalibration]]] = None
        self._sinks: Tuple[Callable[[FrameSet], None], ...] = ()  # every_frame consumers
        self.channel_ok = channel_ok  # FabricHealth.channel_ok: False while a channel is faulted
        self.source_state = SourceState()
        # Counters.
        self.frames = 0
        self.seen = 0  # frames completed by the fabric that the pipeline saw but did not copy (not wanted)
        self.drops = 0
        self.retries = 0
        self.errors = 0
        self.last_error = ""
        self.last_frame_at: Optional[float] = None  # monotonic, of the last frame seen (copied or not)
        self.last_frame_number: Optional[int] = None  # its number
        self.heartbeat_at = time.monotonic()
        self.period: Optional[float] = None  # seconds between fabric frames (smoothed)
        self.meter = RateMeter()
        self._fabric_samples: Deque[Tuple[float, int]] = collections.deque()
        # Grab state.
        self._seq = 0
        self._last_store: Optional[int] = None
        self._last_count: Optional[int] = None

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> "Pipeline":
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                return self
            self._stop.clear()
            self.heartbeat_at = time.monotonic()
            self.last_frame_at = None
            self.period = None
            self._thread = threading.Thread(target=self._run, name="stereocam-pipeline", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout: Optional[float] = None) -> None:
        """Ask the thread to end and join it (at most ``timeout``, default ``wait_s + 1`` s)."""
        with self._lock:
            thread, self._thread = self._thread, None
        self._stop.set()
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.wait_s + 1.0 if timeout is None else timeout)
            if thread.is_alive():
                log.warning("pipeline thread did not end within the timeout")

    @property
    def running(self) -> bool:
        t = self._thread
        return t is not None and t.is_alive()

    def __enter__(self) -> "Pipeline":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- what consumers ask for ---------------------------------------------------------
    @contextlib.contextmanager
    def _wanted_while(self, counter: str) -> Iterator[None]:
        """While inside, the consumer count ``counter`` (an attribute: ``_raw_wanted``, ...) is one higher."""
        with self._lock:
            setattr(self, counter, getattr(self, counter) + 1)
        try:
            yield
        finally:
            with self._lock:
                setattr(self, counter, getattr(self, counter) - 1)

    def raw_wanted(self) -> ContextManager[None]:
        """While inside, every frame set carries the raw pair (copying it costs memory bandwidth)."""
        return self._wanted_while("_raw_wanted")

    def pairs_wanted(self) -> ContextManager[None]:
        """While inside, frame sets also carry the raw store before ``raw`` (``raw_previous``): captures."""
        return self._wanted_while("_pairs_wanted")

    def depth_wanted(self) -> ContextManager[None]:
        """While inside, frame sets carry the stereo core's output (``FrameSet.depth``) where there is one.

        Taking it costs a store copy on the board (the emulated core computes it only when read).
        """
        return self._wanted_while("_depth_wanted")

    @property
    def wants_depth(self) -> bool:
        return self._depth_wanted > 0

    def set_calibration(self, calibration_for: Callable[[int], Optional[FrameCalibration]]) -> None:
        """Stamp frame sets taken with depth with the calibration their FRAME_COUNT ran with."""
        self._calibration_for = calibration_for

    @contextlib.contextmanager
    def every_frame(self, sink: Callable[[FrameSet], None]) -> Iterator[None]:
        """While inside, every frame that completes is copied (whatever ``copy_rate`` says) and handed to
        ``sink`` on the pipeline thread, before it is published.

        For consumers that must see each frame, not the latest (a recording): the feed keeps only
        the newest set. ``sink`` must return at once (queue the set; the arrays are read-only and
        shared) and should not raise (an exception is logged and counted; the frame is still
        published). Frames the pipeline itself misses are ``FRAME_COUNT`` gaps, counted in
        :attr:`drops`. Hold :meth:`raw_wanted` too for the raw pairs.
        """
        with self._lock:
            self._sinks = self._sinks + (sink,)
        try:
            yield
        finally:
            with self._lock:
                sinks = list(self._sinks)
                sinks.remove(sink)
                self._sinks = tuple(sinks)

    @property
    def frames_seen(self) -> int:
        """Frames the pipeline saw complete: copied and published, or seen only (nobody needed them)."""
        return self.frames + self.seen

    def set_copy_rate(self, copy_rate: Optional[Callable[[], Optional[float]]]) -> None:
        """Copy only as many frames a second as ``copy_rate()`` says (None: every frame)."""
        self._copy_rate = copy_rate

    @property
    def wants_raw(self) -> bool:
        return self._raw_wanted > 0

    def set_source(self, state: SourceState) -> None:
        """Record what feeds the core (the caller has already switched the mux)."""
        self.source_state = state

    def frame_count(self) -> int:
        """The core's ``FRAME_COUNT`` register (blocks for one register read)."""
        return self.overlay.frame_count()

    # -- stats --------------------------------------------------------------------------
    def last_frame_age(self) -> Optional[float]:
        """Seconds since the pipeline last saw a frame complete, copied or not (None if none yet)."""
        t = self.last_frame_at
        return None if t is None else time.monotonic() - t

    def fabric_fps(self) -> float:
        """Frames per second the core emitted, from ``FRAME_COUNT`` over the last two seconds."""
        samples = list(self._fabric_samples)
        if len(samples) < 2 or time.monotonic() - samples[-1][0] > 2.0:
            return 0.0
        (t0, c0), (t1, c1) = samples[0], samples[-1]
        return ((c1 - c0) % COUNT_MOD) / (t1 - t0) if t1 > t0 else 0.0

    # -- the thread ---------------------------------------------------------------------
    def _beat(self) -> None:
        self.heartbeat_at = time.monotonic()
        if self._heartbeat is not None:
            self._heartbeat()

    def _fail(self, what: str, exc: BaseException) -> None:
        self.errors += 1
        self.last_error = f"{what}: {exc}"
        log.warning("pipeline: %s: %s", what, exc)

    def _run(self) -> None:
        overlay = self.overlay
        while not self._stop.is_set():
            self._doze()
            try:
                overlay.wait_processed(self.wait_s)
            except RegisterTimeout:
                self._beat()  # healthy, just no frame: the feed shows "no signal"
                continue
            except ChannelFault as exc:  # FabricHealth restarts the channel; wait for it
                self._fault("processed frames channel fault", exc)
                self._beat()
                self._stop.wait(self.wait_s)
                continue
            except ChannelNotStarted as exc:
                self._fail("the fabric is not streaming", exc)
                self._stop.wait(self.wait_s)
                continue
            except Exception as exc:  # a driver bug must not kill the thread
                self._fail("waiting for a frame", exc)
                self._stop.wait(self.wait_s)
                continue
            try:
                if not self._wanted():
                    self.see()
                    self._beat()
                    continue
                frame_set = self.grab()
            except (VDMAError, RegisterTimeout) as exc:
                self._fail("reading a frame", exc)
                self._stop.wait(0.01)
                continue
            except Exception as exc:
                self._fail("reading a frame", exc)
                self._stop.wait(self.wait_s)
                continue
            if frame_set is not None:
                for sink in self._sinks:
                    try:
                        sink(frame_set)
                    except Exception as exc:
                        self._fail("handing a frame to a consumer", exc)
                try:
                    self._publish(frame_set)
                except Exception as exc:
                    self._fail("publishing a frame", exc)
                    continue
            self._beat()

    def _wanted(self) -> bool:
        """Whether to copy the frame that just completed: always, or at the rate somebody needs."""
        if self._copy_rate is None or self._pairs_wanted or self._sinks:
            return True
        rate = self._copy_rate()
        period = self.period
        if rate is None or (period is not None and rate * period >= 0.95):
            return True  # every frame is wanted
        now = time.monotonic()
        if rate <= 0 or now < self._copy_due - 0.25 * (period or 0.0):
            return False
        interval = 1.0 / rate
        self._copy_due = max(self._copy_due + interval, now + 0.5 * interval)
        return True

    def see(self) -> None:
        """Count and number the frame that just completed without copying it (nobody needs it now)."""
        count = self.frame_count()
        store = self.overlay.processed_store().store
        if store == self._last_store and self._last_count is not None and count == self._last_count:
            return
        self._advance(count, store)
        self.seen += 1
        if self._alive is not None:
            self._alive()

    def _doze(self) -> None:
        """Sleep through most of the frame period instead of polling the status register all of it.

        The next frame is due one period after the last; the driver's
        bounded wait then polls only the last ~30% of the period. A frame
        that comes early is only picked up later, never lost.
        """
        last, period = self.last_frame_at, self.period
        if last is None or period is None:
            return
        pause = last + DOZE * period - time.monotonic()
        if pause > 0:
            self._stop.wait(min(pause, self.wait_s))

    def _fault(self, what: str, exc: BaseException) -> None:
        """A channel fault: counted, logged by :class:`~.fabric_health.FabricHealth` (once, not per frame)."""
        self.errors += 1
        self.last_error = f"{what}: {exc}"

    def grab(self) -> Optional[FrameSet]:
        """Copy the latest completed pair into a new :class:`FrameSet`, without waiting (blocks on the copy).

        None if that frame was already published, or if the fabric kept
        moving under three copies (counted as a drop with the next frame).
        The thread calls it after each completed frame; with a stepped
        clock, tests call it directly. Not thread-safe: one caller at a time.
        """
        overlay = self.overlay
        for _ in range(GRAB_ATTEMPTS):
            count = self.frame_count()
            stored = overlay.processed_store()
            store, buf = stored.store, stored.pixels
            if (store == self._last_store and self._last_count is not None
                    and (count - self._last_count) % COUNT_MOD < stored.stores):
                return None  # the same store as last time, and the channel cannot have come round
            started = time.thread_time()
            processed = np.empty(buf.shape, dtype=np.uint8)
            np.copyto(processed, buf)
            depth = None
            if self._depth_wanted and self.has_stereo:
                depth = overlay.take_depth(store) or _no_output(count)
            if self._charge is not None:
                self._charge("copy", time.thread_time() - started)
            state = self.source_state
            raw: Optional[np.ndarray] = None
            raw_previous: Optional[np.ndarray] = None
            raw_store: Optional[int] = None
            if state.source == "virtual" and state.virtual_input is not None and \
                    (count - state.effective_count) % COUNT_MOD < COUNT_MOD // 2:
                raw = state.virtual_input
            elif self._raw_wanted and self.channel_ok("vdma_raw.s2mm"):
                try:
                    rstored = overlay.raw_store()
                    rstore, rbuf = rstored.store, rstored.pixels
                    started = time.thread_time()
                    raw = np.empty(rbuf.shape, dtype=np.uint8)
                    np.copyto(raw, rbuf)
                    if self._charge is not None:
                        self._charge("raw_copy", time.thread_time() - started)
                    raw_store = rstore
                    if self._pairs_wanted:
                        before = overlay.raw_store(rstore - 1).pixels
                        raw_previous = np.empty(before.shape, dtype=np.uint8)
                        np.copyto(raw_previous, before)
                except NoFrameYet:
                    raw = raw_store = None
                except ChannelFault as exc:  # the processed frames go on; FabricHealth restarts it
                    raw = raw_previous = raw_store = None
                    self._fault("raw frames channel fault", exc)
            if self.frame_count() == count:
                break
            self.retries += 1
        else:
            return None  # the fabric kept moving under the copy: counted as a drop next time
        now_wall = self._clock()
        number, now = self._advance(count, store)
        processed.flags.writeable = False
        for copy in (raw, raw_previous):
            if copy is not None and copy.flags.writeable:
                copy.flags.writeable = False
        self._seq += 1
        frame_set = FrameSet(seq=self._seq, frame=number, fabric_count=count, timestamp=now_wall,
                             monotonic=now, source=state.source, processed=processed, raw=raw,
                             raw_previous=raw_previous, raw_store=raw_store, stereo=self.has_stereo,
                             depth=depth, arm_scale=self.arm_scale)
        if self._depth_wanted and self._calibration_for is not None:
            frame_set.calibration = self._calibration_for(count)
        self.frames += 1
        self.meter.mark(now)
        return frame_set

    def _advance(self, count: int, store: int) -> Tuple[int, float]:
        """Book-keeping of a frame seen or copied: ``(frame number, monotonic now)``.

        Frames the fabric completed between two the pipeline saw are drops; the
        period is smoothed from the same counts.
        """
        now = time.monotonic()
        if self._last_count is None or self.last_frame_number is None or self.last_frame_at is None:
            number = count
        else:
            delta = (count - self._last_count) % COUNT_MOD
            self.drops += max(0, delta - 1)
            number = self.last_frame_number + max(1, delta)
            if 0 < delta < 1000:
                period = (now - self.last_frame_at) / delta
                self.period = period if self.period is None else 0.8 * self.period + 0.2 * period
        self._last_store, self._last_count = store, count
        self.last_frame_at, self.last_frame_number = now, number
        self._fabric_samples.append((now, count))
        while self._fabric_samples and now - self._fabric_samples[0][0] > 2.0:
            self._fabric_samples.popleft()
        return number, now

