"""Issue 24, items 1, 4 and 8: the page stays in the window, its messages behave, small fixes.

- Width (item 1 and the issue's check): in every state these tests put the page in (each panel
  opened, each preview shown, a view enlarged), the page is no wider than the window, at
  1440x900 and 375x812 (:func:`.chromium.assert_no_sideways_scroll`). A 707x481 pair with
  fit=pad draws its 1504 px preview inside the 340 px panel.
- Messages (item 4): a non-image file gives no page message per change (the fit preview says it
  beside the chooser); Send gives one error, and Send again still one; messages never cover
  the views (on a phone they sit above them, and a notice leads to an error out of sight); the
  wrong-size message names the page's chooser, not the API's parameter; the
  cameras stalled while the calibration panel looks for corners is a warning in the panel that
  goes when the frames come back, not a page error.
- Calibration panel, captures, views (item 8): opening the panel asks for no candidate that does
  not exist (no 404); a view's caption keeps its name apart from its frame number; a capture's
  id is shown whole and its time in local time; the disparity scale's labels do not overlap.

Same approach as ``tests/browser/test_browser.py``; screenshots in the artifacts folder.
"""
from __future__ import annotations

import json
import re
import urllib.request
from pathlib import Path
from typing import Any, Dict, List, Optional

import pytest
from playwright.sync_api import Page, Response, expect

from stereocam.bench.serve import running_daemon

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    DESKTOP,
    PHONE,
    TIMEOUT_MS,
    assert_messages_clear_of_views,
    assert_no_sideways_scroll,
    daemon_config,
    open_in_window,
    watched_page,
)
from .test_browser import DAEMON_FPS, _pattern_pair, _write_png

pytestmark = BROWSER_TEST_TIMEOUT

WAIT_S = TIMEOUT_MS / 1000
EXPECTED = ("status of 415", "status of 422", "status of 503")
WINDOWS = pytest.mark.parametrize("window", [DESKTOP, PHONE], ids=["1440x900", "375x812"])


def _post(url: str, body: Optional[Dict[str, Any]] = None, method: str = "POST") -> Dict[str, Any]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json"} if data else {})
    with urllib.request.urlopen(req, timeout=WAIT_S) as resp:
        text = resp.read()
        return json.loads(text) if text else {}


def _open(page: Page, base: str, window: Dict[str, int]) -> None:
    open_in_window(page, base, ["raw_left"], window)
    expect(page.get_by_test_id("conn")).to_have_text("live")
    assert_no_sideways_scroll(page, "loaded")


@WINDOWS
def test_fit_preview_stays_in_the_panel_and_upload_messages_do_not_pile_up(
        daemon: str, window: Dict[str, int], tmp_path: Path, artifacts_dir: Path) -> None:
    left, right = _pattern_pair(707, 481)
    pair = [_write_png(tmp_path / "left.png", left), _write_png(tmp_path / "right.png", right)]
    text = tmp_path / "notes.txt"
    text.write_text("not an image\n")
    errors_shown = "[data-testid=message-error]"
    name = f"layout-fit-{window['width']}.png"
    with watched_page(tmp_path, artifacts_dir, name, expected=EXPECTED) as page:
        _open(page, daemon, window)
        errors = page.locator(errors_shown)
        info = page.get_by_test_id("fit-info")

        # exact (the default) and a 707x481 pair: the preview says what to click, in the panel.
        page.get_by_test_id("upload-left").set_input_files(str(pair[0]))
        page.get_by_test_id("upload-right").set_input_files(str(pair[1]))
        expect(info).to_have_attribute("data-problem", "422")
        expect(info).to_contain_text("choose crop, pad or scale")
        assert "fit=" not in (info.text_content() or "")
        assert errors.count() == 0
        assert_no_sideways_scroll(page, "fit exact refused")

        # pad: the 1504 px preview is drawn inside the panel, the page keeps the window's width.
        page.get_by_test_id("upload-fit").select_option("pad")
        figure = page.get_by_test_id("fit-figure")
        expect(figure).to_have_attribute("data-from", "707x481")
        page.wait_for_function("() => document.getElementById('fit-preview').naturalWidth > 0")
        img = page.get_by_test_id("fit-preview").bounding_box()
        panel = page.get_by_test_id("upload-form").bounding_box()
        assert img is not None and panel is not None
        assert img["width"] <= panel["width"], (img, panel)
        assert img["x"] >= panel["x"] and img["x"] + img["width"] <= panel["x"] + panel["width"] + 0.5
        assert_no_sideways_scroll(page, "fit pad preview shown")
        page.get_by_test_id("fit-panel").scroll_into_view_if_needed()
        page.screenshot(path=str(artifacts_dir / f"layout-fit-preview-{window['width']}.png"))

        # A file that is no image: each change re-asks the preview, which answers beside the chooser;
        # no page message per change.
        page.get_by_test_id("upload-left").set_input_files(str(text))
        expect(info).to_have_attribute("data-problem", "415")
        expect(figure).to_be_hidden()
        page.get_by_test_id("upload-fit").select_option("crop")
        page.get_by_test_id("upload-right").set_input_files(str(text))
        page.get_by_test_id("btn-fit-preview").click()
        expect(page.get_by_test_id("btn-fit-preview")).to_be_enabled()
        expect(info).to_have_attribute("data-problem", "415")
        assert errors.count() == 0

        # Send: one error; Send again: still one (the same words replace it).
        for _attempt in range(2):
            page.get_by_test_id("btn-upload").click()
            expect(errors).to_have_count(1)
            expect(page.get_by_test_id("btn-upload")).to_be_enabled()
            expect(errors).to_have_count(1)
        expect(errors.first).to_contain_text("not an image")
        assert "; upload a" not in errors.first.locator(".msg-text").inner_text()  # the API's advice
        assert_messages_clear_of_views(page)
        notice = page.get_by_test_id("messages-notice")
        if window is PHONE:  # the messages are above, out of sight: a notice says so and leads there
            expect(notice).to_have_text("⚠ 1 error above ↑")
            notice.click()
            expect(errors.first).to_be_in_viewport()
            expect(notice).to_be_hidden()
        else:  # beside the views, always in sight
            expect(errors.first).to_be_in_viewport()
            expect(notice).to_be_hidden()
        assert_no_sideways_scroll(page, "upload error shown")
        page.screenshot(path=str(artifacts_dir / f"layout-fit-error-{window['width']}.png"))

        # exact and the wrong size on Send: page words (the chooser), not the API's parameter.
        page.get_by_test_id("upload-fit").select_option("exact")
        page.get_by_test_id("upload-left").set_input_files(str(pair[0]))
        page.get_by_test_id("upload-right").set_input_files(str(pair[1]))
        page.get_by_test_id("btn-upload").click()
        wrong = errors.filter(has_text="do not fit the fabric")
        expect(wrong).to_have_count(1)
        expect(errors).to_have_count(1)  # the stale not-an-image error went (same action)
        words = wrong.locator(".msg-text").inner_text()
        assert "fit=" not in words and "Choose crop, pad or scale" in words, words
        assert_messages_clear_of_views(page)
        assert_no_sideways_scroll(page, "wrong-size error shown")


def _candidate_requests(page: Page) -> List[int]:
    seen: List[int] = []

    def on_response(resp: Response) -> None:
        if resp.url.split("?")[0].endswith("/api/calibration/candidate"):
            seen.append(resp.status)
    page.on("response", on_response)
    return seen


@WINDOWS
def test_panels_views_and_captures_keep_the_width_and_say_things_plainly(
        daemon: str, window: Dict[str, int], tmp_path: Path, artifacts_dir: Path) -> None:
    shot = f"layout-panels-{window['width']}.png"
    with watched_page(tmp_path, artifacts_dir, shot, expected=EXPECTED) as page:
        candidate = _candidate_requests(page)
        _open(page, daemon, window)

        # A view's caption: its name, then (apart) its frame number.
        gap = page.evaluate("""() => {
          const cap = document.querySelector('#views figure figcaption');
          const range = document.createRange();
          range.selectNodeContents(cap.firstChild);
          const no = cap.querySelector('.frame-no').getBoundingClientRect();
          return no.left - range.getBoundingClientRect().right; }""")
        assert gap >= 4, gap

        # The calibration panel: opened twice before any compute, it never asks for a candidate.
        for opening in range(2):
            with page.expect_response(lambda r: "/api/calibration/session" in r.url):
                page.locator("#calib summary").click()
            for _ in range(2):  # two corner polls later the opening's requests have all gone out
                with page.expect_response(lambda r: "/api/calibration/corners" in r.url):
                    pass
            assert_no_sideways_scroll(page, f"calibration panel opened ({opening + 1})")
            page.locator("#calib summary").click()
        assert candidate == []

        # Each view enlarged in turn.
        count = page.locator("#views figure").count()
        for i in range(count):
            fig = page.locator("#views figure").nth(i)
            fig.locator("img").first.click()
            expect(fig).to_have_class(re.compile("view-enlarged"))
            assert_no_sideways_scroll(page, f"view {i} enlarged")
            fig.locator("img").first.click()
            expect(fig).not_to_have_class(re.compile("view-enlarged"))

        # The disparity scale: the labels shown do not overlap (the ends always shown).
        legend = page.get_by_test_id("disparity-legend")
        expect(legend).to_have_attribute("data-ready", "1")
        boxes = page.evaluate("""() => [...document.querySelectorAll('#disparity-legend .legend-tick')]
          .filter((t) => !t.hidden)
          .map((t) => { const r = t.getBoundingClientRect(); return [r.left, r.right]; })""")
        assert len(boxes) >= 2
        assert all(a[1] <= b[0] for a, b in zip(boxes, boxes[1:], strict=False)), boxes

        # A capture: its whole id, its time in local time (the UTC time as the title).
        page.get_by_test_id("btn-capture").click()
        item = page.locator("[data-testid=capture]").first
        expect(item).to_be_visible()
        meta = item.locator(".cap-info small")
        created = meta.get_attribute("data-created") or ""
        assert created, "no creation time"
        assert created not in (meta.inner_text()), meta.inner_text()
        assert meta.get_attribute("title") == "created " + created
        code = item.locator(".cap-info code")
        shown = page.evaluate("el => [el.scrollWidth, el.clientWidth]", code.element_handle())
        assert shown[0] <= shown[1], shown
        cid = code.inner_text()
        listed = json.loads(urllib.request.urlopen(daemon + "/api/captures", timeout=WAIT_S).read())
        ids = [c["id"] for c in (listed["captures"] if isinstance(listed, dict) else listed)]
        assert cid.replace("\n", "") in ids, (cid, ids)
        assert_no_sideways_scroll(page, "capture listed")


def test_cameras_stalled_is_a_warning_in_the_calibration_panel_that_goes(tmp_path: Path,
                                                                       artifacts_dir: Path) -> None:
    config = daemon_config(tmp_path, no_signal_s=1.0)
    with running_daemon(fps=DAEMON_FPS, captures=tmp_path / "captures", log_path=artifacts_dir / "daemon.log",
                        health_timeout=WAIT_S,
                        extra_args=["--config", str(config), "--allow-fault-injection"]) as (_proc, base):
        with watched_page(tmp_path, artifacts_dir, "layout-corners-stalled.png", expected=EXPECTED) as page:
            _open(page, base, DESKTOP)
            page.locator("#calib summary").click()
            state = page.get_by_test_id("calib-live-state")
            expect(state).to_contain_text("not found")
            fault = _post(base + "/api/faults", {"kind": "camera_stall"})
            expect(state).to_have_class("calib-live-state warn")
            expect(state).to_contain_text("come back by themselves")
            assert page.locator("[data-testid=message-error]").count() == 0
            assert_no_sideways_scroll(page, "calibration panel, cameras stalled")
            _post(base + f"/api/faults/{fault['id']}", method="DELETE")
            expect(state).to_contain_text("not found")
            expect(state).not_to_have_class("calib-live-state warn")
            assert page.locator("[data-testid=message-error]").count() == 0
