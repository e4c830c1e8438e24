"""Safety over HTTP: same-origin state changes, the access token, body limits."""
from __future__ import annotations

import pytest

from stereocam.server.http.state import CAPTURES

from .server_fixtures import start_daemon_fixture  # noqa: F401

TOKEN = "s3cret-token-123"


async def test_state_changes_from_another_origin_are_403(start_daemon) -> None:
    d = await start_daemon()
    host = f"127.0.0.1:{d.port}"
    for headers in ({"Origin": "http://evil.example"}, {"Origin": "null"}, {"Origin": f"https://{host}"},
                    {"Origin": "http://127.0.0.1:1"}, {"Sec-Fetch-Site": "cross-site"},
                    {"Sec-Fetch-Site": "same-site"}):
        for method, path, kwargs in (("POST", "/api/captures", {}),
                                     ("PUT", "/api/source", {"json": {"source": "live"}}),
                                     ("DELETE", "/api/captures/20260101T000000Z-000001-abcd", {}),
                                     ("POST", "/api/verify", {})):
            async with d.http.request(method, path, headers=headers, **kwargs) as resp:
                assert resp.status == 403, (headers, method, path)
                error = (await resp.json())["error"]
                assert "another origin" in error and "\n" not in error
    assert list(d.app[CAPTURES].root.iterdir()) == []
    for headers in ({"Origin": f"http://{host}"},
                    {"Origin": f"http://localhost:{d.port}", "Host": f"localhost:{d.port}"},
                    {"Sec-Fetch-Site": "same-origin"}, {}):
        async with d.http.put("/api/source", json={"source": "live"}, headers=headers) as resp:
            assert resp.status == 200, headers
    async with d.http.get("/api/status", headers={"Origin": "http://evil.example"}) as resp:
        assert resp.status == 200  # reads stay open


async def test_access_token_guards_every_state_change(start_daemon) -> None:
    d = await start_daemon(access_token=TOKEN, protect="control")
    changes = (("POST", "/api/captures", {}), ("PUT", "/api/source", {"json": {"source": "live"}}),
               ("POST", "/api/virtual-camera", {"json": {"capture": "20260101T000000Z-000001-abcd"}}),
               ("POST", "/api/verify", {}), ("DELETE", "/api/captures/20260101T000000Z-000001-abcd", {}))
    for method, path, kwargs in changes:
        for headers in ({}, {"Authorization": "Bearer wrong-token-000"}, {"X-Stereocam-Token": "nope"},
                        {"Authorization": f"Basic {TOKEN}"}):
            async with d.http.request(method, path, headers=headers, **kwargs) as resp:
                assert resp.status == 401, (method, path, headers)
                assert resp.headers["WWW-Authenticate"].startswith("Bearer")
                assert "access token" in (await resp.json())["error"]
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    async with d.http.put("/api/source", json={"source": "live"}, headers=bearer) as resp:
        assert resp.status == 200
    async with d.http.post("/api/captures", headers={"X-Stereocam-Token": TOKEN}) as resp:
        assert resp.status == 201
    for path in ("/api/status", "/api/captures", "/api/source", "/metrics", "/healthz",
                 "/snapshot/rect_left.jpg"):
        async with d.http.get(path) as resp:
            assert resp.status == 200, path
    async with d.http.get("/api/status") as resp:
        status = await resp.json()
    assert status["access_token"] is True and TOKEN not in str(status)


async def test_declared_oversized_bodies_are_refused_before_reading(start_daemon) -> None:
    d = await start_daemon(max_upload_bytes=10_000)
    async with d.http.post("/api/captures", data=b"x" * 20_000) as resp:
        assert resp.status == 413
        assert "10000 bytes" in (await resp.json())["error"]


@pytest.mark.parametrize("origin,expected", [
    ("http://127.0.0.1:{port}", True), ("http://127.0.0.1:{port}/", True), ("HTTP://127.0.0.1:{port}", True),
    ("http://127.0.0.1", False), ("ftp://127.0.0.1:{port}", False), ("http://[::1", False), ("", False),
])
async def test_origin_matching(start_daemon, origin, expected) -> None:
    d = await start_daemon()
    async with d.http.put("/api/source", json={"source": "live"},
                          headers={"Origin": origin.format(port=d.port)}) as resp:
        assert (resp.status == 200) is expected, (origin, resp.status)


async def test_with_protect_all_every_read_needs_the_token_too(start_daemon) -> None:
    """The default: a token guards streams, snapshots, captures, status and /ws, not the page or /healthz."""
    d = await start_daemon(access_token=TOKEN)
    async with d.http.post("/api/captures", headers={"X-Stereocam-Token": TOKEN}) as resp:
        assert resp.status == 201
        capture = (await resp.json())["id"]
    reads = ("/api/status", "/api/captures", f"/api/captures/{capture}", "/api/source", "/metrics",
             "/snapshot/rect_left.jpg", "/api/calibration", "/ws")
    for path in reads:
        for headers in ({}, {"Authorization": "Bearer wrong-token-000"}, {"Cookie": "stereocam_token=nope"}):
            async with d.http.get(path, headers=headers) as resp:
                assert resp.status in (401, 404), (path, headers, resp.status)  # 404: a route not installed
                if resp.status == 401:
                    assert "needs the access token" in (await resp.json())["error"]
    async with d.http.get("/stream/rect_left", headers={"Cookie": "stereocam_token=nope"}) as resp:
        assert resp.status == 401
    for how in ({"headers": {"Authorization": f"Bearer {TOKEN}"}},
                {"headers": {"Cookie": f"stereocam_token={TOKEN}"}}, {"params": {"token": TOKEN}}):
        async with d.http.get("/api/status", **how) as resp:
            assert resp.status == 200, how
        async with d.http.get("/snapshot/rect_left.jpg", **how) as resp:
            assert resp.status == 200, how
    async with d.http.ws_connect("/ws", headers={"Cookie": f"stereocam_token={TOKEN}"}) as ws:
        assert not ws.closed
    for path in ("/", "/healthz", "/static/js/main.js"):
        async with d.http.get(path) as resp:
            assert resp.status in (200, 503), path  # healthz: 503 before the first frame, never 401


@pytest.mark.parametrize("host", ["evil.example", "evil.example:{port}", "localhost.evil.example",
                                  "127.0.0.1.nip.io", "[::1", "a b"])
async def test_a_host_that_is_not_ours_is_refused(start_daemon, host) -> None:
    """DNS rebinding: the attacker's name arrives in Host; reads and changes alike get 421."""
    d = await start_daemon()
    header = {"Host": host.format(port=d.port)}
    for method, path in (("GET", "/api/status"), ("GET", "/snapshot/rect_left.jpg"), ("GET", "/"),
                         ("PUT", "/api/source")):
        async with d.http.request(method, path, headers=header, json={"source": "live"}) as resp:
            assert resp.status == 421, (method, path, resp.status)
            assert "not a name of this daemon" in (await resp.json())["error"]


async def test_our_names_and_ip_literals_are_accepted(start_daemon) -> None:
    d = await start_daemon(allowed_hosts=["stereo-board.lan"])
    for host in ("127.0.0.1:{port}", "localhost:{port}", "LOCALHOST", "[::1]:{port}", "192.168.1.77:8080",
                 "stereo-board.lan:{port}", "stereo-board.lan."):
        async with d.http.get("/api/source", headers={"Host": host.format(port=d.port)}) as resp:
            assert resp.status == 200, host


def test_listening_everywhere_adds_the_machines_own_names() -> None:
    import socket

    from stereocam.server.http.security import allowed_host_names

    names = allowed_host_names("0.0.0.0", ["Board.Example"])
    hostname = socket.gethostname().lower()
    assert {hostname, f"{hostname}.local", "localhost", "board.example"} <= names
    assert "0.0.0.0" not in names
    loopback = {"localhost", "localhost.localdomain", "ip6-localhost", "127.0.0.1"}
    assert allowed_host_names("127.0.0.1") == loopback
