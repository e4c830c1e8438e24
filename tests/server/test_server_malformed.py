"""Malformed requests get a one-line 4xx, never a 500 or a traceback in the log."""
from __future__ import annotations

import asyncio
import logging
from typing import Tuple

import aiohttp
import pytest

from stereocam.server.http import routes_calibration, routes_calibration_panel, routes_cameras

from .daemon import wait_for_frames  # noqa: F401

EXT = (routes_calibration.setup, routes_calibration_panel.setup, routes_cameras.setup)
DEEP = b"[" * 100_000 + b"]" * 100_000
JSON_ENDPOINTS = [
    ("PUT", "/api/source"), ("PUT", "/api/calibration"), ("PUT", "/api/calibration/session"),
    ("POST", "/api/calibration/compute"), ("POST", "/api/calibration/apply"), ("PUT", "/api/cameras"),
]


async def raw_request(port: int, data: bytes) -> Tuple[int, bytes]:
    """Send bytes as they are (no client library fixes them up); the status and body of the answer."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(data)
    await writer.drain()
    answer = await asyncio.wait_for(reader.read(), 30)
    writer.close()
    head, _, body = answer.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), body


@pytest.fixture
def tracebacks(caplog: pytest.LogCaptureFixture):
    caplog.set_level(logging.INFO)
    yield lambda: [r for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]


async def test_deeply_nested_json_is_a_400_on_every_json_endpoint(start_daemon, tracebacks) -> None:
    d = await start_daemon(extensions=EXT)
    for method, path in JSON_ENDPOINTS:
        async with d.http.request(method, path, data=DEEP, headers={"Content-Type": "application/json"}) as r:
            body = await r.json()
            assert 400 <= r.status < 500, (method, path, r.status, body)
            assert "\n" not in body["error"]
    async with d.http.ws_connect("/ws") as ws:  # the WebSocket's JSON requests too
        await ws.send_str(DEEP.decode())
        msg = await ws.receive(timeout=30)
        assert msg.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.CLOSE), msg
        assert "JSON" in (msg.data if msg.type == aiohttp.WSMsgType.TEXT else msg.extra or "JSON")
    await wait_for_frames(d, 2)  # healthz: frames still flow
    async with d.http.get("/healthz") as r:
        assert r.status == 200
    assert tracebacks() == []


async def test_a_multipart_part_header_over_8_kb_is_a_400(start_daemon, tracebacks) -> None:
    d = await start_daemon()
    body = (b'--b\r\nContent-Disposition: form-data; name="left"; filename="a.png"\r\nX-Pad: ' + b"a" * 9000
            + b"\r\n\r\nxx\r\n--b--\r\n")
    status, answer = await raw_request(d.port, b"POST /api/virtual-camera HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                                       b"Content-Type: multipart/form-data; boundary=b\r\nContent-Length: "
                                       + str(len(body)).encode() + b"\r\nConnection: close\r\n\r\n" + body)
    assert status == 400 and b"malformed request" in answer, answer[:300]
    assert tracebacks() == []


async def test_authorization_that_is_not_utf8_is_a_401(start_daemon, tracebacks) -> None:
    d = await start_daemon(access_token="open-sesame")
    request = (b"PUT /api/source HTTP/1.1\r\nHost: 127.0.0.1\r\n"
               b"Authorization: Bearer \xff\xfe\x80\r\nContent-Type: application/json\r\n"
               b"Content-Length: 19\r\nConnection: close\r\n\r\n"
               b'{"source": "live"}\n')
    status, answer = await raw_request(d.port, request)
    assert status == 401 and b"needs the access token" in answer, answer
    assert tracebacks() == []


@pytest.mark.parametrize("line", [
    b"GARBAGE\r\n\r\n", b"GET /\x00\x01 HTTP/1.1\r\nHost: x\r\n\r\n",
    b"GET / HTTP/9.9\r\nHost: x\r\n\r\n", b"GET / HTTP/1.1\r\nBad Header\r\n\r\n",
])
async def test_malformed_request_lines_are_a_400_and_one_log_line(
    start_daemon, tracebacks, caplog, line
) -> None:
    d = await start_daemon()
    status, _ = await raw_request(d.port, line)
    assert status == 400
    assert tracebacks() == []
    await wait_for_frames(d, 2)  # healthz: frames still flow
    async with d.http.get("/healthz") as r:
        assert r.status == 200


async def test_a_mux_that_does_not_commit_is_a_503_and_the_daemon_carries_on(
    start_daemon, tracebacks
) -> None:
    d = await start_daemon()
    d.overlay.emulation.mux.hang_update = True
    try:
        async with d.http.put("/api/source", json={"source": "live"}) as r:
            body = await r.json()
        assert r.status == 503, body
        assert body["error"].startswith("the mux did not switch to live (") and "\n" not in body["error"]
    finally:
        d.overlay.emulation.mux.hang_update = False
    async with d.http.put("/api/source", json={"source": "live"}) as r:
        assert r.status == 200, await r.text()
    async with d.http.get("/api/status") as r:
        assert (await r.json())["mux"] == "live"
    assert tracebacks() == []
