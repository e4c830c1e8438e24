"""``stereocam bench depth``: scores scenes in Middlebury's layout and times the model beside OpenCV.

The scenes here are made in the test (a textured plane at a known disparity, written as PNG, PFM
and calib.txt files on disk): no Middlebury data is read.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stereocam.bench import depth
from stereocam.cli import main
from stereocam.overlays.model import stereo_jit

SHIFT = 11


def write_pfm(path: Path, img: np.ndarray) -> None:
    h, w = img.shape
    with open(path, "wb") as f:
        f.write(b"Pf\n%d %d\n-1.0\n" % (w, h))
        f.write(np.flipud(img).astype("<f4").tobytes())


def make_scene(folder: Path, seed: int, h: int = 60, w: int = 160) -> None:
    """A textured wall at disparity SHIFT, its ground truth and masks, as Middlebury lays them out."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    base = (rng.integers(0, 256, (h // 2, (w + SHIFT) // 2 + 1, 3), dtype=np.uint8)
            .repeat(2, axis=0).repeat(2, axis=1)[:, :w + SHIFT])
    Image.fromarray(np.ascontiguousarray(base[:, :w])).save(folder / "im0.png")
    Image.fromarray(np.ascontiguousarray(base[:, SHIFT:SHIFT + w])).save(folder / "im1.png")
    gt = np.full((h, w), float(SHIFT), np.float32)
    gt[:5, :5] = np.inf  # unknown ground truth: left out
    write_pfm(folder / "disp0GT.pfm", gt)
    mask = np.full((h, w), 255, np.uint8)
    mask[:, :SHIFT] = 128  # occluded: left out
    Image.fromarray(mask).save(folder / "mask0nocc.png")
    (folder / "calib.txt").write_text("cam0=[1 0 0; 0 1 0; 0 0 1]\ndoffs=0\nbaseline=1\nwidth=%d\n"
                                      "height=%d\nndisp=24\n" % (w, h))


def test_pfm_files_read_back_top_row_first(tmp_path: Path) -> None:
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    img[0, 0] = np.inf
    write_pfm(tmp_path / "a.pfm", img)
    assert np.array_equal(depth.read_pfm(tmp_path / "a.pfm"), img)
    (tmp_path / "b.pfm").write_bytes(b"P6\n1 1\n255\n\0\0\0")
    with pytest.raises(depth.DepthBenchError, match="not a PFM"):
        depth.read_pfm(tmp_path / "b.pfm")


def test_scores_count_wrong_and_missing_pixels_as_bad() -> None:
    gt = np.full((2, 4), 10.0, np.float32)
    mask = np.full((2, 4), 255, np.uint8)
    mask[1, 3] = 128
    disp = np.array([[10.0, 11.5, 12.5, np.nan], [7.0, 10.0, 10.0, np.nan]], np.float32)
    s = depth.score(disp, gt, mask)  # 7 pixels count; 2 off by > 1, 2 by > 2 (one missing)
    assert s == {"bad_1": pytest.approx(4 / 7), "bad_2": pytest.approx(3 / 7),
                 "density": pytest.approx(6 / 7)}


def test_every_matcher_is_scored_per_scene_and_on_average(tmp_path: Path) -> None:
    for i in range(2):
        make_scene(tmp_path / f"wall{i}", i)
    acc = depth.accuracy(tmp_path, {"model": (depth.model_matcher("numpy"), 32),
                                    "opencv_sgbm": (depth.opencv_sgbm, 16)})
    assert set(acc["scenes"]) == {"wall0", "wall1"}
    m = acc["mean"]["model"]
    assert m["bad_2"] < 0.1 and m["density"] > 0.9
    assert acc["mean"]["opencv_sgbm"]["density"] > 0.5
    assert acc["mean"]["model"]["bad_1"] == pytest.approx(
        np.mean([acc["scenes"][s]["model"]["bad_1"] for s in ("wall0", "wall1")]))


@pytest.mark.slow
def test_the_command_prints_speed_and_accuracy_and_its_floor(tmp_path: Path, capsys) -> None:
    make_scene(tmp_path / "scenes" / "wall", 3)
    code = main(["bench", "depth", "--seconds", "0.1", "--pairs", str(tmp_path / "scenes"), "--json"])
    r = json.loads(capsys.readouterr().out)
    paths = {"model_jit", "model_numpy"} if stereo_jit.available() else {"model_numpy"}  # the board: numpy
    assert set(r["speed"]) == paths | {"opencv_bm", "opencv_sgbm"}
    assert all(v["fps"] > 0 and v["rounds"] >= 3 for v in r["speed"].values())
    assert r["speed"]["opencv_sgbm"]["ratio_to_sgbm"] == 1.0
    assert code == (0 if r["meets_floor"] else 1)
    assert r["accuracy"]["mean"]["model"]["density"] > 0.9


def test_a_folder_without_scenes_is_a_clear_error(tmp_path: Path, capsys) -> None:
    assert main(["bench", "depth", "--seconds", "0.1", "--pairs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no scene folders" in err and "Traceback" not in err
