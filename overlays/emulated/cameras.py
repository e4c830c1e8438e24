"""Emulated live cameras: a synthetic stereo rig of known calibration, and replay of recordings.

Both sources deliver what the demosaic stage of the real board delivers: one
``(H, W, 8)`` uint8 stream frame per :meth:`CameraSource.read` (left RGBY in
channels 0..3, right RGBY in 4..7, gray made exactly as
:func:`..spec.pixel.gray_of` makes it).

:class:`SyntheticRig` ray-traces a small textured scene through the TRUE
camera model (pinhole + Brown-Conrady k1, k2, p1, p2, and the stereo pose of
:attr:`SyntheticRig.model`): rectifying its frames with that model gives
rectified frames, and a calibration computed from
:meth:`SyntheticRig.render_plane_views` must give that model back. Like the
board's MT9V034s, each camera samples the scene through a Bayer filter into
10-bit samples (:attr:`SyntheticRig.raw` keeps the last ones), and the frame
is what the camera input IP makes of them (:mod:`..model.camera_in`, the
model the RTL is bit-exact to).

:class:`ReplaySource` plays back recorded frame pairs from a folder. Its
recordings are frames the IP already demosaiced (captures of the stream):
they are played as they are, not mosaicked again. A stereocam recording
(``POST /api/recordings``: a folder with ``recording.json``) is played frame by
frame in order at the rate it was recorded.

Pixel convention (OpenCV's, and the rectify core's): the centre of pixel
``(column u, row v)`` is at image coordinates ``(u, v)``.
"""
from __future__ import annotations

import bisect
import json
import math
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Protocol, Sequence, Tuple, Union, runtime_checkable

import cv2
import numpy as np

from ...calibration.stereo import StereoModel
from ..model import camera_in as camera_model
from ..spec import camera_in as camera_spec
from ..spec.pixel import gray_of, pack, rgby

__all__ = [
    "CameraSource",
    "SourceClosedError",
    "SyntheticRig",
    "ReplaySource",
    "ReplayError",
    "ReplayEnded",
    "rig_model",
    "undistort_normalized",
]


class SourceClosedError(ValueError):
    """``read`` on a source after its ``close()``."""


@runtime_checkable
class CameraSource(Protocol):
    """What the emulated fabric's camera input needs from a live source.

    ``read`` returns the stereo frame number ``index`` (>= 0) at time ``t``
    seconds as an ``(H, W, 8)`` uint8 array with ``(W, H) == frame_size``.
    It blocks while the frame is made (a few ms) and is deterministic in
    ``(index, t)``. The returned array may be shared with the source and
    read-only: a consumer that modifies it must copy it first. ``close()``
    is idempotent; ``read`` after it raises :class:`SourceClosedError`.
    """

    @property
    def frame_size(self) -> Tuple[int, int]: ...

    def read(self, index: int, t: float) -> np.ndarray: ...

    def close(self) -> None: ...


# --------------------------------------------------------------------------
# Camera geometry
# --------------------------------------------------------------------------

def undistort_normalized(
    K: np.ndarray, D: Union[np.ndarray, Sequence[float]], u: np.ndarray, v: np.ndarray, *,
    tol: float = 1e-13, max_iter: int = 30,
) -> Tuple[np.ndarray, np.ndarray]:
    """Ideal normalized coordinates ``(x, y)`` of raw (distorted) pixel positions ``(u, v)``.

    The exact inverse of the Brown-Conrady model (k1, k2, p1, p2): Newton's
    method in float64 to ``tol`` (normalized units), started from
    ``cv2.undistortPoints``, which alone stops after 5 fixed-point steps and
    is off by ~0.5 px in the corners of a strongly distorted lens. Raises
    ``ValueError`` if the distortion has no inverse there (fold-over).
    """
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(D, dtype=np.float64).reshape(-1)[:4]
    k1, k2, p1, p2 = (float(c) for c in dist)
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    shape = np.broadcast(u, v).shape
    uf = np.broadcast_to(u, shape).reshape(-1)
    vf = np.broadcast_to(v, shape).reshape(-1)
    x_out = np.empty(uf.size)
    y_out = np.empty(uf.size)
    chunk = 1 << 16  # keeps the temporaries in cache: 3x faster than whole-image arrays
    for lo in range(0, uf.size, chunk):
        hi = min(lo + chunk, uf.size)
        yd = (vf[lo:hi] - cy) / fy
        xd = (uf[lo:hi] - cx - skew * yd) / fx
        guess = cv2.undistortPoints(np.stack([uf[lo:hi], vf[lo:hi]], axis=-1).reshape(-1, 1, 2), K, dist)
        x = guess[:, 0, 0].astype(np.float64)
        y = guess[:, 0, 1].astype(np.float64)
        bad = ~(np.isfinite(x) & np.isfinite(y))
        x[bad], y[bad] = xd[bad], yd[bad]
        for _ in range(max_iter):
            x2, y2, xy = x * x, y * y, x * y
            r2 = x2 + y2
            radial = 1.0 + r2 * (k1 + k2 * r2)
            g = 2.0 * k1 + 4.0 * k2 * r2  # d(radial)/dx = g x
            ex = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) - xd
            ey = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy - yd
            a = radial + g * x2 + 2.0 * p1 * y + 6.0 * p2 * x
            b = g * xy + 2.0 * p1 * x + 2.0 * p2 * y  # d ex/dy == d ey/dx
            d = radial + g * y2 + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            if np.any(det <= 0):
                raise ValueError("the distortion folds over inside the image: it has no inverse there")
            dx = (d * ex - b * ey) / det
            dy = (a * ey - b * ex) / det
            x -= dx
            y -= dy
            if float(np.max(np.abs(dx), initial=0.0)) < tol and float(np.max(np.abs(dy), initial=0.0)) < tol:
                break
        else:
            raise ValueError(f"undistortion did not converge in {max_iter} Newton steps: too much distortion")
        x_out[lo:hi] = x
        y_out[lo:hi] = y
    return x_out.reshape(shape), y_out.reshape(shape)


def _rotation(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation about y (yaw), then x (pitch), then z (roll), camera axes (x right, y down, z forward)."""
    a, b, c = (math.radians(d) for d in (yaw_deg, pitch_deg, roll_deg))
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rz


# The rig at 752 x 480 (MT9V034, 6 um square pixels). A 2.52 mm lens gives
# f = 2.52 mm / 6 um = 420 px: about 84 deg horizontal field before the
# (barrel) distortion, which widens it further. Units: pixels for K, metres for T.
_BASE_SIZE = (752, 480)
_K1 = ((420.0, 0.0, 372.3), (0.0, 419.2, 243.6), (0.0, 0.0, 1.0))
_D1 = (-0.15, 0.03, 8.0e-4, -5.0e-4)  # moderate barrel: the rig fits the 80-row bitstream (70 rows)
_K2 = ((423.1, 0.0, 379.8), (0.0, 422.5, 237.2), (0.0, 0.0, 1.0))
_D2 = (-0.145, 0.028, -6.0e-4, 9.0e-4)
_RVEC_DEG = (0.5, -1.0, 0.3)  # rotation vector left -> right, degrees
_C2 = (0.060, -0.0005, 0.0010)  # right camera centre in the left camera's frame, metres


def rig_model(size: Tuple[int, int] = _BASE_SIZE) -> StereoModel:
    """The synthetic rig's calibration for an image of ``size = (width, height)``.

    At 752 x 480: K1 fx 420.0 fy 419.2 cx 372.3 cy 243.6, D1 (-0.15, 0.03,
    8e-4, -5e-4); K2 fx 423.1 fy 422.5 cx 379.8 cy 237.2, D2 (-0.145, 0.028,
    -6e-4, 9e-4); R = Rodrigues((0.5, -1.0, 0.3) deg); right camera centre at
    (60.0, -0.5, 1.0) mm in the left camera's frame, so T = -R @ C2 (metres,
    about (-0.060, 0.0005, -0.002)). Another size scales the intrinsics
    (focal lengths by width/752 and height/480, principal point offsets from
    the image centre likewise): the same lenses on a resampled sensor.
    """
    w, h = int(size[0]), int(size[1])
    if w < 16 or h < 16:
        raise ValueError(f"image size {size} is too small: use at least 16 x 16")
    sx, sy = w / _BASE_SIZE[0], h / _BASE_SIZE[1]

    def scaled(K: Tuple[Tuple[float, ...], ...]) -> np.ndarray:
        k = np.array(K, dtype=np.float64)
        return np.array([
            [k[0, 0] * sx, 0.0, (w - 1) / 2 + (k[0, 2] - (_BASE_SIZE[0] - 1) / 2) * sx],
            [0.0, k[1, 1] * sy, (h - 1) / 2 + (k[1, 2] - (_BASE_SIZE[1] - 1) / 2) * sy],
            [0.0, 0.0, 1.0],
        ])

    R, _ = cv2.Rodrigues(np.radians(np.array(_RVEC_DEG, dtype=np.float64)).reshape(3, 1))
    T = -R @ np.array(_C2, dtype=np.float64)
    return StereoModel(scaled(_K1), np.array(_D1), scaled(_K2), np.array(_D2), R, T, (w, h))


@dataclass(frozen=True)
class _Rays:
    """Viewing rays of every raw pixel of one camera, in the LEFT camera's frame.

    A point on the ray of pixel (u, v) is ``centre + lam * (dx, dy, dz)[v, u]``;
    ``lam`` is the depth along that camera's own optical axis, so depths of
    different surfaces along one ray compare directly.
    """

    centre: np.ndarray  # (3,)
    dx: np.ndarray  # (H, W) float64
    dy: np.ndarray
    dz: np.ndarray

    @classmethod
    def of(cls, K: np.ndarray, D: np.ndarray, R_cam: np.ndarray, centre: np.ndarray,
           u: np.ndarray, v: np.ndarray) -> "_Rays":
        """``R_cam`` rotates left-frame vectors into this camera's frame."""
        x, y = undistort_normalized(K, D, u, v)
        rt = np.asarray(R_cam, dtype=np.float64).T  # camera -> left frame
        dx = rt[0, 0] * x + rt[0, 1] * y + rt[0, 2]
        dy = rt[1, 0] * x + rt[1, 1] * y + rt[1, 2]
        dz = rt[2, 0] * x + rt[2, 1] * y + rt[2, 2]
        return cls(np.asarray(centre, dtype=np.float64), dx, dy, dz)

    def hit(self, origin: np.ndarray, u_axis: np.ndarray, v_axis: np.ndarray,
            ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth ``lam`` (inf where missed or behind) and in-plane coordinates (s, t) in metres."""
        n = np.cross(u_axis, v_axis)
        rel = origin - self.centre
        denom = n[0] * self.dx + n[1] * self.dy + n[2] * self.dz
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = float(n @ rel) / denom
        lam = np.where(np.isfinite(lam) & (lam > 1e-6), lam, np.inf)
        finite = np.isfinite(lam)
        lam0 = np.where(finite, lam, 0.0)
        px = lam0 * self.dx - rel[0]
        py = lam0 * self.dy - rel[1]
        pz = lam0 * self.dz - rel[2]
        s = u_axis[0] * px + u_axis[1] * py + u_axis[2] * pz
        t = v_axis[0] * px + v_axis[1] * py + v_axis[2] * pz
        return lam, s, t


# --------------------------------------------------------------------------
# The synthetic scene
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class _Plane:
    """A textured plane of the scene, in the left camera's frame (metres, seconds).

    Moving planes slide within their own plane, ``offset(t)`` along their
    u and v axes: depth per pixel never changes, only which pixels the
    rectangle covers and where its texture sits, so a frame costs a few
    comparisons and one ``remap`` per plane.
    """

    name: str
    origin: Tuple[float, float, float]  # rest position of the rectangle's centre
    angles: Tuple[float, float, float]  # yaw, pitch, roll in degrees (0: facing the camera)
    texel: float  # metres per texel
    texture: int  # index into the rig's textures
    half_size: Optional[Tuple[float, float]] = None  # None: unbounded (static background)
    shade: float = 1.0
    amplitude: Tuple[float, float] = (0.0, 0.0)  # metres along u, v
    period: Tuple[float, float] = (1.0, 1.0)  # seconds
    phase: Tuple[float, float] = (0.0, 0.0)  # radians

    def axes(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        rot = _rotation(*self.angles)
        return np.array(self.origin, dtype=np.float64), rot[:, 0].copy(), rot[:, 1].copy()

    @property
    def moving(self) -> bool:
        return self.half_size is not None and any(a != 0.0 for a in self.amplitude)

    def offset(self, t: float) -> Tuple[float, float]:
        (au, av), (pu, pv), (qu, qv) = self.amplitude, self.period, self.phase
        return au * math.sin(2.0 * math.pi * t / pu + qu), av * math.sin(2.0 * math.pi * t / pv + qv)


# Textures: index 0 wall, 1 floor, 2 box face, 3 slanted board.
_SCENE: Tuple[_Plane, ...] = (
    _Plane("wall", (0.0, 0.0, 3.0), (14.0, 0.0, 0.0), texel=0.008, texture=0),
    _Plane("floor", (0.0, 1.1, 2.0), (0.0, 90.0, 0.0), texel=0.010, texture=1, shade=0.8),
    _Plane("box", (-0.12, 0.06, 1.0), (0.0, 0.0, 0.0), texel=0.002, texture=2, half_size=(0.22, 0.17),
           amplitude=(0.25, 0.0), period=(7.0, 1.0)),
    _Plane("board", (0.34, -0.14, 1.45), (-35.0, 12.0, 4.0), texel=0.003, texture=3, half_size=(0.25, 0.30),
           shade=0.92, amplitude=(0.06, 0.12), period=(13.0, 9.0), phase=(0.7, 0.0)),
)
@dataclass(frozen=True)
class _Look:
    """How one texture is baked: size in texels, colour tint, checker and ring periods in texels."""

    size: int
    tint: Tuple[float, float, float]
    checker: int
    rings: float
    contrast: float = 1.0


_LOOKS = (  # wall, floor, box face, slanted board
    _Look(1024, (1.00, 0.95, 0.85), checker=32, rings=41.0),
    _Look(1024, (0.80, 0.88, 1.00), checker=50, rings=97.0, contrast=0.8),
    _Look(512, (1.15, 0.80, 0.70), checker=12, rings=17.0, contrast=1.2),
    _Look(512, (0.80, 1.10, 0.85), checker=20, rings=29.0, contrast=1.1),
)
_SKY = 40.0  # radiance where a ray hits nothing
_GRAY_FLOAT = (77 / 256, 150 / 256, 29 / 256)  # gray of float radiance (pixel.GRAY_WEIGHTS / 256)


def _wrap_noise(rng: np.random.Generator, size: int, scale: int, channels: int) -> np.ndarray:
    """Seamlessly tiling (size, size, channels) noise: zero mean, unit deviation, features ~``scale`` texels.

    Made at ``size / scale`` and upsampled (cheap even for coarse scales).
    """
    n = max(4, size // scale)
    base = rng.random((n, n, channels), dtype=np.float32)
    pad = 3
    smooth = cv2.GaussianBlur(cv2.copyMakeBorder(base, pad, pad, pad, pad, cv2.BORDER_WRAP), (0, 0), 0.7)
    f = size / n
    up = cv2.resize(smooth, None, fx=f, fy=f, interpolation=cv2.INTER_CUBIC)
    if up.ndim == 2:
        up = up[..., None]
    o = int(round(pad * f))
    up = up[o:o + size, o:o + size]
    return (up - up.mean()) / (up.std() + 1e-6)


def _bake_texture(rng: np.random.Generator, look: _Look, channels: int) -> np.ndarray:
    """A (size, size[, 3]) float32 radiance texture (DN 0..255): multi-scale noise, a checker, rings.

    Detail down to one texel (for stereo matching and for seeing the
    interpolation), a checker for edges and rings for every orientation.
    Values stay inside [8, 247], so a unit-gain sensor never clips.
    """
    size = look.size
    grey = sum(w * _wrap_noise(rng, size, scale, 1) for scale, w in ((1, 0.5), (4, 0.35), (16, 0.3)))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    checker = ((((xx // look.checker) + (yy // look.checker)) % 2) * 2 - 1)[..., None]
    rings = np.cos(2 * np.pi * np.hypot(xx - size / 2, yy - size / 2) / look.rings)[..., None]
    tex = look.contrast * (30.0 * grey + 26.0 * checker + 14.0 * rings)
    if channels == 3:
        tex = tex + 10.0 * _wrap_noise(rng, size, 32, 3) + (np.asarray(look.tint, np.float32) - 1.0) * 110.0
    tex = np.clip(tex + 128.0, 8.0, 247.0).astype(np.float32)
    return np.ascontiguousarray(tex[..., 0] if channels == 1 else tex)


@dataclass
class _Layer:
    """One moving plane as seen by one camera, cropped to the pixels it can ever cover."""

    plane: _Plane
    rows: slice  # within the camera's moving region
    cols: slice
    s: np.ndarray  # (h, w) float32 in-plane u coordinate, texels from the rest centre
    t: np.ndarray
    depth: np.ndarray  # float32, inf where the ray misses the plane
    centre: Tuple[float, float]  # texture coordinates of the rest centre


@dataclass
class _CameraScene:
    """Everything precomputed for rendering one camera."""

    static_radiance: np.ndarray  # (H, W[, 3]) float32
    static_depth: np.ndarray  # (H, W) float32
    region: Tuple[slice, slice]  # bounding box of every pixel a moving plane can cover
    layers: List[_Layer]


@dataclass
class _Sensor:
    """Per-camera sensor response and readout.

    Each pixel sees the radiance of its Bayer filter's colour; its 10-bit
    sample is 4 x (gain * exposure * radiance + offset + gain * noise),
    rounded and clipped to 0..1023 (radiance is in 8-bit DN, so unit gain
    renders the scene at the brightness the 8-bit rig always had). The
    readout flips (``flip_h`` mirrors columns, ``flip_v`` rows), or
    ``pattern`` (an (H, W) uint8 gray image, sent as 4 x its values)
    replaces the samples. Set through :meth:`SyntheticRig.set_sensor`.
    """

    gain: float = 1.0  # analog gain: scales the signal and the read noise
    offset: float = 0.0
    noise: float = 0.0  # read noise at unit gain: standard deviation in DN, fresh for every frame index
    exposure: float = 1.0  # exposure time relative to the reference exposure: scales the signal only
    flip_h: bool = False
    flip_v: bool = False
    pattern: Optional[np.ndarray] = None
    pattern_rgby: Optional[np.ndarray] = None  # the IP's output for the pattern's samples
    # Bayer phases in the unflipped image (what the array sees): the filter's, and the one the IP
    # demosaics with, seen through the flips (:meth:`SyntheticRig._phases`)
    phase_array: str = camera_spec.BAYER_PHASE
    phase_ip: str = camera_spec.BAYER_PHASE

    @property
    def scale(self) -> float:
        return self.gain * self.exposure

    @property
    def key(self) -> Tuple[float, float, str, str]:
        return (self.scale, self.offset, self.phase_array, self.phase_ip)


class SyntheticRig:
    """A stereo rig of known calibration looking at a slowly moving textured scene.

    The scene, in the left camera's frame (x right, y down, z forward,
    metres): a back wall about 3 m away turned 14 deg, a floor 1.1 m below
    the cameras, a frontal "box face" 0.44 x 0.34 m at 1.0 m sliding
    sideways (+-0.25 m, 7 s period), and a slanted board 0.5 x 0.6 m at
    about 1.45 m sliding within its own plane (periods 13 s and 9 s). Nearest
    surface wins. With ``motion=False`` every plane stays at its rest
    position and every frame is the same.

    :attr:`model` is the true calibration (K in pixels, T in metres).
    Rendering: each raw pixel's ray is computed once through the exact
    inverse distortion; a frame intersects those rays with the planes, samples
    float radiance textures with bilinear ``cv2.remap`` and passes through a
    per-camera sensor stage (Bayer filter, gain, offset, noise, 10-bit
    samples) and the camera input IP's model (demosaic to 8-bit RGB and
    gray). Only the region the moving planes can reach, plus the one-pixel
    reach of the demosaic, is re-rendered per frame. :meth:`set_sensor` sets
    a camera's exposure, gain, flips and test pattern (what the emulated
    MT9V034 sensors do once per frame). Flips follow the MT9V034 family's
    read-out (``spec.camera_in.cfa_phase``): the first pixel read keeps its
    colour when the flipped size is even, so the IP's fixed Bayer phase fits
    (an odd-sized flipped rig shows what the board would: swapped colours).

    ``read`` returns a new, writable frame owned by the caller. Calls from
    several threads are safe (they are serialised).
    """

    def __init__(
        self, *, size: Tuple[int, int] = _BASE_SIZE, model: Optional[StereoModel] = None, motion: bool = True,
        seed: int = 0, colour: bool = True, noise: float = 0.0,
    ) -> None:
        if model is None:
            model = rig_model(size)
        elif tuple(size) != _BASE_SIZE and tuple(size) != tuple(model.image_size):
            raise ValueError(
                f"size {tuple(size)} disagrees with model.image_size {model.image_size}: give one of them"
            )
        if noise < 0 or not math.isfinite(noise):
            raise ValueError(f"noise is a standard deviation in DN (>= 0), got {noise}")
        self.model: StereoModel = model
        self.motion = bool(motion)
        self.seed = int(seed)
        self.colour = bool(colour)
        self._closed = False
        self._lock = threading.Lock()
        w, h = model.image_size
        self._size = (w, h)
        self._sensors = [_Sensor(noise=float(noise)), _Sensor(noise=float(noise))]

        rng = np.random.default_rng(self.seed)
        channels = 3 if self.colour else 1
        self._textures = [_bake_texture(rng, look, channels) for look in _LOOKS]

        R = np.asarray(model.R, dtype=np.float64)
        T = np.asarray(model.T, dtype=np.float64)
        self._poses = ((np.eye(3), np.zeros(3)), (R, -R.T @ T))  # (R_cam, centre in the left frame)
        self._pixel_grid: Dict[int, Tuple[np.ndarray, np.ndarray]] = {}
        self._noise_bank: Dict[int, np.ndarray] = {}
        self._rays: Dict[Tuple[int, int], _Rays] = {}  # (camera, supersample) -> rays
        self._cams = [self._prepare(cam) for cam in (0, 1)]
        self._static_frame: Optional[np.ndarray] = None
        self._static_raw: List[np.ndarray] = []  # per camera: 10-bit samples of the static scene (unflipped)
        self._static_key: Optional[Tuple[Tuple[float, float, str, str], ...]] = None
        self._still: Optional[np.ndarray] = None  # motion=False: the one frame
        self._raw: List[Optional[np.ndarray]] = [None, None]  # the last frame's samples, unflipped

    # -- the CameraSource protocol ---------------------------------------

    @property
    def frame_size(self) -> Tuple[int, int]:
        """``(width, height)`` of the frames."""
        return self._size

    def read(self, index: int, t: float) -> np.ndarray:
        """Stereo frame ``index`` at ``t`` seconds: a new ``(H, W, 8)`` uint8 array owned by the caller.

        Blocks for the rendering (a few ms at 752 x 480). Deterministic in
        ``(index, t)``: ``t`` positions the moving planes, ``index`` seeds
        the sensor noise (if any).
        """
        index = int(index)
        if index < 0:
            raise ValueError(f"frame index must be >= 0, got {index}")
        t = float(t)
        if not math.isfinite(t):
            raise ValueError(f"time must be finite, got {t}")
        with self._lock:
            if self._closed:
                raise SourceClosedError("this SyntheticRig is closed: make a new one")
            return self._read(index, t if self.motion else 0.0)

    def set_sensor(
        self, camera: int, *, gain: float = 1.0, exposure_scale: float = 1.0, flip_h: bool = False,
        flip_v: bool = False, test_pattern: Optional[np.ndarray] = None, noise: Optional[float] = None,
    ) -> None:
        """Set camera ``camera``'s (0 left, 1 right) sensor stage for the frames read from now on.

        The image is ``gain * exposure_scale`` times the unit-gain image
        (``exposure_scale`` is the exposure time over the reference exposure
        the scene's radiance is given for), with read noise of standard
        deviation ``gain * noise`` DN (``noise=None`` keeps the rig's).
        ``flip_h``/``flip_v`` mirror the columns/rows read out.
        ``test_pattern``, an ``(H, W)`` uint8 image at the frame size,
        replaces the picture (gray: R = G = B = Y) and is not flipped. The
        rig keeps a reference to the pattern: do not modify it afterwards.
        """
        if camera not in (0, 1):
            raise ValueError(f"camera is 0 (left) or 1 (right), not {camera!r}")
        gain, exposure_scale = float(gain), float(exposure_scale)
        if not (math.isfinite(gain) and gain >= 0 and math.isfinite(exposure_scale) and exposure_scale >= 0):
            raise ValueError(f"gain and exposure_scale must be finite and >= 0, got {gain}, {exposure_scale}")
        if noise is not None and not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise is a standard deviation in DN (>= 0), got {noise}")
        if test_pattern is not None:
            w, h = self._size
            if test_pattern.shape != (h, w) or test_pattern.dtype != np.uint8:
                raise ValueError(f"test_pattern must be a ({h}, {w}) uint8 image, "
                                 f"got {test_pattern.shape} {test_pattern.dtype}")
        with self._lock:
            s = self._sensors[camera]
            s.gain, s.exposure = gain, exposure_scale
            s.flip_h, s.flip_v = bool(flip_h), bool(flip_v)
            s.phase_array, s.phase_ip = self._phases(s.flip_h, s.flip_v)
            if test_pattern is None:
                s.pattern = s.pattern_rgby = None
            elif test_pattern is not s.pattern:  # the sensors hand the same pattern every frame
                s.pattern = test_pattern
                s.pattern_rgby = camera_model.demosaic_camera(test_pattern.astype(np.uint16) << 2)
            if noise is not None:
                s.noise = float(noise)

    def _phases(self, flip_h: bool, flip_v: bool) -> Tuple[str, str]:
        """Bayer phases in the unflipped image: the filter's, and the IP's demosaic's seen through the flips.

        The sensor reads the rig's frame as the default window (COLUMN_START,
        ROW_START at their reset values) of the rig's size; its read-out
        phase is ``cfa_phase`` of that, the IP demosaics with BAYER_PHASE.
        Rendering unflipped, mosaicking and demosaicking with these phases
        and then flipping gives exactly the IP's output for the flipped read-out
        (the demosaic is mirror-symmetric).
        """
        w, h = self._size
        readout = camera_spec.cfa_phase(camera_spec.DEFAULT_COLUMN_START, camera_spec.DEFAULT_ROW_START, w, h,
                                        column_flip=flip_h, row_flip=flip_v)
        return (camera_model.flipped_phase(readout, w, h, flip_h, flip_v),
                camera_model.flipped_phase(camera_spec.BAYER_PHASE, w, h, flip_h, flip_v))

    @property
    def raw(self) -> Tuple[Optional[np.ndarray], Optional[np.ndarray]]:
        """The 10-bit Bayer samples (uint16, read-out order: flips applied) each camera sent for the last
        frame read, or None for a camera showing a test pattern or before the first read.

        ``camera_model.demosaic(*rig.raw)`` is that frame (without test patterns).
        Read-only views, valid until the next ``read``.
        """
        with self._lock:
            out: List[Optional[np.ndarray]] = []
            for cam, s in enumerate(self._sensors):
                raw = self._raw[cam]
                if raw is None or s.pattern is not None:
                    out.append(None)
                    continue
                view = raw[::-1 if s.flip_v else 1, ::-1 if s.flip_h else 1]
                view.setflags(write=False)
                out.append(view)
            return out[0], out[1]

    def _read(self, index: int, t: float) -> np.ndarray:
        if any(s.noise > 0 and s.pattern is None for s in self._sensors):
            w, h = self._size
            frame = np.empty((h, w, 8), np.uint8)
            for cam in (0, 1):
                if self._sensors[cam].pattern is None:
                    raw = self._sensor(self._radiance(cam, t)[0], cam, index)
                    self._raw[cam] = raw
                    rgby_ = camera_model.demosaic_camera(raw, self._sensors[cam].phase_ip)
                    self._write_rgby(frame, cam, rgby_)
            return self._readout(frame)
        if not self.motion:
            if self._still is None or self._static_key != self._sensor_key():
                self._still = self._render_fast(0.0)
            return self._readout(self._still.copy())
        return self._readout(self._render_fast(t))

    def _readout(self, frame: np.ndarray) -> np.ndarray:
        """Apply each camera's test pattern or flips to ``frame`` in place; returns it."""
        for cam, s in enumerate(self._sensors):
            if s.pattern is None and not (s.flip_h or s.flip_v):
                continue
            view = frame[..., 4 * cam:4 * cam + 4]
            if s.pattern_rgby is not None:
                view[...] = s.pattern_rgby
            else:  # numpy copies overlapping operands first
                view[...] = view[::-1 if s.flip_v else 1, ::-1 if s.flip_h else 1]
        return frame

    def close(self) -> None:
        """Release the precomputed rays and textures. Idempotent."""
        with self._lock:
            self._closed = True
            self._cams = []
            self._textures = []
            self._rays.clear()
            self._pixel_grid.clear()
            self._noise_bank.clear()
            self._static_frame = self._still = None
            self._static_raw = []
            self._raw = [None, None]

    def __enter__(self) -> "SyntheticRig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- rendering ---------------------------------------------------------

    def _grid(self, supersample: int) -> Tuple[np.ndarray, np.ndarray]:
        """Raw pixel positions of the sample points, ``supersample`` x ``supersample`` per pixel."""
        if supersample not in self._pixel_grid:
            w, h = self._size
            n = supersample
            offsets = (np.arange(n) + 0.5) / n - 0.5
            us = (np.arange(w)[:, None] + offsets[None, :]).reshape(-1)
            vs = (np.arange(h)[:, None] + offsets[None, :]).reshape(-1)
            u, v = np.meshgrid(us, vs)
            self._pixel_grid[supersample] = (u, v)
        return self._pixel_grid[supersample]

    def _camera_rays(self, cam: int, supersample: int = 1) -> _Rays:
        key = (cam, supersample)
        if key not in self._rays:
            K, D = (self.model.K1, self.model.D1) if cam == 0 else (self.model.K2, self.model.D2)
            R_cam, centre = self._poses[cam]
            u, v = self._grid(supersample)
            self._rays[key] = _Rays.of(K, D, R_cam, centre, u, v)
        return self._rays[key]

    def _sample(self, plane: _Plane, mapx: np.ndarray, mapy: np.ndarray) -> np.ndarray:
        tex = self._textures[plane.texture]
        out = cv2.remap(tex, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        if plane.shade != 1.0:
            out *= np.float32(plane.shade)
        return out

    def _prepare(self, cam: int) -> _CameraScene:
        rays = self._camera_rays(cam)
        w, h = self._size
        shape = (h, w, 3) if self.colour else (h, w)
        radiance = np.full(shape, _SKY, np.float32)
        depth = np.full((h, w), np.inf, np.float32)
        moving: List[Tuple[_Plane, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for plane in _SCENE:
            origin, ua, va = plane.axes()
            lam, s, t = rays.hit(origin, ua, va)
            if not plane.moving:
                if plane.half_size is not None:
                    hu, hv = plane.half_size
                    lam = np.where((np.abs(s) < hu) & (np.abs(t) < hv), lam, np.inf)
                near = lam < depth
                tex = self._textures[plane.texture]
                cu, cv_ = tex.shape[1] / 2, tex.shape[0] / 2
                img = self._sample(plane, (s / plane.texel + cu).astype(np.float32),
                                   (t / plane.texel + cv_).astype(np.float32))
                np.copyto(radiance, img, where=near[..., None] if self.colour else near)
                np.copyto(depth, lam.astype(np.float32), where=near)
                continue
            hu, hv = plane.half_size  # type: ignore[misc]
            au, av = (abs(a) for a in plane.amplitude)
            reach = (np.abs(s) < hu + au + 1e-9) & (np.abs(t) < hv + av + 1e-9) & np.isfinite(lam)
            moving.append((plane, reach, lam, s, t))
        # Moving planes are drawn over the static scene where they are nearer.
        reach_all = np.zeros((h, w), bool)
        for _, reach, lam, _, _ in moving:
            reach &= lam < depth
            reach_all |= reach
        rows = np.flatnonzero(reach_all.any(axis=1))
        cols = np.flatnonzero(reach_all.any(axis=0))
        if rows.size == 0:
            region = (slice(0, 0), slice(0, 0))
        else:
            region = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
        layers = []
        for plane, reach, lam, s, t in moving:
            r = np.flatnonzero(reach.any(axis=1))
            c = np.flatnonzero(reach.any(axis=0))
            if r.size == 0:
                continue
            box = (slice(int(r[0]), int(r[-1]) + 1), slice(int(c[0]), int(c[-1]) + 1))
            local = (slice(box[0].start - region[0].start, box[0].stop - region[0].start),
                     slice(box[1].start - region[1].start, box[1].stop - region[1].start))
            tex = self._textures[plane.texture]
            layers.append(_Layer(
                plane, local[0], local[1],
                (s[box] / plane.texel).astype(np.float32), (t[box] / plane.texel).astype(np.float32),
                np.where(reach[box], lam[box], np.inf).astype(np.float32),
                (tex.shape[1] / 2, tex.shape[0] / 2),
            ))
        return _CameraScene(radiance, depth, region, layers)

    def _moving_radiance(self, cam: int, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """Float radiance and depth of the camera's moving region at time ``t`` (new arrays)."""
        scene = self._cams[cam]
        rad = scene.static_radiance[scene.region].copy()
        zbuf = scene.static_depth[scene.region].copy()
        for layer in scene.layers:
            plane = layer.plane
            hu, hv = (x / plane.texel for x in plane.half_size)  # type: ignore[union-attr]
            du, dv = (x / plane.texel for x in plane.offset(t))
            sub_z = zbuf[layer.rows, layer.cols]
            hit = (layer.s >= du - hu) & (layer.s < du + hu) & (layer.t >= dv - hv) & (layer.t < dv + hv)
            hit &= layer.depth < sub_z
            if not hit.any():
                continue
            img = self._sample(plane, layer.s - np.float32(du - layer.centre[0]),
                               layer.t - np.float32(dv - layer.centre[1]))
            np.copyto(rad[layer.rows, layer.cols], img, where=hit[..., None] if self.colour else hit)
            np.copyto(sub_z, layer.depth, where=hit)
        return rad, zbuf

    def _radiance(self, cam: int, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """Float radiance (DN at unit gain) and depth of a whole camera image at time ``t``."""
        scene = self._cams[cam]
        rad = scene.static_radiance.copy()
        depth = scene.static_depth.copy()
        rad[scene.region], depth[scene.region] = self._moving_radiance(cam, t)
        return rad, depth

    def _sensor(self, radiance: np.ndarray, cam: int, index: int,
                origin: Tuple[int, int] = (0, 0)) -> np.ndarray:
        """Camera ``cam``'s 10-bit samples (uint16) of ``radiance`` (unflipped, an image whose pixel (0, 0)
        is pixel ``origin`` = (row, column) of the frame): the Bayer filter picks each pixel's colour
        (gray radiance passes as it is), then gain, offset, noise (seeded by ``index``), rounding.

        ``radiance`` is a whole image when there is noise. Without noise the
        stage is pointwise, so the fast path applies it to parts of images.
        Rounds to nearest, ties to even (numpy's rint), clips to 0..1023.
        """
        sensor = self._sensors[cam]
        if radiance.ndim == 3:
            radiance = camera_model.mosaic(radiance, camera_model.shifted_phase(sensor.phase_array, *origin))
        four = np.float32(1 << (camera_spec.RAW_BITS - 8))  # 8-bit DN -> 10-bit samples
        if sensor.noise > 0:
            noise = self._noise_field(cam, index, radiance.shape)
            x = cv2.addWeighted(radiance, four * sensor.scale, noise, four * sensor.noise * sensor.gain,
                                four * sensor.offset)
        else:
            x = radiance * np.float32(four * sensor.scale)
            x += np.float32(four * sensor.offset)
        np.rint(x, out=x)
        np.clip(x, 0, camera_model.RAW_MAX, out=x)
        return x.astype(np.uint16)

    def _noise_field(self, cam: int, index: int, shape: Tuple[int, ...]) -> np.ndarray:
        """Unit Gaussian noise of ``shape`` for frame ``index``: a randomly placed, signed crop of a bank.

        Drawing 2 x 1 M normals per frame would cost 15 ms; crops of one
        bank at random offsets (64 x 64 x 2 signs) are as uncorrelated frame
        to frame as fresh draws (white noise shifted by a nonzero offset).
        """
        w, h = self._size
        if cam not in self._noise_bank:
            bank_rng = np.random.default_rng((self.seed, 0xBA4C, cam))
            bank_shape = (h + 64, w + 64) + ((3,) if self.colour else ())
            self._noise_bank[cam] = bank_rng.standard_normal(bank_shape, dtype=np.float32)
        oy, ox, sign = np.random.default_rng((self.seed, 0x5E5, cam, index)).integers(0, 64, 3)
        crop = self._noise_bank[cam][oy:oy + shape[0], ox:ox + shape[1]]
        if len(shape) == 2 and crop.ndim == 3:
            crop = crop[..., 0]
        crop = -crop if sign & 1 else np.ascontiguousarray(crop)
        if crop.shape != tuple(shape):
            raise ValueError(f"noise for a {shape} image from a rig of frame size {self._size}")
        return crop

    def _sensor_key(self) -> Tuple[Tuple[float, float, str, str], ...]:
        return tuple(s.key for s in self._sensors)

    def _write_rgby(self, out: np.ndarray, cam: int, image: np.ndarray) -> None:
        """Write a camera's ``(H', W', 4)`` RGBY ``image`` into ``out`` (a view of (H', W', 8))."""
        base = 4 * cam
        # mixChannels writes into the view in place: 4x faster than numpy's strided channel copies
        cv2.mixChannels([image], [out], [0, base, 1, base + 1, 2, base + 2, 3, base + 3])

    def _render_fast(self, t: float) -> np.ndarray:
        """Noiseless rendering: the static frame, with only the moving regions (and the demosaic's one pixel
        of reach around them) redone from their new samples."""
        if self._static_frame is None or self._static_key != self._sensor_key():
            w, h = self._size
            frame = np.empty((h, w, 8), np.uint8)
            self._static_raw = []
            for cam in (0, 1):
                raw = self._sensor(self._cams[cam].static_radiance, cam, 0)
                self._static_raw.append(raw)
                self._write_rgby(frame, cam, camera_model.demosaic_camera(raw, self._sensors[cam].phase_ip))
            self._static_frame, self._static_key, self._still = frame, self._sensor_key(), None
        out = self._static_frame.copy()
        h, w = out.shape[:2]
        for cam in (0, 1):
            rows, cols = self._cams[cam].region
            raw = self._static_raw[cam]
            if rows.stop > rows.start:
                raw = raw.copy()
                moving = self._moving_radiance(cam, t)[0]
                raw[rows, cols] = self._sensor(moving, cam, 0, (rows.start, cols.start))
                near = (slice(max(rows.start - 1, 0), min(rows.stop + 1, h)),
                        slice(max(cols.start - 1, 0), min(cols.stop + 1, w)))
                phase = self._sensors[cam].phase_ip
                self._write_rgby(out[near], cam, camera_model.demosaic_window(raw, near[0], near[1], phase))
            self._raw[cam] = raw
        return out

    # -- calibration targets ---------------------------------------------

    def render_plane_views(
        self, pattern_image: np.ndarray, pattern_size_m: Tuple[float, float], pose_R: np.ndarray,
        pose_t: Union[np.ndarray, Sequence[float]], *, background: Union[float, str] = 128.0, t: float = 0.0,
        supersample: int = 2, rgby: bool = False,
    ) -> Tuple[np.ndarray, np.ndarray]:
        """Both cameras' 8-bit gray views of a flat printed target, through the true distortion and Bayer.

        ``pattern_image`` (gray or RGB uint8) is printed over
        ``pattern_size_m = (width, height)`` metres; pattern coordinates are
        x along its columns, y along its rows, z = 0 on the print, origin at
        the image's outer top-left corner (pixel (i, j) covers x in
        [j, j+1] * width/cols). ``pose_R``, ``pose_t`` take pattern points to
        the left camera's frame (``X_left = pose_R @ X + pose_t``, metres),
        like ``cv2.solvePnP``'s rvec/tvec. The right view uses
        :attr:`model`'s R, T. ``background`` is a gray level (0..255) or
        ``"scene"`` (the rig's scene at time ``t``, which may hide the
        target). Each pixel averages ``supersample``\\ :sup:`2` samples (the
        first call at a new supersampling computes those rays: ~0.5 s). The
        gray radiance is sampled as each camera's 10-bit Bayer samples
        (:meth:`set_sensor`'s gain and exposure; unflipped, like the rest of
        this view) and demosaicked by the IP's model: the views are the
        gray (Y) channel of what the IP emits for them, so a calibration sees
        the demosaic's slight blur. Returns new ``(H, W)`` uint8 arrays (left,
        right), or with ``rgby`` the whole ``(H, W, 4)`` R, G, B, Y output of the IP
        (what a live frame of the target carries).
        """
        pattern = np.asarray(pattern_image)
        if pattern.dtype != np.uint8 or pattern.shape[2:] not in ((), (3,)) or pattern.ndim < 2:
            raise ValueError(
                f"pattern_image must be (H, W) or (H, W, 3) uint8, got {pattern.shape} {pattern.dtype}"
            )
        if pattern.ndim == 3:
            pattern = gray_of(pattern)
        pw, ph = (float(x) for x in pattern_size_m)
        if not (pw > 0 and ph > 0):
            raise ValueError(f"pattern_size_m is (width, height) in metres, both > 0; got {pattern_size_m}")
        Rp = np.asarray(pose_R, dtype=np.float64).reshape(3, 3)
        tp = np.asarray(pose_t, dtype=np.float64).reshape(3)
        if abs(np.linalg.det(Rp) - 1.0) > 1e-6 or not np.allclose(Rp.T @ Rp, np.eye(3), atol=1e-6):
            raise ValueError("pose_R must be a rotation matrix (use cv2.Rodrigues on a rotation vector)")
        if not (isinstance(supersample, int) and 1 <= supersample <= 4):
            raise ValueError(f"supersample must be an int from 1 to 4, got {supersample!r}")
        if isinstance(background, str):
            if background != "scene":
                raise ValueError(f"background must be a gray level or 'scene', got {background!r}")
        elif not 0 <= float(background) <= 255:
            raise ValueError(f"background gray level must be in 0..255, got {background}")

        with self._lock:
            if self._closed:
                raise SourceClosedError("this SyntheticRig is closed: make a new one")
            src = pattern.astype(np.float32)
            return self._plane_views(src, (pw, ph), Rp, tp, background, float(t), supersample, rgby)

    def _plane_views(self, src: np.ndarray, size_m: Tuple[float, float], Rp: np.ndarray, tp: np.ndarray,
                     background: Union[float, str], t: float, n: int,
                     rgby: bool = False) -> Tuple[np.ndarray, np.ndarray]:
        rows, cols = src.shape
        pw, ph = size_m
        w, h = self._size
        views = []
        for cam in (0, 1):
            rays = self._camera_rays(cam, n)
            lam, s, tt = rays.hit(tp, Rp[:, 0].copy(), Rp[:, 1].copy())
            mapx = (s * (cols / pw) - 0.5).astype(np.float32)
            mapy = (tt * (rows / ph) - 0.5).astype(np.float32)
            on = np.isfinite(lam) & (mapx > -0.5) & (mapx < cols - 0.5) & (mapy > -0.5) & (mapy < rows - 0.5)
            img = cv2.remap(src, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            if background == "scene":
                scene, depth = self._radiance(cam, t if self.motion else 0.0)
                if scene.ndim == 3:
                    scene = scene @ np.array(_GRAY_FLOAT, np.float32)
                back = np.repeat(np.repeat(scene, n, axis=0), n, axis=1)
                zb = np.repeat(np.repeat(depth, n, axis=0), n, axis=1)
                on &= lam < zb
                img = np.where(on, img, back)
            else:
                img = np.where(on, img, np.float32(background))
            img = img.reshape(h, n, w, n).mean(axis=(1, 3), dtype=np.float32)
            raw = self._sensor(img, cam, 0)
            rgby_ = camera_model.demosaic_camera(raw, self._sensors[cam].phase_ip)
            views.append(np.ascontiguousarray(rgby_ if rgby else rgby_[..., 3]))
        return views[0], views[1]


# --------------------------------------------------------------------------
# Replay
# --------------------------------------------------------------------------

class ReplayError(ValueError):
    """A replay folder that cannot be played: the message names the file and says what to do."""


class ReplayEnded(IndexError):
    """``read`` past the last recorded frame of a ``ReplaySource(loop=False)``."""


_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
_CAPTURE_FILES = ("raw_left.png", "raw_right.png")
# A stereocam recording (server/frames/recordings.py writes it; named here so the emulator needs no server code).
_RECORDING_FILE = "recording.json"
_RECORDING_FORMAT = "stereocam-recording/"
_COUNT_MOD = 1 << 32


def _natural_key(text: str) -> Tuple[object, ...]:
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text.lower()))


@dataclass(frozen=True)
class _Entry:
    """One recorded stereo frame: two files, or one side-by-side file (right is None)."""

    name: str
    left: Path
    right: Optional[Path]
    left_y: Optional[Path] = None  # a recording's Y planes, where Y is not gray_of(RGB)
    right_y: Optional[Path] = None


class ReplaySource:
    """Recorded stereo frames from ``folder``, as a live :class:`CameraSource`.

    The folder holds one kind of recording:

    - pairs ``left<suffix>.<ext>`` / ``right<suffix>.<ext>`` (png, jpg,
      bmp, tif; case-insensitive), matched by suffix, played in natural
      order of the suffix (``left2`` before ``left10``);
    - stereocam captures: subfolders each holding ``raw_left.png`` and
      ``raw_right.png``, played in natural order of the subfolder name;
    - side-by-side images ``sbs<suffix>.<ext>``, left camera in the left half;
    - a stereocam recording: ``recording.json`` and the frames ``frames.jsonl``
      lists (``left_000000.png`` / ``right_000000.png`` ...), played in order.

    Other files are ignored. Gray or colour 8-bit images (colour is RGB
    after decoding; gray fills R, G, B and Y). Frame ``index`` is recording
    ``index % len(self)`` (``loop=True``) or raises :class:`ReplayEnded`
    past the end; ``t`` is ignored, except for a stereocam recording, which
    is played at its own rate whatever the frame clock's: ``read(index, t)``
    gives the frame recorded ``t`` seconds after the first (``t * fps``
    frame periods, by the FRAME_COUNT each frame was recorded with, so a
    frame the recording missed keeps the one before on the stream), looping
    after :attr:`duration_s`; a clock at the recording's :attr:`fps` gets
    every recorded frame once per loop, in order. :meth:`frame` gives
    recorded frame ``k`` whatever the time. The folder is listed and every
    image's header checked when the source is made (a recording's first
    frame only: ``recording.json`` gives its size), so a bad folder fails at
    once with :class:`ReplayError`; pixels are decoded on first use and the
    last ``cache_size`` frames are kept. ``read`` returns a read-only array
    shared with the cache: copy it to modify it. Safe to read from several
    threads.
    """

    def __init__(self, folder: Union[str, Path], *, loop: bool = True, cache_size: int = 8) -> None:
        self.folder = Path(folder)
        self.loop = bool(loop)
        if cache_size < 1:
            raise ValueError(f"cache_size must be >= 1, got {cache_size}")
        self._cache_size = int(cache_size)
        self._cache: "OrderedDict[int, np.ndarray]" = OrderedDict()
        self._lock = threading.Lock()
        self._closed = False
        self.fps: Optional[float] = None  # a recording's frame rate; None for other folders
        self._slots: Optional[List[int]] = None  # a recording's frames, in frame periods from the first
        self._recorded_size: Optional[Tuple[int, int]] = None
        if (self.folder / _RECORDING_FILE).is_file():
            self._entries = self._discover_recording()
        else:
            self._entries = self._discover()
        self._size = self._check_sizes()

    # -- listing -----------------------------------------------------------

    def _discover(self) -> List[_Entry]:
        folder = self.folder
        if not folder.is_dir():
            raise ReplayError(
                f"replay folder {folder} does not exist or is not a folder: give a folder of recordings"
            )
        lefts: Dict[str, Path] = {}
        rights: Dict[str, Path] = {}
        sbs: Dict[str, Path] = {}
        captures: List[_Entry] = []
        for path in sorted(folder.iterdir()):
            if path.name.startswith("."):
                continue  # hidden: e.g. a capture still being written (.incoming-*) or deleted
            if path.is_dir():
                present = [(path / f).is_file() for f in _CAPTURE_FILES]
                if all(present):
                    captures.append(_Entry(path.name, path / _CAPTURE_FILES[0], path / _CAPTURE_FILES[1]))
                elif any(present):
                    have, missing = (_CAPTURE_FILES if present[0] else _CAPTURE_FILES[::-1])
                    raise ReplayError(
                        f"capture {path} has {have} but no {missing}: restore it or remove that folder"
                    )
                continue
            name = path.name.lower()
            if not path.is_file() or path.suffix.lower() not in _IMAGE_EXTS:
                continue
            stem = name[: -len(path.suffix)]
            for prefix, table in (("left", lefts), ("right", rights), ("sbs", sbs)):
                if stem.startswith(prefix):
                    key = stem[len(prefix):]
                    if key in table:
                        raise ReplayError(
                            f"{table[key].name} and {path.name} in {folder} are the same frame in two files: "
                            f"keep one"
                        )
                    table[key] = path
                    break
        found = (("left/right pairs", lefts or rights), ("side-by-side sbs* images", sbs),
                 ("capture folders", captures))
        kinds = [kind for kind, present in found if present]
        if not kinds:
            raise ReplayError(
                f"replay folder {folder} holds no recordings: put left*/right* image pairs, sbs* "
                f"side-by-side images or capture folders (raw_left.png + raw_right.png) in it"
            )
        if len(kinds) > 1:
            raise ReplayError(f"replay folder {folder} mixes {' and '.join(kinds)}: keep one kind per folder")
        if captures:
            return sorted(captures, key=lambda e: _natural_key(e.name))
        if sbs:
            return [_Entry(sbs[k].name, sbs[k], None) for k in sorted(sbs, key=_natural_key)]
        unmatched = sorted([p.name for k, p in lefts.items() if k not in rights]
                           + [p.name for k, p in rights.items() if k not in lefts], key=_natural_key)
        if unmatched:
            more = f" and {len(unmatched) - 5} more" if len(unmatched) > 5 else ""
            shown = ", ".join(unmatched[:5]) + more
            raise ReplayError(
                f"{len(unmatched)} image(s) in {folder} have no partner: {shown}; every left<suffix> needs a "
                f"right<suffix> with the same suffix (e.g. left07.png and right07.png): rename or remove them"
            )
        return [_Entry(f"{lefts[k].name}+{rights[k].name}", lefts[k], rights[k])
                for k in sorted(lefts, key=_natural_key)]

    def _discover_recording(self) -> List[_Entry]:
        """A stereocam recording's frames from its ``recording.json`` and frames file."""
        folder = self.folder

        def bad(what: str) -> ReplayError:
            return ReplayError(f"recording {folder}: {what}; record it again or remove it")

        try:
            doc = json.loads((folder / _RECORDING_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise bad(f"{_RECORDING_FILE} cannot be read ({exc})") from None
        if not isinstance(doc, dict) or not str(doc.get("format", "")).startswith(_RECORDING_FORMAT):
            raise bad(f"{_RECORDING_FILE} is not a stereocam recording's")
        fps, size, count = doc.get("fps"), doc.get("frame_size"), doc.get("frames")
        if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not 0 < fps < 10000:
            raise bad(f"{_RECORDING_FILE} has no valid fps ({fps!r})")
        if not (isinstance(size, list) and len(size) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
            raise bad(f"{_RECORDING_FILE} has no valid frame_size ({size!r})")
        frames_file = folder / str(doc.get("frames_file") or "frames.jsonl")
        entries: List[_Entry] = []
        counts: List[int] = []
        try:
            lines = frames_file.read_text(encoding="utf-8").splitlines()
        except (OSError, ValueError) as exc:
            raise bad(f"{frames_file.name} cannot be read ({exc})") from None

        def member(line: Dict[str, object], key: str) -> Optional[Path]:
            name = line.get(key)
            if name is None:
                return None
            if not isinstance(name, str) or "/" in name or name.startswith("."):
                raise bad(f"{frames_file.name} names a file {name!r} outside the recording")
            return folder / name

        for number, text in enumerate(lines, 1):
            if not text.strip():
                continue
            try:
                line = json.loads(text)
                fabric_count = int(line["fabric_count"])
                left, right = member(line, "left"), member(line, "right")
            except ReplayError:
                raise
            except (ValueError, KeyError, TypeError) as exc:
                raise bad(f"line {number} of {frames_file.name} is damaged ({exc})") from None
            if left is None or right is None:
                raise bad(f"line {number} of {frames_file.name} names no left or right file")
            entries.append(_Entry(left.name, left, right, member(line, "left_y"), member(line, "right_y")))
            counts.append(fabric_count)
        if not entries:
            raise bad("it holds no frames")
        if isinstance(count, int) and count != len(entries):
            raise bad(f"{_RECORDING_FILE} says {count} frames but {frames_file.name} lists {len(entries)}")
        slots = [(c - counts[0]) % _COUNT_MOD for c in counts]
        if any(b <= a for a, b in zip(slots, slots[1:], strict=False)):
            raise bad(f"the FRAME_COUNTs in {frames_file.name} do not increase")
        self.fps = float(fps)
        self._slots = slots
        self._recorded_size = (int(size[0]), int(size[1]))
        return entries

    def _check_sizes(self) -> Tuple[int, int]:
        from PIL import Image, UnidentifiedImageError

        def size_of(path: Path) -> Tuple[int, int]:
            try:
                with Image.open(path) as im:
                    return im.size
            except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
                raise ReplayError(f"cannot read image {path}: {exc}; replace or remove that file") from exc

        first: Optional[Tuple[int, int]] = None
        # A recording: its first frame (recording.json gives the size; every frame is checked on decode).
        entries = self._entries[:1] if self._slots is not None else self._entries
        for entry in entries:
            lw, lh = size_of(entry.left)
            if entry.right is None:
                if lw % 2:
                    raise ReplayError(
                        f"side-by-side image {entry.left} is {lw} pixels wide, an odd number: it must be two "
                        f"equal halves (left camera | right camera)"
                    )
                size = (lw // 2, lh)
            else:
                rs = size_of(entry.right)
                if rs != (lw, lh):
                    raise ReplayError(
                        f"{entry.left.name} is {lw}x{lh} but {entry.right.name} is {rs[0]}x{rs[1]} in "
                        f"{entry.left.parent}: both cameras' images of a frame must have the same size"
                    )
                size = (lw, lh)
            if first is None:
                first = size
            elif size != first:
                raise ReplayError(
                    f"{entry.left} is {size[0]}x{size[1]} per camera but the first frame "
                    f"({self._entries[0].left.name}) is {first[0]}x{first[1]}: every frame of a replay must "
                    f"have the same size; move the odd ones to another folder"
                )
        assert first is not None
        if self._recorded_size is not None and first != self._recorded_size:
            raise ReplayError(
                f"recording {self.folder}: {entries[0].left.name} is {first[0]}x{first[1]} but "
                f"{_RECORDING_FILE} says {self._recorded_size[0]}x{self._recorded_size[1]}; record it again"
            )
        return first

    # -- the CameraSource protocol ---------------------------------------

    @property
    def frame_size(self) -> Tuple[int, int]:
        """``(width, height)`` of one camera's image, from the first recording."""
        return self._size

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def names(self) -> List[str]:
        """The recordings in play order (file names, or capture folder names)."""
        return [e.name for e in self._entries]

    @property
    def is_recording(self) -> bool:
        """Whether the folder is a stereocam recording (played at its :attr:`fps`)."""
        return self._slots is not None

    @property
    def slots(self) -> List[int]:
        """When each frame is played, in frame periods (``1 / fps``) from the first: ``[0, 1, 2, ...]``
        for a recording that missed no frame; ``range(len(self))`` for other folders."""
        return list(self._slots) if self._slots is not None else list(range(len(self._entries)))

    @property
    def duration_s(self) -> Optional[float]:
        """A recording's length (the last frame's slot plus one period) in seconds; None for others."""
        if self._slots is None or self.fps is None:
            return None
        return (self._slots[-1] + 1) / self.fps

    def read(self, index: int, t: float = 0.0) -> np.ndarray:
        """Recorded stereo frame number ``index`` (a recording: the one at ``t`` s), read-only ``(H, W, 8)``.

        See the class doc. Raises :class:`ReplayEnded` past the end without ``loop``, and
        :class:`ReplayError` naming the file if an image cannot be decoded.
        """
        if self._closed:
            raise SourceClosedError(f"the ReplaySource of {self.folder} is closed: make a new one")
        index = int(index)
        if index < 0:
            raise ValueError(f"frame index must be >= 0, got {index}")
        if self._slots is not None and self.fps is not None:
            period = self._slots[-1] + 1
            slot = math.floor(max(0.0, float(t)) * self.fps + 1e-6)
            if slot >= period and not self.loop:
                raise ReplayEnded(f"the recording {self.folder} lasts {period / self.fps:g} s; "
                                  f"t = {t:g} s is past the end")
            return self.frame(bisect.bisect_right(self._slots, slot % period) - 1)
        n = len(self._entries)
        if index >= n and not self.loop:
            raise ReplayEnded(f"the replay of {self.folder} has {n} frames; frame {index} is past the end")
        return self.frame(index % n)

    def frame(self, k: int) -> np.ndarray:
        """Recorded frame ``k`` (0 .. len - 1), read-only ``(H, W, 8)``, whatever the time."""
        if self._closed:
            raise SourceClosedError(f"the ReplaySource of {self.folder} is closed: make a new one")
        n = len(self._entries)
        if not 0 <= int(k) < n:
            raise IndexError(f"frame {k} of a replay of {n} frames")
        slot = int(k)
        with self._lock:
            frame = self._cache.get(slot)
            if frame is not None:
                self._cache.move_to_end(slot)
                return frame
        frame = self._decode(self._entries[slot])
        frame.setflags(write=False)
        with self._lock:
            self._cache[slot] = frame
            self._cache.move_to_end(slot)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return frame

    def close(self) -> None:
        """Drop the cache. Idempotent."""
        self._closed = True
        with self._lock:
            self._cache.clear()

    def __enter__(self) -> "ReplaySource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- decoding ----------------------------------------------------------

    def _load(self, path: Path) -> np.ndarray:
        """An (H, W) gray or (H, W, 3) RGB uint8 image."""
        data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data is not None and data.size else None
        if image is None:
            raise ReplayError(
                f"cannot decode image {path} (missing, truncated or corrupt): replace or remove it"
            )
        if image.dtype != np.uint8:
            raise ReplayError(
                f"image {path} has {image.dtype} pixels; cameras are 8-bit: convert it to 8 bits"
            )
        if image.ndim == 3:
            if image.shape[2] == 1:
                image = image[..., 0]
            elif image.shape[2] == 2:  # gray + alpha
                image = image[..., 0]
            elif image.shape[2] == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
            elif image.shape[2] == 4:
                image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
            else:
                raise ReplayError(f"image {path} has {image.shape[2]} channels: use gray or RGB images")
        return np.ascontiguousarray(image)

    def _decode(self, entry: _Entry) -> np.ndarray:
        w, h = self._size
        left = self._load(entry.left)
        if entry.right is None:
            if left.shape[:2] != (h, 2 * w):
                raise ReplayError(f"{entry.left} changed size since the replay was opened: reopen the folder")
            left, right = left[:, :w], left[:, w:]
        else:
            right = self._load(entry.right)
            for path, img in ((entry.left, left), (entry.right, right)):
                if img.shape[:2] != (h, w):
                    raise ReplayError(f"{path} changed size since the replay was opened: reopen the folder")
        if left.ndim != right.ndim:  # one gray, one colour: both as RGB
            left, right = (np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x for x in (left, right))
        sides = [rgby(np.ascontiguousarray(left)), rgby(np.ascontiguousarray(right))]
        for side, y_path in zip(sides, (entry.left_y, entry.right_y), strict=True):
            if y_path is not None:
                y = self._load(y_path)
                if y.ndim != 2 or y.shape != side.shape[:2]:
                    raise ReplayError(f"{y_path} is not a gray image of its frame's size: replace or "
                                      f"remove it")
                side[..., 3] = y
        return pack(sides[0], sides[1])
