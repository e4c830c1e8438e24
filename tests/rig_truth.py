"""The synthetic rig's true depth at a rectified pixel, for the depth readout's tests.

The emulated fabric's default camera source is :class:`SyntheticRig`: planes at known places
in the left camera's frame (``scene.SCENE``: a wall, a floor, and two moving rectangles).
A rectified left pixel (u, v) looks along ``R1^T K_rect^-1 (u, v, 1)`` (``K_rect`` from P1);
the nearest plane it meets is the surface there, and its distance along the rectified
camera's optical axis is the depth Z that disparity measures (Z = f B / d).

Only pixels that can never see a moving plane have a depth fixed in time: :func:`static_depth`
answers None for a pixel whose neighbourhood (the block matcher's window) any moving
rectangle can reach at any time of its motion.
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from stereocam.overlays.emulated.scene import SCENE

BLOCK_MARGIN_PX = 12  # StereoBM's 19-px block reaches 9 px; a little more for the rectified interpolation


def _ray(R1: np.ndarray, P1: np.ndarray, u: float, v: float) -> np.ndarray:
    """Direction (left camera's frame) of rectified left pixel (u, v), scaled so that its rectified z is 1."""
    r = np.array([(u - P1[0, 2]) / P1[0, 0], (v - P1[1, 2]) / P1[1, 1], 1.0])
    return np.asarray(R1, dtype=np.float64).T @ r


def _hit(direction: np.ndarray, plane: object) -> "tuple[float, float, float]":
    """(lam, s, t): the distance factor along ``direction`` and in-plane coordinates at rest (metres)."""
    origin, ua, va = plane.axes()  # type: ignore[attr-defined]
    n = np.cross(ua, va)
    den = float(n @ direction)
    if abs(den) < 1e-12:
        return float("inf"), 0.0, 0.0
    lam = float(n @ origin) / den
    if lam <= 1e-6:
        return float("inf"), 0.0, 0.0
    rel = lam * direction - origin
    return lam, float(ua @ rel), float(va @ rel)


def _reachable(direction: np.ndarray, plane: object, slack_m: float = 0.0) -> bool:
    """Whether the moving rectangle can cover this ray at some time of its motion."""
    lam, s, t = _hit(direction, plane)
    if not np.isfinite(lam):
        return False
    hu, hv = plane.half_size  # type: ignore[attr-defined]
    au, av = (abs(a) for a in plane.amplitude)  # type: ignore[attr-defined]
    return abs(s) <= hu + au + slack_m and abs(t) <= hv + av + slack_m


def static_depth(rectification: "dict[str, Sequence]", u: int, v: int,
                 margin_px: int = BLOCK_MARGIN_PX) -> Optional[float]:
    """True Z (metres) at rectified left pixel (u, v), or None if a moving plane may be in its window.

    ``rectification``: GET /api/calibration's ``rectification`` (R1, P1 as nested lists).
    """
    R1 = np.asarray(rectification["R1"], dtype=np.float64)
    P1 = np.asarray(rectification["P1"], dtype=np.float64)
    for du in (-margin_px, 0, margin_px):
        for dv in (-margin_px, 0, margin_px):
            d = _ray(R1, P1, u + du, v + dv)
            if any(_reachable(d, p, 0.01) for p in SCENE if p.half_size is not None):
                return None
    d = _ray(R1, P1, u, v)
    lam = min(_hit(d, p)[0] for p in SCENE if p.half_size is None)
    # |d|'s rectified z is 1, so lam is the rectified depth itself.
    return lam if np.isfinite(lam) else None
