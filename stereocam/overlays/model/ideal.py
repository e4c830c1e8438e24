"""The core's mapping in real numbers: what the fixed-point steps 1-4 approximate.

Binary64 and continuous in (x, y), so calibration figures can invert it
with Newton's method; it is OpenCV's ``initUndistortRectifyMap`` for the
same calibration. The core's fixed-point positions (:mod:`.fixed`) equal
``rint(32 * u)`` of it on all but a few pixels in 100,000 and never differ
by more than 1/32 pixel.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np

from ..spec.rectify import CameraParams


def ideal_positions(p: CameraParams, x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Source position (pixels) of output positions (x, y); NaN where the homography maps to infinity."""
    h00, h01, h02, h10, h11, h12, h20, h21, h22 = p.hinv
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    with np.errstate(all="ignore"):
        Z = h20 * x + h21 * y + h22
        Z = np.where(Z != 0.0, Z, np.nan)
        xn = ((h00 * x + h01 * y + h02) / Z - p.cx) / p.fx
        yn = ((h10 * x + h11 * y + h12) / Z - p.cy) / p.fy
        x2, y2, xy = xn * xn, yn * yn, xn * yn
        r2 = x2 + y2
        radial = 1.0 + (p.k1 + p.k2 * r2) * r2
        xd = xn * radial + 2.0 * p.p1 * xy + p.p2 * (r2 + 2.0 * x2)
        yd = yn * radial + p.p1 * (r2 + 2.0 * y2) + 2.0 * p.p2 * xy
        return p.fx * xd + p.cx, p.fy * yd + p.cy
