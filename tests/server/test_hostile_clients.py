"""Hostile and slow clients: what the daemon does; how fast is ``stereocam bench robustness``'s.

- 2,000 malformed requests (:func:`stereocam.bench.malformed.malformed_requests`: uploads, JSON,
  YAML calibrations, headers, request lines, on every endpoint) and malformed WebSocket messages
  against ``stereocam serve`` run as a subprocess, as on the board: every one gets the 4xx it
  should, none a 5xx; the daemon's log holds no traceback; an MJPEG client watching all along
  gets frames throughout and after; the daemon's memory comes back within 50 MB of where it
  started; nothing any of them sent was taken (calibration, captures, settings).
- Bodies whose Content-Encoding does not decode: a 400, and no traceback in the log.
- The "billion laughs" in a calibration, three ways: a 400 that says why, the calibration unchanged.
- A slow reader: each frame it is sent is the newest the daemon has, and it skips what it missed.
- 300 idle sockets against the daemon at an fd limit of 256: ``/healthz`` answers after the header
  timeout, a stream goes on delivering, the log says so in a few lines.
- The access token, sent every way there is at ``log_level: debug``, is in no line of the log.
"""
from __future__ import annotations

import asyncio
import logging
import os
import resource
import signal
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import pytest

from stereocam.bench.alias_bomb import alias_bombs
from stereocam.bench.barrage import FLOOR_RSS_DELTA_MB, Barrage, run_barrage
from stereocam.bench.daemon_process import daemon, daemon_facts, log_tracebacks
from stereocam.bench.malformed import malformed_requests
from stereocam.bench.malformed_bodies import JSON_ENDPOINTS
from stereocam.bench.malformed_headers import corrupt_encoding_cases
from stereocam.bench.raw_http import get_json, send_raw
from stereocam.bench.rectify import bench_calibration
from stereocam.bench.serve import daemon_command, free_port, wait_healthy
from stereocam.calibration.file import Calibration
from stereocam.server.frames.encoders import EncoderKey
from stereocam.server.http import routes_calibration
from stereocam.server.http.state import ENCODERS, FEED, PIPELINE
from stereocam.server.http.streams import STREAMS

from .daemon import make_overlay  # noqa: F401

pytestmark = pytest.mark.slow

REQUESTS = 2000
TEST_FPS = 10.0  # the subprocess daemon's cameras: enough to see the stream flow, cheap on a shared machine
BOUND_S = 120.0  # a last resort against a hang: nothing here waits this long on a working daemon
SETTLE_S = 30.0  # the memory's time to come down after the barrage (freed memory goes back at once)


# -- 2,000 malformed requests against the daemon as a process -------------------------------------------

@dataclass
class Run:
    barrage: Barrage
    log: str
    calibration_before: Dict[str, Any]
    calibration_after: Dict[str, Any]
    captures: List[Any]
    signal_after: bool
    state_files: List[str]


@pytest.fixture(scope="module")
def hostile_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """The daemon (``stereocam serve``, token set, ``protect: control``) under :data:`REQUESTS` malformed
    requests; what it answered, logged and kept."""
    folder = tmp_path_factory.mktemp("hostile")
    log_path = folder / "daemon.log"
    with daemon(fps=TEST_FPS, log_path=log_path, folder=folder) as (proc, base):
        port = int(base.rsplit(":", 1)[1])

        async def run() -> Run:
            frame_size, calibration = await daemon_facts(port)
            before = await get_json(port, "/api/calibration")
            cases = malformed_requests(REQUESTS, frame_size=frame_size, calibration_yaml=calibration)
            barrage = await run_barrage(port, proc.pid, cases, settle_s=SETTLE_S)
            after = await get_json(port, "/api/calibration")
            captures = (await get_json(port, "/api/captures"))["captures"]
            status = await get_json(port, "/api/status")
            return Run(barrage, "", before, after, captures, bool(status["signal"]), [])

        result = asyncio.run(run())
        assert proc.poll() is None, "the daemon died"
    result.log = log_path.read_text(errors="replace")
    result.state_files = sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                                if p.is_file() and p != log_path and p.name != "stereocam.yaml")
    return result


def test_the_requests_cover_every_kind_and_every_endpoint_with_a_body() -> None:
    model, rect, _, _ = bench_calibration()
    cases = malformed_requests(REQUESTS, calibration_yaml=Calibration.derive(model, rect).to_yaml())
    kinds = Counter(c.kind for c in cases)
    assert len(cases) == REQUESTS
    assert all(kinds[k] >= 100 for k in ("upload", "json", "yaml", "header", "line")), kinds
    names = " | ".join(c.name for c in cases)
    for method, path in JSON_ENDPOINTS:
        assert any(c.data.startswith(method + b" " + path + b" ") for c in cases), path
    for what in ("PNG claiming 60000x60000", "JPEG claiming", "BMP claiming", "TIFF claiming",
                 "flipped bytes", "cut to", "a part header over 8 KB", "16-bit PNG", "two-page TIFF",
                 "alias bomb", "a merge key",
                 "flow lists 100000 deep", "block maps 300 deep", "model.K1:", "over 256 KiB", "not UTF-8",
                 "Authorization b'Bearer \\xff", "Host b'evil.example'", "Origin b'null'", "header b'X: aaa",
                 "200 headers", "chunks", "raw b'GARBAGE", "cut short", "a flipped bit in the request line"):
        assert what in names, what
    assert len({c.data for c in cases}) >= 0.9 * len(cases), "the cases repeat themselves"


@pytest.mark.timeout(900)  # a busy machine makes this slower, never red
def test_every_malformed_request_gets_the_4xx_it_should_and_none_a_5xx(hostile_run: Run) -> None:
    b = hostile_run.barrage
    assert len(b.outcomes) >= REQUESTS
    errors = [(o.case.name, o.status) for o in b.status_5xx]
    assert errors == []
    unexpected = [f"{o.case.kind}: {o.case.name}: {o.complaint}" for o in b.unexpected]
    assert unexpected == []
    assert sum(1 for o in b.outcomes if o.status is not None and 400 <= o.status < 500) >= 0.75 * REQUESTS
    assert b.websocket and b.websocket_unexpected == [], b.websocket_unexpected


@pytest.mark.timeout(900)
def test_the_daemon_logs_no_traceback(hostile_run: Run) -> None:
    assert log_tracebacks(hostile_run.log) == []
    assert "Traceback" not in hostile_run.log


@pytest.mark.timeout(900)
def test_the_watched_stream_flows_throughout_and_after(hostile_run: Run) -> None:
    """Parts arrive between every 500 answers (each batch takes longer than a frame period even on a
    fast machine) and after the last one; the frames are the camera's again at the end."""
    b = hostile_run.barrage
    done = sorted(o.started + o.seconds for o in b.outcomes)
    marks = [b.start] + done[499::500]
    figures = b.figures()
    for i, (t0, t1) in enumerate(zip(marks, marks[1:], strict=False)):
        assert b.watch.between(t0, t1), (f"no part while answers {500 * i} to {500 * (i + 1)} came", figures)
    last = max(t for t, _, _ in b.watch.parts)
    assert last > b.end, "no part after the barrage"
    assert hostile_run.signal_after, "no frame signal after the barrage"
    frames = [f for _, f, signal in b.watch.parts if signal]
    assert frames == sorted(frames) and len(set(frames)) == len(frames), "frames out of order or repeated"


@pytest.mark.timeout(900)
def test_memory_comes_back_within_50_mb(hostile_run: Run) -> None:
    b = hostile_run.barrage
    start, end, peak = b.rss_start_mb, b.rss_end_mb, b.rss_peak_mb
    assert end - start <= FLOOR_RSS_DELTA_MB, (
        f"resident memory {start:.0f} MB after the warm-up, {end:.0f} MB {SETTLE_S:g} s after the barrage "
        f"(peak {peak:.0f} MB)")


@pytest.mark.timeout(900)
def test_nothing_a_malformed_request_sent_was_taken(hostile_run: Run) -> None:
    assert hostile_run.calibration_after["id"] == hostile_run.calibration_before["id"]
    assert hostile_run.captures == []
    assert hostile_run.state_files == []  # no calibration.yaml, no calibration-pairs/settings.json


# -- bodies that do not decode ---------------------------------------------------------------------------

@pytest.fixture
def tracebacks(caplog: pytest.LogCaptureFixture):
    caplog.set_level(logging.INFO)
    yield lambda: [r.getMessage() for r in caplog.records if r.exc_info or "Traceback" in r.getMessage()]


async def test_a_body_whose_content_encoding_does_not_decode_is_a_400_without_a_traceback(start_daemon,
                                                                                         tracebacks) -> None:
    d = await start_daemon(extensions=(routes_calibration.setup,))
    for case in corrupt_encoding_cases(token=None):
        status, answer = await send_raw(d.port, case.data)
        assert status == 400 and b"the body cannot be read" in answer, (case.name, status, answer[-300:])
    for _ in range(3):  # aiohttp reads what is left of a body after answering: let it, then look at the log
        async with d.http.get("/api/status") as r:
            assert r.status == 200
    assert tracebacks() == []


# -- the billion laughs ----------------------------------------------------------------------------------

async def test_a_yaml_alias_bomb_is_refused_with_a_400_that_says_why(start_daemon) -> None:
    d = await start_daemon(extensions=(routes_calibration.setup,))
    async with d.http.get("/api/calibration") as r:
        before = await r.json()
    for name, text in alias_bombs(before["yaml"]).items():
        async with d.http.put("/api/calibration", data=text.encode(),
                              headers={"Content-Type": "application/yaml"}) as r:
            body = await r.json()
        assert r.status == 400, (name, body)
        assert "YAML aliases" in body["error"] and "previous calibration stays active" in body["error"], name
        assert "\n" not in body["error"]
    async with d.http.get("/api/calibration") as r:
        assert (await r.json())["id"] == before["id"]


# -- a slow reader -----------------------------------------------------------------------------------------

async def test_a_slow_reader_is_sent_the_newest_frame_and_skips_what_it_missed(start_daemon) -> None:
    """The cameras move one frame at a time (stepped clock) while a client with 4 KB of receive buffer
    reads nothing: the daemon sends it what fits in its buffers, then waits. When the client reads
    again, the next frame it gets is the newest, not the ones it missed; and each frame the daemon
    sent it was the newest the daemon had at that moment."""
    d = await start_daemon(overlay=make_overlay(clock="stepped", calibrate=False), no_signal_s=60)
    loop = asyncio.get_running_loop()
    feed = d.app[FEED]
    # Every stepped frame is copied and published: on a busy machine the CPU budget plans a copy rate
    # that would leave a stepped frame uncopied, and the step below would wait for it for ever.
    with d.app[PIPELINE].every_frame(lambda frame_set: None):

        async def until(condition: Callable[[], bool], what: str) -> None:
            deadline = time.monotonic() + BOUND_S
            while not condition():
                assert time.monotonic() < deadline, what
                await asyncio.sleep(0.005)

        def encoded() -> Optional[int]:
            encoder = d.app[ENCODERS].active().get(EncoderKey("rect_left", d.config.default_quality))
            value = encoder.output.current()[1] if encoder is not None else None
            return None if value is None else int(value.frame)

        async def step() -> int:
            """One frame more from the cameras, through the pipeline and the encoder, and to the client if it
            has room (else the client's stream is held up in a write): the frame's number."""
            seq = feed.frames.seq
            await loop.run_in_executor(None, d.overlay.step)
            await until(lambda: feed.frames.seq > seq and encoded() == feed.last_frame.frame,
                        "no frame encoded")
            newest = feed.last_frame.frame
            client = next(iter(d.app[STREAMS].clients.values()))
            await until(lambda: client.last_frame == newest or client.writing_since is not None, "not sent")
            return int(newest)

        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.setblocking(False)
        await loop.sock_connect(sock, ("127.0.0.1", d.port))
        reader, writer = await asyncio.open_connection(sock=sock, limit=4096)

        async def read_part() -> int:
            await asyncio.wait_for(reader.readuntil(b"--frame\r\n"), BOUND_S)
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), BOUND_S)
            headers = dict(line.split(": ", 1) for line in head.decode().strip().split("\r\n"))
            await asyncio.wait_for(reader.readexactly(int(headers["Content-Length"]) + 2), BOUND_S)
            return int(headers["X-Frame-Number"])

        try:
            writer.write(b"GET /stream/rect_left HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await writer.drain()
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), BOUND_S)
            assert head.startswith(b"HTTP/1.1 200"), head
            await loop.run_in_executor(None, d.overlay.step)  # the fabric hands each frame on one step later
            await step()
            await read_part()  # the stream's first frame
            stepped = [await step() for _ in range(20)]  # the client reads nothing meanwhile
            received = []
            while not received or received[-1] != stepped[-1]:
                received.append(await read_part())
                assert len(received) <= len(stepped), (received, stepped)
            client = next(iter(d.app[STREAMS].clients.values()))
            assert client.lag_max_frames == 0 and client.lag_max_s == 0.0, client.to_json()
        finally:
            writer.close()
        assert all(f in stepped for f in received) and received == sorted(received), (received, stepped)
        assert len(received) < len(stepped) // 2, f"the client was sent every frame it missed: {received}"


# -- the daemon bugs the barrage found, one by one -------------------------------------------------------

@pytest.mark.parametrize("fast", [True, False], ids=["libyaml", "python"])
@pytest.mark.parametrize("text, words", [
    ("a: !!bool maybe\n", "'maybe' is not a value"), ("a: !!int xyz\n", "a value cannot be read"),
    ("a: 2001-13-45\n", "month must be in 1..12"), ("a: " + "1" * 5000 + "\n", "too many digits"),
    ("a: 0x" + "f" * 5000 + "\n", "wider than 64 bits"), ("a: 0b" + "1" * 65 + "\n", "wider than 64 bits"),
    ("a: " + "1:" * 3000 + "1\n", "wider than 64 bits"), ("a: \x00\n", "not valid YAML"),
])
def test_yaml_values_the_safe_constructor_cannot_read_are_refused(monkeypatch, fast, text, words) -> None:
    """``!!bool maybe`` was a KeyError, a 4301-digit integer a ValueError the calibration PUT did not
    expect: a 500 with a traceback. Now every one is a YamlRefused (a 400 naming the problem)."""
    import yaml

    from stereocam.calibration.safe_yaml import YamlRefused, load

    if not fast:
        monkeypatch.delattr(yaml, "CSafeLoader", raising=False)
    with pytest.raises(YamlRefused, match=words):
        load(text)
    assert load("a: 0x" + "f" * 16 + "\n") == {"a": 2 ** 64 - 1}  # 64 bits are fine


async def test_headers_that_are_not_utf8_are_4xx_without_a_traceback(start_daemon, tracebacks) -> None:
    """An Origin or Host with bytes that are not UTF-8 was a 500 (the refusal could not be encoded),
    and so was a WebSocket key that is not ASCII (aiohttp decodes it before checking it)."""
    d = await start_daemon()
    for head, status in ((b"POST /api/captures HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: \xff\xfe\r\n", 403),
                         (b"GET /api/status HTTP/1.1\r\nHost: \xff.example\r\n", 421),
                         (b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                          b"Connection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
                          b"Sec-WebSocket-Key: \xff\xfe\r\n", 400)):
        got, answer = await send_raw(d.port, head + b"Content-Length: 0\r\nConnection: close\r\n\r\n")
        assert got == status, (head, got, answer[-300:])
        assert b"\\xff" in answer or status == 400, answer[-300:]  # the bytes shown, as escapes
    assert tracebacks() == []


async def test_a_client_that_goes_away_mid_body_leaves_no_traceback(start_daemon, tracebacks) -> None:
    """A handler reading the body of a client that closed got ConnectionResetError, which aiohttp logs
    as a failed request with a traceback: the guard makes it a quiet 400 nobody receives."""
    d = await start_daemon(extensions=(routes_calibration.setup,))
    for path, ctype in (("/api/source", "application/json"), ("/api/calibration", "application/yaml"),
                        ("/api/virtual-camera", "multipart/form-data; boundary=b")):
        data = (f"PUT {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {ctype}\r\n"
                f"Content-Length: 100000\r\n\r\n").encode() + b"{" * 1000
        if path == "/api/virtual-camera":
            data = data.replace(b"PUT", b"POST", 1)
        got, _ = await send_raw(d.port, data, half_close=True)
        assert got in (None, 400), (path, got)
    for _ in range(3):  # the handlers finish on the loop: let them
        async with d.http.get("/api/status") as r:
            assert r.status == 200
    assert tracebacks() == []


# -- idle sockets at the fd limit ------------------------------------------------------------------------

FD_LIMIT = 256
IDLE_SOCKETS = 300
HEADER_TIMEOUT_S = 1.0


class PartCounter(threading.Thread):
    """Reads an MJPEG stream on a socket of its own and notes when each part began to arrive."""

    def __init__(self, port: int, path: str) -> None:
        super().__init__(daemon=True)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=BOUND_S)
        self.sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        self.arrivals: List[float] = []
        self.error: Optional[str] = None

    def run(self) -> None:
        tail = b""
        try:
            while True:
                chunk = self.sock.recv(65536)
                if not chunk:
                    self.error = "the stream ended"
                    return
                data = tail + chunk
                self.arrivals.extend(time.monotonic() for _ in range(data.count(b"--frame\r\n")))
                tail = data[-16:].replace(b"--frame\r\n", b"")
        except OSError as exc:
            self.error = f"the stream broke: {exc}"

    def parts_after(self, t: float) -> int:
        return sum(1 for a in self.arrivals if a > t)

    def close(self) -> None:
        self.sock.shutdown(socket.SHUT_RDWR)  # ends run()'s recv
        self.join(BOUND_S)
        self.sock.close()


def _start_daemon(tmp_path: Path, settings: str, *,
                  limit: Optional[int] = None) -> Tuple["subprocess.Popen[bytes]", int, Path]:
    """``stereocam serve`` as a process with ``settings`` (YAML), its fd limit at ``limit``, healthy."""
    config = tmp_path / "stereocam.yaml"
    config.write_text(settings)
    port, log_path = free_port(), tmp_path / "daemon.log"

    def limit_fds() -> None:
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (limit, limit))

    with open(log_path, "wb") as log:
        command = daemon_command(port, TEST_FPS, tmp_path / "captures", ["--config", str(config)])
        proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                preexec_fn=limit_fds)
    try:
        wait_healthy(f"http://127.0.0.1:{port}", proc, BOUND_S)
    except Exception:
        _stop(proc)
        raise
    return proc, port, log_path


def _stop(proc: "subprocess.Popen[bytes]") -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=BOUND_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def _healthz(port: int) -> Optional[int]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5.0) as resp:
            return int(resp.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)
    except (urllib.error.URLError, OSError):
        return None


@pytest.mark.timeout(900)
def test_300_idle_sockets_at_an_fd_limit_of_256_leave_health_and_streams_answering(tmp_path) -> None:
    """Issue 20 item 4's check. The daemon closes what the idle sockets hold within the header timeout
    (1 s here) and half a second of sweep; that is the daemon's design. Measured from outside on a
    shared machine it can take longer, so the bound asserted is BOUND_S and the time is printed."""
    proc, port, log_path = _start_daemon(tmp_path, f"header_timeout_s: {HEADER_TIMEOUT_S}\n", limit=FD_LIMIT)
    idle: List[socket.socket] = []
    stream = PartCounter(port, "/stream/rect_left?fps=5")
    stream.start()
    try:
        deadline = time.monotonic() + BOUND_S
        while len(stream.arrivals) < 2:
            assert time.monotonic() < deadline and stream.error is None, stream.error or "no part"
            time.sleep(0.05)
        before = _fds(proc.pid)
        flood = time.monotonic()
        for _ in range(IDLE_SOCKETS):  # connected, never a byte: held open by this test all along
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setblocking(False)
            s.connect_ex(("127.0.0.1", port))
            idle.append(s)
        while _healthz(port) != 200:
            assert time.monotonic() < flood + BOUND_S, f"/healthz did not answer within {BOUND_S} s"
            time.sleep(0.2)
        print(f"/healthz answered {time.monotonic() - flood:.2f} s after {IDLE_SOCKETS} idle sockets "
              f"(header timeout {HEADER_TIMEOUT_S:g} s)")
        # The header timeout closes what the daemon accepted of them (this test still holds its ends)...
        while _fds(proc.pid) > before + 10:
            assert time.monotonic() < flood + BOUND_S, f"the daemon still holds {_fds(proc.pid)} fds"
            time.sleep(0.2)
        closed = time.monotonic()
        print(f"the daemon was back to {_fds(proc.pid)} fds {closed - flood:.2f} s after the flood")
        # ... and status, health and the stream that was watching all along answer after it.
        for _ in range(3):
            assert _healthz(port) == 200
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=BOUND_S) as resp:
            assert resp.status == 200
        while stream.parts_after(closed) < 3:
            assert time.monotonic() < closed + BOUND_S and stream.error is None, stream.error or "no part"
            time.sleep(0.05)
        assert stream.error is None
    finally:
        for s in idle:
            s.close()
        stream.close()
        _stop(proc)
    log = log_path.read_text(errors="replace")
    about = [line for line in log.splitlines()
             if "connections" in line or "accept" in line or "Too many open files" in line]
    assert len(about) <= 5, about  # a few summary lines, not one per socket or per retry
    assert "out of system resource" not in log and "Traceback" not in log


# -- the token and the log ----------------------------------------------------------------------------------

LOG_TOKEN = "t0k+en/with=signs=="


@pytest.mark.timeout(600)
def test_no_log_line_at_any_level_holds_the_token(tmp_path) -> None:
    """log_level debug (every request logged) while the token comes every way it may, right and wrong,
    in URLs, cookies, headers, a Referer and a malformed request line."""
    proc, port, log_path = _start_daemon(tmp_path, f"access_token: {LOG_TOKEN}\nlog_level: debug\n")
    encoded = urllib.parse.quote(LOG_TOKEN, safe="")
    try:
        requests = [
            f"GET /?token={encoded} HTTP/1.1\r\nHost: 127.0.0.1\r\n",
            f"GET /snapshot/rect_left.jpg?token={encoded} HTTP/1.1\r\nHost: 127.0.0.1\r\n",
            f"GET /api/status?token={LOG_TOKEN} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"Referer: http://127.0.0.1:{port}/?token={encoded}\r\n",
            f"GET /api/point?x=1&y=1&token={encoded} HTTP/1.1\r\nHost: 127.0.0.1\r\n",
            f"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nCookie: stereocam_token={encoded}\r\n",
            f"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {LOG_TOKEN}\r\n",
            f"POST /api/captures HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Stereocam-Token: {LOG_TOKEN}\r\n"
            "Content-Length: 0\r\n",
            f"GET /api/status?token={encoded}x HTTP/1.1\r\nHost: 127.0.0.1\r\n",  # wrong by a letter
            f"GET /stream/rect_left?token={encoded}&fps=1 HTTP/1.1 junk\r\nHost: 127.0.0.1\r\n",  # malformed
            f"GET /api/status?token={encoded} HTTP/1.1\r\nHost: evil.example\r\nOrigin: null\r\n",
            *(f"POST /signin HTTP/1.1\r\nHost: 127.0.0.1\r\n"
              # the sign-in form, right and wrong
              f"Content-Type: application/x-www-form-urlencoded\r\nContent-Length: {len(body)}\r\n\r\n{body}"
              for body in (f"token={encoded}", f"token={encoded}x")),
        ]
        for text in requests:
            with socket.create_connection(("127.0.0.1", port), timeout=BOUND_S) as s:
                head, sep, body = text.partition("\r\n\r\n")
                s.sendall((head + ("\r\n" if sep else "") + "Connection: close\r\n\r\n" + body).encode())
                while s.recv(65536):
                    pass
    finally:
        _stop(proc)
    log = log_path.read_text(errors="replace")
    assert "token=<redacted>" in log  # the access log did log those requests
    for secret in {LOG_TOKEN, encoded, urllib.parse.quote_plus(LOG_TOKEN), encoded + "x"}:
        assert secret not in log, [line for line in log.splitlines() if secret in line]
