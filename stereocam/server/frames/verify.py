"""Verify (the paper's flow 5): compare the model's output with the fabric's, bit for bit.

:func:`compare` takes two ``(H, W, 8)`` uint8 stream frames (see
:mod:`...overlays.spec.pixel`): ``expected`` (the numpy model's output) and
``actual`` (what the fabric wrote back). It reports whether they are
identical and, per channel (:data:`...overlays.spec.pixel.CHANNELS`), per
camera and overall: how many pixels differ and their share, the largest
absolute difference and the PSNR in dB. :func:`difference_image` shows
where they differ.

PSNR is ``10 log10(255^2 / MSE)``; for identical data it is infinite, which
JSON cannot carry: reports use ``None`` there (read ``None`` as "identical",
never as "unknown").

Pure functions of their arguments, synchronous, thread-safe, and they never
modify or keep the frames they are given. Mismatched inputs raise
:class:`VerifyError` (a ``ValueError`` of kind ``FAILED``: both frames
come from the daemon, so a mismatch is the server's problem, not the
client's).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

import cv2
import numpy as np

from ...overlays.model.stereo_result import StereoResult
from ...overlays.spec import pixel
from ..errors import ApiError

__all__ = ["VerifyError", "VerifyReport", "ChannelStats", "compare", "difference_image", "compare_stereo"]

_CAMERAS = (("left", pixel.LEFT), ("right", pixel.RIGHT))
EXAMPLES = 10  # differing pixels a report lists


class VerifyError(ApiError, ValueError):
    """The two frames cannot be compared (shape or type mismatch): a failure of the daemon's."""


@dataclass(frozen=True)
class ChannelStats:
    """Differences over one channel, one camera (4 channels) or the whole frame (8 channels).

    ``differing``: pixel positions where at least one of the channels
    differs; ``share`` = differing / (width x height); ``max_diff``:
    largest absolute difference (0..255); ``psnr_db``: None when identical.
    """

    differing: int
    share: float
    max_diff: int
    psnr_db: Optional[float]

    def to_json(self) -> Dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class VerifyReport:
    """The result of :func:`compare`.

    ``first_difference`` is None when identical, else the first differing
    pixel in raster order: ``{"x", "y", "expected": [8 values],
    "actual": [8 values]}`` (channel order of ``pixel.CHANNELS``).
    ``regions``: per camera, the smallest rectangle holding its differing
    pixels (``{"x0", "y0", "x1", "y1"}``, inclusive) or None; ``examples``:
    the first :data:`EXAMPLES` differing pixels in raster order, shaped like
    ``first_difference``, so a script sees where to look without the image.
    """

    identical: bool
    width: int
    height: int
    overall: ChannelStats
    cameras: Dict[str, ChannelStats]
    channels: Dict[str, ChannelStats]
    first_difference: Optional[Dict[str, Any]]
    regions: Dict[str, Optional[Dict[str, int]]] = field(default_factory=dict)
    examples: List[Dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> Dict[str, Any]:
        """A JSON-ready dict (PSNR of identical data is ``null``)::

            {"identical": false, "width": 752, "height": 480,
             "differing": 12, "share": 3.3e-05, "max_diff": 1, "psnr_db": 97.1,
             "cameras": {"left": {...}, "right": {...}},
             "channels": {"L_R": {"differing", "share", "max_diff", "psnr_db"}, ...},
             "first_difference": {"x": 5, "y": 0, "expected": [...], "actual": [...]},
             "regions": {"left": {"x0": 5, "y0": 0, "x1": 40, "y1": 9}, "right": None},
             "examples": [{"x": 5, "y": 0, "expected": [...], "actual": [...]}, ...]}
        """
        out: Dict[str, Any] = {"identical": self.identical, "width": self.width, "height": self.height}
        out.update(self.overall.to_json())
        out["cameras"] = {name: s.to_json() for name, s in self.cameras.items()}
        out["channels"] = {name: s.to_json() for name, s in self.channels.items()}
        out["first_difference"] = self.first_difference
        out["regions"] = {name: None if r is None else dict(r) for name, r in self.regions.items()}
        out["examples"] = [dict(e) for e in self.examples]
        return out


def _check(expected: Any, actual: Any) -> Tuple[np.ndarray, np.ndarray]:
    for name, frame in (("expected", expected), ("actual", actual)):
        if not isinstance(frame, np.ndarray):
            raise VerifyError(
                f"cannot compare: the {name} frame is a {type(frame).__name__}, not a numpy array"
            )
        if frame.dtype != np.uint8:
            raise VerifyError(
                f"cannot compare: the {name} frame has {frame.dtype} pixels; stream frames are uint8"
            )
        if frame.ndim != 3 or frame.shape[2] != pixel.BYTES_PER_PIXEL or 0 in frame.shape:
            raise VerifyError(
                f"cannot compare: the {name} frame has shape {frame.shape}; a stream frame is (H, W, 8)"
            )
    if expected.shape != actual.shape:
        eh, ew = expected.shape[:2]
        ah, aw = actual.shape[:2]
        raise VerifyError(
            f"cannot compare frames of different sizes: expected {ew}x{eh}, actual {aw}x{ah}; "
            f"the model and the fabric must process the same input size"
        )
    return expected, actual


def _absdiff(expected: np.ndarray, actual: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.maximum(expected, actual) - np.minimum(expected, actual))


def _psnr(sum_sq: int, samples: int) -> Optional[float]:
    if sum_sq == 0:
        return None
    return 10.0 * math.log10(255.0 * 255.0 * samples / sum_sq)


def _stats(diff: np.ndarray, hists: np.ndarray, pixels: int) -> ChannelStats:
    """``diff``: (H, W, k) differences; ``hists``: their (k, 256) histograms."""
    values = np.arange(256, dtype=np.int64)
    sum_sq = int((hists.sum(axis=0) * values * values).sum())
    nonzero = np.flatnonzero(hists.sum(axis=0))
    max_diff = int(nonzero[-1]) if nonzero.size else 0
    differing = int(np.count_nonzero(diff.max(axis=2))) if max_diff else 0
    samples = pixels * diff.shape[2]
    return ChannelStats(differing, differing / pixels, max_diff, _psnr(sum_sq, samples))


def compare(expected: np.ndarray, actual: np.ndarray) -> VerifyReport:
    """Compare two ``(H, W, 8)`` uint8 stream frames; see the module doc.

    Raises :class:`VerifyError` if either is not such a frame or their sizes
    differ. Blocks for a few tens of ms at 752x480 on the board: run it in a
    worker thread.
    """
    expected, actual = _check(expected, actual)
    h, w = expected.shape[:2]
    pixels = h * w
    if np.array_equal(expected, actual):
        same = ChannelStats(0, 0.0, 0, None)
        return VerifyReport(
            identical=True, width=w, height=h, overall=same,
            cameras={name: same for name, _ in _CAMERAS},
            channels={name: same for name in pixel.CHANNELS},
            first_difference=None, regions={name: None for name, _ in _CAMERAS},
        )
    diff = _absdiff(expected, actual)
    hists = np.stack([np.bincount(diff[..., c].ravel(), minlength=256) for c in range(diff.shape[2])])
    channels = {
        name: _stats(diff[..., c:c + 1], hists[c:c + 1], pixels) for c, name in enumerate(pixel.CHANNELS)
    }
    cameras = {
        name: _stats(diff[..., side], hists[side], pixels) for name, side in _CAMERAS
    }
    overall = _stats(diff, hists, pixels)
    flat = np.flatnonzero(diff.max(axis=2).ravel())
    examples = []
    for index in flat[:EXAMPLES]:
        y, x = divmod(int(index), w)
        examples.append({"x": x, "y": y, "expected": [int(v) for v in expected[y, x]],
                         "actual": [int(v) for v in actual[y, x]]})
    return VerifyReport(
        identical=False, width=w, height=h, overall=overall, cameras=cameras, channels=channels,
        first_difference=examples[0], regions={name: _region(diff[..., side]) for name, side in _CAMERAS},
        examples=examples,
    )


def _region(diff: np.ndarray) -> Optional[Dict[str, int]]:
    """The inclusive bounding box of the pixels where ``diff`` (H, W, k) is not zero, or None."""
    mask = diff.max(axis=2) > 0
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not rows.size:
        return None
    return {"x0": int(cols[0]), "y0": int(rows[0]), "x1": int(cols[-1]), "y1": int(rows[-1])}


def difference_image(expected: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """Where the frames differ, as a fresh ``(H, 2W, 3)`` uint8 RGB image: left camera | right camera.

    Black where all four channels of a camera are equal. Elsewhere the
    largest difference over that camera's R, G, B and Y is shown in the
    TURBO colour map on a fixed log scale: light blue for 1 (one LSB),
    green-cyan for 2, yellow for 16, orange for 40, dark red for 255. The
    scale is the same for every frame, so a colour always means the same
    difference, and a single off-by-one pixel stands out against the black.
    Raises :class:`VerifyError` like
    :func:`compare`.
    """
    expected, actual = _check(expected, actual)
    diff = _absdiff(expected, actual)
    sides = [diff[..., side].max(axis=2) for _, side in _CAMERAS]
    m = np.concatenate(sides, axis=1)  # (H, 2W) uint8
    out = np.zeros(m.shape + (3,), dtype=np.uint8)
    mask = m > 0
    if not mask.any():
        return out
    scaled = 64.0 + (191.0 / math.log(255.0)) * np.log(np.maximum(m, 1).astype(np.float32))
    level = np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(level, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    out[mask] = colours[mask]
    return out



def compare_stereo(model: StereoResult, core: StereoResult) -> Dict[str, Any]:
    """The stereo core's output against its model's on the same rectified pair, beat for beat.

    ``differing`` counts pixels where the disparity, the confidence or the reason differs (each
    also on its own); ``examples`` the first :data:`EXAMPLES` of them in raster order, with both
    sides' values. Raises :class:`VerifyError` for outputs of different sizes.
    """
    if model.disp.shape != core.disp.shape:
        raise VerifyError(f"cannot compare the stereo outputs: the model's is {model.disp.shape[::-1]}, "
                          f"the core's {core.disp.shape[::-1]}")
    parts = {"disparity": model.disp != core.disp, "confidence": model.conf != core.conf,
             "reason": model.reason != core.reason}
    any_diff = parts["disparity"] | parts["confidence"] | parts["reason"]
    h, w = model.disp.shape
    examples = []
    for index in np.flatnonzero(any_diff.ravel())[:EXAMPLES]:
        y, x = divmod(int(index), w)
        examples.append({"x": x, "y": y,
                         "model": {"disp": int(model.disp[y, x]), "conf": int(model.conf[y, x]),
                                   "reason": int(model.reason[y, x])},
                         "core": {"disp": int(core.disp[y, x]), "conf": int(core.conf[y, x]),
                                  "reason": int(core.reason[y, x])}})
    differing = int(np.count_nonzero(any_diff))
    return {"compared": True, "identical": differing == 0, "width": w, "height": h, "differing": differing,
            **{f"{name}_differing": int(np.count_nonzero(m)) for name, m in parts.items()},
            "examples": examples}
