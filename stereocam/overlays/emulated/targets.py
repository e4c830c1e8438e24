"""Emulated calibration targets: a checkerboard held in front of the synthetic rig.

The daemon's calibration panel needs cameras that see a checkerboard in
many poses, with a known true calibration to compare the result with.
:class:`CheckerboardTarget` is that camera source: the
:class:`.render.SyntheticRig`'s scene with a printed board held still in
front of it, moved to a new random pose every ``hold_s`` seconds.

:func:`board_image` is the printed board, :func:`random_board_poses` the
poses (random tilt, 0.35 to 0.7 m away, anywhere in the image, the whole
print inside both images); the tests' synthetic calibration views use both.

Board coordinates (what :meth:`.render.SyntheticRig.render_plane_views`
takes): metres, x along the print's columns, y along its rows, z = 0 on the
print, origin at the print's outer top-left corner. The print is a
``cols`` x ``rows`` inner-corner checkerboard with a one-square white
margin, so inner corner ``(row r, column c)`` is at
``((c + 2) * square, (r + 2) * square)``.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ...calibration.stereo import StereoModel
from ..spec.pixel import pack
from .cameras import SourceClosedError
from .render import SyntheticRig

__all__ = [
    "CheckerboardTarget",
    "board_corners",
    "board_image",
    "board_size_m",
    "random_board_poses",
]

Pose = Tuple[np.ndarray, np.ndarray]  # (R (3, 3), t (3,)): board coordinates -> the left camera's frame


def _check_pattern(pattern: Sequence[int], least: int = 1) -> Tuple[int, int]:
    if len(pattern) != 2:
        raise ValueError(f"pattern is (cols, rows) inner corners, got {tuple(pattern)}")
    cols, rows = (int(x) for x in pattern)
    if (cols, rows) != tuple(pattern) or cols < least or rows < least:
        raise ValueError(
            f"pattern is (cols, rows) inner corners, whole numbers >= {least}, got {tuple(pattern)}"
        )
    return cols, rows


def _check_square(square: float) -> float:
    square = float(square)
    if not (math.isfinite(square) and square > 0):
        raise ValueError(f"square is the checker square's side in metres (> 0), got {square}")
    return square


def board_image(cols: int = 9, rows: int = 6, px: int = 40) -> np.ndarray:
    """The printed board: ``cols`` x ``rows`` inner corners, a one-square white margin, (H, W) uint8.

    ``px`` pixels per square; the top-left square inside the margin is black.
    """
    cols, rows = _check_pattern((cols, rows))
    if int(px) != px or px < 1:
        raise ValueError(f"px is pixels per square, a whole number >= 1, got {px}")
    px = int(px)
    board = np.full(((rows + 3) * px, (cols + 3) * px), 255, np.uint8)
    for i in range(rows + 1):
        for j in range(cols + 1):
            if (i + j) % 2 == 0:
                board[(i + 1) * px:(i + 2) * px, (j + 1) * px:(j + 2) * px] = 0
    return board


def board_size_m(pattern: Sequence[int] = (9, 6), square: float = 0.03) -> Tuple[float, float]:
    """``(width, height)`` of the print in metres, margin included: ``(cols + 3, rows + 3)`` squares."""
    cols, rows = _check_pattern(pattern)
    square = _check_square(square)
    return (cols + 3) * square, (rows + 3) * square


def board_corners(pattern: Sequence[int] = (9, 6), square: float = 0.03) -> np.ndarray:
    """The inner corners in board coordinates, ``(cols * rows, 3)`` float64, row by row.

    The order of ``stereocam.calibration.calibrate.Pattern.object_points``, shifted by
    the margin and the first square (``(2, 2)`` squares).
    """
    cols, rows = _check_pattern(pattern)
    square = _check_square(square)
    return np.array([[(c + 2) * square, (r + 2) * square, 0.0] for r in range(rows) for c in range(cols)])


def random_board_poses(
    model: StereoModel, pattern: Sequence[int] = (9, 6), square: float = 0.03, *, n: int,
    rng: np.random.Generator, distance: Tuple[float, float] = (0.35, 0.7), tilt: float = 0.6,
    roll: float = 0.3, margin: float = 4.0, max_tries: int = 1000,
) -> List[Pose]:
    """``n`` random poses of the printed board that both cameras of ``model`` see whole.

    Like a person holding the board up to a rig: a rotation vector of up to
    ``tilt`` radians about x and y each and ``roll`` about z (0.6 rad: up to
    ~35 deg), the print's centre on the ray of a random pixel in the middle
    60 % of the left image, ``distance`` metres along it. A pose is kept
    only when the print's four outer corners project at least ``margin``
    pixels inside both images (through the true distortion); each pose is
    drawn from ``rng`` in that order, so a seed gives the same poses.
    Returns ``(R, t)`` pairs taking board coordinates to the left camera's
    frame (``render_plane_views``' ``pose_R``, ``pose_t``). Raises
    ``ValueError`` if ``max_tries`` draws in a row give no pose (the board
    is too big for the images at that distance).
    """
    if int(n) != n or n < 0:
        raise ValueError(f"n is how many poses, a whole number >= 0, got {n}")
    near, far = (float(d) for d in distance)
    if not (math.isfinite(far) and 0 < near <= far):
        raise ValueError(
            f"distance is (nearest, farthest) in metres, 0 < nearest <= farthest, got {distance}"
        )
    if not (0 <= tilt <= math.pi / 2 and 0 <= roll <= math.pi):
        raise ValueError(f"tilt must be in 0..pi/2 and roll in 0..pi radians, got {tilt}, {roll}")
    if max_tries < 1:
        raise ValueError(f"max_tries must be >= 1, got {max_tries}")
    width, height = board_size_m(pattern, square)
    outline = np.array([[0, 0, 0], [width, 0, 0], [width, height, 0], [0, height, 0]], float)
    centre = np.array([width / 2, height / 2, 0.0])
    w, h = model.image_size
    low, high = float(margin), np.array([w, h], dtype=np.float64) - 1.0 - float(margin)
    K1_inv = np.linalg.inv(model.K1)
    poses: List[Pose] = []
    tries = 0
    while len(poses) < n:
        if tries == max_tries:
            raise ValueError(
                f"no pose of a {width:.3f} x {height:.3f} m board {near}..{far} m away fits in both "
                f"{w}x{h} images in {max_tries} tries: use smaller squares or a larger distance"
            )
        tries += 1
        rvec = np.array([rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-roll, roll)])
        R, _ = cv2.Rodrigues(rvec)
        ray = K1_inv @ np.array([rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h, 1.0])
        t = ray * rng.uniform(near, far) - R @ centre
        inside = True
        right = (model.R @ R, model.R @ t + model.T)
        for K, D, (Rc, tc) in ((model.K1, model.D1, (R, t)), (model.K2, model.D2, right)):
            p = cv2.projectPoints(outline, cv2.Rodrigues(Rc)[0], tc, K, D)[0].reshape(-1, 2)
            inside &= bool(np.all((p > low) & (p < high)))
        if inside:
            poses.append((R, t))
            tries = 0
    return poses


class CheckerboardTarget:
    """The synthetic rig's cameras watching a person hold a checkerboard up to them, pose after pose.

    A :class:`.cameras.CameraSource`: each frame is ``rig``'s scene (the
    default :class:`.render.SyntheticRig`) as background with a printed
    ``pattern`` = (cols, rows) inner-corner board of ``square``-metre
    squares in front, gray (R = G = B = Y). The board holds still for
    ``hold_s`` seconds of the frame clock's ``t``, then jumps to the next
    pose of an endless seeded sequence (:meth:`pose`, from
    :func:`random_board_poses`); the background is the scene at the start
    of the hold. :attr:`model` is the rig's true calibration, which a
    calibration from these frames must give back.

    Each pose is rendered once (:meth:`.render.SyntheticRig.render_plane_views`,
    ``supersample`` x ``supersample`` samples a pixel) and cached with the
    sensor settings, so steady frames cost a copy (~1 ms at 752 x 480).
    Rendering a pose at 752 x 480 takes ~120 ms with ``supersample=2``
    (the default: corners found within 0.2 px of the model's projection;
    at 60 fps the frame clock skips ~7 frames when the pose changes) and
    ~45 ms with 1 (corners off by up to 0.45 px: too rough to check a
    calibration against); the first render also traces the rays (~0.8 s).
    :meth:`set_sensor` is forwarded to the rig (as the emulated MT9V034s
    call it): a new exposure or gain renders the pose again, flips and test
    patterns apply to every frame read. Read noise, if the rig has any, is
    drawn once per pose and sensor setting. Set the sensors through the
    target, not the rig. :meth:`pose_index` says which pose a time shows.

    ``read`` returns a new, writable frame owned by the caller. Calls from
    several threads are safe (they are serialised). ``close()`` closes the
    rig too.
    """

    _CACHE_SIZE = 4  # renders kept: the pose shown and a few sensor settings (AEC steps back and forth)

    def __init__(
        self, rig: Optional[SyntheticRig] = None, *, pattern: Tuple[int, int] = (9, 6), square: float = 0.025,
        hold_s: float = 1.5, seed: int = 0, supersample: int = 2,
    ) -> None:
        self.pattern: Tuple[int, int] = _check_pattern(pattern, least=3)
        self.square = _check_square(square)
        hold_s = float(hold_s)
        if not (math.isfinite(hold_s) and hold_s > 0):
            raise ValueError(f"hold_s is how long each pose is held, in seconds (> 0), got {hold_s}")
        self.hold_s = hold_s
        if not (isinstance(supersample, int) and 1 <= supersample <= 4):
            raise ValueError(f"supersample must be an int from 1 to 4, got {supersample!r}")
        self.supersample = supersample
        if int(seed) != seed or seed < 0:
            raise ValueError(f"seed must be a whole number >= 0, got {seed!r}")
        self.seed = int(seed)
        if rig is not None and not isinstance(rig, SyntheticRig):
            raise ValueError(f"rig must be a SyntheticRig, got {type(rig).__name__}")
        self._rig = rig if rig is not None else SyntheticRig()
        self._board = board_image(*self.pattern)
        self._size_m = board_size_m(self.pattern, self.square)
        try:
            self.pose(0)  # fails now, not on the clock thread, if the board fits nowhere
        except ValueError:
            if rig is None:
                self._rig.close()
            raise
        self._lock = threading.Lock()
        self._closed = False
        self._cache: "OrderedDict[Tuple[object, ...], np.ndarray]" = OrderedDict()

    # -- what is shown ---------------------------------------------------

    @property
    def model(self) -> StereoModel:
        """The rig's true calibration (K in pixels, T in metres)."""
        return self._rig.model

    @property
    def rig(self) -> SyntheticRig:
        """The wrapped rig (its scene is the background)."""
        return self._rig

    def pose_index(self, t: float) -> int:
        """Which pose is shown at ``t`` seconds (>= 0): ``floor(t / hold_s)``."""
        t = float(t)
        if not (math.isfinite(t) and t >= 0):
            raise ValueError(f"time must be finite and >= 0 seconds, got {t}")
        return int(math.floor(t / self.hold_s))

    def pose(self, index: int) -> Pose:
        """Pose ``index`` (>= 0) as ``(R, t)``: board coordinates to the left camera's frame (metres).

        Drawn by :func:`random_board_poses` from a generator seeded with
        ``(seed, index)``, so any pose is found without the ones before it.
        """
        if int(index) != index or index < 0:
            raise ValueError(f"pose index must be a whole number >= 0, got {index!r}")
        rng = np.random.default_rng((self.seed, int(index)))
        return random_board_poses(self.model, self.pattern, self.square, n=1, rng=rng)[0]

    # -- the CameraSource protocol ---------------------------------------

    @property
    def frame_size(self) -> Tuple[int, int]:
        """``(width, height)`` of the frames."""
        return self._rig.frame_size

    def read(self, index: int, t: float) -> np.ndarray:
        """Stereo frame ``index`` at ``t`` seconds: a new ``(H, W, 8)`` uint8 array owned by the caller.

        The board in pose :meth:`pose_index` ``(t)``; blocks for the
        rendering when that pose (or the sensor setting) is new.
        """
        index = int(index)
        if index < 0:
            raise ValueError(f"frame index must be >= 0, got {index}")
        k = self.pose_index(t)
        with self._lock:
            if self._closed:
                raise SourceClosedError("this CheckerboardTarget is closed: make a new one")
            rig = self._rig
            # The rig's sensor stage (gain x exposure, offset, noise) is in the render; flips and
            # test patterns are its readout, applied to every frame below.
            key = (k, rig._sensor_key(), tuple(s.noise for s in rig._sensors))
            frame = self._cache.get(key)
            if frame is None:
                R, tp = self.pose(k)
                left, right = rig.render_plane_views(
                    self._board, self._size_m, R, tp, background="scene", t=k * self.hold_s,
                    supersample=self.supersample, rgby=True,
                )
                frame = pack(left, right)  # the camera input's R, G, B and Y for the target's Bayer samples
                self._cache[key] = frame
                while len(self._cache) > self._CACHE_SIZE:
                    self._cache.popitem(last=False)
            else:
                self._cache.move_to_end(key)
            return rig._readout(frame.copy())

    def set_sensor(
        self, camera: int, *, gain: float = 1.0, exposure_scale: float = 1.0, flip_h: bool = False,
        flip_v: bool = False, test_pattern: Optional[np.ndarray] = None, noise: Optional[float] = None,
    ) -> None:
        """Set camera ``camera``'s sensor stage: :meth:`.render.SyntheticRig.set_sensor`."""
        with self._lock:
            self._rig.set_sensor(camera, gain=gain, exposure_scale=exposure_scale, flip_h=flip_h,
                                 flip_v=flip_v, test_pattern=test_pattern, noise=noise)

    def close(self) -> None:
        """Drop the cache and close the rig. Idempotent."""
        with self._lock:
            self._closed = True
            self._cache.clear()
        self._rig.close()

    def __enter__(self) -> "CheckerboardTarget":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
