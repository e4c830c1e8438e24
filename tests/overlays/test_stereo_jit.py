"""The compiled stereo path (numba) computes exactly the numpy path's integers."""
from __future__ import annotations

import numpy as np
import pytest

from stereocam.overlays.model import stereo, stereo_fast, stereo_jit

from .test_stereo_model import VARIANTS, scenes, shifted

pytestmark = [pytest.mark.not_on_armhf("numba has no armhf wheels; the numpy path serves there"),
              pytest.mark.not_on_board_env("the board (armv7l) has no numba: its env runs the numpy path, "
                                           "tests/overlays/test_stereo_model.py")]


def test_numba_is_installed_in_this_env() -> None:
    assert stereo_jit.available(), stereo_jit.unavailable_reason()
    assert stereo.fastest_path() == "jit"


@pytest.mark.parametrize("scene", list(scenes()))
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_compiled_path_equals_numpy(scene: str, variant: str) -> None:
    left, right = scenes()[scene]
    assert stereo_jit.compute(left, right, VARIANTS[variant]).equal(
        stereo_fast.compute(left, right, VARIANTS[variant]))


def test_compiled_path_equals_numpy_on_a_full_frame_with_128_disparities() -> None:
    left, right = shifted(480, 752, 37, 2, noise=6)
    left[:, 300:420] = 90  # a textureless patch
    p = stereo.spec.DEFAULT_PARAMS
    a = stereo_jit.compute(left, right, p)
    b = stereo_fast.compute(left, right, p)
    assert a.equal(b)
    assert (a.disp[10:-10, 200:280] == 37 * 16).mean() > 0.9


def test_bad_input_is_refused_before_compiling() -> None:
    with pytest.raises(ValueError, match="differ in size"):
        stereo_jit.compute(np.zeros((10, 20), np.uint8), np.zeros((10, 22), np.uint8))
