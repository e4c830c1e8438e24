"""Reading calibrations users already have.

For now: the two files OpenCV's ``stereo_calib`` sample writes,
``intrinsics.yml`` (M1, D1, M2, D2) and ``extrinsics.yml`` (R, T, R1, R2, P1,
P2, Q). Every problem is a :class:`CalibrationFileError` whose message names
the file and the field, so the CLI can print it on one line.
"""
from __future__ import annotations

from pathlib import Path
from typing import Dict, Sequence, Tuple

import numpy as np

from .stereo import Rectification, StereoModel

INTRINSIC_FIELDS = ("M1", "D1", "M2", "D2")
EXTRINSIC_FIELDS = ("R", "T", "R1", "R2", "P1", "P2", "Q")
SHAPES: Dict[str, Tuple[int, ...]] = {
    "M1": (3, 3), "M2": (3, 3), "R": (3, 3), "T": (3,), "R1": (3, 3), "R2": (3, 3),
    "P1": (3, 4), "P2": (3, 4), "Q": (4, 4),
}


class CalibrationFileError(ValueError):
    """A calibration file that cannot be used; the message says which and why."""


def _read_opencv_file(path: Path, fields: Sequence[str]) -> Dict[str, np.ndarray]:
    import cv2

    if not path.is_file():
        raise CalibrationFileError(f"{path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 5 wraps parse errors in SystemError
        cause = exc.__cause__ or exc
        lines = str(cause).strip().splitlines()
        reason = lines[-1].split("error: ", 1)[-1] if lines else "parse error"
        raise CalibrationFileError(f"{path}: not an OpenCV YAML/XML file ({reason})") from None
    try:
        if not fs.isOpened():
            raise CalibrationFileError(f"{path}: not an OpenCV YAML/XML file")
        out: Dict[str, np.ndarray] = {}
        missing = []
        for name in fields:
            node = fs.getNode(name)
            if node.empty() or node.isNone():
                missing.append(name)
                continue
            mat = node.mat()
            if mat is None:
                raise CalibrationFileError(f"{path}: {name} is not a matrix")
            out[name] = np.asarray(mat, dtype=np.float64)
        if missing:
            raise CalibrationFileError(f"{path}: missing {', '.join(missing)} (expected {', '.join(fields)})")
        return out
    finally:
        fs.release()


def _shaped(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(value)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    want = SHAPES[name]
    if want == (3,):
        if value.size != 3:
            raise CalibrationFileError(f"{path}: {name} must have 3 values, has {value.size}")
        return value.reshape(3)
    if value.shape != want:
        raise CalibrationFileError(f"{path}: {name} must be {want[0]}x{want[1]}, is {'x'.join(map(str, value.shape))}")
    return value


def _distortion(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    d = value.reshape(-1)
    if not np.all(np.isfinite(d)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    if d.size not in (4, 5, 8, 12, 14):
        raise CalibrationFileError(f"{path}: {name} has {d.size} coefficients; expected k1, k2, p1, p2[, k3...]")
    if np.any(d[4:] != 0):
        raise CalibrationFileError(
            f"{path}: {name} has k3 = {d[4]:g} (or a higher term) but the core models only k1, k2, p1, p2: "
            "recalibrate with k3 fixed at 0 (cv2.CALIB_FIX_K3)"
        )
    return d[:4]


def load_opencv_pair(intrinsics: Path, extrinsics: Path, image_size: Tuple[int, int]) -> Tuple[StereoModel, Rectification]:
    """The stereo model and rectification from OpenCV stereo_calib files.

    ``image_size`` (width, height) comes from the images: these files do not
    record it.
    """
    intr = _read_opencv_file(intrinsics, INTRINSIC_FIELDS)
    extr = _read_opencv_file(extrinsics, EXTRINSIC_FIELDS)
    m = {n: _shaped(intrinsics, n, intr[n]) for n in ("M1", "M2")}
    d = {n: _distortion(intrinsics, n, intr[n]) for n in ("D1", "D2")}
    e = {n: _shaped(extrinsics, n, v) for n, v in extr.items()}
    model = StereoModel(m["M1"], d["D1"], m["M2"], d["D2"], e["R"], e["T"], image_size)
    rect = Rectification(e["R1"], e["R2"], e["P1"], e["P2"], e["Q"], image_size)
    return model, rect


def parse_calibration_arg(arg: str) -> Tuple[Path, Path]:
    """``intrinsics.yml,extrinsics.yml`` -> two paths."""
    parts = [p for p in arg.split(",") if p]
    if len(parts) != 2:
        raise CalibrationFileError(
            f"--calibration takes two files separated by a comma, intrinsics.yml,extrinsics.yml; got {arg!r}"
        )
    return Path(parts[0]), Path(parts[1])
