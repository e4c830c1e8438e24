"""Encoding: each view encoded once per frame, whatever the number of clients, and only while watched.

Event-loop side of the frame path:

``FrameFeed.frames --> [DisparityWorker] --> Encoder --> Encoded --> clients`` (the feed: :mod:`.feed`)

- :class:`Encoder` (one per :class:`EncoderKey` = view, JPEG quality, gray)
  runs only while it has subscribers; it encodes the newest frame set in a
  worker thread (never one published before it started: that one is as old
  as the time nobody watched), at most at the highest rate a subscriber asked for, and
  publishes the :class:`Encoded` bytes that every client of that key sends
  as they are: the MJPEG part (headers included) and the bare JPEG are built
  once, in the worker thread; a WebSocket message adds its small header, with
  the frame's age, as it is sent.
- :class:`Encoders` is the registry: ``with encoders.subscribe(key, fps) as
  encoder:`` starts an encoder (and what it needs: the raw copy, the
  disparity worker) on first use and stops it when the last subscriber
  leaves.

All classes here are used from the event-loop thread only; the encode
functions run in worker threads.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import math
import struct
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple

import cv2
import numpy as np

from .cpu_budget import CpuBudget, Demand, ViewPlan
from .feed import BroadcastClosed, FeedItem, FrameFeed, Latest
from .held import HeldFrames, ShownLatest
from .pipeline import FrameSet, NoSignal, Pipeline, RateMeter
from .views import (
    RAW_VIEWS,
    DisparityWorker,
    ViewUnavailable,
    needs_disparity,
    no_signal_detail,
    no_signal_image,
    render,
    uses_disparity_worker,
    view_size,
)

log = logging.getLogger(__name__)

__all__ = [
    "EncoderKey", "Encoded", "Encoder", "Encoders", "Pacer", "encode_image", "encoded_for", "png_for",
    "BOUNDARY",
]

BOUNDARY = "frame"


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
    JPEG, CRLF); ``jpeg`` a view of the JPEG inside it; ``ws_sent_at`` the
    WebSocket message (4-byte big-endian header length, JSON header, JPEG).
    """

    key: EncoderKey
    frame: int
    timestamp: float
    signal: bool
    part: bytes
    jpeg_start: int
    meta: Dict[str, Any] = field(default_factory=dict, repr=False)  # the WebSocket header's fields

    @property
    def jpeg(self) -> memoryview:
        return memoryview(self.part)[self.jpeg_start:len(self.part) - 2]

    def ws_sent_at(self, now: float) -> bytes:
        """The WebSocket message with ``age_s`` (``now`` minus the capture time, both the daemon's
        wall clock) in its header: how old the frame is as it leaves, for the page's latency figure.
        Built per send (a small header and one copy of the JPEG): the age is the sender's."""
        meta = json.dumps(dict(self.meta, age_s=round(max(0.0, now - self.timestamp), 4))).encode("utf-8")
        return b"".join((struct.pack(">I", len(meta)), meta, self.jpeg))

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
    doc = {"view": key.view, "frame": frame, "timestamp": round(timestamp, 6), "signal": signal,
           "gray": key.gray, "quality": key.quality, "scale": key.scale}
    return Encoded(key=key, frame=frame, timestamp=timestamp, signal=signal, part=head + jpeg + b"\r\n",
                   jpeg_start=len(head), meta=doc)


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
        # What the source holds now was published before anyone asked for this key: a view left
        # unwatched holds its last frame for as long (seconds), so the first encode is of a newer one.
        self._start_seq = source.seq
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
        seq = self._start_seq
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


def demand_for(key: EncoderKey, asked: float, fabric_fps: float, frame_size: Tuple[int, int],
               budget: CpuBudget, disparity_fps: float) -> Demand:
    """What an encoder of ``key`` asked at ``asked`` fps needs (its measured costs, or the budget's
    priors until measured): its target is capped by the fabric's rate, and a disparity view's by
    ``disparity_fps``, whose matching it shares with the other disparity view."""
    target = min(asked, fabric_fps) if fabric_fps > 0 else asked
    match = 0.0
    if uses_disparity_worker(key.view):
        target = min(target, disparity_fps)
        w, h = frame_size
        match = budget.cost("match", budget.priors.match_s_per_pixel * w * h)
    size = view_size(key.view, frame_size, key.scale)
    prior = budget.priors.view_seconds(key.view, key.gray, key.scale, key.quality, frame_size, size)
    return Demand(key=key, asked=asked, target=target, cost=budget.cost(key, prior),
                  raw=key.view in RAW_VIEWS, match=match)


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
        self.held = HeldFrames()  # the disparity view's recent frames and the frozen ones (freeze, ruler)
        self.disparity_output: Latest[FeedItem] = ShownLatest(self.held)
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
        if uses_disparity_worker(key.view):
            self.disparity.acquire()
            source = self.disparity_output
        if self.pipeline is not None and (key.view in RAW_VIEWS or needs_disparity(key.view)):
            stack = contextlib.ExitStack()
            stack.enter_context(self.pipeline.raw_wanted() if key.view in RAW_VIEWS
                                else self.pipeline.depth_wanted())
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
        if uses_disparity_worker(key.view):
            self.disparity.release()
        hold = self._raw_holds.pop(key, None)
        if hold is not None:
            hold.close()

    # -- the CPU budget ----------------------------------------------------------------------
    def demands(self, fabric_fps: float, frame_size: Tuple[int, int]) -> List[Demand]:
        """What every running encoder needs, for :meth:`CpuBudget.plan` (see cpu_budget.py)."""
        budget = self.budget
        assert budget is not None
        return [demand_for(key, encoder.fps, fabric_fps, frame_size, budget, self.disparity.fps)
                for key, encoder in self._encoders.items()]

    def apply(self, plans: Dict[Any, ViewPlan]) -> None:
        """Give every encoder (and the disparity worker) its planned rate."""
        disparity: Optional[float] = None
        for key, encoder in self._encoders.items():
            plan = plans.get(key)
            encoder.limit = None if plan is None or not plan.limited else plan.planned
            if uses_disparity_worker(key.view) and plan is not None:
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

