"""The synthetic rig: a stereo pair of known calibration ray-tracing its scene through Bayer sensors.

:class:`SyntheticRig` ray-traces the scene (:mod:`.scene`) through the TRUE
camera model (pinhole + Brown-Conrady k1, k2, p1, p2, and the stereo pose of
:attr:`SyntheticRig.model`, :mod:`.lens`): rectifying its frames with that
model gives rectified frames, and a calibration computed from
:meth:`SyntheticRig.render_plane_views` must give that model back. Like the
board's MT9V034s, each camera samples the scene through a Bayer filter into
10-bit samples (:attr:`SyntheticRig.raw` keeps the last ones), and the frame
is what the camera input IP makes of them (:mod:`..model.camera_in`, the
model the RTL is bit-exact to).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from ...calibration.stereo import StereoModel
from ..model import camera_in as camera_model
from ..spec import camera_in as camera_spec
from ..spec.pixel import gray_of
from .cameras import SourceClosedError
from .lens import BASE_SIZE, Rays, rig_model
from .scene import LOOKS, SCENE, SKY, Plane, bake_texture

__all__ = ["SyntheticRig"]

_GRAY_FLOAT = (77 / 256, 150 / 256, 29 / 256)  # gray of float radiance (pixel.GRAY_WEIGHTS / 256)


@dataclass
class _Layer:
    """One moving plane as seen by one camera, cropped to the pixels it can ever cover."""

    plane: Plane
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
        self, *, size: Tuple[int, int] = BASE_SIZE, model: Optional[StereoModel] = None, motion: bool = True,
        seed: int = 0, colour: bool = True, noise: float = 0.0,
    ) -> None:
        if model is None:
            model = rig_model(size)
        elif tuple(size) != BASE_SIZE and tuple(size) != tuple(model.image_size):
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
        self._textures = [bake_texture(rng, look, channels) for look in LOOKS]

        R = np.asarray(model.R, dtype=np.float64)
        T = np.asarray(model.T, dtype=np.float64)
        self._poses = ((np.eye(3), np.zeros(3)), (R, -R.T @ T))  # (R_cam, centre in the left frame)
        self._pixel_grid: Dict[int, Tuple[np.ndarray, np.ndarray]] = {}
        self._noise_bank: Dict[int, np.ndarray] = {}
        self._rays: Dict[Tuple[int, int], Rays] = {}  # (camera, supersample) -> rays
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

    def _camera_rays(self, cam: int, supersample: int = 1) -> Rays:
        key = (cam, supersample)
        if key not in self._rays:
            K, D = (self.model.K1, self.model.D1) if cam == 0 else (self.model.K2, self.model.D2)
            R_cam, centre = self._poses[cam]
            u, v = self._grid(supersample)
            self._rays[key] = Rays.of(K, D, R_cam, centre, u, v)
        return self._rays[key]

    def _sample(self, plane: Plane, mapx: np.ndarray, mapy: np.ndarray) -> np.ndarray:
        tex = self._textures[plane.texture]
        out = cv2.remap(tex, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        if plane.shade != 1.0:
            out *= np.float32(plane.shade)
        return out

    def _prepare(self, cam: int) -> _CameraScene:
        rays = self._camera_rays(cam)
        w, h = self._size
        shape = (h, w, 3) if self.colour else (h, w)
        radiance = np.full(shape, SKY, np.float32)
        depth = np.full((h, w), np.inf, np.float32)
        moving: List[Tuple[Plane, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for plane in SCENE:
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
