"""The synthetic rig's lenses: their true calibration, the exact inverse of their distortion, and each
pixel's viewing ray.

Pixel convention (OpenCV's, and the rectify core's): the centre of pixel
``(column u, row v)`` is at image coordinates ``(u, v)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, Tuple, Union

import cv2
import numpy as np

from ...calibration.stereo import StereoModel

__all__ = ["BASE_SIZE", "Rays", "rig_model", "rotation", "undistort_normalized"]


def undistort_normalized(
    K: np.ndarray, D: Union[np.ndarray, Sequence[float]], u: np.ndarray, v: np.ndarray, *,
    tol: float = 1e-13, max_iter: int = 30,
) -> Tuple[np.ndarray, np.ndarray]:
    """Ideal normalized coordinates ``(x, y)`` of raw (distorted) pixel positions ``(u, v)``.

    The exact inverse of the Brown-Conrady model (k1, k2, p1, p2): Newton's
    method in float64 to ``tol`` (normalized units), started from
    ``cv2.undistortPoints``, which alone stops after 5 fixed-point steps and
    is off by ~0.5 px in the corners of a strongly distorted lens. Raises
    ``ValueError`` if the distortion has no inverse there (fold-over).
    """
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(D, dtype=np.float64).reshape(-1)[:4]
    k1, k2, p1, p2 = (float(c) for c in dist)
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    shape = np.broadcast(u, v).shape
    uf = np.broadcast_to(u, shape).reshape(-1)
    vf = np.broadcast_to(v, shape).reshape(-1)
    x_out = np.empty(uf.size)
    y_out = np.empty(uf.size)
    chunk = 1 << 16  # keeps the temporaries in cache: 3x faster than whole-image arrays
    for lo in range(0, uf.size, chunk):
        hi = min(lo + chunk, uf.size)
        yd = (vf[lo:hi] - cy) / fy
        xd = (uf[lo:hi] - cx - skew * yd) / fx
        guess = cv2.undistortPoints(np.stack([uf[lo:hi], vf[lo:hi]], axis=-1).reshape(-1, 1, 2), K, dist)
        x = guess[:, 0, 0].astype(np.float64)
        y = guess[:, 0, 1].astype(np.float64)
        bad = ~(np.isfinite(x) & np.isfinite(y))
        x[bad], y[bad] = xd[bad], yd[bad]
        for _ in range(max_iter):
            x2, y2, xy = x * x, y * y, x * y
            r2 = x2 + y2
            radial = 1.0 + r2 * (k1 + k2 * r2)
            g = 2.0 * k1 + 4.0 * k2 * r2  # d(radial)/dx = g x
            ex = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) - xd
            ey = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy - yd
            a = radial + g * x2 + 2.0 * p1 * y + 6.0 * p2 * x
            b = g * xy + 2.0 * p1 * x + 2.0 * p2 * y  # d ex/dy == d ey/dx
            d = radial + g * y2 + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            if np.any(det <= 0):
                raise ValueError("the distortion folds over inside the image: it has no inverse there")
            dx = (d * ex - b * ey) / det
            dy = (a * ey - b * ex) / det
            x -= dx
            y -= dy
            if float(np.max(np.abs(dx), initial=0.0)) < tol and float(np.max(np.abs(dy), initial=0.0)) < tol:
                break
        else:
            raise ValueError(f"undistortion did not converge in {max_iter} Newton steps: too much distortion")
        x_out[lo:hi] = x
        y_out[lo:hi] = y
    return x_out.reshape(shape), y_out.reshape(shape)


def rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation about y (yaw), then x (pitch), then z (roll), camera axes (x right, y down, z forward)."""
    a, b, c = (math.radians(d) for d in (yaw_deg, pitch_deg, roll_deg))
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rz


# The rig at 752 x 480 (MT9V034, 6 um square pixels). A 2.52 mm lens gives
# f = 2.52 mm / 6 um = 420 px: about 84 deg horizontal field before the
# (barrel) distortion, which widens it further. Units: pixels for K, metres for T.
BASE_SIZE = (752, 480)
_K1 = ((420.0, 0.0, 372.3), (0.0, 419.2, 243.6), (0.0, 0.0, 1.0))
_D1 = (-0.15, 0.03, 8.0e-4, -5.0e-4)  # moderate barrel: the rig fits the 80-row bitstream (70 rows)
_K2 = ((423.1, 0.0, 379.8), (0.0, 422.5, 237.2), (0.0, 0.0, 1.0))
_D2 = (-0.145, 0.028, -6.0e-4, 9.0e-4)
_RVEC_DEG = (0.5, -1.0, 0.3)  # rotation vector left -> right, degrees
_C2 = (0.060, -0.0005, 0.0010)  # right camera centre in the left camera's frame, metres


def rig_model(size: Tuple[int, int] = BASE_SIZE) -> StereoModel:
    """The synthetic rig's calibration for an image of ``size = (width, height)``.

    At 752 x 480: K1 fx 420.0 fy 419.2 cx 372.3 cy 243.6, D1 (-0.15, 0.03,
    8e-4, -5e-4); K2 fx 423.1 fy 422.5 cx 379.8 cy 237.2, D2 (-0.145, 0.028,
    -6e-4, 9e-4); R = Rodrigues((0.5, -1.0, 0.3) deg); right camera centre at
    (60.0, -0.5, 1.0) mm in the left camera's frame, so T = -R @ C2 (metres,
    about (-0.060, 0.0005, -0.002)). Another size scales the intrinsics
    (focal lengths by width/752 and height/480, principal point offsets from
    the image centre likewise): the same lenses on a resampled sensor.
    """
    w, h = int(size[0]), int(size[1])
    if w < 16 or h < 16:
        raise ValueError(f"image size {size} is too small: use at least 16 x 16")
    sx, sy = w / BASE_SIZE[0], h / BASE_SIZE[1]

    def scaled(K: Tuple[Tuple[float, ...], ...]) -> np.ndarray:
        k = np.array(K, dtype=np.float64)
        return np.array([
            [k[0, 0] * sx, 0.0, (w - 1) / 2 + (k[0, 2] - (BASE_SIZE[0] - 1) / 2) * sx],
            [0.0, k[1, 1] * sy, (h - 1) / 2 + (k[1, 2] - (BASE_SIZE[1] - 1) / 2) * sy],
            [0.0, 0.0, 1.0],
        ])

    R, _ = cv2.Rodrigues(np.radians(np.array(_RVEC_DEG, dtype=np.float64)).reshape(3, 1))
    T = -R @ np.array(_C2, dtype=np.float64)
    return StereoModel(scaled(_K1), np.array(_D1), scaled(_K2), np.array(_D2), R, T, (w, h))


@dataclass(frozen=True)
class Rays:
    """Viewing rays of every raw pixel of one camera, in the LEFT camera's frame.

    A point on the ray of pixel (u, v) is ``centre + lam * (dx, dy, dz)[v, u]``;
    ``lam`` is the depth along that camera's own optical axis, so depths of
    different surfaces along one ray compare directly.
    """

    centre: np.ndarray  # (3,)
    dx: np.ndarray  # (H, W) float64
    dy: np.ndarray
    dz: np.ndarray

    @classmethod
    def of(cls, K: np.ndarray, D: np.ndarray, R_cam: np.ndarray, centre: np.ndarray,
           u: np.ndarray, v: np.ndarray) -> "Rays":
        """``R_cam`` rotates left-frame vectors into this camera's frame."""
        x, y = undistort_normalized(K, D, u, v)
        rt = np.asarray(R_cam, dtype=np.float64).T  # camera -> left frame
        dx = rt[0, 0] * x + rt[0, 1] * y + rt[0, 2]
        dy = rt[1, 0] * x + rt[1, 1] * y + rt[1, 2]
        dz = rt[2, 0] * x + rt[2, 1] * y + rt[2, 2]
        return cls(np.asarray(centre, dtype=np.float64), dx, dy, dz)

    def hit(self, origin: np.ndarray, u_axis: np.ndarray, v_axis: np.ndarray,
            ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth ``lam`` (inf where missed or behind) and in-plane coordinates (s, t) in metres."""
        n = np.cross(u_axis, v_axis)
        rel = origin - self.centre
        denom = n[0] * self.dx + n[1] * self.dy + n[2] * self.dz
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = float(n @ rel) / denom
        lam = np.where(np.isfinite(lam) & (lam > 1e-6), lam, np.inf)
        finite = np.isfinite(lam)
        lam0 = np.where(finite, lam, 0.0)
        px = lam0 * self.dx - rel[0]
        py = lam0 * self.dy - rel[1]
        pz = lam0 * self.dz - rel[2]
        s = u_axis[0] * px + u_axis[1] * py + u_axis[2] * pz
        t = v_axis[0] * px + v_axis[1] * py + v_axis[2] * pz
        return lam, s, t
