"""stereocam.client against the real daemon (start_daemon, in process): every call, exact values.

The client is synchronous, so each call runs in a thread (``asyncio.to_thread``) while the
daemon serves on the test's loop.
"""
from __future__ import annotations

import asyncio
import hashlib
import io
import json
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any, Callable, TypeVar

import cv2
import numpy as np
import pytest

from stereocam.client import Client, ClientError, Frame, Recording, decode_image
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.spec import pixel

from ..server.daemon import (
    SMALL,
    Daemon,
    rig_frame,
    start_daemon_fixture,  # noqa: F401
    wait_for_frames,
)

pytestmark = pytest.mark.slow

W, H = SMALL
T = TypeVar("T")


async def call(fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """A blocking client call, off the loop the daemon runs on."""
    return await asyncio.to_thread(fn, *args, **kwargs)


def pattern_pair(seed: int = 1) -> "tuple[np.ndarray, np.ndarray]":
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8)
    base = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)
    return base, np.ascontiguousarray(np.roll(base, -12, axis=1))


def model_output(daemon: Daemon, frame: np.ndarray) -> np.ndarray:
    config, options = daemon.overlay.core_setup()
    return RectifyModel(config.left, config.right, config.width, config.height, options).process(frame).frame


async def client_on(start_daemon: Any, **settings: Any) -> "tuple[Daemon, Client]":
    d = await start_daemon(**settings)
    return d, Client(d.url, token=settings.get("access_token"))


async def upload_pattern(d: Daemon, c: Client, seed: int = 1) -> "tuple[np.ndarray, np.ndarray, np.ndarray]":
    """Upload a pattern pair as arrays; (left, right, the model's 8-channel output for it)."""
    left, right = pattern_pair(seed)
    reply = await call(c.upload, left, right)
    assert reply["source"] == "virtual" and (reply["width"], reply["height"]) == (W, H)
    return left, right, model_output(d, pixel.pack(pixel.rgby(left), pixel.rgby(right)))


async def test_status_views_and_snapshots_are_the_daemons_pixels(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    status = await call(c.status)
    assert status["backend"] == "emulated" and status["frame_size"] == [W, H]
    views = await call(c.views)
    names = [v["name"] for v in views]
    assert names[:2] == ["raw_left", "raw_right"] and "disparity" in names and "sbs" in names
    left, right, expected = await upload_pattern(d, c)
    snap = await call(c.snapshot, "rect_left")
    assert isinstance(snap, Frame) and snap.view == "rect_left" and snap.lossy is False and snap.signal
    np.testing.assert_array_equal(snap.image, expected[..., [0, 1, 2]])  # RGB, exactly the model's
    np.testing.assert_array_equal((await call(c.snapshot, "raw_right")).image, right)
    gray = await call(c.snapshot, "rect_right", gray=True)
    np.testing.assert_array_equal(gray.image, expected[..., 7])
    sbs = await call(c.snapshot, "sbs", scale=0.5)
    assert sbs.image.shape == (H // 2, W, 3)
    jpeg = await call(c.snapshot, "rect_left", lossless=False, quality=95)
    assert jpeg.lossy is True and jpeg.image.shape == (H, W, 3) and jpeg.number >= 0
    assert np.abs(jpeg.image.astype(int) - snap.image.astype(int)).mean() < 4  # JPEG: close, not exact


async def test_errors_carry_the_status_and_the_daemons_line(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    with pytest.raises(ClientError) as err:
        await call(c.snapshot, "nope")
    assert err.value.status == 404 and "nope" in err.value.message
    assert str(err.value).startswith("404 GET /snapshot/nope.png: ")
    with pytest.raises(ClientError) as err:
        await call(c.verify)
    assert err.value.status == 409 and "\n" not in err.value.message
    with pytest.raises(ClientError) as err:
        await call(c.set_source, "virtual")
    assert err.value.status == 409
    small = np.zeros((H // 2, W // 2, 3), np.uint8)
    with pytest.raises(ClientError) as err:
        await call(c.upload, small, small)
    assert err.value.status == 422 and "fit" in err.value.message
    with pytest.raises(ValueError):
        await call(c.upload, small)  # a pair needs both
    assert await call(c.source) == "live"  # nothing changed


async def test_mjpeg_stream_gives_frames_and_closes(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    await upload_pattern(d, c)
    with await call(c.stream, "rect_left", fps=10) as stream:
        first = await call(next, stream)
        second = await call(next, stream)
    assert first.view == "rect_left" and first.lossy and first.image.shape == (H, W, 3)
    assert second.number >= first.number and second.timestamp >= first.timestamp
    assert await _clients_drop(c)
    assert await call(next, stream, None) is None  # a closed stream ends


async def _clients_drop(c: Client) -> bool:
    """Wait until the daemon counts no client (a closed connection is noticed at its next write)."""
    while (await call(c.status))["clients"] != 0:
        await asyncio.sleep(0.05)
    return True


async def test_websocket_stream_interleaves_views_and_closes(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    seen: "dict[str, Frame]" = {}
    stream = await call(c.watch, ["rect_left", "disparity"], fps=10, scale=0.5)
    try:
        while len(seen) < 2:
            frame = await call(next, stream)
            seen[frame.view] = frame
    finally:
        await call(stream.close)
    assert seen["rect_left"].image.shape == (H // 2, W // 2, 3) and seen["rect_left"].lossy
    assert seen["disparity"].image.shape == (H // 2, W // 2, 3)
    assert await call(next, stream, None) is None
    assert await _clients_drop(c)
    bad = await call(c.watch, ["nope"])
    with pytest.raises(ClientError) as err:
        await call(next, bad)
    await call(bad.close)
    assert err.value.status is None and "nope" in err.value.message


async def test_the_websocket_stream_works_where_a_loop_already_runs(start_daemon) -> None:
    """As in Jupyter, whose kernel runs an event loop in the thread the notebook's code runs in."""
    d, c = await client_on(start_daemon)

    async def notebook_cell() -> Frame:
        with c.watch(["raw_left"], fps=5) as stream:  # called synchronously, inside a running loop
            return next(stream)

    frame = await call(asyncio.run, notebook_cell())
    assert frame.view == "raw_left" and frame.image.shape == (H, W, 3)


async def test_virtual_camera_preview_and_verify(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    left, right, expected = await upload_pattern(d, c, seed=2)
    vc = await call(c.virtual_camera)
    assert vc["source"] == "virtual" and vc["input"] == "upload (left, right)" and vc["playing"] is None
    result = await call(c.virtual_result, "right")
    np.testing.assert_array_equal(result.image, expected[..., [4, 5, 6]])
    assert result.number == vc["frame"]
    report = await call(c.verify)
    assert report["identical"] is True and report["differing"] == 0 and report["psnr_db"] is None
    diff = await call(c.verify_difference)
    assert diff.shape == (H, 2 * W, 3) and not diff.any()
    small = left[: H - 20, : W - 30]
    preview, fit = await call(c.preview, small, right[: H - 20, : W - 30], fit="pad")
    assert fit["mode"] == "pad" and fit["padded"] == [15, 10, 15, 10] and preview.shape == (H, 2 * W, 3)
    np.testing.assert_array_equal(preview[10:H - 10, 15:W - 15], small)
    sbs = np.concatenate([left, right], axis=1)
    encoded = cv2.imencode(".png", sbs[..., ::-1])[1].tobytes()
    reply = await call(c.upload, sbs=encoded)  # bytes, as a file holds them
    assert reply["input"].startswith("upload")
    np.testing.assert_array_equal((await call(c.snapshot, "raw_left")).image, left)
    assert (await call(c.set_source, "live"))["source"] == "live"
    assert await call(c.source) == "live"
    assert (await call(c.set_source, "virtual"))["source"] == "virtual"


async def test_upload_from_a_file_path(start_daemon, tmp_path: Path) -> None:
    d, c = await client_on(start_daemon)
    left, right = pattern_pair(4)
    paths = []
    for name, img in (("l.png", left), ("r.png", right)):
        cv2.imwrite(str(tmp_path / name), img[..., ::-1])
        paths.append(tmp_path / name)
    await call(c.upload, *paths)
    np.testing.assert_array_equal((await call(c.snapshot, "raw_right")).image, right)


async def test_captures_round_trip_bit_exact(start_daemon, tmp_path: Path) -> None:
    d, c = await client_on(start_daemon)
    left, right, expected = await upload_pattern(d, c, seed=3)
    entry = await call(c.capture)
    cid = entry["id"]
    listing = await call(c.captures)
    assert [e["id"] for e in listing] == [cid]
    info = await call(c.capture_info, cid)
    assert info["meta"]["source"] == "virtual" and info["meta"]["frame_size"] == [W, H]
    for f in listing[0]["files"]:  # every file as stored, bit for bit
        data = await call(c.capture_file, cid, f["name"])
        assert len(data) == f["bytes"]
        if f["sha256"] is not None:  # every image's; meta.json holds the hashes, so not its own
            assert hashlib.sha256(data).hexdigest() == f["sha256"]
    pngs = [f["name"][:-4] for f in listing[0]["files"] if f["name"].endswith(".png")]
    assert [f["name"] for f in listing[0]["files"] if f["sha256"] is None] == ["meta.json"]
    images = await call(c.capture_images, cid)
    assert sorted(images) == sorted(pngs)
    assert {"raw_left", "raw_right", "rect_left", "rect_right"} <= set(images)
    np.testing.assert_array_equal(images["raw_left"], left)
    np.testing.assert_array_equal(images["raw_right"], right)
    np.testing.assert_array_equal(images["rect_left"], expected[..., [0, 1, 2]])
    np.testing.assert_array_equal(images["rect_right"], expected[..., [4, 5, 6]])
    dest = tmp_path / "capture.zip"
    await call(c.download_capture, cid, dest)
    with zipfile.ZipFile(dest) as z:
        stored = {Path(n).name: z.read(n) for n in z.namelist()}
    assert {Path(n).name for n in stored} == {f["name"] for f in listing[0]["files"]}
    assert not (tmp_path / "capture.zip.part").exists()
    disparity = await call(c.capture_disparity, cid)  # the stereo core's codes, 16-bit, exact
    assert disparity.dtype == np.uint16 and np.array_equal(disparity, images["disparity"])
    assert await call(c.cloud, cid) == stored["cloud.ply"]
    assert (await call(c.cloud)).startswith(b"ply\nformat binary_little_endian 1.0\ncomment stereocam")
    buf = io.BytesIO()
    await call(c.download_capture, cid, buf)
    assert zipfile.ZipFile(buf).namelist()
    replay = await call(c.replay_capture, cid)
    assert replay["input"] == f"capture {cid}"
    await call(c.delete_capture, cid)
    assert await call(c.captures) == []
    with pytest.raises(ClientError) as err:
        await call(c.capture_info, cid)
    assert err.value.status == 404
    restored = await call(c.restore_capture, cid)
    assert restored["id"] == cid and [e["id"] for e in await call(c.captures)] == [cid]


async def test_recordings_listed_downloaded_and_opened_as_arrays(start_daemon, tmp_path: Path) -> None:
    d, c = await client_on(start_daemon)
    await wait_for_frames(d, 3)
    started = await call(c.start_recording)
    rid = started["id"]
    assert started["state"] == "recording"
    while (await call(c.recording_info, rid))["frames"] < 3:
        await asyncio.sleep(0.05)
    done = await call(c.stop_recording, rid)
    assert done["state"] == "done" and done["frames"] >= 3
    listing = await call(c.recordings)
    assert [r["id"] for r in listing["recordings"]] == [rid] and listing["recording"] is None
    with await call(c.open_recording, rid) as rec:
        assert rec.id == rid and len(rec) == done["frames"] == rec.meta["frames"]
        raw, _ = rig_frame(SMALL)  # the still source: every frame is this raw pair
        for rl, rr in rec:
            np.testing.assert_array_equal(rl, raw[..., 0:3])
            np.testing.assert_array_equal(rr, raw[..., 4:7])
        last = len(rec) - 1
        np.testing.assert_array_equal(await call(c.recording_frame, rid, last, "right"), rec.pair(last)[1])
    with pytest.raises(ClientError) as err:
        await call(c.recording_frame, rid, done["frames"])
    assert err.value.status == 404
    dest = tmp_path / "rec.zip"
    await call(c.download_recording, rid, dest)
    with Recording(dest) as again:
        assert again.frames == rec.frames
    timed = await call(c.start_recording, 0.2)
    while (await call(c.recording_info, timed["id"]))["state"] != "done":
        await asyncio.sleep(0.05)
    playing = await call(c.play_recording, rid)
    assert playing["input"] == f"recording {rid}" and playing["playing"]["recording"] == rid
    with pytest.raises(ClientError) as err:
        await call(c.delete_recording, rid)  # playing
    assert err.value.status == 409
    await call(c.set_source, "live")
    await call(c.delete_recording, rid)
    with pytest.raises(ClientError) as err:
        await call(c.recording_info, rid)
    assert err.value.status == 404


async def test_cameras_calibration_and_depth(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    cams = await call(c.cameras)
    assert set(cams) == {"left", "right", "health"} and cams["health"]["ok"] is True
    after = await call(c.set_cameras, camera="left", gain=2.0, aec=False)
    assert after["left"]["gain"] == 2.0 and after["left"]["aec"] is False
    assert after["right"]["gain"] == cams["right"]["gain"]
    with pytest.raises(ClientError) as err:
        await call(c.set_cameras, exposure_us=999999)
    assert err.value.status == 400 and "exposure" in err.value.message
    assert (await call(c.cameras))["left"]["gain"] == 2.0  # the refusal changed nothing
    cal = await call(c.calibration)
    assert cal["id"].startswith("synthetic-rig-") and cal["image_size"] == [W, H]
    model = await call(c.calibration_file)
    assert model is not None and model.id == cal["file_id"]
    assert cal["id"] == (await call(c.status))["calibration"]["id"]
    applied = await call(c.set_calibration, model)
    assert applied["id"] == model.id == (await call(c.status))["calibration"]["id"]  # PUT: the file's id
    with pytest.raises(ClientError) as err:
        await call(c.set_calibration, "not: [a calibration")
    assert err.value.status == 400
    info = await call(c.disparity_info)
    assert info["num_disparities"] == 128 and len(info["colors"]) == 256
    p = await call(c.point, W // 2, H // 2)
    rect = (await call(c.snapshot, "rect_left")).image  # the still frame: the same pixels every frame
    px = rect[H // 2, W // 2]
    assert [p["rect_left"][k] for k in "rgb"] == [int(v) for v in px]
    assert p["depth_m"] is None or p["depth_m"] > 0
    with pytest.raises(ClientError) as err:
        await call(c.point, W, 0)
    assert err.value.status == 400
    # Freeze a frame, measure on it, let it go.
    held = await call(c.freeze)
    n = held["frame"]
    assert await call(c.frozen) == [n]
    # Two pixels of that frame the matcher found (the readout says), measured on that frame.
    seen = []
    for x in range(W // 8, W, W // 16):
        for y in (H // 4, H // 2, 3 * H // 4):
            q = await call(c.point, x, y, frame=n)
            if q["disparity_px"] and q["point_m"] is not None:
                seen.append(((x, y), q["point_m"]))
    assert len(seen) >= 2, "the rig's frame has texture to match"
    (a, pa), (b, pb) = seen[0], seen[-1]
    r = await call(c.ruler, a, b, frame=n)
    assert r["frame"] == n and [q["point_m"] for q in r["points"]] == [pa, pb]
    assert r["distance_m"] == pytest.approx(float(np.linalg.norm(np.subtract(pb, pa))))
    with pytest.raises(ClientError) as err:
        await call(c.ruler, a, (W, 0), frame=n)
    assert err.value.status == 400 and "point 2" in err.value.message
    await call(c.release, n)
    assert await call(c.frozen) == []


async def test_the_stereo_core_registers(start_daemon) -> None:
    d, c = await client_on(start_daemon)
    state = await call(c.stereo)
    assert state["present"] is True and state["by"] == "stereo core"
    assert state["params"] == state["defaults"] and state["limits"]["num_disp"]["multiple_of"] == 32
    changed = await call(c.set_stereo, uniqueness=20, median=False)
    assert changed["params"]["uniqueness"] == 20 and changed["params"]["median"] is False
    with pytest.raises(ClientError) as err:
        await call(c.set_stereo, num_disp=40)
    assert err.value.status == 422 and "a multiple of 32" in err.value.message
    assert (await call(c.stereo))["params"] == changed["params"]  # the refusal changed nothing


async def test_the_token_is_sent(start_daemon) -> None:
    d, c = await client_on(start_daemon, access_token="s3cret+/=")
    assert (await call(c.status))["access_token"] is True
    with await call(c.stream, "raw_left", fps=5) as s:
        assert (await call(next, s)).image.shape == (H, W, 3)
    ws = await call(c.watch, ["raw_left"], fps=5)
    try:
        assert (await call(next, ws)).view == "raw_left"
    finally:
        await call(ws.close)
    anon = Client(d.url)
    with pytest.raises(ClientError) as err:
        await call(anon.status)
    assert err.value.status == 401
    with pytest.raises(ClientError) as err:
        await call(anon.watch, ["raw_left"])
    assert err.value.status == 401
    assert "token" in repr(c) and "s3cret" not in repr(c)


def test_decoding_refuses_what_is_not_an_image_or_a_recording() -> None:
    with pytest.raises(ValueError, match="not a readable image"):
        decode_image(b"nope")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("x/other.json", json.dumps({}))
    with pytest.raises(ValueError, match="not a stereocam recording"):
        Recording(io.BytesIO(buf.getvalue()))


def test_the_client_does_not_import_the_daemon() -> None:
    """It talks HTTP only: importing it loads nothing of stereocam.server."""
    code = ("import sys, stereocam.client; "
            "print(sorted(m for m in sys.modules if m.startswith('stereocam.server')))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert out.stdout.strip() == "[]"


def test_every_call_of_the_client_has_a_test_here() -> None:
    """A call added to Client without a test above fails here (the check of issue 24)."""
    source = Path(__file__).read_text()
    calls = [name for name in vars(Client) if not name.startswith("_") and callable(getattr(Client, name))]
    untested = [name for name in calls if f"c.{name}" not in source]
    assert len(calls) >= 30 and untested == []
