"""Stereo pairs on disk: which image files are read, what a capture's files are called, in what order.

The calibration's pair finder, the emulated cameras' replay and the daemon's
capture store all read (or write) these folders; defined once here, the
lowest layer that needs them, a folder one accepts the others read alike.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Tuple

__all__ = ["CAPTURE_FILES", "IMAGE_EXTS", "RAW_FRAMES", "capture_file", "is_image_file", "natural_key"]

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
"""Image files a folder of ``left*``/``right*`` pairs may hold (lower-case; matched case-insensitively)."""

RAW_FRAMES = ("raw_left", "raw_right")
"""A capture's camera frames, as the demosaic delivered them: what replay and calibration read."""


def capture_file(frame: str, *, y_plane: bool = False) -> str:
    """The file in a capture folder holding ``frame`` (``raw_left``, ``rect_right``, ...).

    With ``y_plane``, the file of its separate gray (Y) plane, stored only
    where Y is not the gray of the RGB pixels.
    """
    return f"{frame}_y.png" if y_plane else f"{frame}.png"


CAPTURE_FILES = (capture_file(RAW_FRAMES[0]), capture_file(RAW_FRAMES[1]))
"""The two files that make a folder a capture (``raw_left.png``, ``raw_right.png``)."""


def is_image_file(path: Path) -> bool:
    """Whether ``path`` is an image a pair may be made of: a visible file with an :data:`IMAGE_EXTS` suffix.

    Hidden files (a capture store's unfinished captures) never count.
    """
    return not path.name.startswith(".") and path.suffix.lower() in IMAGE_EXTS and path.is_file()


def natural_key(text: str) -> Tuple[object, ...]:
    """Sort key putting ``left2`` before ``left10`` (digit runs compared as numbers, case ignored)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text.lower()))
