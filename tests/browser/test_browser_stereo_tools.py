"""Issue 24, item 4: the stereo tools on the live views, at 1440x900.

- The side-by-side view's "epipolar lines" toggle draws horizontal lines and the matched features
  over the view and says how well the rectified rows agree ("rows agree within M px median, P px
  90th; N matches": the figures GET /api/alignment gives), without enlarging the view; digits still
  pick views after the click.
- Each raw view's "histogram" toggle draws its histogram under it with the clipped shares; "clipping"
  lays the daemon's clipping mask (the frame's size) over the view.
- No sideways scroll (1440x900, and 375x812 with the tools on), messages clear of the views, no console error.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from playwright.sync_api import expect

from stereocam.server.frames import views

from .chromium import (
    BROWSER_TEST_TIMEOUT,
    DESKTOP,
    PHONE,
    assert_messages_clear_of_views,
    assert_no_sideways_scroll,
    get_json,
    wait_frames,
    watched_page,
)

pytestmark = [BROWSER_TEST_TIMEOUT, pytest.mark.slow]

SBS = next(v.name for v in views.REGISTRY if v.renders == "hconcat")  # the registry says which
RAW = [v.name for v in views.REGISTRY if v.raw]
FIRST = views.VIEWS[0]


def test_epipolar_lines_and_exposure_tools(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    width, height = get_json(daemon + "/api/status")["frame_size"]
    with watched_page(tmp_path, artifacts_dir, "stereo-tools.png") as page:
        page.set_viewport_size(DESKTOP)
        page.goto(daemon + "/")
        for view in [SBS, *RAW]:
            wait_frames(page, [view])
        assert_no_sideways_scroll(page, "tools off at 1440x900")

        # Epipolar lines over the side-by-side view, the figure under it.
        page.get_by_test_id("epi-toggle-" + SBS).click()
        figure = page.get_by_test_id("epi-figure-" + SBS)
        expect(figure).to_have_text(re.compile(
            r"^rows (agree within|differ by) \d+\.\d\d px median, \d+\.\d\d px 90th[;(] ?\d+ matches"))
        overlay = page.get_by_test_id("epi-" + SBS)
        expect(overlay).to_be_visible()
        drawn = page.evaluate("""id => { const s = document.getElementById(id);
            return {lines: s.querySelectorAll('.epi-lines line').length,
                    matches: s.querySelectorAll('.epi-matches line').length,
                    box: s.getAttribute('viewBox'), frame: Number(s.dataset.frame)}; }""", "epi-" + SBS)
        assert drawn["lines"] == len(range(16, height, 32)) and drawn["matches"] >= 8
        assert drawn["box"] == f"0 0 {2 * width} {height}" and drawn["frame"] >= 0
        median = float(figure.get_attribute("data-median") or "nan")
        warned = median > 1.0
        expect(figure).to_have_class(re.compile(r"\bwarn\b" if warned else r"\bok\b"))
        expect(page.locator(f"figure[data-view={SBS}]")).not_to_have_class(re.compile(r"\bview-enlarged\b"))
        # A digit after the click still picks a view (the checkbox keeps only Space and Enter).
        page.keyboard.press("1")
        expect(page.locator(f"figure[data-view={FIRST}]")).to_have_class(re.compile(r"\bview-enlarged\b"))
        page.keyboard.press("1")
        expect(page.locator(f"figure[data-view={FIRST}]")).not_to_have_class(re.compile(r"\bview-enlarged\b"))

        # Exposure: a histogram under each raw view, the clipping mask over it.
        for view in RAW:
            page.get_by_test_id("hist-toggle-" + view).click()
            page.get_by_test_id("clip-toggle-" + view).click()
        for view in RAW:
            canvas = page.get_by_test_id("hist-" + view)
            expect(canvas).to_be_visible()
            expect(canvas).to_have_attribute("data-drawn", "1")
            assert page.evaluate("""id => { const c = document.getElementById(id);
                const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
                let lit = 0;
                for (let i = 0; i < d.length; i += 4) if (d[i] + d[i + 1] + d[i + 2] > 100) lit++;
                return lit; }""", "hist-" + view) > 100  # bars drawn, not just the background
            expect(page.get_by_test_id("hist-figure-" + view)).to_have_text(
                re.compile(r"^clipped: [<\d.]+% at 255, [<\d.]+% black$"))
            mask = page.get_by_test_id("clip-" + view)
            expect(mask).to_be_visible()
            page.wait_for_function("id => document.getElementById(id).naturalWidth > 0", arg="clip-" + view)
            natural = page.evaluate("id => { const m = document.getElementById(id); "
                                    "return [m.naturalWidth, m.naturalHeight]; }", "clip-" + view)
            assert natural == [width, height]
        assert_no_sideways_scroll(page, "every tool on at 1440x900")
        assert_messages_clear_of_views(page)
        page.screenshot(path=str(artifacts_dir / "stereo-tools-on.png"))
        page.set_viewport_size(PHONE)
        expect(page.get_by_test_id("hist-" + RAW[0])).to_be_visible()
        assert_no_sideways_scroll(page, "every tool on at 375x812")
        page.set_viewport_size(DESKTOP)

        # Off again: nothing drawn over the views, nothing under them.
        page.get_by_test_id("epi-toggle-" + SBS).click()
        expect(overlay).to_be_hidden()
        expect(figure).to_be_hidden()
        for view in RAW:
            page.get_by_test_id("hist-toggle-" + view).click()
            page.get_by_test_id("clip-toggle-" + view).click()
            expect(page.get_by_test_id("hist-" + view)).to_be_hidden()
            expect(page.get_by_test_id("clip-" + view)).to_be_hidden()
            expect(page.get_by_test_id("tools-out-" + view)).to_be_hidden()
        assert_no_sideways_scroll(page, "tools off again")
