"""Safety over HTTP: same-origin state changes, the access token (one rule wherever it arrives, the
page's cookie set by the server, every GET taking ?token=, never in the log), body limits."""
from __future__ import annotations

import asyncio
import io
import logging
import re
from urllib.parse import quote

import aiohttp
import pytest
from yarl import URL

from stereocam.server.http.app import default_extensions
from stereocam.server.http.state import CAPTURES

from .daemon import WAIT_S, wait_for_frames  # noqa: F401

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
    """The default: a token guards streams, snapshots, captures, status and /ws, not the page (nor the
    view registry it is built from) or /healthz."""
    d = await start_daemon(access_token=TOKEN, extensions=default_extensions())  # production's routes
    await wait_for_frames(d)
    async with d.http.post("/api/captures", headers={"X-Stereocam-Token": TOKEN}) as resp:
        assert resp.status == 201
        capture = (await resp.json())["id"]
    reads = ("/api/status", "/api/captures", f"/api/captures/{capture}", "/api/source", "/metrics",
             "/snapshot/rect_left.jpg", "/api/calibration", "/ws")
    for path in reads:
        for headers in ({}, {"Authorization": "Bearer wrong-token-000"}, {"Cookie": "stereocam_token=nope"}):
            async with d.http.get(path, headers=headers) as resp:
                assert resp.status == 401, (path, headers, resp.status)
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
    for path in ("/", "/healthz", "/static/js/main.js", "/api/views"):
        async with d.http.get(path) as resp:
            assert resp.status == 200, path  # frames flow (healthz would be 503 before the first), never 401


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


# -- the token: one rule wherever it arrives ----------------------------------------------------------

ODD_TOKEN = "a+b/c=d+e/f=="  # what base64 tokens look like: each of + / = once and again


async def test_a_token_with_plus_slash_and_equals_works_wherever_it_arrives(start_daemon) -> None:
    d = await start_daemon(access_token=ODD_TOKEN)
    encoded = quote(ODD_TOKEN, safe="")
    ways = {  # name: (headers, query)
        "bearer": ({"Authorization": f"Bearer {ODD_TOKEN}"}, ""),
        "x-header": ({"X-Stereocam-Token": ODD_TOKEN}, ""),
        "cookie as sent": ({"Cookie": f"stereocam_token={ODD_TOKEN}"}, ""),
        "cookie URI-encoded (what the page's script wrote)": ({"Cookie": f"stereocam_token={encoded}"}, ""),
        "query as typed": ({}, f"?token={ODD_TOKEN}"),
        "query encoded": ({}, f"?token={encoded}"),
    }
    for name, (headers, suffix) in ways.items():
        for path in ("/api/status", "/snapshot/rect_left.jpg"):
            async with d.http.get(URL(path + suffix, encoded=True), headers=headers) as resp:
                assert resp.status == 200, (name, path, resp.status)
    for wrong in ("a%20b/c=d%20e/f==", "a%20b/c=d+e/f==", ODD_TOKEN[:-1], ODD_TOKEN + "x"):  # + no space
        async with d.http.get(URL(f"/api/status?token={wrong}", encoded=True)) as resp:
            assert resp.status == 401, wrong


async def test_the_page_url_token_becomes_the_servers_httponly_cookie_and_leaves_the_url(start_daemon
                                                                                          ) -> None:
    d = await start_daemon(access_token=ODD_TOKEN, protect="control")
    page = URL(f"/?fps=30&token={quote(ODD_TOKEN, safe='')}&view=sbs", encoded=True)
    async with d.http.get(page, allow_redirects=False) as resp:
        assert resp.status == 303
        assert resp.headers["Location"] == "/?fps=30&view=sbs"
        cookies = {c.split("=", 1)[0]: c for c in resp.headers.getall("Set-Cookie")}
    token_cookie = cookies["stereocam_token"].lower()
    for attribute in ("httponly", "samesite=strict", "path=/", "max-age="):
        assert attribute in token_cookie, token_cookie
    # Earlier daemons' script-readable cookie is removed, not set: nothing a script reads tells of the token.
    assert "max-age=0" in cookies["stereocam_has_token"].lower()
    assert ODD_TOKEN not in cookies["stereocam_token"]  # percent-encoded: a legal cookie value as it is
    # A browser sends it back: changes (same origin) and reads go through with it alone.
    jar = d.session(cookie_jar=aiohttp.CookieJar(unsafe=True))  # unsafe: keeps cookies of an IP address
    async with jar.get(page) as resp:  # follows the redirect, keeps the cookies
        assert resp.status == 200 and resp.url.query_string == "fps=30&view=sbs"
    async with jar.post("/api/captures", headers={"Origin": f"http://127.0.0.1:{d.port}"}) as resp:
        assert resp.status == 201, await resp.text()
    async with jar.post("/api/captures", headers={"Origin": "http://evil.example"}) as resp:
        assert resp.status == 403  # another origin's page: refused before the cookie counts
    async with jar.get(URL("/?token=", encoded=True), allow_redirects=False) as resp:
        assert resp.status == 303 and resp.headers["Location"] == "/"
        assert all("max-age=0" in c.lower() for c in resp.headers.getall("Set-Cookie"))
    async with jar.get("/", allow_redirects=False):
        pass
    async with jar.post("/api/captures") as resp:
        assert resp.status == 401  # forgotten
    # A change never takes the token from a link: ?token= is for readers that cannot send headers.
    async with d.http.post(URL(f"/api/captures?token={quote(ODD_TOKEN, safe='')}", encoded=True)) as resp:
        assert resp.status == 401


GET_SAMPLES = {"view": "rect_left", "fmt": "jpg", "side": "left", "path": "js/main.js", "frame": "1",
               "file": "meta.json"}


async def test_every_get_accepts_the_token_in_the_url(start_daemon) -> None:
    """API.md: with protect: all, every read takes ?token=; no GET's own parameter check refuses it."""
    from stereocam.server.http.app import default_extensions

    d = await start_daemon(access_token=TOKEN, extensions=default_extensions())
    async with d.http.post("/api/captures", headers={"X-Stereocam-Token": TOKEN}) as resp:
        capture = (await resp.json())["id"]
    samples = {**GET_SAMPLES, "id": capture}
    paths = []
    for route in d.app.router.routes():
        if route.method != "GET":
            continue
        canonical = route.resource.canonical if route.resource is not None else ""
        paths.append(re.sub(r"\{(\w+)[^}]*\}", lambda m: samples.get(m.group(1), "x"), canonical))
    assert "/api/point" in paths and "/stream/rect_left" in paths
    for path in paths:
        async with d.http.get(path, params={"token": TOKEN}) as resp:
            error = (await resp.json())["error"] if resp.status >= 400 else ""
            assert resp.status != 401 and "token" not in error, (path, resp.status, error)
        async with d.http.get(path) as resp:
            if (path not in ("/", "/healthz", "/api/views", "/signin", "/api/session")
                    and not path.startswith("/static/")):
                assert resp.status == 401, (path, resp.status)
    async with d.http.get("/api/point", params={"x": "3", "y": "4", "token": TOKEN}) as resp:
        assert resp.status == 200, await resp.text()


# -- Expect: 100-continue ----------------------------------------------------------------------------

async def test_expect_continue_over_the_limit_gets_413_before_any_100(start_daemon) -> None:
    d = await start_daemon(max_upload_bytes=10_000)
    reader, writer = await asyncio.open_connection("127.0.0.1", d.port)
    writer.write(b"POST /api/virtual-camera HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: image/png\r\n"
                 b"Content-Length: 1000000000\r\nExpect: 100-continue\r\n\r\n")
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), WAIT_S)
    assert head.startswith(b"HTTP/1.1 413"), head
    rest = await asyncio.wait_for(reader.read(), WAIT_S)  # the body, then the daemon closes
    assert b"1000000000 bytes" in rest and b"10000 bytes" in rest, rest
    writer.close()
    # Within the limit the client is told to go on, and is answered.
    async with d.http.put("/api/source", json={"source": "live"}, expect100=True) as resp:
        assert resp.status == 200


# -- the log ------------------------------------------------------------------------------------------

async def test_the_access_log_redacts_every_token(start_daemon, caplog) -> None:
    caplog.set_level(logging.DEBUG)
    caplog.set_level(logging.DEBUG, logger="aiohttp.access")
    d = await start_daemon(access_token=ODD_TOKEN)
    encoded = quote(ODD_TOKEN, safe="")
    for target in (f"/?token={encoded}", f"/snapshot/rect_left.jpg?token={encoded}&scale=0.5",
                   f"/api/status?token={ODD_TOKEN}", "/api/status?token=a-wrong-guess-000"):
        async with d.http.get(URL(target, encoded=True), allow_redirects=False,
                              headers={"Referer": f"http://127.0.0.1:{d.port}/?token={encoded}"}) as resp:
            await resp.read()
    access = [r.getMessage() for r in caplog.records if r.name == "aiohttp.access"]
    assert len(access) == 4 and all("token=<redacted>" in line for line in access), access
    assert "scale=0.5" in access[1]
    for secret in (ODD_TOKEN, encoded, "a-wrong-guess-000"):
        assert secret not in caplog.text


def test_the_log_handlers_filter_takes_the_token_out_of_any_record() -> None:
    from stereocam.server.http.security import TokenRedactor

    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.addFilter(TokenRedactor(ODD_TOKEN))
    logger = logging.getLogger("test.redactor")
    logger.addHandler(handler)
    logger.propagate = False
    try:
        logger.warning("refused a malformed request: %r", f"GET /stream/x?token={ODD_TOKEN} HTTP/1.1 junk")
        logger.warning("header %s", f"Bearer {ODD_TOKEN}")
        logger.warning("encoded %s", quote(ODD_TOKEN, safe=""))
        try:
            raise ValueError(f"bad token {ODD_TOKEN}")
        except ValueError:
            logger.exception("failed")
    finally:
        logger.removeHandler(handler)
    text = stream.getvalue()
    assert ODD_TOKEN not in text and quote(ODD_TOKEN, safe="") not in text, text
    assert text.count("<redacted>") >= 4 and "ValueError" in text
