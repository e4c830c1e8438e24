"""Steps 1-4 of the core in fixed point: output pixel -> source position in 1/32 pixel.

Two forms of the same integer arithmetic (``RECTIFY_CORE.md``, "Steps 1-4"):
:func:`position` for one pixel in Python integers (the reference, written
like the document), and :func:`positions` for a whole frame in numpy int64,
exact because every product wider than 63 bits is split (:func:`_mulr`) and
every division is done in 15-bit chunks (:func:`_divr`). Tests check the two
agree bit for bit; the RTL is checked against both.
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from ..spec.rectify import (
    ACC_BITS,
    COORD_LIMIT,
    K_FMT,
    P_FMT,
    R2_LIMIT,
    RADIAL_LIMIT,
    SU_SHIFT,
    XD_LIMIT,
    XN_LIMIT,
    CameraRegs,
    F,
)

_ACC_HALF = 1 << (ACC_BITS - 1)
_ACC_MASK = (1 << ACC_BITS) - 1


def wrap_acc(value: int) -> int:
    """A homography accumulator: two's complement, ``ACC_BITS`` wide, wrapping."""
    return ((value + _ACC_HALF) & _ACC_MASK) - _ACC_HALF


def rnd(product: int, shift: int) -> int:
    """Drop ``shift`` fractional bits, rounding half up (towards +infinity)."""
    return (product + (1 << (shift - 1))) >> shift


def divide(num: int, den: int) -> int:
    """``num / den`` with F fractional bits, rounded half away from zero (``den`` > 0, |num| < 4 den)."""
    q = (abs(num) << (F + 1)) // den
    mag = (q + 1) >> 1
    return mag if num >= 0 else -mag


def position(r: CameraRegs, x: int, y: int) -> Optional[Tuple[int, int]]:
    """Source position ``(iu, iv)`` in 1/32 pixel of output pixel (x, y), or None: the pixel gives 0."""
    n = r.n
    X = wrap_acc(n[0] * x + n[1] * y + n[2])
    Y = wrap_acc(n[3] * x + n[4] * y + n[5])
    Z = wrap_acc(n[6] * x + n[7] * y + n[8])
    if Z <= 0 or abs(X) >= XN_LIMIT * Z or abs(Y) >= XN_LIMIT * Z:
        return None
    xn = divide(X, Z)
    yn = divide(Y, Z)
    x2 = rnd(xn * xn, F)
    y2 = rnd(yn * yn, F)
    xy = rnd(xn * yn, F)
    r2 = x2 + y2
    if r2 >= R2_LIMIT << F:
        return None
    t = rnd(r.k2 * r2, F)  # K_FMT.frac fractional bits
    s = r.k1 + t
    radial = (1 << F) + rnd(s * r2, K_FMT.frac)
    if abs(radial) >= RADIAL_LIMIT << F:
        return None
    a = rnd(xn * radial, F)
    b = rnd(yn * radial, F)
    xy2 = 2 * xy
    xd = a + rnd(r.p1 * xy2, P_FMT.frac) + rnd(r.p2 * (r2 + 2 * x2), P_FMT.frac)
    yd = b + rnd(r.p1 * (r2 + 2 * y2), P_FMT.frac) + rnd(r.p2 * xy2, P_FMT.frac)
    if abs(xd) >= XD_LIMIT << F or abs(yd) >= XD_LIMIT << F:
        return None
    iu = rnd(r.fx * xd + (r.cx << F), SU_SHIFT)
    iv = rnd(r.fy * yd + (r.cy << F), SU_SHIFT)
    if not (-COORD_LIMIT < iu < COORD_LIMIT and -COORD_LIMIT < iv < COORD_LIMIT):
        return None
    return iu, iv


# ---- the same, a frame at a time ---------------------------------------------------------------
_SPLIT = 22  # b = bh * 2**22 + bl: every partial product below stays under 2**62


def _mulr(a: np.ndarray, b: "np.ndarray | int", shift: int, add_hi: "np.ndarray | int" = 0) -> np.ndarray:
    """Exact ``(a * b + add_hi * 2**22 + 2**(shift-1)) >> shift`` for |a|, |b| < 2**40, shift >= 22."""
    b = np.asarray(b, dtype=np.int64)
    bh = b >> _SPLIT
    bl = b & ((1 << _SPLIT) - 1)
    low = (a * bl + (1 << (shift - 1))) >> _SPLIT
    return (a * bh + add_hi + low) >> (shift - _SPLIT)


def _divr(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """:func:`divide` for arrays: long division in 15-bit chunks (den < 2**47, so r << 15 fits int64)."""
    mag = np.abs(num)
    q = mag // den
    rem = mag - q * den
    left = F + 1
    while left:
        step = min(15, left)
        rem = rem << step
        digit = rem // den
        rem -= digit * den
        q = (q << step) | digit
        left -= step
    out = (q + 1) >> 1
    return np.where(num >= 0, out, -out)


def positions(r: CameraRegs, x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`position` for integer arrays ``x``, ``y``: ``(iu, iv, valid)``; iu, iv are 0 where not valid."""
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    n = [np.int64(v) for v in r.n]

    def acc(i: int) -> np.ndarray:
        return ((n[i] * x + n[i + 1] * y + n[i + 2] + _ACC_HALF) & _ACC_MASK) - _ACC_HALF

    X, Y, Z = acc(0), acc(3), acc(6)
    valid = (Z > 0) & (np.abs(X) < XN_LIMIT * Z) & (np.abs(Y) < XN_LIMIT * Z)
    Z = np.where(valid, Z, 1)
    X = np.where(valid, X, 0)
    Y = np.where(valid, Y, 0)
    xn = _divr(X, Z)
    yn = _divr(Y, Z)
    x2 = _mulr(xn, xn, F)
    y2 = _mulr(yn, yn, F)
    xy = _mulr(xn, yn, F)
    r2 = x2 + y2
    valid &= r2 < (R2_LIMIT << F)
    r2 = np.where(valid, r2, 0)
    t = _mulr(r2, r.k2, F)
    s = r.k1 + t
    radial = (1 << F) + _mulr(s, r2, K_FMT.frac)
    valid &= np.abs(radial) < (RADIAL_LIMIT << F)
    radial = np.where(valid, radial, 0)
    a = _mulr(xn, radial, F)
    b = _mulr(yn, radial, F)
    xy2 = 2 * xy
    xd = a + _mulr(xy2, r.p1, P_FMT.frac) + _mulr(r2 + 2 * x2, r.p2, P_FMT.frac)
    yd = b + _mulr(r2 + 2 * y2, r.p1, P_FMT.frac) + _mulr(xy2, r.p2, P_FMT.frac)
    valid &= (np.abs(xd) < (XD_LIMIT << F)) & (np.abs(yd) < (XD_LIMIT << F))
    xd = np.where(valid, xd, 0)
    yd = np.where(valid, yd, 0)
    iu = _mulr(xd, r.fx, SU_SHIFT, np.int64(r.cx) << (F - _SPLIT))
    iv = _mulr(yd, r.fy, SU_SHIFT, np.int64(r.cy) << (F - _SPLIT))
    valid &= (iu > -COORD_LIMIT) & (iu < COORD_LIMIT) & (iv > -COORD_LIMIT) & (iv < COORD_LIMIT)
    return np.where(valid, iu, 0), np.where(valid, iv, 0), valid
