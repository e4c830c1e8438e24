"""Connections, bounded: a header timeout, a keep-alive idle timeout, a cap below the fd limit.

What aiohttp's own ``TCPSite`` lets through: a socket that sends nothing, half a header or half
a body stays open for its keep-alive timeout (an hour) or forever; sockets pile up to the fd
limit, and then asyncio's accept loop, which goes on accepting after the first ``EMFILE``,
logs ``socket.accept() out of system resource`` up to a hundred times a loop turn while status,
captures and streams stop answering. So the daemon listens with :class:`BoundedSite` instead:

- A connection (:class:`BoundedRequestHandler`) that owes a request's line and headers must
  send them within ``header_timeout_s`` of its first byte (a new connection: of its opening); a
  body that stalls (no byte for ``header_timeout_s`` while its handler waits for it) closes the
  connection; between requests a connection may stay idle for ``keepalive_timeout_s``. A sweep
  every :func:`sweep_period` closes the overdue, so the bound holds within that period.
  A client being answered (an MJPEG stream, a WebSocket, a request being handled) is busy, never
  idle, whatever it sends: a stream that stops reading is the stream sweeper's
  (``stream_timeout_s``).
- At most :func:`connection_cap` connections are open: ``max_connections``, lowered to keep
  :data:`FD_RESERVE` fds free below the process's fd limit. A connection past the cap sheds the
  one idle the longest (the oldest idle first); when none is idle the newcomer is closed.
- When ``accept()`` fails for want of fds or memory, the site stops accepting for a back-off
  (:data:`BACKOFF_MIN_S`, doubling up to :data:`BACKOFF_MAX_S`) and sheds an idle connection.
- All of it is said in one warning line at most every :data:`LOG_INTERVAL_S` (counts), never a
  line per socket.
- A request with ``Expect: 100-continue`` whose ``Content-Length`` is over ``max_upload_bytes`` is
  answered 413 and closed before anything tells its client to send the body (aiohttp answers
  ``100 Continue`` before any middleware runs).

Everything here runs on the event loop's thread.
"""
from __future__ import annotations

import asyncio
import errno
import logging
import os
import resource
import socket
from collections import Counter
from dataclasses import dataclass
from typing import Any, Awaitable, Callable, Dict, List, Optional, Tuple

from aiohttp import web
from aiohttp.web_protocol import RequestHandler
from aiohttp.web_request import BaseRequest

from .errors import json_error, too_large
from .security import AccessLog

log = logging.getLogger(__name__)

__all__ = ["ConnectionLimits", "BoundedSite", "BoundedRequestHandler", "Connections", "connection_cap",
           "sweep_period", "FD_RESERVE", "LOG_INTERVAL_S"]

FD_RESERVE = 48  # fds kept free for what the daemon opens besides connections (captures, recordings, /proc)
MIN_CONNECTIONS = 4
LOG_INTERVAL_S = 10.0  # at most one line about connections per this long
BACKOFF_MIN_S = 0.05
BACKOFF_MAX_S = 1.0
ACCEPT_BATCH = 64  # connections accepted per loop turn at most (the loop serves the others between)
OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})

RequestHandlerFn = Callable[[BaseRequest], Awaitable[web.StreamResponse]]


@dataclass(frozen=True)
class ConnectionLimits:
    """The bounds of :mod:`.connections` (the settings of the same names; ``max_body``:
    ``max_upload_bytes``, for ``Expect: 100-continue``)."""

    header_timeout_s: float = 10.0
    keepalive_timeout_s: float = 60.0
    max_connections: int = 256
    max_body: int = 16 * 1024 * 1024


def open_fds() -> Optional[int]:
    """How many fds this process has open now (Linux), or None."""
    try:
        return len(os.listdir("/proc/self/fd")) - 1  # less the one listdir opened
    except OSError:
        return None


def connection_cap(max_connections: int) -> int:
    """``max_connections``, lowered so the fds open now plus the connections plus :data:`FD_RESERVE`
    stay within the soft ``RLIMIT_NOFILE`` (at least :data:`MIN_CONNECTIONS`)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return max_connections
    in_use = open_fds()
    room = soft - (in_use if in_use is not None else 64) - FD_RESERVE
    return max(MIN_CONNECTIONS, min(max_connections, room))


def sweep_period(limits: ConnectionLimits) -> float:
    """How often overdue connections are looked for: the timeouts hold within this."""
    return max(0.05, min(0.5, limits.header_timeout_s / 4, limits.keepalive_timeout_s / 4))


class Tally:
    """Counts what happened to connections; logs the counts in one line at most every
    :data:`LOG_INTERVAL_S` (the first at once), so a flood of sockets is a few lines."""

    def __init__(self, describe: Callable[[], str]) -> None:
        self.counts: Counter = Counter()
        self.describe = describe
        self.logged_at = float("-inf")

    def add(self, what: str, now: float) -> None:
        self.counts[what] += 1
        self.flush(now)

    def flush(self, now: float, *, last: bool = False) -> None:
        """Log the counts if the interval has passed (``last``: whatever the interval, at the end)."""
        if not self.counts or (now - self.logged_at < LOG_INTERVAL_S and not last):
            return
        first = self.logged_at == float("-inf")
        since = "" if first else f" in the last {now - self.logged_at:.0f} s"
        what = ", ".join(f"{n} {text}" for text, n in self.counts.most_common())
        log.warning("connections: %s%s (%s)", what, since, self.describe())
        self.counts.clear()
        self.logged_at = now


class Connections:
    """The open connections, oldest idle first to shed; ``pending``: accepted, not yet connected."""

    def __init__(self) -> None:
        self.handlers: Dict["BoundedRequestHandler", None] = {}  # an ordered set
        self.pending = 0

    def __len__(self) -> int:
        return len(self.handlers) + self.pending

    def add(self, handler: "BoundedRequestHandler") -> None:
        self.handlers[handler] = None

    def discard(self, handler: "BoundedRequestHandler") -> None:
        self.handlers.pop(handler, None)

    def oldest_idle(self) -> Optional["BoundedRequestHandler"]:
        idle = [h for h in self.handlers if h.idle_since is not None and h.transport is not None]
        return min(idle, key=lambda h: h.idle_since or 0.0) if idle else None


class BoundedRequestHandler(RequestHandler):
    """aiohttp's connection, which knows whether it waits on its client (and since when).

    ``idle_since``: loop time since which no request is being handled (None while one is);
    ``head_since``: since when a request's head is owed (the connection's opening, or the first
    byte after a request); ``last_data``: the last byte received. :meth:`overdue` says which
    timeout, if any, has run out.
    """

    def __init__(self, manager: web.Server, *, loop: asyncio.AbstractEventLoop, table: Connections,
                 limits: ConnectionLimits, **kwargs: Any) -> None:
        super().__init__(manager, loop=loop, **kwargs)
        self.table = table
        self.limits = limits
        now = loop.time()
        self.idle_since: Optional[float] = now
        self.head_since: Optional[float] = now
        self.last_data = now
        self.request: Optional[BaseRequest] = None

    def connection_lost(self, exc: Optional[BaseException]) -> None:
        self.table.discard(self)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        now = self._loop.time()
        self.last_data = now
        if self.request is None and self.head_since is None:
            self.head_since = now  # the first byte of the next request: its head is owed from now
        super().data_received(data)

    async def _handle_request(self, request: BaseRequest, start_time: Optional[float],
                              request_handler: RequestHandlerFn) -> Tuple[web.StreamResponse, bool]:
        self.request, self.idle_since, self.head_since = request, None, None
        refuse = _declares_too_much(request, self.limits.max_body)
        try:
            handler = _refuse_too_large(self.limits.max_body) if refuse else request_handler
            return await super()._handle_request(request, start_time, handler)
        finally:
            self.request, self.idle_since = None, self._loop.time()
            if refuse:
                self.force_close()  # its client waits for a 100 that will not come: no body follows

    def overdue(self, now: float) -> Optional[str]:
        """The timeout that has run out for this connection (``header``, ``body``, ``idle``), or None."""
        request = self.request
        if request is None:
            if self.head_since is not None and now - self.head_since > self.limits.header_timeout_s:
                return "header"
            if self.idle_since is not None and now - self.idle_since > self.limits.keepalive_timeout_s:
                return "idle"
            return None
        # A body the handler waits for, that stopped coming. Reading paused is the daemon holding
        # the client back (its handler has not read what came), not the client stalling.
        paused = bool(getattr(self, "_reading_paused", False))
        if (not request.content.is_eof() and not paused
                and now - self.last_data > self.limits.header_timeout_s):
            return "body"
        return None


def _declares_too_much(request: BaseRequest, max_body: int) -> bool:
    expect = request.headers.get("Expect", "").lower()
    length = request.content_length
    return expect == "100-continue" and length is not None and length > max_body


def _refuse_too_large(limit: int) -> RequestHandlerFn:
    """The handler for a request that declared a body over ``limit``: 413, and the connection closes."""

    async def refuse(request: BaseRequest) -> web.StreamResponse:
        resp = json_error(413, too_large(limit, request.content_length))
        resp.force_close()
        return resp

    return refuse


class BoundedSite(web.BaseSite):
    """Listens on ``host:port`` and accepts connections itself, within :class:`ConnectionLimits`
    (see the module doc). Start and stop it as aiohttp's ``TCPSite``; ``port`` is the bound one."""

    def __init__(self, runner: web.BaseRunner, host: str, port: int, *, limits: ConnectionLimits,
                 backlog: int = 128, **handler_kwargs: Any) -> None:
        super().__init__(runner, backlog=backlog)
        self._host, self._port = host, port
        self.limits = limits
        self.cap = connection_cap(limits.max_connections)
        self.table = Connections()
        self._handler_kwargs = {"access_log_class": AccessLog, **handler_kwargs,
                                "keepalive_timeout": limits.keepalive_timeout_s}
        self._listeners: List[socket.socket] = []
        self._sweeper: Optional["asyncio.Task[None]"] = None
        self._resume: Optional[asyncio.TimerHandle] = None
        self._backoff = BACKOFF_MIN_S
        self.tally = Tally(self._describe)

    @property
    def name(self) -> str:
        host = f"[{self._host}]" if ":" in self._host else self._host
        return f"http://{host}:{self._port}"

    @property
    def port(self) -> int:
        return self._port

    def _describe(self) -> str:
        limits = self.limits
        return (f"{len(self.table)} open of at most {self.cap}, "
                f"header timeout {limits.header_timeout_s:g} s, keep-alive {limits.keepalive_timeout_s:g} s")

    async def start(self) -> None:
        await super().start()
        loop = asyncio.get_running_loop()
        self._listeners = _listen(self._host, self._port, self._backlog)  # OSError: the caller says why
        self._port = self._listeners[0].getsockname()[1]
        self._accepting(True)
        self._sweeper = loop.create_task(self._sweep(), name="stereocam-connections")
        if self.cap < self.limits.max_connections:
            log.info("at most %d connections (max_connections %d, lowered to stay below the fd limit of %d)",
                     self.cap, self.limits.max_connections, resource.getrlimit(resource.RLIMIT_NOFILE)[0])

    async def stop(self) -> None:
        self._accepting(False)
        if self._resume is not None:
            self._resume.cancel()
        for sock in self._listeners:
            sock.close()
        self._listeners = []
        if self._sweeper is not None:
            self._sweeper.cancel()
            await asyncio.gather(self._sweeper, return_exceptions=True)
        self.tally.flush(asyncio.get_running_loop().time(), last=True)
        await super().stop()

    # -- accepting ----------------------------------------------------------------------------------

    def _accepting(self, on: bool) -> None:
        loop = asyncio.get_running_loop()
        for sock in self._listeners:
            if on:
                loop.add_reader(sock.fileno(), self._on_readable, sock)
            else:
                loop.remove_reader(sock.fileno())

    def _on_readable(self, sock: socket.socket) -> None:
        """Accept what is waiting (up to :data:`ACCEPT_BATCH`); on ``EMFILE`` and the like, back off."""
        loop = asyncio.get_running_loop()
        for _ in range(ACCEPT_BATCH):
            try:
                conn, _addr = sock.accept()
            except (BlockingIOError, InterruptedError):
                self._backoff = BACKOFF_MIN_S
                return
            except ConnectionAbortedError:
                continue
            except OSError as exc:
                if exc.errno in OUT_OF_RESOURCES:
                    self._out_of_resources(exc)
                else:
                    self.tally.add(f"accept() failed ({exc.strerror or exc})", loop.time())
                return
            self._admit(conn)

    def _out_of_resources(self, exc: OSError) -> None:
        """Stop accepting for the back-off, free an fd by shedding the oldest idle connection."""
        loop = asyncio.get_running_loop()
        self._accepting(False)
        victim = self.table.oldest_idle()
        if victim is not None:
            self._shed(victim)
        lacking = "fd" if exc.errno in (errno.EMFILE, errno.ENFILE) else "memory"
        self.tally.add(f"times accept() found no {lacking} (accepting paused)", loop.time())
        if self._resume is None:
            self._resume = loop.call_later(self._backoff, self._resume_accepting)
        self._backoff = min(BACKOFF_MAX_S, self._backoff * 2)

    def _resume_accepting(self) -> None:
        self._resume = None
        if self._listeners:
            self._accepting(True)

    def _shed(self, handler: BoundedRequestHandler) -> None:
        self.table.discard(handler)  # its fd is free as far as the cap counts, from now
        handler.force_close()

    def _admit(self, conn: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        if len(self.table) >= self.cap:
            victim = self.table.oldest_idle()
            if victim is None:
                conn.close()
                self.tally.add("refused (every connection busy)", loop.time())
                return
            self._shed(victim)
            self.tally.add("idle shed for newer ones", loop.time())
        conn.setblocking(False)
        self.table.pending += 1
        loop.create_task(self._connect(conn))

    async def _connect(self, conn: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        server = self._runner.server
        assert server is not None

        made: List[BoundedRequestHandler] = []

        def handler() -> BoundedRequestHandler:  # from pending to the table: counted once all along
            h = BoundedRequestHandler(server, loop=loop, table=self.table, limits=self.limits,
                                      **self._handler_kwargs)
            made.append(h)
            self.table.add(h)
            self.table.pending -= 1
            return h

        try:
            await loop.connect_accepted_socket(handler, conn)
        except OSError:
            conn.close()
            if made:
                self.table.discard(made[0])
            else:
                self.table.pending -= 1

    # -- timeouts -----------------------------------------------------------------------------------

    async def _sweep(self) -> None:
        """Close the connections whose timeout has run out (every :func:`sweep_period`)."""
        loop = asyncio.get_running_loop()
        period = sweep_period(self.limits)
        notes = {"header": "closed by the header timeout", "body": "closed: their body stalled"}
        while True:
            await asyncio.sleep(period)
            now = loop.time()
            for h in list(self.table.handlers):
                why = h.overdue(now)
                if why is None:
                    continue
                self._shed(h)
                if why in notes:  # an idle keep-alive closing is ordinary: browsers reopen
                    self.tally.add(notes[why], now)
            self.tally.flush(now)


def _listen(host: str, port: int, backlog: int) -> List[socket.socket]:
    """Listening sockets for ``host`` (every address it resolves to; port 0: one free port for all)."""
    infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    out: List[socket.socket] = []
    try:
        for family, kind, proto, _, addr in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            out.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            if port == 0 and len(out) > 1:
                addr = (addr[0], out[0].getsockname()[1], *addr[2:])
            sock.bind(addr)
            sock.listen(backlog)
            sock.setblocking(False)
    except OSError:
        for sock in out:
            sock.close()
        raise
    return out
