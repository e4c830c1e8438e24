"""The camera input IP as numpy: Bayer mosaics in, the fabric's 64-bit stereo stream frames out.

Bit-exact to ``stereocam/overlays/rtl/camera/`` (co-simulated by ``tests/hdl/test_camera_in_rtl.py``) and
written from :mod:`..spec.camera_in` alone: the Bayer phase, the demosaic's taps
(:data:`~..spec.camera_in.KERNELS`), the 10 -> 8 bit rounding, the mirrored borders and the rules
for frames the two cameras disagree on. The emulated cameras render through it, so an emulated
frame is what the RTL outputs for the sensor samples the emulated sensors read out.

A camera's raw frame is an ``(H, W)`` integer array of 10-bit samples in read-out order (row 0 is
the first row the sensor sends, column 0 the first pixel of a row).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from ..spec import camera_in as spec
from ..spec.pixel import GRAY_WEIGHTS, pack

__all__ = [
    "phase_cell",
    "flipped_phase",
    "shifted_phase",
    "mosaic",
    "demosaic_camera",
    "demosaic_window",
    "demosaic",
    "expected_frames",
    "pixel_bus",
    "BusTiming",
]

RAW_MAX = (1 << spec.RAW_BITS) - 1


def phase_cell(phase: str) -> Tuple[int, int]:
    """``(column, row)`` of the red sample inside each 2x2 cell of a ``phase``."""
    code = spec.phase_code(phase)
    return code & 1, code >> 1


def _phase_of(r_col: int, r_row: int) -> str:
    return spec.CFA_PHASES[2 * (r_row & 1) + (r_col & 1)]


def flipped_phase(phase: str, width: int, height: int, flip_h: bool = False, flip_v: bool = False) -> str:
    """The phase of a ``width`` x ``height`` mosaic of ``phase`` after mirroring its columns/rows.

    Mirroring moves column x to ``width - 1 - x``: the red column changes parity when the width is
    even. Used both ways (the relation is its own inverse).
    """
    r_col, r_row = phase_cell(phase)
    if flip_h:
        r_col ^= (width - 1) & 1
    if flip_v:
        r_row ^= (height - 1) & 1
    return _phase_of(r_col, r_row)


def shifted_phase(phase: str, row0: int, col0: int) -> str:
    """The phase of the part of a ``phase`` mosaic that starts at ``(row0, col0)``."""
    r_col, r_row = phase_cell(phase)
    return _phase_of(r_col ^ (col0 & 1), r_row ^ (row0 & 1))


def _check_raw(raw: np.ndarray) -> np.ndarray:
    raw = np.asarray(raw)
    if raw.ndim != 2 or raw.dtype.kind not in "ui":
        raise ValueError(f"a raw Bayer frame is an (H, W) integer array, got {raw.shape} {raw.dtype}")
    h, w = raw.shape
    if h < spec.MIN_HEIGHT or w < spec.MIN_WIDTH:
        raise ValueError(
            f"a raw frame needs at least {spec.MIN_WIDTH} x {spec.MIN_HEIGHT} samples, got {w} x {h}"
        )
    if raw.size and (int(raw.min()) < 0 or int(raw.max()) > RAW_MAX):
        raise ValueError(f"raw samples are {spec.RAW_BITS}-bit (0..{RAW_MAX}), got {raw.min()}..{raw.max()}")
    return raw


def mosaic(rgb: np.ndarray, phase: str = spec.BAYER_PHASE) -> np.ndarray:
    """The Bayer mosaic of an ``(H, W, 3)`` image: each pixel keeps the channel its filter passes.

    Keeps the dtype (float radiance or integer samples); an ``(H, W)`` gray image is its own mosaic.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        return rgb.copy()
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got {rgb.shape}")
    r_col, r_row = phase_cell(phase)
    out = np.empty(rgb.shape[:2], rgb.dtype)
    b_col, b_row = 1 - r_col, 1 - r_row
    out[r_row::2, r_col::2] = rgb[r_row::2, r_col::2, 0]
    out[b_row::2, b_col::2] = rgb[b_row::2, b_col::2, 2]
    out[r_row::2, b_col::2] = rgb[r_row::2, b_col::2, 1]
    out[b_row::2, r_col::2] = rgb[b_row::2, r_col::2, 1]
    return out


def _reflect(index: np.ndarray, size: int) -> np.ndarray:
    """Reflect-101 indices (``-1 -> 1``, ``size -> size - 2``) for offsets of at most one."""
    index = np.where(index < 0, -index, index)
    return np.where(index >= size, 2 * (size - 1) - index, index)


def _site(phase_col: int, phase_row: int, px: int, py: int) -> str:
    """The site name of pixels at column parity ``px``, row parity ``py`` for a red cell position."""
    on_red_row = (py ^ phase_row) == 0
    on_red_col = (px ^ phase_col) == 0
    if on_red_row:
        return "R" if on_red_col else "Gr"
    return "Gb" if on_red_col else "B"


def _demosaic_padded(padded: np.ndarray, phase: str) -> np.ndarray:
    """RGBY ``(h, w, 4)`` uint8 of the inner ``h x w`` of ``padded`` (one sample of margin all round).

    ``phase`` is that of the inner region's pixel (0, 0). Works on the four 2x2 sub-lattices, which
    are contiguous quarter-size planes: each site kind sums its taps (spec.KERNELS) in uint16 (at
    most 4 * 1023; gray at most 65,408). 1.9 ms for a 752 x 480 camera on one desktop core.
    """
    hp, wp = padded.shape
    h, w = hp - 2, wp - 2
    p = padded.astype(np.uint16, copy=False)
    planes = [[np.ascontiguousarray(p[a::2, b::2]) for b in (0, 1)] for a in (0, 1)]
    out = np.empty((h, w, 4), np.uint8)
    r_col, r_row = phase_cell(phase)
    for py in (0, 1):
        ny = (h - py + 1) // 2
        for px in (0, 1):
            nx = (w - px + 1) // 2
            if ny <= 0 or nx <= 0:
                continue
            rgb = []
            for taps in spec.KERNELS[_site(r_col, r_row, px, py)]:
                acc: Optional[np.ndarray] = None
                for dy, dx, weight in taps:
                    ry, rx = 1 + py + dy, 1 + px + dx
                    view = planes[ry & 1][rx & 1][ry >> 1:(ry >> 1) + ny, rx >> 1:(rx >> 1) + nx]
                    if acc is None:
                        acc = view * np.uint16(weight) if weight != 1 else view.copy()
                    elif weight == 1:
                        acc += view
                    else:
                        acc += view * np.uint16(weight)
                assert acc is not None
                acc += np.uint16(spec.OUT_ROUND)
                acc >>= np.uint16(spec.OUT_SHIFT)
                np.minimum(acc, np.uint16(spec.OUT_MAX), out=acc)
                rgb.append(acc)
            r, g, b = rgb
            gray = r * np.uint16(GRAY_WEIGHTS[0])
            gray += g * np.uint16(GRAY_WEIGHTS[1])
            gray += b * np.uint16(GRAY_WEIGHTS[2])
            gray += np.uint16(1 << 7)
            gray >>= np.uint16(8)
            sub = out[py::2, px::2]
            sub[..., 0], sub[..., 1], sub[..., 2], sub[..., 3] = r, g, b, gray
    return out


def demosaic_window(raw: np.ndarray, rows: slice, cols: slice, phase: str = spec.BAYER_PHASE) -> np.ndarray:
    """``demosaic_camera(raw, phase)[rows, cols]``, computed from that window and a one-sample margin.

    ``rows``/``cols`` are plain slices (step 1) inside the frame. What the emulated rig uses to
    redo only the part of a frame that changed.
    """
    raw = _check_raw(raw)
    h, w = raw.shape
    r0, r1, _ = rows.indices(h)
    c0, c1, _ = cols.indices(w)
    if r1 <= r0 or c1 <= c0:
        return np.empty((max(r1 - r0, 0), max(c1 - c0, 0), 4), np.uint8)
    ri = _reflect(np.arange(r0 - 1, r1 + 1), h)
    ci = _reflect(np.arange(c0 - 1, c1 + 1), w)
    if r0 >= 1 and r1 < h and c0 >= 1 and c1 < w:
        padded = raw[r0 - 1:r1 + 1, c0 - 1:c1 + 1]
    else:
        padded = raw[ri[:, None], ci[None, :]]
    return _demosaic_padded(padded, shifted_phase(phase, r0, c0))


def demosaic_camera(raw: np.ndarray, phase: str = spec.BAYER_PHASE) -> np.ndarray:
    """One camera's ``(H, W, 4)`` RGBY uint8 image of an ``(H, W)`` 10-bit raw frame of ``phase``."""
    raw = _check_raw(raw)
    return _demosaic_padded(np.pad(raw, 1, mode="reflect"), phase)


def demosaic(bayer_left: np.ndarray, bayer_right: np.ndarray, phase: str = spec.BAYER_PHASE) -> np.ndarray:
    """The ``(H, W, 8)`` stream frame the IP emits for one frame of both cameras (same size)."""
    left, right = np.asarray(bayer_left), np.asarray(bayer_right)
    if left.shape != right.shape:
        raise ValueError(f"left {left.shape} and right {right.shape} frames differ in size")
    return pack(demosaic_camera(left, phase), demosaic_camera(right, phase))


# --------------------------------------------------------------------------
# Frames as the sensors send them, and what the IP makes of them
# --------------------------------------------------------------------------

Lines = Sequence[np.ndarray]  # one frame of one camera: its lines (1-D arrays of 10-bit samples) in order


def expected_frames(left: Sequence[Lines], right: Sequence[Lines],
                    max_width: int = spec.PARAMETERS["MAX_WIDTH"],
                    phase: str = spec.BAYER_PHASE) -> List[np.ndarray]:
    """The stream frames the IP emits for frames sent at the same time by both cameras (spec rules).

    ``left[k]`` and ``right[k]`` are frame k of each camera as line lists (lines may differ in
    length, frames in line count). Rows are taken while both cameras' lines have the length of the
    frame's first line (MIN_WIDTH..``max_width``); the frame ends at the first row where they
    don't; fewer than MIN_HEIGHT rows give no frame. Assumes no FIFO overflow (TREADY keeps up).
    """
    if len(left) != len(right):
        raise ValueError("both cameras send the same number of frames (hardware-synchronised)")
    out = []
    for lf, rf in zip(left, right, strict=True):
        rows = 0
        width = len(lf[0]) if len(lf) and len(rf) else 0
        if not spec.MIN_WIDTH <= width <= max_width:
            continue
        for a, b in zip(lf, rf):  # noqa: B905 - the shorter camera ends the frame
            if len(a) != width or len(b) != width:
                break
            rows += 1
        if rows >= spec.MIN_HEIGHT:
            out.append(demosaic(np.stack(lf[:rows]), np.stack(rf[:rows]), phase))
    return out


@dataclass(frozen=True)
class BusTiming:
    """Blanking of the sensor's parallel bus, in pixel clocks (the MT9V034's own defaults are 94 and
    45 rows). ``fv_lead``/``fv_trail``: FRAME_VALID high before the first and after the last line."""

    hblank: int = 94
    vblank: int = spec.MIN_VBLANK_PCLK
    fv_lead: int = 2
    fv_trail: int = 2


def pixel_bus(frames: Sequence[Lines], timing: BusTiming = BusTiming()) -> np.ndarray:
    """The sensor's bus clock by clock for ``frames``: an ``(N, 3)`` int array of (DOUT, LINE_VALID,
    FRAME_VALID), one row per rising edge of PIXCLK; DOUT is 0 while LINE_VALID is low.

    Starts and ends with ``timing.vblank`` clocks of FRAME_VALID low.
    """
    parts: List[np.ndarray] = [np.zeros((timing.vblank, 3), np.int32)]
    for frame in frames:
        if timing.fv_lead:
            parts.append(np.tile(np.array([[0, 0, 1]], np.int32), (timing.fv_lead, 1)))
        for k, line in enumerate(frame):
            line = np.asarray(line, dtype=np.int32)
            block = np.empty((len(line), 3), np.int32)
            block[:, 0], block[:, 1], block[:, 2] = line, 1, 1
            parts.append(block)
            if k + 1 < len(frame):
                parts.append(np.tile(np.array([[0, 0, 1]], np.int32), (timing.hblank, 1)))
        if timing.fv_trail:
            parts.append(np.tile(np.array([[0, 0, 1]], np.int32), (timing.fv_trail, 1)))
        parts.append(np.zeros((timing.vblank, 3), np.int32))
    return np.concatenate(parts)
