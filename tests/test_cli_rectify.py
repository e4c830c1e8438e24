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

from .sample import calibrate_sample, pair_paths, write_opencv_files


@pytest.fixture(scope="module")
def calfiles(tmp_path_factory) -> "tuple[Path, Path]":
    return write_opencv_files(calibrate_sample(), tmp_path_factory.mktemp("cal"))


def cal_arg(files) -> str:
    return f"{files[0]},{files[1]}"


def run_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("stereocam rectify: error: "), err
    assert "Traceback" not in err
    return err


def test_gray_pair_is_rectified_like_opencv(tmp_path, calfiles, capsys) -> None:
    left, right = pair_paths(3)
    assert main(["rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path / "out"), str(left), str(right)]) == 0
    out = capsys.readouterr().out
    assert "line buffer: 63 of 80 rows needed (delay 35)" in out
    cal = calibrate_sample()
    for path, K, D, R, P in ((left, cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1),
                             (right, cal.model.K2, cal.model.D2, cal.rect.R2, cal.rect.P2)):
        got = cv2.imread(str(tmp_path / "out" / ("left.png" if path == left else "right.png")), cv2.IMREAD_UNCHANGED)
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
    assert main(["rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path / "o"), *map(str, paths)]) == 0
    got = cv2.imread(str(tmp_path / "o" / "left.png"), cv2.IMREAD_UNCHANGED)
    assert got.shape == (480, 640, 3)
    cal = calibrate_sample()
    m1, m2 = cv2.initUndistortRectifyMap(cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1, (640, 480), cv2.CV_16SC2)
    expected = cv2.remap(cv2.imread(str(paths[0])), m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    assert np.count_nonzero(got == expected) >= 0.999 * got.size
    assert not np.array_equal(got[..., 0], got[..., 2])


def test_console_script_runs(tmp_path, calfiles) -> None:
    exe = shutil.which("stereocam", path=os.path.dirname(sys.executable))
    assert exe, "the stereocam console script is installed beside the interpreter"
    left, right = pair_paths(1)
    done = subprocess.run([exe, "rectify", "--calibration", cal_arg(calfiles), "-o", str(tmp_path), str(left), str(right)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "left.png").stat().st_size > 1000 and (tmp_path / "right.png").is_file()
    bad = subprocess.run([exe, "rectify", "--calibration", "nope.yml", "-o", str(tmp_path), str(left), str(right)],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "two files separated by a comma" in bad.stderr and "Traceback" not in bad.stderr


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
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), np.zeros((480, 640), np.uint16))
    cal = cal_arg(calfiles)
    for l_img, r_img, message in (
        (corrupt, right, "corrupt.png: not a readable image"),
        (left, small, "left is 640x480 but right is 120x100"),
        (huge_l, huge_r, "a 2000x100 frame does not fit the core (at most 752x1024)"),
        (deep, right, "uint16 pixels"),
        (tmp_path / "nope.png", right, "nope.png: no such file"),
    ):
        assert message in run_error(capsys, ["rectify", "--calibration", cal, "-o", str(tmp_path / "o"), str(l_img), str(r_img)])
