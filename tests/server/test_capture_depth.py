"""Captures hold depth: the stereo core's disparity (16-bit PNG), its confidence and the point cloud
of the calibration the frame ran with, listed in meta.json, in the zip and at
``GET /api/captures/{id}/cloud.ply``; the newest frame's cloud at ``GET /api/cloud.ply``. Read back
with OpenCV and trimesh on a real daemon on the emulated fabric."""
from __future__ import annotations

import dataclasses
import io
import zipfile
from typing import Any, Dict

import cv2
import numpy as np
import pytest
import trimesh

from stereocam.overlays.model.stereo import compute
from stereocam.overlays.spec.pixel import gray_of
from stereocam.overlays.spec.stereo import DEFAULT_BUILD, DEFAULT_PARAMS, INVALID
from stereocam.server.http.state import CALIBRATION

from .daemon import start_uncalibrated, wait_for_frames

pytestmark = pytest.mark.slow
DEPTH_FILES = {"disparity.png", "confidence.png", "cloud.ply"}


async def get_bytes(d: Any, path: str) -> bytes:
    async with d.http.get(path) as resp:
        assert resp.status == 200, (path, resp.status, await resp.text())
        return await resp.read()


def decode(data: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None
    return image[..., ::-1] if image.ndim == 3 else image


async def rect_gray(d: Any, cid: str, meta: Dict[str, Any], name: str) -> np.ndarray:
    """The stored rectified frame's gray channel, the stereo core's input (capture_images.py's rules)."""
    entry = meta["images"][name]
    image = decode(await get_bytes(d, f"/api/captures/{cid}/{entry['file']}"))
    if entry["y_file"]:
        return decode(await get_bytes(d, f"/api/captures/{cid}/{entry['y_file']}"))
    return image if image.ndim == 2 else gray_of(np.ascontiguousarray(image))


def ply_of(data: bytes) -> trimesh.PointCloud:
    cloud = trimesh.load(io.BytesIO(data), file_type="ply")
    assert isinstance(cloud, trimesh.PointCloud)
    return cloud


async def test_a_capture_stores_disparity_confidence_and_its_cloud(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d)
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        info = await resp.json()
    cid = info["id"]
    assert DEPTH_FILES <= {f["name"] for f in info["files"]}
    async with d.http.get(f"/api/captures/{cid}") as resp:
        meta = (await resp.json())["meta"]
    depth = meta["depth"]
    assert depth["disparity"] == "disparity.png" and depth["confidence"] == "confidence.png"
    assert depth["cloud"] == "cloud.ply" and depth["cloud_unavailable"] is None
    assert DEPTH_FILES <= {f["name"] for f in meta["files"]}  # with their sizes and hashes

    # The disparity and confidence are the stereo core's on the stored rectified gray pair, bit for bit.
    disp = decode(await get_bytes(d, f"/api/captures/{cid}/disparity.png"))
    conf = decode(await get_bytes(d, f"/api/captures/{cid}/confidence.png"))
    left, right = [await rect_gray(d, cid, meta, n) for n in ("rect_left", "rect_right")]
    expected = compute(left, right)
    assert disp.dtype == np.uint16 and np.array_equal(disp, expected.disp)
    assert conf.dtype == np.uint8 and np.array_equal(conf, expected.conf)
    assert depth["valid_pixels"] == int(np.count_nonzero(disp != INVALID)) > 0
    # what computed it, so that `stereocam disparity` can again
    build = {k: v for k, v in dataclasses.asdict(DEFAULT_BUILD).items() if k != "name"}
    assert depth["matcher"] == {"params": DEFAULT_PARAMS.as_json(), "build": build}

    # The cloud: Q [x y d 1] by hand, in metres, coloured by the rectified left image.
    scale = d.app[CALIBRATION].now.frame_calibration.depth
    assert scale is not None and scale.unit_m is not None
    Q = np.asarray(scale.Q)
    ys, xs = np.nonzero(disp != INVALID)
    X, Y, Z, W = Q @ np.stack([xs, ys, disp[ys, xs] / 16.0, np.ones(len(xs))])
    keep = W != 0
    hand = np.stack([X[keep], Y[keep], Z[keep]], axis=1) / W[keep, None] * scale.unit_m
    async with d.http.get(f"/api/captures/{cid}/cloud.ply") as resp:
        assert resp.status == 200
        assert f'filename="{cid}.ply"' in resp.headers["Content-Disposition"]
        data = await resp.read()
    assert data.startswith(b"ply\nformat binary_little_endian 1.0\ncomment stereocam point cloud; frame ")
    cloud = ply_of(data)
    np.testing.assert_allclose(cloud.vertices, hand, rtol=1e-5)
    rect_left = decode(await get_bytes(d, f"/api/captures/{cid}/{meta['images']['rect_left']['file']}"))
    colours = rect_left[ys, xs][keep]
    rgb = colours if colours.ndim == 2 else np.repeat(colours[:, None], 3, axis=1)
    assert np.array_equal(cloud.colors[:, :3], rgb)
    assert 0.2 < np.median(cloud.vertices[:, 2]) < 20  # the synthetic rig's scene, in metres

    # The zip holds them too.
    with zipfile.ZipFile(io.BytesIO(await get_bytes(d, f"/api/captures/{cid}.zip"))) as z:
        assert {f"{cid}/{name}" for name in DEPTH_FILES} <= set(z.namelist())
        assert z.read(f"{cid}/cloud.ply") == data

    # The live frame's cloud: the still source shows the same frame, so the same points.
    live = await get_bytes(d, "/api/cloud.ply")
    np.testing.assert_array_equal(ply_of(live).vertices, cloud.vertices)


async def test_without_a_calibration_there_is_no_cloud_and_it_says_why(start_daemon) -> None:
    d = await start_uncalibrated(start_daemon)
    async with d.http.get("/api/cloud.ply") as resp:
        assert resp.status == 409
        body = await resp.json()
    assert "no point cloud of frame" in body["error"] and "no calibration" in body["error"]
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        info = await resp.json()
    names = {f["name"] for f in info["files"]}
    assert {"disparity.png", "confidence.png"} <= names and "cloud.ply" not in names
    async with d.http.get(f"/api/captures/{info['id']}") as resp:
        depth = (await resp.json())["meta"]["depth"]
    assert depth["cloud"] is None and "no calibration" in depth["cloud_unavailable"]
    async with d.http.get(f"/api/captures/{info['id']}/cloud.ply") as resp:
        assert resp.status == 409
        assert "has no point cloud" in (await resp.json())["error"]
