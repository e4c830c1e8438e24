"""The stereo model's three paths compute the same integers, and those integers measure disparity."""
from __future__ import annotations

import numpy as np
import pytest

from stereocam.overlays.model import stereo, stereo_fast, stereo_jit, stereo_reference
from stereocam.overlays.model.stereo_result import StereoResult
from stereocam.overlays.spec import stereo as spec

pytestmark = pytest.mark.armhf

P32 = spec.DEFAULT_PARAMS.with_values(num_disp=32)
#: Every switch and penalty the core has, each away from its default at least once.
VARIANTS = {
    "default": P32,
    "plain": P32.with_values(subpixel=False, median=False, lr_check=False),
    "no-uniqueness": P32.with_values(uniqueness=0, lr_tol=0),
    "strict": P32.with_values(uniqueness=255, lr_tol=15),
    "edges-everywhere": P32.with_values(edge_thresh=0, p1=5, p2_edge=5, p2=193),
    "no-penalties": P32.with_values(p1=0, p2_edge=0, p2=0),
    "64": P32.with_values(num_disp=64),
}


def shifted(h: int, w: int, shift: int, seed: int, noise: int = 3) -> "tuple[np.ndarray, np.ndarray]":
    """A random texture and the same texture seen ``shift`` pixels to the left, with sensor noise."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h, w + shift), dtype=np.uint8)
    right = base[:, shift:shift + w].astype(int) + rng.integers(-noise, noise + 1, (h, w))
    return base[:, :w].copy(), right.clip(0, 255).astype(np.uint8)


def scenes() -> "dict[str, tuple[np.ndarray, np.ndarray]]":
    rng = np.random.default_rng(7)
    stripes = np.tile((np.arange(40) % 6 * 40).astype(np.uint8), (12, 1))
    two_planes_l, two_planes_r = shifted(16, 40, 5, 3)
    near_l, near_r = shifted(16, 40, 12, 4)
    two_planes_l[:, 20:] = near_l[:, 20:]
    two_planes_r[:, 8:28] = near_r[:, 20:40]
    return {
        "random": (rng.integers(0, 256, (10, 36), np.uint8), rng.integers(0, 256, (10, 36), np.uint8)),
        "shifted": shifted(12, 44, 7, 1),
        "textureless": (np.full((9, 30), 128, np.uint8), np.full((9, 30), 128, np.uint8)),
        "repetitive": (stripes, np.roll(stripes, -3, axis=1)),
        "two-planes": (two_planes_l, two_planes_r),
        "smallest": shifted(spec.MIN_HEIGHT, spec.MIN_WIDTH, 2, 5),
    }


@pytest.mark.parametrize("scene", list(scenes()))
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_numpy_path_equals_the_per_pixel_reference(scene: str, variant: str) -> None:
    left, right = scenes()[scene]
    want = stereo_reference.compute(left, right, VARIANTS[variant])
    got = stereo_fast.compute(left, right, VARIANTS[variant])
    assert np.array_equal(got.disp, want.disp)
    assert np.array_equal(got.conf, want.conf)
    assert np.array_equal(got.reason, want.reason)


def test_a_shifted_texture_is_matched_at_its_shift_to_a_sixteenth() -> None:
    left, right = shifted(40, 120, 9, 11)
    r = stereo_fast.compute(left, right, P32)
    inner = r.disp[4:-4, 40:-8]
    assert (inner == 9 * spec.SUBPIX_ONE).mean() > 0.9
    # Left of x = 9 the right camera did not see the texture: nothing there may claim the shift.
    assert not (r.disp[:, :9] == 9 * spec.SUBPIX_ONE).any()
    assert (r.reason[:, 3:9] != spec.REASON_VALID).mean() > 0.8
    assert r.conf[4:-4, 40:-8].mean() > 100


@pytest.mark.parametrize("scene", list(scenes()))
def test_invalid_pixels_carry_the_code_a_reason_and_no_confidence(scene: str) -> None:
    r = stereo_fast.compute(*scenes()[scene], P32)
    invalid = r.disp == spec.INVALID
    assert np.array_equal(invalid, r.reason != spec.REASON_VALID)
    assert not r.conf[invalid].any()
    assert set(np.unique(r.reason)) <= set(spec.REASONS)
    assert (r.disp[~invalid] <= 16 * (P32.num_disp - 1) + 8).all()


def test_the_output_beats_carry_all_three_fields() -> None:
    r = stereo_fast.compute(*scenes()["two-planes"], P32)
    beats = r.beats()
    assert beats.dtype == np.uint32
    back = StereoResult.from_beats(beats)
    assert back.equal(r)
    assert not (beats >> 27).any()


@pytest.mark.parametrize("bad, words", [
    ((np.zeros((10, 20), np.uint8), np.zeros((10, 21), np.uint8)), "differ in size"),
    ((np.zeros((10, 20), np.uint16), np.zeros((10, 20), np.uint16)), "8-bit gray"),
    ((np.zeros((10, 20, 3), np.uint8), np.zeros((10, 20, 3), np.uint8)), "8-bit gray"),
    ((np.zeros((5, 20), np.uint8), np.zeros((5, 20), np.uint8)), "height 5"),
    ((np.zeros((10, 800), np.uint8), np.zeros((10, 800), np.uint8)), "width 800"),
])
def test_bad_input_is_refused_with_what_is_wrong(bad: tuple, words: str) -> None:
    for path in ("numpy", "reference"):
        with pytest.raises(ValueError, match=words):
            stereo.compute(*bad, P32, path=path)
    with pytest.raises(ValueError, match="unknown model path"):
        stereo.compute(*scenes()["random"], P32, path="gpu")


def test_the_fastest_path_is_the_compiled_one_where_numba_runs_else_numpy() -> None:
    left, right = scenes()["shifted"]
    assert stereo.compiled_path_installed() == stereo_jit.available()  # what the daemon decides by
    if stereo_jit.available():  # the current env
        assert stereo.fastest_path() == "jit"
    else:  # the board and armhf envs, as on the board
        assert stereo.fastest_path() == "numpy"
        with pytest.raises(RuntimeError, match=r"pip install 'stereocam\[fast\]'"):
            stereo_jit.compute(left, right, P32)
    assert stereo.compute(left, right, P32).equal(stereo_fast.compute(left, right, P32))
