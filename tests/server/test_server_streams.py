"""Streams over HTTP: MJPEG, snapshots, the WebSocket; real clients (ffmpeg, OpenCV) read them."""
from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import struct
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Tuple

import cv2
import numpy as np
import pytest
from aiohttp import WSMsgType

from stereocam.server.frames.encoders import EncoderKey
from stereocam.server.http.metrics import METRICS
from stereocam.server.http.state import ENCODERS, FEED, PIPELINE
from stereocam.server.http.streams import STREAMS

from .daemon import (
    TEST_FPS,
    WAIT_S,
    H,
    W,
    read_parts,  # noqa: F401
    until,
    wait_for_frames,
)

pytestmark = pytest.mark.slow


def jpeg_size(data: bytes) -> tuple:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None, "not a decodable JPEG"
    return img.shape


async def test_mjpeg_stream_parts_carry_frame_number_and_timestamp(start_daemon) -> None:
    d = await start_daemon()
    t0 = time.time()
    async with d.http.get("/stream/rect_left") as resp:
        assert resp.status == 200
        assert resp.headers["Content-Type"] == "multipart/x-mixed-replace; boundary=frame"
        assert "no-store" in resp.headers["Cache-Control"]
        parts = await read_parts(resp, 4)
    numbers = [int(h["x-frame-number"]) for h, _ in parts]
    assert numbers == sorted(numbers) and len(set(numbers)) == 4, f"frames repeat or go back: {numbers}"
    for headers, body in parts:
        assert headers["content-type"] == "image/jpeg"
        assert int(headers["content-length"]) == len(body)
        assert t0 - 1 < float(headers["x-timestamp"]) < time.time() + 0.1
        assert jpeg_size(body) == (H, W, 3)


@pytest.mark.parametrize("view,shape", [
    ("raw_left", (H, W, 3)), ("raw_right", (H, W, 3)), ("rect_right", (H, W, 3)), ("sbs", (H, 2 * W, 3)),
    ("anaglyph", (H, W, 3)), ("disparity", (H, W, 3)),
])
async def test_every_view_streams(start_daemon, view, shape) -> None:
    d = await start_daemon()
    async with d.http.get(f"/stream/{view}") as resp:
        assert resp.status == 200
        parts = await read_parts(resp, 2)
    assert jpeg_size(parts[-1][1]) == shape


async def test_gray_and_quality_parameters(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/stream/rect_left", params={"gray": "1", "quality": "30"}) as resp:
        _, low = (await read_parts(resp, 1))[0]
    async with d.http.get("/stream/rect_left", params={"gray": "1", "quality": "95"}) as resp:
        _, high = (await read_parts(resp, 1))[0]
    assert jpeg_size(low) == (H, W) and jpeg_size(high) == (H, W)
    assert len(low) < len(high)


@pytest.mark.parametrize("query,status,words", [
    ({"fps": "0"}, 400, "fps must be"), ({"fps": "121"}, 400, "fps must be"),
    ({"fps": "abc"}, 400, "fps must be"),
    ({"quality": "0"}, 400, "quality must be"), ({"quality": "101"}, 400, "quality must be"),
    ({"quality": "5.5"}, 400, "quality must be"), ({"gray": "maybe"}, 400, "gray must be"),
    ({"colour": "1"}, 400, "unknown query parameter"),
])
async def test_bad_stream_parameters_are_400(start_daemon, query, status, words) -> None:
    d = await start_daemon()
    for path in ("/stream/rect_left", "/snapshot/rect_left.jpg"):
        async with d.http.get(path, params=query) as resp:
            assert resp.status == status
            body = await resp.json()
            assert words in body["error"] and "\n" not in body["error"]


async def test_unknown_view_is_404(start_daemon) -> None:
    d = await start_daemon()
    for path in ("/stream/edges", "/snapshot/edges.jpg", "/snapshot/rect_left.gif"):
        async with d.http.get(path) as resp:
            assert resp.status == 404
            assert "error" in await resp.json()


async def test_snapshots_are_newer_than_the_request(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 3)
    pipeline = d.app[PIPELINE]
    for fmt in ("jpg", "png"):
        before = pipeline.last_frame_number
        t0 = time.time()
        async with d.http.get(f"/snapshot/rect_left.{fmt}") as resp:
            assert resp.status == 200
            assert resp.content_type == ("image/jpeg" if fmt == "jpg" else "image/png")
            body = await resp.read()
            frame = int(resp.headers["X-Frame-Number"])
            stamp = float(resp.headers["X-Timestamp"])
        assert frame > before and stamp >= t0
        assert jpeg_size(body) == (H, W, 3)


def frame_period(d) -> float:
    """The fabric's frame period: nominal, or as measured when a loaded machine makes it longer."""
    return max(1 / TEST_FPS, d.app[PIPELINE].period or 0.0)


async def first_frame_stamp(d, kind: str, view: str, **query: str) -> float:
    """``X-Timestamp`` (the daemon's capture time) of the first frame a new client of ``view`` gets
    (``kind`` "encoder": the first frame a newly started encoder publishes, whoever asks)."""
    if kind == "encoder":
        key = EncoderKey(view, int(query.get("quality", 80)))
        with d.app[ENCODERS].subscribe(key, TEST_FPS) as encoder:
            _, first = await asyncio.wait_for(encoder.output.wait_newer(0), WAIT_S)
        return first.timestamp
    if kind == "mjpeg":
        async with d.http.get(f"/stream/{view}", params=query) as resp:
            assert resp.status == 200
            headers, _ = (await read_parts(resp, 1))[0]
        return float(headers["x-timestamp"])
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_str(json.dumps({"views": [view], **query}))
        msg = await ws.receive(timeout=WAIT_S)
        assert msg.type == WSMsgType.BINARY, msg
        (n,) = struct.unpack(">I", msg.data[:4])
        return float(json.loads(msg.data[4:4 + n])["timestamp"])


@pytest.mark.parametrize("kind", ["mjpeg", "ws", "encoder"])
async def test_a_new_streams_first_frame_is_newer_than_the_request(start_daemon, kind) -> None:
    """After a view went unwatched, the feed still holds the last frame copied for it, many frame
    periods old; a new client's first frame is one captured after it asked (in the daemon's clock,
    allowing 2 frame periods), not that one: ``ffmpeg -frames 1`` gets a picture of now."""
    d = await start_daemon()
    feed, pipeline = d.app[FEED], d.app[PIPELINE]
    async with d.http.get("/stream/rect_left") as resp:
        await read_parts(resp, 2)
    await until(lambda: not d.app[ENCODERS].active(), "the encoder stopping")
    # Unwatched, frames are seen but no longer copied: wait until the one the feed holds is stale.
    await until(lambda: feed.last_frame is not None
                and pipeline.last_frame_number - feed.last_frame.frame >= 10
                and time.time() - feed.last_frame.timestamp > 10 * frame_period(d), "the view going stale")
    stale = feed.last_frame
    asked = time.time()
    stamp = await first_frame_stamp(d, kind, "rect_left")
    assert stamp >= asked - 2 * frame_period(d), (
        f"the first frame is {asked - stamp:.3f} s older than the request (the stale one: "
        f"{asked - stale.timestamp:.3f} s)")


async def test_a_client_joining_a_slow_stream_gets_a_frame_newer_than_its_request(start_daemon) -> None:
    """An encoder shared with a 1 fps client holds a frame up to a second old; a client joining it
    does not start with that one."""
    d = await start_daemon()
    async with d.session().get("/stream/rect_left", params={"fps": "1"}) as slow:
        await read_parts(slow, 2)
        (encoder,) = d.app[ENCODERS].active().values()

        def held_is_stale() -> bool:
            _, held = encoder.output.current()
            return held is not None and time.time() - held.timestamp > 5 * frame_period(d)

        await until(held_is_stale, "the 1 fps encoder's frame ageing")
        asked = time.time()
        stamp = await first_frame_stamp(d, "mjpeg", "rect_left")
    assert stamp >= asked - 2 * frame_period(d), f"the first frame is {asked - stamp:.3f} s older than asked"


async def test_png_snapshot_is_lossless(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/snapshot/rect_left.png") as resp:
        png = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    _, processed = d.overlay.fabric.latest_processed()
    np.testing.assert_array_equal(png, processed[..., [2, 1, 0]])  # a still scene: every frame is the same
    async with d.http.get("/snapshot/raw_right.png", params={"gray": "1"}) as resp:
        gray = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    _, raw = d.overlay.fabric.latest_raw()
    np.testing.assert_array_equal(gray, raw[..., 7])


async def test_each_view_is_encoded_once_per_frame_whatever_the_clients(start_daemon) -> None:
    d = await start_daemon()
    metrics = d.app[METRICS]
    sessions = [d.session() for _ in range(6)]
    responses = [await s.get("/stream/rect_left") for s in sessions]
    try:
        await asyncio.gather(*(read_parts(r, 2) for r in responses))
        frames0 = d.app[PIPELINE].frames
        enc0 = metrics.encode["rect_left"][0]
        await asyncio.gather(*(read_parts(r, 8) for r in responses))
        frames = d.app[PIPELINE].frames - frames0
        encodes = metrics.encode["rect_left"][0] - enc0
        assert encodes <= frames + 1, f"{encodes} encodes for {frames} frames with 6 clients"
        assert list(d.app[ENCODERS].active()) == [EncoderKey("rect_left", 80, False)]
    finally:
        for r in responses:
            r.close()


async def test_nothing_is_encoded_while_nobody_watches(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/stream/anaglyph") as resp:
        await read_parts(resp, 2)
    # The server notices the disconnect at its next write.
    await until(lambda: not d.app[ENCODERS].active(), "the encoder stopping")
    count = d.app[METRICS].encode["anaglyph"][0]
    await wait_for_frames(d, d.app[PIPELINE].frames + 5)
    assert d.app[METRICS].encode["anaglyph"][0] == count
    assert not d.app[PIPELINE].wants_raw


async def test_fps_parameter_limits_the_rate(start_daemon) -> None:
    """At most 5 parts a second; and not far fewer, counted in the fabric's frames (at least one in
    ten of its 25 a second), which a loaded machine slows as much as it slows the stream."""
    d = await start_daemon(fps=25)
    async with d.http.get("/stream/rect_left", params={"fps": "5"}) as resp:
        await read_parts(resp, 1)
        t0 = time.monotonic()
        parts = await read_parts(resp, 6)
        rate = 5 / (time.monotonic() - t0)
    frames = [int(h["x-frame-number"]) for h, _ in parts]
    gap = (frames[-1] - frames[0]) / (len(frames) - 1)  # fabric frames per part: 25 / 5 when on time
    assert rate < 6.5, rate
    assert gap <= 25 / 2.5, frames


async def test_more_streams_than_max_streams_get_503(start_daemon) -> None:
    d = await start_daemon(max_streams=2)
    responses = [await d.session().get("/stream/rect_left") for _ in range(2)]
    for r in responses:
        await read_parts(r, 1)
    async with d.http.get("/stream/raw_left") as resp:
        assert resp.status == 503
        assert "max_streams" in (await resp.json())["error"]
    async with d.http.get("/ws") as resp:
        assert resp.status == 503
    assert len(d.app[STREAMS]) == 2
    responses[0].close()
    await until(lambda: len(d.app[STREAMS]) < 2, "the closed stream leaving")
    async with d.http.get("/stream/raw_left") as resp:
        assert resp.status == 200
    responses[1].close()


async def test_a_client_that_stops_reading_is_dropped_and_others_go_on(start_daemon) -> None:
    # 2 s: ample for the reading client's writes on a busy machine; the stuck one never drains.
    d = await start_daemon(stream_timeout_s=2.0, fps=25)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", d.port))
    sock.sendall(b"GET /stream/rect_left?quality=100 HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    try:
        async with d.http.get("/stream/rect_left") as good:
            await read_parts(good, 2)
            streams = d.app[STREAMS]
            deadline = time.monotonic() + WAIT_S
            while streams.dropped == 0:
                assert time.monotonic() < deadline, "the stuck client was never dropped"
                await read_parts(good, 1)  # the reading client keeps getting frames meanwhile
            parts = await read_parts(good, 3)
            assert len({h["x-frame-number"] for h, _ in parts}) == 3
            assert len(streams) == 1
    finally:
        sock.close()


async def test_no_signal_frame_within_a_second_and_recovery(start_daemon) -> None:
    d = await start_daemon()  # the default no_signal_s
    async with d.http.get("/stream/rect_left") as resp:
        await read_parts(resp, 2)
        async with d.http.get("/healthz") as health:
            assert health.status == 200 and (await health.text()).strip() == "ok"
        d.overlay.emulation.cameras_running = False
        t0 = time.monotonic()
        while True:
            headers, body = (await read_parts(resp, 1))[0]
            if headers.get("x-signal") == "none":
                break
            assert time.monotonic() - t0 < WAIT_S, "no no-signal frame"
        assert time.monotonic() - t0 < 1.0
        assert jpeg_size(body) == (H, W, 3)
        deadline = time.monotonic() + WAIT_S
        while True:  # healthz says so once the last frame is older than its bound
            async with d.http.get("/healthz") as health:
                if health.status == 503:
                    break
                assert health.status == 200 and time.monotonic() < deadline, health.status
            await asyncio.sleep(0.05)
        async with d.http.get("/snapshot/rect_left.jpg") as snap:
            assert snap.status == 503 and "no signal" in (await snap.json())["error"]
        assert d.app[FEED].signal is False
        d.overlay.emulation.cameras_running = True
        deadline = time.monotonic() + WAIT_S
        while True:
            headers, _ = (await read_parts(resp, 1))[0]
            if "x-signal" not in headers:
                break
            assert time.monotonic() < deadline
    async with d.http.get("/healthz") as health:
        assert health.status == 200


async def test_websocket_sends_header_and_jpeg_per_view(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        assert ws.compress == 0, "JPEG frames are not deflated"
        await ws.send_str(json.dumps({"views": ["rect_left", "raw_right"], "fps": 10}))
        seen: dict = {}
        deadline = time.monotonic() + WAIT_S
        while len(seen) < 2 or min(len(v) for v in seen.values()) < 2:
            assert time.monotonic() < deadline
            msg = await ws.receive(timeout=WAIT_S)
            assert msg.type == WSMsgType.BINARY
            (n,) = struct.unpack(">I", msg.data[:4])
            header = json.loads(msg.data[4:4 + n])
            assert jpeg_size(msg.data[4 + n:]) == (H, W, 3)
            seen.setdefault(header["view"], []).append(header["frame"])
            assert isinstance(header["timestamp"], float)
        assert set(seen) == {"rect_left", "raw_right"}
        for frames in seen.values():
            assert frames == sorted(set(frames))
        await ws.send_str(json.dumps({"views": ["nope"]}))
        while True:
            msg = await ws.receive(timeout=WAIT_S)
            if msg.type == WSMsgType.TEXT:
                assert "unknown view" in json.loads(msg.data)["error"]
                break
        await ws.send_str(json.dumps({"views": []}))
    await until(lambda: not d.app[ENCODERS].active() and not len(d.app[STREAMS]), "the socket ending")


async def test_websocket_from_another_origin_is_refused(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/ws", headers={"Origin": "http://evil.example", "Upgrade": "websocket",
                                          "Connection": "Upgrade"}) as resp:
        assert resp.status == 403


def _ffmpeg() -> str:
    path = shutil.which("ffmpeg") or "/usr/bin/ffmpeg"
    if not os.path.exists(path):
        pytest.fail("ffmpeg is not installed (./scripts/test installs it)")
    return path


async def test_ffmpeg_reads_n_frames_from_a_stream(start_daemon, tmp_path) -> None:
    d = await start_daemon()
    out = tmp_path / "f%02d.jpg"
    proc = await asyncio.create_subprocess_exec(
        _ffmpeg(), "-hide_banner", "-loglevel", "error",
        "-f", "mpjpeg", "-i", f"{d.url}stream/rect_left?fps=10",
        "-frames:v", "5", "-c", "copy", str(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, err = await asyncio.wait_for(proc.communicate(), 60)
    assert proc.returncode == 0, err.decode()
    files = sorted(tmp_path.glob("f*.jpg"))
    assert len(files) == 5
    for f in files:
        assert jpeg_size(f.read_bytes()) == (H, W, 3)


async def test_vlc_plays_a_stream(start_daemon) -> None:
    """VLC (cvlc, headless) reads the MJPEG stream and decodes it: it re-encodes what it got to a file.

    VLC refuses to run as root, so as root it runs as ``nobody`` (setpriv) in a folder it may write.
    """
    cvlc = shutil.which("cvlc") or "/usr/bin/cvlc"
    if not os.path.exists(cvlc):
        pytest.fail("VLC is not installed (./scripts/test installs vlc-bin and vlc-plugin-base)")
    d = await start_daemon()
    folder = Path(tempfile.mkdtemp(prefix="stereocam-vlc-"))
    try:
        os.chmod(folder, 0o777)
        out = folder / "out.ts"
        command = [cvlc, "-I", "dummy", "--no-audio", "--vout=dummy", f"{d.url}stream/rect_left?fps=10",
                   "--sout", f"#transcode{{vcodec=mp4v,vb=2000}}:std{{access=file,mux=ts,dst={out}}}"]
        if os.geteuid() == 0:
            command = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups", "env",
                       f"HOME={folder}", *command]
        log = folder / "vlc.log"  # a file, not a pipe nobody reads while VLC plays
        with open(log, "wb") as errors:
            proc = await asyncio.create_subprocess_exec(*command, stdout=subprocess.DEVNULL, stderr=errors)
        try:
            # A live stream never ends: VLC plays until its file holds 10 frames (a busy machine: later).
            deadline = time.monotonic() + WAIT_S
            while (await _probe(out))[0][2] < 10:
                assert proc.returncode is None, f"VLC exited: {log.read_text(errors='replace')[-2000:]}"
                assert time.monotonic() < deadline, f"VLC wrote under 10 frames in {WAIT_S} s"
                await asyncio.sleep(0.5)
        finally:
            proc.terminate()
            await asyncio.wait_for(proc.wait(), WAIT_S)
        err = log.read_text(errors="replace")[-2000:]
        (width, height, frames), text, perr = await _probe(out)
        assert text, (perr, err)
        assert (width, height) == (W, H) and frames >= 10, (text, err)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


async def _probe(path: Path) -> Tuple[Tuple[int, int, int], str, str]:
    """``((width, height, frames), ffprobe's output, its errors)`` of the video in ``path``.

    Zeros while there is no readable video stream yet.
    """
    if not path.is_file():
        return (0, 0, 0), "", "no file yet"
    probe = await asyncio.create_subprocess_exec(
        shutil.which("ffprobe") or "/usr/bin/ffprobe", "-v", "error", "-count_frames",
        "-select_streams", "v:0", "-show_entries", "stream=nb_read_frames,width,height", "-of", "csv=p=0",
        str(path),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = await asyncio.wait_for(probe.communicate(), WAIT_S)
    text = out.decode()
    lines = [line for line in text.splitlines() if line.strip()]  # the first: the stream (ts repeats it)
    fields = lines[0].split(",")[:3] if probe.returncode == 0 and lines else []
    if len(fields) < 3 or not all(f.strip().isdigit() for f in fields):
        return (0, 0, 0), text, err.decode()
    width, height, frames = (int(f) for f in fields)
    return (width, height, frames), text, err.decode()


def _videocapture_frames(url: str, n: int) -> list:
    cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG)
    try:
        assert cap.isOpened(), f"OpenCV could not open {url}"
        shapes = []
        for _ in range(n):
            ok, img = cap.read()
            assert ok, "VideoCapture.read failed"
            shapes.append(img.shape)
        return shapes
    finally:
        cap.release()


async def test_opencv_videocapture_reads_a_stream(start_daemon) -> None:
    d = await start_daemon()
    shapes = await asyncio.get_running_loop().run_in_executor(
        None, _videocapture_frames, f"{d.url}stream/sbs?fps=10", 3)
    assert shapes == [(H, 2 * W, 3)] * 3


async def test_streams_end_and_the_daemon_stops_within_two_seconds(start_daemon) -> None:
    d = await start_daemon()
    resp = await d.http.get("/stream/rect_left")
    await read_parts(resp, 2)
    ws = await d.session().ws_connect("/ws")
    await ws.send_str(json.dumps({"views": ["rect_right"]}))
    await ws.receive(timeout=WAIT_S)
    d.overlay.fabric.select("virtual")
    took = await d.stop(close_sessions=False, close_overlay=False)
    assert took < 2.0
    rest = await asyncio.wait_for(resp.content.read(), WAIT_S)  # the stream ended
    assert isinstance(rest, bytes)
    msg = await ws.receive(timeout=WAIT_S)
    assert msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSED, WSMsgType.CLOSING)
    assert d.overlay.fabric.source == "live"
    assert not d.overlay.fabric.streaming
    resp.close()


async def test_a_slow_reader_gets_the_newest_frame_not_one_that_waited_in_buffers(start_daemon) -> None:
    """One part read every 0.5 s from a 25 fps stream: each part is the frame that was newest when the
    client last made room, about 0.5 s old, not one from seconds ago."""
    d = await start_daemon()
    await wait_for_frames(d, 2)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a reader that does not buffer ahead
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", d.port))
    reader, writer = await asyncio.open_connection(sock=sock, limit=4096)  # stops reading beyond 8 KB
    writer.write(b"GET /stream/rect_left HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    await writer.drain()
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 30)
    assert head.startswith(b"HTTP/1.1 200")
    ages, reads = [], []
    try:
        for _ in range(10):
            await asyncio.sleep(0.5)  # the slow reader's pace (the subject of the test, not a wait)
            await asyncio.wait_for(reader.readuntil(b"--frame\r\n"), 30)
            part_head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 30)
            headers = dict(line.split(": ", 1) for line in part_head.decode().strip().split("\r\n"))
            reads.append(time.time())
            ages.append(reads[-1] - float(headers["X-Timestamp"]))
            await asyncio.wait_for(reader.readexactly(int(headers["Content-Length"]) + 2), 30)
    finally:
        writer.close()
    # Without the send-queue limit the kernel's buffers fill with seconds of frames and the ages grow
    # by about 0.46 s a read (over 4 s, 9 reads, by the end). With it they stay at the few reads'
    # worth the client's own buffers hold (measured: 1 to 3).
    interval = (reads[-1] - reads[0]) / (len(reads) - 1)
    assert max(ages[4:]) < 4.5 * interval, ([round(a, 2) for a in ages], round(interval, 2))
    assert d.app[STREAMS].dropped == 0
