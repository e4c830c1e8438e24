"""The ruler (``GET /api/ruler``) and freeze (``/api/freeze``) of issue 24, item 4, on the real daemon.

The ruler's numbers are checked against the calibration's maths (``[X Y Z W] = Q [x y d 1]`` with the
block matcher's own disparity of the held frame) and against the synthetic rig's truth
(``tests/rig_truth.py``: the back wall's depth at a rectified pixel); a frozen frame is read whatever
the feed has moved on to, and a released or pushed-out one gets 410.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Dict, List, Tuple

import numpy as np
import pytest

from stereocam.server.frames.held import PINNED_MAX
from stereocam.server.frames.views import disparity_raw
from stereocam.server.http.state import CALIBRATION, ENCODERS, FEED

from ..rig_truth import static_depth
from .daemon import FULL, WAIT_S, make_overlay, wait_for_frames

pytestmark = pytest.mark.slow

# Rectified left pixels on the rig's back wall, never reached by its moving planes, far apart (a
# long distance is measured to a few per cent although each depth is only good to 2 %).
A, B = (615, 381), (180, 100)


def _truth_point(rect: Dict[str, Any], u: int, v: int) -> np.ndarray:
    """The rig's true 3-D point (metres, rectified left camera) at rectified left pixel (u, v)."""
    z = static_depth(rect, u, v)
    assert z is not None, (u, v)
    P1 = np.asarray(rect["P1"], dtype=np.float64)
    return np.array([(u - P1[0, 2]) / P1[0, 0] * z, (v - P1[1, 2]) / P1[1, 1] * z, z])


async def _get(d: Any, path: str) -> Tuple[int, Dict[str, Any]]:
    async with d.http.get(path) as resp:
        return resp.status, await resp.json()


async def _freeze(d: Any, body: Any = None) -> Tuple[int, Dict[str, Any]]:
    kwargs = {} if body is None else {"json": body}
    async with d.http.post("/api/freeze", **kwargs) as resp:
        return resp.status, await resp.json()


async def _next_frame_after(d: Any, frame: int) -> None:
    """Wait until the feed has a frame newer than ``frame`` (waiting makes the pipeline copy one)."""
    await d.app[FEED].next_frame(timeout=WAIT_S, accept=lambda fs: fs.frame > frame)


async def test_ruler_measures_the_frozen_frame_by_the_calibration_and_the_rig(start_daemon) -> None:
    # The ARM's StereoBM (a fabric without the stereo core): its disparity is within 2 % of the rig's
    # truth at A and B; the core's, read by the ruler where there is one, in test_stereo_daemon.py.
    d = await start_daemon(overlay=make_overlay(size=FULL, fps=5.0, calibrate=False, stereo=False))
    await wait_for_frames(d)
    rect = d.app[CALIBRATION].now.calibration.rect
    rectification = {"R1": rect.R1.tolist(), "P1": rect.P1.tolist()}
    Q = np.asarray(rect.Q, dtype=np.float64)

    status, frozen = await _freeze(d)
    assert status == 200, frozen
    n = frozen["frame"]
    assert frozen["frozen"] == [n] and frozen["max_frozen"] == PINNED_MAX and frozen["released"] == []
    assert (await _get(d, "/api/freeze"))[1]["frozen"] == [n]
    await _next_frame_after(d, n)  # the feed moved on: the answers are still the frozen frame's

    status, r = await _get(d, f"/api/ruler?x0={A[0]}&y0={A[1]}&x1={B[0]}&y1={B[1]}&frame={n}")
    assert status == 200, r
    assert r["frame"] == n and r["calibration_id"] is not None
    held = d.app[ENCODERS].held.pinned[n]
    disp = disparity_raw(held)
    points = []
    for (x, y), p in zip((A, B), r["points"], strict=True):
        assert (p["x"], p["y"]) == (x, y)
        assert p["disparity_px"] == disp[y, x] / 16 > 0  # the frozen frame's own disparity
        X, Y, Z, W = Q @ np.array([x, y, p["disparity_px"], 1.0])
        assert p["point_m"] == pytest.approx([X / W, Y / W, Z / W], rel=1e-9)
        assert p["depth_m"] == pytest.approx(r["focal_px"] * r["baseline_m"] / p["disparity_px"], rel=1e-9)
        truth = _truth_point(rectification, x, y)
        assert abs(p["depth_m"] - truth[2]) / truth[2] < 0.02, (p, truth)
        points.append(np.array(p["point_m"]))
        # the point readout of the frozen frame says the same
        status, q = await _get(d, f"/api/point?x={x}&y={y}&frame={n}")
        assert status == 200 and q["frame"] == n and q["disparity_px"] == p["disparity_px"], q
    assert r["distance_m"] == pytest.approx(float(np.linalg.norm(points[1] - points[0])), rel=1e-9)
    true_distance = float(np.linalg.norm(_truth_point(rectification, *B) - _truth_point(rectification, *A)))
    assert abs(r["distance_m"] - true_distance) / true_distance < 0.03, (r["distance_m"], true_distance)

    # Released: that frame is gone, and the API says so and what to do.
    async with d.http.delete(f"/api/freeze/{n}") as resp:
        assert resp.status == 200 and (await resp.json())["frozen"] == []
    async with d.http.delete(f"/api/freeze/{n}") as resp:
        assert resp.status == 404 and "not frozen" in (await resp.json())["error"]
    for path in (f"/api/ruler?x0=1&y0=1&x1=2&y1=2&frame={n}", f"/api/point?x=1&y=1&frame={n}"):
        status, body = await _get(d, path)
        assert status == 410 and "freeze again" in body["error"], (path, body)
    # A live page's readout and ruler may take the newest instead (no error), and learn which frame.
    ruler = f"/api/ruler?x0={A[0]}&y0={A[1]}&x1={B[0]}&y1={B[1]}&frame={n}"
    for path in (ruler, f"/api/point?x=1&y=1&frame={n}"):
        status, body = await _get(d, path + "&fallback=newest")
        assert status == 200 and body["frame"] > n, (path, body)
        status, body = await _get(d, path + "&fallback=oldest")
        assert status == 400 and "the only fallback is newest" in body["error"], (path, body)


async def test_freeze_holds_a_few_frames_and_pushes_the_oldest_out(start_daemon) -> None:
    d = await start_daemon(overlay=make_overlay(size=FULL, fps=5.0, calibrate=False))
    await wait_for_frames(d)
    pinned: List[int] = []
    for _ in range(PINNED_MAX + 1):
        status, body = await _freeze(d)
        assert status == 200, body
        pinned.append(body["frame"])
        await _next_frame_after(d, body["frame"])
    assert body["released"] == [pinned[0]] and body["frozen"] == pinned[1:]
    status, body = await _get(d, f"/api/ruler?x0={A[0]}&y0={A[1]}&x1={B[0]}&y1={B[1]}&frame={pinned[0]}")
    assert status == 410 and f"frame {pinned[0]} is no longer held" in body["error"], body
    status, body = await _get(d, f"/api/ruler?x0={A[0]}&y0={A[1]}&x1={B[0]}&y1={B[1]}&frame={pinned[1]}")
    assert status == 200 and body["frame"] == pinned[1], body
    # Freezing a given frame: one still held is pinned again; one long gone is 410.
    status, body = await _freeze(d, {"frame": pinned[1]})
    assert status == 200 and body["frame"] == pinned[1] and body["frozen"][-1] == pinned[1], body
    status, body = await _freeze(d, {"frame": 10 ** 12})
    assert status == 410 and "freeze again" in body["error"], body


async def test_ruler_and_freeze_refuse_bad_input_with_what_to_do(start_daemon) -> None:
    d = await start_daemon(overlay=make_overlay(size=FULL, fps=5.0, calibrate=False))
    await wait_for_frames(d)
    w, h = FULL
    for query, words in ((f"x0={w}&y0=1&x1=1&y1=1", "point 1: x0 = 752 is outside the image"),
                         ("x0=1&y0=1&x1=1&y1=-1", "point 2: y1 = -1 is outside the image"),
                         ("x0=1&y0=1&x1=1", "point 2: give y1"),
                         ("x0=a&y0=1&x1=1&y1=1", "point 1: x0 must be a whole number"),
                         ("x0=1&y0=1&x1=1&y1=1&z=1", "unknown query parameter 'z'"),
                         ("x0=1&y0=1&x1=1&y1=1&frame=x", "frame must be a whole number")):
        status, body = await _get(d, "/api/ruler?" + query)
        assert status == 400 and words in body["error"], (query, body)
    # A point without a disparity (the left border, which the right camera does not see): 422 naming it.
    status, frozen = await _freeze(d)
    n = frozen["frame"]
    assert disparity_raw(d.app[ENCODERS].held.pinned[n])[240, 5] < 0  # the block matcher found none
    status, body = await _get(d, f"/api/ruler?x0={A[0]}&y0={A[1]}&x1=5&y1=240&frame={n}")
    assert status == 422, body
    assert body["error"].startswith(f"point 2 (x 5, y 240) has no disparity in frame {n}"), body
    assert "pick a point on a textured surface" in body["error"]
    for bad, words in (({"frame": "x"}, "frame must be a frame number"), ({"frame": -1}, "frame must be"),
                       ({"frame": 1, "z": 2}, 'send {"frame": N}'), ([1], 'send {"frame": N}')):
        status, body = await _freeze(d, bad)
        assert status == 400 and words in body["error"], (bad, body)
    async with d.http.delete("/api/freeze/abc") as resp:
        assert resp.status == 400
    assert (await _get(d, "/api/freeze"))[1]["frozen"] == [n]  # refusals lose nothing
    # No calibration: 409 saying why there is no depth and what to do.
    in_effect = d.app[CALIBRATION]
    in_effect.swap(dataclasses.replace(in_effect.now, calibration=None))
    await _next_frame_after(d, n)
    status, body = await _get(d, f"/api/ruler?x0={A[0]}&y0={A[1]}&x1={B[0]}&y1={B[1]}")
    assert status == 409 and "no distances without depth" in body["error"], body
    assert "apply one in the calibration panel" in body["error"]
