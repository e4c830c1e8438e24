"""The fast model: the same core, a frame at a time.

Steps 1-4 depend only on the parameters, so they are computed once per
parameter set (:func:`.fixed.positions`, exact int64 numpy, bit for bit the
reference's integers). Step 5 uses 5 fractional bits and weights that are
exact integer products (sum 1024, rounded half up): this is exactly OpenCV's
fixed-point bilinear ``remap`` with ``CV_16SC2`` maps (``INTER_TAB_SIZE`` 32,
``INTER_REMAP_COEF_BITS`` 15 = our 10 bits times 32), so ``cv2.remap`` does
the per-frame work, bit-exact. The few pixels whose neighbours fall outside
the line-buffer window (only with a calibration that does not fit the
bitstream) are recomputed in numpy afterwards.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Tuple, Union

import cv2
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
from .fixed import positions
from .frames import newest_row
from .result import CoreOptions, ModelResult

NEIGHBOURS = ((0, 0), (1, 0), (0, 1), (1, 1))
Camera = Union[CameraParams, CameraRegs]


@dataclass(frozen=True)
class SourceMap:
    """Fixed-point source positions of every output pixel of one camera.

    ``iu``/``iv`` are int64 in 1/32 pixel; ``valid`` is False where a
    validity limit was reached (the pixel gives 0; iu, iv are 0 there).
    """

    iu: np.ndarray
    iv: np.ndarray
    valid: np.ndarray

    @classmethod
    def compute(cls, p: Camera, width: int, height: int) -> "SourceMap":
        """Steps 1-4 for a ``width`` x ``height`` frame (a calibration is converted to registers first)."""
        y, x = np.mgrid[0:height, 0:width]
        iu, iv, valid = positions(as_registers(p, width, height), x, y)
        return cls(iu, iv, valid)

    def neighbour_rows_needed(self, width: int, height: int) -> Tuple[np.ndarray, np.ndarray]:
        """Per output row, the lowest and highest input row any in-image neighbour needs.

        Rows with no such neighbour give (height, -1), which never constrains.
        """
        x0 = self.iu >> FRAC_BITS
        y0 = self.iv >> FRAC_BITS
        lo = np.full(height, height, dtype=np.int64)
        hi = np.full(height, -1, dtype=np.int64)
        for dx, dy in NEIGHBOURS:
            xs, ys = x0 + dx, y0 + dy
            inside = self.valid & (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
            big = np.where(inside, ys, -1).max(axis=1)
            small = np.where(inside, ys, height).min(axis=1)
            hi = np.maximum(hi, big)
            lo = np.minimum(lo, small)
        return lo, hi


def _cv_maps(smap: SourceMap, width: int, height: int) -> Tuple[np.ndarray, np.ndarray]:
    """OpenCV ``CV_16SC2`` + ``CV_16UC1`` maps equivalent to ``smap``.

    Invalid pixels point at (-2, -2), whose four neighbours are all outside
    the image, so ``BORDER_CONSTANT`` 0 yields 0 exactly as the core does.
    Coordinates are clamped to [-2, size + 1], which keeps every
    "all neighbours outside" case outside and fits int16.
    """
    x0 = np.where(smap.valid, smap.iu >> FRAC_BITS, -2)
    y0 = np.where(smap.valid, smap.iv >> FRAC_BITS, -2)
    x0 = np.clip(x0, -2, width + 1)
    y0 = np.clip(y0, -2, height + 1)
    frac = (smap.iv & (FRAC_ONE - 1)) * FRAC_ONE + (smap.iu & (FRAC_ONE - 1))
    map1 = np.dstack([x0, y0]).astype(np.int16)
    map2 = np.where(smap.valid, frac, 0).astype(np.uint16)
    return map1, map2


class _CameraPlan:
    """Everything precomputed for one camera: OpenCV maps and line-buffer fix-ups."""

    def __init__(self, params: Camera, width: int, height: int, options: CoreOptions) -> None:
        self.smap = SourceMap.compute(params, width, height)
        self.map1, self.map2 = _cv_maps(self.smap, width, height)
        # Pixels with a neighbour inside the image but outside the line-buffer window.
        y = np.arange(height, dtype=np.int64)[:, None]
        last = np.minimum(y + options.lb_delay, height - 1)
        first = last - options.lb_rows + 1
        x0 = self.smap.iu >> FRAC_BITS
        y0 = self.smap.iv >> FRAC_BITS
        bad = np.zeros((height, width), dtype=bool)
        for dx, dy in NEIGHBOURS:
            xs, ys = x0 + dx, y0 + dy
            inside = self.smap.valid & (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
            bad |= inside & ((ys < first) | (ys > last))
        self.fix_y, self.fix_x = np.nonzero(bad)
        self.overflow = bool(self.fix_y.size)
        if self.overflow:
            fy, fx = self.fix_y, self.fix_x
            iu, iv = self.smap.iu[fy, fx], self.smap.iv[fy, fx]
            fu, fv = iu & (FRAC_ONE - 1), iv & (FRAC_ONE - 1)
            weights = ((FRAC_ONE - fu) * (FRAC_ONE - fv), fu * (FRAC_ONE - fv), (FRAC_ONE - fu) * fv, fu * fv)
            f_first, f_last = first[fy, 0], last[fy, 0]
            self.fix_taps = []
            for (dx, dy), w in zip(NEIGHBOURS, weights, strict=True):
                xs, ys = (iu >> FRAC_BITS) + dx, (iv >> FRAC_BITS) + dy
                ok = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height) & (ys >= f_first) & (ys <= f_last)
                self.fix_taps.append((np.where(ok, ys, 0), np.where(ok, xs, 0), np.where(ok, w, 0)))

    def run(self, src: np.ndarray) -> np.ndarray:
        """Rectify one camera's contiguous ``(H, W, C)`` or ``(H, W)`` image."""
        out = cv2.remap(
            src, self.map1, self.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        if out.ndim == 2 and src.ndim == 3:
            out = out[..., None]
        if self.overflow:
            total = np.zeros((self.fix_y.size,) + src.shape[2:], dtype=np.int64)
            for ys, xs, w in self.fix_taps:
                wk = w if src.ndim == 2 else w[:, None]
                total += wk * src[ys, xs].astype(np.int64)
            out[self.fix_y, self.fix_x] = ((total + WEIGHT_ROUND) >> WEIGHT_BITS).astype(np.uint8)
        return out


class RectifyModel:
    """The core for one parameter set and options; :meth:`process` runs a frame.

    ``left`` and ``right`` are register sets, or calibrations converted to
    registers for this frame size. Construction does steps 1-4 for every
    output pixel (tens of milliseconds for 752x480); :meth:`process` is
    cheap and thread-safe (no shared mutable state), so one model can serve
    several threads.
    """

    def __init__(self, left: Camera, right: Camera, width: int, height: int, options: CoreOptions) -> None:
        self.width = width
        self.height = height
        self.options = options
        self.plans: Dict[int, _CameraPlan] = {}
        if not options.bypass:
            self.plans = {
                0: _CameraPlan(left, width, height, options),
                1: _CameraPlan(right, width, height, options),
            }

    @property
    def lb_overflow(self) -> bool:
        """True if every complete frame through this model raises FLAGS.LB_OVERFLOW."""
        return any(p.overflow for p in self.plans.values())

    def _overflow_in(self, keep: np.ndarray) -> bool:
        return any(p.overflow and bool(keep[p.fix_y].any()) for p in self.plans.values())

    def _source(self, frame: np.ndarray, words: np.ndarray, cam: int) -> np.ndarray:
        """One camera's pixels as the line buffer holds them: RGB + recomputed gray, or gray alone."""
        base = 4 * cam
        if not self.options.colour:
            return np.ascontiguousarray(frame[..., base + 3])
        if self.options.gray:
            return gray_of(frame[..., base:base + 3])
        src = np.ascontiguousarray(words[..., cam]).view(np.uint8).reshape(self.height, self.width, 4)
        src[..., 3] = gray_of(src[..., :3])
        return src

    def process(
        self, frame: np.ndarray, out: Optional[np.ndarray] = None, *, rows: Optional[int] = None
    ) -> ModelResult:
        """Run one ``(H, W, 8)`` frame.

        ``rows`` (the malformed-input rule, :mod:`.frames`): only the first
        ``rows`` input lines arrived; output rows that needed later ones are
        0 and raise no flag.
        """
        h, w = self.height, self.width
        if frame.shape != (h, w, 8) or frame.dtype != np.uint8:
            raise ValueError(
                f"the model is set up for ({h}, {w}, 8) uint8 frames, got {frame.shape} {frame.dtype}"
            )
        if out is None:
            out = np.empty_like(frame)
        overflow = self.lb_overflow
        if self.options.bypass:
            out[...] = frame
        else:
            # One camera's RGBY pixel is 4 bytes: viewing the frame as (H, W, 2) uint32 moves a
            # camera in and out with word copies instead of byte-strided ones (4x less time).
            words = np.ascontiguousarray(frame).view(np.uint32).reshape(h, w, 2)
            out_words = out.view(np.uint32).reshape(h, w, 2) if out.flags.c_contiguous else None
            for cam, plan in self.plans.items():
                base = 4 * cam
                res = plan.run(self._source(frame, words, cam))
                if res.ndim == 2:
                    out[..., base:base + 4] = res[..., None]
                elif out_words is not None:
                    out_words[..., cam] = res.view(np.uint32).reshape(h, w)
                else:
                    out[..., base:base + 4] = res
        if rows is not None and rows < h:
            y = np.arange(h)
            newest = y if self.options.bypass else newest_row(y, h, self.options.lb_delay)
            keep = np.asarray(newest < rows)
            out[~keep] = 0
            overflow = self._overflow_in(keep)
        row = self.options.debug_row
        if row is not None and 0 <= row < h:
            out[row] = 255
        return ModelResult(out, lb_overflow=overflow)
