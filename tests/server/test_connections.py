"""Connections are bounded (stereocam/server/http/connections.py): what idle, slow and departed clients get.

- A socket that sends nothing, half a header, a header a byte at a time, or half a body is closed
  after ``header_timeout_s``, while an MJPEG stream and a WebSocket that send nothing go on
  getting frames; a body that keeps coming is read whole.
- An idle keep-alive connection serves the next request, and closes after ``keepalive_timeout_s``.
- At ``max_connections``, a new connection sheds the one idle the longest; when every one is busy
  (streams), the new one is closed and the streams go on.
- ``accept()`` failing for want of fds pauses accepting and is logged once, not once per try.
- A state-changing request whose client has already gone away is not acted on.

Each wait here waits for its condition; the bounds are last resorts that only a hang reaches.
The daemon closes an overdue connection within its sweep period (0.5 s at most) of the timeout;
that figure is the daemon's design, not asserted here: a loaded machine may take longer.
"""
from __future__ import annotations

import asyncio
import errno
import json
import logging
import struct
import time
from typing import List, Tuple

from aiohttp import WSMsgType, web

from stereocam.server.http.connections import BoundedSite, ConnectionLimits
from stereocam.server.http.state import CAPTURES

from .daemon import WAIT_S, read_parts, wait_for_frames  # noqa: F401

Conn = Tuple[asyncio.StreamReader, asyncio.StreamWriter]


async def connect(d) -> Conn:
    return await asyncio.open_connection("127.0.0.1", d.port)


async def closed_by_daemon(conn: Conn, timeout: float = WAIT_S) -> bool:
    """Wait until the daemon closes ``conn`` (EOF or reset); False if it is still open at ``timeout``."""
    reader, _ = conn
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            data = await asyncio.wait_for(reader.read(65536), deadline - time.monotonic())
            if not data:
                return True
    except (ConnectionError, asyncio.TimeoutError) as exc:
        return isinstance(exc, ConnectionError)
    return False


def request(path: str, method: str = "GET", extra: str = "", body: bytes = b"") -> bytes:
    head = f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{extra}"
    if body or method != "GET":
        head += f"Content-Length: {len(body)}\r\n"
    return (head + "\r\n").encode() + body


async def answer(conn: Conn, timeout: float = WAIT_S) -> Tuple[int, bytes]:
    """Read one response with a Content-Length from ``conn``: (status, body)."""
    reader, _ = conn
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), timeout)
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.lower(): v for k, _, v in (line.partition(": ") for line in lines[1:])}
    length = int(headers["content-length"])
    body = await asyncio.wait_for(reader.readexactly(length), timeout)
    return int(lines[0].split()[1]), body


def close(conns: List[Conn]) -> None:
    for _, writer in conns:
        writer.close()


async def next_ws_frame(ws) -> int:
    msg = await ws.receive(timeout=WAIT_S)
    assert msg.type == WSMsgType.BINARY, msg
    (n,) = struct.unpack(">I", msg.data[:4])
    return int(json.loads(msg.data[4:4 + n])["frame"])


# -- timeouts ----------------------------------------------------------------------------------------

async def test_silent_half_sent_and_dribbling_requests_are_closed_while_streams_go_on(start_daemon,
                                                                                      caplog) -> None:
    caplog.set_level(logging.INFO, "stereocam.server.http.connections")
    d = await start_daemon(header_timeout_s=1.0)
    await wait_for_frames(d)
    stream = await d.http.get("/stream/rect_left?fps=10")
    assert stream.status == 200
    ws = await d.session().ws_connect("/ws")
    await ws.send_str(json.dumps({"views": ["rect_right"], "fps": 10}))
    await next_ws_frame(ws)

    silent = [await connect(d) for _ in range(30)]
    half_header = await connect(d)
    half_header[1].write(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    half_body = await connect(d)
    half_body[1].write(b"PUT /api/source HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                       b"Content-Length: 100\r\n\r\n{\"sou")
    dribble = await connect(d)

    async def dribbling() -> None:  # a byte every 0.1 s: each is progress, the head never ends
        try:
            dribble[1].write(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            for _ in range(int(WAIT_S / 0.1)):
                dribble[1].write(b"a")
                await dribble[1].drain()
                await asyncio.sleep(0.1)
        except ConnectionError:
            pass

    writer = asyncio.get_running_loop().create_task(dribbling())
    try:
        others = [("half a header", half_header), ("half a body", half_body), ("dribbling", dribble)]
        for what, conn in [("silent", c) for c in silent] + others:
            assert await closed_by_daemon(conn), f"a {what} connection is still open after {WAIT_S} s"
    finally:
        writer.cancel()
        close(silent + [half_header, half_body, dribble])

    # The clients being answered sent nothing all along: still served, frames still coming.
    first = (await read_parts(stream, 1))[0][0]["x-frame-number"]
    later = (await read_parts(stream, 3))[-1][0]["x-frame-number"]
    assert int(later) > int(first)
    a = await next_ws_frame(ws)
    assert await next_ws_frame(ws) > a
    async with d.http.get("/api/source") as resp:
        assert resp.status == 200
    stream.close()
    await ws.close()
    lines = [r for r in caplog.records if r.name.endswith("connections")]
    texts = [r.getMessage() for r in lines]
    assert 1 <= len(texts) <= 3, texts  # a summary, not a line per socket
    assert any("closed by the header timeout" in text for text in texts), texts


async def test_a_body_that_keeps_coming_is_read_whole(start_daemon) -> None:
    """Slower than the header timeout in all, but never stalled: the upload is answered. (The timeout
    is 8 s against 4 bytes every 0.2 s: only an 8 s stall of this very process could close it.)"""
    d = await start_daemon(header_timeout_s=8.0)
    body = json.dumps({"source": "live"}).encode() + b" " * 180
    conn = await connect(d)
    conn[1].write(request("/api/source", "PUT", "Content-Type: application/json\r\n", body)[:-len(body)])
    t0 = time.monotonic()
    for i in range(0, len(body), 4):  # 50 pieces: 10 s of body, 4 bytes every 0.2 s
        conn[1].write(body[i:i + 4])
        await asyncio.sleep(0.2)
    status, text = await answer(conn)
    assert status == 200, text
    assert time.monotonic() - t0 > 8.0  # it did take longer than the header timeout
    close([conn])


async def test_an_idle_keep_alive_connection_serves_the_next_request_then_closes(start_daemon) -> None:
    d = await start_daemon(header_timeout_s=30.0, keepalive_timeout_s=3.0)
    conn = await connect(d)
    conn[1].write(request("/api/source"))
    assert (await answer(conn))[0] == 200
    conn[1].write(request("/api/source"))  # the same connection, at once
    assert (await answer(conn))[0] == 200
    assert await closed_by_daemon(conn)  # idle for its keep-alive timeout (aiohttp's own: an hour)
    close([conn])


# -- the cap ---------------------------------------------------------------------------------------------

async def test_past_max_connections_the_oldest_idle_one_is_shed(start_daemon) -> None:
    d = await start_daemon(max_connections=6, header_timeout_s=120.0, keepalive_timeout_s=120.0)
    idle = []
    for _ in range(6):  # one after the other, each idle from its answer on
        conn = await connect(d)
        conn[1].write(request("/api/source"))
        assert (await answer(conn))[0] == 200
        idle.append(conn)
    newcomer = await connect(d)
    newcomer[1].write(request("/api/source"))
    assert (await answer(newcomer))[0] == 200
    assert await closed_by_daemon(idle[0]), "the oldest idle connection was not shed"
    for conn in idle[2:]:  # the newer ones serve on (the newcomer's answer may have shed idle[1] too)
        conn[1].write(request("/api/source"))
        assert (await answer(conn))[0] == 200
    close(idle + [newcomer])


async def test_when_every_connection_is_busy_a_new_one_is_closed_and_the_streams_go_on(start_daemon) -> None:
    d = await start_daemon(max_connections=4)
    await wait_for_frames(d)
    http = d.session()
    streams = [await http.get("/stream/rect_left?fps=10") for _ in range(4)]
    for s in streams:
        assert s.status == 200
        await read_parts(s, 1)
    conn = await connect(d)
    conn[1].write(request("/api/source"))
    assert await closed_by_daemon(conn), "a connection past the cap was served while every one is busy"
    for s in streams:
        numbers = [int(h["x-frame-number"]) for h, _ in await read_parts(s, 2)]
        assert numbers[1] > numbers[0]
        s.close()
    close([conn])


# -- out of fds ------------------------------------------------------------------------------------------

class NoFds:
    """A listening socket's stand-in whose every ``accept()`` fails as at the fd limit."""

    def __init__(self) -> None:
        self.calls = 0

    def accept(self) -> None:
        self.calls += 1
        raise OSError(errno.EMFILE, "Too many open files")


async def test_accept_out_of_fds_backs_off_logs_once_and_serves_again(caplog) -> None:
    caplog.set_level(logging.INFO, "stereocam.server.http.connections")

    async def hello(request: web.Request) -> web.Response:
        return web.Response(text="hello")

    app = web.Application()
    app.router.add_get("/", hello)
    runner = web.AppRunner(app)
    await runner.setup()
    site = BoundedSite(runner, "127.0.0.1", 0, limits=ConnectionLimits())
    await site.start()
    try:
        fake = NoFds()
        for _ in range(2000):  # the readiness events of a busy second at the fd limit
            site._on_readable(fake)  # type: ignore[arg-type]
        assert fake.calls == 2000  # one accept() per event, not a batch of failing ones each
        lines = [r.getMessage() for r in caplog.records
                 if r.name.endswith("connections") and r.levelno >= logging.WARNING]
        assert len(lines) == 1 and "accept() found no fd" in lines[0], lines
        reader, writer = await asyncio.open_connection("127.0.0.1", site.port)  # accepted after the pause
        writer.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), WAIT_S)
        assert head.startswith(b"HTTP/1.1 200")
        writer.close()
    finally:
        await runner.cleanup()


# -- a client that went away ------------------------------------------------------------------------

async def test_a_request_whose_client_went_away_is_not_acted_on(start_daemon) -> None:
    """The request and the client's FIN wait together when the daemon reads them (a client that gave
    up on a daemon too busy to accept): no recording nobody knows the id of, no capture."""
    d = await start_daemon()
    await wait_for_frames(d)
    for path in ("/api/recordings", "/api/captures"):
        reader, writer = await connect(d)
        writer.write(request(path, "POST"))
        writer.write_eof()  # gone (FIN) before the daemon read a byte: this test runs on the daemon's loop
        got = await asyncio.wait_for(reader.read(), WAIT_S)  # until the daemon is done with it
        assert got == b"" or got.startswith(b"HTTP/1.1 400"), got[:200]
        writer.close()
    for _ in range(3):
        async with d.http.get("/api/source") as resp:
            assert resp.status == 200
    async with d.http.get("/api/recordings") as resp:
        doc = await resp.json()
    assert doc["recording"] is None and doc["recordings"] == [], doc
    assert list(d.app[CAPTURES].root.iterdir()) == []
