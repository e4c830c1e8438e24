"""What the core does with an input frame of the wrong size ("Malformed input" in RECTIFY_CORE.md).

The model works on frames of exactly ``WIDTH x HEIGHT``; these rules turn
the frame the stream delivered into that, or into nothing, the way the RTL
does: a frame whose lines have the wrong length is dropped, a frame with
too few lines is completed (rows that needed missing input are 0), extra
lines are ignored. Every case raises ``SIZE_ERROR``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def newest_row(y: "int | np.ndarray", height: int, lb_delay: int) -> "int | np.ndarray":
    """``e(y)``: the newest input row buffered while output row ``y`` is produced."""
    return np.minimum(y + lb_delay, height - 1)


@dataclass(frozen=True)
class FrameFit:
    """How an input frame fits the configured size."""

    size_error: bool
    dropped: bool  # nothing is emitted
    rows: int  # complete input lines received before the error (``r``); HEIGHT when none


def fit_frame(shape: "tuple[int, ...]", width: int, height: int, lb_delay: int, bypass: bool) -> FrameFit:
    """Apply the malformed-input rules to a well-formed ``(H', W', 8)`` frame of any size."""
    h_in, w_in = int(shape[0]), int(shape[1])
    if h_in == 0 or w_in == 0:  # no beat at all: the stream never moved
        return FrameFit(size_error=False, dropped=True, rows=0)
    if (h_in, w_in) == (height, width):
        return FrameFit(size_error=False, dropped=False, rows=height)
    if w_in != width:
        return FrameFit(size_error=True, dropped=True, rows=0)
    rows = min(h_in, height)
    first = 0 if bypass else int(newest_row(0, height, lb_delay))
    return FrameFit(size_error=True, dropped=rows <= first, rows=rows)


def padded(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """The frame cut or zero-padded to ``height`` rows (its width must already be ``width``)."""
    if frame.shape[0] == height:
        return frame
    out = np.zeros((height, width) + frame.shape[2:], dtype=frame.dtype)
    rows = min(height, frame.shape[0])
    out[:rows] = frame[:rows]
    return out
