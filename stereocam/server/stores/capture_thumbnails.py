"""The small JPEG the capture list shows for each capture."""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ...calibration.image_files import ImageTooLarge, capture_file, check_image_header
from .errors import Damaged, StoreError, gone
from .files import MAX_IMAGE_FILE_BYTES, read_member

__all__ = ["THUMB_FRAMES", "THUMB_WIDTH", "thumbnail_jpeg"]

THUMB_FRAMES = ("rect_left", "raw_left")  # what a thumbnail shows: the first of these that can be read
THUMB_WIDTH = 160  # pixels: the capture list's thumbnails (shown at 80 CSS px, sharp on a 2x screen)
_THUMB_QUALITY = 80


def thumbnail_jpeg(cid: str, folder: Path, width: int = THUMB_WIDTH) -> bytes:
    """The thumbnail of the capture ``cid`` in ``folder``: the first of :data:`THUMB_FRAMES` that reads.

    NotFound if the folder is gone meanwhile; :class:`.store_errors.Damaged` when no image can be read.
    """
    image = None
    for name in map(capture_file, THUMB_FRAMES):
        try:
            data = read_member(folder, name, MAX_IMAGE_FILE_BYTES)
        except FileNotFoundError:
            continue
        except (OSError, ValueError):
            continue
        try:
            check_image_header(data, name)
        except ImageTooLarge:  # no capture of ours: treated as unreadable
            continue
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is not None:
            break
    if image is None:
        if not os.path.isdir(folder):
            raise gone("capture", cid)
        raise Damaged(f"capture {cid} has no readable "
                             f"{' or '.join(map(capture_file, THUMB_FRAMES))} for a thumbnail")
    h, w = image.shape[:2]
    tw = max(1, min(int(width), w))
    th = max(1, round(h * tw / w))
    small = cv2.resize(image, (tw, th), interpolation=cv2.INTER_AREA) if tw != w else image
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, _THUMB_QUALITY])
    if not ok:
        raise StoreError(f"cannot encode the thumbnail of capture {cid}")
    return buf.tobytes()
