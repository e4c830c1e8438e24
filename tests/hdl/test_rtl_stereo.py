"""``stereocam.overlays.rtl.stereo_core.RtlStereo``: the stereo core's RTL under Verilator against its model.

The same harness program as the rectify core's (``sim/harness.cpp``), built for ``stereo_core``.
A small build (96 columns, 32 disparities, 8 a clock; about 10 s to build, cached) runs many
pairs with random TVALID gaps and TREADY backpressure (seed 1, ``STEREOCAM_RTL_SEED`` chooses
another); one 752x480 pair with 128 disparities goes through the ``depth`` build (its program
takes 10-60 s to build, the frame 4-15 s: 4.2 clocks a pixel, on two loaded cores). The bench's
``--rtl`` runs two of the synthetic rig's 752x480 pairs through it as well.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterator, Tuple

import cv2
import numpy as np
import pytest

from stereocam.cli import main
from stereocam.overlays.model import stereo as model
from stereocam.overlays.rtl.core import RtlCore, RtlError, build_harness
from stereocam.overlays.rtl.stereo_core import RtlStereo, stereo_parameters, stereo_sources
from stereocam.overlays.spec import stereo as spec
from stereocam.overlays.spec.rectify import CORE_ID as RECTIFY_ID
from stereocam.overlays.spec.rectify import Build as RectifyBuild

from ..cli.one_line import run_error
from ..overlays.test_stereo_model import scenes, shifted
from ..sample import calibrate_sample, pair_paths, write_opencv_files
from .test_stereo_core_rtl import model_beats

SMALL = spec.Build("small", 96, 64, 32, 8)
P32 = spec.DEFAULT_PARAMS.with_values(num_disp=32)
RECTIFY_SMALL = RectifyBuild("small-colour", 96, 64, 16, colour=True)  # test_rtl_core.py's (cached)


@pytest.fixture(scope="module")
def rtl() -> Iterator[RtlStereo]:
    with RtlStereo(SMALL, gaps=True, seed=int(os.environ.get("STEREOCAM_RTL_SEED", "1"))) as core:
        yield core


def same(got: model.StereoResult, want: model.StereoResult, label: str) -> None:
    bad = got.beats() != want.beats()
    if bad.any():
        y, x = (int(v) for v in np.argwhere(bad)[0])
        raise AssertionError(f"{label}: {int(bad.sum())} of {bad.size} beats differ; first at x={x} y={y}: "
                             f"RTL {int(got.beats()[y, x]):#010x}, model {int(want.beats()[y, x]):#010x}")


def textured(h: int, w: int, seed: int) -> Tuple[np.ndarray, np.ndarray]:
    """Smooth texture on two planes (near on the right half), as a camera sees a scene."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h // 4 + 2, (w + 40) // 4 + 2)).astype(float)
    big = np.kron(base, np.ones((4, 4)))[:h, :w + 40]
    big = (big + rng.normal(0, 6, big.shape)).clip(0, 255).astype(np.uint8)
    left = big[:, 12:12 + w].copy()
    right = big[:, :w].copy()
    right[:, w // 2:] = big[:, w // 2 - 8 + 12:w - 8 + 12]
    return left, right


@pytest.mark.parametrize("scene", list(scenes()))
def test_the_models_scenes_equal_the_model(rtl: RtlStereo, scene: str) -> None:
    """Random, shifted, textureless, repetitive, two planes and the smallest frame: every beat."""
    left, right = scenes()[scene]
    same(rtl.compute(left, right, P32), model.compute(left, right, P32), scene)


def test_random_and_textured_pairs_equal_the_model(rtl: RtlStereo) -> None:
    rng = np.random.default_rng(3)
    pairs = [(rng.integers(0, 256, (24, 96), np.uint8), rng.integers(0, 256, (24, 96), np.uint8)),
             shifted(30, 96, 9, 4), textured(32, 80, 5), textured(20, 96, 6)]
    for i, (left, right) in enumerate(pairs):
        same(rtl.compute(left, right, P32), model.compute(left, right, P32), f"pair {i}")
    assert rtl.clocks_per_pixel >= SMALL.max_disp // SMALL.parallel
    assert rtl._sim.last.out_waits > 0, "gaps: the output saw backpressure"


def test_register_changes_between_frames(rtl: RtlStereo) -> None:
    """Each frame with other parameters and another size; 16 disparities (which the depth build's model
    refuses) against the model's steps."""
    left, right = textured(24, 72, 8)
    variants = [P32, P32.with_values(subpixel=False, median=False, lr_check=False),
                P32.with_values(uniqueness=60, lr_tol=0),
                P32.with_values(edge_thresh=0, p1=5, p2_edge=5, p2=193),
                P32.with_values(p1=0, p2_edge=0, p2=0), P32]
    for i, p in enumerate(variants):
        crop_l, crop_r = left[: 12 + 2 * i, : 40 + 6 * i], right[: 12 + 2 * i, : 40 + 6 * i]
        same(rtl.compute(crop_l, crop_r, p), model.compute(crop_l, crop_r, p), f"variant {i}")
    narrow = P32.with_values(num_disp=16)
    got = rtl.compute(left, right, narrow)
    assert np.array_equal(got.beats(), model_beats(left, right, narrow))
    assert rtl.read(spec.STEREO_MAP.offset("FLAGS")) == 0


def test_without_gaps_the_core_takes_about_its_slots() -> None:
    """Full-speed streams: the frame's clocks are the core's 4 a pixel and its sweeps, nothing waits."""
    left, right = textured(40, 96, 9)
    with RtlStereo(SMALL, gaps=False) as core:
        same(core.compute(left, right, P32), model.compute(left, right, P32), "no gaps")
        assert core._sim.last.out_waits == 0
        assert 4 <= core.clocks_per_pixel < 8, core.clocks_per_pixel


def test_bad_input_and_failures_say_what_is_wrong(rtl: RtlStereo) -> None:
    left, right = shifted(12, 40, 3, 1)
    with pytest.raises(ValueError, match="8-bit gray"):
        rtl.compute(left.astype(np.uint16), right, P32)
    with pytest.raises(ValueError, match="width 100: the core takes 9 .. 96"):
        rtl.compute(np.zeros((12, 100), np.uint8), np.zeros((12, 100), np.uint8), P32)
    with pytest.raises(ValueError, match="num_disp = 64"):
        rtl.compute(left, right, spec.DEFAULT_PARAMS.with_values(num_disp=64))
    same(rtl.compute(left, right, P32), model.compute(left, right, P32), "after the refusals")
    with pytest.raises(ValueError, match="4 x PARALLEL"):
        RtlStereo(spec.Build("odd", 96, 64, 32, 16))
    with RtlStereo(SMALL) as doomed:
        doomed._sim._proc.kill()
        doomed._sim._proc.wait()
        with pytest.raises(RtlError, match="not running"):
            doomed.compute(left, right, P32)


def test_the_rectify_core_builds_from_the_same_harness(rtl: RtlStereo) -> None:
    """One harness.cpp, two tops: each build's harness_top.h names its own; the stereo build is cached."""
    top = (rtl.harness.directory / "src" / "harness_top.h").read_text()
    assert "using HarnessTop = Vstereo_core;" in top and "HARNESS_REGISTERED_OUTPUTS = false;" in top
    with RtlCore(RECTIFY_SMALL) as rect:
        text = (rect.harness.directory / "src" / "harness_top.h").read_text()
        assert "using HarnessTop = Vrectify_core;" in text and "HARNESS_REGISTERED_OUTPUTS = true;" in text
        assert rect.read(0) == RECTIFY_ID
    again = build_harness(None, top="stereo_core", parameters=stereo_parameters(SMALL),
                          sources=stereo_sources(), registered_outputs=False)
    assert not again.built and again.executable == rtl.harness.executable


@pytest.mark.timeout(3600)  # the depth build's program, when not cached, and the frame
def test_a_full_frame_through_the_depth_build() -> None:
    """752x480 with 128 disparities (the cameras' frame, the default parameters), one pair."""
    left, right = textured(480, 752, 10)
    with RtlStereo(spec.DEFAULT_BUILD, seed=3) as core:
        got = core.compute(left, right)
        same(got, model.compute(left, right), "752x480")
        assert 4 <= core.clocks_per_pixel < 5, core.clocks_per_pixel
        assert 0.2 < got.valid.mean() < 1  # matched, and some pixels refused (LR, uniqueness, border)


# ---- stereocam disparity --core rtl --------------------------------------------------------------
def test_the_disparity_command_writes_the_same_files_with_the_rtl(tmp_path: Path) -> None:
    """``--core rtl`` against ``--core model``: a cropped rectified pair with other parameters, and a
    calibrated pair (rectified by the model first) with its cloud; every file byte for byte."""
    crops = []
    for i, path in enumerate(pair_paths(4)):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)[100:220, 150:390]
        crops.append(tmp_path / f"crop{i}.png")
        cv2.imwrite(str(crops[-1]), image)
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)
    runs = {"crop": ["--rectified", "--num-disp", "32", "--uniqueness", "40", *map(str, crops)],
            "calibrated": ["--calibration", f"{intr},{extr}", "--units", "mm", *map(str, pair_paths(5))]}
    for name, argv in runs.items():
        outputs = {}
        for core in ("model", "rtl"):
            out = tmp_path / f"{name}-{core}"
            assert main(["disparity", "--core", core, "-o", str(out), *argv]) == 0
            outputs[core] = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
        assert outputs["rtl"] == outputs["model"], name
        assert len(outputs["rtl"]) == (4 if name == "calibrated" else 3)


def test_the_disparity_command_refuses_in_one_line(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    wide = tmp_path / "wide.png"
    cv2.imwrite(str(wide), np.zeros((20, 800), np.uint8))
    err = run_error(capsys, ["disparity", "--core", "rtl", "--rectified", "-o", str(tmp_path / "o"),
                             str(wide), str(wide)])
    assert "width 800: the core takes 9 .. 752 pixels" in err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((20, 60), np.uint8))
    err = run_error(capsys, ["disparity", "--core", "rtl", "--rectified", "--num-disp", "48", "-o",
                             str(tmp_path / "o"), str(small), str(small)])
    assert "num_disp = 48" in err and not (tmp_path / "o").exists()


# ---- stereocam bench depth --rtl --------------------------------------------------------------------
def test_the_depth_bench_times_the_rtl_beside_the_model(capsys: pytest.CaptureFixture[str]) -> None:
    """``--rtl``: pairs a second (wall and the harness's CPU), clocks a pixel, equal to the model."""
    code = main(["bench", "depth", "--rtl", "--seconds", "0.1", "--json"])
    r = json.loads(capsys.readouterr().out)
    rtl = r["rtl"]
    assert rtl["equal_to_model"] is True and rtl["pairs"] == 2
    assert 4 <= rtl["clocks_per_pixel"] < 5
    assert rtl["fps"] > 0 and rtl["fps_cpu"] > 0 and rtl["ratio_to_sgbm"] > 0
    assert code == (0 if r["meets_floor"] else 1)
