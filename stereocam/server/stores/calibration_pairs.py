"""The calibration panel's work: checkerboard corners on live frames, stored pairs, coverage, figures.

Everything here is blocking (OpenCV, disk) and runs on the daemon's work
threads; :mod:`..http.routes_calibration_panel` holds the HTTP side.

Pairs are ordinary captures (:class:`.captures.CaptureStore`) kept in their
own folder, ``<captures>/../calibration-pairs/`` by default, with the
corners found in each image in ``meta.json``: a pair survives a restart, is
written atomically like any capture, and the folder is a valid input of
``stereocam calibrate`` on a host. The panel's settings (pattern, square,
alpha) live in ``settings.json`` in the same folder.
"""
from __future__ import annotations

import errno
import json
import logging
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import cv2
import numpy as np

from ...calibration.calibrate import (
    CalibrationError,
    CalibrationReport,
    ImagePair,
    Pattern,
    Progress,
    calibrate_pairs,
    core_rectified_points,
    detect_corners,
    parse_pattern,
)
from ...overlays.model.fast import RectifyModel
from ...overlays.model.result import CoreOptions
from ...overlays.spec import pixel
from ..errors import ApiError, Kind
from .captures import CAPTURE_FILES, CaptureInfo, CaptureStore
from .files import read_member

log = logging.getLogger(__name__)

__all__ = [
    "PanelSettings", "PanelError", "PAIRS_FOLDER", "PURPOSE", "COVERAGE_GRID", "SAME_VIEW_PX",
    "detect_frame", "pair_entries", "coverage", "same_view", "compute", "rectified_figure",
    "load_settings", "save_settings",
]

PAIRS_FOLDER = "calibration-pairs"
SETTINGS_FILE = "settings.json"
MAX_SETTINGS_BYTES = 64 * 1024  # three fields; larger is not the panel's file
PURPOSE = "calibration-pair"
COVERAGE_GRID = (16, 10)  # cells across and down in which coverage is counted
SAME_VIEW_PX = 6.0  # a new pair whose corners are this close (mean) to a stored pair's adds nothing
MIN_SQUARE_MM = 0.1
MAX_SQUARE_MM = 1000.0


class PanelError(ApiError):
    """A refusal of the calibration panel: its ``kind`` (of itself: the pairs cannot be used) and one
    line for the user."""

    kind = Kind.UNUSABLE


# -- settings -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class PanelSettings:
    """The board the user holds (inner corners, square size) and the rectification's alpha."""

    pattern: Pattern
    alpha: float = 0.0

    @classmethod
    def default(cls) -> "PanelSettings":
        return cls(Pattern(9, 6, 0.025), 0.0)

    def to_json(self) -> Dict[str, Any]:
        return {"pattern": str(self.pattern), "square_mm": round(self.pattern.square * 1000.0, 6),
                "alpha": self.alpha}

    def updated(self, doc: Mapping[str, Any]) -> "PanelSettings":
        """These settings with the fields of ``doc`` changed; :class:`PanelError` names a bad one."""
        if not isinstance(doc, Mapping):
            raise PanelError('send a JSON object such as {"pattern": "9x6", "square_mm": 25, "alpha": 0}',
                             kind=Kind.BAD_REQUEST)
        unknown = sorted(set(doc) - {"pattern", "square_mm", "alpha"})
        if unknown:
            raise PanelError(f"unknown field {unknown[0]!r}: the fields are pattern, square_mm and alpha",
                             kind=Kind.BAD_REQUEST)
        cols, rows, square = self.pattern.cols, self.pattern.rows, self.pattern.square
        alpha = self.alpha
        if "pattern" in doc:
            if not isinstance(doc["pattern"], str):
                raise PanelError('pattern is a string of inner corners, e.g. "9x6"', kind=Kind.BAD_REQUEST)
            try:
                cols, rows = parse_pattern(doc["pattern"])
            except CalibrationError as exc:
                raise PanelError(str(exc), kind=Kind.BAD_REQUEST) from None
            if cols * rows > 2000:
                raise PanelError(f"pattern {cols}x{rows} has more than 2000 corners: count the inner corners "
                                 "of your board", kind=Kind.BAD_REQUEST)
        if "square_mm" in doc:
            value = doc["square_mm"]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not MIN_SQUARE_MM <= value <= MAX_SQUARE_MM:
                raise PanelError(f"square_mm is the side of one square in millimetres, from "
                                 f"{MIN_SQUARE_MM:g} to {MAX_SQUARE_MM:g}; got {value!r}",
                                 kind=Kind.BAD_REQUEST)
            square = float(value) / 1000.0
        if "alpha" in doc:
            value = doc["alpha"]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise PanelError(f"alpha is from 0 (only valid pixels) to 1 (every source pixel); "
                                 f"got {value!r}", kind=Kind.BAD_REQUEST)
            alpha = float(value)
        return PanelSettings(Pattern(cols, rows, square), alpha)


def load_settings(folder: Path) -> PanelSettings:
    """The settings saved in ``folder``; the defaults (9x6, 25 mm, alpha 0) if none or unreadable.

    Read without following a symbolic link and at most :data:`MAX_SETTINGS_BYTES`.
    """
    path = folder / SETTINGS_FILE
    try:
        doc = json.loads(read_member(folder, SETTINGS_FILE, MAX_SETTINGS_BYTES).decode("utf-8"))
        return PanelSettings.default().updated(doc)
    except FileNotFoundError:
        return PanelSettings.default()
    except (OSError, ValueError, RecursionError, PanelError, CalibrationError) as exc:
        why = "it is a symbolic link, not a file" if getattr(exc, "errno", None) == errno.ELOOP else (
            getattr(exc, "message", None) or exc)
        log.warning("the calibration panel's settings %s cannot be used (%s): using 9x6, 25 mm, alpha 0",
                    path, why)
        return PanelSettings.default()


def save_settings(folder: Path, settings: PanelSettings) -> None:
    """Write ``settings.json`` atomically (a crash leaves the old or the new file, never half of one)."""
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".settings-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(settings.to_json(), fh, indent=2)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, folder / SETTINGS_FILE)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


# -- corners --------------------------------------------------------------------------------------

def _points(corners: Optional[np.ndarray]) -> Optional[List[List[float]]]:
    return None if corners is None else np.round(corners, 2).tolist()


def detect_frame(raw: np.ndarray, pattern: Pattern, *, thorough: bool) -> Dict[str, Any]:
    """Corners of ``pattern`` in both gray images of a raw ``(H, W, 8)`` frame.

    ``{"left": [[x, y], ...] | None, "right": ..., "ms": time taken}``; the
    right camera's corners are in the left's order. ``thorough`` adds the
    slower detector (pair capture); the live preview leaves it out.
    """
    t0 = time.perf_counter()
    left = detect_corners(np.ascontiguousarray(raw[..., pixel.LEFT][..., pixel.Y]), pattern,
                          thorough=thorough)
    right = detect_corners(np.ascontiguousarray(raw[..., pixel.RIGHT][..., pixel.Y]), pattern,
                           thorough=thorough)
    if left is not None and right is not None and float(np.dot(left[-1] - left[0], right[-1] - right[0])) < 0:
        right = right[::-1].copy()
    return {"left": _points(left), "right": _points(right), "ms": round((time.perf_counter() - t0) * 1e3, 1)}


def missing_in(found: Mapping[str, Any]) -> Optional[str]:
    """Which image lacks the pattern ("the left image", ...), None if both show it."""
    left, right = found.get("left") is None, found.get("right") is None
    if left and right:
        return "either image"
    if left or right:
        return "the left image" if left else "the right image"
    return None


# -- stored pairs ---------------------------------------------------------------------------------

def pair_entries(store: CaptureStore) -> List[Dict[str, Any]]:
    """The stored pairs, oldest first: id, created, frame, pattern and corners (from meta.json)."""
    return [_entry(info) for info in _oldest_first(store)]


def _oldest_first(store: CaptureStore) -> List[CaptureInfo]:
    return sorted(store.list(), key=lambda info: info.id)  # ids start with the UTC time


def _entry(info: CaptureInfo) -> Dict[str, Any]:
    meta = info.meta
    found = meta.get("corners")
    corners: Mapping[str, Any] = found if isinstance(found, dict) else {}
    return {"id": info.id, "created": info.created, "frame": info.frame,
            "pattern": meta.get("pattern") if isinstance(meta.get("pattern"), str) else None,
            "corners": {side: corners.get(side) for side in ("left", "right")},
            "error": info.error}


def _array(points: Any) -> Optional[np.ndarray]:
    try:
        a = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return a if a.ndim == 2 and a.shape[1] == 2 and len(a) >= 4 and np.all(np.isfinite(a)) else None


def coverage(entries: Sequence[Mapping[str, Any]], size: Tuple[int, int]) -> Dict[str, Any]:
    """Share of each image, on a :data:`COVERAGE_GRID` of cells, that some pair's board covered.

    A board covers the cells inside the convex hull of its corners: the
    calibration only knows the lens where it saw corners, so users aim for
    the whole image, corners included.
    """
    gw, gh = COVERAGE_GRID
    w, h = size
    out: Dict[str, Any] = {"grid": [gw, gh]}
    for side in ("left", "right"):
        mask = np.zeros((gh * 8, gw * 8), np.uint8)
        for entry in entries:
            pts = _array((entry.get("corners") or {}).get(side))
            if pts is None:
                continue
            scaled = pts * np.array([gw * 8 / w, gh * 8 / h])
            hull = cv2.convexHull(np.round(scaled).astype(np.int32))
            cv2.fillConvexPoly(mask, hull, 1)
        cells = mask.reshape(gh, 8, gw, 8).mean(axis=(1, 3)) >= 0.5
        out[side] = round(float(cells.mean()), 4)
    return out


def same_view(found: Mapping[str, Any], entries: Sequence[Mapping[str, Any]]) -> Optional[str]:
    """The id of a stored pair showing the board where ``found`` shows it (both cameras), else None."""
    new = {side: _array(found.get(side)) for side in ("left", "right")}
    for entry in entries:
        close = True
        for side in ("left", "right"):
            old, cur = _array((entry.get("corners") or {}).get(side)), new[side]
            if old is None or cur is None or old.shape != cur.shape:
                close = False
                break
            gap = min(float(np.linalg.norm(old - cur, axis=1).mean()),
                      float(np.linalg.norm(old[::-1] - cur, axis=1).mean()))
            close = close and gap < SAME_VIEW_PX
        if close:
            return str(entry["id"])
    return None


# -- compute and figures --------------------------------------------------------------------------

def pair_ids(store: CaptureStore) -> List[str]:
    """The ids of the sound stored pairs, oldest first (what a compute uses)."""
    return [i.id for i in _oldest_first(store) if i.error is None]


def compute(store: CaptureStore, ids: Sequence[str], settings: PanelSettings, rectify: Any, *,
            progress: Progress, min_pairs: int = 5) -> CalibrationReport:
    """Calibrate from the stored pairs ``ids`` with ``settings`` (blocking, seconds).

    The report's pairs are in the order of ``ids``. Raises
    :class:`PanelError` (unusable) with the calibrator's message when it cannot
    calibrate (too few pairs showing the pattern, divergence, registers).
    """
    for i in ids:  # the listing reports a link as damage, and damaged pairs are left out: one made since
        linked = [name for name in CAPTURE_FILES if os.path.islink(store.root / i / name)]
        if linked:
            raise PanelError(f"pair {i}: {linked[0]} is a symbolic link, not a file; delete that pair")
    pairs = [ImagePair(i, store.root / i / CAPTURE_FILES[0], store.root / i / CAPTURE_FILES[1]) for i in ids]
    if len(pairs) < min_pairs:
        raise PanelError(f"{len(pairs)} pairs are stored and at least {min_pairs} are needed: capture more "
                         "pairs, moving and tilting the board between them")
    limits = {k: getattr(rectify, k) for k in ("max_width", "max_height")
              if isinstance(getattr(rectify, k, None), int)}
    try:
        report = calibrate_pairs(
            pairs, settings.pattern, alpha=settings.alpha, lb_rows=rectify.lb_rows, min_pairs=min_pairs,
            progress=progress, **limits,
            source=f"stereocam serve calibration panel: {len(pairs)} pairs, pattern {settings.pattern}, "
                   f"squares {settings.pattern.square * 1000:g} mm, alpha {settings.alpha:g}")
    except ValueError as exc:  # CalibrationError, NotEnoughPairs, CoreParamsError: all say what to do
        raise PanelError(str(exc)) from None
    return report


LINE_EVERY_PX = 32


def rectified_figure(store: CaptureStore, pair_id: str, report: CalibrationReport, lb_rows: int) -> bytes:
    """PNG: the pair through the core model with the candidate, side by side, rows drawn across.

    Corners found in the raw images are drawn where the core puts them
    (green left, magenta right) in both halves, so a row error shows as a
    gap between a corner and its partner's line.
    """
    cal = report.calibration
    left, right = store.raw_pair(pair_id)
    w, h = cal.image_size
    if left.shape[:2] != (h, w):
        raise PanelError(f"pair {pair_id} is {left.shape[1]}x{left.shape[0]}, the calibration is for {w}x{h}")
    options = CoreOptions(lb_rows=max(lb_rows, cal.fit.rows), lb_delay=cal.fit.delay, gray=True)
    out = RectifyModel(cal.left, cal.right, w, h, options).process(pixel.pack(left, right)).frame
    sbs = np.concatenate([out[..., pixel.LEFT][..., pixel.Y], out[..., pixel.RIGHT][..., pixel.Y]], axis=1)
    figure = cv2.cvtColor(np.ascontiguousarray(sbs), cv2.COLOR_GRAY2BGR)
    for y in range(LINE_EVERY_PX // 2, h, LINE_EVERY_PX):
        cv2.line(figure, (0, y), (2 * w - 1, y), (0, 200, 255), 1, cv2.LINE_AA)
    m, r = cal.model, cal.rect
    found = detect_frame(pixel.pack(left, right), report.pattern, thorough=True)
    colours = {"left": (60, 220, 60), "right": (230, 60, 230)}
    for side, params, K, D, R, P in (("left", cal.left, m.K1, m.D1, r.R1, r.P1),
                                     ("right", cal.right, m.K2, m.D2, r.R2, r.P2)):
        pts = _array(found[side])
        if pts is None:
            continue
        rect = core_rectified_points(params, pts, K, D, R, P, size=(w, h))
        for x, y in rect:
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            for offset in (0, w):
                centre = (int(round((x + offset) * 4)), int(round(y * 4)))
                cv2.circle(figure, centre, 12, colours[side], 1, cv2.LINE_AA, shift=2)
    cv2.line(figure, (w, 0), (w, h - 1), (255, 255, 255), 1)
    ok, png = cv2.imencode(".png", figure)
    if not ok:  # pragma: no cover - OpenCV encodes any BGR uint8 image
        raise PanelError("cannot encode the figure", kind=Kind.FAILED)
    return png.tobytes()
