"""The daemon serves depth from the fabric's stereo core (issue 23, item 5), on the real daemon.

On the emulated fabric the core is its bit-exact model: the disparity view, the depth view, the
point readout and Verify read the core's output; ``/api/stereo`` reads and sets its registers; a
fabric without the core falls back to OpenCV's StereoBM on the ARM, and status says which.
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest

from stereocam.overlays.model.stereo import compute
from stereocam.overlays.spec import pixel
from stereocam.overlays.spec.stereo import DEFAULT_PARAMS, INVALID
from stereocam.server.frames.depth import BY_ARM, BY_CORE, LEFT_Y, RIGHT_Y
from stereocam.server.frames.views import colour_depth, colour_disparity, depth_metres, disparity_map
from stereocam.server.http.state import CALIBRATION, FEED

from .daemon import WAIT_S, H, W, make_overlay, show_pair, wait_for_frames

pytestmark = pytest.mark.slow


async def _png(d: Any, path: str) -> np.ndarray:
    async with d.http.get(path) as resp:
        assert resp.status == 200, await resp.text()
        data = await resp.read()
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None
    return image


async def _rectified(d: Any) -> np.ndarray:
    """The still frame's rectified pair, as the fabric delivers it (every frame the same)."""
    fs = await d.app[FEED].next_frame(timeout=WAIT_S)  # waiting makes the pipeline copy one
    return fs.processed


async def _core_disparity(d: Any, params: Any = DEFAULT_PARAMS) -> np.ndarray:
    p = await _rectified(d)
    return compute(p[..., LEFT_Y].copy(), p[..., RIGHT_Y].copy(), params).disp


def _as_disp16(disp: np.ndarray) -> np.ndarray:
    out = disp.astype(np.int16)
    out[disp == INVALID] = -16
    return out


async def test_status_and_the_views_come_from_the_stereo_core(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d)
    stereo = d.overlay.emulation.stereo
    assert stereo is not None
    status, body = await d.json("GET", "/api/status")
    assert status == 200 and body["disparity"]["by"] == BY_CORE == "stereo core"
    core = body["disparity"]["stereo"]
    assert core["frame_count"] > 0 and core["enabled"] and core["params"] == DEFAULT_PARAMS.as_json()
    assert core["flags"] == {"SIZE_ERROR": False, "CONFIG_ERROR": False}
    assert stereo.computed_frames == 0, "nobody watched the disparity: the emulated core computed nothing"

    disp = await _core_disparity(d)
    view = await _png(d, "/snapshot/disparity.png")
    expected = colour_disparity(_as_disp16(disp))
    assert np.array_equal(view, expected)  # the core's disparity, JET, invalid black
    assert (view[disp == INVALID] == 0).all() and (disp != INVALID).mean() > 0.5

    depth = await _png(d, "/snapshot/depth.png")
    scale = d.app[CALIBRATION].now.frame_calibration.depth
    assert scale is not None and scale.unit_m is not None
    z = depth_metres(_as_disp16(disp), scale)
    assert np.array_equal(depth, colour_depth(z)) and (depth[disp == INVALID] == 0).all()
    valid = np.isfinite(z)
    assert valid.mean() > 0.5 and 1.0 < float(np.median(z[valid])) < 5.0  # the rig's wall is about 3 m away
    assert stereo.computed_frames >= 1


async def test_the_point_readout_reads_the_cores_disparity(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d)
    disp = await _core_disparity(d)
    ys, xs = np.nonzero(disp != INVALID)
    x, y = int(xs[len(xs) // 2]), int(ys[len(ys) // 2])
    status, p = await d.json("GET", f"/api/point?x={x}&y={y}")
    assert status == 200, p
    assert p["disparity_px"] == disp[y, x] / 16
    assert p["depth_m"] == pytest.approx(p["focal_px"] * p["baseline_m"] / p["disparity_px"], rel=1e-6)
    ys, xs = np.nonzero(disp == INVALID)
    status, p = await d.json("GET", f"/api/point?x={int(xs[0])}&y={int(ys[0])}")
    assert status == 200 and p["disparity_px"] is None and p["depth_m"] is None


async def test_get_and_put_the_matchers_registers(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d)
    status, state = await d.json("GET", "/api/stereo")
    assert status == 200 and state["present"] and state["by"] == BY_CORE
    assert state["params"] == state["defaults"] == DEFAULT_PARAMS.as_json()
    assert state["limits"]["num_disp"] == {"min": 32, "max": 128, "multiple_of": 32}
    assert state["limits"]["p2"] == {"min": 0, "max": 193}
    assert state["limits"]["median"] == {"type": "boolean"}
    assert state["build"]["max_disp"] == 128 and state["status"]["enabled"]

    change = {"num_disp": 64, "uniqueness": 30, "median": False}
    status, body = await d.json("PUT", "/api/stereo", json=change)
    assert status == 200 and body["applied"], body
    wanted = DEFAULT_PARAMS.with_values(num_disp=64, uniqueness=30, median=False)
    assert body["params"] == wanted.as_json() and not body["status"]["apply_pending"]
    stereo = d.overlay.emulation.stereo
    assert stereo is not None and stereo.active == wanted  # latched at a frame start
    # The views follow: frames from now on carry the new parameters' output.
    latched = body["status"]["frame_count"]
    await d.app[FEED].next_frame(timeout=WAIT_S, accept=lambda fs: fs.fabric_count > latched)
    view = await _png(d, "/snapshot/disparity.png")
    assert np.array_equal(view, colour_disparity(_as_disp16(await _core_disparity(d, wanted))))

    for change, words in (({"num_disp": 40}, "num_disp = 40: the core takes a multiple of 32"),
                          ({"p1": 70}, "p1 = 70: the core takes a whole number in 0 .. 63"),
                          ({"p2_edge": 150}, "p1 <= p2_edge <= p2"),
                          ({"median": 1}, "median = 1: the core takes true or false")):
        status, body = await d.json("PUT", "/api/stereo", json=change)
        assert status == 422 and words in body["error"] and "previous parameters stay active" in body["error"]
    status, body = await d.json("PUT", "/api/stereo", json={"p3": 1})
    assert status == 400 and "unknown parameter 'p3'" in body["error"]
    status, body = await d.json("PUT", "/api/stereo", json=[1])
    assert status == 400 and "JSON object" in body["error"]
    status, state = await d.json("GET", "/api/stereo")
    assert state["params"] == wanted.as_json() and stereo.active == wanted  # the refusals changed nothing
    assert not state["status"]["flags"]["CONFIG_ERROR"]


async def test_verify_compares_the_cores_disparity_with_the_model(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d)
    rng = np.random.default_rng(5)
    coarse = rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8)
    left = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)
    right = np.ascontiguousarray(np.roll(left, -9, axis=1))
    await show_pair(d, left, right)
    status, report = await d.json("POST", "/api/verify")
    assert status == 200, report
    stereo = report["stereo"]
    assert stereo["compared"] and stereo["identical"] and stereo["differing"] == 0, stereo
    assert stereo["by"] == BY_CORE and stereo["params"] == DEFAULT_PARAMS.as_json()
    assert (stereo["width"], stereo["height"]) == (W, H) and stereo["examples"] == []


async def test_without_a_stereo_core_the_arm_computes_the_disparity(start_daemon) -> None:
    d = await start_daemon(overlay=make_overlay(calibrate=False, stereo=False))
    await wait_for_frames(d)
    status, body = await d.json("GET", "/api/status")
    arm = body["disparity"].pop("arm")
    assert body["disparity"] == {"by": BY_ARM, "stereo": None} and BY_ARM == "ARM, OpenCV StereoBM"
    # off the board StereoBM runs at full size, at the default disparity rate, and status says so
    assert arm == {"scale": 1.0, "size": [W, H], "num_disparities": 128, "block_size": 19, "max_fps": 10.0,
                   "text": "StereoBM at full size, 128 disparities, block 19, at most 10 fps"}
    status, state = await d.json("GET", "/api/stereo")
    assert status == 200 and state == {"present": False, "by": BY_ARM}
    status, body = await d.json("PUT", "/api/stereo", json={"p1": 8})
    assert status == 409 and "no stereo core" in body["error"] and "StereoBM" in body["error"]

    p = await _rectified(d)
    bm = disparity_map(p[..., pixel.LEFT.start + pixel.Y], p[..., pixel.RIGHT.start + pixel.Y])
    view = await _png(d, "/snapshot/disparity.png")
    assert np.array_equal(view, colour_disparity(bm))
    depth = await _png(d, "/snapshot/depth.png")
    assert depth.shape == (H, W, 3) and (depth[bm < 0] == 0).all() and depth.any()

    flat = np.full((H, W, 3), 90, np.uint8)
    await show_pair(d, flat, flat)
    status, report = await d.json("POST", "/api/verify")
    assert status == 200 and report["stereo"]["compared"] is False and report["stereo"]["by"] == BY_ARM


async def test_within_the_boards_budget_the_arm_matches_at_half_size_and_status_says_so(start_daemon) -> None:
    """arm_disparity: half (what `auto` chooses on the board, where StereoBM at full size costs a
    Cortex-A9 seconds a frame): the views and the readout read StereoBM of the half-size pair, in
    full-size pixels, and /api/status says how the ARM computes them and at what rate."""
    d = await start_daemon(overlay=make_overlay(calibrate=False, stereo=False), arm_disparity="half",
                           disparity_fps=2)
    await wait_for_frames(d)
    status, body = await d.json("GET", "/api/status")
    arm = body["disparity"]["arm"]
    assert (arm["scale"], arm["size"], arm["num_disparities"], arm["block_size"], arm["max_fps"]) == (
        0.5, [W // 2, H // 2], 64, 9, 2.0)
    assert arm["text"] == f"StereoBM at half size ({W // 2}x{H // 2}), 64 disparities, block 9, at most 2 fps"
    p = await _rectified(d)
    left, right = p[..., pixel.LEFT.start + pixel.Y], p[..., pixel.RIGHT.start + pixel.Y]
    half = disparity_map(left, right, 0.5)
    assert not np.array_equal(half, disparity_map(left, right)), "the two scales differ on this scene"
    view = await _png(d, "/snapshot/disparity.png")
    assert np.array_equal(view, colour_disparity(half))
    assert (half[half >= 0] % 2 == 0).all(), "1/16 of a half-size pixel, doubled: 1/16 full-size pixels"
