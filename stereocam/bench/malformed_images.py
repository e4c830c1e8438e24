"""Images for the upload cases: good ones of any size and format, and headers that lie about the size."""
from __future__ import annotations

import io
import struct
import zlib
from typing import Callable

import numpy as np

from .raw_http import RobustnessBenchError


def smooth_picture(w: int, h: int, seed: int) -> np.ndarray:
    """A smooth random RGB picture (JPEG keeps it recognisable, PNG compresses it somewhat)."""
    import cv2

    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (max(1, h // 16), max(1, w // 16), 3), dtype=np.uint8)
    return np.ascontiguousarray(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR))


def encode_image(image: np.ndarray, fmt: str) -> bytes:
    import cv2

    ok, buf = cv2.imencode(fmt, image)
    if not ok:  # pragma: no cover - OpenCV refuses only invalid images
        raise RobustnessBenchError(f"OpenCV could not encode a {image.shape} image as {fmt}")
    return buf.tobytes()


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_claiming(w: int, h: int, *, depth: int = 8) -> bytes:
    """A PNG whose header claims ``w`` x ``h`` pixels, with a few bytes of data (a decompression bomb)."""
    ihdr = struct.pack(">IIBBBBB", w, h, depth, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(b"\0" * 64))
            + _png_chunk(b"IEND", b""))


def jpeg_claiming(jpeg: bytes, w: int, h: int) -> bytes:
    """``jpeg`` with its frame header (SOF0) claiming ``w`` x ``h`` pixels."""
    at = jpeg.find(b"\xff\xc0")
    if at < 0:
        raise RobustnessBenchError("the JPEG has no SOF0 marker")
    return jpeg[:at + 5] + struct.pack(">HH", h, w) + jpeg[at + 9:]


def bmp_claiming(w: int, h: int) -> bytes:
    """A 24-bit BMP header claiming ``w`` x ``h`` pixels, with 64 bytes of pixels."""
    info = struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + 40 + 64, 0, 0, 54) + info + b"\0" * 64


def tiff_claiming(w: int, h: int) -> bytes:
    """A little-endian RGB TIFF whose tags claim ``w`` x ``h`` pixels, with 64 bytes of pixels."""
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 2),
               (273, 4, 1, 8 + 2 + 12 * 10 + 4), (277, 3, 1, 3), (278, 4, 1, h), (279, 4, 1, 64),
               (284, 3, 1, 1)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHII", tag, kind, count, value) if kind == 4
        else struct.pack("<HHIHH", tag, kind, count, value, 0)
        for tag, kind, count, value in entries) + struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", 8) + ifd + b"\0" * 64


def pil_bytes(save: Callable[[io.BytesIO], None]) -> bytes:
    buf = io.BytesIO()
    save(buf)
    return buf.getvalue()
