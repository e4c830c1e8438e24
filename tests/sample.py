"""OpenCV's stereo sample (tests/data/opencv-stereo-calib) calibrated once per test session.

The calibration follows OpenCV's stereo_calib sample with the core's lens
model (k3 fixed at 0). Cached: several test modules share it.
"""
from __future__ import annotations

import functools
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import List, Tuple

import cv2
import numpy as np

from stereocam.calibration.stereo import Rectification, StereoModel, core_cameras, rectify
from stereocam.overlays.emulated.targets import board_image, board_size_m, random_board_poses
from stereocam.overlays.spec.rectify import CameraParams

DATA = Path(__file__).parent / "data" / "opencv-stereo-calib"
PAIRS = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
PATTERN = (9, 6)


@dataclass(frozen=True)
class SampleCalibration:
    model: StereoModel
    rect: Rectification
    left: CameraParams
    right: CameraParams
    rms: float


def pair_paths(i: int) -> Tuple[Path, Path]:
    return DATA / f"left{i:02d}.jpg", DATA / f"right{i:02d}.jpg"


@functools.lru_cache(maxsize=1)
def calibrate_sample() -> SampleCalibration:
    obj = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0:PATTERN[0], 0:PATTERN[1]].T.reshape(-1, 2)
    objs: List[np.ndarray] = []
    lefts: List[np.ndarray] = []
    rights: List[np.ndarray] = []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    for i in PAIRS:
        corners = []
        for path in pair_paths(i):
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            assert img is not None, f"cannot read {path}"
            ok, c = cv2.findChessboardCorners(img, PATTERN)
            assert ok, f"no chessboard in {path}"
            corners.append(cv2.cornerSubPix(img, c, (11, 11), (-1, -1), crit))
        objs.append(obj)
        lefts.append(corners[0])
        rights.append(corners[1])
    size = (640, 480)
    flags = cv2.CALIB_FIX_K3
    _, K1, D1, _, _ = cv2.calibrateCamera(objs, lefts, size, None, None, flags=flags)
    _, K2, D2, _, _ = cv2.calibrateCamera(objs, rights, size, None, None, flags=flags)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        objs, lefts, rights, K1, D1, K2, D2, size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5),
    )
    model = StereoModel(K1, D1.ravel()[:4], K2, D2.ravel()[:4], R, T.ravel(), size)
    rect = rectify(model, alpha=0.0)
    left, right = core_cameras(model, rect)
    return SampleCalibration(model, rect, left, right, float(rms))


def read_pair(i: int = 1, flags: int = cv2.IMREAD_GRAYSCALE) -> Tuple[np.ndarray, np.ndarray]:
    left, right = (cv2.imread(str(p), flags) for p in pair_paths(i))
    return left, right


def write_opencv_files(cal: SampleCalibration, folder: Path) -> Tuple[Path, Path]:
    """intrinsics.yml and extrinsics.yml as OpenCV's stereo_calib sample writes them."""
    intr, extr = folder / "intrinsics.yml", folder / "extrinsics.yml"
    fs = cv2.FileStorage(str(intr), cv2.FILE_STORAGE_WRITE)
    for name, value in (("M1", cal.model.K1), ("D1", np.append(cal.model.D1, 0.0)),
                        ("M2", cal.model.K2), ("D2", np.append(cal.model.D2, 0.0))):
        fs.write(name, np.asarray(value, dtype=np.float64).reshape(1, -1) if name.startswith("D") else value)
    fs.release()
    fs = cv2.FileStorage(str(extr), cv2.FILE_STORAGE_WRITE)
    for name, value in (("R", cal.model.R), ("T", cal.model.T.reshape(3, 1)), ("R1", cal.rect.R1),
                        ("R2", cal.rect.R2), ("P1", cal.rect.P1), ("P2", cal.rect.P2), ("Q", cal.rect.Q)):
        fs.write(name, np.asarray(value, dtype=np.float64))
    fs.release()
    return intr, extr


# -- checkerboard views of the synthetic rig (known calibration) -----------------

SYNTH_PATTERN = (9, 6)
SYNTH_SQUARE = 0.03  # metres


@functools.lru_cache(maxsize=2)
def synthetic_views(
    n: int = 12, seed: int = 0,
) -> "Tuple[StereoModel, Tuple[Tuple[np.ndarray, np.ndarray], ...]]":
    """The synthetic rig's true model and ``n`` (left, right) gray views of a 9x6 board (30 mm squares).

    Poses are random (seeded): tilted up to ~35 degrees, 0.35 to 0.7 m away,
    anywhere in the image, kept only when the whole printed board is inside
    both images. About 2 s for 12 views at 752x480 (cached per session).
    """
    from stereocam.overlays.emulated.render import SyntheticRig

    board = board_image(*SYNTH_PATTERN)
    size_m = board_size_m(SYNTH_PATTERN, SYNTH_SQUARE)
    with SyntheticRig(motion=False, colour=False) as rig:
        rng = np.random.default_rng(seed)
        poses = random_board_poses(rig.model, SYNTH_PATTERN, SYNTH_SQUARE, n=n, rng=rng)
        views = tuple(rig.render_plane_views(board, size_m, R, t) for R, t in poses)
        return rig.model, views


# -- image files that lie about their size -----------------------------------------

def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_claiming(w: int, h: int) -> bytes:
    """A tiny, well-formed PNG whose IHDR (valid CRC) claims w x h RGB pixels: no pixel data to speak of."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", zlib.compress(b"\x00" * 64))
            + png_chunk(b"IEND", b""))
