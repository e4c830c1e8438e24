"""Virtual-camera uploads: untrusted image bytes in, a checked stream frame out.

The daemon hands this module what a client sent: multipart fields ``left``
and ``right`` (a stereo pair) or ``sbs`` (one side-by-side image, left camera
in the left half), or a JSON body ``{"capture": "<id>"}`` to replay a stored
capture. Everything here is pure and synchronous: it reads only the bytes it
is given and touches nothing on disk, so a refused upload changes nothing.

Accepted: PNG, BMP, JPEG and TIFF (recognised by their first bytes, not by
a file name or content type), 8 bits per channel, gray or RGB. Alpha is
dropped (not composited), palette images become RGB, 1-bit images gray
(0/255), CMYK and YCbCr are converted to RGB. Multi-page TIFF, animated
PNG, 16-bit samples and other pixel types are refused with advice. The JPEG/TIFF
orientation tag is ignored: the pixels are used as stored, as the cameras
deliver them.

Safety: the image size is read from the header and refused (413) above
``max_pixels`` before any pixel is decoded; a wrong size (422) is also
refused before decoding; truncated or corrupt data gives 400. Pillow's
warnings about odd files (corrupt TIFF tags, APNG, ...) are suppressed
while decoding: they never escape as Python warnings. Because Python's
warning filters are process-global, decoding holds a module lock, so
decodes run one at a time (a 752x480 pair decodes in milliseconds).

Every refusal is an :class:`UploadError` with the HTTP ``status`` and a
one-line ``message`` naming the field; ``to_json()`` is the response body.
"""
from __future__ import annotations

import io
import threading
import warnings
from dataclasses import dataclass
from typing import IO, Any, Callable, Dict, Mapping, Optional, Tuple

import numpy as np
from PIL import BmpImagePlugin, Image, JpegImagePlugin, PngImagePlugin, TiffImagePlugin

from ..overlays.spec import pixel
from .captures import ID_EXAMPLE, CaptureStore
from .errors import ApiError

__all__ = [
    "UploadError",
    "decode_image",
    "decode_pair",
    "parse_json_capture_request",
    "MAX_UPLOAD_BYTES",
    "MAX_IMAGE_PIXELS",
    "ACCEPTED_FORMATS",
    "PAIR_FIELDS",
    "SBS_FIELD",
]

MAX_UPLOAD_BYTES = 16 * 1024 * 1024
"""Largest request body (all fields together) the daemon should accept: aiohttp's ``client_max_size``.

Also the default limit of one field in :func:`decode_image`. Two 752x480
pairs of uncompressed 24-bit BMP or TIFF need about 2.2 MB.
"""

MAX_IMAGE_PIXELS = 4096 * 4096
"""Largest image (width x height) decoded at all; larger headers are refused as decompression bombs."""

ACCEPTED_FORMATS = ("PNG", "BMP", "JPEG", "TIFF")
PAIR_FIELDS = ("left", "right")
SBS_FIELD = "sbs"
_ACCEPTED_TEXT = "PNG, BMP, JPEG or TIFF"
_FIELDS_TEXT = "send the fields left and right (a stereo pair) or one field sbs (a side-by-side image)"

_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "PNG"),
    (b"\xff\xd8\xff", "JPEG"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"BM", "BMP"),
)
_OTHER_MAGIC = (
    (b"GIF87a", "GIF"),
    (b"GIF89a", "GIF"),
    (b"II+\x00", "BigTIFF"),
    (b"MM\x00+", "BigTIFF"),
    (b"\x00\x00\x00\x0cjP  \r\n\x87\n", "JPEG 2000"),
    (b"\xff\x4f\xff\x51", "JPEG 2000"),
    (b"\xff\x0a", "JPEG XL"),
    (b"\x00\x00\x00\x0cJXL \r\n\x87\n", "JPEG XL"),
    (b"%PDF", "PDF"),
    (b"\x00\x00\x01\x00", "ICO"),
    (b"8BPS", "Photoshop"),
    (b"P1", "PBM"), (b"P2", "PGM"), (b"P3", "PPM"), (b"P4", "PBM"), (b"P5", "PGM"), (b"P6", "PPM"),
    (b"<svg", "SVG"),
    (b"<?xml", "XML/SVG"),
    (b"qoif", "QOI"),
)
_OPENERS: Dict[str, Callable[[IO[bytes]], Image.Image]] = {
    "PNG": PngImagePlugin.PngImageFile,
    "BMP": BmpImagePlugin.BmpImageFile,
    "JPEG": JpegImagePlugin.JpegImageFile,
    "TIFF": TiffImagePlugin.TiffImageFile,
}
_HIGH_DEPTH_MODES = {"I": 32, "F": 32, "I;32": 32, "I;32B": 32, "I;32L": 32,
                     "I;16": 16, "I;16B": 16, "I;16L": 16, "I;16N": 16, "I;16S": 16}
_HIGH_DEPTH_ADVICE = (
    "the cameras deliver 8 bits per channel: save it with 8 bits per channel "
    "(e.g. ImageMagick -depth 8, or numpy (img >> 8).astype(np.uint8))"
)

_DECODE_LOCK = threading.Lock()


class UploadError(ApiError):
    """An upload that is refused: ``status`` is the HTTP status, ``message`` one line for the user."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(" ".join(str(message).split()), status=status)


def _sniff(data: bytes, field: str) -> str:
    for magic, fmt in _MAGIC:
        if data.startswith(magic):
            return fmt
    kind = next((name for magic, name in _OTHER_MAGIC if data.startswith(magic)), None)
    if kind is None and data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        kind = "WebP"
    if kind is None and data[4:8] == b"ftyp":
        brand = data[8:12]
        kind = "HEIF/AVIF" if brand[:3] in (b"hei", b"hev", b"mif", b"msf", b"avi") else "MP4/QuickTime"
    what = f"a {kind} file" if kind else "not an image this server recognises"
    raise UploadError(415, f"{field}: {what}; upload a {_ACCEPTED_TEXT} image")


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if not text:
        return type(exc).__name__
    return text if len(text) <= 120 else text[:117] + "..."


@dataclass
class _Opened:
    image: Image.Image
    fmt: str

    @property
    def size(self) -> Tuple[int, int]:
        w, h = self.image.size
        return int(w), int(h)


def _open(data: bytes, field: str, max_pixels: int, max_bytes: int) -> _Opened:
    """Header only: format, size and bomb checks. Caller holds ``_DECODE_LOCK`` and closes the image."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"field {field}: expected bytes, got {type(data).__name__}")
    if len(data) == 0:
        raise UploadError(400, f"{field} is empty: upload a {_ACCEPTED_TEXT} image in it")
    if len(data) > max_bytes:
        raise UploadError(
            413, f"{field} is {len(data)} bytes, more than the {max_bytes} accepted: upload a smaller image"
        )
    data = bytes(data)
    fmt = _sniff(data, field)
    try:
        # The plugin class directly: Image.open would add its own decompression-bomb
        # check (a warning, or an error past 2x its limit) before ours.
        image = _OPENERS[fmt](io.BytesIO(data))
    except Exception as exc:  # untrusted bytes: a decoder fails in many ways (SyntaxError, struct.error, ...)
        raise UploadError(400, f"{field}: the {fmt} image is truncated or corrupt ({_reason(exc)})") from None
    opened = _Opened(image, fmt)
    try:
        w, h = opened.size
        if w <= 0 or h <= 0:
            raise UploadError(400, f"{field}: the {fmt} image is corrupt (it claims {w}x{h} pixels)")
        if w * h > max_pixels:
            raise UploadError(
                413,
                f"{field}: the image header claims {w}x{h} pixels ({w * h / 1e6:.1f} megapixels), more "
                f"than the {max_pixels / 1e6:.1f} megapixels accepted (a decompression bomb?); "
                f"upload a smaller image",
            )
        try:
            frames = int(getattr(image, "n_frames", 1))  # TIFF pages, APNG frames
        except Exception as exc:
            raise UploadError(
                400, f"{field}: the {fmt} image is truncated or corrupt ({_reason(exc)})"
            ) from None
        if frames > 1:
            raise UploadError(415, f"{field}: the {fmt} file holds {frames} images; upload a single image")
    except BaseException:
        image.close()
        raise
    return opened


def _bit_depth(opened: _Opened, data: bytes) -> int:
    """Bits per sample as stored (Pillow silently reduces 16-bit colour PNG and TIFF to 8 bits)."""
    image = opened.image
    if image.mode in _HIGH_DEPTH_MODES:
        return _HIGH_DEPTH_MODES[image.mode]
    if opened.fmt == "PNG" and data[12:16] == b"IHDR":
        return data[24]
    if opened.fmt == "TIFF":
        bits = getattr(image, "tag_v2", {}).get(TiffImagePlugin.BITSPERSAMPLE, 8)
        values = bits if isinstance(bits, tuple) else (bits,)
        return max((int(b) for b in values), default=8)
    return 8


def _to_array(opened: _Opened, field: str) -> np.ndarray:
    """Decode the pixels to an (H, W) gray or (H, W, 3) RGB uint8 array (caller holds ``_DECODE_LOCK``)."""
    image, fmt = opened.image, opened.fmt
    try:
        image.load()
    except Exception as exc:  # untrusted bytes: OSError("image file is truncated"), SyntaxError, ...
        raise UploadError(400, f"{field}: the {fmt} image is truncated or corrupt ({_reason(exc)})") from None
    mode = image.mode
    try:
        if mode in ("L", "RGB"):
            out = image
        elif mode in ("1", "LA", "La"):
            out = image.convert("L")
        elif mode in ("P", "PA"):
            out = image.convert("RGBA").convert("RGB")
        elif mode in ("RGBA", "RGBa", "RGBX", "CMYK", "YCbCr"):
            out = image.convert("RGB")
        else:
            raise UploadError(
                415, f"{field}: {fmt} images with {mode} pixels are not supported; upload 8-bit gray or RGB"
            )
        array = np.array(out, dtype=np.uint8)
    except UploadError:
        raise
    except Exception as exc:
        raise UploadError(400, f"{field}: the {fmt} image cannot be decoded ({_reason(exc)})") from None
    return np.ascontiguousarray(array)


def decode_image(
    data: bytes,
    *,
    field: str,
    max_pixels: int = MAX_IMAGE_PIXELS,
    max_bytes: int = MAX_UPLOAD_BYTES,
    size: Optional[Tuple[int, int]] = None,
) -> np.ndarray:
    """Decode one uploaded image to a fresh ``(H, W)`` gray or ``(H, W, 3)`` RGB uint8 array.

    ``field`` names the upload in messages. ``size = (width, height)``, if
    given, is the required size: anything else is refused (422) before the
    pixels are decoded. Raises :class:`UploadError`: 400 empty, truncated or
    corrupt; 413 more than ``max_bytes`` bytes or ``max_pixels`` pixels;
    415 not PNG/BMP/JPEG/TIFF, 16- or 32-bit, several pages, other pixel types;
    422 wrong size. Thread-safe (see the module doc).
    """
    def wrong_size(w: int, h: int) -> Optional[UploadError]:
        if size is None or (w, h) == (int(size[0]), int(size[1])):
            return None
        return UploadError(422, f"{field} is {w}x{h}, the fabric takes {int(size[0])}x{int(size[1])}")

    return _decode(data, field, max_pixels, max_bytes, wrong_size)


def _decode(
    data: bytes, field: str, max_pixels: int, max_bytes: int,
    wrong_size: Callable[[int, int], Optional[UploadError]],
) -> np.ndarray:
    with _DECODE_LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opened = _open(data, field, max_pixels, max_bytes)
        try:
            refusal = wrong_size(*opened.size)
            if refusal is not None:
                raise refusal
            bits = _bit_depth(opened, bytes(data))
            if bits > 8:
                raise UploadError(415, f"{field} is a {bits}-bit {opened.fmt} image; {_HIGH_DEPTH_ADVICE}")
            return _to_array(opened, field)
        finally:
            opened.image.close()


def decode_pair(
    fields: Mapping[str, Any],
    *,
    size: Tuple[int, int],
    max_pixels: int = MAX_IMAGE_PIXELS,
    max_bytes: int = MAX_UPLOAD_BYTES,
) -> np.ndarray:
    """The ``(H, W, 8)`` uint8 stream frame for the virtual camera from an upload's fields.

    ``fields`` maps field names to their bytes: exactly ``left`` and
    ``right``, or exactly ``sbs``. ``size = (width, height)`` is one camera's
    image size, as the fabric takes it. If one side is gray and the other
    colour, the gray one is used as RGB (R = G = B). Gray is computed as the
    demosaic stage computes it (:func:`..overlays.spec.pixel.rgby`).

    Raises :class:`UploadError`: 400 for missing, unknown or extra fields
    (named), and everything :func:`decode_image` raises, naming the field.
    The fields are checked in order (``left`` before ``right``).
    """
    width, height = int(size[0]), int(size[1])
    if width <= 0 or height <= 0:
        raise ValueError(f"size must be a positive (width, height), got {size!r}")
    names = list(fields)
    unknown = [n for n in names if n not in PAIR_FIELDS and n != SBS_FIELD]
    if unknown:
        shown = ", ".join(repr(str(n)[:40]) for n in unknown)
        raise UploadError(400, f"unknown field(s) {shown}: {_FIELDS_TEXT}")
    if not names:
        raise UploadError(400, f"no image was sent: {_FIELDS_TEXT}")
    if SBS_FIELD in names:
        if len(names) > 1:
            others = " and ".join(n for n in PAIR_FIELDS if n in names)
            raise UploadError(400, f"both {SBS_FIELD} and {others} were sent: {_FIELDS_TEXT}, not both")
        def wrong_size(w: int, h: int) -> Optional[UploadError]:
            if (w, h) == (2 * width, height):
                return None
            odd = " (an odd width cannot be split into two equal halves)" if w % 2 else ""
            return UploadError(
                422,
                f"{SBS_FIELD} is {w}x{h}{odd}, a side-by-side image for the fabric must be "
                f"{2 * width}x{height} (two {width}x{height} halves, left camera on the left)",
            )

        both = _decode(fields[SBS_FIELD], SBS_FIELD, max_pixels, max_bytes, wrong_size)
        left, right = both[:, :width], both[:, width:]
    else:
        missing = [n for n in PAIR_FIELDS if n not in names]
        if missing:
            raise UploadError(400, f"field {missing[0]} is missing: {_FIELDS_TEXT}")
        left = decode_image(fields["left"], field="left", max_pixels=max_pixels, max_bytes=max_bytes,
                            size=(width, height))
        right = decode_image(fields["right"], field="right", max_pixels=max_pixels, max_bytes=max_bytes,
                             size=(width, height))
    if left.ndim != right.ndim:  # one gray, one colour: both as RGB
        left, right = (np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x for x in (left, right))
    return pixel.pack(pixel.rgby(np.ascontiguousarray(left)), pixel.rgby(np.ascontiguousarray(right)))


def parse_json_capture_request(obj: Any) -> str:
    """The capture id of a JSON body ``{"capture": "<id>"}`` (replay that capture's raw pair).

    Checks the shape and the id's form only; whether the capture exists is
    the store's answer (404). Raises :class:`UploadError` (400) otherwise.
    """
    if not isinstance(obj, dict):
        raise UploadError(400, f'send a JSON object {{"capture": "<id>"}}, got {type(obj).__name__}')
    extra = [k for k in obj if k != "capture"]
    if extra:
        shown = ", ".join(repr(str(k)[:40]) for k in extra)
        raise UploadError(400, f'unknown key(s) {shown}: send only {{"capture": "<id>"}}')
    if "capture" not in obj:
        raise UploadError(400, 'key "capture" is missing: send {"capture": "<id>"}')
    value = obj["capture"]
    if not isinstance(value, str):
        raise UploadError(
            400, f'"capture" must be a capture id string like {ID_EXAMPLE}, got {type(value).__name__}'
        )
    if not CaptureStore.valid_id(value):
        shown = value if len(value) <= 40 else value[:40] + "..."
        raise UploadError(400, f"invalid capture id {shown!r}: capture ids look like {ID_EXAMPLE}")
    return value

