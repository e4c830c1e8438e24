"""ROS camera_info export (``calibration export --ros``) and the distortion terms other tools' files carry."""
from __future__ import annotations

import re
from pathlib import Path
from typing import List, Tuple

import cv2
import numpy as np
import pytest
import yaml

from stereocam.calibration.file import Calibration, load_calibration
from stereocam.calibration.formats import CalibrationFileError
from stereocam.cli import main

from ..sample import PAIRS, PATTERN, calibrate_sample, pair_paths, write_opencv_files

ROS_KEYS = ["image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
            "distortion_coefficients", "rectification_matrix", "projection_matrix"]


def sample(units: str) -> Calibration:
    s = calibrate_sample()
    return Calibration.derive(s.model, s.rect, alpha=0.0, units=units, source="tests.sample")


def cli(capsys: pytest.CaptureFixture, argv: List[str]) -> Tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_export_ros_then_import_gives_the_same_calibration(tmp_path: Path, capsys) -> None:
    cal = sample("m")
    path = cal.save(tmp_path / "calibration.yaml")
    code, out, err = cli(capsys, ["calibration", "export", str(path), "--ros", str(tmp_path / "ros")])
    assert code == 0, err
    left, right = tmp_path / "ros" / "left.yaml", tmp_path / "ros" / "right.yaml"
    assert out == f"wrote {left} and {right} (ROS camera_info, calibration {cal.id})\n"
    for name, file, K, D, R, P in (("left", left, cal.model.K1, cal.model.D1, cal.rect.R1, cal.rect.P1),
                                   ("right", right, cal.model.K2, cal.model.D2, cal.rect.R2, cal.rect.P2)):
        data = yaml.safe_load(file.read_text())  # camera_calibration_parsers' layout, as PyYAML reads it
        assert list(data) == ROS_KEYS
        assert (data["image_width"], data["image_height"], data["camera_name"]) == (640, 480, name)
        assert data["distortion_model"] == "plumb_bob"
        for key, value, rows, cols in (("camera_matrix", K, 3, 3), ("rectification_matrix", R, 3, 3),
                                       ("projection_matrix", P, 3, 4),
                                       ("distortion_coefficients", np.append(D, 0.0), 1, 5)):
            assert (data[key]["rows"], data[key]["cols"]) == (rows, cols)
            assert data[key]["data"] == [float(v) for v in np.ravel(value)], key  # exactly the doubles

    again = tmp_path / "again.yaml"
    code, out, err = cli(capsys, ["calibration", "import", str(left), str(right), "-o", str(again)])
    assert code == 0, err
    back = load_calibration(again)
    assert (back.left, back.right, back.fit) == (cal.left, cal.right, cal.fit), "the same registers"
    assert back.core_config() == cal.core_config()
    for name in ("K1", "D1", "K2", "D2"):
        assert np.array_equal(getattr(back.model, name), getattr(cal.model, name)), name
    for name in ("R1", "R2", "P1", "P2"):
        assert np.array_equal(getattr(back.rect, name), getattr(cal.rect, name)), name
    # R, T and Q are rebuilt from the rectification (ROS files do not carry them).
    assert np.allclose(back.model.R, cal.model.R, atol=1e-12)
    assert np.allclose(back.model.T, cal.model.T, rtol=1e-9, atol=1e-12)
    assert np.allclose(back.rect.Q, cal.rect.Q, rtol=1e-9, atol=1e-12)
    assert back.units == "m" and back.image_size == cal.image_size


def test_export_ros_converts_lengths_to_metres(tmp_path: Path, capsys) -> None:
    cal = sample("mm")
    path = cal.save(tmp_path / "calibration.yaml")
    code, out, err = cli(capsys, ["calibration", "export", str(path), "--ros", str(tmp_path / "ros"),
                                  "--opencv", str(tmp_path / "cv")])
    assert code == 0, err
    assert out.splitlines()[0] == (f"wrote {tmp_path / 'cv' / 'intrinsics.yml'} and "
                                   f"{tmp_path / 'cv' / 'extrinsics.yml'} (calibration {cal.id})")
    right = yaml.safe_load((tmp_path / "ros" / "right.yaml").read_text())
    P2 = np.array(right["projection_matrix"]["data"]).reshape(3, 4)
    assert P2[0, 3] == pytest.approx(cal.rect.P2[0, 3] / 1000, rel=1e-15)
    back = load_calibration([tmp_path / "ros" / "left.yaml", tmp_path / "ros" / "right.yaml"])
    assert np.allclose(back.model.T, cal.model.T / 1000, rtol=1e-9, atol=1e-15)
    assert (back.left, back.right) == (cal.left, cal.right)


def test_export_ros_says_when_the_unit_is_not_a_length(tmp_path: Path, capsys) -> None:
    path = sample("squares").save(tmp_path / "calibration.yaml")
    code, out, err = cli(capsys, ["calibration", "export", str(path), "--ros", str(tmp_path / "ros")])
    assert code == 0, err
    assert out.rstrip("\n").endswith("; note: the calibration's lengths are in 'squares', not a known unit, "
                                      "so T is written as it is, while ROS expects metres")


def test_export_needs_a_format(tmp_path: Path, capsys) -> None:
    path = sample("m").save(tmp_path / "calibration.yaml")
    code, out, err = cli(capsys, ["calibration", "export", str(path)])
    assert code == 2 and err == (
        "stereocam calibration export: error: say what to write: --opencv OUTDIR, --ros OUTDIR or both\n")


# -- distortion terms the core does not model ----------------------------------------------------------

def opencv_sample_calibration() -> Tuple[np.ndarray, ...]:
    """OpenCV's stereo_calib sample, run as the sample runs it on its own pairs (its flags)."""
    obj = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0:PATTERN[0], 0:PATTERN[1]].T.reshape(-1, 2)
    objs, lefts, rights = [], [], []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    for i in PAIRS:
        corners = []
        for path in pair_paths(i):
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            ok, c = cv2.findChessboardCorners(img, PATTERN)
            assert ok, path
            corners.append(cv2.cornerSubPix(img, c, (11, 11), (-1, -1), crit))
        objs.append(obj)
        lefts.append(corners[0])
        rights.append(corners[1])
    size = (640, 480)
    K1 = cv2.initCameraMatrix2D(objs, lefts, size, 0)
    K2 = cv2.initCameraMatrix2D(objs, rights, size, 0)
    flags = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_USE_INTRINSIC_GUESS
             | cv2.CALIB_SAME_FOCAL_LENGTH | cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_K4
             | cv2.CALIB_FIX_K5)
    _, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        objs, lefts, rights, K1, np.zeros(8), K2, np.zeros(8), size, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5))
    return K1, D1, K2, D2


def test_opencv_sample_files_are_refused_for_k6_not_k3(tmp_path: Path) -> None:
    K1, D1, K2, D2 = opencv_sample_calibration()
    d = D1.ravel()
    # k1, k2 and k6 (p1, p2: CALIB_ZERO_TANGENT_DIST); 8 coefficients (OpenCV 5: 14, the rest 0).
    assert d.size in (8, 14) and np.flatnonzero(d).tolist() == [0, 1, 7], d
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)
    fs = cv2.FileStorage(str(intr), cv2.FILE_STORAGE_WRITE)  # intrinsics.yml as stereo_calib writes it
    for name, value in (("M1", K1), ("D1", D1.reshape(1, -1)), ("M2", K2), ("D2", D2.reshape(1, -1))):
        fs.write(name, np.asarray(value, dtype=np.float64))
    fs.release()
    with pytest.raises(CalibrationFileError) as err:
        load_calibration([intr, extr], image_size=(640, 480))
    assert str(err.value) == (
        f"{intr}: D1 has k6 = {d[7]:g} but the core models only k1, k2, p1, p2: recalibrate without "
        "cv2.CALIB_RATIONAL_MODEL (or with cv2.CALIB_FIX_K6)")


@pytest.mark.parametrize("coefficients, message", [
    ([0.1, 0.0, 0.0, 0.0, 0.2], "D1 has k3 = 0.2 but the core models only k1, k2, p1, p2: recalibrate with "
                                "k3 fixed at 0 (cv2.CALIB_FIX_K3)"),
    ([0.1, 0.0, 0.0, 0.0, 0.2, 0.3, 0.0, 0.0],
     "D1 has k3 = 0.2, k4 = 0.3 but the core models only k1, k2, p1, p2: recalibrate with k3 fixed at 0 "
     "(cv2.CALIB_FIX_K3) and without cv2.CALIB_RATIONAL_MODEL (or with cv2.CALIB_FIX_K4)"),
    ([0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.02],
     "D1 has s1 = 0.01, ty = 0.02 but the core models only k1, k2, p1, p2: recalibrate without "
     "cv2.CALIB_THIN_PRISM_MODEL and without cv2.CALIB_TILTED_MODEL"),
])
def test_each_extra_term_is_named_with_its_flag(tmp_path: Path, coefficients, message) -> None:
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)
    fs = cv2.FileStorage(str(intr), cv2.FILE_STORAGE_WRITE)
    s = calibrate_sample().model
    for name, value in (("M1", s.K1), ("D1", np.array([coefficients])), ("M2", s.K2),
                        ("D2", np.append(s.D2, 0.0).reshape(1, -1))):
        fs.write(name, np.asarray(value, dtype=np.float64))
    fs.release()
    with pytest.raises(CalibrationFileError, match=re.escape(f"{intr}: {message}")):
        load_calibration([intr, extr], image_size=(640, 480))
