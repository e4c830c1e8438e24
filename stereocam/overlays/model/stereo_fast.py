"""The stereo core in numpy: whole rows and columns at a time, the same integers as the reference.

This path runs wherever numpy does (the board has no numba); :mod:`.stereo_jit` is faster where
numba installs. Both are tested equal to :mod:`.stereo_reference`. The steps are those of
``STEREO_CORE.md``; :func:`finish` (steps 4-7 from the summed costs) is shared with the compiled
path's fallback and its tests.
"""
from __future__ import annotations

import numpy as np

from ..spec import stereo as spec
from .stereo_result import StereoResult, check_pair

#: The paths whose previous pixel is on the row above, by their column step; the first path is
#: the one from the left (on the same row).
UPPER_PATHS = tuple(dx for dx, dy in spec.PATHS if dy == -1)
assert spec.PATHS[0] == (-1, 0) and len(UPPER_PATHS) == len(spec.PATHS) - 1
_BYTE_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], np.uint8)


def popcount64(words: np.ndarray) -> np.ndarray:
    """Bits set in each uint64 (numpy 2's ``bitwise_count``, or a byte table on numpy 1)."""
    counter = getattr(np, "bitwise_count", None)
    if counter is not None:
        return counter(words).astype(np.uint8)
    as_bytes = np.ascontiguousarray(words).view(np.uint8).reshape(words.shape + (8,))
    return _BYTE_POPCOUNT[as_bytes].sum(axis=-1, dtype=np.uint8)


def census(img: np.ndarray) -> np.ndarray:
    """Step 1: (H, W) uint64 census words. Padding with 255 makes outside neighbours never darker."""
    h, w = img.shape
    ry, rx = spec.CENSUS_H // 2, spec.CENSUS_W // 2
    padded = np.pad(img, ((ry, ry), (rx, rx)), constant_values=255)
    out = np.zeros((h, w), np.uint64)
    for bit, (dy, dx) in enumerate(spec.CENSUS_OFFSETS):
        darker = padded[ry + dy:ry + dy + h, rx + dx:rx + dx + w] < img
        out |= darker.astype(np.uint64) << np.uint64(bit)
    return out


def costs(cl: np.ndarray, cr: np.ndarray, num_disp: int) -> np.ndarray:
    """Step 2: (H, W, D) uint8 matching costs."""
    h, w = cl.shape
    out = np.full((h, w, num_disp), spec.COST_OOB, np.uint8)
    for d in range(min(num_disp, w)):
        out[:, d:, d] = popcount64(cl[:, d:] ^ cr[:, :w - d])
    return out


def _step(c: np.ndarray, prev: np.ndarray, p2: np.ndarray, p1: int) -> np.ndarray:
    """One step along a path for N pixels at once: c, prev (N, D) int16; p2 (N, 1)."""
    pmin = prev.min(axis=1, keepdims=True)
    best = np.minimum(prev, pmin + p2)
    np.minimum(best[:, 1:], prev[:, :-1] + p1, out=best[:, 1:])
    np.minimum(best[:, :-1], prev[:, 1:] + p1, out=best[:, :-1])
    return c + best - pmin


def _p2(here: np.ndarray, there: np.ndarray, p: spec.StereoParams) -> np.ndarray:
    edge = np.abs(here.astype(np.int16) - there.astype(np.int16)) >= p.edge_thresh
    return np.where(edge, np.int16(p.p2_edge), np.int16(p.p2)).astype(np.int16)[:, None]


def aggregate(c: np.ndarray, left: np.ndarray, p: spec.StereoParams) -> np.ndarray:
    """Step 3: (H, W, D) int16 sums of the four paths' costs."""
    h, w, _ = c.shape
    c16 = c.astype(np.int16)
    img = left.astype(np.int16)
    total = c16.copy()  # path "left", column by column
    for x in range(1, w):
        total[:, x] = _step(c16[:, x], total[:, x - 1], _p2(img[:, x], img[:, x - 1], p), p.p1)
    for dx in UPPER_PATHS:  # the paths from the row above, row by row
        prev = c16[0]
        total[0] += prev
        for y in range(1, h):
            row = c16[y].copy()
            lo, hi = max(0, -dx), w - max(0, dx)  # columns whose previous pixel is in the image
            row[lo:hi] = _step(c16[y, lo:hi], prev[lo + dx:hi + dx],
                               _p2(img[y, lo:hi], img[y - 1, lo + dx:hi + dx], p), p.p1)
            total[y] += row
            prev = row
    return total


def winners(total: np.ndarray, p: spec.StereoParams) -> "tuple[np.ndarray, ...]":
    """Step 4-5: per pixel the winner d1, its sum s1, the runner-up s2 and the disparity code."""
    h, w, nd = total.shape
    d1 = np.argmin(total, axis=2)
    s1 = np.take_along_axis(total, d1[..., None], axis=2)[..., 0].astype(np.int32)
    near = np.abs(np.arange(nd)[None, None, :] - d1[..., None]) <= 1
    s2 = np.where(near, np.iinfo(np.int16).max, total).min(axis=2).astype(np.int32)
    code = d1.astype(np.int32) * spec.SUBPIX_ONE
    if p.subpixel:
        inner = (d1 > 0) & (d1 < nd - 1)
        a = np.take_along_axis(total, np.clip(d1 - 1, 0, nd - 1)[..., None], axis=2)[..., 0].astype(np.int32)
        b = np.take_along_axis(total, np.clip(d1 + 1, 0, nd - 1)[..., None], axis=2)[..., 0].astype(np.int32)
        den = np.maximum(a + b - 2 * s1, 1)
        num = (a - b) * spec.SUBPIX_ONE + den
        q = np.abs(num) // (2 * den)
        code = np.where(inner, code + np.where(num >= 0, q, -q), code)
    return d1, s1, s2, code


def right_winners(total: np.ndarray) -> np.ndarray:
    """Step 6: the right image's winner at each column, by the diagonal minimum of the same sums."""
    h, w, nd = total.shape
    diag = np.full((h, w, nd), np.iinfo(np.int16).max, np.int16)
    for d in range(min(nd, w)):
        diag[:, :w - d, d] = total[:, d:, d]
    return np.argmin(diag, axis=2)


def finish(total: np.ndarray, d1: np.ndarray, s1: np.ndarray, s2: np.ndarray, code: np.ndarray,
           right_best: np.ndarray, p: spec.StereoParams) -> StereoResult:
    """Steps 4-7 from the winners: validity in the spec's order, confidence and the median."""
    h, w = d1.shape
    xs = np.arange(w)[None, :]
    xr = xs - d1
    border = xr < 0
    unique = s2 * spec.UNIQUENESS_ONE > s1 * (spec.UNIQUENESS_ONE + p.uniqueness)
    reason = np.full((h, w), spec.REASON_VALID, np.uint8)
    reason[border] = spec.REASON_BORDER
    reason[~border & ~unique] = spec.REASON_UNIQUENESS
    if p.lr_check:
        theirs = np.take_along_axis(right_best, np.clip(xr, 0, w - 1), axis=1)
        lr_bad = ~border & unique & (np.abs(d1 - theirs) > p.lr_tol)
        reason[lr_bad] = spec.REASON_LR
    valid = reason == spec.REASON_VALID
    disp = np.where(valid, code, spec.INVALID).astype(np.uint16)
    safe = np.maximum(s2, 1)
    conf = np.where(valid & (s2 > 0), np.minimum(255, ((s2 - s1) * 256) // safe), 0).astype(np.uint8)
    if p.median:
        disp, reason, conf = median(disp, reason, conf)
    return StereoResult(disp, conf, reason)


def median(disp: np.ndarray, reason: np.ndarray, conf: np.ndarray) -> "tuple[np.ndarray, ...]":
    """Step 7: the 3x3 median of the codes; outside the image counts as the centre; invalid stays."""
    h, w = disp.shape
    padded = np.pad(disp, 1)
    inside = np.pad(np.ones((h, w), bool), 1)
    window = np.empty((9, h, w), np.uint16)
    for i, (dy, dx) in enumerate((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)):
        sl = (slice(1 + dy, 1 + dy + h), slice(1 + dx, 1 + dx + w))
        window[i] = np.where(inside[sl], padded[sl], disp)
    m = np.partition(window, 4, axis=0)[4]
    keep = disp == spec.INVALID
    out = np.where(keep, disp, m).astype(np.uint16)
    lost = ~keep & (m == spec.INVALID)
    reason = reason.copy()
    reason[lost] = spec.REASON_MEDIAN
    conf = np.where(lost, 0, conf).astype(np.uint8)
    return out, reason, conf


def compute(left: np.ndarray, right: np.ndarray, p: spec.StereoParams = spec.DEFAULT_PARAMS) -> StereoResult:
    """The core's output for a rectified gray pair (``uint8``, same shape)."""
    check_pair(left, right, p)
    c = costs(census(left), census(right), p.num_disp)
    total = aggregate(c, left, p)
    d1, s1, s2, code = winners(total, p)
    return finish(total, d1, s1, s2, code, right_winners(total), p)
