"""The feed: frame sets from the pipeline thread to the event loop, newest first.

``pipeline thread --push--> FrameFeed.frames --> encoders, snapshots, captures``

- :class:`Latest` is the latest-value-wins broadcast every stage hands on
  with: publishing replaces the value and wakes every waiter; a waiter asks
  for "newer than what I had" and gets the newest, skipping what it missed.
  Nothing queues per reader.
- :class:`FrameFeed` takes frame sets from the pipeline thread (keeping only
  the newest one if the loop is busy) and publishes a
  :class:`~.pipeline.NoSignal` marker when frames stop, twice a second.

Both are used from the event-loop thread only, except :meth:`FrameFeed.push`
and :meth:`FrameFeed.alive` (pipeline thread).
"""
from __future__ import annotations

import asyncio
import threading
import time
from typing import Any, Callable, Generic, Optional, Tuple, TypeVar, Union

from .pipeline import FrameSet, NoSignal

__all__ = ["Latest", "BroadcastClosed", "FrameFeed", "FeedItem", "NO_SIGNAL_REPEAT_S"]

T = TypeVar("T")
FeedItem = Union[FrameSet, NoSignal]
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
