"""The synthetic rig's scene: textured planes in the left camera's frame, and how their textures are baked.

The scene (x right, y down, z forward, metres): a back wall about 3 m away
turned 14 deg, a floor 1.1 m below the cameras, a frontal "box face" sliding
sideways and a slanted board sliding within its own plane. Radiance is in
8-bit DN at unit sensor gain.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from .lens import rotation

__all__ = ["LOOKS", "SCENE", "SKY", "Look", "Plane", "bake_texture"]


@dataclass(frozen=True)
class Plane:
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
        rot = rotation(*self.angles)
        return np.array(self.origin, dtype=np.float64), rot[:, 0].copy(), rot[:, 1].copy()

    @property
    def moving(self) -> bool:
        return self.half_size is not None and any(a != 0.0 for a in self.amplitude)

    def offset(self, t: float) -> Tuple[float, float]:
        (au, av), (pu, pv), (qu, qv) = self.amplitude, self.period, self.phase
        return au * math.sin(2.0 * math.pi * t / pu + qu), av * math.sin(2.0 * math.pi * t / pv + qv)


# Textures: index 0 wall, 1 floor, 2 box face, 3 slanted board.
SCENE: Tuple[Plane, ...] = (
    Plane("wall", (0.0, 0.0, 3.0), (14.0, 0.0, 0.0), texel=0.008, texture=0),
    Plane("floor", (0.0, 1.1, 2.0), (0.0, 90.0, 0.0), texel=0.010, texture=1, shade=0.8),
    Plane("box", (-0.12, 0.06, 1.0), (0.0, 0.0, 0.0), texel=0.002, texture=2, half_size=(0.22, 0.17),
           amplitude=(0.25, 0.0), period=(7.0, 1.0)),
    Plane("board", (0.34, -0.14, 1.45), (-35.0, 12.0, 4.0), texel=0.003, texture=3, half_size=(0.25, 0.30),
           shade=0.92, amplitude=(0.06, 0.12), period=(13.0, 9.0), phase=(0.7, 0.0)),
)
@dataclass(frozen=True)
class Look:
    """How one texture is baked: size in texels, colour tint, checker and ring periods in texels."""

    size: int
    tint: Tuple[float, float, float]
    checker: int
    rings: float
    contrast: float = 1.0


LOOKS = (  # wall, floor, box face, slanted board
    Look(1024, (1.00, 0.95, 0.85), checker=32, rings=41.0),
    Look(1024, (0.80, 0.88, 1.00), checker=50, rings=97.0, contrast=0.8),
    Look(512, (1.15, 0.80, 0.70), checker=12, rings=17.0, contrast=1.2),
    Look(512, (0.80, 1.10, 0.85), checker=20, rings=29.0, contrast=1.1),
)
SKY = 40.0  # radiance where a ray hits nothing


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


def bake_texture(rng: np.random.Generator, look: Look, channels: int) -> np.ndarray:
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

