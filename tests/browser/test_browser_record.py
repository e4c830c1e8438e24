"""Fit on upload and recordings from the page: headless Chromium, the real daemon.

- Fit: a 707x481 pair is refused as it is (exact), previewed with ``pad`` (the preview is
  752x480 per camera, side by side), sent with ``pad``, and Verify says identical.
- Recording: a 2 s recording from the page is listed with its frames, replays into the
  virtual camera (the source switches to virtual) and is deleted with undo, as captures are:
  gone at once, Undo brings it back as it was; without undo it stays deleted (404), and is
  still restorable from the trash.

Same approach as ``tests/browser/test_browser.py``; screenshots in the artifacts folder.
"""
from __future__ import annotations

import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
from playwright.sync_api import expect

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    assert_no_sideways_scroll,
    daemon_serving,
    get_json,
    record_in_page,
    watched_page,
)
from .test_browser import DAEMON_FPS, _errors, _pattern_pair, _wait_status_source, _write_png

pytestmark = BROWSER_TEST_TIMEOUT


def test_a_pair_of_another_size_is_fitted_previewed_and_verified(tmp_path: Path, artifacts_dir: Path) -> None:
    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS) as base:
        width, height = get_json(base + "/api/status")["frame_size"]
        left, right = _pattern_pair(707, 481)
        left_png = _write_png(tmp_path / "left.png", left)
        right_png = _write_png(tmp_path / "right.png", right)
        with watched_page(tmp_path, artifacts_dir, "page-fit.png", expected=["status of 422"]) as page:
            page.goto(base + "/")
            page.get_by_test_id("upload-left").set_input_files(str(left_png))
            page.get_by_test_id("upload-right").set_input_files(str(right_png))
            # exact (the default) refuses it and says what to do.
            page.get_by_test_id("btn-upload").click()
            error = page.get_by_test_id("message-error").last
            expect(error).to_contain_text("fit")
            error.locator("button").last.click()
            # pad: the preview shows what the fabric will get.
            page.get_by_test_id("upload-fit").select_option("pad")
            page.get_by_test_id("btn-fit-preview").click()
            figure = page.get_by_test_id("fit-figure")
            expect(figure).to_be_visible()
            expect(figure).to_have_attribute("data-from", "707x481")
            expect(figure).to_have_attribute("data-to", f"{width}x{height}")
            page.wait_for_function("() => document.getElementById('fit-preview').naturalWidth > 0")
            size = page.evaluate("() => { const i = document.getElementById('fit-preview');"
                                 " return [i.naturalWidth, i.naturalHeight]; }")
            assert size == [2 * width, height]
            assert_no_sideways_scroll(page, "fit preview shown")  # issue 24: it was 2708 px wide
            expect(page.get_by_test_id("fit-info")).to_contain_text("padded")
            page.get_by_test_id("btn-upload").click()
            expect(page.get_by_test_id("upload-info")).to_contain_text("padded")
            expect(page.get_by_test_id("source-virtual")).to_be_checked()
            page.get_by_test_id("btn-verify").click()
            expect(page.get_by_test_id("verify-result")).to_have_attribute("data-identical", "true")
            # The fabric got the pair centred on black: its raw input equals the padded images.
            raw = get_png(base + "/snapshot/raw_left.png")
            left_pad = (width - 707) // 2
            assert raw.shape[:2] == (height, width)
            assert int(raw[:, :max(1, left_pad)].max()) == 0  # the padding is black
            assert _errors(page) == []


def get_png(url: str) -> np.ndarray:
    import urllib.request

    with urllib.request.urlopen(url, timeout=60) as resp:
        return cv2.imdecode(np.frombuffer(resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)


def test_a_recording_is_made_listed_replayed_and_deleted(tmp_path: Path, artifacts_dir: Path) -> None:
    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS) as base:
        with watched_page(tmp_path, artifacts_dir, "page-recording.png", expected=["status of 404"]) as page:
            page.goto(base + "/")
            item = record_in_page(page, 2)
            frames = int(item.get_attribute("data-frames") or 0)
            listed = get_json(base + "/api/recordings")["recordings"][0]
            assert frames == listed["frames"] and frames >= 2, listed
            assert listed["complete"] is True
            href = item.get_by_test_id("recording-download").get_attribute("href")
            assert href and href.endswith(".zip")
            item.get_by_test_id("recording-replay").click()
            _wait_status_source(page, "virtual")
            expect(page.get_by_test_id("source-virtual")).to_be_checked()
            expect(page.get_by_test_id("status-playing")).to_contain_text(f"recording {listed['id']}")
            page.get_by_test_id("source-live").check()
            _wait_status_source(page, "live")
            # A damaged frame stops a replay: the status says so, and why, until the next input.
            damaged = tmp_path / "recordings" / listed["id"] / "left_000001.png"
            damaged.write_bytes(damaged.read_bytes()[:100])
            item.get_by_test_id("recording-replay").click()
            expect(page.get_by_test_id("status-playing")).to_contain_text("stopped: ")
            expect(page.get_by_test_id("status-playing")).to_contain_text("left_000001.png")
            page.get_by_test_id("source-live").check()
            _wait_status_source(page, "live")
            expect(page.get_by_test_id("status-playing")).to_have_count(0)
            # Delete with undo: gone at once (no question asked), Undo brings it back as it was.
            rid = listed["id"]
            items = page.locator("[data-testid=recording]")
            item.get_by_test_id("recording-delete").click()
            expect(items).to_have_count(0)
            undo = page.get_by_test_id("message-undo")
            expect(undo).to_be_visible()
            expect(undo).to_contain_text(rid)
            page.screenshot(path=str(artifacts_dir / "recording-deleted-undo.png"))
            page.wait_for_function("id => fetch('/api/recordings/' + id).then(r => r.status === 404)",
                                   arg=rid)
            assert get_json(base + "/api/recordings")["recordings"] == []
            undo.get_by_test_id("btn-undo").click()
            expect(items).to_have_count(1)
            expect(page.locator(f"[data-testid=recording][data-id='{rid}']")).to_have_attribute(
                "data-frames", str(frames))
            assert get_json(base + f"/api/recordings/{rid}")["meta"]["frames"] == frames
            # Without undo: the message goes by itself, the recording stays deleted, and restorable.
            items.first.get_by_test_id("recording-delete").click()
            expect(items).to_have_count(0)
            expect(page.get_by_test_id("message-undo")).to_have_count(1)
            expect(page.get_by_test_id("message-undo")).to_have_count(0)
            assert _status(base + f"/api/recordings/{rid}") == 404
            page.reload()
            expect(page.get_by_test_id("recordings-list")).to_have_attribute("data-count", "0")
            req = urllib.request.Request(base + f"/api/recordings/{rid}/restore", method="POST")
            with urllib.request.urlopen(req, timeout=60) as resp:
                assert resp.status == 200
            assert get_json(base + f"/api/recordings/{rid}")["frames"] == frames
            assert _errors(page) == []


def _status(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=60) as resp:
            return int(resp.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)
