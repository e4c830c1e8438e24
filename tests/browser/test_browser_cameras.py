"""The page's camera controls, in headless Chromium, against the real daemon.

Same approach as ``tests/browser/test_browser.py``: ``stereocam serve`` as a subprocess on a free
port (emulated fabric and sensors), Debian's ``/usr/bin/chromium`` driven by Playwright.
The test loads the page, checks the controls show ``GET /api/cameras``, turns AEC off with
its checkbox, sets a low exposure with the exposure control, measures the mean brightness of
``/snapshot/raw_left.png``, sets a high exposure with the control and waits (bounded only as a
last resort) until the live picture is clearly brighter. A bad value shows the daemon's error in the
message area. A screenshot goes to the artifacts folder, also when the test fails.
"""
from __future__ import annotations

import json
import math
import time
import urllib.request
from pathlib import Path
from typing import Tuple

import numpy as np
from playwright.sync_api import Page, expect

from .chromium import BROWSER_TEST_TIMEOUT, get_json, watched_page

pytestmark = BROWSER_TEST_TIMEOUT

DAEMON_FPS = 15.0
LOW_US = 300
HIGH_US = 15000  # within one frame of the sensors (16.7 ms at the profile's 60 fps): longer is refused
WAIT_S = 120.0  # last-resort bound of each wait for a condition (a busy machine only makes them longer)
# Frames after the first snapshot taken once the exposure is in use: the frames then in the
# fabric's frame stores may have been exposed before the change; this many later, none is.
SETTLE_FRAMES = 3
# Chromium logs every non-2xx fetch; the 400 the test provokes on purpose is fine.
EXPECTED_400 = "status of 400"


def _snapshot_brightness(base: str) -> Tuple[int, float]:
    """The frame number and mean brightness of a fresh ``/snapshot/raw_left.png``."""
    import cv2

    with urllib.request.urlopen(base + "/snapshot/raw_left.png", timeout=60) as resp:
        frame = int(resp.headers["X-Frame-Number"])
        data = np.frombuffer(resp.read(), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    assert image is not None and image.size > 0
    return frame, float(np.mean(image))


def _mean_brightness(base: str) -> float:
    return _snapshot_brightness(base)[1]


def _settled_brightness(base: str) -> float:
    """The mean brightness of a frame surely exposed after the settings now in use were applied."""
    first, _ = _snapshot_brightness(base)
    deadline = time.monotonic() + WAIT_S
    while True:
        frame, mean = _snapshot_brightness(base)
        if frame >= first + SETTLE_FRAMES:
            return mean
        assert time.monotonic() < deadline, f"frame {frame} (from {first}) after {WAIT_S} s"


def _set_exposure(page: Page, base: str, us: int) -> None:
    """Set the exposure through the page's number input; wait until the daemon uses it."""
    page.get_by_test_id("camera-exposure").fill(str(us))
    page.get_by_test_id("camera-exposure").dispatch_event("change")
    deadline = time.monotonic() + WAIT_S
    while True:
        left = get_json(base + "/api/cameras")["left"]
        if abs(float(left["exposure_us"]) - us) <= max(0.05 * us, 50):
            break
        assert time.monotonic() < deadline, f"exposure never became {us} µs: {left}"
        time.sleep(0.2)
    # The range slider follows the number input, and both come to show the exposure in use (whole rows).
    in_use = round(float(left["exposure_us"]))
    expect(page.get_by_test_id("camera-exposure")).to_have_value(str(in_use))
    expect(page.get_by_test_id("camera-exposure-range")).to_have_value(str(in_use))


def test_camera_controls_change_the_picture(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "cameras.png", expected=[EXPECTED_400]) as page:
        _drive(page, daemon, artifacts_dir)


def _drive(page: Page, base: str, artifacts_dir: Path) -> None:
    page.goto(base + "/")
    expect(page.get_by_test_id("conn")).to_have_text("live")
    for testid in ("camera-exposure", "camera-gain", "camera-aec", "camera-agc", "camera-flip-h",
                   "camera-flip-v", "camera-test-pattern", "camera-target"):
        expect(page.get_by_test_id(testid)).to_be_visible()
    expect(page.get_by_test_id("camera-target")).to_have_value("both")

    # The controls show what GET /api/cameras says.
    page.wait_for_function("() => document.getElementById('camera-form').dataset.exposure !== undefined")
    # The exposure inputs end where the sensor's timing does (PUT refuses beyond it).
    lo, hi = get_json(base + "/api/cameras")["left"]["exposure_range_us"]
    for testid in ("camera-exposure", "camera-exposure-range"):
        assert page.get_by_test_id(testid).get_attribute("max") == str(math.floor(hi))
        assert page.get_by_test_id(testid).get_attribute("min") == str(math.ceil(lo))
    state = get_json(base + "/api/cameras")
    left = state["left"]
    assert left is not None, state
    if left["aec"]:
        expect(page.get_by_test_id("camera-aec")).to_be_checked()
    expect(page.get_by_test_id("camera-test-pattern")).to_have_value(left["test_pattern"] or "off")

    # AEC off with its checkbox (check it first if it is off, so the click really changes it).
    aec = page.get_by_test_id("camera-aec")
    if not aec.is_checked():
        aec.check()
        deadline = time.monotonic() + WAIT_S
        while not get_json(base + "/api/cameras")["left"]["aec"]:
            assert time.monotonic() < deadline, "AEC never turned on"
            time.sleep(0.2)
    aec.uncheck()
    deadline = time.monotonic() + WAIT_S
    while True:
        cams = get_json(base + "/api/cameras")
        if not cams["left"]["aec"] and not cams["right"]["aec"]:
            break
        assert time.monotonic() < deadline, f"AEC never turned off: {cams}"
        time.sleep(0.2)
    expect(aec).not_to_be_checked()

    # Low exposure through the control, then the picture's brightness once the view has updated.
    _set_exposure(page, base, LOW_US)
    dark = _settled_brightness(base)

    # High exposure through the range slider: value + input/change events (debounced PUT).
    page.evaluate(
        "us => { const r = document.getElementById('camera-exposure-range'); r.value = String(us);"
        " r.dispatchEvent(new Event('input', {bubbles: true}));"
        " r.dispatchEvent(new Event('change', {bubbles: true})); }", HIGH_US)
    # The number input follows (then shows the value in use: whole sensor rows, so close to it).
    page.wait_for_function(
        "us => Math.abs(Number(document.getElementById('camera-exposure').value) - us) <= 0.05 * us",
        arg=HIGH_US)
    deadline = time.monotonic() + WAIT_S
    bright = dark
    while True:
        bright = _mean_brightness(base)
        if bright > 1.3 * dark + 1.0:
            break
        assert time.monotonic() < deadline, f"the picture did not get brighter: {dark:.1f} -> {bright:.1f}"
        time.sleep(0.3)
    cams = get_json(base + "/api/cameras")
    assert abs(float(cams["left"]["exposure_us"]) - HIGH_US) <= 0.05 * HIGH_US, cams
    assert abs(float(cams["right"]["exposure_us"]) - HIGH_US) <= 0.05 * HIGH_US, cams
    (artifacts_dir / "brightness.json").write_text(json.dumps({"dark": dark, "bright": bright}))
    page.screenshot(path=str(artifacts_dir / "cameras-bright.png"), full_page=True)

    # An out-of-range value: the daemon's 400 is shown in the message area.
    assert page.locator("[data-testid=message-error]").count() == 0
    page.get_by_test_id("camera-gain").fill("9")
    page.get_by_test_id("camera-gain").dispatch_event("change")
    expect(page.get_by_test_id("message-error").first).to_contain_text("400")
    expect(page.get_by_test_id("message-error").first).to_contain_text("gain")
    # The control goes back to the value in use.
    expect(page.get_by_test_id("camera-gain")).not_to_have_value("9")
