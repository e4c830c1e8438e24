"""The stereo tools (issue 24, item 4): how well a rectified pair's rows agree, and exposure.

- :func:`alignment`: ORB features of the rectified left and right gray images, matched
  (Hamming, Lowe's ratio test, then only pairs a rectified rig can produce: a small band of
  rows, a disparity in range), refined to sub-pixel corners; reports the matched pairs' vertical
  offsets. On a well-calibrated rig they are a fraction of a pixel: a knocked rig shows at once.
- :func:`histogram`: 256-bin histograms of a camera's B, G, R and gray (Y) channels and the share
  of its pixels at 0 and at 255, with a mask of those pixels (red: 255 in some channel, blue: 0 in
  every channel) as a PNG for the page to lay over the view.

Both block (numpy/OpenCV work): call them on a worker thread. ``*_of`` cache them per frame set.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Dict, List, Optional

import cv2
import numpy as np

from .pipeline import FrameSet
from .views import ViewUnavailable, render

__all__ = ["Alignment", "alignment", "alignment_of", "histogram", "histogram_of", "MIN_MATCHES",
           "MAX_REPORTED", "ROW_BAND_PX"]

MIN_MATCHES = 8        # fewer matched pairs than this say nothing trustworthy about the rows
MAX_REPORTED = 300     # matches listed in the answer (all of them count in the figures)
ROW_BAND_PX = 24.0     # a match more rows apart than this is a wrong match, not a misaligned rig
MAX_DISPARITY_PX = 200.0
MIN_DISPARITY_PX = -8.0
RATIO = 0.75           # Lowe's ratio test
ORB_FEATURES = 1000
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)


@dataclasses.dataclass(frozen=True)
class Alignment:
    """What :func:`alignment` found: ``count`` matched pairs (``matches``: the first MAX_REPORTED,
    ``[xl, yl, xr, yr]`` in full-resolution pixels of each image), their ``median_dy``/``p90_dy``
    (absolute vertical offsets, px; None below MIN_MATCHES) and ``mean_dy`` (signed: right minus
    left), ``features`` found in each image."""

    width: int
    height: int
    features: Dict[str, int]
    count: int
    median_dy: Optional[float]
    p90_dy: Optional[float]
    mean_dy: Optional[float]
    matches: List[List[float]]

    @property
    def enough(self) -> bool:
        return self.count >= MIN_MATCHES

    def to_json(self) -> Dict[str, Any]:
        return {"width": self.width, "height": self.height, "features": self.features,
                "matches_count": self.count, "median_dy_px": self.median_dy, "p90_dy_px": self.p90_dy,
                "mean_dy_px": self.mean_dy, "matches": self.matches, "enough": self.enough,
                "min_matches": MIN_MATCHES}


def _refine(gray: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Sub-pixel corner positions near ``pts`` (ORB's are whole pixels of its pyramid levels)."""
    if len(pts) == 0:
        return pts
    refined = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2).astype(np.float32).copy(), (4, 4), (-1, -1),
                               _SUBPIX)
    return refined.reshape(-1, 2)


def alignment(left: np.ndarray, right: np.ndarray) -> Alignment:
    """The vertical offsets of features matched between a rectified gray pair ``left``, ``right``."""
    left = np.ascontiguousarray(left)
    right = np.ascontiguousarray(right)
    h, w = left.shape[:2]
    orb = cv2.ORB.create(nfeatures=ORB_FEATURES)
    kl, dl = orb.detectAndCompute(left, None)
    kr, dr = orb.detectAndCompute(right, None)
    features = {"left": len(kl), "right": len(kr)}
    pairs: List[List[float]] = []
    if dl is not None and dr is not None and len(kl) >= 2 and len(kr) >= 2:
        knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(dl, dr, k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
        if good:
            pl = np.array([kl[m.queryIdx].pt for m in good], dtype=np.float32)
            pr = np.array([kr[m.trainIdx].pt for m in good], dtype=np.float32)
            keep = (np.abs(pr[:, 1] - pl[:, 1]) <= ROW_BAND_PX) & \
                   (pl[:, 0] - pr[:, 0] >= MIN_DISPARITY_PX) & (pl[:, 0] - pr[:, 0] <= MAX_DISPARITY_PX)
            pl, pr = _refine(left, pl[keep]), _refine(right, pr[keep])
            # One match per left point (a refined corner may merge with its neighbour's).
            seen = set()
            for a, b in zip(pl.tolist(), pr.tolist(), strict=True):
                key = (round(a[0], 1), round(a[1], 1))
                if key in seen or abs(b[1] - a[1]) > ROW_BAND_PX:
                    continue
                seen.add(key)
                pairs.append([round(a[0], 2), round(a[1], 2), round(b[0], 2), round(b[1], 2)])
    count = len(pairs)
    median = p90 = mean = None
    if count >= MIN_MATCHES:
        dy = np.array([p[3] - p[1] for p in pairs])
        median = round(float(np.median(np.abs(dy))), 3)
        p90 = round(float(np.percentile(np.abs(dy), 90)), 3)
        mean = round(float(np.mean(dy)), 3)
    return Alignment(w, h, features, count, median, p90, mean, pairs[:MAX_REPORTED])


def alignment_of(fs: FrameSet) -> Alignment:
    """:func:`alignment` of ``fs``'s rectified pair, once per frame set."""
    return fs.cache.get(("tool", "alignment"), lambda: alignment(render(fs, "rect_left", True),
                                                                 render(fs, "rect_right", True)))


def histogram(bgr: np.ndarray, y: np.ndarray) -> Dict[str, Any]:
    """Histograms and clipping of one camera's ``bgr`` image and its gray channel ``y``.

    ``clipped_high``: share of pixels with 255 in some channel (the mask's red), ``clipped_low``:
    with 0 in every channel (its blue); ``at_0``/``at_255``: the share per channel."""
    n = int(y.size)
    channels = {"b": bgr[..., 0], "g": bgr[..., 1], "r": bgr[..., 2], "y": y}
    hist = {k: np.bincount(c.ravel(), minlength=256).tolist() for k, c in channels.items()}
    high = (bgr == 255).any(axis=2)
    low = (bgr == 0).all(axis=2)
    mask = np.zeros(y.shape + (4,), dtype=np.uint8)  # BGRA, transparent where nothing is clipped
    mask[high] = (0, 0, 255, 255)
    mask[low] = (255, 96, 0, 255)
    ok, png = cv2.imencode(".png", mask, [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGRA image
        raise RuntimeError("the clipping mask could not be encoded")
    return {"width": int(y.shape[1]), "height": int(y.shape[0]), "pixels": n, "bins": 256,
            "histogram": hist,
            "at_0": {k: int(hist[k][0]) / n for k in channels},
            "at_255": {k: int(hist[k][255]) / n for k in channels},
            "clipped_high": int(high.sum()) / n, "clipped_low": int(low.sum()) / n,
            "mask_png": bytes(png)}


def histogram_of(fs: FrameSet, view: str) -> Dict[str, Any]:
    """:func:`histogram` of raw view ``view`` of ``fs`` (ViewUnavailable without the raw pair), once
    per frame set."""
    if fs.raw is None:
        raise ViewUnavailable(f"frame {fs.frame} was read without its raw pair")
    return fs.cache.get(("tool", "histogram", view),
                        lambda: histogram(render(fs, view, False), render(fs, view, True)))

