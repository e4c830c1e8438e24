"""The stereo tools (issue 24, item 4): row alignment of a rectified pair, exposure histograms."""
from __future__ import annotations

import base64
from typing import Tuple

import cv2
import numpy as np
import pytest

from stereocam.overlays.spec import pixel
from stereocam.server.frames.tools import MAX_REPORTED, MIN_MATCHES, alignment, alignment_of, histogram
from stereocam.server.frames.views import render
from stereocam.server.http.state import FEED, VIRTUAL

from .daemon import H, W, show_pair


def textured(w: int, h: int, seed: int = 1) -> np.ndarray:
    """A gray scene with corners everywhere (blurred noise, stretched to 0..255)."""
    rng = np.random.default_rng(seed)
    noise = (rng.random((h, w)) * 255).astype(np.uint8)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2), None, 0, 255, cv2.NORM_MINMAX)


def rectified_pair(dy: int, w: int = 752, h: int = 480, disparity: int = 12) -> Tuple[np.ndarray, np.ndarray]:
    """Left and right views of one scene, the right ``disparity`` px to the left and ``dy`` rows down."""
    scene = textured(w + 2 * disparity + 40, h + 40)
    left = scene[20:20 + h, 20:20 + w]
    right = scene[20 - dy:20 - dy + h, 20 + disparity:20 + disparity + w]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


# -- alignment, as a function -------------------------------------------------------------------

def test_aligned_pair_rows_agree() -> None:
    left, right = rectified_pair(0)
    found = alignment(left, right)
    assert found.enough and found.count >= 100
    assert found.median_dy is not None and found.median_dy <= 0.05
    assert found.mean_dy is not None and abs(found.mean_dy) <= 0.1
    assert len(found.matches) == min(found.count, MAX_REPORTED)
    on_place = [abs(xl - xr - 12) <= 0.5 and abs(yr - yl) <= 0.5 for xl, yl, xr, yr in found.matches]
    assert sum(on_place) >= 0.9 * len(on_place)  # the disparity is 12 px: the matches sit where they should


@pytest.mark.parametrize("dy", [2, -3])
def test_pair_shifted_vertically_reports_the_shift(dy: int) -> None:
    left, right = rectified_pair(dy)
    found = alignment(left, right)
    assert found.enough and found.count >= 100
    assert found.median_dy == pytest.approx(abs(dy), abs=0.1)
    assert found.mean_dy == pytest.approx(dy, abs=0.3)  # signed: right row minus left row
    assert found.p90_dy is not None and found.p90_dy >= found.median_dy
    js = found.to_json()
    assert js["matches_count"] == found.count and js["median_dy_px"] == found.median_dy
    assert js["enough"] is True and js["min_matches"] == MIN_MATCHES


def test_featureless_pair_has_too_few_matches() -> None:
    flat = np.full((480, 752), 128, np.uint8)
    found = alignment(flat, flat.copy())
    assert found.count == 0 and not found.enough
    assert found.median_dy is None and found.p90_dy is None and found.matches == []
    assert found.to_json()["enough"] is False


# -- histogram, as a function -------------------------------------------------------------------

def test_histogram_is_bincount_and_clipping_is_exact() -> None:
    rng = np.random.default_rng(5)
    bgr = rng.integers(1, 255, (30, 40, 3), dtype=np.uint8)
    bgr[0, :10] = (255, 10, 10)    # 10 pixels clipped high (one channel)
    bgr[1, :4] = (0, 0, 0)         # 4 pixels black in every channel
    bgr[2, :3] = (0, 50, 50)       # 3 pixels at 0 in one channel only: not clipped low
    y = rng.integers(0, 256, (30, 40), dtype=np.uint8)
    out = histogram(bgr, y)
    n = 30 * 40
    assert out["pixels"] == n and out["bins"] == 256 and (out["width"], out["height"]) == (40, 30)
    for name, channel in zip("bgr", range(3), strict=True):
        assert out["histogram"][name] == np.bincount(bgr[..., channel].ravel(), minlength=256).tolist()
    assert out["histogram"]["y"] == np.bincount(y.ravel(), minlength=256).tolist()
    assert out["clipped_high"] == 10 / n and out["clipped_low"] == 4 / n
    assert out["at_255"]["b"] == 10 / n and out["at_0"]["b"] == 7 / n and out["at_0"]["g"] == 4 / n
    assert out["at_0"]["y"] == int((y == 0).sum()) / n
    mask = cv2.imdecode(np.frombuffer(out["mask_png"], np.uint8), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (30, 40, 4)
    assert (mask[..., 3] > 0).sum() == 14
    assert tuple(mask[0, 0]) == (0, 0, 255, 255) and tuple(mask[1, 0]) == (255, 96, 0, 255)
    assert mask[2, 0, 3] == 0


# -- over HTTP ------------------------------------------------------------------------------------

async def _get_after(d, path: str, frame: int):
    """``GET path`` until it answers about a frame at or after ``frame`` (the uploaded pair)."""
    while True:
        async with d.http.get(path) as resp:
            body = await resp.json()
            if body.get("frame", -1) >= frame:
                return resp.status, body


async def test_api_alignment_of_a_shifted_pair(start_daemon) -> None:
    """The answer is :func:`alignment` of the frame's rectified pair (the rig's rectification warps
    the uploaded pair, so its 2 rows become other offsets: the exact 2 px is tested above)."""
    d = await start_daemon()
    left, right = rectified_pair(2, W, H)
    frame = (await show_pair(d, left, right))["frame"]
    status, body = await _get_after(d, "/api/alignment", frame)
    assert status == 200, body
    fs = d.app[FEED].last_frame  # the same still input: the same rectified pair as the answer's frame
    assert fs is not None and fs.frame >= frame
    expected = alignment(render(fs, "rect_left", True), render(fs, "rect_right", True))
    assert body["median_dy_px"] == expected.median_dy and body["p90_dy_px"] == expected.p90_dy
    assert body["matches_count"] == expected.count and body["matches"] == expected.matches
    assert alignment_of(fs) is alignment_of(fs)  # once per frame: every poll of it shares the answer
    assert body["enough"] is True and body["matches_count"] >= MIN_MATCHES
    assert (body["width"], body["height"]) == (W, H) and body["source"] == "virtual"
    assert all(len(m) == 4 for m in body["matches"])
    async with d.http.get("/api/alignment?x=1") as resp:
        assert resp.status == 400 and "unknown query parameter" in (await resp.json())["error"]


async def test_api_alignment_of_a_featureless_pair_is_422(start_daemon) -> None:
    d = await start_daemon()
    flat = np.full((H, W), 128, np.uint8)
    frame = (await show_pair(d, flat, flat))["frame"]
    status, body = await _get_after(d, "/api/alignment", frame)
    assert status == 422
    assert body["error"].startswith("too few features") and "textured" in body["error"]
    assert body["matches_count"] == 0 and body["median_dy_px"] is None and body["enough"] is False


async def test_api_histogram_of_the_raw_frame(start_daemon) -> None:
    d = await start_daemon()
    left = textured(W, H, 7)
    left[:5] = 255  # 5 rows clipped high
    left[5:8] = 0   # 3 rows black
    right = textured(W, H, 8)
    frame = (await show_pair(d, left, right))["frame"]
    status, body = await _get_after(d, "/api/histogram", frame)
    assert status == 200
    raw = d.app[VIRTUAL].input
    n = W * H
    assert set(body["views"]) == {"raw_left", "raw_right"}
    for view, cam in (("raw_left", pixel.LEFT), ("raw_right", pixel.RIGHT)):
        got = body["views"][view]
        for name, ch in (("r", pixel.R), ("g", pixel.G), ("b", pixel.B), ("y", pixel.Y)):
            plane = raw[..., cam.start + ch]
            assert got["histogram"][name] == np.bincount(plane.ravel(), minlength=256).tolist()
        mask = cv2.imdecode(np.frombuffer(base64.b64decode(got["mask_png"].split(",", 1)[1]), np.uint8),
                            cv2.IMREAD_UNCHANGED)
        assert mask.shape == (H, W, 4)
    lg = body["views"]["raw_left"]
    high = int((raw[..., 0:3] == 255).any(axis=2).sum())
    low = int((raw[..., 0:3] == 0).all(axis=2).sum())
    assert high >= 5 * W and low >= 3 * W
    assert lg["clipped_high"] == high / n and lg["clipped_low"] == low / n
    status, one = await _get_after(d, "/api/histogram?view=raw_right&mask=0", frame)
    assert status == 200 and list(one["views"]) == ["raw_right"]
    assert "mask_png" not in one["views"]["raw_right"]
    async with d.http.get("/api/histogram?view=rect_left") as resp:
        assert resp.status == 400 and "not a raw camera view" in (await resp.json())["error"]
    async with d.http.get("/api/histogram?mask=2") as resp:
        assert resp.status == 400
