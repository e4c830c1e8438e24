"""The barrage: malformed requests and WebSocket messages sent while one client watches a stream.

What it measures: the answers, the longest gap in the watched stream, and the daemon's memory.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple

from . import serve as bench_serve
from .daemon_process import rss_mb
from .malformed import warmup_requests
from .malformed_case import Case
from .raw_http import STALL_TIMEOUT_S, RobustnessBenchError, first_line, send_raw

FLOOR_STREAM_GAP_S = 1.0
FLOOR_RSS_DELTA_MB = 50.0
FLOOR_5XX = 0
FLOOR_TRACEBACKS = 0


@dataclass
class Outcome:
    case: Case
    status: Optional[int]
    answer: bytes = field(repr=False, default=b"")
    started: float = 0.0  # monotonic
    seconds: float = 0.0

    @property
    def complaint(self) -> Optional[str]:
        problem = self.case.complaint(self.status)
        if problem is None and b"Traceback" in self.answer:
            problem = "a traceback in the answer"
        return problem


async def send_all(port: int, cases: Sequence[Case], *, concurrency: int = 6) -> List[Outcome]:
    """Send every case, ``concurrency`` at a time; their outcomes in the order of ``cases``."""
    gate = asyncio.Semaphore(concurrency)

    async def one(case: Case) -> Outcome:
        async with gate:
            t0 = time.monotonic()
            status, answer = await send_raw(port, case.data, half_close=not case.answered)
            return Outcome(case, status, answer, t0, time.monotonic() - t0)

    return list(await asyncio.gather(*(one(c) for c in cases)))


WS_MESSAGES: List[Tuple[str, Any]] = [
    ("not JSON", "views please"), ("deep JSON", "[" * 30_000 + "]" * 30_000), ("a list", "[]"),
    ("null", "null"), ("a string", '"rect_left"'), ("views a string", '{"views": "rect_left"}'),
    ("a view number", '{"views": [1]}'),
    ("an unknown view", '{"views": ["nope"]}'), ("fps 0", '{"views": ["rect_left"], "fps": 0}'),
    ("fps text", '{"views": ["rect_left"], "fps": "x"}'), ("fps NaN", '{"views": ["rect_left"], "fps": NaN}'),
    ("quality 1000", '{"views": ["rect_left"], "quality": 1000}'), ("an unknown key", '{"bogus": 1}'),
    ("gray maybe", '{"views": ["rect_left"], "gray": "maybe"}'),
    ("20 views", json.dumps({"views": ["rect_left"] * 20})),
    ("a huge number", '{"views": ["rect_left"], "fps": ' + "9" * 5000 + "}"), ("binary", b"\x00\x01\x02"),
    ("over 64 KB", "x" * 70_000),
]


async def websocket_abuse(port: int, *, repeat: int = 2) -> List[Tuple[str, str]]:
    """Send each of :data:`WS_MESSAGES` on ``/ws`` ``repeat`` times: ``(message, what came back)``, where
    what came back is ``error`` (a text ``{"error": ...}``), ``closed <code>`` or what else it was.
    A socket the daemon closes (a message over its 64 KB limit) is opened again."""
    import aiohttp

    out: List[Tuple[str, str]] = []
    async with aiohttp.ClientSession(f"http://127.0.0.1:{port}") as session:
        ws = await session.ws_connect("/ws")
        try:
            for _ in range(repeat):
                for name, message in WS_MESSAGES:
                    if ws.closed:
                        ws = await session.ws_connect("/ws")
                    if isinstance(message, bytes):
                        await ws.send_bytes(message)
                    else:
                        await ws.send_str(message)
                    reply = await ws.receive(timeout=STALL_TIMEOUT_S)
                    if reply.type == aiohttp.WSMsgType.TEXT and "error" in json.loads(reply.data):
                        out.append((name, "error"))
                    elif reply.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                                        aiohttp.WSMsgType.CLOSING):
                        out.append((name, f"closed {ws.close_code}"))
                    else:
                        out.append((name, f"{reply.type.name} {str(reply.data)[:60]}"))
        finally:
            await ws.close()
    return out


@dataclass
class StreamWatch:
    """Parts of one MJPEG stream as they arrive: ``(monotonic time, frame number, signal)``."""

    parts: List[Tuple[float, int, bool]] = field(default_factory=list)
    error: Optional[str] = None

    def max_gap(self, start: float, end: float) -> float:
        """The longest time without a part between ``start`` and ``end`` (monotonic)."""
        times = [start] + [t for t, _, _ in self.parts if start < t < end] + [end]
        return max(b - a for a, b in zip(times, times[1:], strict=False))

    def between(self, start: float, end: float) -> List[Tuple[float, int, bool]]:
        return [p for p in self.parts if start <= p[0] <= end]


async def watch_stream(port: int, path: str, watch: StreamWatch, stop: asyncio.Event,
                       *, token: Optional[str] = None) -> None:
    """Read the MJPEG stream at ``path`` until ``stop``, recording each part in ``watch``."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        auth = f"Authorization: Bearer {token}\r\n" if token else ""
        writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{auth}\r\n".encode())
        await writer.drain()
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
        if not head.startswith(b"HTTP/1.1 200"):
            watch.error = f"GET {path}: {first_line(head)!r}"
            return
        while not stop.is_set():
            block = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
            headers = bench_serve.part_headers(block)
            if b"content-length" not in headers:
                continue
            await asyncio.wait_for(reader.readexactly(int(headers[b"content-length"]) + 2), STALL_TIMEOUT_S)
            watch.parts.append((time.monotonic(), int(headers.get(b"x-frame-number", b"-1")),
                                headers.get(b"x-signal") != b"none"))
    except asyncio.TimeoutError:
        watch.error = f"GET {path}: no part for {STALL_TIMEOUT_S:g} s"
    except (ConnectionError, asyncio.IncompleteReadError, ValueError) as exc:
        if not stop.is_set():
            watch.error = f"GET {path}: {type(exc).__name__}: {exc}"
    finally:
        writer.close()


@dataclass
class Barrage:
    """What :func:`run_barrage` saw; ``figures()`` is its part of the bench's JSON."""

    outcomes: List[Outcome]
    watch: StreamWatch
    start: float
    end: float
    rss_ready_mb: float
    rss_start_mb: float
    rss_peak_mb: float
    rss_end_mb: float
    warmup: int
    websocket: List[Tuple[str, str]] = field(default_factory=list)

    @property
    def websocket_unexpected(self) -> List[Tuple[str, str]]:
        """WebSocket messages not answered as they should be: an error, or (over 64 KB) a close 1009."""
        return [(name, got) for name, got in self.websocket
                if got != ("closed 1009" if name == "over 64 KB" else "error")]

    @property
    def unexpected(self) -> List[Outcome]:
        return [o for o in self.outcomes if o.complaint is not None]

    @property
    def status_5xx(self) -> List[Outcome]:
        return [o for o in self.outcomes if o.status is not None and o.status >= 500]

    def figures(self) -> Dict[str, Any]:
        statuses: Dict[str, int] = {}
        kinds: Dict[str, int] = {}
        for o in self.outcomes:
            key = "none" if o.status is None else str(o.status)
            statuses[key] = statuses.get(key, 0) + 1
            kinds[o.case.kind] = kinds.get(o.case.kind, 0) + 1
        during = self.watch.between(self.start, self.end)
        return {
            "requests": len(self.outcomes),
            "kinds": dict(sorted(kinds.items())),
            "warmup_requests": self.warmup,
            "seconds": round(self.end - self.start, 2),
            "statuses": dict(sorted(statuses.items())),
            "status_5xx": len(self.status_5xx),
            "unexpected": [f"{o.case.kind}: {o.case.name}: {o.complaint}" for o in self.unexpected][:20],
            "websocket_messages": len(self.websocket),
            "websocket_unexpected": [f"{name}: {got}" for name, got in self.websocket_unexpected][:20],
            "stream_parts": len(during),
            "no_signal_parts": sum(1 for _, _, signal in during if not signal),
            "stream_max_gap_s": round(self.watch.max_gap(self.start, self.end), 3),
            "rss_ready_mb": round(self.rss_ready_mb, 1),
            "rss_start_mb": round(self.rss_start_mb, 1),
            "rss_peak_mb": round(self.rss_peak_mb, 1),
            "rss_end_mb": round(self.rss_end_mb, 1),
            "rss_delta_mb": round(self.rss_end_mb - self.rss_start_mb, 1),
        }


async def run_barrage(port: int, pid: int, cases: Sequence[Case], *, concurrency: int = 6,
                      settle_s: float = 30.0, warmup: Optional[Sequence[Case]] = None,
                      view: str = "rect_left") -> Barrage:
    """Warm up, then send ``cases`` while watching ``/stream/<view>`` and the daemon's memory.

    After the last answer, waits up to ``settle_s`` for the daemon's memory to come back within
    :data:`FLOOR_RSS_DELTA_MB` of where it started (a condition, not a fixed time).
    """
    rss_ready = rss_mb(pid)
    watch = StreamWatch()
    stop = asyncio.Event()
    watcher = asyncio.ensure_future(watch_stream(port, f"/stream/{view}", watch, stop))
    try:
        warm = list(warmup if warmup is not None else warmup_requests(cases))
        await send_all(port, warm, concurrency=concurrency)
        deadline = time.monotonic() + STALL_TIMEOUT_S
        while not watch.parts and watch.error is None:  # the stream runs before the barrage starts
            if time.monotonic() > deadline:
                raise RobustnessBenchError(f"/stream/{view} sent no part in {STALL_TIMEOUT_S:g} s")
            await asyncio.sleep(0.05)
        rss_start = rss_mb(pid)
        peak = [rss_start]

        async def sample() -> None:
            while True:
                peak[0] = max(peak[0], rss_mb(pid))
                await asyncio.sleep(0.1)

        sampler = asyncio.ensure_future(sample())
        start = time.monotonic()
        try:
            outcomes, websocket = await asyncio.gather(send_all(port, cases, concurrency=concurrency),
                                                       websocket_abuse(port))
        finally:
            end = time.monotonic()
            sampler.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sampler
        settle_until = time.monotonic() + settle_s
        rss_end = rss_mb(pid)
        while rss_end - rss_start > FLOOR_RSS_DELTA_MB and time.monotonic() < settle_until:
            await asyncio.sleep(0.5)
            rss_end = rss_mb(pid)
        # The stream goes on after the barrage: one more part.
        parts = len(watch.parts)
        deadline = time.monotonic() + STALL_TIMEOUT_S
        while len(watch.parts) == parts and watch.error is None and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
    finally:
        stop.set()
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watcher
    if watch.error is not None:
        raise RobustnessBenchError(f"the monitored stream failed: {watch.error}")
    return Barrage(outcomes=outcomes, watch=watch, start=start, end=end, rss_ready_mb=rss_ready,
                   rss_start_mb=rss_start, rss_peak_mb=max(peak[0], rss_end), rss_end_mb=rss_end,
                   warmup=len(warm), websocket=websocket)
