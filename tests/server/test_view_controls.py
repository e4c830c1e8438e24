"""Per-view quality, size and rate over the page's socket, each frame's age as it leaves (the page's
latency figure), the ping the page times the round trip with, and a recording's frames one by one
(the capture viewer's stepping): issue 24, build item 4."""
from __future__ import annotations

import asyncio
import json
import struct
import time
from typing import Any, Dict, List, Tuple

import cv2
import numpy as np
import pytest
from aiohttp import WSMsgType

from stereocam.server.http.routes_recordings import RECORDINGS
from stereocam.server.http.state import SETTINGS
from stereocam.server.stores.recordings import frame_names

from .daemon import WAIT_S, H, W, wait_for_frames
from .test_recordings import finished, record

pytestmark = pytest.mark.slow


async def _frames(ws: Any, n_each: int, views: List[str]) -> Dict[str, List[Tuple[Dict[str, Any], float]]]:
    """``n_each`` frames of each view: (header, the receiving wall-clock time)."""
    got: Dict[str, List[Tuple[Dict[str, Any], float]]] = {v: [] for v in views}
    deadline = time.monotonic() + WAIT_S
    while min(len(x) for x in got.values()) < n_each:
        assert time.monotonic() < deadline, {v: len(x) for v, x in got.items()}
        msg = await ws.receive(timeout=WAIT_S)
        assert msg.type == WSMsgType.BINARY, msg
        received = time.time()
        (n,) = struct.unpack(">I", msg.data[:4])
        header = json.loads(msg.data[4:4 + n])
        img = cv2.imdecode(np.frombuffer(msg.data[4 + n:], np.uint8), cv2.IMREAD_UNCHANGED)
        header["size"] = (img.shape[1], img.shape[0])
        header["bytes"] = len(msg.data)
        got[header["view"]].append((header, received))
    return got


async def _error(ws: Any) -> str:
    """The next text message's error (frames of the old subscription may come first)."""
    while True:
        msg = await ws.receive(timeout=WAIT_S)
        if msg.type == WSMsgType.TEXT:
            doc = json.loads(msg.data)
            assert set(doc) == {"error"}, doc
            return str(doc["error"])
        assert msg.type == WSMsgType.BINARY, msg


async def test_each_view_gets_its_own_quality_size_and_rate(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json({"views": [{"view": "rect_left", "quality": 30, "scale": 0.25, "fps": 5},
                                      {"view": "raw_right", "quality": 95},
                                      "rect_right"],
                            "fps": 10, "scale": 0.5})
        got = await _frames(ws, 3, ["rect_left", "raw_right", "rect_right"])
    left = [h for h, _ in got["rect_left"]]
    assert {(h["quality"], h["scale"], h["size"]) for h in left} == {(30, 0.25, (W // 4, H // 4))}
    right = [h for h, _ in got["raw_right"]]
    assert {(h["quality"], h["scale"], h["size"]) for h in right} == {(95, 0.5, (W // 2, H // 2))}
    # a view that sets nothing gets the message's scale and the daemon's default quality
    assert {(h["quality"], h["scale"], h["size"]) for h, _ in got["rect_right"]} == {
        (d.app[SETTINGS].default_quality, 0.5, (W // 2, H // 2))}


async def test_the_encoders_run_at_each_views_quality_and_rate(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json({"views": [{"view": "rect_left", "quality": 40, "fps": 2},
                                      {"view": "rect_right", "quality": 90, "fps": 7}], "fps": 10})
        await _frames(ws, 2, ["rect_left", "rect_right"])
        async with d.http.get("/api/status") as resp:
            status = await resp.json()
    asked = {(e["view"], e["quality"]): e["asked_fps"] for e in status["encoders"]}
    assert asked == {("rect_left", 40): 2.0, ("rect_right", 90): 7.0}


QUALITY = "rect_left: quality must be a whole number in 1..100"


@pytest.mark.parametrize("entry, words", [
    ({"view": "rect_left", "quality": 0}, "rect_left: quality must be a whole number in 1..100, got '0'"),
    ({"view": "rect_left", "quality": 101}, "rect_left: quality must be a whole number in 1..100"),
    ({"view": "rect_left", "quality": 50.5}, "rect_left: quality must be a whole number in 1..100"),
    ({"view": "rect_left", "quality": True}, QUALITY + ", got 'True'"),
    ({"view": "rect_left", "fps": 0}, "rect_left: fps must be a number in (0, "),
    ({"view": "rect_left", "fps": 1000}, "rect_left: fps must be a number in (0, "),
    ({"view": "rect_left", "fps": None}, "rect_left: fps must be a number in (0, "),
    ({"view": "rect_left", "scale": 0.3}, "rect_left: scale must be one of 0.25, 0.5, 1"),
    ({"view": "rect_left", "size": 2}, "rect_left: unknown key 'size': a view's entry may set fps, quality"),
    ({"view": "nope", "quality": 50}, "unknown view 'nope'"),
    ({"quality": 50}, 'each entry of views is a view name or {"view": NAME'),
    (7, 'each entry of views is a view name or {"view": NAME'),
])
async def test_out_of_range_view_settings_are_refused_on_the_socket(start_daemon, entry, words) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json({"views": ["rect_right"], "fps": 10})
        await _frames(ws, 1, ["rect_right"])
        await ws.send_json({"views": [entry, "rect_right"]})
        error = await _error(ws)
        assert words in error and "\n" not in error, error
        # the refusal changed nothing: the subscription before it goes on, and a good one is taken
        await _frames(ws, 2, ["rect_right"])
        await ws.send_json({"views": [{"view": "rect_left", "quality": 60}]})
        got = await _frames(ws, 1, ["rect_left"])
        assert got["rect_left"][0][0]["quality"] == 60
    await wait_for_frames(d, 2)
    async with d.http.get("/healthz") as resp:
        assert resp.status == 200


async def test_out_of_range_stream_settings_over_http_are_400(start_daemon) -> None:
    d = await start_daemon()
    for query, words in (("quality=0", "quality must be a whole number in 1..100"),
                         ("fps=0", "fps must be a number in (0, "), ("scale=0.3", "scale must be one of")):
        async with d.http.get(f"/stream/rect_left?{query}") as resp:
            assert resp.status == 400
            assert words in (await resp.json())["error"]


async def test_each_frame_says_how_old_it_was_when_sent(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json({"views": ["rect_left", "disparity"], "fps": 10})
        got = await _frames(ws, 3, ["rect_left", "disparity"])
    for frames in got.values():
        for header, received in frames:
            age = header["age_s"]
            assert isinstance(age, float) and age >= 0.0, header
            # seconds, measured on the one clock the capture time is on: sent before it was received
            assert header["timestamp"] + age <= received, (header, received)
    # the disparity is computed after the frame came, so its frames leave older than the frame's moment
    assert all(h["age_s"] > 0 for h, _ in got["disparity"])


async def test_a_ping_is_answered_and_leaves_the_subscription_alone(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json({"views": ["rect_left"], "fps": 10})
        await _frames(ws, 1, ["rect_left"])
        await ws.send_json({"ping": 12.5})
        while True:
            msg = await ws.receive(timeout=WAIT_S)
            if msg.type == WSMsgType.TEXT:
                assert json.loads(msg.data) == {"pong": 12.5}
                break
        await _frames(ws, 2, ["rect_left"])
        for bad in ({"ping": "x"}, {"ping": 1, "views": []}, {"ping": True}):
            await ws.send_json(bad)
            assert 'a ping is {"ping": N} alone' in await _error(ws)
        await _frames(ws, 1, ["rect_left"])


# -- a recording's frames, one by one ----------------------------------------------------------------

async def test_a_recordings_frames_one_by_one(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 3)
    rid = (await record(d))["id"]  # until stopped
    async with d.http.get(f"/api/recordings/{rid}/frames/0/left.png") as resp:
        assert resp.status == 409
        assert "still running" in (await resp.json())["error"]
    async def recorded() -> int:
        async with d.http.get(f"/api/recordings/{rid}") as resp:
            return int((await resp.json())["frames"])

    deadline = time.monotonic() + WAIT_S
    while await recorded() < 2:
        assert time.monotonic() < deadline, "no frame recorded"
        await asyncio.sleep(0.05)
    async with d.http.post(f"/api/recordings/{rid}/stop") as resp:
        assert resp.status == 200, await resp.text()
    done = await finished(d, rid)
    n = done["frames"]
    assert n >= 1
    folder = d.app[RECORDINGS].root / rid
    for index in (0, n - 1):
        for side, name in zip(("left", "right"), frame_names(index), strict=True):
            async with d.http.get(f"/api/recordings/{rid}/frames/{index}/{side}.png") as resp:
                assert resp.status == 200, await resp.text()
                assert resp.content_type == "image/png"
                assert resp.headers["X-Frames"] == str(n)
                assert resp.headers["X-Color"] == "rgb"
                assert await resp.read() == (folder / name).read_bytes()
    async with d.http.get(f"/api/recordings/{rid}/frames/{n}/left.png") as resp:
        assert resp.status == 404
        error = (await resp.json())["error"]
        assert error == f"recording {rid} has no frame {n}: its frames are 0 to {n - 1}"
    for path, status, words in (
            (f"/api/recordings/{rid}/frames/-1/left.png", 400, "frame index must be a whole number"),
            (f"/api/recordings/{rid}/frames/x/left.png", 400, "frame index must be a whole number"),
            (f"/api/recordings/{rid}/frames/0/top.png", 404, "ask for left.png or right.png"),
            ("/api/recordings/20261122T040512Z-000123-ab12/frames/0/left.png", 404, "no recording"),
            ("/api/recordings/nonsense/frames/0/left.png", 400, "")):
        async with d.http.get(path) as resp:
            assert resp.status == status, (path, await resp.text())
            assert words in (await resp.json())["error"]
    (folder / frame_names(0)[1]).unlink()
    async with d.http.get(f"/api/recordings/{rid}/frames/0/right.png") as resp:
        assert resp.status == 422, await resp.text()
        assert "is missing" in (await resp.json())["error"]
