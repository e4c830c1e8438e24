"""Issue 21, item 4 ("Each fact once"): the views are listed once, in ``stereocam/server/frames/views.py``.

The page (its figures, the 1..N shortcuts, the WebSocket subscription), the bench and the browser
tests read that registry (the page through ``GET /api/views``); a view added in one place only
fails here: a list of views typed in the page's scripts or HTML, the bench or a browser test, a
registry entry that does not render, or an API answer that is not the registry.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import List, Tuple

import numpy as np
import pytest

from stereocam.bench import budget
from stereocam.server.frames import views
from stereocam.server.frames.pipeline import FrameSet

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "stereocam" / "server" / "http" / "static"
RENDERS = {"camera", "hconcat", "anaglyph", "disparity", "depth"}  # what views._render knows
# Quoted literals with nothing but commas, whitespace and comments between them.
_LITERAL = re.compile(r"""(["'])([A-Za-z0-9_]+)\1""")
_BETWEEN = re.compile(r"""\s*,?\s*(?:(?://|#)[^\n]*\n\s*)*""")


def view_runs(text: str) -> List[Tuple[int, List[str]]]:
    """Runs of view names written as consecutive string literals (a list, tuple or set of views):
    ``(line, names)`` for each run of two or more."""
    names = set(views.VIEWS)
    runs: List[Tuple[int, List[str]]] = []
    run: List[str] = []
    start = end = 0
    for m in _LITERAL.finditer(text):
        joined = run and _BETWEEN.fullmatch(text, end, m.start()) is not None
        if m.group(2) in names and (joined or not run):
            if not run:
                start = m.start()
            run.append(m.group(2))
        else:
            if len(run) >= 2:
                runs.append((text.count("\n", 0, start) + 1, run))
            run = [m.group(2)] if m.group(2) in names else []
            start = m.start()
        end = m.end()
    if len(run) >= 2:
        runs.append((text.count("\n", 0, start) + 1, run))
    return runs


def test_view_runs_finds_lists() -> None:
    assert view_runs('x = ["raw_left", "raw_right",\n  // c\n  "sbs"]; y = "sbs"') == [
        (1, ["raw_left", "raw_right", "sbs"])]
    assert view_runs('[["raw_left", "raw left"], ["raw_right", "raw right"]]') == []
    assert view_runs("('rect_left', 'rect_right')") == [(1, ["rect_left", "rect_right"])]


def _page_and_bench() -> List[Path]:
    files = sorted(p for p in STATIC.rglob("*") if p.suffix in (".js", ".html", ".css"))
    return files + sorted((ROOT / "stereocam" / "bench").glob("*.py"))


def test_page_and_bench_carry_no_view_list() -> None:
    """Two or more view names side by side in the page's files or the bench are a copy of the
    registry (or a part of it that a new view would miss): read ``GET /api/views`` (its fields,
    e.g. ``readout``) or ``views.VIEWS`` instead."""
    found = {str(p.relative_to(ROOT)): view_runs(p.read_text()) for p in _page_and_bench()}
    assert {k: v for k, v in found.items() if v} == {}


def test_page_html_names_no_view() -> None:
    """index.html has no figure of its own: js/views.js builds one per view of the registry."""
    html = (STATIC / "index.html").read_text()
    assert re.findall(r'data-view="[^"]*"|\b(?:view|frame|rate)-[a-z_]+\b"', html) == []
    assert re.findall(r"<figure[^>]*\bclass=\"view\b", html) == []


def test_browser_tests_type_no_view_list() -> None:
    """A browser test may pick some views; the whole list comes from the registry."""
    for path in sorted((ROOT / "tests").glob("test_browser*.py")):
        for line, run in view_runs(path.read_text()):
            assert set(run) != set(views.VIEWS), f"{path.name}:{line} types the view list: use views.VIEWS"


def test_registry_is_consistent() -> None:
    names = [v.name for v in views.REGISTRY]
    assert len(set(names)) == len(names) and tuple(names) == views.VIEWS == budget.VIEWS
    assert len(names) <= 9, "the page's shortcuts 1..9 number the views"
    for v in views.REGISTRY:
        assert v.renders in RENDERS, v
        assert v.worker in (None, views.DISPARITY_WORKER), v
        assert v.caption and v.alt, v
    assert views.GRAY_VIEWS == {v.name for v in views.REGISTRY if v.gray}
    assert views.RAW_VIEWS == {v.name for v in views.REGISTRY if v.raw}


def test_every_view_renders() -> None:
    """A registry entry without its renderer fails here, not on the page."""
    h, w = 64, 320  # wider than StereoBM's 128 disparities and its block
    raw = np.random.default_rng(4).integers(0, 256, (h, w, 8), dtype=np.uint8)
    fs = FrameSet(seq=1, frame=1, fabric_count=1, timestamp=0.0, monotonic=0.0, source="live",
                  processed=raw.copy(), raw=raw)
    for v in views.REGISTRY:
        for gray in (False, True):
            img = views.render(fs, v.name, gray)
            assert img.shape[:2] == views.view_size(v.name, (w, h))[::-1], v
            assert img.ndim == (2 if gray and v.gray else 3), v
    with pytest.raises(KeyError):
        views.render(fs, "edges")


async def test_api_views_is_the_registry(start_daemon) -> None:
    """``GET /api/views``: the registry in its order, open like the page even with a token."""
    d = await start_daemon(access_token="s3cret-token")
    async with d.session() as http, http.get("/api/views") as resp:
        assert resp.status == 200
        doc = await resp.json()
    assert doc == {"views": [v.as_json() for v in views.REGISTRY]}
    assert [v["name"] for v in doc["views"]] == list(views.VIEWS)
    assert set(doc["views"][0]) == {"name", "caption", "alt", "renders", "gray", "raw", "worker", "wide",
                                    "readout"}
