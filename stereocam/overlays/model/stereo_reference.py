"""The stereo core, one pixel at a time in plain Python integers: the reading of the spec to trust.

Slow (seconds for a 64x32 pair): the fast paths (:mod:`.stereo_fast`, :mod:`.stereo_jit`) are
tested equal to it, and it is written to be read beside ``STEREO_CORE.md``, step by step.
"""
from __future__ import annotations

from typing import List

import numpy as np

from ..spec import stereo as spec
from .stereo_result import StereoResult, check_pair


def census(img: np.ndarray) -> List[List[int]]:
    """Step 1: each pixel's 62-bit word; a neighbour outside the image counts as the centre (bit 0)."""
    h, w = img.shape
    out = [[0] * w for _ in range(h)]
    for y in range(h):
        for x in range(w):
            centre = int(img[y, x])
            word = 0
            for bit, (dy, dx) in enumerate(spec.CENSUS_OFFSETS):
                yy, xx = y + dy, x + dx
                if 0 <= yy < h and 0 <= xx < w and int(img[yy, xx]) < centre:
                    word |= 1 << bit
            out[y][x] = word
    return out


def cost(cl: List[List[int]], cr: List[List[int]], y: int, x: int, d: int) -> int:
    """Step 2: the Hamming distance, or COST_OOB left of the right image."""
    if x - d < 0:
        return spec.COST_OOB
    return bin(cl[y][x] ^ cr[y][x - d]).count("1")


def compute(left: np.ndarray, right: np.ndarray, p: spec.StereoParams = spec.DEFAULT_PARAMS) -> StereoResult:
    """The core's output for a rectified gray pair (``uint8``, same shape)."""
    check_pair(left, right, p)
    h, w = left.shape
    nd = p.num_disp
    cl, cr = census(left), census(right)
    # Step 3: L[r][y][x][d]; the previous pixel of path r at (x + dx, y + dy).
    total = [[[0] * nd for _ in range(w)] for _ in range(h)]
    for (dx, dy) in spec.PATHS:
        lr: List[List[List[int]]] = [[[0] * nd for _ in range(w)] for _ in range(h)]
        for y in range(h):
            for x in range(w):
                c = [cost(cl, cr, y, x, d) for d in range(nd)]
                px, py = x + dx, y + dy
                if not (0 <= px < w and 0 <= py < h):
                    lr[y][x] = c
                else:
                    prev = lr[py][px]
                    pmin = min(prev)
                    edge = abs(int(left[y, x]) - int(left[py, px])) >= p.edge_thresh
                    p2 = p.p2_edge if edge else p.p2
                    row = []
                    for d in range(nd):
                        best = min(prev[d], pmin + p2)
                        if d > 0:
                            best = min(best, prev[d - 1] + p.p1)
                        if d < nd - 1:
                            best = min(best, prev[d + 1] + p.p1)
                        row.append(c[d] + best - pmin)
                    lr[y][x] = row
                for d in range(nd):
                    total[y][x][d] += lr[y][x][d]
    disp = np.full((h, w), spec.INVALID, np.uint16)
    conf = np.zeros((h, w), np.uint8)
    reason = np.zeros((h, w), np.uint8)
    # Step 6's right winners: the diagonal minimum of the same sums.
    right_best = [[0] * w for _ in range(h)]
    for y in range(h):
        for xr in range(w):
            best_d, best_s = 0, None
            for d in range(nd):
                if xr + d >= w:
                    break
                s = total[y][xr + d][d]
                if best_s is None or s < best_s:
                    best_d, best_s = d, s
            right_best[y][xr] = best_d
    for y in range(h):
        for x in range(w):
            sums = total[y][x]
            d1 = min(range(nd), key=lambda d: (sums[d], d))  # step 4: lowest sum, lowest d on ties
            s1 = sums[d1]
            s2 = min(sums[d] for d in range(nd) if abs(d - d1) > 1)
            code = d1 * spec.SUBPIX_ONE
            if p.subpixel and 0 < d1 < nd - 1:  # step 5
                a, b = sums[d1 - 1], sums[d1 + 1]
                den = max(a + b - 2 * s1, 1)
                num = (a - b) * spec.SUBPIX_ONE + den
                q = abs(num) // (2 * den)
                code += q if num >= 0 else -q  # C's division: toward zero
            why = spec.REASON_VALID
            if x - d1 < 0:
                why = spec.REASON_BORDER
            elif s2 * spec.UNIQUENESS_ONE <= s1 * (spec.UNIQUENESS_ONE + p.uniqueness):
                why = spec.REASON_UNIQUENESS
            elif p.lr_check and abs(d1 - right_best[y][x - d1]) > p.lr_tol:
                why = spec.REASON_LR
            reason[y, x] = why
            if why == spec.REASON_VALID:
                disp[y, x] = code
                conf[y, x] = min(255, ((s2 - s1) * 256) // s2) if s2 > 0 else 0
    if p.median:  # step 7
        src = disp.copy()
        for y in range(h):
            for x in range(w):
                centre = int(src[y, x])
                if centre == spec.INVALID:
                    continue
                window = []
                for yy in range(y - 1, y + 2):
                    for xx in range(x - 1, x + 2):
                        inside = 0 <= yy < h and 0 <= xx < w
                        window.append(int(src[yy, xx]) if inside else centre)
                m = sorted(window)[4]
                disp[y, x] = m
                if m == spec.INVALID:
                    reason[y, x] = spec.REASON_MEDIAN
                    conf[y, x] = 0
    return StereoResult(disp, conf, reason)
