"""Verify (flow 5): the model-versus-fabric comparison and its difference image."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from stereocam.overlays.spec import pixel
from stereocam.server.frames.verify import EXAMPLES, ChannelStats, VerifyError, compare, difference_image
from stereocam.server.http.errors import status_of

pytestmark = pytest.mark.armhf

W, H = 40, 30


def frame(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 8), dtype=np.uint8)


def test_identical_frames() -> None:
    a = frame()
    report = compare(a, a.copy())
    assert report.identical and (report.width, report.height) == (W, H)
    assert report.overall == ChannelStats(0, 0.0, 0, None)
    assert list(report.channels) == list(pixel.CHANNELS)
    assert all(s.psnr_db is None and s.differing == 0 for s in report.channels.values())
    assert report.first_difference is None
    js = report.to_json()
    assert json.loads(json.dumps(js, allow_nan=False)) == js
    assert js["identical"] is True and js["psnr_db"] is None and js["differing"] == 0
    assert js["channels"]["R_Y"] == {"differing": 0, "share": 0.0, "max_diff": 0, "psnr_db": None}
    assert js["cameras"]["left"]["psnr_db"] is None
    image = difference_image(a, a.copy())
    assert image.shape == (H, 2 * W, 3) and image.dtype == np.uint8 and not image.any()


def test_differences_are_counted_per_channel_camera_and_overall() -> None:
    expected = frame(1)
    actual = expected.copy()
    # left R: 3 pixels off by one (either way); right Y: 1 pixel off by 40; x=5 y=7 differs in L_G, L_B
    for (y, x), delta in zip([(0, 0), (2, 3), (29, 39)], [1, -1, 1], strict=True):
        actual[y, x, 0] = np.uint8((int(expected[y, x, 0]) + delta) % 256)
    actual[10, 20, 7] = np.uint8((int(expected[10, 20, 7]) + 40) % 256)
    actual[7, 5, 1] ^= 1
    actual[7, 5, 2] ^= 2
    d = np.abs(expected.astype(int) - actual.astype(int))

    report = compare(expected, actual)
    assert not report.identical
    n = W * H
    ch = report.channels
    assert ch["L_R"].differing == 3 and ch["L_R"].share == pytest.approx(3 / n)
    assert ch["L_R"].max_diff == int(d[..., 0].max())
    assert ch["L_G"].differing == 1 and ch["L_B"].differing == 1 and ch["L_B"].max_diff == 2
    assert ch["R_Y"].differing == 1 and ch["R_Y"].max_diff == int(d[10, 20, 7])
    assert ch["L_Y"] == ChannelStats(0, 0.0, 0, None) and ch["R_R"].psnr_db is None
    assert report.cameras["left"].differing == 4  # (0,0) (2,3) (29,39) (7,5)
    assert report.cameras["right"].differing == 1
    assert report.overall.differing == 5 and report.overall.share == pytest.approx(5 / n)
    assert report.overall.max_diff == int(d.max())

    def psnr(sq: np.ndarray) -> float:
        return 10 * math.log10(255**2 / sq.mean())

    sq = d.astype(float) ** 2
    assert ch["L_R"].psnr_db == pytest.approx(psnr(sq[..., 0]))
    assert report.cameras["right"].psnr_db == pytest.approx(psnr(sq[..., 4:]))
    assert report.overall.psnr_db == pytest.approx(psnr(sq))

    assert report.first_difference == {
        "x": 0, "y": 0, "expected": expected[0, 0].tolist(), "actual": actual[0, 0].tolist()
    }
    js = report.to_json()
    assert json.loads(json.dumps(js, allow_nan=False)) == js
    assert js["differing"] == 5 and js["channels"]["L_R"]["differing"] == 3


def test_psnr_against_opencv() -> None:
    a, b = frame(2), frame(3)
    report = compare(a, b)
    assert report.overall.psnr_db == pytest.approx(cv2.PSNR(a, b), rel=1e-9)
    assert report.channels["R_B"].psnr_db == pytest.approx(cv2.PSNR(a[..., 6].copy(), b[..., 6].copy()))


def test_first_difference_is_in_raster_order() -> None:
    a = frame(4)
    b = a.copy()
    b[5, 30, 6] ^= 1
    b[5, 2, 3] ^= 1  # same row, further left: this one is first
    b[9, 0, 0] ^= 1
    assert compare(a, b).first_difference["x"] == 2  # type: ignore[index]
    assert compare(a, b).first_difference["y"] == 5  # type: ignore[index]


def test_regions_and_examples_say_where_the_frames_differ() -> None:
    a = frame(7)
    b = a.copy()
    for y, x in [(3, 17), (12, 4), (8, 25)]:  # left camera only: the right camera has no region
        b[y, x, 1] ^= 4
    report = compare(a, b)
    assert report.regions == {"left": {"x0": 4, "y0": 3, "x1": 25, "y1": 12}, "right": None}
    assert [(e["x"], e["y"]) for e in report.examples] == [(17, 3), (25, 8), (4, 12)]
    assert report.examples[1]["actual"] == b[8, 25].tolist() and report.examples[0] == report.first_difference
    c = a.copy()
    c[..., 4] ^= 1  # every pixel of the right camera: the examples stop at EXAMPLES
    many = compare(a, c)
    assert len(many.examples) == EXAMPLES and many.regions["right"] == {
        "x0": 0, "y0": 0, "x1": a.shape[1] - 1, "y1": a.shape[0] - 1}
    assert compare(a, a.copy()).to_json()["regions"] == {"left": None, "right": None}


def test_compare_does_not_modify_its_inputs() -> None:
    a, b = frame(5), frame(6)
    a0, b0 = a.copy(), b.copy()
    a.setflags(write=False)
    b.setflags(write=False)
    compare(a, b)
    difference_image(a, b)
    assert np.array_equal(a, a0) and np.array_equal(b, b0)


def test_strided_views_compare_like_copies() -> None:
    big = np.random.default_rng(7).integers(0, 256, (H * 2, W * 2, 8), dtype=np.uint8)
    a, b = big[::2, ::2], big[1::2, 1::2]
    assert compare(a, b) == compare(a.copy(), b.copy())


def test_difference_image_shows_where_and_how_much() -> None:
    a = np.zeros((H, W, 8), np.uint8)
    b = a.copy()
    b[3, 4, 0] = 1  # left, 1 LSB
    b[3, 5, 3] = 255  # left, gray channel, maximal
    b[10, 11, 6] = 16  # right
    img = difference_image(a, b)
    assert img.shape == (H, 2 * W, 3) and img.dtype == np.uint8
    lit = np.argwhere(img.any(axis=2))
    assert sorted(map(tuple, lit)) == [(3, 4), (3, 5), (10, W + 11)]

    def colour(level: int) -> np.ndarray:
        return cv2.applyColorMap(np.array([[level]], np.uint8), cv2.COLORMAP_TURBO)[0, 0, ::-1]

    assert np.array_equal(img[3, 4], colour(64))  # one LSB: light blue, always the same
    assert np.array_equal(img[3, 5], colour(255))
    assert np.array_equal(img[10, W + 11], colour(160))  # log2(16) / log2(255) of the way
    assert img[3, 4, 2] > img[3, 4, 0]  # blue-ish
    assert img[3, 5, 0] > img[3, 5, 2]  # red-ish

    # the scale is absolute: a one-LSB difference looks the same whatever else differs
    c = a.copy()
    c[3, 4, 0] = 1
    assert np.array_equal(difference_image(a, c)[3, 4], img[3, 4])


def test_difference_image_is_symmetric() -> None:
    a, b = frame(8), frame(9)
    assert np.array_equal(difference_image(a, b), difference_image(b, a))


@pytest.mark.parametrize("expected, actual, message", [
    (np.zeros((30, 40, 8), np.uint8), np.zeros((29, 40, 8), np.uint8),
     "cannot compare frames of different sizes: expected 40x30, actual 40x29; the model and the fabric must "
     "process the same input size"),
    (np.zeros((30, 40, 8), np.uint8), np.zeros((30, 41, 8), np.uint8), "expected 40x30, actual 41x30"),
    (np.zeros((30, 40, 4), np.uint8), np.zeros((30, 40, 4), np.uint8),
     r"the expected frame has shape \(30, 40, 4\); a stream frame is \(H, W, 8\)"),
    (np.zeros((30, 40, 8), np.uint8), np.zeros((30, 40), np.uint8), r"the actual frame has shape \(30, 40\)"),
    (np.zeros((0, 40, 8), np.uint8), np.zeros((0, 40, 8), np.uint8), "has shape"),
    (np.zeros((30, 40, 8), np.uint16), np.zeros((30, 40, 8), np.uint8),
     "the expected frame has uint16 pixels; stream frames are uint8"),
    ([[0]], np.zeros((30, 40, 8), np.uint8), "the expected frame is a list, not a numpy array"),
    (np.zeros((30, 40, 8), np.uint8), None, "the actual frame is a NoneType, not a numpy array"),
])
def test_mismatched_inputs_raise_a_clear_error(expected: object, actual: object, message: str) -> None:
    for call in (compare, difference_image):
        with pytest.raises(VerifyError, match=message) as err:
            call(expected, actual)  # type: ignore[arg-type]
        assert status_of(err.value) == 500 and isinstance(err.value, ValueError)
        assert err.value.to_json() == {"error": err.value.message} and "\n" not in err.value.message


def test_full_size_frame_is_fast_enough() -> None:
    a = np.random.default_rng(10).integers(0, 256, (480, 752, 8), dtype=np.uint8)
    b = a.copy()
    b[::7, ::5, 2] ^= 1
    report = compare(a, b)
    assert report.channels["L_B"].differing == len(range(0, 480, 7)) * len(range(0, 752, 5))
    assert report.channels["L_B"].max_diff == 1 and report.overall.max_diff == 1
    assert difference_image(a, b).shape == (480, 1504, 3)
