"""Stereo calibration from checkerboard pairs, with figures measured through the core.

The steps, as pure functions a daemon can call in a worker thread:

1. :func:`find_pairs` / :func:`pairs_from_files`: the image pairs to use
   (stereocam capture folders holding ``raw_left.png`` and ``raw_right.png``,
   folders of such captures, folders of ``left*``/``right*`` images, or two
   lists of files paired in order).
2. :func:`calibrate_pairs`: for each pair, checkerboard corners found and
   refined to sub-pixel (``findChessboardCorners`` + ``cornerSubPix``); each
   camera calibrated alone and then both together (``stereoCalibrate``) with
   the core's lens model, k1, k2, p1, p2 (k3 fixed at 0); pairs whose
   reprojection error is far above the others dropped (once); stereo
   rectification (each camera rotated half way, zero disparity at
   infinity, the user's alpha); everything folded into the core's register
   values (:class:`~.file.Calibration`); and the figures of the
   :class:`CalibrationReport`.

The rectified row error is measured through the core's own mapping, not
OpenCV's: each detected raw corner is carried to the rectified position
whose core source position (steps 1-4 of ``stereocam/overlays/RECTIFY_CORE.md``, the
real-number mapping of :mod:`~stereocam.overlays.model.ideal` that the fixed-point
core approximates) is that corner, by Newton's method started from
``cv2.undistortPoints``; the forward mapping used is checked against the
core's fixed-point positions (:func:`~stereocam.overlays.model.reference.source_position`)
at the nearest output pixels, within their 1/32 pixel. ``row_error`` is then ``|y_left - y_right|`` of
corresponding corners: 0 for a perfect calibration and detector.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from ..overlays.model.ideal import ideal_positions
from ..overlays.model.reference import source_position
from ..overlays.spec.rectify import (
    DEFAULT_LB_ROWS,
    DEFAULT_MAX_HEIGHT,
    DEFAULT_MAX_WIDTH,
    FRAC_ONE,
    CameraParams,
)
from .file import Calibration
from .image_files import CAPTURE_FILES, ImageTooLarge, decode_image_file, is_image_file, natural_key
from .stereo import StereoModel, rectify

MIN_PAIRS = 5
# A pair is dropped when its RMS error exceeds both of these: corners misdetected, or the board moved.
OUTLIER_PX = 2.0
OUTLIER_FACTOR = 4.0

Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``: stage is "detect", "calibrate" or "check"."""


class CalibrationError(ValueError):
    """Calibration cannot go on; the message says what to change."""


class CalibrationInputError(CalibrationError):
    """An input that cannot be used: missing, unreadable, or of the wrong size."""


class NotEnoughPairs(CalibrationError):
    """Too few pairs in which both cameras show the whole pattern."""


# --------------------------------------------------------------------------
# Pattern and lengths
# --------------------------------------------------------------------------

_LENGTH_UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}


def parse_pattern(text: str) -> Tuple[int, int]:
    """``"9x6"`` -> (9, 6): inner corners per row and per column."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise CalibrationError(f"pattern {text!r}: give inner corners as COLSxROWS, e.g. 9x6")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 3 or rows < 3:
        raise CalibrationError(f"pattern {text!r}: a checkerboard needs at least 3x3 inner corners")
    return cols, rows


def parse_length(text: str) -> float:
    """``"25mm"``, ``"2.5 cm"``, ``"0.025m"``, ``"1in"`` -> metres."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zA-Z]*)\s*", text)
    if not m:
        raise CalibrationError(f"square size {text!r}: give a length with its unit, e.g. 25mm")
    unit = m.group(2).lower()
    if unit not in _LENGTH_UNITS:
        raise CalibrationError(f"square size {text!r}: give the unit ({', '.join(_LENGTH_UNITS)}), e.g. 25mm")
    value = float(m.group(1)) * _LENGTH_UNITS[unit]
    if not value > 0:
        raise CalibrationError(f"square size {text!r} must be more than 0")
    if not math.isfinite(value):
        raise CalibrationError(f"square size {text!r} is not a finite length")
    return value


@dataclass(frozen=True)
class Pattern:
    """A checkerboard: ``cols`` x ``rows`` inner corners, squares of ``square`` metres."""

    cols: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CalibrationError(
                f"a checkerboard needs at least 3x3 inner corners, not {self.cols}x{self.rows}"
            )
        if not (self.square > 0 and math.isfinite(self.square)):
            raise CalibrationError(f"square size must be more than 0 metres, not {self.square}")

    @classmethod
    def parse(cls, pattern: str, square: str) -> "Pattern":
        cols, rows = parse_pattern(pattern)
        return cls(cols, rows, parse_length(square))

    @property
    def size(self) -> Tuple[int, int]:
        return self.cols, self.rows

    def __str__(self) -> str:
        return f"{self.cols}x{self.rows}"

    def object_points(self) -> np.ndarray:
        """(cols*rows, 3) float32 corner positions in metres, row by row, z = 0."""
        obj = np.zeros((self.rows * self.cols, 3), np.float32)
        obj[:, :2] = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2) * self.square
        return obj


# --------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------

ImageLike = Union[Path, np.ndarray]


@dataclass(frozen=True)
class ImagePair:
    """One stereo view: two files, or two arrays (gray, or RGB as the daemon holds them)."""

    name: str
    left: ImageLike = field(repr=False)
    right: ImageLike = field(repr=False)

    def load(self) -> Tuple[np.ndarray, np.ndarray]:
        """Both images as (H, W) uint8 gray.

        Raises :class:`CalibrationInputError` if one is unreadable or they differ in size.
        """
        left, right = _gray(self.left, f"{self.name} left"), _gray(self.right, f"{self.name} right")
        if left.shape != right.shape:
            raise CalibrationInputError(
                f"pair {self.name}: left is {left.shape[1]}x{left.shape[0]} but right is "
                f"{right.shape[1]}x{right.shape[0]}: both cameras' images must have the same size"
            )
        return left, right


def _gray(image: ImageLike, what: str) -> np.ndarray:
    if isinstance(image, np.ndarray):
        if (
            image.dtype != np.uint8
            or image.ndim not in (2, 3)
            or (image.ndim == 3 and image.shape[2] not in (1, 3, 4))
        ):
            raise CalibrationInputError(
                f"{what}: expected an (H, W) or (H, W, 3) uint8 image, got {image.shape} {image.dtype}"
            )
        if image.ndim == 2:
            return image
        if image.shape[2] == 1:
            return np.ascontiguousarray(image[..., 0])
        code = cv2.COLOR_RGB2GRAY if image.shape[2] == 3 else cv2.COLOR_RGBA2GRAY
        return cv2.cvtColor(np.ascontiguousarray(image), code)
    path = Path(image)
    if not path.is_file():
        raise CalibrationInputError(f"{path}: no such file")
    try:
        gray = decode_image_file(path, cv2.IMREAD_GRAYSCALE)
    except ImageTooLarge as exc:
        raise CalibrationInputError(f"{exc}: replace it or leave that pair out") from None
    if gray is None:
        raise CalibrationInputError(
            f"{path}: not a readable image (missing, truncated or corrupt): replace it or leave that pair out"
        )
    return gray


def _is_capture(folder: Path) -> bool:
    return all((folder / f).is_file() for f in CAPTURE_FILES)


def _image_pairs_in(folder: Path) -> List[ImagePair]:
    """``left<suffix>.<ext>`` / ``right<suffix>.<ext>`` files of one folder, matched by suffix."""
    sides: Dict[str, Dict[str, Path]] = {"left": {}, "right": {}}
    for p in folder.iterdir():
        if not is_image_file(p):
            continue
        stem = p.stem.lower()
        for side in sides:
            if stem.startswith(side):
                sides[side][stem[len(side) :]] = p
    lonely = sorted(set(sides["left"]) ^ set(sides["right"]), key=natural_key)
    if lonely:
        k = lonely[0]
        have = sides["left"].get(k) or sides["right"][k]
        other = "right" if k in sides["left"] else "left"
        raise CalibrationInputError(f"{have} has no {other}{k}.* beside it: give both images of every pair")
    return [
        ImagePair(sides["left"][k].name, sides["left"][k], sides["right"][k])
        for k in sorted(sides["left"], key=natural_key)
    ]


def find_pairs(inputs: Sequence[Union[str, Path]]) -> List[ImagePair]:
    """Image pairs from capture folders, folders of captures, or folders of left*/right* images.

    A folder holding ``raw_left.png`` and ``raw_right.png`` is one pair
    (named after the folder); otherwise its subfolders that do are pairs, in
    natural order; otherwise its ``left*``/``right*`` images matched by
    suffix. Hidden folders and files (a capture store's unfinished captures)
    are skipped. Raises :class:`CalibrationInputError` naming what is missing.
    """
    pairs: List[ImagePair] = []
    if not inputs:
        raise CalibrationInputError(
            "no inputs: give capture folders, or image files with --left ... --right ..."
        )
    for item in inputs:
        path = Path(item)
        if not path.exists():
            raise CalibrationInputError(f"{path}: no such file or folder")
        if path.is_file():
            raise CalibrationInputError(
                f"{path} is a file: give capture folders, "
                "or image files with --left FILES... --right FILES..."
            )
        if _is_capture(path):
            pairs.append(ImagePair(path.name, path / CAPTURE_FILES[0], path / CAPTURE_FILES[1]))
            continue
        # Hidden folders are the capture store's unfinished or deleted captures.
        subs = sorted(
            (d for d in path.iterdir() if d.is_dir() and not d.name.startswith(".")),
            key=lambda d: natural_key(d.name),
        )
        found = [d for d in subs if _is_capture(d)]
        for d in subs:
            halves = [(d / f).is_file() for f in CAPTURE_FILES]
            if any(halves) and not all(halves):
                missing = CAPTURE_FILES[halves.index(False)]
                raise CalibrationInputError(
                    f"capture {d} has no {missing}: remove that folder or capture again"
                )
        if found:
            pairs += [ImagePair(d.name, d / CAPTURE_FILES[0], d / CAPTURE_FILES[1]) for d in found]
            continue
        images = _image_pairs_in(path)
        if not images:
            raise CalibrationInputError(
                f"{path}: no captures (folders holding {' and '.join(CAPTURE_FILES)}) "
                "and no left*/right* images"
            )
        pairs += images
    return pairs


def pairs_from_files(
    lefts: Sequence[Union[str, Path]], rights: Sequence[Union[str, Path]]
) -> List[ImagePair]:
    """Pairs of image files given in order (``--left FILES... --right FILES...``)."""
    if len(lefts) != len(rights):
        raise CalibrationInputError(
            f"{len(lefts)} left images but {len(rights)} right images: --left and --right pair files in order"
        )
    if not lefts:
        raise CalibrationInputError("no images: give --left FILES... --right FILES...")
    return [ImagePair(Path(a).name, Path(a), Path(b)) for a, b in zip(lefts, rights, strict=True)]


# --------------------------------------------------------------------------
# Corners
# --------------------------------------------------------------------------

SUBPIX_WINDOW_FRACTION = 0.35
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)


def detect_corners(gray: np.ndarray, pattern: Pattern, *, thorough: bool = True) -> Optional[np.ndarray]:
    """Sub-pixel inner corners ((cols*rows, 2) float64, row by row) of the pattern in a gray image, or None.

    ``findChessboardCorners``, or ``findChessboardCornersSB`` where it finds
    nothing and ``thorough`` (the slower detector: leave it out for a live
    preview, where a miss costs nothing but a frame).

    ``cornerSubPix``'s half window is 0.35 of the shortest distance between
    neighbouring corners (along rows, columns and diagonals), at most 11 (OpenCV's
    stereo_calib uses 11 always): a window reaching the edges around the next
    corner pulls a corner of an oblique view by pixels. On OpenCV's sample
    this lowers the stereo RMS from 0.44 to 0.20 px.
    """
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(gray, pattern.size, flags=flags)
    if (not found or corners is None) and not thorough:
        return None
    if not found or corners is None:
        # The sector-based detector finds small, oblique boards the classic one misses (OpenCV 4.5).
        found, corners = cv2.findChessboardCornersSB(gray, pattern.size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found or corners is None:
            return None
    grid = corners.reshape(pattern.rows, pattern.cols, 2).astype(np.float64)
    spacing = min(
        np.linalg.norm(grid[:, 1:] - grid[:, :-1], axis=2).min(),
        np.linalg.norm(grid[1:, :] - grid[:-1, :], axis=2).min(),
        np.linalg.norm(grid[1:, 1:] - grid[:-1, :-1], axis=2).min(),
        np.linalg.norm(grid[1:, :-1] - grid[:-1, 1:], axis=2).min(),
    )
    win = int(np.clip(math.floor(spacing * SUBPIX_WINDOW_FRACTION), 3, 11))
    refined = cv2.cornerSubPix(gray, corners.astype(np.float32), (win, win), (-1, -1), _SUBPIX_CRITERIA)
    return refined.reshape(-1, 2).astype(np.float64)


def _same_order(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``right``'s corners in the same order as ``left``'s (the detector may start from the other end)."""
    if float(np.dot(left[-1] - left[0], right[-1] - right[0])) < 0:
        return right[::-1].copy()
    return right


# --------------------------------------------------------------------------
# The core's mapping and its inverse
# --------------------------------------------------------------------------


def core_source(p: CameraParams, x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The core's source position (pixels) of output positions (x, y), in real numbers.

    Continuous in (x, y) (:func:`~stereocam.overlays.model.ideal.ideal_positions`), for
    Newton's method; at integer pixels the core's fixed-point ``iu`` is
    ``rint(32 * u)`` or next to it. NaN where the homography maps to infinity.
    """
    return ideal_positions(p, x, y)


def _check_against_reference(p: CameraParams, x: np.ndarray, y: np.ndarray, size: Tuple[int, int]) -> None:
    """:func:`core_source` must be within 1/32 pixel of the core's positions at these output pixels."""
    xi = np.rint(x).astype(np.int64)
    yi = np.rint(y).astype(np.int64)
    u, v = core_source(p, xi.astype(np.float64), yi.astype(np.float64))
    for k in range(xi.size):
        ref = source_position(p, int(xi[k]), int(yi[k]), *size)
        mine = (int(np.rint(u[k] * FRAC_ONE)), int(np.rint(v[k] * FRAC_ONE)))
        if ref is not None and max(abs(ref[0] - mine[0]), abs(ref[1] - mine[1])) > 1:
            raise RuntimeError(  # pragma: no cover - would be a bug in core_source or the model
                f"core_source disagrees with the core model at ({xi[k]}, {yi[k]}): {mine} != {ref}"
            )


def core_rectified_points(
    p: CameraParams,
    points: np.ndarray,
    K: np.ndarray,
    D: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    *,
    size: Tuple[int, int],
    tol: float = 1e-9,
    max_iter: int = 30,
) -> np.ndarray:
    """Rectified positions ((N, 2)) whose core source positions are the raw ``points`` ((N, 2)).

    Started from ``cv2.undistortPoints(points, K, D, R=R, P=P)`` and refined
    by Newton's method on :func:`core_source` to ``tol`` pixels; checked
    against the core model (registers for a ``size`` = (width, height)
    frame) at the nearest output pixels. Raises
    :class:`CalibrationError` if a point does not converge (a corner where
    the lens model folds over).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    guess = cv2.undistortPoints(pts.reshape(-1, 1, 2), K, D, R=R, P=P).reshape(-1, 2).astype(np.float64)
    x, y = guess[:, 0].copy(), guess[:, 1].copy()
    tu, tv = pts[:, 0], pts[:, 1]
    h = 1e-3
    for _ in range(max_iter):
        u, v = core_source(p, x, y)
        eu, ev = u - tu, v - tv
        if float(np.max(np.hypot(eu, ev), initial=0.0)) < tol:
            break
        ux, vx = core_source(p, x + h, y)
        ux2, vx2 = core_source(p, x - h, y)
        uy, vy = core_source(p, x, y + h)
        uy2, vy2 = core_source(p, x, y - h)
        a, b = (ux - ux2) / (2 * h), (uy - uy2) / (2 * h)
        c, d = (vx - vx2) / (2 * h), (vy - vy2) / (2 * h)
        det = a * d - b * c
        if not np.all(np.isfinite(det)) or np.any(np.abs(det) < 1e-12):
            raise CalibrationError(
                "a corner lies where the lens model folds over: recalibrate with more views "
                "near the image edges"
            )
        x -= (d * eu - b * ev) / det
        y -= (a * ev - c * eu) / det
    else:
        raise CalibrationError(
            "corner positions did not converge through the core's mapping: "
            "the lens model is unusable there; recalibrate"
        )
    _check_against_reference(p, x, y, size)
    return np.stack([x, y], axis=1)


# --------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PairResult:
    """One input pair: used, or rejected with the reason; its figures if it was used."""

    name: str
    used: bool
    reason: str = ""
    rms: Optional[float] = None  # px, both cameras
    rms_left: Optional[float] = None
    rms_right: Optional[float] = None
    row_error_mean: Optional[float] = None  # px, through the core
    row_error_max: Optional[float] = None

    def to_dict(self) -> Dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CalibrationReport:
    """What :func:`calibrate_pairs` found. ``calibration`` is ready to save and program if :attr:`fits`."""

    calibration: Calibration
    pattern: Pattern
    pairs: Tuple[PairResult, ...]
    rms: float  # stereo reprojection RMS over all used corners, px
    row_error_mean: float  # mean |y_left - y_right| of corners rectified through the core, px
    row_error_max: float
    lb_rows: int  # rows of the bitstream it was checked against

    @property
    def pairs_used(self) -> int:
        return sum(p.used for p in self.pairs)

    @property
    def pairs_rejected(self) -> int:
        return sum(not p.used for p in self.pairs)

    @property
    def rows_needed(self) -> int:
        return self.calibration.fit.rows

    @property
    def fits(self) -> bool:
        return self.calibration.fit.fits(self.lb_rows)

    def check(self) -> None:
        """Raise ``LineBufferTooSmall`` (a ``ValueError``) if the bitstream cannot run this calibration."""
        self.calibration.check_fits(self.lb_rows)

    def to_dict(self) -> Dict[str, Any]:
        """A JSON-able summary (what ``stereocam calibrate --json`` prints)."""
        cal = self.calibration
        m = cal.model
        cams = {}
        for side, K, D in (("left", m.K1, m.D1), ("right", m.K2, m.D2)):
            cams[side] = {
                "fx": float(K[0, 0]),
                "fy": float(K[1, 1]),
                "cx": float(K[0, 2]),
                "cy": float(K[1, 2]),
                "k1": float(D[0]),
                "k2": float(D[1]),
                "p1": float(D[2]),
                "p2": float(D[3]),
            }
        return {
            "id": cal.id,
            "image_size": list(cal.image_size),
            "pattern": str(self.pattern),
            "square_m": self.pattern.square,
            "pairs_used": self.pairs_used,
            "pairs_rejected": self.pairs_rejected,
            "pairs": [p.to_dict() for p in self.pairs],
            "rms": self.rms,
            "row_error_mean": self.row_error_mean,
            "row_error_max": self.row_error_max,
            "rows_needed": self.rows_needed,
            "lb_rows": self.lb_rows,
            "lb_delay": cal.fit.delay,
            "fits": self.fits,
            "alpha": cal.alpha,
            "baseline_m": m.baseline,
            **cams,
        }

    def lines(self) -> List[str]:
        """The report for people, one line per item."""
        out = [
            f"pairs: {self.pairs_used} used, {self.pairs_rejected} rejected (pattern {self.pattern}, "
            f"squares {self.pattern.square * 1000:g} mm)"
        ]
        for p in self.pairs:
            if p.used:
                out.append(
                    f"  {p.name}: reprojection {p.rms:.3f} px (left {p.rms_left:.3f}, right "
                    f"{p.rms_right:.3f}); row error mean {p.row_error_mean:.3f}, max {p.row_error_max:.3f} px"
                )
            else:
                out.append(f"  {p.name}: rejected, {p.reason}")
        m = self.calibration.model
        out.append(f"reprojection error (RMS): {self.rms:.3f} px")
        out.append(
            f"rectified row error through the core: mean {self.row_error_mean:.3f} px, "
            f"max {self.row_error_max:.3f} px"
        )
        for side, K, D in (("left", m.K1, m.D1), ("right", m.K2, m.D2)):
            out.append(
                f"{side}: fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} "
                f"k1 {D[0]:.4f} k2 {D[1]:.4f} p1 {D[2]:.5f} p2 {D[3]:.5f}"
            )
        out.append(f"baseline: {m.baseline * 1000:.2f} mm")
        fit = self.calibration.fit
        verdict = "fits" if self.fits else "does NOT fit"
        out.append(f"line buffer: {fit.rows} of {self.lb_rows} rows needed (delay {fit.delay}): {verdict}")
        return out

    def quality(self) -> Dict[str, Any]:
        """The figures stored in the calibration file's ``quality`` section."""
        return _quality(self.pattern, self.pairs, self.rms, self.row_error_mean, self.row_error_max)


def _quality(
    pattern: Pattern, pairs: Sequence[PairResult], rms: float, mean: float, worst: float
) -> Dict[str, Any]:
    return {
        "pattern": str(pattern),
        "square_m": pattern.square,
        "rms_px": round(rms, 6),
        "row_error_mean_px": round(mean, 6),
        "row_error_max_px": round(worst, 6),
        "pairs_used": [{"name": p.name, "rms_px": round(p.rms or 0.0, 6)} for p in pairs if p.used],
        "pairs_rejected": [{"name": p.name, "reason": p.reason} for p in pairs if not p.used],
    }


# --------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------


@dataclass
class _Views:
    index: List[int]  # into the caller's pairs
    left: List[np.ndarray]
    right: List[np.ndarray]


def _stereo_calibrate(
    views: _Views, pattern: Pattern, size: Tuple[int, int]
) -> Tuple[StereoModel, float, np.ndarray]:
    """(model, RMS, per-view RMS (N, 2)) of a stereo calibration with k3 fixed at 0."""
    obj = [pattern.object_points()] * len(views.index)
    lefts = [c.reshape(-1, 1, 2).astype(np.float32) for c in views.left]
    rights = [c.reshape(-1, 1, 2).astype(np.float32) for c in views.right]
    flags = cv2.CALIB_FIX_K3
    try:
        _, K1, D1, _, _ = cv2.calibrateCamera(obj, lefts, size, None, None, flags=flags)
        _, K2, D2, _, _ = cv2.calibrateCamera(obj, rights, size, None, None, flags=flags)
        out = cv2.stereoCalibrateExtended(
            obj,
            lefts,
            rights,
            K1,
            D1,
            K2,
            D2,
            size,
            np.eye(3),
            np.zeros((3, 1)),
            flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5),
        )
    except cv2.error as exc:
        lines = str(exc).strip().splitlines()
        raise CalibrationError(
            f"OpenCV could not calibrate these views ({lines[-1] if lines else exc}): "
            "capture more pairs with the board at different angles"
        ) from None
    rms, K1, D1, K2, D2, R, T = out[:7]
    per_view = np.asarray(out[-1], dtype=np.float64).reshape(-1, 2)
    model = StereoModel(
        K1, np.asarray(D1).ravel()[:4], K2, np.asarray(D2).ravel()[:4], R, np.asarray(T).ravel(), size
    )
    if not (np.all(np.isfinite(model.K1)) and np.all(np.isfinite(model.K2)) and np.isfinite(rms)):
        raise CalibrationError(
            "the calibration diverged: capture more pairs with the board at different angles"
        )
    return model, float(rms), per_view


def calibrate_pairs(
    pairs: Sequence[ImagePair],
    pattern: Pattern,
    *,
    alpha: float = 0.0,
    lb_rows: int = DEFAULT_LB_ROWS,
    min_pairs: int = MIN_PAIRS,
    max_width: int = DEFAULT_MAX_WIDTH,
    max_height: int = DEFAULT_MAX_HEIGHT,
    progress: Optional[Progress] = None,
    source: str = "",
) -> CalibrationReport:
    """Calibrate the stereo rig from checkerboard ``pairs`` and derive the core's registers.

    Blocking, CPU-bound (about a second for a dozen 640x480 pairs): call it
    from a worker thread in a server. Images are read one pair at a time
    and not kept. ``progress(stage, done, total)`` is called from the
    calling thread as work advances.

    Raises (all ``ValueError``): :class:`CalibrationInputError` for a
    missing or unreadable image or pairs of different sizes;
    :class:`NotEnoughPairs` when fewer than ``min_pairs`` pairs show the
    whole pattern in both cameras; :class:`CalibrationError` when the
    calibration fails; ``CoreParamsError`` subclasses when the result does not
    fit the core's registers or a ``max_width`` x ``max_height`` frame. A
    calibration that needs more than ``lb_rows`` line-buffer rows is
    returned (see :attr:`CalibrationReport.fits` and
    :meth:`CalibrationReport.check`), so its figures can be shown.
    """
    if not pairs:
        raise CalibrationInputError("no image pairs to calibrate from")
    if not 0.0 <= alpha <= 1.0:
        raise CalibrationError(f"alpha must be between 0 (only valid pixels) and 1 (all pixels), not {alpha}")
    report = progress or (lambda stage, done, total: None)
    views, results, size = _detect_views(pairs, pattern, report)
    _require(views, results, min_pairs, len(pairs))
    views, model, rms, per_view = _calibrate_views(views, pairs, results, pattern, size, min_pairs, report)
    report("calibrate", 2, 3)
    rect = rectify(model, alpha=alpha)
    cal = Calibration.derive(
        model, rect, alpha=float(alpha), units="m", source=source, max_width=max_width, max_height=max_height
    )
    report("calibrate", 3, 3)
    rows = _check_through_core(cal, views, pairs, per_view, results, report)
    ordered = tuple(results[i] for i in range(len(pairs)))
    mean, worst = float(rows.mean()), float(rows.max())
    cal = dataclasses.replace(cal, quality=_quality(pattern, ordered, rms, mean, worst))
    return CalibrationReport(cal, pattern, ordered, rms, mean, worst, lb_rows)


def _detect_views(
    pairs: Sequence[ImagePair], pattern: Pattern, report: Progress
) -> Tuple[_Views, Dict[int, PairResult], Tuple[int, int]]:
    """The corners of every pair showing the whole pattern in both images, the rejected pairs' results,
    and the image size.

    Reads one pair at a time and keeps only its corners. Raises
    :class:`CalibrationInputError` for pairs of another size than the
    first, :class:`NotEnoughPairs` when no pair shows the pattern.
    """
    total = len(pairs)
    results: Dict[int, PairResult] = {}
    views = _Views([], [], [])
    size: Optional[Tuple[int, int]] = None
    first = ""
    for i, pair in enumerate(pairs):
        report("detect", i, total)
        left, right = pair.load()
        h, w = left.shape
        if size is None:
            size, first = (w, h), pair.name
        elif (w, h) != size:
            raise CalibrationInputError(
                f"pair {pair.name} is {w}x{h} but the first pair ({first}) is {size[0]}x{size[1]}: "
                "all pairs must come from the same cameras at the same size"
            )
        cl = detect_corners(left, pattern)
        cr = detect_corners(right, pattern)
        del left, right
        if cl is None or cr is None:
            where = (
                "either image"
                if cl is None and cr is None
                else ("the left image" if cl is None else "the right image")
            )
            results[i] = PairResult(pair.name, False, f"the {pattern} pattern was not found in {where}")
            continue
        views.index.append(i)
        views.left.append(cl)
        views.right.append(_same_order(cl, cr))
    report("detect", total, total)
    assert size is not None
    if not views.index:
        raise NotEnoughPairs(
            f"the {pattern} pattern was found in none of the {total} pairs: check the pattern "
            "(--pattern, the page's inner corners: per row x per column, e.g. a board of 10x7 squares "
            "has 9x6) and that the whole board is in both images"
        )
    return views, results, size


def _calibrate_views(
    views: _Views,
    pairs: Sequence[ImagePair],
    results: Dict[int, PairResult],
    pattern: Pattern,
    size: Tuple[int, int],
    min_pairs: int,
    report: Progress,
) -> Tuple[_Views, StereoModel, float, np.ndarray]:
    """The stereo calibration of ``views``, once more without its outliers if enough pairs remain.

    A pair whose RMS error exceeds both :data:`OUTLIER_PX` and
    :data:`OUTLIER_FACTOR` times the median is dropped (its result goes to
    ``results``). Returns the views kept, the model, its RMS and the
    per-view RMS ``(N, 2)``.
    """
    report("calibrate", 0, 3)
    model, rms, per_view = _stereo_calibrate(views, pattern, size)
    pair_rms = np.sqrt((per_view**2).mean(axis=1))
    median = float(np.median(pair_rms))
    limit = max(OUTLIER_PX, OUTLIER_FACTOR * median)
    bad = [k for k in range(len(views.index)) if pair_rms[k] > limit]
    if not bad or len(views.index) - len(bad) < min_pairs:
        return views, model, rms, per_view
    for k in bad:
        i = views.index[k]
        results[i] = PairResult(
            pairs[i].name,
            False,
            f"reprojection error {pair_rms[k]:.2f} px is more than {OUTLIER_FACTOR:g}x the median "
            f"{median:.2f} px (corners misdetected, blur, or the board moved)",
        )
    keep = [k for k in range(len(views.index)) if k not in bad]
    views = _Views(
        [views.index[k] for k in keep], [views.left[k] for k in keep], [views.right[k] for k in keep]
    )
    report("calibrate", 1, 3)
    model, rms, per_view = _stereo_calibrate(views, pattern, size)
    return views, model, rms, per_view


def _check_through_core(
    cal: Calibration,
    views: _Views,
    pairs: Sequence[ImagePair],
    per_view: np.ndarray,
    results: Dict[int, PairResult],
    report: Progress,
) -> np.ndarray:
    """The rectified row error ``|y_left - y_right|`` of every used corner, through the core's mapping.

    Fills ``results`` with each used pair's figures.
    """
    model, rect, size = cal.model, cal.rect, cal.image_size
    pair_rms = np.sqrt((per_view**2).mean(axis=1))
    report("check", 0, len(views.index))
    all_rows: List[np.ndarray] = []
    for k, i in enumerate(views.index):
        yl = core_rectified_points(cal.left, views.left[k], model.K1, model.D1, rect.R1, rect.P1, size=size)
        yr = core_rectified_points(cal.right, views.right[k], model.K2, model.D2, rect.R2, rect.P2, size=size)
        rows = np.abs(yl[:, 1] - yr[:, 1])
        all_rows.append(rows)
        results[i] = PairResult(
            pairs[i].name,
            True,
            "",
            float(pair_rms[k]),
            float(per_view[k, 0]),
            float(per_view[k, 1]),
            float(rows.mean()),
            float(rows.max()),
        )
        report("check", k + 1, len(views.index))
    return np.concatenate(all_rows)


def _require(views: _Views, results: Dict[int, PairResult], min_pairs: int, total: int) -> None:
    if len(views.index) >= min_pairs:
        return
    reasons = "; ".join(f"{r.name}: {r.reason}" for r in results.values())
    raise NotEnoughPairs(
        f"only {len(views.index)} of {total} pairs show the whole pattern in both cameras and at least "
        f"{min_pairs} are needed: capture more pairs with the whole board visible in both images"
        + (f" ({reasons})" if reasons else "")
    )
