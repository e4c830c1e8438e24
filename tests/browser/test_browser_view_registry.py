"""Issue 21, item 4: the page's live-view figures are built from ``GET /api/views`` (the view
registry, ``stereocam/server/frames/views.py``), in its order, and its 1..N shortcuts follow that order.
"""
from __future__ import annotations

import re
from pathlib import Path

from playwright.sync_api import expect

from stereocam.server.frames import views

from .chromium import BROWSER_TEST_TIMEOUT, get_json, wait_frames, watched_page

pytestmark = BROWSER_TEST_TIMEOUT

DAEMON_FPS = 10.0


def test_figures_are_the_api_views_in_order(daemon: str, tmp_path: Path, artifacts_dir: Path) -> None:
    api = get_json(daemon + "/api/views")["views"]
    assert [v["name"] for v in api] == list(views.VIEWS)
    with watched_page(tmp_path, artifacts_dir, "view-registry.png") as page:
        page.goto(daemon + "/")
        page.wait_for_function("() => document.body.dataset.ready === '1'")
        figures = page.eval_on_selector_all("#views figure.view", """figs => figs.map(f => ({
            name: f.dataset.view, wide: f.classList.contains('view-wide'),
            img: f.querySelector('img').getAttribute('data-testid'), alt: f.querySelector('img').alt,
            caption: f.querySelector('figcaption').firstChild.textContent.trim(),  // not frame no./rate
            rate: (f.querySelector('.view-rate') || {}).id,
            corners: !!f.querySelector('svg.corners-overlay')}))""")
        assert [f["name"] for f in figures] == [v["name"] for v in api]
        for f, v in zip(figures, api, strict=True):
            assert f == {"name": v["name"], "wide": v["wide"], "img": "view-" + v["name"], "alt": v["alt"],
                         "caption": v["caption"], "rate": "rate-" + v["name"], "corners": v["raw"]}, v
        # Every view gets frames over the WebSocket (the page subscribes to the registry's views).
        for v in api:
            wait_frames(page, [v["name"]])

        # The shortcuts: one digit per view, in the registry's order.
        page.keyboard.press("?")
        overlay = page.get_by_test_id("shortcuts")
        row = overlay.get_by_test_id("shortcut").filter(has_text="Enlarge view")
        expect(row).to_have_text(re.compile(rf"1\s*–\s*{len(api)}\s*Enlarge view 1 to {len(api)}\b"))
        captions = ", ".join(re.sub(r" \(.*\)$", "", v["caption"]) for v in api)
        expect(overlay).to_contain_text("Views are numbered as on the page: " + captions + ".")
        page.keyboard.press("Escape")
        expect(overlay).to_be_hidden()
        for i, v in enumerate(api, start=1):
            fig = page.locator(f"figure[data-view={v['name']}]")
            page.keyboard.press(str(i))
            expect(fig).to_have_class(re.compile("view-enlarged"))
            page.keyboard.press("Escape")
            expect(fig).not_to_have_class(re.compile("view-enlarged"))
