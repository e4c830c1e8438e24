"""The live views' tools and the capture viewer, in Debian's Chromium against the real daemon.

Views: frame number and delivered/target rate on every view; the disparity view's colour scale
(the daemon's own JET colours, 0..128 px, labelled in metres from the calibration); **depth under the
pointer** on the synthetic rig (the emulated fabric's default source) within 2 % of the rig's true
depth at that pixel (``tests/rig_truth.py`` traces the rig's scene), with the displayed-to-full-resolution
pixel mapping checked exactly on a thumbnail, an enlarged view and a fullscreen one; the point readout
on the rectified views against a lossless snapshot; fullscreen with its button.

Captures: thumbnails; the viewer (raw and rectified, left and right; zoom by buttons and wheel; pan by
drag; x, y and channel values under the pointer equal the stored PNG's); replay into the virtual
camera; delete with undo (gone from the list at once; Undo restores; without undo it stays deleted on
the daemon, and a page closed before its undo leaves the capture deleted and restorable).

Screenshots go to the artifacts folder. Every wait waits for a condition.
"""
from __future__ import annotations

import json
import math
import re
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Dict, Iterator, Tuple

import cv2
import numpy as np
import pytest
from playwright.sync_api import Page, expect

from stereocam.server.frames import views

from ..rig_truth import static_depth
from ..slowness import SLOWNESS
from .chromium import (
    BROWSER_TEST_TIMEOUT,
    TIMEOUT_MS,
    assert_no_sideways_scroll,
    get_json,
    wait_frames,
    watched_page,
)

pytestmark = BROWSER_TEST_TIMEOUT

DAEMON_FPS = 10.0  # the daemon fixture's camera rate (tests/browser/conftest.py)
# A capture on the fabric with the stereo core waits for its frame's depth: where numba is missing (the
# board env) the core's model is numpy's, seconds a frame, and a loaded machine made one capture take
# more than the page's minute (the Capture button stayed busy; the last fresh run).
CAPTURE_TIMEOUT_MS = TIMEOUT_MS * SLOWNESS


@pytest.fixture
def daemon(tmp_path: Path, artifacts_dir: Path) -> Iterator[str]:
    """The daemon on a fabric without the stereo core: the 2 % depth checks below are StereoBM's (the
    core's model is 0.2-0.3 px off on the rig's back wall; the core's readout: tests/server)."""
    from .chromium import daemon_serving

    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS, settings={"stereo_core": False}) as base:
        yield base


@pytest.fixture
def daemon_with_core(tmp_path: Path, artifacts_dir: Path) -> Iterator[str]:
    """The daemon on a fabric with the stereo core (in every env, numba or not): captures hold depth."""
    from .chromium import daemon_serving

    with daemon_serving(tmp_path, artifacts_dir, fps=DAEMON_FPS, settings={"stereo_core": True}) as base:
        yield base

VIEWS = list(views.VIEWS)  # the registry, never a list of its own
# Pixels on the rig's back wall, never reached by its moving planes (rig_truth.static_depth says so).
WALL = [(615, 381), (644, 350), (612, 404)]


def _png(url: str) -> np.ndarray:
    with urllib.request.urlopen(url, timeout=60) as resp:
        data = resp.read()
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None, url
    return img


def _image_pixel(box: Dict[str, float], natural: Tuple[int, int], full: Tuple[int, int],
                 client: Tuple[float, float]) -> Tuple[int, int]:
    """The full-resolution pixel at ``client`` of an <img> shown with object-fit: contain (Python's own)."""
    s = min(box["width"] / natural[0], box["height"] / natural[1])
    cw, ch = natural[0] * s, natural[1] * s
    left, top = box["x"] + (box["width"] - cw) / 2, box["y"] + (box["height"] - ch) / 2
    return math.floor((client[0] - left) / cw * full[0]), math.floor((client[1] - top) / ch * full[1])


def _natural(page: Page, view: str) -> Tuple[int, int]:
    """The decoded size of the JPEG a view's <img> shows (its data-size: naturalWidth is 0 while the
    next frame loads)."""
    size = page.get_attribute(f"#view-{view}", "data-size") or ""
    a, _, b = size.partition("x")
    return int(a), int(b)


def _client_of(page: Page, view: str, full: Tuple[int, int], px: Tuple[int, int]) -> Tuple[float, float]:
    """Client coordinates of the centre of full-resolution pixel ``px`` of a view's <img>."""
    box = page.locator(f"#view-{view}").bounding_box()
    assert box is not None
    nat = _natural(page, view)
    s = min(box["width"] / nat[0], box["height"] / nat[1])
    cw, ch = nat[0] * s, nat[1] * s
    left, top = box["x"] + (box["width"] - cw) / 2, box["y"] + (box["height"] - ch) / 2
    return left + (px[0] + 0.5) * cw / full[0], top + (px[1] + 0.5) * ch / full[1]


def _hover(page: Page, view: str, full: Tuple[int, int], px: Tuple[int, int]) -> Dict[str, Any]:
    """Point at pixel ``px`` of ``view``; the readout once it shows the pixel the page computed for the
    pointer, and that pixel as Python computes it from the same pointer position."""
    page.locator(f"#view-{view}").scroll_into_view_if_needed()
    x, y = _client_of(page, view, full, px)
    page.mouse.move(x - 3, y - 3)
    page.mouse.move(x, y)
    page.wait_for_function(
        "v => { const b = document.getElementById('readout-' + v);"
        " const p = (b.dataset.pointer || '').split(',');"
        " return !b.hidden && b.dataset.x !== undefined && b.dataset.error !== '1'"
        " && Number(p[0]) === Number(b.dataset.x)"
        " && Number(p[1]) === Number(b.dataset.y) && p[2] === b.dataset.side; }", arg=view)
    data = page.evaluate("v => ({...document.getElementById('readout-' + v).dataset,"
                         " text: document.getElementById('readout-' + v).textContent})", view)
    box = page.locator(f"#view-{view}").bounding_box()
    nat = _natural(page, view)
    cx, cy = (float(v) for v in data["client"].split(","))
    data["expected"] = _image_pixel(box, nat, full, (cx, cy))
    return data


def test_views_rates_legend_fullscreen_and_depth_under_the_pointer(daemon: str, tmp_path: Path,
                                                                   artifacts_dir: Path) -> None:
    w, h = get_json(daemon + "/api/status")["frame_size"]
    rectification = get_json(daemon + "/api/calibration")["rectification"]
    scale = get_json(daemon + "/api/disparity")
    fb = scale["focal_px"] * scale["baseline_m"]
    with watched_page(tmp_path, artifacts_dir, "views.png") as page:
        page.goto(daemon + "/")
        wait_frames(page, VIEWS)

        # Frame number and delivered / target rate on every view.
        for view in VIEWS:
            expect(page.locator(f"#frame-{view}")).to_have_text(re.compile(r"^#\d+$"))
            expect(page.get_by_test_id(f"rate-{view}")).to_have_text(re.compile(r"^[\d.]+ / [\d.]+ fps"))
            shown = int(page.locator(f"#frame-{view}").get_attribute("data-frame") or -1)
            assert shown >= 0

        # The colour scale: the daemon's colours, ticks in px and metres (Z = f B / d).
        legend = page.get_by_test_id("disparity-legend")
        expect(legend).to_have_attribute("data-ready", "1")
        ticks = legend.locator(".legend-tick")
        expect(ticks).to_have_count(6)
        for i in range(6):
            d = int(ticks.nth(i).get_attribute("data-disparity") or -1)
            z = ticks.nth(i).get_attribute("data-depth")
            assert z == "Infinity" if d == 0 else float(z or 0) == pytest.approx(fb / d), (d, z)
        lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(1, -1), cv2.COLORMAP_JET)[0]
        bar = page.evaluate("() => { const c = document.querySelector('#disparity-legend canvas');"
                            " return Array.from(c.getContext('2d').getImageData(0, 0, c.width, 1).data); }")
        for column in (0, 64, 128, 200, 255):
            level = min(255, round((column + 0.5) * 255 / 256))
            assert bar[4 * column:4 * column + 3] == lut[level][::-1].tolist(), column

        # Depth under the pointer on the thumbnail: the page's pixel is the one Python computes for
        # the pointer's position, and the depth there is within 2 % of the rig's true depth.
        for px in WALL:
            truth = static_depth(rectification, *px)
            assert truth is not None, px
            r = _hover(page, "disparity", (w, h), px)
            got = (int(r["x"]), int(r["y"]))
            assert got == r["expected"], (r, px)
            assert abs(got[0] - px[0]) <= 1 and abs(got[1] - px[1]) <= 1, (got, px)
            truth = static_depth(rectification, *got)
            assert truth is not None
            assert abs(float(r["depth"]) - truth) / truth < 0.02, (r, truth)
            assert f"Z {float(r['depth']):.3f} m" in r["text"]

        # Enlarged (full size): every image pixel is addressable, the mapping exact.
        page.locator("figure[data-view=disparity]").click()
        page.wait_for_function("s => document.getElementById('view-disparity')?.dataset.size === s",
                               arg=f"{w}x{h}")
        for px in WALL:
            r = _hover(page, "disparity", (w, h), px)
            assert (int(r["x"]), int(r["y"])) == px == r["expected"], r
            truth = static_depth(rectification, *px)
            assert abs(float(r["depth"]) - truth) / truth < 0.02, (r, truth)
        page.screenshot(path=str(artifacts_dir / "views-disparity-enlarged.png"))
        assert_no_sideways_scroll(page, "disparity view enlarged")

        # Fullscreen on the enlarged view, with its button; the readout still exact (letterboxed).
        button = page.get_by_test_id("fullscreen-disparity")
        expect(button).to_be_visible()
        button.click()
        page.wait_for_function("() => document.fullscreenElement"
                               " && document.fullscreenElement.dataset.view === 'disparity'")
        expect(button).to_have_text("exit fullscreen")
        r = _hover(page, "disparity", (w, h), WALL[0])
        assert (int(r["x"]), int(r["y"])) == WALL[0] == r["expected"], r
        assert abs(float(r["depth"]) - static_depth(rectification, *WALL[0])) < 0.02 * float(r["depth"])
        page.screenshot(path=str(artifacts_dir / "views-fullscreen.png"))
        button.click()
        page.wait_for_function("() => document.fullscreenElement === null")
        expect(button).to_have_text("fullscreen")
        page.locator("figure[data-view=disparity] figcaption").click()
        page.wait_for_function("s => document.getElementById('view-disparity')?.dataset.size === s",
                               arg=f"{w // 2}x{h // 2}")

        # The point readout on the rectified views: x, y and the pixel's values, as a lossless
        # snapshot has them (the wall does not move).
        snap = {side: _png(daemon + f"/snapshot/rect_{side}.png") for side in ("left", "right")}
        for view, side, px in (("rect_left", "left", WALL[0]), ("rect_right", "right", WALL[1]),
                               ("sbs", "right", (w + WALL[2][0], WALL[2][1])), ("sbs", "left", WALL[1])):
            full = (2 * w if view == "sbs" else w, h)
            r = _hover(page, view, full, px)
            ex, ey = r["expected"]
            if view == "sbs" and ex >= w:
                ex -= w
            assert (int(r["x"]), int(r["y"])) == (ex, ey) and r["side"] == side, (view, r)
            values = json.loads(r["values"])
            b, g, rr = snap[side][ey, ex].tolist()
            assert (values["r"], values["g"], values["b"]) == (rr, g, b), (view, r)
            if side == "left":
                truth = static_depth(rectification, ex, ey)
                assert truth is not None and abs(float(r["depth"]) - truth) / truth < 0.02, (view, r)
            else:
                assert "Z " not in r["text"]
        page.mouse.move(1, 1)
        expect(page.get_by_test_id("readout-sbs")).to_be_hidden()


# -- captures ------------------------------------------------------------------------------------


def _viewer_point(page: Page, px: Tuple[int, int]) -> Dict[str, Any]:
    """Point at image pixel ``px`` in the viewer; the readout's data once it shows that pixel."""
    canvas = page.get_by_test_id("cv-canvas")
    box = canvas.bounding_box()
    assert box is not None
    zoom, tx, ty = (float(canvas.get_attribute(f"data-{k}") or "nan") for k in ("zoom", "tx", "ty"))
    x = box["x"] + tx + (px[0] + 0.5) * zoom
    y = box["y"] + ty + (px[1] + 0.5) * zoom
    page.mouse.move(x, y)
    readout = page.get_by_test_id("cv-readout")
    expect(readout).to_have_attribute("data-x", str(px[0]))
    expect(readout).to_have_attribute("data-y", str(px[1]))
    return json.loads(readout.get_attribute("data-values") or "{}")


def _status(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=60) as resp:
            return resp.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_captures_thumbnails_viewer_replay_and_delete_with_undo(daemon_with_core: str, tmp_path: Path,
                                                               artifacts_dir: Path) -> None:
    daemon = daemon_with_core
    w, h = get_json(daemon + "/api/status")["frame_size"]
    # The page's own checks that a deleted capture is gone (fetch) log a 404.
    with watched_page(tmp_path, artifacts_dir, "captures.png", expected=["status of 404"]) as page:
        page.goto(daemon + "/")
        wait_frames(page, ["rect_left"])
        items = page.get_by_test_id("captures-list").locator("[data-testid=capture]")
        for n in (1, 2):
            page.get_by_test_id("btn-capture").click(timeout=CAPTURE_TIMEOUT_MS)
            expect(items).to_have_count(n, timeout=CAPTURE_TIMEOUT_MS)
        ids = [items.nth(i).get_attribute("data-id") for i in range(2)]
        assert all(ids)
        # Thumbnails, from the daemon, decoded.
        for i in range(2):
            thumb = items.nth(i).get_by_test_id("capture-thumb")
            thumb.scroll_into_view_if_needed()  # loading="lazy"
            expect(thumb).to_have_attribute("src", f"/api/captures/{ids[i]}/thumb.jpg")
            page.wait_for_function("el => el.complete && el.naturalWidth === 160", arg=thumb.element_handle())

        # The viewer: the rectified left image first, then each of the four; values from the PNGs.
        cid = ids[0]
        items.nth(0).get_by_test_id("capture-open").click()
        viewer = page.get_by_test_id("capture-viewer")
        expect(viewer).to_be_visible()
        expect(page.get_by_test_id("cv-title")).to_have_text(cid)
        assert_no_sideways_scroll(page, "capture viewer open")
        canvas = page.get_by_test_id("cv-canvas")
        expect(canvas).to_have_attribute("data-loaded", "rect_left")
        # The capture's depth files, each a download link to the file the daemon serves.
        files = page.get_by_test_id("cv-files").get_by_test_id("cv-file")
        expect(files).to_have_text(["cloud.ply", "confidence.png", "disparity.png"])
        expect(files.nth(0)).to_have_attribute("href", f"/api/captures/{cid}/cloud.ply")
        meta = get_json(daemon + f"/api/captures/{cid}")["meta"]["images"]
        for name in ("raw_left", "raw_right", "rect_left", "rect_right"):
            page.get_by_test_id(f"cv-image-{name}").click()
            expect(canvas).to_have_attribute("data-loaded", name)
            png = _png(daemon + f"/api/captures/{cid}/{meta[name]['file']}")
            for px in ((0, 0), (w - 1, h - 1), (123, 77)):
                values = _viewer_point(page, px)
                if png.ndim == 2:
                    assert values["gray"] == int(png[px[1], px[0]]), (name, px, values)
                else:
                    b, g, r = png[px[1], px[0]].tolist()
                    assert (values["r"], values["g"], values["b"]) == (r, g, b), (name, px, values)
                if meta[name].get("y_file"):
                    y_png = _png(daemon + f"/api/captures/{cid}/{meta[name]['y_file']}")
                    assert values["y"] == int(y_png[px[1], px[0]]), (name, px, values)

        # Zoom with the buttons (about the centre) and the wheel (about the pointer: the pixel under it
        # stays), pan by dragging.
        zoom0 = float(canvas.get_attribute("data-zoom") or 0)
        page.get_by_test_id("cv-zoom-in").click()
        zoom_above = "z => Number(document.querySelector('[data-testid=cv-canvas]').dataset.zoom) > z"
        page.wait_for_function(zoom_above, arg=zoom0 * 1.2)
        _viewer_point(page, (300, 200))
        zoom1 = float(canvas.get_attribute("data-zoom") or 0)
        page.mouse.wheel(0, -100)
        page.wait_for_function(zoom_above, arg=zoom1 * 1.2)
        readout = page.get_by_test_id("cv-readout")
        expect(readout).to_have_attribute("data-x", "300")
        expect(readout).to_have_attribute("data-y", "200")
        zoom2 = float(canvas.get_attribute("data-zoom") or 0)
        box = canvas.bounding_box()
        assert box is not None
        tx0 = float(canvas.get_attribute("data-tx") or 0)
        start = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.move(*start)
        page.mouse.down()
        page.mouse.move(start[0] + 40, start[1] + 25, steps=4)
        page.mouse.up()
        assert float(canvas.get_attribute("data-tx") or 0) == pytest.approx(tx0 + 40)
        assert float(canvas.get_attribute("data-zoom") or 0) == zoom2
        values = _viewer_point(page, (310, 210))  # still exact after zoom and pan
        b, g, r = _png(daemon + f"/api/captures/{cid}/rect_right.png")[210, 310].tolist()
        assert (values["r"], values["g"], values["b"]) == (r, g, b)
        page.screenshot(path=str(artifacts_dir / "capture-viewer.png"))

        # Replay into the virtual camera.
        page.get_by_test_id("cv-replay").click()
        replaying = page.get_by_test_id("message-info").filter(has_text="Replaying capture " + cid)
        expect(replaying).to_be_visible()
        page.wait_for_function("() => { const s = document.querySelector('[data-testid=status-source]');"
                               " return s !== null && s.textContent === 'virtual'; }")
        assert get_json(daemon + "/api/virtual-camera")["input"] == f"capture {cid}"
        page.get_by_test_id("cv-close").click()
        expect(viewer).to_be_hidden()

        # Delete with undo: gone from the list at once, Undo brings it back as it was.
        files_before = get_json(daemon + f"/api/captures/{cid}")["files"]
        items.nth(0).get_by_test_id("capture-delete").click()
        expect(items).to_have_count(1)
        undo = page.get_by_test_id("message-undo")
        expect(undo).to_be_visible()
        expect(undo).to_contain_text(cid)
        page.screenshot(path=str(artifacts_dir / "capture-deleted-undo.png"))
        page.wait_for_function("id => fetch('/api/captures/' + id).then(r => r.status === 404)", arg=cid)
        undo.get_by_test_id("btn-undo").click()
        expect(items).to_have_count(2)
        expect(page.locator(f"[data-testid=capture][data-id='{cid}']")).to_be_visible()
        assert get_json(daemon + f"/api/captures/{cid}")["files"] == files_before

        # Without undo: the message goes by itself, the capture stays deleted.
        other = ids[1]
        page.locator(f"[data-testid=capture][data-id='{other}']").get_by_test_id("capture-delete").click()
        expect(items).to_have_count(1)
        expect(page.get_by_test_id("message-undo")).to_have_count(1)
        expect(page.get_by_test_id("message-undo")).to_have_count(0)
        assert _status(daemon + f"/api/captures/{other}") == 404
        page.reload()
        expect(page.get_by_test_id("captures-list").locator("[data-testid=capture]")).to_have_count(1)

        # The page closed right after a delete: the delete stands and nothing is lost (restorable).
        page.locator(f"[data-testid=capture][data-id='{cid}']").get_by_test_id("capture-delete").click()
        expect(page.get_by_test_id("message-undo")).to_be_visible()
        page.wait_for_function("id => fetch('/api/captures/' + id).then(r => r.status === 404)", arg=cid)
        page.goto("about:blank")
        assert _status(daemon + f"/api/captures/{cid}") == 404
        req = urllib.request.Request(daemon + f"/api/captures/{cid}/restore", method="POST")
        with urllib.request.urlopen(req, timeout=60) as resp:
            assert resp.status == 200
        assert get_json(daemon + f"/api/captures/{cid}")["files"] == files_before
        page.goto(daemon + "/")
        expect(page.locator("[data-testid=capture]")).to_have_count(1)
