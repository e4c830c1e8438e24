"""Stereo pairs on disk: which image files are read, what a capture's files are called, in what order.

The calibration's pair finder, the emulated cameras' replay and the daemon's
capture store all read (or write) these folders; defined once here, the
lowest layer that needs them, a folder one accepts the others read alike.
"""
from __future__ import annotations

import io
import re
import threading
import warnings
from pathlib import Path
from typing import IO, Any, Optional, Tuple, Union

import numpy as np

__all__ = ["CAPTURE_FILES", "IMAGE_EXTS", "MAX_IMAGE_PIXELS", "RAW_FRAMES", "ImageTooLarge", "capture_file",
           "check_image_header", "decode_image_bytes", "decode_image_file", "image_size", "is_image_file",
           "natural_key"]

MAX_IMAGE_PIXELS = 4096 * 4096
"""Largest image (width x height) decoded at all, from a file or an upload: a header claiming more is
refused before a pixel is decoded (a decompression bomb would take gigabytes; the sensors are 752x480)."""

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


class ImageTooLarge(ValueError):
    """An image file whose header claims more than :data:`MAX_IMAGE_PIXELS`; the message names it."""


_HEADER_LOCK = threading.Lock()  # Python's warning filters are process-wide


def image_size(source: Union[bytes, Path, IO[bytes]], where: str,
               max_pixels: int = MAX_IMAGE_PIXELS) -> Optional[Tuple[int, int]]:
    """``(width, height)`` from the header of an image (bytes, or a file or an open one: only its header
    is read).

    None when Pillow does not read the format or cannot parse the header (the decoder then
    decides); raises :class:`ImageTooLarge` over ``max_pixels`` pixels, before any pixel is
    decoded. Pillow's warnings about odd files are suppressed, and its own decompression-bomb
    error (far above our limit) counts as too large.
    """
    from PIL import Image

    too_large = f"{where}: the image header claims more than the {max_pixels / 1e6:.1f} megapixels read"
    with _HEADER_LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            with Image.open(io.BytesIO(source) if isinstance(source, bytes) else source) as image:
                w, h = image.size
        except Image.DecompressionBombError:
            raise ImageTooLarge(f"{too_large} (a decompression bomb?)") from None
        except Exception:  # not a format Pillow reads, or a header it cannot parse
            return None
    if w * h > max_pixels:
        raise ImageTooLarge(f"{too_large}: {w}x{h} ({w * h / 1e6:.1f} megapixels; a decompression bomb?)")
    return int(w), int(h)


def check_image_header(data: bytes, where: str) -> None:
    """Raise :class:`ImageTooLarge` when the image's header claims more than :data:`MAX_IMAGE_PIXELS`."""
    image_size(data, where)


OPENCV_LOG_LEVEL_ERROR = 2  # cv::utils::logging::LOG_LEVEL_ERROR, in OpenCV 4 and 5 alike


def _opencv_errors_only(cv2: Any) -> None:
    """OpenCV prints its own warnings about a corrupt file straight to stderr ("[ WARN:0@0.1] ...
    PNG input buffer is incomplete"), beside the one-line error the caller gives: errors only.
    OpenCV 5 has the setting in ``cv2.utils.logging``, OpenCV 4 (the board's, Debian's) as
    ``cv2.setLogLevel``."""
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    set_level = getattr(logging, "setLogLevel", None) or getattr(cv2, "setLogLevel", None)
    if set_level is not None:
        set_level(OPENCV_LOG_LEVEL_ERROR)


def decode_image_file(path: Path, flags: int) -> Optional[np.ndarray]:
    """``cv2.imdecode(bytes, flags)`` of the file at ``path``, its header checked first.

    None when the file is missing, empty or not decodable (as ``cv2.imdecode``); raises
    :class:`ImageTooLarge` for a header over :data:`MAX_IMAGE_PIXELS` pixels, which OpenCV would
    otherwise decode (up to a gigapixel) or fail on with an error of its own.
    """
    data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else None
    if data is None or not data.size:
        return None
    return decode_image_bytes(data.tobytes(), flags, str(path))


def decode_image_bytes(data: bytes, flags: int, where: str) -> Optional[np.ndarray]:
    """:func:`decode_image_file` of a file's bytes (read by the caller, e.g. without following a link)."""
    import cv2

    if not data:
        return None
    check_image_header(data, where)
    _opencv_errors_only(cv2)
    try:
        return cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error:  # a header Pillow could not read and OpenCV refuses (e.g. over its own limits)
        return None
