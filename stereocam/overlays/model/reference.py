"""The plain reference model: the core's equations, one pixel at a time.

This is the executable form of ``stereocam/overlays/RECTIFY_CORE.md`` and is written
for reading, not speed (a 752x480 pair takes tens of seconds): steps 1-4 are
:func:`.fixed.position` in Python integers, step 5 the document's integer
interpolation with the line-buffer window. The fast model (:mod:`.fast`) and
the RTL must agree with it bit for bit.
"""
from __future__ import annotations

from typing import List, Optional, Tuple, Union

import numpy as np

from ..spec.pixel import gray_of
from ..spec.rectify import (
    FRAC_BITS,
    FRAC_ONE,
    WEIGHT_BITS,
    WEIGHT_ROUND,
    CameraParams,
    CameraRegs,
    as_registers,
)
from .fixed import position
from .frames import newest_row
from .result import CoreOptions, ModelResult

Camera = Union[CameraParams, CameraRegs]


def source_position(p: Camera, x: int, y: int, width: int, height: int) -> Optional[Tuple[int, int]]:
    """Fixed-point source position ``(iu, iv)`` (1/32 pixel) of output pixel (x, y); None gives 0."""
    return position(as_registers(p, width, height), x, y)


def window(y: int, height: int, lb_rows: int, lb_delay: int) -> Tuple[int, int]:
    """Input rows (first, last) an output row ``y`` may read from the line buffer."""
    last = int(newest_row(y, height, lb_delay))
    return last - lb_rows + 1, last


def interpolate(plane: np.ndarray, iu: int, iv: int, rows: Tuple[int, int]) -> Tuple[int, bool]:
    """Step 5 for one channel: value and whether a needed row was outside the line buffer."""
    height, width = plane.shape
    x0, du = iu >> FRAC_BITS, iu & (FRAC_ONE - 1)
    y0, dv = iv >> FRAC_BITS, iv & (FRAC_ONE - 1)
    taps = []
    overflow = False
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        xs, ys = x0 + dx, y0 + dy
        value = 0
        if 0 <= xs < width and 0 <= ys < height:  # outside the image: reads 0
            if rows[0] <= ys <= rows[1]:
                value = int(plane[ys, xs])
            else:
                overflow = True  # inside the image but not buffered: reads 0, sticky flag
        taps.append(value)
    g0, g1, g2, g3 = taps
    top = (FRAC_ONE - du) * g0 + du * g1
    bottom = (FRAC_ONE - du) * g2 + du * g3
    return ((FRAC_ONE - dv) * top + dv * bottom + WEIGHT_ROUND) >> WEIGHT_BITS, overflow


def camera_planes(frame: np.ndarray, cam: int, options: CoreOptions) -> List[np.ndarray]:
    """The planes the core interpolates for one camera: R, G, B and gray, or gray alone.

    The colour build stores R, G, B and recomputes each tap's gray from them;
    the gray build stores the stream's gray byte.
    """
    base = 4 * cam
    if not options.colour:
        return [frame[:, :, base + 3]]
    rgb = frame[:, :, base:base + 3]
    gray = gray_of(rgb)
    if options.gray:
        return [gray]
    return [rgb[:, :, 0], rgb[:, :, 1], rgb[:, :, 2], gray]


def rectify_reference(
    frame: np.ndarray, left: Camera, right: Camera, options: CoreOptions, rows: Optional[range] = None,
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
            regs = as_registers(params, width, height)
            planes = camera_planes(frame, cam, options)
            base = 4 * cam
            for y in out_rows:
                held = window(y, height, options.lb_rows, options.lb_delay)
                for x in range(width):
                    pos = position(regs, x, y)
                    if pos is None:
                        continue
                    values = []
                    for plane in planes:
                        value, ovf = interpolate(plane, pos[0], pos[1], held)
                        values.append(value)
                        overflow |= ovf
                    out[y, x, base:base + 4] = values if len(values) == 4 else values * 4
    if options.debug_row is not None and 0 <= options.debug_row < height:
        out[options.debug_row] = 255
    return ModelResult(out, lb_overflow=overflow)
