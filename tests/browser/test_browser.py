"""The page, in headless Chromium, against the real daemon: flows 1 and 4-6 by clicking.

The test starts ``stereocam serve`` itself (a subprocess on a free port, at a
modest frame rate: the machine has two shared cores), loads ``/`` in Debian's
``/usr/bin/chromium`` driven by the ``playwright`` package (never
``playwright install``), and checks that

- every view's <img> shows at least two different frames (``data-frame``, set by the page's live.js
  from the WebSocket header);
- an API error (verify before any upload: 409) shows up in the message area;
- Capture adds a capture to the list; its zip link points at the daemon;
- the virtual camera: switching to it, uploading a generated pair of the daemon's frame
  size, the fabric's output shown, and Verify saying "identical" with its difference image;
- switching back to live, the views move again;

A screenshot of the page goes to the artifacts folder, also when the test fails. Every wait
waits for a condition on the page, bounded only as a last resort (``browser.TIMEOUT_MS``).
"""
from __future__ import annotations

import re
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import List, Tuple

import numpy as np
from playwright.sync_api import Page, expect

from stereocam.server.frames import views

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    TIMEOUT_MS,
    daemon_serving,
    get_json,
    wait_new_frames,
    watched_page,
)

pytestmark = BROWSER_TEST_TIMEOUT

VIEWS = list(views.VIEWS)  # the registry, never a list of its own
DAEMON_FPS = 15.0
# Chromium logs every non-2xx fetch; the one the test provokes on purpose (verify before upload) is fine.
EXPECTED_409 = "status of 409"


def _pattern_pair(width: int, height: int) -> Tuple[np.ndarray, np.ndarray]:
    """A recognisable BGR pair: coloured checkerboard over gradients; right = left shifted 24 px."""
    y, x = np.mgrid[0:height, 0:width + 24]
    checker = ((x // 32 + y // 32) % 2).astype(np.uint8)
    img = np.stack([x * 255 // (width + 24), y * 255 // height, 60 + 150 * checker], axis=-1).astype(np.uint8)
    img[(y % 96 < 4) | (x % 96 < 4)] = (255, 255, 255)
    left = np.ascontiguousarray(img[:, 24:])
    right = np.ascontiguousarray(img[:, :width])
    return left, right


def _write_png(path: Path, image: np.ndarray) -> Path:
    import cv2

    assert cv2.imwrite(str(path), image), path
    return path


def test_page_end_to_end(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    status = get_json(daemon + "/api/status")
    frame_size = status["frame_size"]
    assert isinstance(frame_size, list) and len(frame_size) == 2, frame_size
    width, height = int(frame_size[0]), int(frame_size[1])
    left, right = _pattern_pair(width, height)
    left_png = _write_png(tmp_path / "left.png", left)
    right_png = _write_png(tmp_path / "right.png", right)

    with watched_page(tmp_path, artifacts_dir, "page.png", expected=[EXPECTED_409]) as page:
        _drive_page(page, daemon, width, height, left_png, right_png)


def _frame(page: Page, view: str) -> int:
    value = page.get_attribute(f"#view-{view}", "data-frame")
    return int(value) if value else -1


def _wait_new_frames(page: Page, views: List[str], count: int = 2) -> None:
    """Wait until each view's <img> has shown ``count`` different frames from now on."""
    for view in views:
        wait_new_frames(page, view, count)
        # The <img> really decoded a JPEG of a sensible size (recorded by its onload: reading
        # naturalWidth here would race the next frame's src change, which resets it to 0).
        size = page.get_attribute(f"#view-{view}", "data-size") or ""
        width, _, height = size.partition("x")
        assert width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0, (view, size)


def _errors(page: Page) -> List[str]:
    return page.locator("[data-testid=message-error]").all_inner_texts()


def _wait_status_source(page: Page, source: str) -> None:
    page.wait_for_function(
        "s => { const el = document.querySelector('[data-testid=status-source]');"
        " return el !== null && el.textContent === s; }",
        arg=source)


def _drive_page(page: Page, base: str, width: int, height: int, left_png: Path, right_png: Path) -> None:
    page.goto(base + "/")
    expect(page.get_by_test_id("conn")).to_have_text("live")

    # 1. Every view moves: two different frames each.
    _wait_new_frames(page, VIEWS)
    # The status panel fills in from /api/status.
    expect(page.get_by_test_id("status-backend")).to_contain_text("emulated")
    expect(page.get_by_test_id("status-frame_size")).to_have_text(f"{width} × {height}")
    _wait_status_source(page, "live")
    expect(page.get_by_test_id("source-live")).to_be_checked()

    # 2. An API error is shown, not swallowed: verify before any virtual input is 409.
    assert _errors(page) == []
    page.get_by_test_id("btn-verify").click()
    expect(page.get_by_test_id("message-error").first).to_contain_text("409")
    for button in page.locator("[data-testid=message-error] button").all():
        button.click()
    assert _errors(page) == []

    # 3. Capture (flow 1): the new capture is listed, with a download link and a delete button.
    captures = page.get_by_test_id("captures-list").locator("[data-testid=capture]")
    before = captures.count()
    page.get_by_test_id("btn-capture").click()
    expect(captures).to_have_count(before + 1)
    new_id = captures.first.get_attribute("data-id")
    assert new_id
    href = captures.first.get_by_test_id("capture-download").get_attribute("href")
    assert href == f"/api/captures/{new_id}.zip"
    with urllib.request.urlopen(base + href, timeout=60) as resp:
        assert resp.status == 200 and resp.read(2) == b"PK"

    # 4. Virtual camera (flow 4): without an input the switch says what to do and stays live;
    # uploading the pair switches to it and shows the fabric's output.
    page.get_by_test_id("source-virtual").click()  # not check(): the radio goes back to live
    expect(page.get_by_test_id("message-error").filter(has_text="no input yet")).to_be_visible()
    expect(page.get_by_test_id("source-live")).to_be_checked()
    _wait_status_source(page, "live")
    for button in page.locator("[data-testid=message-error] button").all():
        button.click()
    assert _errors(page) == []
    rect_before = int(page.get_attribute("#view-rect_left", "data-received") or 0)
    page.get_by_test_id("upload-left").set_input_files(str(left_png))
    page.get_by_test_id("upload-right").set_input_files(str(right_png))
    page.get_by_test_id("btn-upload").click()
    expect(page.get_by_test_id("upload-result")).to_be_visible()
    for side in ("left", "right"):
        size = page.evaluate(
            "id => { const i = document.getElementById(id); return [i.naturalWidth, i.naturalHeight]; }",
            f"vc-result-{side}")
        assert size == [width, height], (side, size)
    expect(page.get_by_test_id("source-virtual")).to_be_checked()
    # The rect views now show the fabric's output of the upload: they received a new frame.
    page.wait_for_function(
        "n => Number(document.getElementById('view-rect_left')?.dataset.received) > n", arg=rect_before)

    # 5. Verify (flow 5): identical, with a per-channel table and a difference image.
    page.get_by_test_id("btn-verify").click()
    expect(page.get_by_test_id("verify-result")).to_be_visible()
    expect(page.get_by_test_id("verify-identical")).to_contain_text("identical")
    expect(page.get_by_test_id("verify-result")).to_have_attribute("data-identical", "true")
    assert page.locator("#verify-table tbody tr").count() >= 2
    page.wait_for_function(
        "() => document.getElementById('verify-difference').naturalWidth > 0")

    # 6. Back to live (flow 6): the views move again.
    page.get_by_test_id("source-live").check()
    _wait_status_source(page, "live")
    _wait_new_frames(page, ["raw_left", "rect_left", "rect_right"])
    assert _errors(page) == [], _errors(page)


def test_views_are_thumbnails_until_clicked_and_show_why_the_budget_lowers_them(
        tmp_path: Path, artifacts_dir: Path) -> None:
    """Thumbnails on the page, full size on click; each view's rate and why the CPU budget lowers it;
    nothing encoded while the page is hidden."""
    budget = ["--cpu-budget", "0.05"]
    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS, extra_args=budget) as base:
        width, height = get_json(base + "/api/status")["frame_size"]
        with watched_page(tmp_path, artifacts_dir, "page-budget.png") as page:
            page.goto(base + "/")
            _wait_new_frames(page, VIEWS)
            for view in VIEWS:
                w = width * (2 if view == "sbs" else 1)
                assert page.get_attribute(f"#view-{view}", "data-size") == f"{w // 2}x{height // 2}", view
            # The budget of 0.05 cores cannot hold seven views at 15 fps: each says so.
            rate = page.get_by_test_id("rate-disparity")
            expect(rate).to_contain_text("fps ▾")
            why = re.compile(r"lowered to [\d.]+ fps: CPU budget: 0.05 cores")
            expect(rate).to_have_attribute("title", why)
            expect(page.get_by_test_id("status-cpu")).to_contain_text("of 0.05 cores (views lowered to")
            # Click: full size; Escape: back to the thumbnail.
            page.locator("figure[data-view=rect_left]").click()
            expect(page.locator("figure[data-view=rect_left]")).to_have_class(re.compile("view-enlarged"))
            page.wait_for_function(
                "s => document.getElementById('view-rect_left')?.dataset.size === s", arg=f"{width}x{height}")
            assert page.get_attribute("#view-rect_right", "data-size") == f"{width // 2}x{height // 2}"
            page.keyboard.press("Escape")
            page.wait_for_function(
                "s => document.getElementById('view-rect_left')?.dataset.size === s",
                arg=f"{width // 2}x{height // 2}")
            # A hidden page asks for nothing: the daemon stops every encoder.
            page.evaluate("() => { Object.defineProperty(document, 'hidden', {value: true,"
                          " configurable: true}); document.dispatchEvent(new Event('visibilitychange')); }")
            deadline = time.monotonic() + TIMEOUT_MS / 1000
            while get_json(base + "/api/status")["encoders"]:
                assert time.monotonic() < deadline, "encoders still running for a hidden page"
                time.sleep(0.1)
            assert _errors(page) == []
