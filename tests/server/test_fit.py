"""Fit on upload: exact, crop, pad and scale, in the upload code and over HTTP."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from stereocam.overlays.spec import pixel
from stereocam.server.http.metrics import METRICS
from stereocam.server.http.state import VIRTUAL
from stereocam.server.http.uploads import (
    FIT_MODES,
    UploadError,
    apply_fit,
    decode_pair_fitted,
    fit_pair,
    plan_fit,
)

from .daemon import FULL, H, W, make_overlay, pair_form, png  # noqa: F401

pytestmark = pytest.mark.slow


def rgb(seed: int, w: int, h: int) -> np.ndarray:
    """A smooth colour image (JPEG-free tests need no smoothness, resizing does: INTER_AREA averages)."""
    coarse = np.random.default_rng(seed).integers(0, 256, (max(2, h // 8), max(2, w // 8), 3), dtype=np.uint8)
    return np.ascontiguousarray(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC))


def centred(image: np.ndarray, w: int, h: int) -> np.ndarray:
    """``image`` centred on a black w x h canvas, cut where it sticks out (written out by hand)."""
    ih, iw = image.shape[:2]
    out = np.zeros((h, w) + image.shape[2:], np.uint8)
    sx, dx = max(0, (iw - w) // 2), max(0, (w - iw) // 2)
    sy, dy = max(0, (ih - h) // 2), max(0, (h - ih) // 2)
    cw, ch = min(iw, w), min(ih, h)
    out[dy:dy + ch, dx:dx + cw] = image[sy:sy + ch, sx:sx + cw]
    return out


# -- the geometry ---------------------------------------------------------------------------------

def test_pad_of_707x481_to_752x480_pads_the_width_and_cuts_a_row() -> None:
    fit = plan_fit("pad", (707, 481), (752, 480))
    doc = fit.to_json()
    assert (doc["mode"], doc["from"], doc["to"]) == ("pad", [707, 481], [752, 480])
    assert doc["padded"] == [22, 0, 23, 0] and doc["cropped"] == [0, 0, 0, 1] and doc["scale"] == 1.0
    assert "padded 45 columns (22 left, 23 right) with black" in doc["text"]
    assert "cropped 1 row (0 top, 1 bottom)" in doc["text"]
    image = rgb(1, 707, 481)
    out = apply_fit(image, fit)
    assert out.shape == (480, 752, 3)
    np.testing.assert_array_equal(out, centred(image, 752, 480))
    assert not out[:, :22].any() and not out[:, 752 - 23:].any()
    np.testing.assert_array_equal(out[:, 22:22 + 707], image[:480])


def test_crop_takes_the_centre_and_says_where_it_had_to_pad() -> None:
    bigger = rgb(2, 800, 500)
    out = apply_fit(bigger, plan_fit("crop", (800, 500), (752, 480)))
    np.testing.assert_array_equal(out, bigger[10:490, 24:776])
    fit = plan_fit("crop", (800, 400), (752, 480))  # wider, but not as tall: padded in height
    assert fit.cropped == (24, 0, 24, 0) and fit.padded == (0, 40, 0, 40)
    assert "padded 80 rows (40 top, 40 bottom) with black" in fit.text()
    image = rgb(3, 800, 400)
    np.testing.assert_array_equal(apply_fit(image, fit), centred(image, 752, 480))


@pytest.mark.parametrize("size, resized, padded", [
    ((1504, 480), (752, 240), (0, 120, 0, 120)),   # twice as wide: shrunk by 2, letterboxed
    ((376, 480), (376, 480), (188, 0, 188, 0)),    # already as tall: pillarboxed, not resized
    ((188, 120), (752, 480), (0, 0, 0, 0)),        # the same aspect ratio, smaller: enlarged x4
])
def test_scale_keeps_the_aspect_ratio_and_letterboxes(size, resized, padded) -> None:
    fit = plan_fit("scale", size, (752, 480))
    assert fit.resized == resized and fit.padded == padded and fit.cropped == (0, 0, 0, 0)
    image = rgb(4, *size)
    out = apply_fit(image, fit)
    interpolation = cv2.INTER_AREA if fit.scale < 1 else cv2.INTER_LINEAR
    expected = image if resized == size else cv2.resize(image, resized, interpolation=interpolation)
    np.testing.assert_array_equal(out, centred(expected, 752, 480))


def test_shrinking_averages_areas() -> None:
    """INTER_AREA: a 2x shrink of a fine checkerboard is flat gray, not aliased stripes."""
    board = (np.indices((480, 1504)).sum(axis=0) % 2 * 255).astype(np.uint8)
    out = apply_fit(board, plan_fit("scale", (1504, 480), (752, 480)))
    middle = out[120:360]
    assert middle.min() >= 127 and middle.max() <= 128


def test_exact_and_fits_of_the_right_size_change_nothing() -> None:
    image = rgb(5, W, H)
    for mode in FIT_MODES:
        fit = plan_fit(mode, (W, H), (W, H))
        assert not fit.changed and fit.text() == "already the fabric's size: unchanged"
        np.testing.assert_array_equal(apply_fit(image, fit), image)


def test_a_pair_gets_the_same_fit_and_must_be_one_size() -> None:
    left, right = rgb(6, 300, 200), rgb(7, 300, 200)
    fl, fr, fit = fit_pair(left, right, (W, H), "scale")
    assert fl.shape == fr.shape == (H, W, 3) and fit.source == (300, 200)
    np.testing.assert_array_equal(fr, apply_fit(right, fit))
    with pytest.raises(UploadError) as err:
        fit_pair(left, rgb(8, 301, 200), (W, H), "pad")
    assert err.value.status == 400
    assert err.value.message == ("left is 300x200 but right is 301x200: the two images of a pair must be "
                                 "the same size")
    with pytest.raises(UploadError) as err:
        fit_pair(left, right, (W, H), "stretch")
    assert err.value.status == 400
    assert err.value.message == "unknown fit 'stretch': use exact, crop, pad or scale"


def test_decoding_fits_pairs_and_side_by_side_images() -> None:
    left, right = rgb(9, 400, 260), rgb(10, 400, 260)
    frame, fit = decode_pair_fitted({"left": png(left), "right": png(right)}, size=(W, H), fit="crop")
    assert frame.shape == (H, W, 8) and fit.mode == "crop" and fit.source == (400, 260)
    np.testing.assert_array_equal(frame[..., 0:3], centred(left, W, H))
    np.testing.assert_array_equal(frame[..., 4:7], centred(right, W, H))
    # Y as the demosaic makes it
    np.testing.assert_array_equal(frame[..., 3], pixel.gray_of(centred(left, W, H)))
    sbs_frame, sbs_fit = decode_pair_fitted({"sbs": png(np.hstack([left, right]))}, size=(W, H), fit="crop")
    np.testing.assert_array_equal(sbs_frame, frame)
    assert sbs_fit == fit
    with pytest.raises(UploadError) as err:
        decode_pair_fitted({"sbs": png(rgb(11, 401, 260))}, size=(W, H), fit="pad")
    assert err.value.status == 422 and "odd width" in err.value.message
    with pytest.raises(UploadError) as err:  # exact keeps its clear error, and says how to fit instead
        decode_pair_fitted({"left": png(left), "right": png(right)}, size=(W, H))
    assert err.value.status == 422
    assert err.value.message == (f"left is 400x260, the fabric takes {W}x{H}; "
                                 f"or send fit=crop, pad or scale to make it fit")
    with pytest.raises(UploadError) as err:  # the bomb check still comes before any pixel is decoded
        decode_pair_fitted({"left": png(left), "right": png(right)}, size=(W, H), fit="scale",
                           max_pixels=1000)
    assert err.value.status == 413


# -- over HTTP ------------------------------------------------------------------------------------

async def test_a_707x481_pair_uploaded_with_fit_pad_is_accepted_and_verify_identical(start_daemon) -> None:
    """The issue's check, at the API: the page's upload with fit=pad, then Verify."""
    d = await start_daemon(overlay=make_overlay(size=FULL, calibrate=False))
    left, right = rgb(20, 707, 481), np.ascontiguousarray(np.roll(rgb(20, 707, 481), -9, axis=1))
    async with d.http.post("/api/virtual-camera?fit=pad", data=pair_form(left, right)) as resp:
        assert resp.status == 200, await resp.text()
        body = await resp.json()
    assert body["source"] == "virtual" and (body["width"], body["height"]) == FULL
    fit = body["fit"]
    assert (fit["mode"], fit["from"], fit["to"]) == ("pad", [707, 481], [752, 480])
    assert fit["padded"] == [22, 0, 23, 0] and fit["cropped"] == [0, 0, 0, 1]
    vc = d.app[VIRTUAL]
    np.testing.assert_array_equal(vc.input[..., 0:3], centred(left, *FULL))
    np.testing.assert_array_equal(vc.input[..., 4:7], centred(right, *FULL))
    async with d.http.post("/api/verify") as resp:
        assert resp.status == 200, await resp.text()
        report = await resp.json()
    assert report["identical"] is True and report["differing"] == 0
    assert (report["width"], report["height"]) == FULL


@pytest.mark.parametrize("mode, size", [("crop", (420, 300)), ("pad", (300, 200)), ("scale", (752, 480))])
async def test_every_fit_mode_goes_through_the_fabric_bit_exact(start_daemon, mode, size) -> None:
    d = await start_daemon()
    left, right = rgb(21, *size), rgb(22, *size)
    # fit as a form field (the other tests use ?fit=)
    async with d.http.post("/api/virtual-camera", data=pair_form(left, right, fit=mode)) as resp:
        assert resp.status == 200, await resp.text()
        body = await resp.json()
    assert body["fit"]["mode"] == mode and body["fit"]["from"] == list(size) and body["fit"]["to"] == [W, H]
    fit = plan_fit(mode, size, (W, H))
    np.testing.assert_array_equal(d.app[VIRTUAL].input[..., 0:3], apply_fit(left, fit))
    np.testing.assert_array_equal(d.app[VIRTUAL].input[..., 4:7], apply_fit(right, fit))
    if mode == "scale":  # 752x480 -> 376x240: a 2x shrink, the whole frame, no padding
        assert body["fit"]["resized"] == [W, H] and body["fit"]["padded"] == [0, 0, 0, 0]
        np.testing.assert_array_equal(d.app[VIRTUAL].input[..., 0:3], cv2.resize(left, (W, H),
                                                                                 interpolation=cv2.INTER_AREA))
    async with d.http.post("/api/verify") as resp:
        assert (await resp.json())["identical"] is True


async def test_bad_fits_are_refused_and_change_nothing(start_daemon) -> None:
    d = await start_daemon()
    left, right = rgb(23, 300, 200), rgb(24, 300, 200)
    cases = [
        ("/api/virtual-camera?fit=stretch", pair_form(left, right), 400, "unknown fit 'stretch'"),
        ("/api/virtual-camera", pair_form(left, right, fit="zoom"), 400, "unknown fit 'zoom'"),
        ("/api/virtual-camera?fit=pad", pair_form(left, right, fit="crop"), 400,
         "fit is 'pad' in the URL but 'crop' in the form: send one"),
        ("/api/virtual-camera?fit=pad", pair_form(left, rgb(25, 300, 201)), 400,
         "left is 300x200 but right is 300x201: the two images of a pair must be the same size"),
        ("/api/virtual-camera", pair_form(left, right), 422, "or send fit=crop, pad or scale"),
        ("/api/virtual-camera?fit=exact", pair_form(left, right), 422,
         f"left is 300x200, the fabric takes {W}x{H}"),
    ]
    for url, data, status, message in cases:
        async with d.http.post(url, data=data) as resp:
            assert resp.status == status, (url, await resp.text())
            assert message in (await resp.json())["error"], url
    assert d.app[VIRTUAL].input is None and d.overlay.fabric.source == "live"
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    async with d.http.post("/api/virtual-camera?fit=pad", json={"capture": cid}) as resp:
        assert resp.status == 400 and "fit applies to uploaded images" in (await resp.json())["error"]
    # then the same pair with a good fit works
    async with d.http.post("/api/virtual-camera?fit=pad", data=pair_form(left, right)) as resp:
        assert resp.status == 200


async def test_the_preview_shows_the_fitted_pair_without_touching_the_fabric(start_daemon) -> None:
    d = await start_daemon()
    left, right = rgb(26, 420, 300), rgb(27, 420, 300)
    uploads_before = dict(d.app[METRICS].uploads)
    async with d.http.post("/api/virtual-camera/preview?fit=crop", data=pair_form(left, right)) as resp:
        assert resp.status == 200, await resp.text()
        assert resp.content_type == "image/png" and resp.headers["X-Frame-Size"] == f"{W}x{H}"
        fit = json.loads(resp.headers["X-Fit"])
        shown = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    assert fit["mode"] == "crop" and fit["from"] == [420, 300] and fit["cropped"] == [22, 30, 22, 30]
    assert shown.shape == (H, 2 * W, 3)
    np.testing.assert_array_equal(shown[..., ::-1], np.hstack([centred(left, W, H), centred(right, W, H)]))
    assert d.app[VIRTUAL].input is None and d.overlay.fabric.source == "live"
    assert dict(d.app[METRICS].uploads) == uploads_before  # a preview is not an upload
    gray = rgb(28, 300, 200)[..., 0]
    async with d.http.post("/api/virtual-camera/preview", data=pair_form(gray, gray, fit="scale")) as resp:
        shown = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    assert shown.ndim == 2 and shown.shape == (H, 2 * W)  # gray cameras: a gray preview
    mismatched = pair_form(left, rgb(29, 10, 10))
    async with d.http.post("/api/virtual-camera/preview?fit=pad", data=mismatched) as resp:
        assert resp.status == 400 and "same size" in (await resp.json())["error"]
    async with d.http.post("/api/virtual-camera/preview", json={"capture": "x"}) as resp:
        assert resp.status == 415
