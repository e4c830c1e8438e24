"""Point clouds from the stereo core's disparity codes and a calibration's Q, as binary PLY.

Here, below the CLI and the daemon, so that ``stereocam disparity`` and the daemon's captures and
``GET /api/cloud.ply`` write the very same points for the same codes.

Geometry: OpenCV's ``reprojectImageTo3D``. For a left pixel (x, y) with disparity d pixels
(the core's code / 16), ``[X, Y, Z, W] = Q [x, y, d, 1]`` and the point is ``(X, Y, Z) / W`` in
the rectified left camera's frame (x right, y down, z forward). Q from ``stereoRectify`` has
``Q[3][2] = -1 / Tx``, with Tx in the unit of the calibration's T (its ``units``), and the
focal length and principal point in pixels, so ``(X, Y, Z) / W`` is in the unit of T: metres
are that times the metres per unit (``units: mm``: x 0.001). Pixels without a disparity
(code :data:`~stereocam.overlays.spec.stereo.INVALID`) and points at infinity (W = 0, or not
finite) are dropped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..overlays.spec import pixel
from ..overlays.spec import stereo as spec

__all__ = ["PointCloud", "reproject", "ply_bytes", "left_colour", "PLY_DTYPE"]

#: One vertex as the PLY stores it: float x, y, z (metres) and uchar red, green, blue.
PLY_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                      ("red", "u1"), ("green", "u1"), ("blue", "u1")])


@dataclass(frozen=True)
class PointCloud:
    """``points`` (N, 3) float32 metres in the rectified left camera's frame; ``colours`` (N, 3) uint8 RGB;
    ``pixels`` (N, 2) the (x, y) of the left pixel each came from."""

    points: np.ndarray
    colours: np.ndarray
    pixels: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _check_q(Q: object) -> np.ndarray:
    q = np.asarray(Q, dtype=np.float64)
    if q.shape != (4, 4) or not np.all(np.isfinite(q)):
        raise ValueError(f"Q must be a finite 4x4 matrix, not {q.shape}")
    if q[3, 2] == 0:
        raise ValueError("the calibration's Q gives no depth (Q[3][2] is 0): rectify again")
    return q


def reproject(disp: np.ndarray, Q: object, unit_m: float, colour: Optional[np.ndarray] = None) -> PointCloud:
    """The points of the disparity codes ``disp`` ((H, W) uint16, x16) by ``Q``, in metres.

    ``unit_m`` is metres per unit of the calibration's T; ``colour`` the rectified left image
    ((H, W, 3) RGB or (H, W) gray uint8) that colours each point (gray 128 without one).
    ValueError for arrays or a Q that do not fit.
    """
    d = np.asarray(disp)
    if d.dtype != np.uint16 or d.ndim != 2:
        raise ValueError(f"disparity codes are (H, W) uint16, not {d.dtype} {d.shape}")
    if not (unit_m > 0 and np.isfinite(unit_m)):
        raise ValueError(f"metres per unit must be a positive number, not {unit_m!r}")
    q = _check_q(Q)
    ys, xs = np.nonzero(d != spec.INVALID)
    dp = d[ys, xs].astype(np.float64) / spec.SUBPIX_ONE
    homog = np.stack([xs.astype(np.float64), ys.astype(np.float64), dp, np.ones_like(dp)])
    X, Y, Z, W = q @ homog
    with np.errstate(divide="ignore", invalid="ignore"):
        pts = np.stack([X / W, Y / W, Z / W], axis=1) * unit_m
    keep = (W != 0) & np.all(np.isfinite(pts), axis=1)
    pts, xs, ys = pts[keep], xs[keep], ys[keep]
    if colour is None:
        rgb = np.full((len(xs), 3), 128, np.uint8)
    else:
        c = np.asarray(colour)
        if c.dtype != np.uint8 or c.shape[:2] != d.shape or c.ndim not in (2, 3):
            raise ValueError(f"the colour image must be uint8 of the disparity's size "
                             f"{d.shape[1]}x{d.shape[0]}, not {c.dtype} {c.shape}")
        rgb = np.repeat(c[ys, xs][:, None], 3, axis=1) if c.ndim == 2 else c[ys, xs][:, :3]
    return PointCloud(pts.astype(np.float32), np.ascontiguousarray(rgb, dtype=np.uint8),
                      np.stack([xs, ys], axis=1).astype(np.int32))


def _comment(text: str) -> str:
    """One PLY comment line: no line breaks, ASCII (the header is ASCII)."""
    return " ".join(text.encode("ascii", "replace").decode("ascii").split())


def ply_bytes(cloud: PointCloud, comment: str) -> bytes:
    """``cloud`` as a PLY file: ``binary_little_endian 1.0``, one ``element vertex`` of float x, y, z
    (metres) and uchar red, green, blue, after a comment naming stereocam, ``comment`` (the frame)
    and the units."""
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment " + _comment(f"stereocam point cloud; {comment}"),
        "comment units: metres; frame: the rectified left camera (x right, y down, z forward)",
        f"element vertex {len(cloud)}",
        "property float x", "property float y", "property float z",
        "property uchar red", "property uchar green", "property uchar blue",
        "end_header",
    ]
    body = np.empty(len(cloud), PLY_DTYPE)
    for i, axis in enumerate("xyz"):
        body[axis] = cloud.points[:, i]
    for i, name in enumerate(("red", "green", "blue")):
        body[name] = cloud.colours[:, i]
    return ("\n".join(header) + "\n").encode("ascii") + body.tobytes()


def left_colour(rectified: np.ndarray) -> np.ndarray:
    """The rectified left camera's RGB ((H, W, 3)) of a rectified stream frame ((H, W, 8))."""
    return np.ascontiguousarray(rectified[..., pixel.LEFT][..., :3])
