"""Encoding: each view encoded once per frame, whatever the number of clients, and only while watched.

Event-loop side of the frame path:

``pipeline thread --push--> FrameFeed.frames --> [DisparityWorker] --> Encoder --> Encoded --> clients``

- :class:`Latest` is the latest-value-wins broadcast every stage hands on
  with: publishing replaces the value and wakes every waiter; a waiter asks
  for "newer than what I had" and gets the newest, skipping what it missed.
  Nothing queues per reader.
- :class:`FrameFeed` takes frame sets from the pipeline thread (keeping only
  the newest one if the loop is busy) and publishes a
  :class:`~.pipeline.NoSignal` marker when frames stop, twice a second.
- :class:`Encoder` (one per :class:`EncoderKey` = view, JPEG quality, gray)
  runs only while it has subscribers; it encodes the newest frame set in a
  worker thread, at most at the highest rate a subscriber asked for, and
  publishes the :class:`Encoded` bytes that every client of that key sends
  as they are: the MJPEG part (headers included), the bare JPEG and the
  WebSocket message are all built once, in the worker thread.
- :class:`Encoders` is the registry: ``with encoders.subscribe(key, fps) as
  encoder:`` starts an encoder (and what it needs: the raw copy, the
  disparity worker) on first use and stops it when the last subscriber
  leaves.

All classes here are used from the event-loop thread only, except
:meth:`FrameFeed.push` (pipeline thread) and the encode functions (worker
threads).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import math
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Generic, Iterator, List, Optional, Tuple, TypeVar, Union

import cv2
import numpy as np

from .cpu_budget import PRIOR_ENCODE_S_PER_BYTE, PRIOR_MATCH_S_PER_PIXEL, CpuBudget, Demand, ViewPlan
from .pipeline import FrameSet, NoSignal, Pipeline, RateMeter
from .views import (
    RAW_VIEWS,
    DisparityWorker,
    ViewUnavailable,
    no_signal_detail,
    no_signal_image,
    render,
    view_size,
)

log = logging.getLogger(__name__)

__all__ = [
    "Latest", "BroadcastClosed", "FrameFeed", "FeedItem", "EncoderKey", "Encoded", "Encoder", "Encoders",
    "encode_image", "encoded_for", "png_for", "BOUNDARY",
]

T = TypeVar("T")
FeedItem = Union[FrameSet, NoSignal]
BOUNDARY = "frame"
NO_SIGNAL_REPEAT_S = 0.5


class BroadcastClosed(Exception):
    """The broadcast was closed (the daemon is shutting down)."""


class Latest(Generic[T]):
    """Latest-value-wins broadcast for asyncio tasks of one loop.

    :meth:`publish` never blocks and keeps only the newest value; every task
    waiting in :meth:`wait_newer` wakes and gets ``(seq, value)`` of the
    newest one. Sequence numbers start at 1; ``wait_newer(0)`` returns the
    current value if there is one.
    """

    def __init__(self) -> None:
        self._seq = 0
        self._value: Optional[T] = None
        self._event = asyncio.Event()
        self._closed = False
        self.subscribers = 0  # informational: tasks currently waiting or reading

    @property
    def seq(self) -> int:
        return self._seq

    @property
    def closed(self) -> bool:
        return self._closed

    def publish(self, value: T) -> None:
        if self._closed:
            return
        self._value = value
        self._seq += 1
        event, self._event = self._event, asyncio.Event()
        event.set()

    def current(self) -> Tuple[int, Any]:
        """``(seq, value)`` now (``(0, None)`` before the first publish)."""
        return self._seq, self._value

    async def wait_newer(self, seq: int) -> Tuple[int, T]:
        """The newest value with a sequence number above ``seq``, waiting for one if needed."""
        while self._seq <= seq or self._value is None:
            if self._closed:
                raise BroadcastClosed("the stream is closing")
            await self._event.wait()
        if self._closed:
            raise BroadcastClosed("the stream is closing")
        return self._seq, self._value

    def close(self) -> None:
        """Wake every waiter with :class:`BroadcastClosed`; later publishes are ignored."""
        self._closed = True
        self._event.set()


# -- the feed: pipeline thread -> loop ------------------------------------------------------------

class FrameFeed:
    """The loop side of the pipeline: ``frames`` broadcasts frame sets and no-signal markers.

    :meth:`push` is called on the pipeline thread and never blocks; if the
    loop has not yet taken the previous set, the new one replaces it. Run
    :meth:`watch` as a background task: it publishes a
    :class:`~.pipeline.NoSignal` every :data:`NO_SIGNAL_REPEAT_S` while no
    frame came for ``no_signal_s``.
    """

    def __init__(self, *, frame_size: Tuple[int, int], no_signal_s: float) -> None:
        self.loop: Optional[asyncio.AbstractEventLoop] = None
        self.frame_size = frame_size
        self.no_signal_s = no_signal_s
        self.frames: Latest[FeedItem] = Latest()
        self._lock = threading.Lock()
        self._pending: Optional[FrameSet] = None
        self._scheduled = False
        self.last_frame: Optional[FrameSet] = None
        self.last_frame_at: Optional[float] = None  # monotonic, when the pipeline pushed it
        self.started_at = time.monotonic()
        self.started_wall = time.time()
        self.coalesced = 0
        self._marker_seq = 0
        self._waiters = 0

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver to ``loop`` from now on (call on the loop before the pipeline starts)."""
        self.loop = loop
        self.started_at = time.monotonic()
        self.started_wall = time.time()

    # pipeline thread
    def push(self, frame_set: FrameSet) -> None:
        with self._lock:
            if self._pending is not None:
                self.coalesced += 1
            self._pending = frame_set
            self.last_frame_at = time.monotonic()
            if self._scheduled:
                return
            self._scheduled = True
        loop = self.loop
        if loop is None:
            with self._lock:
                self._scheduled = False
            return
        try:
            loop.call_soon_threadsafe(self._deliver)
        except RuntimeError:  # the loop is closed: the daemon is stopping
            pass

    def alive(self) -> None:
        """The fabric completed a frame that nobody needed copied (pipeline thread): the signal is on."""
        with self._lock:
            self.last_frame_at = time.monotonic()

    @property
    def waiting(self) -> bool:
        """Whether a capture, snapshot or round trip waits for a frame now: the pipeline copies every one."""
        return self._waiters > 0

    def _deliver(self) -> None:
        with self._lock:
            frame_set, self._pending = self._pending, None
            self._scheduled = False
        if frame_set is not None:
            self.last_frame = frame_set
            self.frames.publish(frame_set)

    @property
    def signal(self) -> bool:
        t = self.last_frame_at
        return t is not None and time.monotonic() - t < self.no_signal_s

    def frame_age(self) -> Optional[float]:
        t = self.last_frame_at
        return None if t is None else time.monotonic() - t

    def no_signal_marker(self) -> NoSignal:
        self._marker_seq += 1
        last = self.last_frame
        return NoSignal(seq=self._marker_seq, timestamp=time.time(),
                        since=last.timestamp if last is not None else self.started_wall,
                        last_frame=last.frame if last is not None else None, size=self.frame_size)

    async def watch(self) -> None:
        """Publish no-signal markers while frames do not come (run as a task; cancel to stop)."""
        period = min(0.1, self.no_signal_s / 2)
        last_marker = 0.0
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            since = self.last_frame_at if self.last_frame_at is not None else self.started_at
            if now - since >= self.no_signal_s and now - last_marker >= NO_SIGNAL_REPEAT_S:
                last_marker = now
                self.frames.publish(self.no_signal_marker())

    async def next_frame(self, *, after_seq: Optional[int] = None, timeout: float,
                         accept: Callable[[FrameSet], bool] = lambda fs: True) -> FrameSet:
        """The first frame set published after now (or after ``after_seq``) that ``accept`` takes.

        Raises ``asyncio.TimeoutError`` after ``timeout`` s, :class:`BroadcastClosed` on shutdown.
        """
        seq = self.frames.seq if after_seq is None else after_seq

        async def wait() -> FrameSet:
            nonlocal seq
            while True:
                seq, item = await self.frames.wait_newer(seq)
                if isinstance(item, FrameSet) and accept(item):
                    return item

        self._waiters += 1
        try:
            return await asyncio.wait_for(wait(), timeout)
        finally:
            self._waiters -= 1

    def close(self) -> None:
        self.frames.close()


# -- encoding ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class EncoderKey:
    view: str
    quality: int
    gray: bool = False
    scale: float = 1.0  # of the view's size: thumbnails cost a fraction of the full view


class Pacer:
    """At most ``fps`` frames a second, on a steady schedule that does not burst after a stall."""

    def __init__(self, fps: float) -> None:
        self.interval = 1.0 / fps
        self.due = 0.0

    def set_rate(self, fps: float) -> None:
        self.interval = 1.0 / fps

    def wait(self, now: float) -> float:
        """Seconds to wait before the next frame (0: now)."""
        early = self.due - now
        return early if early > 0.25 * self.interval else 0.0

    def sent(self, now: float) -> None:
        self.due = max(self.due + self.interval, now + 0.5 * self.interval)


@dataclass(eq=False)
class Encoded:
    """One encoded frame of one key, shared read-only by every client.

    ``part`` is the whole multipart/x-mixed-replace part (boundary, headers,
    JPEG, CRLF); ``jpeg`` a view of the JPEG inside it; ``ws`` the WebSocket
    message (4-byte big-endian header length, JSON header, JPEG).
    """

    key: EncoderKey
    frame: int
    timestamp: float
    signal: bool
    part: bytes
    jpeg_start: int
    ws: bytes = field(repr=False)

    @property
    def jpeg(self) -> memoryview:
        return memoryview(self.part)[self.jpeg_start:len(self.part) - 2]

    def headers(self) -> Dict[str, str]:
        """HTTP headers for this frame sent on its own (snapshots)."""
        h = {"X-Frame-Number": str(self.frame), "X-Timestamp": f"{self.timestamp:.6f}"}
        if not self.signal:
            h["X-Signal"] = "none"
        return h


def encode_image(image: np.ndarray, fmt: str = ".jpg", quality: int = 80) -> bytes:
    """JPEG (at ``quality``) or PNG (fast, lossless) bytes of a BGR or gray uint8 image."""
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == ".jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
    ok, buf = cv2.imencode(fmt, image, params)
    if not ok:  # pragma: no cover - OpenCV refuses only invalid images
        raise ValueError(f"OpenCV could not encode a {image.shape} image as {fmt}")
    return buf.tobytes()


def _package(key: EncoderKey, frame: int, timestamp: float, signal: bool, jpeg: bytes) -> Encoded:
    head = (
        f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n"
        f"X-Frame-Number: {frame}\r\nX-Timestamp: {timestamp:.6f}\r\n"
        + ("" if signal else "X-Signal: none\r\n")
        + "\r\n"
    ).encode("ascii")
    meta = json.dumps({"view": key.view, "frame": frame, "timestamp": round(timestamp, 6), "signal": signal,
                       "gray": key.gray}).encode("utf-8")
    return Encoded(key=key, frame=frame, timestamp=timestamp, signal=signal, part=head + jpeg + b"\r\n",
                   jpeg_start=len(head), ws=struct.pack(">I", len(meta)) + meta + jpeg)


def encoded_for(key: EncoderKey, item: FeedItem,
                observe: Optional[Callable[[str, float], None]] = None,
                charge: Optional[Callable[[EncoderKey, float], None]] = None) -> Encoded:
    """The :class:`Encoded` frame of ``key`` for a feed item; blocks (worker thread).

    For a frame set the result is cached in the set, so a stream and any
    number of snapshots of the same frame share one encode. ``observe`` gets
    the encode's wall time, ``charge`` the CPU seconds of render, scaling and
    encode together (the CPU budget's cost of a frame of ``key``).
    """
    if isinstance(item, NoSignal):
        size = view_size(key.view, item.size, key.scale)
        image = no_signal_image(size, no_signal_detail(item.since, item.last_frame))
        jpeg = encode_image(image, ".jpg", key.quality)
        return _package(key, item.last_frame or 0, item.timestamp, False, jpeg)

    def compute() -> Encoded:
        cpu = time.thread_time()
        image = render(item, key.view, key.gray, key.scale)
        t0 = time.perf_counter()
        jpeg = encode_image(image, ".jpg", key.quality)
        if observe is not None:
            observe(key.view, time.perf_counter() - t0)
        if charge is not None:
            charge(key, time.thread_time() - cpu)
        return _package(key, item.frame, item.timestamp, True, jpeg)

    return item.cache.get(("jpeg", key), compute)


def png_for(frame_set: FrameSet, view: str, gray: bool = False, scale: float = 1.0) -> bytes:
    """Lossless PNG bytes of a view of ``frame_set`` (cached in the set); blocks (worker thread)."""
    def compute() -> bytes:
        return encode_image(render(frame_set, view, gray, scale), ".png")

    png: bytes = frame_set.cache.get(("png", view, bool(gray), scale), compute)
    return png


class Encoder:
    """Encodes the newest feed item for one key while it has subscribers (see the module doc)."""

    def __init__(self, key: EncoderKey, source: Latest[FeedItem], executor: concurrent.futures.Executor, *,
                 observe: Optional[Callable[[str, float], None]] = None,
                 charge: Optional[Callable[[EncoderKey, float], None]] = None,
                 on_error: Optional[Callable[[str], None]] = None) -> None:
        self.key = key
        self.source = source
        self.output: Latest[Encoded] = Latest()
        self._executor = executor
        self._observe = observe
        self._charge = charge
        self._on_error = on_error
        self._rates: List[float] = []
        self._task: Optional[asyncio.Task[None]] = None
        self.meter = RateMeter()
        self.frames = 0
        self.limit: Optional[float] = None  # the CPU budget's planned rate (None: no limit)

    @property
    def fps(self) -> float:
        """The highest rate a subscriber asked for."""
        return max(self._rates, default=0.0)

    @property
    def rate(self) -> float:
        """The rate it encodes at: what its clients asked, within the CPU budget's plan."""
        fps = self.fps
        return fps if self.limit is None else min(fps, self.limit)

    @property
    def subscribers(self) -> int:
        return len(self._rates)

    def add(self, fps: float) -> None:
        self._rates.append(float(fps))
        if self._task is None:
            name = f"stereocam-encode-{self.key.view}"
            self._task = asyncio.get_running_loop().create_task(self._run(), name=name)

    def remove(self, fps: float) -> None:
        self._rates.remove(float(fps))

    def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
        self.output.close()

    async def _run(self) -> None:
        try:
            await self._encode_loop()
        except BroadcastClosed:  # the feed closed: shutdown
            self.output.close()

    async def _encode_loop(self) -> None:
        loop = asyncio.get_running_loop()
        seq = 0
        pacer: Optional[Pacer] = None
        while True:
            seq, item = await self.source.wait_newer(seq)
            rate = self.rate
            if isinstance(item, FrameSet) and rate > 0:
                if pacer is None:
                    pacer = Pacer(rate)
                pacer.set_rate(rate)
                early = pacer.wait(loop.time())
                if early > 0:  # nobody wants frames this often: wait, then take the newest
                    await asyncio.sleep(early)
                    seq, item = self.source.current()
            started = loop.time()
            try:
                encoded = await loop.run_in_executor(self._executor, encoded_for, self.key, item,
                                                     self._observe, self._charge)
            except ViewUnavailable:
                continue  # the raw copy starts with the next frame
            except Exception as exc:
                log.warning("encoding %s failed: %s", self.key, exc)
                if self._on_error is not None:
                    self._on_error(f"encoding {self.key.view}: {exc}")
                continue
            if isinstance(item, FrameSet):
                if pacer is not None:
                    pacer.sent(started)
                self.frames += 1
                self.meter.mark()
            self.output.publish(encoded)


class Encoders:
    """The encoders of one daemon, by key; ``subscribe`` is the only way to get one (loop thread only)."""

    def __init__(self, feed: FrameFeed, pipeline: Optional[Pipeline],
                 executor: concurrent.futures.Executor, *, disparity_fps: float,
                 observe: Optional[Callable[[str, float], None]] = None,
                 on_error: Optional[Callable[[str], None]] = None,
                 budget: Optional[CpuBudget] = None) -> None:
        self.feed = feed
        self.pipeline = pipeline
        self.executor = executor
        self.observe = observe
        self.on_error = on_error
        self.budget = budget
        self.disparity_output: Latest[FeedItem] = Latest()
        self.disparity = DisparityWorker(feed.frames, self.disparity_output, fps=disparity_fps,
                                         charge=budget.charge if budget is not None else None)
        self._encoders: Dict[EncoderKey, Encoder] = {}
        self._raw_holds: Dict[EncoderKey, contextlib.ExitStack] = {}

    def active(self) -> Dict[EncoderKey, Encoder]:
        return dict(self._encoders)

    @contextlib.contextmanager
    def subscribe(self, key: EncoderKey, fps: float) -> Iterator[Encoder]:
        """The running encoder of ``key``, kept running (at least at ``fps``) inside the block."""
        encoder = self._encoders.get(key)
        if encoder is None:
            encoder = self._start(key)
        encoder.add(fps)
        try:
            yield encoder
        finally:
            encoder.remove(fps)
            if encoder.subscribers == 0 and self._encoders.get(key) is encoder:
                self._stop(key)

    def _start(self, key: EncoderKey) -> Encoder:
        source = self.feed.frames
        if key.view == "disparity":
            self.disparity.acquire()
            source = self.disparity_output
        elif key.view in RAW_VIEWS and self.pipeline is not None:
            stack = contextlib.ExitStack()
            stack.enter_context(self.pipeline.raw_wanted())
            self._raw_holds[key] = stack
        charge = self.budget.charge if self.budget is not None else None
        encoder = Encoder(key, source, self.executor, observe=self.observe, charge=charge,
                          on_error=self.on_error)
        plan = self.budget.plans.get(key) if self.budget is not None else None
        if self.budget is not None and self.budget.plans and plan is None:
            # A new view while the budget is tight starts at the common rate, not at full speed.
            encoder.limit = None if math.isinf(self.budget.rate_cap) else self.budget.rate_cap
        self._encoders[key] = encoder
        return encoder

    def _stop(self, key: EncoderKey) -> None:
        encoder = self._encoders.pop(key)
        encoder.stop()
        if key.view == "disparity":
            self.disparity.release()
        hold = self._raw_holds.pop(key, None)
        if hold is not None:
            hold.close()

    # -- the CPU budget ----------------------------------------------------------------------
    def demands(self, fabric_fps: float, frame_size: Tuple[int, int]) -> List[Demand]:
        """What every running encoder needs, for :meth:`CpuBudget.plan` (see cpu_budget.py)."""
        budget = self.budget
        assert budget is not None
        out: List[Demand] = []
        for key, encoder in self._encoders.items():
            asked = encoder.fps
            target = min(asked, fabric_fps) if fabric_fps > 0 else asked
            match = 0.0
            if key.view == "disparity":
                target = min(target, self.disparity.fps)
                w, h = frame_size
                match = budget.cost("match", PRIOR_MATCH_S_PER_PIXEL * w * h)
            w, h = view_size(key.view, frame_size, key.scale)
            prior = PRIOR_ENCODE_S_PER_BYTE * w * h * (1 if key.gray else 3)
            out.append(Demand(key=key, asked=asked, target=target, cost=budget.cost(key, prior),
                              raw=key.view in RAW_VIEWS, match=match))
        return out

    def apply(self, plans: Dict[Any, ViewPlan]) -> None:
        """Give every encoder (and the disparity worker) its planned rate."""
        disparity: Optional[float] = None
        for key, encoder in self._encoders.items():
            plan = plans.get(key)
            encoder.limit = None if plan is None or not plan.limited else plan.planned
            if key.view == "disparity" and plan is not None:
                disparity = max(disparity or 0.0, plan.planned)
        self.disparity.limit = disparity

    def copy_rate(self) -> Optional[float]:
        """Frames per second the pipeline must copy (pipeline thread): every frame while somebody
        waits for one (captures, snapshots, Verify), else what the budget's fastest view needs."""
        if self.feed.waiting or self.budget is None:
            return None
        if self._encoders and not self.budget.plans:
            return None  # watched, not yet planned
        return self.budget.copy_rate

    def status(self) -> List[Dict[str, Any]]:
        """Each running encoder: its key, clients, the rate asked, planned and delivered, and why lower."""
        plans = self.budget.plans if self.budget is not None else {}
        out: List[Dict[str, Any]] = []
        for key, enc in self._encoders.items():
            plan = plans.get(key)
            out.append({
                "view": key.view, "quality": key.quality, "gray": key.gray, "scale": key.scale,
                "subscribers": enc.subscribers, "asked_fps": round(enc.fps, 2),
                "target_fps": round(plan.target, 2) if plan is not None else round(enc.fps, 2),
                "planned_fps": round(enc.rate, 2), "delivered_fps": round(enc.meter.rate(), 2),
                "cost_ms": round(plan.cost_s * 1e3, 3) if plan is not None else None,
                "limited_by": plan.reason if plan is not None else "",
            })
        return out

    def fps_by_view(self) -> Dict[str, float]:
        """Encoded frames per second per view (the fastest encoder of each view)."""
        out: Dict[str, float] = {}
        for key, enc in self._encoders.items():
            out[key.view] = round(max(out.get(key.view, 0.0), enc.meter.rate()), 2)
        return out

    async def close(self) -> None:
        for key in list(self._encoders):
            self._stop(key)
        self.disparity_output.close()
        await self.disparity.close()

