"""The stereo core compiled with numba: the same integers as the numpy path, about ten times sooner.

Used where numba installs (``pip install stereocam[fast]``; the serve and test envs have it);
:func:`available` says whether it can run here. The kernels keep the spec's steps and order:
the costs and the path from the left row by row in parallel, the paths from the row above
one row at a time (serially: a parallel region per row waits for its slowest thread, and on a busy
machine that is most of the time), then each pixel's winner, runner-up, sub-pixel
code and the right image's winner per column. Validity, confidence and the median are numpy's
(:func:`.stereo_fast.finish`), shared with the other path, as they cost little.
The first call compiles (a few seconds; numba caches the machine code beside this file when it
can write there).
"""
from __future__ import annotations

from typing import Any, Callable, Optional

import numpy as np

from ..spec import stereo as spec
from . import stereo_fast
from .stereo_result import StereoResult, check_pair

_kernels: Optional[Any] = None
_error: Optional[str] = None


def _build() -> Any:
    import numba  # noqa: PLC0415 - optional, and its import costs a second

    njit: Callable[..., Any] = numba.njit
    prange = numba.prange
    oob = spec.COST_OOB
    uppers = stereo_fast.UPPER_PATHS
    n_up = len(uppers)
    big = np.int16(np.iinfo(np.int16).max)

    @njit(inline="always")
    def popcount(v: Any) -> Any:
        v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
        v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
        v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
        return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)

    @njit(inline="always")
    def step(c: Any, prev: Any, out: Any, p1: int, p2: int, nd: int) -> None:
        pmin = prev[0]
        for d in range(1, nd):
            if prev[d] < pmin:
                pmin = prev[d]
        jump = pmin + p2
        for d in range(nd):
            best = prev[d]
            if jump < best:
                best = jump
            if d > 0 and prev[d - 1] + p1 < best:
                best = prev[d - 1] + p1
            if d < nd - 1 and prev[d + 1] + p1 < best:
                best = prev[d + 1] + p1
            out[d] = c[d] + best - pmin

    @njit(parallel=True, cache=True)
    def costs_and_left(cl: Any, cr: Any, img: Any, cost: Any, total: Any,
                       p1: int, p2: int, p2e: int, thr: int) -> None:
        h, w, nd = cost.shape
        for y in prange(h):
            for x in range(w):
                a = cl[y, x]
                for d in range(nd):
                    cost[y, x, d] = popcount(a ^ cr[y, x - d]) if x - d >= 0 else oob
            for d in range(nd):
                total[y, 0, d] = cost[y, 0, d]
            for x in range(1, w):
                pen = p2e if abs(np.int32(img[y, x]) - np.int32(img[y, x - 1])) >= thr else p2
                step(cost[y, x], total[y, x - 1], total[y, x], p1, pen, nd)

    @njit(cache=True)  # serial: a parallel region per row stalls on a busy machine (one late thread)
    def upper_paths(cost: Any, img: Any, total: Any, p1: int, p2: int, p2e: int, thr: int) -> None:
        h, w, nd = cost.shape
        prev = np.empty((n_up, w, nd), np.int16)
        cur = np.empty((n_up, w, nd), np.int16)
        for x in range(w):
            for d in range(nd):
                c = cost[0, x, d]
                for k in range(n_up):
                    prev[k, x, d] = c
                total[0, x, d] += n_up * c
        for y in range(1, h):
            for x in range(w):
                for k in range(n_up):
                    px = x + uppers[k]
                    if px < 0 or px >= w:
                        for d in range(nd):
                            cur[k, x, d] = cost[y, x, d]
                    else:
                        pen = p2e if abs(np.int32(img[y, x]) - np.int32(img[y - 1, px])) >= thr else p2
                        step(cost[y, x], prev[k, px], cur[k, x], p1, pen, nd)
                for d in range(nd):
                    acc = total[y, x, d]
                    for k in range(n_up):
                        acc += cur[k, x, d]
                    total[y, x, d] = acc
            prev, cur = cur, prev

    @njit(parallel=True, cache=True)
    def winners(total: Any, subpixel: bool, d1o: Any, s1o: Any, s2o: Any, codeo: Any, rbest: Any) -> None:
        h, w, nd = total.shape
        for y in prange(h):
            for x in range(w):
                s = total[y, x]
                d1 = 0
                s1 = s[0]
                for d in range(1, nd):
                    if s[d] < s1:
                        s1 = s[d]
                        d1 = d
                s2 = big
                for d in range(nd):
                    if (d < d1 - 1 or d > d1 + 1) and s[d] < s2:
                        s2 = s[d]
                code = d1 * 16
                if subpixel and 0 < d1 < nd - 1:
                    a = np.int32(s[d1 - 1])
                    b = np.int32(s[d1 + 1])
                    den = a + b - 2 * np.int32(s1)
                    if den < 1:
                        den = 1
                    num = (a - b) * 16 + den
                    q = abs(num) // (2 * den)
                    code += q if num >= 0 else -q
                d1o[y, x] = d1
                s1o[y, x] = s1
                s2o[y, x] = s2
                codeo[y, x] = code
            for xr in range(w):
                best_d = 0
                best_s = total[y, xr, 0]
                for d in range(1, min(nd, w - xr)):
                    v = total[y, xr + d, d]
                    if v < best_s:
                        best_s = v
                        best_d = d
                rbest[y, xr] = best_d

    return costs_and_left, upper_paths, winners


def available() -> bool:
    """Whether the compiled path can run here (numba imports and the kernels build)."""
    return _load() is not None


def unavailable_reason() -> Optional[str]:
    _load()
    return _error


def _load() -> Optional[Any]:
    global _kernels, _error
    if _kernels is None and _error is None:
        try:
            _kernels = _build()
        except ImportError as exc:
            _error = f"numba is not installed ({exc}); pip install 'stereocam[fast]'"
        except Exception as exc:  # a numba that imports but cannot compile here: numpy serves
            _error = f"numba could not build the kernels: {exc}"
    return _kernels


def compute(left: np.ndarray, right: np.ndarray, p: spec.StereoParams = spec.DEFAULT_PARAMS) -> StereoResult:
    """The core's output for a rectified gray pair; raises RuntimeError where numba is missing."""
    check_pair(left, right, p)
    kernels = _load()
    if kernels is None:
        raise RuntimeError(f"the compiled stereo model cannot run: {_error}")
    costs_and_left, upper_paths, winners = kernels
    h, w = left.shape
    nd = p.num_disp
    cl = stereo_fast.census(left)
    cr = stereo_fast.census(right)
    cost = np.empty((h, w, nd), np.int16)
    total = np.empty((h, w, nd), np.int16)
    args = (int(p.p1), int(p.p2), int(p.p2_edge), int(p.edge_thresh))
    costs_and_left(cl, cr, left, cost, total, *args)
    upper_paths(cost, left, total, *args)
    d1 = np.empty((h, w), np.int64)
    s1 = np.empty((h, w), np.int32)
    s2 = np.empty((h, w), np.int32)
    code = np.empty((h, w), np.int32)
    rbest = np.empty((h, w), np.int64)
    winners(total, bool(p.subpixel), d1, s1, s2, code, rbest)
    return stereo_fast.finish(total, d1, s1, s2, code, rbest, p)
