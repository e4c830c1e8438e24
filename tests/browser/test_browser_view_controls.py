"""Issue 24, item 4: each view's quality, size and rate chosen on the page, the bandwidth and the
glass-to-glass latency shown, and a recording stepped through frame by frame in the capture viewer.

- The Views menu's ⚙ of a view sets its JPEG quality, size and rate: the daemon encodes it so
  (``/api/status`` encoders), the view shows a JPEG of that size, and the choice survives a reload;
  "Show all, first order, all auto" undoes it.
- Each view's caption shows the bytes/s received and its latency in ms; the menu shows the total.
- A recording made on the page opens in the viewer: ←/→, Home/End and the buttons step through
  its frames, the frame number is shown, the pixel readout is the stored PNG's.
- No sideways scroll at 1440x900 and 375x812 with the menu, the settings and the viewer open;
  no console error.
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path
from typing import Any, Dict, List

import cv2
import pytest
from playwright.sync_api import Page, expect

from stereocam.server.frames import views
from stereocam.server.http.settings import Settings

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    DESKTOP,
    PHONE,
    TIMEOUT_MS,
    assert_no_sideways_scroll,
    get_json,
    live_page,
    record_in_page,
    wait_frames,
)
from .test_browser import DAEMON_FPS

pytestmark = [BROWSER_TEST_TIMEOUT, pytest.mark.slow]

VIEWS = list(views.VIEWS)
PAGE_FPS = 15.0  # the page's rate without ?fps= (core.js WS_FPS)
NET = re.compile(r"^\d+(\.\d)? (B|kB|MB)/s · \d+ ms$")


def _encoders(base: str, view: str) -> List[Dict[str, Any]]:
    encoders: List[Dict[str, Any]] = get_json(base + "/api/status")["encoders"]
    return [e for e in encoders if e["view"] == view and e["subscribers"] > 0]


def _wait_encoded_as(base: str, view: str, **want: Any) -> None:
    """Until the daemon's only encoder of ``view`` has ``want`` (quality, scale, asked_fps)."""
    deadline = time.monotonic() + TIMEOUT_MS / 1000
    while True:
        got = _encoders(base, view)
        if len(got) == 1 and all(got[0][k] == v for k, v in want.items()):
            return
        assert time.monotonic() < deadline, f"{view}: encoders {got}, wanted {want}"
        time.sleep(0.1)


def _choose(page: Page, view: str, quality: str, size: str, fps: str) -> None:
    page.get_by_test_id(f"views-quality-{view}").select_option(quality)
    page.get_by_test_id(f"views-scale-{view}").select_option(size)
    page.get_by_test_id(f"views-fps-{view}").select_option(fps)


def test_a_views_quality_size_and_rate_are_chosen_shown_and_remembered(tmp_path: Path,
                                                                         artifacts_dir: Path) -> None:
    with live_page(tmp_path, artifacts_dir, "view-controls.png", fps=DAEMON_FPS,
                   viewport=DESKTOP) as (base, page):
        width, height = get_json(base + "/api/status")["frame_size"]
        wait_frames(page, VIEWS)
        page.get_by_test_id("views-menu-open").click()
        expect(page.get_by_test_id("views-opts-row-rect_left")).to_be_hidden()
        page.get_by_test_id("views-opts-rect_left").click()
        expect(page.get_by_test_id("views-opts-row-rect_left")).to_be_visible()
        expect(page.get_by_test_id("views-quality-rect_left")).to_have_value("auto")
        _choose(page, "rect_left", "30", "0.25", "2")
        expect(page.get_by_test_id("views-fps-rect_left")).to_be_focused()
        assert_no_sideways_scroll(page, "a view's settings open at 1440x900")
        _wait_encoded_as(base, "rect_left", quality=30, scale=0.25, asked_fps=2.0)
        page.wait_for_function("s => document.getElementById('view-rect_left')?.dataset.size === s",
                               arg=f"{width // 4}x{height // 4}")
        # Bandwidth and latency, per view and in all, from the frames received.
        for view in ("rect_left", "disparity"):
            net = page.get_by_test_id(f"net-{view}")
            expect(net).to_have_text(NET)
            page.wait_for_function(
                "v => { const d = document.getElementById('net-' + v)?.dataset;"
                " return d && Number(d.bps) > 0 && Number(d.latencyMs) > 0; }", arg=view)
        total = page.get_by_test_id("bw-total")
        expect(total).to_have_text(re.compile(r"^Received: \d+(\.\d)? (kB|MB)/s in all$"))
        per_view = page.evaluate(
            "() => [...document.querySelectorAll('.view-net')]"
            ".reduce((a, e) => a + Number(e.dataset.bps || 0), 0)")
        assert per_view > 0 and int(total.get_attribute("data-bps") or 0) > 0
        # The smaller, rarer, lower-quality view costs less than a full-rate one of the same size.
        page.wait_for_function(
            "() => Number(document.getElementById('net-rect_left').dataset.bps)"
            " < Number(document.getElementById('net-rect_right').dataset.bps)")
        page.get_by_test_id("views-menu-open").click()  # closes the menu
        assert_no_sideways_scroll(page, "captions with bandwidth and latency at 1440x900")

        # Kept with the layout: after a reload the daemon is asked the same.
        page.reload()
        wait_frames(page, VIEWS)
        _wait_encoded_as(base, "rect_left", quality=30, scale=0.25, asked_fps=2.0)
        page.get_by_test_id("views-menu-open").click()
        page.get_by_test_id("views-opts-rect_left").click()
        expect(page.get_by_test_id("views-quality-rect_left")).to_have_value("30")
        expect(page.get_by_test_id("views-scale-rect_left")).to_have_value("0.25")
        expect(page.get_by_test_id("views-fps-rect_left")).to_have_value("2")
        stored = json.loads(page.evaluate("() => localStorage.getItem('stereocam.views-layout')"))
        assert stored["settings"]["rect_left"] == {"quality": 30, "scale": 0.25, "fps": 2}

        # All auto again: the daemon's default quality, the page's rate.
        page.get_by_test_id("views-reset").click()
        expect(page.get_by_test_id("views-quality-rect_left")).to_have_value("auto")
        _wait_encoded_as(base, "rect_left", quality=Settings().default_quality, asked_fps=PAGE_FPS)


def test_view_settings_on_a_phone_have_no_sideways_scroll(tmp_path: Path, artifacts_dir: Path) -> None:
    with live_page(tmp_path, artifacts_dir, "view-controls-phone.png", fps=DAEMON_FPS,
                   viewport=PHONE) as (base, page):
        width, height = get_json(base + "/api/status")["frame_size"]
        wait_frames(page, VIEWS)
        expect(page.get_by_test_id("net-rect_left")).to_have_text(NET)
        assert_no_sideways_scroll(page, "captions with bandwidth and latency at 375x812")
        page.get_by_test_id("views-menu-open").click()
        page.get_by_test_id("views-opts-sbs").click()
        assert_no_sideways_scroll(page, "a view's settings open at 375x812")
        page.get_by_test_id("views-scale-sbs").select_option("1")
        _wait_encoded_as(base, "sbs", scale=1.0)
        page.wait_for_function("s => document.getElementById('view-sbs')?.dataset.size === s",
                               arg=f"{2 * width}x{height}")
        assert_no_sideways_scroll(page, "a view at a chosen size at 375x812")


def _readout_matches_file(page: Page, png: Path) -> None:
    """Point at a pixel: the viewer's values are the stored PNG's (RGB)."""
    box = page.get_by_test_id("cv-canvas").bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + box["width"] * 0.37, box["y"] + box["height"] * 0.41)
    readout = page.get_by_test_id("cv-readout")
    expect(readout).to_have_attribute("data-x", re.compile(r"^\d+$"))
    x, y = int(readout.get_attribute("data-x") or -1), int(readout.get_attribute("data-y") or -1)
    values = json.loads(readout.get_attribute("data-values") or "{}")
    b, g, r = (int(c) for c in cv2.imread(str(png), cv2.IMREAD_COLOR)[y, x])
    assert (values["r"], values["g"], values["b"]) == (r, g, b), (x, y, values)


@pytest.mark.parametrize("viewport", [DESKTOP, PHONE], ids=["1440x900", "375x812"])
def test_a_recording_is_stepped_through_frame_by_frame(tmp_path: Path, artifacts_dir: Path,
                                                       viewport: Dict[str, int]) -> None:
    with live_page(tmp_path, artifacts_dir, f"recording-steps-{viewport['width']}.png", fps=DAEMON_FPS,
                   viewport=viewport) as (base, page):
        item = record_in_page(page, 2)
        frames = int(item.get_attribute("data-frames") or 0)
        assert frames >= 3, frames
        rid = item.get_attribute("data-id")
        folder = tmp_path / "recordings" / str(rid)
        item.get_by_test_id("recording-view").click()
        canvas = page.get_by_test_id("cv-canvas")
        expect(canvas).to_have_attribute("data-loaded", "left:0")
        expect(page.get_by_test_id("cv-frame")).to_have_text(f"frame 0 / {frames - 1}")
        expect(page.get_by_test_id("cv-prev")).to_be_disabled()
        expect(page.get_by_test_id("cv-first")).to_be_disabled()
        expect(page.get_by_test_id("cv-replay")).to_be_hidden()  # a capture's, not a recording's
        assert_no_sideways_scroll(page, "a recording in the viewer")
        _readout_matches_file(page, folder / "left_000000.png")

        page.keyboard.press("ArrowRight")
        expect(canvas).to_have_attribute("data-loaded", "left:1")
        expect(page.get_by_test_id("cv-frame")).to_have_text(f"frame 1 / {frames - 1}")
        _readout_matches_file(page, folder / "left_000001.png")
        page.keyboard.press("End")
        expect(canvas).to_have_attribute("data-loaded", f"left:{frames - 1}")
        expect(page.get_by_test_id("cv-next")).to_be_disabled()
        page.keyboard.press("ArrowRight")  # past the last: stays on it
        expect(page.get_by_test_id("cv-frame")).to_have_text(f"frame {frames - 1} / {frames - 1}")
        page.get_by_test_id("cv-prev").click()
        expect(canvas).to_have_attribute("data-loaded", f"left:{frames - 2}")
        page.keyboard.press("Home")
        expect(canvas).to_have_attribute("data-loaded", "left:0")
        page.get_by_test_id("cv-side-right").click()
        expect(canvas).to_have_attribute("data-loaded", "right:0")
        page.get_by_test_id("cv-next").click()
        expect(canvas).to_have_attribute("data-loaded", "right:1")
        _readout_matches_file(page, folder / "right_000001.png")
        page.get_by_test_id("cv-last").click()
        expect(canvas).to_have_attribute("data-loaded", f"right:{frames - 1}")
        assert_no_sideways_scroll(page, "a recording stepped to its last frame")
        page.keyboard.press("Escape")
        expect(page.get_by_test_id("capture-viewer")).to_be_hidden()
