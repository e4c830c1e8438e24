"""The page's Stereo matcher panel and the status panel's Disparity group, in headless Chromium.

``stereocam serve`` (emulated fabric, with its stereo core) as a subprocess; the panel shows what
``GET /api/stereo`` says, sets a parameter through its input and Apply (the daemon then holds it),
and shows the daemon's refusal of a value the core would not take, the core keeping its values.
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest
from playwright.sync_api import expect

from .chromium import BROWSER_TEST_TIMEOUT, get_json, watched_page

NO_NUMBA = ("the emulated stereo core without numba (the numpy path) takes seconds a frame, so the "
            "panel's round trips outlast the page's waits; the panel is the same page in every env")
pytestmark = [BROWSER_TEST_TIMEOUT, pytest.mark.not_on_board_env(NO_NUMBA)]

DAEMON_FPS = 10.0
DAEMON_SETTINGS = {"stereo_core": True}  # the emulated fabric with the core (the default where numba is)
WAIT_S = 120.0  # last-resort bound of a wait for a condition
EXPECTED_422 = "status of 422"  # the refusal the test provokes on purpose


def test_the_stereo_panel_sets_the_matcher(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "stereo.png", expected=[EXPECTED_422]) as page:
        page.goto(daemon + "/")
        expect(page.get_by_test_id("stereo-by")).to_contain_text("stereo core")
        state = get_json(daemon + "/api/stereo")
        for name, value in state["params"].items():
            field = page.get_by_test_id("stereo-" + name.replace("_", "-"))
            expect(field).to_be_visible()
            if isinstance(value, bool):
                (expect(field).to_be_checked if value else expect(field).not_to_be_checked)()
            else:
                expect(field).to_have_value(str(value))
        expect(page.get_by_test_id("stereo-num-disp")).to_have_attribute("max", "128")

        # A change through the input and Apply: the core holds it.
        page.get_by_test_id("stereo-uniqueness").fill("25")
        page.get_by_test_id("stereo-apply").click()
        deadline = time.monotonic() + WAIT_S
        while get_json(daemon + "/api/stereo")["params"]["uniqueness"] != 25:
            assert time.monotonic() < deadline, "uniqueness never became 25"
            time.sleep(0.2)
        expect(page.locator("#messages")).to_contain_text("uniqueness set")  # the page has the answer
        expect(page.get_by_test_id("stereo-uniqueness")).to_have_value("25")

        # A value the core refuses: the daemon's words on the page, the core's values unchanged.
        page.get_by_test_id("stereo-num-disp").fill("40")
        page.get_by_test_id("stereo-apply").click()
        expect(page.locator("#messages")).to_contain_text("a multiple of 32")
        expect(page.get_by_test_id("stereo-num-disp")).to_have_value(str(state["params"]["num_disp"]))
        assert get_json(daemon + "/api/stereo")["params"]["num_disp"] == state["params"]["num_disp"]

        # The status panel says what computes the disparity.
        expect(page.locator("#status")).to_contain_text("stereo core")
