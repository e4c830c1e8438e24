"""``stereocam rectify``: real files in, real PNGs out, one-line errors with exit code 2."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereocam.cli import main

from ..sample import calibrate_sample, pair_paths, png_claiming, write_opencv_files
from ..slowness import SLOWNESS
from .one_line import run_error

pytestmark = pytest.mark.armhf


@pytest.fixture(scope="module")
def calfiles(tmp_path_factory) -> "tuple[Path, Path]":
    return write_opencv_files(calibrate_sample(), tmp_path_factory.mktemp("cal"))


def cal_arg(files) -> str:
    return f"{files[0]},{files[1]}"


def test_gray_pair_is_rectified_like_opencv(tmp_path, calfiles, capsys) -> None:
    left, right = pair_paths(3)
    args = ["rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path / "out"), str(left), str(right)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "line buffer: 63 of 80 rows needed (delay 35)" in out
    cal = calibrate_sample()
    for path, K, D, R, P in ((left, cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1),
                             (right, cal.model.K2, cal.model.D2, cal.rect.R2, cal.rect.P2)):
        name = "left.png" if path == left else "right.png"
        got = cv2.imread(str(tmp_path / "out" / name), cv2.IMREAD_UNCHANGED)
        assert got.ndim == 2, "gray input gives gray output"
        src = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        m1, m2 = cv2.initUndistortRectifyMap(K, D, R, P, (640, 480), cv2.CV_16SC2)
        expected = cv2.remap(src, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        assert np.count_nonzero(got == expected) >= 0.999 * got.size


def test_colour_pair_gives_colour_output(tmp_path, calfiles) -> None:
    paths = []
    for i, p in enumerate(pair_paths(5)):
        img = cv2.applyColorMap(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), cv2.COLORMAP_TURBO)
        paths.append(tmp_path / f"c{i}.png")
        cv2.imwrite(str(paths[-1]), img)
    args = ["rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path / "o"), *map(str, paths)]
    assert main(args) == 0
    got = cv2.imread(str(tmp_path / "o" / "left.png"), cv2.IMREAD_UNCHANGED)
    assert got.shape == (480, 640, 3)
    cal = calibrate_sample()
    m1, m2 = cv2.initUndistortRectifyMap(
        cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1, (640, 480), cv2.CV_16SC2
    )
    expected = cv2.remap(cv2.imread(str(paths[0])), m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    assert np.count_nonzero(got == expected) >= 0.999 * got.size
    assert not np.array_equal(got[..., 0], got[..., 2])


@pytest.mark.not_on_armhf(
    "the project is imported from the checkout there, not pip-installed: no console script")
def test_console_script_runs(tmp_path, calfiles) -> None:
    exe = shutil.which("stereocam", path=os.path.dirname(sys.executable))
    assert exe, "the stereocam console script is installed beside the interpreter"
    left, right = pair_paths(1)
    args = [exe, "rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path), str(left), str(right)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120 * SLOWNESS)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "left.png").stat().st_size > 1000 and (tmp_path / "right.png").is_file()
    args = [exe, "rectify", "--calibration", "nope.yml", "-o", str(tmp_path), str(left), str(right)]
    bad = subprocess.run(args, capture_output=True, text=True, timeout=120 * SLOWNESS)
    assert bad.returncode == 2 and "two files separated by a comma" in bad.stderr
    assert "Traceback" not in bad.stderr
    # A truncated image: the one line, without OpenCV's own warning printed beside it.
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(cv2.imencode(".png", cv2.imread(str(left)))[1].tobytes()[:200])
    args = [exe, "rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path), str(corrupt), str(right)]
    bad = subprocess.run(args, capture_output=True, text=True, timeout=120 * SLOWNESS)
    assert bad.returncode == 2
    assert bad.stderr.splitlines()[-1] == (f"stereocam rectify: error: {corrupt}: not a readable image "
                                           "(PNG, JPEG, BMP, TIFF, PGM/PPM)")
    # OpenCV's logger says nothing (libpng's own "libpng error: ..." line, which OpenCV 4 lets through
    # to stderr, is not OpenCV's to silence).
    assert "[ WARN" not in bad.stderr and "Traceback" not in bad.stderr, bad.stderr


def write_yml(path: Path, **mats) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in mats.items():
        fs.write(k, np.asarray(v, dtype=np.float64))
    fs.release()
    return path


def read_yml(path: Path) -> dict:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    keys = fs.root().keys()
    out = {k: fs.getNode(k).mat() for k in keys}
    fs.release()
    return out


@pytest.mark.parametrize("case, message", [
    ("too_few_rows", "needs 63 line-buffer rows but the core buffers 40"),
    ("k3", "D1 has k3 = 0.1 but the core models only k1, k2, p1, p2: recalibrate with k3 fixed at 0"),
    ("missing", "missing R2"),
    ("nan", "P1 has values that are not finite numbers"),
    ("singular", "rectification.P1 is not the projection of a rectified camera"),
    ("out_of_range", "left FX = 1e+06 is outside the register's range"),
    ("malformed", "not an OpenCV YAML/XML file"),
    ("no_file", "no such file"),
    ("shape", "P2 must be 3x4, is 3x3"),
])
def test_bad_calibrations_get_one_line_and_exit_2(tmp_path, calfiles, capsys, case, message) -> None:
    intr, extr = read_yml(calfiles[0]), read_yml(calfiles[1])
    lb = ["--lb-rows", "40"] if case == "too_few_rows" else []
    if case == "k3":
        intr["D1"] = np.array([[-0.28, 0.06, 0.0, 0.0, 0.1]])
    if case == "missing":
        del extr["R2"]
    if case == "nan":
        extr["P1"][0, 0] = np.nan
    if case == "singular":
        extr["P1"] = np.zeros((3, 4))
    if case == "out_of_range":
        intr["M1"][0, 0] = 1e6
    if case == "shape":
        extr["P2"] = extr["P2"][:, :3]
    i_path = write_yml(tmp_path / "i.yml", **intr)
    e_path = write_yml(tmp_path / "e.yml", **extr)
    if case == "malformed":
        e_path.write_text("%YAML:1.0\nR: !!opencv-matrix\n  rows: 3\n  cols: [oops\n")
    if case == "no_file":
        e_path = tmp_path / "absent.yml"
    left, right = pair_paths(1)
    err = run_error(capsys, ["rectify", *lb, "--calibration", f"{i_path},{e_path}", "-o", str(tmp_path / "o"),
                             str(left), str(right)])
    assert message in err
    assert not (tmp_path / "o" / "left.png").exists(), "nothing is written for a refused calibration"


def test_bad_images_get_one_line_and_exit_2(tmp_path, calfiles, capsys) -> None:
    left, right = pair_paths(1)
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(left.read_bytes()[:200])
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 120), np.uint8))
    huge_l, huge_r = tmp_path / "hl.png", tmp_path / "hr.png"
    cv2.imwrite(str(huge_l), np.zeros((100, 2000), np.uint8))
    cv2.imwrite(str(huge_r), np.zeros((100, 2000), np.uint8))
    bomb, gigapixel = tmp_path / "bomb.png", tmp_path / "gigapixel.png"
    bomb.write_bytes(png_claiming(5000, 5000))  # OpenCV would decode it: 75 MB for a header
    gigapixel.write_bytes(png_claiming(60000, 60000))  # OpenCV raised its own error: a traceback
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), np.zeros((480, 640), np.uint16))
    cal = cal_arg(calfiles)
    too_many = "the image header claims more than the 16.8 megapixels read"
    for l_img, r_img, message in (
        (corrupt, right, "corrupt.png: not a readable image"),
        (left, small, "left is 640x480 but right is 120x100"),
        (huge_l, huge_r, "a 2000x100 frame does not fit the core (at most 752x1024)"),
        (deep, right, "uint16 pixels"),
        (bomb, right, f"bomb.png: {too_many}: 5000x5000 (25.0 megapixels"),
        (left, gigapixel, f"gigapixel.png: {too_many} (a decompression bomb?)"),
        (tmp_path / "nope.png", right, "nope.png: no such file"),
    ):
        args = ["rectify", "--calibration", cal, "-o", str(tmp_path / "o"), str(l_img), str(r_img)]
        assert message in run_error(capsys, args)


# -- --fit: a pair of another size than the calibration's -------------------------

def gray(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def rectified(tmp_path: Path, name: str, cal: str, left: np.ndarray, right: np.ndarray,
              *extra: str) -> np.ndarray:
    """``stereocam rectify`` of the pair (written as PNGs), its left output."""
    folder = tmp_path / name
    folder.mkdir()
    cv2.imwrite(str(folder / "l.png"), left)
    cv2.imwrite(str(folder / "r.png"), right)
    assert main(["rectify", "--calibration", cal, *extra, "-o", str(folder / "out"),
                 str(folder / "l.png"), str(folder / "r.png")]) == 0
    return cv2.imread(str(folder / "out" / "left.png"), cv2.IMREAD_UNCHANGED)


def test_fit_pad_rectifies_a_smaller_pair_as_that_pair_padded_with_black(tmp_path, calfiles, capsys) -> None:
    cal = cal_arg(calfiles)
    left, right = (gray(p)[5:-4, 20:-13] for p in pair_paths(3))  # 607x471
    got = rectified(tmp_path, "fit", cal, left, right, "--size", "640x480", "--fit", "pad")
    out = capsys.readouterr().out
    assert ("fit pad: 607x471 -> 640x480: padded 33 columns (16 left, 17 right) with black; "
            "padded 9 rows (4 top, 5 bottom) with black") in out
    pad = ((4, 5), (16, 17))
    expected = rectified(tmp_path, "by-hand", cal, np.pad(left, pad), np.pad(right, pad))
    assert got.shape == (480, 640)
    np.testing.assert_array_equal(got, expected)


def test_fit_crop_takes_the_centre_of_a_larger_pair(tmp_path, calfiles) -> None:
    cal = cal_arg(calfiles)
    left, right = (cv2.copyMakeBorder(gray(p), 11, 11, 30, 31, cv2.BORDER_REFLECT) for p in pair_paths(4))
    got = rectified(tmp_path, "fit", cal, left, right, "--size", "640x480", "--fit", "crop")
    expected = rectified(tmp_path, "by-hand", cal, *(gray(p) for p in pair_paths(4)))  # what was added, cut
    np.testing.assert_array_equal(got, expected)


def test_fit_scale_shrinks_with_inter_area_keeping_the_aspect_ratio(tmp_path, calfiles, capsys) -> None:
    cal = cal_arg(calfiles)
    big = [cv2.resize(gray(p), (1280, 960), interpolation=cv2.INTER_CUBIC) for p in pair_paths(5)]
    got = rectified(tmp_path, "fit", cal, *big, "--size", "640x480", "--fit", "scale")
    assert "shrunk from 1280x960 to 640x480 (x0.5, aspect ratio kept)" in capsys.readouterr().out
    expected = rectified(tmp_path, "by-hand", cal,
                         *(cv2.resize(b, (640, 480), interpolation=cv2.INTER_AREA) for b in big))
    np.testing.assert_array_equal(got, expected)


def test_fit_uses_the_size_a_stereocam_calibration_records(tmp_path, calfiles, capsys) -> None:
    yaml_path = tmp_path / "calibration.yaml"
    assert main(["calibration", "import", "--size", "640x480", str(calfiles[0]), str(calfiles[1]),
                 "-o", str(yaml_path)]) == 0
    left, right = (gray(p)[:, :600] for p in pair_paths(3))
    got = rectified(tmp_path, "fit", str(yaml_path), left, right, "--fit", "scale")
    assert got.shape == (480, 640)
    assert "padded 40 columns (20 left, 20 right) with black" in capsys.readouterr().out


def test_fit_errors_get_one_line_and_exit_2(tmp_path, calfiles, capsys) -> None:
    cal = cal_arg(calfiles)
    small_l, small_r = tmp_path / "sl.png", tmp_path / "sr.png"
    cv2.imwrite(str(small_l), gray(pair_paths(1)[0])[:400, :500])
    cv2.imwrite(str(small_r), gray(pair_paths(1)[1])[:400, :500])
    odd_r = tmp_path / "odd.png"
    cv2.imwrite(str(odd_r), gray(pair_paths(1)[1])[:400, :501])
    out = str(tmp_path / "o")
    for argv, message in (
        (["--fit", "pad", str(small_l), str(small_r)], "does not record the image size"),  # no --size
        (["--size", "640x480", str(small_l), str(small_r)],
         "the images are 500x400, the calibration is for 640x480: give --fit crop, pad or scale"),
        (["--size", "640x480", "--fit", "pad", str(small_l), str(odd_r)],
         "left is 500x400 but right is 501x400"),
    ):
        assert message in run_error(capsys, ["rectify", "--calibration", cal, "-o", out, *argv])
    assert not (tmp_path / "o" / "left.png").exists()
    with pytest.raises(SystemExit) as stop:  # argparse names the choices
        main(["rectify", "--calibration", cal, "--fit", "stretch", "-o", out, str(small_l), str(small_r)])
    assert stop.value.code == 2
    assert "invalid choice: 'stretch'" in capsys.readouterr().err
