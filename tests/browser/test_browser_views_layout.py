"""Issue 24, item 3: the views fit the screen, sharp, chosen, hidden and reordered by the user.

- At 1440x900 the seven views of the default layout are all inside the window without scrolling.
- At device pixel ratio 2 each thumbnail's JPEG is at least twice its CSS width, or its caption
  says why not ("shown at N px: CPU budget").
- Hiding a view in the Views menu stops its stream (the daemon's /api/status lists no encoder for
  it) and survives a reload; so does a new order (the 1..N shortcuts follow it).
- 375x812 (a phone) has no sideways scroll, with the menu open too; messages stay clear of the views.

Same approach as ``tests/browser/test_browser.py``; screenshots in the artifacts folder.
"""
from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any, Dict, List

import pytest
from playwright.sync_api import Page, expect

from stereocam.server.frames import views

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    PHONE,
    TIMEOUT_MS,
    assert_messages_clear_of_views,
    assert_no_sideways_scroll,
    daemon_serving,
    get_json,
    open_in_window,
    wait_frames,
    watched_page,
)
from .test_browser import DAEMON_FPS

pytestmark = [BROWSER_TEST_TIMEOUT, pytest.mark.slow]

VIEWS = list(views.VIEWS)  # the registry, never a list of its own


def _shown_order(page: Page) -> List[str]:
    page.wait_for_selector("#views[data-views-ready='1']", state="attached")
    order: List[str] = page.evaluate(
        "() => [...document.querySelectorAll('#views figure.view:not([hidden])')].map(f => f.dataset.view)")
    return order


def _encoded_views(base: str) -> List[str]:
    encoders: List[Dict[str, Any]] = get_json(base + "/api/status")["encoders"]
    return sorted({e["view"] for e in encoders if e["subscribers"] > 0})


def _wait_encoded(base: str, view: str, watched: bool) -> None:
    """Until the daemon encodes ``view`` for a client (``watched``) or no longer does."""
    deadline = time.monotonic() + TIMEOUT_MS / 1000
    while (view in _encoded_views(base)) != watched:
        assert time.monotonic() < deadline, f"{view}: still {'not ' if watched else ''}encoded"
        time.sleep(0.1)


def test_seven_views_fit_1440x900_and_are_sharp_at_dpr_2(daemon: str, tmp_path: Path,
                                                         artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "views-layout-dpr2.png", device_scale_factor=2) as page:
        open_in_window(page, daemon, VIEWS)
        assert _shown_order(page) == VIEWS
        boxes = page.evaluate("""() => [...document.querySelectorAll('#views figure.view')].map(f => {
            const r = f.getBoundingClientRect();
            return {view: f.dataset.view, left: r.left, top: r.top, right: r.right, bottom: r.bottom}; })""")
        assert page.evaluate("() => window.scrollY") == 0
        for b in boxes:
            inside = b["left"] >= 0 and b["top"] >= 0 and b["right"] <= 1440 and b["bottom"] <= 900
            assert inside, f"{b['view']} is not inside the 1440x900 window: {b}"
        assert page.evaluate("() => window.devicePixelRatio") == 2
        # Each JPEG at least twice its CSS width, or the view says the CPU budget kept it smaller.
        for view in VIEWS:
            page.wait_for_function(
                """v => { const img = document.getElementById('view-' + v);
                          const note = document.getElementById('note-' + v);
                          const got = Number((img.dataset.size || '0x0').split('x')[0]);
                          const why = /^shown at \\d+ px: CPU budget$/;
                          const said = !note.hidden && why.test(note.textContent);
                          return got >= 2 * img.clientWidth || said; }""",
                arg=view)
        assert_no_sideways_scroll(page, "seven views at 1440x900, ratio 2")
        assert_messages_clear_of_views(page)


def test_views_the_cpu_budget_cannot_afford_at_full_size_say_so(tmp_path: Path, artifacts_dir: Path) -> None:
    """0.05 cores cannot encode seven full-size views: each steps down to half size and says why."""
    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS, extra_args=["--cpu-budget", "0.05"]) as base:
        width, height = get_json(base + "/api/status")["frame_size"]
        with watched_page(tmp_path, artifacts_dir, "views-layout-budget.png", device_scale_factor=2) as page:
            open_in_window(page, base, VIEWS)
            for view in VIEWS:
                w = width * (2 if view == "sbs" else 1)
                note = page.get_by_test_id(f"note-{view}")
                expect(note).to_have_text(f"shown at {w // 2} px: CPU budget")
                page.wait_for_function("a => document.getElementById('view-' + a[0])?.dataset.size === a[1]",
                                       arg=[view, f"{w // 2}x{height // 2}"])
            assert_no_sideways_scroll(page, "budget notes at 1440x900")
            # The enlarged view is asked at full size whatever the budget: its note goes.
            page.locator("figure[data-view=rect_left]").click()
            expect(page.get_by_test_id("note-rect_left")).to_be_hidden()
            page.wait_for_function("s => document.getElementById('view-rect_left')?.dataset.size === s",
                                   arg=f"{width}x{height}")
            assert_no_sideways_scroll(page, "a view enlarged with budget notes")


def test_hidden_and_reordered_views_are_remembered_and_hidden_ones_not_encoded(
        daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "views-layout-menu.png") as page:
        open_in_window(page, daemon, VIEWS)
        assert _encoded_views(daemon) == sorted(VIEWS)

        # Hide the anaglyph with the keyboard: open the menu, tick its box off with Space.
        page.get_by_test_id("views-menu-open").click()
        page.get_by_test_id("views-show-anaglyph").focus()
        page.keyboard.press("Space")
        expect(page.locator("figure[data-view=anaglyph]")).to_be_hidden()
        assert "anaglyph" not in _shown_order(page)
        # The daemon stops encoding it (its encoder goes once nobody watches it).
        _wait_encoded(daemon, "anaglyph", False)

        # Move the disparity view to the top with its "up" button (clicked, then by keyboard).
        page.get_by_test_id("views-up-disparity").click()
        expect(page.get_by_test_id("views-up-disparity")).to_be_focused()
        for _ in range(VIEWS.index("disparity") - 2):
            page.keyboard.press("Enter")
        expect(page.get_by_test_id("views-up-disparity")).to_be_focused()
        page.keyboard.press("Enter")
        expected = ["disparity"] + [v for v in VIEWS if v not in ("anaglyph", "disparity")]
        assert _shown_order(page) == expected
        expect(page.get_by_test_id("views-up-disparity")).to_be_disabled()
        assert_no_sideways_scroll(page, "Views menu open at 1440x900")
        assert_messages_clear_of_views(page)

        # Shortcut 1 after clicks on the menu's controls: the first view on screen (disparity).
        page.get_by_test_id("views-menu-open").click()  # closes the menu
        page.locator("h1").click()
        page.keyboard.press("1")
        expect(page.locator("figure[data-view=disparity]")).to_have_class(re.compile(r"\bview-enlarged\b"))
        page.keyboard.press("1")
        expect(page.locator("figure[data-view=disparity]")).not_to_have_class(re.compile(r"\bview-enlarged\b"))

        # Both survive a reload, and the hidden view is never asked for.
        page.reload()
        wait_frames(page, expected)
        assert _shown_order(page) == expected
        expect(page.locator("figure[data-view=anaglyph]")).to_be_hidden()
        assert "anaglyph" not in _encoded_views(daemon)
        expect(page.get_by_test_id("note-anaglyph")).to_be_hidden()

        # Back to every view in the registry's order.
        page.get_by_test_id("views-menu-open").click()
        page.get_by_test_id("views-reset").click()
        assert _shown_order(page) == VIEWS
        wait_frames(page, ["anaglyph"])
        _wait_encoded(daemon, "anaglyph", True)


def test_phone_has_no_sideways_scroll_with_the_menu(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    with watched_page(tmp_path, artifacts_dir, "views-layout-phone.png") as page:
        open_in_window(page, daemon, VIEWS, PHONE)
        assert_no_sideways_scroll(page, "seven views at 375x812")
        page.get_by_test_id("views-menu-open").click()
        expect(page.get_by_test_id("views-menu-list")).to_be_visible()
        assert_no_sideways_scroll(page, "Views menu open at 375x812")
        page.get_by_test_id("views-show-raw_left").uncheck()
        expect(page.locator("figure[data-view=raw_left]")).to_be_hidden()
        assert_no_sideways_scroll(page, "a view hidden at 375x812")
        assert_messages_clear_of_views(page)
