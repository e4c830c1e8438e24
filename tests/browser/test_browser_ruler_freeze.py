"""Issue 24, item 4: the ruler and freeze on the live views, in Chromium against the real daemon.

- Ruler (its button, or R): two clicks on the disparity thumbnail place two points (the view is not
  enlarged); the label gives the distance GET /api/ruler gives for those points, within 3 % of the
  synthetic rig's truth (tests/rig_truth.py); the points, the line and the label are drawn over the
  view. Escape clears it; the points can be typed too (Enter measures).
- Freeze (its button, or Z): "frozen at frame N", the disparity view shows frame N, the views stop
  changing while the daemon makes newer frames and encodes none for the page; the depth readout and the
  ruler read frame N (their figures equal the API's for frame=N). Unfreeze: frames flow again and the
  daemon holds no frozen frame.
- No sideways scroll at 1440x900 and 375x812 with the ruler shown.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Tuple

import numpy as np
import pytest
from playwright.sync_api import Page, expect

from ..rig_truth import static_depth
from .chromium import (
    BROWSER_TEST_TIMEOUT,
    DESKTOP,
    PHONE,
    assert_no_sideways_scroll,
    get_json,
    open_in_window,
    wait_new_frames,
    watched_page,
)

pytestmark = [BROWSER_TEST_TIMEOUT, pytest.mark.slow]

# Rectified left pixels on the rig's back wall, far apart (as tests/server/test_ruler_freeze.py).
A, B = (615, 381), (180, 100)


def _client_of(page: Page, view: str, full: Tuple[int, int], px: Tuple[int, int]) -> Tuple[float, float]:
    """Client coordinates of the centre of full-resolution pixel ``px`` of a view's <img> (contained)."""
    box = page.locator(f"#view-{view}").bounding_box()
    assert box is not None
    a, _, b = (page.get_attribute(f"#view-{view}", "data-size") or "").partition("x")
    nat = (int(a), int(b))
    s = min(box["width"] / nat[0], box["height"] / nat[1])
    cw, ch = nat[0] * s, nat[1] * s
    left, top = box["x"] + (box["width"] - cw) / 2, box["y"] + (box["height"] - ch) / 2
    return left + (px[0] + 0.5) * cw / full[0], top + (px[1] + 0.5) * ch / full[1]


def _truth(rect: dict, u: int, v: int) -> np.ndarray:
    z = static_depth(rect, u, v)
    assert z is not None, (u, v)
    P1 = np.asarray(rect["P1"], dtype=np.float64)
    return np.array([(u - P1[0, 2]) / P1[0, 0] * z, (v - P1[1, 2]) / P1[1, 1] * z, z])


def _points(page: Page) -> Tuple[Tuple[int, int], Tuple[int, int]]:
    x0, y0, x1, y1 = (int(page.get_by_test_id(f"ruler-{n}").input_value()) for n in ("x0", "y0", "x1", "y1"))
    return (x0, y0), (x1, y1)


def _query(p: Tuple[int, int], q: Tuple[int, int]) -> str:
    return f"x0={p[0]}&y0={p[1]}&x1={q[0]}&y1={q[1]}"


def test_ruler_and_freeze(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    w, h = get_json(daemon + "/api/status")["frame_size"]
    rect = get_json(daemon + "/api/calibration")["rectification"]
    with watched_page(tmp_path, artifacts_dir, "ruler-freeze.png") as page:
        open_in_window(page, daemon, ["disparity", "rect_left"])
        expect(page.get_by_test_id("disparity-legend")).to_have_attribute("data-ready", "1")

        # The ruler, from its shortcut; two clicks on the disparity thumbnail.
        page.locator("body").press("r")
        expect(page.get_by_test_id("btn-ruler")).to_have_attribute("aria-pressed", "true")
        label = page.get_by_test_id("ruler-label")
        expect(label).to_contain_text("Click point 1")
        for px in (A, B):
            page.mouse.click(*_client_of(page, "disparity", (w, h), px))
        expect(page.locator("figure[data-view=disparity]")).not_to_have_class(re.compile(r"\bview-enlarged\b"))
        expect(label).to_have_attribute("data-distance", re.compile(r"^\d"))
        p, q = _points(page)
        box = page.locator("#view-disparity").bounding_box()
        assert box is not None
        near = math.ceil(max(w / box["width"], h / box["height"])) + 1  # a screen pixel, in frame pixels
        assert all(abs(a - b) <= near for a, b in zip(p + q, A + B, strict=True)), (p, q, near)
        live = float(label.get_attribute("data-distance") or "nan")
        truth = float(np.linalg.norm(_truth(rect, *q) - _truth(rect, *p)))
        assert abs(live - truth) / truth < 0.03, (live, truth)
        newest = get_json(daemon + "/api/ruler?" + _query(p, q))
        assert newest["distance_m"] == pytest.approx(live, rel=0.01)  # the wall does not move
        svg = page.get_by_test_id("ruler-disparity")
        expect(svg).to_be_visible()
        expect(svg.locator("circle")).to_have_count(2)
        expect(svg.locator("line")).to_have_count(1)
        expect(svg.locator(".ruler-label")).to_have_text(re.compile(r"^\d+\.\d+ (c?m)$"))
        expect(page.get_by_test_id("ruler-rect_left").locator("circle")).to_have_count(2)
        assert_no_sideways_scroll(page, "ruler shown at 1440x900")

        # Freeze, from its shortcut: the frame the disparity view shows.
        page.locator("body").press("z")
        state = page.get_by_test_id("freeze-state")
        expect(state).to_have_text(re.compile(r"^frozen at frame \d+$"))
        n = int(state.get_attribute("data-frame") or -1)
        assert page.get_attribute("#view-disparity", "data-frame") == str(n)
        assert get_json(daemon + "/api/freeze")["frozen"] == [n]
        on_screen = "v => { const i = document.getElementById('view-' + v); return [i.dataset.frame, i.src] }"
        shown = {v: page.evaluate(on_screen, v) for v in ("disparity", "rect_left")}
        # The daemon encodes nothing for the page, and makes newer frames: the views do not change.
        page.wait_for_function(
            "async () => (await (await fetch('/api/status')).json()).encoders.length === 0", polling=200)
        page.wait_for_function(
            "async ([q, n]) => (await (await fetch('/api/ruler?' + q)).json()).frame > n + 2",
            arg=[_query(p, q), n], polling=200)
        for v, before in shown.items():
            assert page.evaluate(on_screen, v) == before, v
        # The ruler reads the frozen frame: its figure is the API's for frame=N.
        expect(label).to_have_attribute("data-frame", str(n))
        frozen = get_json(daemon + f"/api/ruler?{_query(p, q)}&frame={n}")
        distance = float(label.get_attribute("data-distance") or "nan")
        assert distance == pytest.approx(frozen["distance_m"], rel=1e-12)
        # So does the depth readout under the pointer.
        page.mouse.move(*_client_of(page, "disparity", (w, h), A))
        # Until the readout answers for the pixel now under the pointer (the one before may still
        # show), read whole: its attributes change together when the next answer lands.
        answer = page.wait_for_function(
            """n => { const r = document.getElementById('readout-disparity');
                     const [x, y] = (r.dataset.pointer || '').split(',');
                     if (r.hidden || r.dataset.x !== x || r.dataset.y !== y || r.dataset.frame !== n)
                         return null;
                     return {...r.dataset}; }""", arg=str(n)).json_value()
        rx, ry = int(answer["x"]), int(answer["y"])
        point = get_json(daemon + f"/api/point?x={rx}&y={ry}&frame={n}")
        assert float(answer["disparity"] or "nan") == point["disparity_px"]
        assert float(answer["depth"] or "nan") == pytest.approx(point["depth_m"], rel=1e-12)
        page.screenshot(path=str(artifacts_dir / "ruler-frozen.png"))

        # Escape clears the ruler; typed points (Enter) measure the frozen frame again.
        page.mouse.move(1, 1)
        page.keyboard.press("Escape")
        expect(svg).to_be_hidden()
        expect(page.get_by_test_id("ruler-x0")).to_have_value("")
        for name, value in zip(("x0", "y0", "x1", "y1"), A + B, strict=True):
            page.get_by_test_id(f"ruler-{name}").fill(str(value))
        page.keyboard.press("Enter")
        expect(label).to_have_attribute("data-frame", str(n))
        expect(label).to_have_attribute("data-distance", re.compile(r"^\d"))
        typed = get_json(daemon + f"/api/ruler?{_query(A, B)}&frame={n}")
        distance = float(label.get_attribute("data-distance") or "nan")
        assert distance == pytest.approx(typed["distance_m"], rel=1e-12)
        expect(svg.locator("circle")).to_have_count(2)

        page.set_viewport_size(PHONE)
        expect(page.get_by_test_id("ruler-box")).to_be_visible()
        assert_no_sideways_scroll(page, "ruler shown and frozen at 375x812")
        page.set_viewport_size(DESKTOP)

        # Unfreeze (the button): frames flow again, the daemon lets the frame go.
        page.get_by_test_id("btn-freeze").click()
        expect(state).to_be_hidden()
        expect(page.get_by_test_id("btn-freeze")).to_have_attribute("aria-pressed", "false")
        wait_new_frames(page, "disparity")
        assert get_json(daemon + "/api/freeze")["frozen"] == []
        assert not math.isnan(float(label.get_attribute("data-distance") or "nan"))
