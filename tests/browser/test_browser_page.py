"""The page as a person uses it: headless Chromium, the real daemon.

Same approach as ``tests/browser/test_browser.py``: ``stereocam serve`` as a subprocess on a free port
(emulated fabric), Debian's ``/usr/bin/chromium`` driven by Playwright, a screenshot of each
test in the artifacts folder (also when it fails), every wait for a condition.

- Messages (item 1): an error says what to do in plain words with the HTTP detail behind a
  disclosure and stays; success and information fade by themselves; a later success of the same
  action clears the stale error (a 422 upload, then a good one).
- Layout (item 6): at 375x812 Capture and the first view are on the first screen; light and
  dark follow the system; the favicon is an SVG that is linked and served; the keyboard
  shortcuts work (never while typing) and ``?`` lists them.
- Status (item 7): grouped; the cameras stalled by fault injection, the status panel and the
  frames the views get over the WebSocket both say NO SIGNAL, and both say frames again after.
- Calibration panel (item 8): the corners are drawn over the image of the very frame they were
  found in, the per-pair row-error bars are readable, the rectified preview has a legend.
"""
from __future__ import annotations

import json
import os
import re
import struct
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional

import numpy as np
import pytest
from playwright.sync_api import Page, WebSocket, expect

from stereocam.bench.serve import running_daemon

from ..overlays.test_fabric import zynq_device_tree
from .chromium import (
    BROWSER_TEST_TIMEOUT,
    TIMEOUT_MS,
    assert_no_sideways_scroll,
    daemon_and_page,
    daemon_config,
    daemon_serving,
    get_json,
    wait_frames,
    watched_page,
)

pytestmark = BROWSER_TEST_TIMEOUT

DAEMON_FPS = 10.0
WAIT_S = TIMEOUT_MS / 1000
EXPECTED = ("status of 409", "status of 422", "status of 404", "status of 503")


def _png(path: Path, image: np.ndarray) -> Path:
    import cv2

    assert cv2.imwrite(str(path), image), path
    return path


def _pair(tmp_path: Path, width: int, height: int, name: str) -> List[Path]:
    y, x = np.mgrid[0:height, 0:width]
    img = np.stack([x * 255 // max(1, width), y * 255 // max(1, height), ((x // 32 + y // 32) % 2) * 200],
                   axis=-1).astype(np.uint8)
    return [_png(tmp_path / f"{name}-left.png", img), _png(tmp_path / f"{name}-right.png", img)]


def _post(url: str, body: Optional[Dict[str, Any]] = None, method: str = "POST") -> Dict[str, Any]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json"} if data else {})
    with urllib.request.urlopen(req, timeout=WAIT_S * 5) as resp:
        text = resp.read()
        return json.loads(text) if text else {}


def _upload(page: Page, files: List[Path]) -> None:
    page.get_by_test_id("upload-left").set_input_files(str(files[0]))
    page.get_by_test_id("upload-right").set_input_files(str(files[1]))
    page.get_by_test_id("btn-upload").click()


# -- item 1: messages -------------------------------------------------------------------------

def test_messages_say_what_to_do_fade_and_clear(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    width, height = get_json(daemon + "/api/status")["frame_size"]
    good = _pair(tmp_path, width, height, "good")
    wrong = _pair(tmp_path, 320, 200, "wrong")
    with watched_page(tmp_path, artifacts_dir, "messages.png", expected=EXPECTED) as page:
        page.goto(daemon + "/")
        expect(page.get_by_test_id("conn")).to_have_text("live")
        errors = page.get_by_test_id("message-error")

        # Verify before any upload: plain words first, the HTTP detail behind a closed disclosure.
        page.get_by_test_id("btn-verify").click()
        verify_error = errors.filter(has_text="Verify needs a virtual-camera input first")
        expect(verify_error).to_have_count(1)
        expect(verify_error.locator(".msg-text")).to_have_text(
            "Verify needs a virtual-camera input first: upload a pair (Virtual camera panel), "
            "then press Verify.")
        details = verify_error.locator("details")
        expect(details.locator("summary")).to_have_text("HTTP 409")
        assert details.get_attribute("open") is None
        expect(details.locator("code")).to_contain_text("POST /api/verify → 409: ")
        expect(details.locator("code")).not_to_be_visible()
        details.locator("summary").click()
        expect(details.locator("code")).to_be_visible()
        page.screenshot(path=str(artifacts_dir / "messages-error.png"))

        # A wrong-size upload: a 422 in plain words; the same error again replaces it, not stacks.
        _upload(page, wrong)
        upload_error = errors.filter(has_text="do not fit the fabric")
        expect(upload_error).to_have_count(1)
        expect(upload_error.locator("summary")).to_have_text("HTTP 422")
        page.get_by_test_id("btn-upload").click()
        expect(upload_error.locator("summary")).to_have_text("HTTP 422")
        page.wait_for_function("() => !document.getElementById('btn-upload').disabled")
        expect(upload_error).to_have_count(1)

        # A good upload: the stale 422 goes, a success message comes and fades by itself.
        _upload(page, good)
        success = page.get_by_test_id("message-info").filter(has_text="Sent through the fabric")
        expect(success).to_have_count(1)
        expect(upload_error).to_have_count(0)
        expect(verify_error).to_have_count(1)  # another action's error stays until dismissed...
        expect(success).to_have_count(0)       # ...while the success fades by itself
        expect(verify_error).to_have_count(1)

        # Verify now works: its own stale 409 goes.
        page.get_by_test_id("btn-verify").click()
        expect(page.get_by_test_id("verify-result")).to_have_attribute("data-identical", "true")
        expect(page.get_by_test_id("message-info").filter(has_text="identical")).to_have_count(1)
        expect(errors).to_have_count(0)


# -- item 6: layout, themes, favicon, shortcuts -------------------------------------------------

def test_phone_layout_themes_and_favicon(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "phone.png") as page:
        page.set_viewport_size({"width": 375, "height": 812})
        page.emulate_media(color_scheme="dark")
        page.goto(daemon + "/")
        expect(page.get_by_test_id("conn")).to_have_text("live")
        wait_frames(page, ["raw_left"])
        for testid in ("btn-capture", "view-raw_left"):
            box = page.get_by_test_id(testid).bounding_box()
            assert box is not None, testid
            assert box["y"] >= 0 and box["y"] + box["height"] <= 812, (testid, box)
            assert box["x"] >= 0 and box["x"] + box["width"] <= 375, (testid, box)
        assert_no_sideways_scroll(page, "phone, loaded")
        # Capture works from there.
        page.get_by_test_id("btn-capture").click()
        expect(page.locator("[data-testid=capture]")).to_have_count(1)
        page.screenshot(path=str(artifacts_dir / "phone-dark.png"))

        background = "() => getComputedStyle(document.body).backgroundColor"
        dark = page.evaluate(background)
        page.emulate_media(color_scheme="light")
        page.wait_for_function(f"d => ({background})() !== d", arg=dark)
        light = page.evaluate(background)
        assert _luminance(light) > _luminance(dark) + 0.5, (light, dark)
        page.screenshot(path=str(artifacts_dir / "phone-light.png"))

        href = page.get_attribute("link[rel=icon]", "href")
        assert href == "/static/favicon.svg"
        with urllib.request.urlopen(daemon + href, timeout=WAIT_S) as resp:
            assert resp.status == 200
            assert resp.headers["Content-Type"].startswith("image/svg+xml")
            assert b"<svg" in resp.read()


def _luminance(css: str) -> float:
    r, g, b = (int(v) for v in re.findall(r"\d+", css)[:3])
    return (0.2126 * r + 0.7152 * g + 0.0722 * b) / 255


def test_keyboard_shortcuts(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "shortcuts.png", expected=EXPECTED) as page:
        page.goto(daemon + "/")
        expect(page.get_by_test_id("conn")).to_have_text("live")
        page.wait_for_function("() => document.body.dataset.ready === '1'")
        overlay = page.get_by_test_id("shortcuts")

        # "?" lists them; Escape closes the list.
        page.keyboard.press("?")
        expect(overlay).to_be_visible()
        rows = overlay.get_by_test_id("shortcut")
        assert rows.count() >= 8
        for text in ("Capture", "Verify", "live cameras", "virtual camera", "Fullscreen", "calibration pair"):
            expect(rows.filter(has_text=text).first).to_be_visible()
        page.screenshot(path=str(artifacts_dir / "shortcuts-overlay.png"))
        page.keyboard.press("Escape")
        expect(overlay).to_be_hidden()
        # The "?" button in the header opens it too; "?" closes it.
        page.get_by_test_id("btn-shortcuts").click()
        expect(overlay).to_be_visible()
        page.keyboard.press("?")
        expect(overlay).to_be_hidden()

        # Every request the page makes is counted (fetch is called within the key's handler).
        page.evaluate("""() => { window.__posts = []; const f = window.fetch;
            window.fetch = (url, init) => { if (init && init.method && init.method !== 'GET')
              window.__posts.push(init.method + ' ' + url); return f(url, init); }; }""")
        posts = "() => window.__posts.slice()"

        # Never while typing in a field.
        page.get_by_test_id("camera-exposure").focus()
        page.keyboard.press("p")
        page.keyboard.press("v")
        assert page.evaluate(posts) == []
        page.get_by_test_id("camera-exposure").evaluate("el => el.blur()")

        # p: Capture.
        page.keyboard.press("p")
        assert page.evaluate(posts) == ["POST /api/captures"]
        expect(page.locator("[data-testid=capture]")).to_have_count(1)
        # v: Verify (no virtual input yet: the plain-words 409).
        page.keyboard.press("v")
        needs_input = page.get_by_test_id("message-error").filter(has_text="Verify needs a virtual-camera")
        expect(needs_input).to_be_visible()
        # u: virtual camera (none yet: says so, stays live); l: live.
        page.keyboard.press("u")
        expect(page.get_by_test_id("message-error").filter(has_text="no input yet")).to_be_visible()
        expect(page.get_by_test_id("source-live")).to_be_checked()
        assert page.evaluate(posts)[-1] == "PUT /api/source"
        # 1..7: enlarge a view; Escape: back.
        page.keyboard.press("3")
        expect(page.locator("figure[data-view=rect_left]")).to_have_class(re.compile("view-enlarged"))
        page.keyboard.press("Escape")
        expect(page.locator("figure[data-view=rect_left]")).not_to_have_class(re.compile("view-enlarged"))


# A click on a control focuses it: the page's shortcuts must still work after it (only a text field,
# or the keys that operate the focused control, keep a key from them).
CLICKED = {"radio": "source-live", "checkbox": "camera-flip-h", "select": "camera-target",
           "button": "btn-capture"}


@pytest.mark.parametrize("kind", sorted(CLICKED))
def test_shortcuts_work_after_a_click_on_a_control(daemon: str, tmp_path: Path, artifacts_dir: Path,
                                                   kind: str) -> None:
    with watched_page(tmp_path, artifacts_dir, f"shortcuts-after-{kind}.png", expected=EXPECTED) as page:
        page.goto(daemon + "/")
        expect(page.get_by_test_id("conn")).to_have_text("live")
        page.wait_for_function("() => document.body.dataset.ready === '1'")
        control = page.get_by_test_id(CLICKED[kind])
        control.click()
        if kind == "select":
            page.keyboard.press("Escape")  # close the option list the click opened; the select keeps focus
        focused = f"() => document.activeElement && document.activeElement.id === '{CLICKED[kind]}'"
        page.wait_for_function(focused)
        overlay = page.get_by_test_id("shortcuts")
        page.keyboard.press("?")
        expect(overlay).to_be_visible()
        page.keyboard.press("?")
        expect(overlay).to_be_hidden()
        control.focus()
        page.keyboard.press("3")
        expect(page.locator("figure[data-view=rect_left]")).to_have_class(re.compile("view-enlarged"))
        page.keyboard.press("Escape")
        expect(page.locator("figure[data-view=rect_left]")).not_to_have_class(re.compile("view-enlarged"))
        control.focus()
        page.keyboard.press("u")  # the virtual camera: none uploaded yet, and the page says so
        expect(page.get_by_test_id("message-error").filter(has_text="no input yet")).to_be_visible()


# -- item 7: status grouped, one truth about the signal ----------------------------------------

def test_status_groups_and_signal_agree_with_the_views(tmp_path: Path, artifacts_dir: Path) -> None:
    config = daemon_config(tmp_path, no_signal_s=2.0)
    with running_daemon(fps=DAEMON_FPS, captures=tmp_path / "captures", log_path=artifacts_dir / "daemon.log",
                        health_timeout=WAIT_S,
                        extra_args=["--config", str(config), "--allow-fault-injection"]) as (_proc, base):
        with watched_page(tmp_path, artifacts_dir, "status.png", expected=EXPECTED) as page:
            headers: Dict[str, Dict[str, Any]] = {}  # view -> the header of the newest frame the page got

            def on_frame(payload: Any) -> None:
                if isinstance(payload, (bytes, bytearray)) and len(payload) > 4:
                    n = struct.unpack(">I", payload[:4])[0]
                    header = json.loads(payload[4:4 + n])
                    headers[header["view"]] = header

            def on_socket(ws: WebSocket) -> None:
                ws.on("framereceived", on_frame)

            page.on("websocket", on_socket)
            page.goto(base + "/")
            expect(page.get_by_test_id("conn")).to_have_text("live")
            for group in ("fabric", "cameras", "core", "calibration", "clients"):
                expect(page.get_by_test_id(f"status-group-{group}")).to_be_visible()
            for side in ("left", "right"):
                cam = page.get_by_test_id(f"status-sensor-{side}")
                expect(cam).to_contain_text("ok · exposure ")
                expect(cam).to_contain_text(" ms · gain ")
                expect(cam).to_contain_text("auto ")
            signal = page.get_by_test_id("status-signal")
            expect(signal).to_have_text(re.compile("^yes"))
            _wait_views(page, headers, True)

            fault = _post(base + "/api/faults", {"kind": "camera_stall"})
            expect(signal).to_contain_text("NO SIGNAL")
            expect(page.get_by_test_id("status-faults")).to_contain_text("cameras")
            _wait_views(page, headers, False)
            assert "NO SIGNAL" in (signal.text_content() or "")  # both at once
            page.screenshot(path=str(artifacts_dir / "status-no-signal.png"), full_page=True)

            _post(base + f"/api/faults/{fault['id']}", method="DELETE")
            expect(signal).to_have_text(re.compile("^yes"))
            _wait_views(page, headers, True)
            assert (signal.text_content() or "").startswith("yes")
            expect(page.get_by_test_id("status-faults")).to_have_text("none")


def _wait_views(page: Page, headers: Dict[str, Dict[str, Any]], signal: bool) -> None:
    """Wait until the newest frame the page got for each raw and rectified view has ``signal``."""
    deadline = time.monotonic() + WAIT_S
    views = ("raw_left", "raw_right", "rect_left", "rect_right")
    while not all(v in headers and headers[v]["signal"] is signal for v in views):
        assert time.monotonic() < deadline, {v: headers.get(v) for v in views}
        page.wait_for_timeout(100)  # lets Playwright deliver the socket's frames (a poll, not a fixed wait)


# -- item 8: calibration panel ------------------------------------------------------------------

@pytest.fixture
def checkerboard(tmp_path: Path, artifacts_dir: Path) -> Iterator[str]:
    args = ["--source", "checkerboard"]
    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS, extra_args=args) as base:
        yield base


def _store_pairs(base: str, count: int) -> None:
    """Store ``count`` calibration pairs through the API (the board moves every 1.5 s)."""
    deadline = time.monotonic() + 400
    stored = get_json(base + "/api/calibration/session")["count"]
    while stored < count:
        assert time.monotonic() < deadline, f"only {stored} pairs"
        try:
            stored = _post(base + "/api/calibration/pairs")["count"]
        except urllib.error.HTTPError as exc:
            assert exc.code in (409, 422, 503), exc
            time.sleep(0.3)  # the board has not moved yet: ask again


def test_calibration_corners_on_the_frame_bars_and_legend(checkerboard: str, tmp_path: Path,
                                                          artifacts_dir: Path) -> None:
    import cv2

    base = checkerboard
    _store_pairs(base, 5)
    cand = _post(base + "/api/calibration/compute")
    report = cand["report"]
    with watched_page(tmp_path, artifacts_dir, "calibration-panel.png", expected=EXPECTED) as page:
        page.goto(base + "/")
        expect(page.get_by_test_id("conn")).to_have_text("live")
        page.locator("#calib summary").click()

        # The corners sit on the frame the overlay shows: its image is the detection's frame.
        for side in ("left", "right"):
            svg = f"corners-{side}"
            page.wait_for_function(
                "id => { const s = document.getElementById(id);"
                " return s !== null && s.dataset.corners === '54' && s.dataset.frame !== ''"
                " && s.querySelector('image') !== null; }", arg=svg)
            shot = page.evaluate(
                "id => { const s = document.getElementById(id); return {frame: s.dataset.frame,"
                " href: s.querySelector('image').getAttribute('href'),"
                " points: s.querySelector('polyline').getAttribute('points')}; }", svg)
            assert f"/api/calibration/corners/{shot['frame']}/{side}.jpg" in shot["href"]
            try:
                url = base + shot["href"].replace("scale=0.5", "scale=1")
                with urllib.request.urlopen(url, timeout=WAIT_S) as resp:
                    assert resp.headers["X-Frame-Number"] == shot["frame"]
                    image = cv2.imdecode(np.frombuffer(resp.read(), np.uint8), cv2.IMREAD_GRAYSCALE)
            except urllib.error.HTTPError as exc:  # three newer detections since: take the next one
                assert exc.code == 404
                continue
            drawn = np.array([[float(v) for v in p.split(",")] for p in shot["points"].split()])
            found, corners = cv2.findChessboardCorners(image, (9, 6))
            assert found, side
            corners = corners.reshape(-1, 2)
            if np.linalg.norm(corners[0] - drawn[0]) > np.linalg.norm(corners[-1] - drawn[0]):
                corners = corners[::-1]
            assert np.abs(corners - drawn).max() < 2.0, (side, np.abs(corners - drawn).max())
        page.screenshot(path=str(artifacts_dir / "calibration-corners.png"))

        # The computed calibration: readable row-error bars on one scale, and the preview's legend.
        expect(page.get_by_test_id("calib-result")).to_be_visible()
        bars = page.get_by_test_id("calib-pair-bar")
        expect(bars).to_have_count(report["pairs_used"])
        worst = max(p["row_error_max"] for p in report["pairs"] if p["used"])
        used = [p for p in report["pairs"] if p["used"]]
        for i, pair in enumerate(used):
            track = bars.nth(i).bounding_box()
            assert track is not None and track["height"] >= 10 and track["width"] >= 80, track
            mean = bars.nth(i).locator(".bar-mean").bounding_box()
            peak = bars.nth(i).locator(".bar-max").bounding_box()
            assert mean is not None and peak is not None
            assert mean["height"] >= 10
            expected = track["width"] * pair["row_error_max"] / worst
            assert abs(peak["width"] - expected) <= 2.5, (peak, track, pair)
            assert abs(mean["width"] - max(2, track["width"] * pair["row_error_mean"] / worst)) <= 2.5
        legend = page.get_by_test_id("calib-legend")
        expect(legend).to_be_visible()
        for text in ("amber lines", "green rings", "magenta rings", "white line"):
            expect(legend).to_contain_text(text)
        page.wait_for_function("() => document.getElementById('calib-rectified').naturalWidth > 0")
        page.get_by_test_id("calib-result").screenshot(path=str(artifacts_dir / "calibration-result.png"))
        assert_no_sideways_scroll(page, "calibration result shown")

        # The preview at its own size (rows can be judged), scrolled inside its frame; a click fits it again.
        rectified = page.get_by_test_id("calib-rectified")
        fitted = rectified.bounding_box()
        assert fitted is not None
        tabs = len(page.context.pages)
        rectified.click()
        figure = page.get_by_test_id("calib-rectified-figure")
        expect(figure).to_have_attribute("data-zoomed", "true")
        expect(page.get_by_test_id("calib-rectified-hint")).to_contain_text("full size")
        natural = page.evaluate("() => document.getElementById('calib-rectified').naturalWidth")
        drawn_as = "w => document.getElementById('calib-rectified').getBoundingClientRect().width === w"
        page.wait_for_function(drawn_as, arg=natural)
        assert natural > 2 * fitted["width"], (natural, fitted)
        assert_no_sideways_scroll(page, "rectified preview at full size")
        assert len(page.context.pages) == tabs  # shown in the page, no tab opened
        rectified.click()
        expect(figure).to_have_attribute("data-zoomed", "false")
        page.wait_for_function(drawn_as, arg=fitted["width"])


def test_a_board_without_its_bitstream_is_shown_in_red(tmp_path: Path, artifacts_dir: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 25 item 5: pynq importable (a package on disk) and no bitstream: the page says the fabric is
    emulated, in the status panel and on the backend badge, with what to do."""
    site = tmp_path / "board-site"
    (site / "pynq").mkdir(parents=True)
    (site / "pynq" / "__init__.py").write_text("# stands for PYNQ's package: importable, never imported\n")
    path = [str(site), os.environ.get("PYTHONPATH", "")]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in path if p))
    monkeypatch.setenv("STEREOCAM_DEVICE_TREE", str(zynq_device_tree(tmp_path)))
    missing = tmp_path / "overlay" / "stereocam.bit"
    with daemon_and_page(tmp_path, artifacts_dir, fps=5.0, viewport=(1400, 1000),
                         settings={"backend": "auto", "bitstream": str(missing)}) as (base, _context, page):
        try:
            page.goto(base + "/")
            warning = page.get_by_test_id("status-backend_warning")
            expect(warning).to_contain_text(f"stereocam.bit is not at {missing}")
            expect(warning).to_contain_text("--backend emulated")
            expect(warning).to_have_class("bad")
            badge = page.get_by_test_id("backend")
            expect(badge).to_have_text("backend: emulated (NO BITSTREAM)")
            expect(badge).to_have_class(re.compile(r"\bbadge-bad\b"))
        finally:
            page.screenshot(path=str(artifacts_dir / "board-without-bitstream.png"), full_page=True)
