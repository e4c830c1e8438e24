"""The stereo camera model: two pinhole cameras with Brown-Conrady distortion.

``R`` and ``T`` take points from the left camera's frame to the right's
(OpenCV's ``stereoCalibrate`` convention: ``X_right = R @ X_left + T``).
Distortion is ``(k1, k2, p1, p2)``: the rectify core has no k3.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Tuple

import numpy as np

if TYPE_CHECKING:
    from ..overlays.spec.rectify import CameraParams


@dataclass(frozen=True)
class StereoModel:
    K1: np.ndarray  # 3x3 left intrinsics
    D1: np.ndarray  # (4,) left k1, k2, p1, p2
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray  # 3x3 rotation left -> right
    T: np.ndarray  # (3,) translation left -> right, in the units of the pattern
    image_size: Tuple[int, int]  # (width, height)

    def __post_init__(self) -> None:
        shapes = (("K1", (3, 3)), ("K2", (3, 3)), ("R", (3, 3)), ("D1", (4,)), ("D2", (4,)), ("T", (3,)))
        for name, shape in shapes:
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if name in ("D1", "D2", "T"):
                value = value.reshape(-1)
            if value.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        w, h = self.image_size
        object.__setattr__(self, "image_size", (int(w), int(h)))

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))


@dataclass(frozen=True)
class Rectification:
    """Output of stereo rectification (OpenCV ``stereoRectify`` conventions)."""

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray  # 3x4
    P2: np.ndarray  # 3x4
    Q: np.ndarray  # 4x4
    image_size: Tuple[int, int]


def rectify(model: StereoModel, *, alpha: float = 0.0) -> Rectification:
    """Rotate each camera half way to a common virtual camera; zero disparity at infinity.

    ``alpha`` 0 keeps only valid pixels, 1 keeps every source pixel (OpenCV's meaning).
    """
    import cv2

    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        model.K1, model.D1, model.K2, model.D2, model.image_size, model.R, model.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=float(alpha),
    )
    return Rectification(R1, R2, P1, P2, Q, model.image_size)


def inverse_homography(K: np.ndarray, R: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``H^-1 = K (P R)^-1``: rectified pixel -> ideal raw pixel (column vectors).

    ``P`` is the 3x3 left part of the rectified projection. Raises
    ``numpy.linalg.LinAlgError`` if ``P R`` is singular.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # a hostile file's 1e308: refused just below
        M = np.asarray(P, dtype=np.float64)[:, :3] @ np.asarray(R, dtype=np.float64)
    if not np.all(np.isfinite(M)):
        raise np.linalg.LinAlgError("the rectifying projection P*R is not finite: its numbers are too large")
    # Singular when |det M| < 1e-12 max(1, s^3), s the largest |entry|: det(M / s) for s > 1,
    # whose entries are at most 1, so the determinant cannot overflow.
    scale = float(np.abs(M).max())
    if abs(np.linalg.det(M / scale if scale > 1.0 else M)) < 1e-12:
        raise np.linalg.LinAlgError("the rectifying projection P*R is singular")
    return np.asarray(K, dtype=np.float64) @ np.linalg.inv(M)


def camera_params(K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray) -> "CameraParams":
    """One camera's core parameters from its intrinsics, distortion and rectification."""
    from ..overlays.spec.rectify import CameraParams

    K = np.asarray(K, dtype=np.float64)
    d = np.asarray(D, dtype=np.float64).reshape(-1)
    if d.size > 4 and np.any(d[4:] != 0):
        raise ValueError(
            f"distortion has {d.size} coefficients and k3 or higher is not 0 ({d[4:].tolist()}): "
            "the core models k1, k2, p1, p2 only; calibrate with k3 fixed at 0 (cv2.CALIB_FIX_K3)"
        )
    hinv = inverse_homography(K, R, P)
    return CameraParams(
        tuple(float(v) for v in hinv.ravel()),
        float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
        *(float(v) for v in np.pad(d[:4], (0, max(0, 4 - d.size)))),
    )


def core_cameras(model: StereoModel, rect: Rectification) -> "Tuple[CameraParams, CameraParams]":
    """Left and right core parameters for a rectified stereo model."""
    return (
        camera_params(model.K1, model.D1, rect.R1, rect.P1),
        camera_params(model.K2, model.D2, rect.R2, rect.P2),
    )
