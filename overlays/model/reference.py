"""The plain reference model: the core's equations, one pixel at a time.

This is the executable form of ``overlays/RECTIFY_CORE.md`` and is written
for reading, not speed (a 752x480 pair takes seconds). Every arithmetic step
is a Python float operation (IEEE-754 binary64, round to nearest even, no
fused multiply-add) in exactly the order the document gives; the fast model
(:mod:`.fast`) must agree with it bit for bit.
"""
from __future__ import annotations

import math
from typing import List, Optional, Tuple

import numpy as np

from ..spec.rectify import (
    COORD_LIMIT,
    FRAC_BITS,
    FRAC_ONE,
    WEIGHT_BITS,
    WEIGHT_ROUND,
    CameraParams,
)
from .result import CoreOptions, ModelResult


def source_position(p: CameraParams, x: int, y: int) -> Optional[Tuple[int, int]]:
    """Fixed-point source position ``(iu, iv)`` (units of 1/32 pixel) of output pixel (x, y).

    None when the position is not finite or beyond the signed 16.5 range:
    such a pixel is outside the image and gives 0.
    """
    h00, h01, h02, h10, h11, h12, h20, h21, h22 = p.hinv
    xf = float(x)
    yf = float(y)
    # Step 1: homogeneous inverse mapping, column-vector form.
    X = (h00 * xf + h01 * yf) + h02
    Y = (h10 * xf + h11 * yf) + h12
    Z = (h20 * xf + h21 * yf) + h22
    if Z == 0.0:
        return None
    xp = X / Z
    yp = Y / Z
    # Step 2: normalise.
    xn = (xp - p.cx) / p.fx
    yn = (yp - p.cy) / p.fy
    x2 = xn * xn
    y2 = yn * yn
    xy = xn * yn
    r2 = x2 + y2
    # Step 3: Brown-Conrady distortion, k1, k2 radial, p1, p2 tangential.
    radial = 1.0 + (p.k1 + p.k2 * r2) * r2
    xd = (xn * radial + 2.0 * p.p1 * xy) + p.p2 * (r2 + 2.0 * x2)
    yd = (yn * radial + p.p1 * (r2 + 2.0 * y2)) + 2.0 * p.p2 * xy
    # Step 4: back to pixels, then to 1/32-pixel fixed point (round half to even).
    su = (p.fx * xd + p.cx) * FRAC_ONE
    sv = (p.fy * yd + p.cy) * FRAC_ONE
    if not (math.isfinite(su) and math.isfinite(sv)):
        return None
    if not (-COORD_LIMIT < su < COORD_LIMIT and -COORD_LIMIT < sv < COORD_LIMIT):
        return None
    return round(su), round(sv)


def window(y: int, height: int, lb_rows: int, lb_delay: int) -> Tuple[int, int]:
    """Input rows (first, last) held in the line buffer while output row ``y`` is produced."""
    last = min(y + lb_delay, height - 1)
    return last - lb_rows + 1, last


def interpolate(
    plane: np.ndarray, iu: int, iv: int, rows: Tuple[int, int]
) -> Tuple[int, bool]:
    """Step 5 for one channel: value and whether a needed row was outside the line buffer."""
    height, width = plane.shape
    x0, fu = iu >> FRAC_BITS, iu & (FRAC_ONE - 1)
    y0, fv = iv >> FRAC_BITS, iv & (FRAC_ONE - 1)
    weights = (
        (FRAC_ONE - fu) * (FRAC_ONE - fv),
        fu * (FRAC_ONE - fv),
        (FRAC_ONE - fu) * fv,
        fu * fv,
    )
    total = 0
    overflow = False
    for (dx, dy), w in zip(((0, 0), (1, 0), (0, 1), (1, 1)), weights):
        xs, ys = x0 + dx, y0 + dy
        if not (0 <= xs < width and 0 <= ys < height):
            continue  # outside the image: reads 0
        if not (rows[0] <= ys <= rows[1]):
            overflow = True  # inside the image but not buffered: reads 0, sticky flag
            continue
        total += w * int(plane[ys, xs])
    return (total + WEIGHT_ROUND) >> WEIGHT_BITS, overflow


def rectify_reference(
    frame: np.ndarray, left: CameraParams, right: CameraParams, options: CoreOptions,
    rows: Optional[range] = None,
) -> ModelResult:
    """Run the core on one ``(H, W, 8)`` stream frame, pixel by pixel.

    ``rows`` limits the work to some output rows (the others stay 0), for
    spot checks and for measuring the reference's speed.
    """
    height, width = frame.shape[:2]
    out_rows = range(height) if rows is None else rows
    out = np.zeros_like(frame)
    overflow = False
    if options.bypass:
        out[...] = frame
    else:
        for cam, params in ((0, left), (1, right)):
            base = 4 * cam
            channels: List[int] = [base + 3] if options.gray else [base + c for c in range(4)]
            for y in out_rows:
                held = window(y, height, options.lb_rows, options.lb_delay)
                for x in range(width):
                    pos = source_position(params, x, y)
                    if pos is None:
                        continue
                    for ch in channels:
                        value, ovf = interpolate(frame[:, :, ch], pos[0], pos[1], held)
                        out[y, x, ch] = value
                        overflow |= ovf
            if options.gray:
                for c in range(3):
                    out[:, :, base + c] = out[:, :, base + 3]
    if options.debug_row is not None and 0 <= options.debug_row < height:
        out[options.debug_row] = 255
    return ModelResult(out, lb_overflow=overflow)
