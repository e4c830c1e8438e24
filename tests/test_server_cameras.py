"""The camera sensors over HTTP (issue 5): GET/PUT /api/cameras, status, metrics, capture metadata."""
from __future__ import annotations

import asyncio
import time

import cv2
import numpy as np

from stereocam.overlays.emulated.cameras import SyntheticRig
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.server import routes_cameras
from stereocam.server.app import default_extensions
from stereocam.server.routes_cameras import CAMERA_SERVICE

from .server_fixtures import (
    SMALL,
    TEST_FPS,
    read_parts,
    start_daemon_fixture,  # noqa: F401
    wait_for_frames,
)

CAMERAS_EXT = [routes_cameras.setup]


async def _start(start_daemon, **kwargs):
    return await start_daemon(extensions=CAMERAS_EXT, **kwargs)


def test_serve_installs_the_cameras_extension() -> None:
    assert routes_cameras.setup in default_extensions()


async def test_get_put_round_trip(start_daemon) -> None:
    d = await _start(start_daemon)
    async with d.http.get("/api/cameras") as resp:
        assert resp.status == 200
        body = await resp.json()
    assert set(body) == {"left", "right", "health"}
    assert body["health"]["ok"] is True
    assert body["health"]["left"]["chip_id"] == "0x1324"
    for c in ("left", "right"):
        assert {"exposure_us", "gain", "aec", "agc", "flip_h", "flip_v", "test_pattern"} <= set(body[c])

    put = {"exposure_us": 4000, "gain": 2.0, "aec": False, "agc": False, "flip_h": True, "flip_v": False,
           "test_pattern": None}
    async with d.http.put("/api/cameras", json=put) as resp:
        assert resp.status == 200, await resp.text()
        answer = await resp.json()
    for c in ("left", "right"):
        v = answer[c]
        assert abs(v["exposure_us"] - 4000) < 60  # whole rows
        assert v["gain"] == 2.0 and v["flip_h"] is True and v["flip_v"] is False
        assert v["aec"] is False and v["agc"] is False and v["test_pattern"] is None
    async with d.http.put("/api/cameras", json={"gain": 3.0, "camera": "right"}) as resp:
        assert resp.status == 200
        answer = await resp.json()
    assert answer["right"]["gain"] == 3.0 and answer["left"]["gain"] == 2.0
    async with d.http.get("/api/cameras") as resp:
        body = await resp.json()
    assert body["right"]["gain"] == 3.0 and body["left"]["flip_h"] is True


async def test_put_goes_through_the_security_middleware(start_daemon) -> None:
    d = await start_daemon(extensions=CAMERAS_EXT, access_token="open-sesame")
    async with d.http.put("/api/cameras", json={"gain": 2.0}) as resp:
        assert resp.status == 401
    evil = {"Origin": "http://evil.example"}
    async with d.http.put("/api/cameras", json={"gain": 2.0}, headers=evil) as resp:
        assert resp.status == 403
    token = {"X-Stereocam-Token": "open-sesame"}
    async with d.http.put("/api/cameras", json={"gain": 2.0}, headers=token) as resp:
        assert resp.status == 200


async def test_bad_inputs_are_refused_naming_the_field(start_daemon) -> None:
    d = await _start(start_daemon)
    async with d.http.get("/api/cameras") as resp:
        before = await resp.json()
    cases = [
        ({"gain": 4.5}, "gain"),
        ({"gain": 0.5}, "gain"),
        ({"exposure_us": -1}, "exposure_us"),
        ({"exposure_us": 10_000_000}, "exposure"),
        ({"aec": "yes"}, "aec"),
        ({"flip_h": 1}, "flip_h"),
        ({"test_pattern": "zebra"}, "test_pattern"),
        ({"shutter": 5}, "shutter"),
        ({"gain": 2.0, "camera": "middle"}, "camera"),
        ([1, 2], "object"),
    ]
    for body, word in cases:
        async with d.http.put("/api/cameras", json=body) as resp:
            assert resp.status == 400, (body, await resp.text())
            error = (await resp.json())["error"]
        assert word in error and "\n" not in error, (body, error)
    as_json = {"Content-Type": "application/json"}
    async with d.http.put("/api/cameras", data=b"{not json", headers=as_json) as resp:
        assert resp.status == 400
        assert "JSON" in (await resp.json())["error"]
    async with d.http.get("/api/cameras") as resp:
        after = await resp.json()
    assert after["left"] == before["left"] and after["right"] == before["right"]  # nothing changed


def _mean(png: bytes) -> float:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return float(img.mean())


async def _snapshot_mean_later(d) -> float:
    from stereocam.server.state import PIPELINE

    start = d.app[PIPELINE].frames
    deadline = time.monotonic() + 10
    while d.app[PIPELINE].frames < start + 4:  # the new registers latch at a frame start
        assert time.monotonic() < deadline
        await asyncio.sleep(0.02)
    async with d.http.get("/snapshot/raw_left.png") as resp:
        assert resp.status == 200
        return _mean(await resp.read())


async def test_more_exposure_brightens_the_raw_view(start_daemon) -> None:
    overlay = EmulatedOverlay(source=SyntheticRig(size=SMALL, motion=False), fps=TEST_FPS)
    d = await start_daemon(overlay=overlay, extensions=CAMERAS_EXT)
    async with d.http.put("/api/cameras", json={"aec": False, "agc": False, "gain": 1.0,
                                                "exposure_us": 2000}) as resp:
        assert resp.status == 200, await resp.text()
    dark = await _snapshot_mean_later(d)
    async with d.http.put("/api/cameras", json={"exposure_us": 8000}) as resp:
        assert resp.status == 200, await resp.text()
    bright = await _snapshot_mean_later(d)
    assert bright > dark * 1.5, (dark, bright)


async def test_a_sensor_not_answering(start_daemon) -> None:
    d = await _start(start_daemon)
    pair = d.app[CAMERA_SERVICE].pair
    pair.right.answering = False
    async with d.http.put("/api/cameras", json={"gain": 2.0}) as resp:
        assert resp.status == 503
        error = (await resp.json())["error"]
    assert "right" in error
    async with d.http.get("/api/status") as resp:
        sensors = (await resp.json())["sensors"]
    assert sensors["ok"] is False
    assert sensors["health"]["right"]["ok"] is False and sensors["health"]["right"]["error"]
    assert sensors["health"]["left"]["ok"] is True
    async with d.http.put("/api/cameras", json={"gain": 2.0, "camera": "right"}) as resp:
        assert resp.status == 503
    async with d.http.put("/api/cameras", json={"gain": 2.0, "camera": "left"}) as resp:
        assert resp.status == 200
        assert (await resp.json())["right"] is None
    async with d.http.get("/stream/raw_left") as stream:  # the video goes on
        assert stream.status == 200
        await read_parts(stream, 2)
    async with d.http.get("/metrics") as resp:
        text = await resp.text()
    assert 'stereocam_sensor_ok{camera="right"} 0' in text
    assert 'stereocam_sensor_ok{camera="left"} 1' in text


async def test_a_missing_sensor_at_startup_does_not_stop_the_daemon(start_daemon) -> None:
    d = await start_daemon(extensions=[routes_cameras.extension(chip_ids=(0x1324, 0x1313))])
    async with d.http.get("/api/status") as resp:
        assert resp.status == 200
        sensors = (await resp.json())["sensors"]
    assert sensors["health"]["right"]["ok"] is False
    assert "0x1313" in sensors["health"]["right"]["error"] or "1313" in sensors["health"]["right"]["error"]
    async with d.http.get("/stream/raw_right") as stream:
        assert stream.status == 200
        await read_parts(stream, 2)


async def test_captures_and_metrics_carry_the_values(start_daemon) -> None:
    d = await _start(start_daemon)
    async with d.http.put("/api/cameras", json={"aec": False, "agc": False, "gain": 2.5,
                                                "exposure_us": 3000}) as resp:
        assert resp.status == 200
        values = await resp.json()
    await wait_for_frames(d, 2)
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        cid = (await resp.json())["id"]
    async with d.http.get(f"/api/captures/{cid}") as resp:
        meta = (await resp.json())["meta"]
    assert meta["cameras"]["left"]["gain"] == 2.5
    assert meta["cameras"]["right"]["exposure_us"] == values["right"]["exposure_us"]
    async with d.http.get("/metrics") as resp:
        text = await resp.text()
    assert 'stereocam_sensor_gain{camera="left"} 2.5' in text
    assert f'stereocam_sensor_exposure_us{{camera="right"}} {values["right"]["exposure_us"]:g}' in text
    assert 'stereocam_sensor_ok{camera="left"} 1' in text
