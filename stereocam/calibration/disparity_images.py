"""The stereo core's output as image files: disparity codes, confidence and a colour rendering.

Shared by ``stereocam disparity`` and the daemon's captures, so both write the same bytes.
``disparity.png`` is 16-bit gray holding the core's codes as they are (disparity x 16, 65535
where invalid), so it reads back bit for bit; ``confidence.png`` is 8-bit gray; the colour
rendering maps 0 .. ``num_disp`` pixels onto OpenCV's JET, invalid pixels black.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from ..overlays.spec import stereo as spec

__all__ = ["DISPARITY_FILE", "CONFIDENCE_FILE", "COLOUR_FILE", "png", "disparity_png", "confidence_png",
           "colour_disparity", "colour_png"]

DISPARITY_FILE = "disparity.png"
CONFIDENCE_FILE = "confidence.png"
COLOUR_FILE = "disparity_colour.png"
PNG_OPTIONS = (cv2.IMWRITE_PNG_COMPRESSION, 3)


def png(image: np.ndarray, options: Sequence[int] = PNG_OPTIONS) -> bytes:
    """Lossless PNG bytes of a gray (H, W) uint8/uint16 or an RGB (H, W, 3) uint8 image."""
    a = np.asarray(image)
    if a.ndim == 3:
        a = a[..., 2::-1]  # RGB to OpenCV's BGR
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a), list(options))
    if not ok:
        raise ValueError(f"OpenCV cannot encode a {a.dtype} {a.shape} image as PNG")
    return buf.tobytes()


def _codes(disp: np.ndarray) -> np.ndarray:
    d = np.asarray(disp)
    if d.dtype != np.uint16 or d.ndim != 2:
        raise ValueError(f"disparity codes are (H, W) uint16, not {d.dtype} {d.shape}")
    return d


def disparity_png(disp: np.ndarray) -> bytes:
    """The 16-bit PNG of the codes (disparity x 16; 65535 where invalid), exact."""
    return png(_codes(disp))


def confidence_png(conf: np.ndarray) -> bytes:
    """The 8-bit PNG of the confidence (0 .. 255; 0 where invalid)."""
    c = np.asarray(conf)
    if c.dtype != np.uint8 or c.ndim != 2:
        raise ValueError(f"confidence is (H, W) uint8, not {c.dtype} {c.shape}")
    return png(c)


def colour_disparity(disp: np.ndarray, num_disp: int = spec.DEFAULT_PARAMS.num_disp) -> np.ndarray:
    """(H, W, 3) RGB: 0 .. ``num_disp`` pixels of disparity on JET, black where invalid."""
    d = _codes(disp)
    if num_disp <= 0:
        raise ValueError(f"num_disp must be positive, not {num_disp}")
    level = np.clip(d.astype(np.float32) * (255.0 / (spec.SUBPIX_ONE * num_disp)), 0, 255).round()
    out = cv2.applyColorMap(level.astype(np.uint8), cv2.COLORMAP_JET)[..., ::-1]
    out[d == spec.INVALID] = 0
    return np.ascontiguousarray(out)


def colour_png(disp: np.ndarray, num_disp: int = spec.DEFAULT_PARAMS.num_disp) -> bytes:
    """:func:`colour_disparity` as PNG."""
    return png(colour_disparity(disp, num_disp))
