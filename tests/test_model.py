"""The rectify core model: reference vs fast path bit for bit, and vs OpenCV."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from stereocam.overlays.model.fast import RectifyModel, SourceMap
from stereocam.overlays.model.linebuffer import rows_needed
from stereocam.overlays.model.reference import rectify_reference, source_position
from stereocam.overlays.model.result import CoreOptions
from stereocam.overlays.spec.rectify import CameraParams


def random_params(rng: np.random.Generator, w: int, h: int, *, strength: float = 1.0) -> CameraParams:
    """A plausible camera: intrinsics, distortion and a small rectifying rotation."""
    f = rng.uniform(0.6, 1.4) * w
    K = np.array([[f, 0, w / 2 + rng.uniform(-3, 3)], [0, f * rng.uniform(0.97, 1.03), h / 2 + rng.uniform(-3, 3)], [0, 0, 1]])
    R, _ = cv2.Rodrigues(rng.normal(0, 0.03 * strength, 3))
    P = K.copy()
    P[0, 2] += rng.uniform(-2, 2)
    P[:2, :2] *= rng.uniform(0.9, 1.1)
    hinv = K @ np.linalg.inv(P @ R)
    k = rng.normal(0, [0.2 * strength, 0.05 * strength, 0.003 * strength, 0.003 * strength])
    return CameraParams(tuple(hinv.ravel()), K[0, 0], K[1, 1], K[0, 2], K[1, 2], *k)


def translate(dx: float, dy: float, *, w: int = 40, h: int = 30, k1: float = 0.0) -> CameraParams:
    """Pure translation by (dx, dy) pixels, optionally with radial distortion."""
    return CameraParams((1.0, 0.0, dx, 0.0, 1.0, dy, 0.0, 0.0, 1.0), float(w), float(w), w / 2, h / 2, k1, 0.0, 0.0, 0.0)


def random_frame(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    return rng.integers(0, 256, (h, w, 8), dtype=np.uint8)


def both(frame, left, right, options):
    h, w = frame.shape[:2]
    ref = rectify_reference(frame, left, right, options)
    fast = RectifyModel(left, right, w, h, options).process(frame)
    return ref, fast


def assert_same(ref, fast) -> None:
    diff = np.argwhere(ref.frame != fast.frame)
    assert diff.size == 0, f"{len(diff)} values differ, first at {diff[0]}"
    assert ref.lb_overflow == fast.lb_overflow


@pytest.mark.parametrize("seed", range(6))
def test_fast_equals_reference_on_random_calibrations(seed: int) -> None:
    rng = np.random.default_rng(seed)
    w, h = 48, 32
    left, right = random_params(rng, w, h, strength=3.0), random_params(rng, w, h, strength=3.0)
    frame = random_frame(rng, w, h)
    fit = rows_needed([left, right], w, h)
    ref, fast = both(frame, left, right, CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay))
    assert_same(ref, fast)
    assert not ref.lb_overflow, "a buffer of exactly rows_needed rows must be enough"
    assert np.count_nonzero(ref.frame) > frame.size // 4, "the test calibration should keep most of the image"


def test_exact_pixel_positions_copy_the_input() -> None:
    """Integer translation without distortion: every source lies exactly on a pixel."""
    rng = np.random.default_rng(1)
    frame = random_frame(rng, 40, 30)
    p = translate(3.0, -2.0)
    ref, fast = both(frame, p, p, CoreOptions(lb_rows=30, lb_delay=0))
    assert_same(ref, fast)
    # Output (x, y) reads input (x + 3, y - 2); outside the image it is 0.
    np.testing.assert_array_equal(ref.frame[2:, :37], frame[:-2, 3:])
    assert not ref.frame[:2].any() and not ref.frame[:, 37:].any()


def test_half_steps_round_half_to_even() -> None:
    """A shift of 1/64 px lands exactly between two 1/32 steps: the tie goes to even."""
    p = translate(1.0 / 64.0, 3.0 / 64.0)
    assert source_position(p, 0, 0) == (0, 2)  # 0.5 -> 0, 1.5 -> 2
    assert source_position(p, 1, 0) == (32, 2)  # 32.5 -> 32
    rng = np.random.default_rng(2)
    frame = random_frame(rng, 40, 30)
    assert_same(*both(frame, p, p, CoreOptions(lb_rows=30)))


def test_sources_outside_the_image_read_zero_per_neighbour() -> None:
    """A half-pixel shift past the left edge blends the edge pixel with 0, like BORDER_CONSTANT."""
    frame = np.full((30, 40, 8), 200, dtype=np.uint8)
    p = translate(-0.5, 0.0)
    ref, fast = both(frame, p, p, CoreOptions(lb_rows=30))
    assert_same(ref, fast)
    assert ref.frame[5, 0, 0] == 100  # (16 * 0 + 16 * 200) / 32
    assert ref.frame[5, 1, 0] == 200
    far = translate(100.0, 0.0)
    assert not rectify_reference(frame, far, far, CoreOptions(lb_rows=30)).frame.any()


def test_line_buffer_window_zeroes_and_flags() -> None:
    """Reading 10 rows below with a 4-row buffer and no delay overflows; the fit fixes it."""
    rng = np.random.default_rng(3)
    frame = random_frame(rng, 40, 30)
    p = translate(0.25, 10.5)
    fit = rows_needed([p, p], 40, 30)
    assert fit.delay == 11 and fit.rows == 2
    ref, fast = both(frame, p, p, CoreOptions(lb_rows=4, lb_delay=0))
    assert_same(ref, fast)
    assert ref.lb_overflow
    ok_ref, ok_fast = both(frame, p, p, CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay))
    assert_same(ok_ref, ok_fast)
    assert not ok_ref.lb_overflow
    assert ok_ref.frame[:19].any() and not np.array_equal(ok_ref.frame, ref.frame)


@pytest.mark.parametrize("seed", range(3))
def test_too_small_buffer_is_bit_exact_too(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    w, h = 48, 32
    left, right = random_params(rng, w, h, strength=4.0), random_params(rng, w, h, strength=4.0)
    fit = rows_needed([left, right], w, h)
    options = CoreOptions(lb_rows=max(1, fit.rows - 3), lb_delay=max(0, fit.delay - 2))
    ref, fast = both(random_frame(rng, w, h), left, right, options)
    assert_same(ref, fast)
    assert ref.lb_overflow


def test_degenerate_positions_give_zero() -> None:
    """Z = 0 on a column, and a distortion so strong the position overflows 16.5 bits."""
    frame = np.full((30, 40, 8), 77, dtype=np.uint8)
    z0 = CameraParams((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -5.0), 40.0, 40.0, 20.0, 15.0, 0.0, 0.0, 0.0, 0.0)
    assert source_position(z0, 5, 3) is None
    wild = CameraParams((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), 1.0, 1.0, 20.0, 15.0, 900.0, 0.0, 0.0, 0.0)
    assert source_position(wild, 0, 0) is None
    for p in (z0, wild):
        ref, fast = both(frame, p, p, CoreOptions(lb_rows=30))
        assert_same(ref, fast)
        assert not ref.frame[:, 5].any() if p is z0 else not ref.frame[0, 0].any()


def test_gray_bypass_and_debug_line() -> None:
    rng = np.random.default_rng(4)
    w, h = 40, 30
    left, right = random_params(rng, w, h), random_params(rng, w, h)
    frame = random_frame(rng, w, h)
    fit = rows_needed([left, right], w, h)
    gray = CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay, gray=True, debug_row=7)
    ref, fast = both(frame, left, right, gray)
    assert_same(ref, fast)
    colour = rectify_reference(frame, left, right, CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay)).frame
    for c in range(3):
        np.testing.assert_array_equal(ref.frame[8:, :, c], colour[8:, :, 3])
        np.testing.assert_array_equal(ref.frame[8:, :, 4 + c], colour[8:, :, 7])
    assert (ref.frame[7] == 255).all()
    by_ref, by_fast = both(frame, left, right, CoreOptions(bypass=True))
    assert_same(by_ref, by_fast)
    np.testing.assert_array_equal(by_ref.frame, frame)


def test_source_map_matches_reference_positions() -> None:
    rng = np.random.default_rng(5)
    p = random_params(rng, 64, 48, strength=2.0)
    smap = SourceMap.compute(p, 64, 48)
    for y in range(0, 48, 5):
        for x in range(0, 64, 3):
            pos = source_position(p, x, y)
            assert smap.valid[y, x] == (pos is not None)
            if pos is not None:
                assert (int(smap.iu[y, x]), int(smap.iv[y, x])) == pos


def test_model_equals_opencv_remap_on_the_sample_calibration() -> None:
    """Real calibration from OpenCV's sample pairs, colour: >= 99.9 % equal, mean diff < 0.01 per channel."""
    from stereocam.overlays.spec import pixel

    from .sample import calibrate_sample, read_pair

    cal = calibrate_sample()
    grays = read_pair(1)
    # Colourise the gray sample so R, G, B and gray all differ.
    rgbs = [cv2.cvtColor(cv2.applyColorMap(g, cv2.COLORMAP_JET), cv2.COLOR_BGR2RGB) for g in grays]
    srcs = [pixel.rgby(c) for c in rgbs]
    h, w = grays[0].shape
    fit = rows_needed([cal.left, cal.right], w, h)
    model = RectifyModel(cal.left, cal.right, w, h, CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay))
    out = model.process(pixel.pack(*srcs))
    assert not out.lb_overflow
    for K, D, R, P, src, base in (
        (cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1, srcs[0], 0),
        (cal.model.K2, cal.model.D2, cal.rect.R2, cal.rect.P2, srcs[1], 4),
    ):
        m1, m2 = cv2.initUndistortRectifyMap(K, D, R, P, (w, h), cv2.CV_16SC2)
        expected = cv2.remap(src, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        for c in range(4):
            diff = np.abs(out.frame[..., base + c].astype(int) - expected[..., c].astype(int))
            assert np.count_nonzero(diff == 0) >= math.ceil(0.999 * diff.size), f"channel {base + c}"
            assert diff.mean() < 0.01
        assert np.count_nonzero(expected.any(axis=2)) > 0.9 * expected.shape[0] * expected.shape[1]


def test_rows_needed_for_the_sample_calibration() -> None:
    from .sample import calibrate_sample

    cal = calibrate_sample()
    fit = rows_needed([cal.left, cal.right], 640, 480)
    # The sample's strong barrel distortion (k1 ~ -0.28) needs more than a few rows but fits 80.
    assert 20 < fit.rows <= 80
    options = CoreOptions(lb_rows=fit.rows - 1, lb_delay=fit.delay)
    assert RectifyModel(cal.left, cal.right, 640, 480, options).lb_overflow


def test_reference_equals_fast_on_the_sample_calibration_at_full_size() -> None:
    """Bands of a real 640x480 calibration, colour noise input: bit-exact."""
    from .sample import calibrate_sample

    cal = calibrate_sample()
    fit = rows_needed([cal.left, cal.right], 640, 480)
    options = CoreOptions(lb_rows=fit.rows, lb_delay=fit.delay)
    frame = random_frame(np.random.default_rng(7), 640, 480)
    fast = RectifyModel(cal.left, cal.right, 640, 480, options).process(frame).frame
    for band in (range(0, 12), range(234, 246), range(468, 480)):
        ref = rectify_reference(frame, cal.left, cal.right, options, rows=band).frame
        np.testing.assert_array_equal(ref[band.start:band.stop], fast[band.start:band.stop])
        assert ref[band.start:band.stop].any()
