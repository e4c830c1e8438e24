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

Fit. ``exact`` (the default) refuses an image that is not the fabric's
frame size. The other modes make any size fit, the same way for both
images of a pair (which must then be the same size as each other):
``crop`` and ``pad`` centre the image on the frame, cutting what sticks out
and filling what is missing with black (they differ only in what they are
for: ``crop`` for images larger than the frame, ``pad`` for smaller ones; an
image larger in one dimension and smaller in the other is cut in one and
padded in the other either way, and :class:`Fit` says so); ``scale``
resizes to the largest size that fits inside the frame keeping the aspect
ratio (``cv2.INTER_AREA`` when shrinking, ``INTER_LINEAR`` when enlarging)
and pads the rest with black (letterbox). :func:`fit_pair` does it on
decoded images (the daemon and ``stereocam rectify --fit``);
:func:`decode_pair_fitted` on an upload's fields.

Every refusal is an :class:`UploadError` with the HTTP ``status`` and a
one-line ``message`` naming the field; ``to_json()`` is the response body.
"""
from __future__ import annotations

import io
import threading
import warnings
from dataclasses import dataclass
from typing import IO, TYPE_CHECKING, Any, Callable, Dict, List, Mapping, Optional, Tuple

import cv2
import numpy as np

from ...calibration.image_files import MAX_IMAGE_PIXELS  # larger headers: decompression bombs
from ...overlays.spec import pixel
from ..errors import ApiError
from ..stores.ids import ID_EXAMPLE, valid_id

if TYPE_CHECKING:  # pragma: no cover
    from PIL import Image

__all__ = [
    "UploadError",
    "decode_image",
    "decode_pair",
    "parse_json_capture_request",
    "parse_json_replay_request",
    "Fit",
    "FIT_MODES",
    "parse_fit",
    "plan_fit",
    "apply_fit",
    "fit_pair",
    "decode_pair_fitted",
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


def _opener(fmt: str) -> Callable[[IO[bytes]], Image.Image]:
    """Pillow's reader of ``fmt``, imported at the first upload: not at start (the board's A9 pays for it)."""
    from PIL import BmpImagePlugin, JpegImagePlugin, PngImagePlugin, TiffImagePlugin

    openers: Dict[str, Callable[[IO[bytes]], Image.Image]] = {
        "PNG": PngImagePlugin.PngImageFile,
        "BMP": BmpImagePlugin.BmpImageFile,
        "JPEG": JpegImagePlugin.JpegImageFile,
        "TIFF": TiffImagePlugin.TiffImageFile,
    }
    return openers[fmt]


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
        image = _opener(fmt)(io.BytesIO(data))
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
    if opened.fmt == "PNG" and data[12:16] == b"IHDR":
        return data[24]  # the header's own depth: older Pillows open 16-bit gray as mode "I" (32-bit)
    if image.mode in _HIGH_DEPTH_MODES:
        return _HIGH_DEPTH_MODES[image.mode]
    if opened.fmt == "TIFF":
        from PIL import TiffImagePlugin

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
    demosaic stage computes it (:func:`...overlays.spec.pixel.rgby`).

    Raises :class:`UploadError`: 400 for missing, unknown or extra fields
    (named), and everything :func:`decode_image` raises, naming the field.
    The fields are checked in order (``left`` before ``right``).
    """
    width, height = _check_size(size)
    if _check_fields(fields) == SBS_FIELD:
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
        left = decode_image(fields["left"], field="left", max_pixels=max_pixels, max_bytes=max_bytes,
                            size=(width, height))
        right = decode_image(fields["right"], field="right", max_pixels=max_pixels, max_bytes=max_bytes,
                             size=(width, height))
    return _pack(left, right)


def _pack(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    if left.ndim != right.ndim:  # one gray, one colour: both as RGB
        left, right = (np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x for x in (left, right))
    return pixel.pack(pixel.rgby(np.ascontiguousarray(left)), pixel.rgby(np.ascontiguousarray(right)))


def _check_size(size: Tuple[int, int]) -> Tuple[int, int]:
    width, height = int(size[0]), int(size[1])
    if width <= 0 or height <= 0:
        raise ValueError(f"size must be a positive (width, height), got {size!r}")
    return width, height


def _check_fields(fields: Mapping[str, Any]) -> str:
    """``"sbs"`` or ``"pair"``: which fields an upload sent (400 for a wrong set, named)."""
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
        return SBS_FIELD
    missing = [n for n in PAIR_FIELDS if n not in names]
    if missing:
        raise UploadError(400, f"field {missing[0]} is missing: {_FIELDS_TEXT}")
    return "pair"


# -- fit ------------------------------------------------------------------------------------------

FIT_MODES = ("exact", "crop", "pad", "scale")
FIT_HINT = "; or send fit=crop, pad or scale to make it fit"


def parse_fit(value: Optional[str]) -> str:
    """The fit mode named by ``value`` (None or empty: ``exact``); 400 for anything else."""
    if value is None or value == "":
        return "exact"
    if value not in FIT_MODES:
        shown = value if len(value) <= 20 else value[:20] + "..."
        raise UploadError(400, f"unknown fit {shown!r}: use exact, crop, pad or scale")
    return value


@dataclass(frozen=True)
class Fit:
    """How an image of ``source`` size was made the fabric's ``size`` (both ``(width, height)``).

    In order: resized to ``resized`` (by ``scale``; only ``scale`` mode resizes), then
    ``cropped`` pixels cut from its (left, top, right, bottom) and ``padded`` black pixels
    added on each side. The same for both images of a pair.
    """

    mode: str
    source: Tuple[int, int]
    size: Tuple[int, int]
    scale: float = 1.0
    resized: Tuple[int, int] = (0, 0)
    cropped: Tuple[int, int, int, int] = (0, 0, 0, 0)
    padded: Tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def changed(self) -> bool:
        return self.source != self.size

    def text(self) -> str:
        """What was done, in words (``"padded 45 columns (22 left, 23 right) with black; ..."``)."""
        parts: List[str] = []
        if self.resized != self.source:
            how = "shrunk" if self.scale < 1 else "enlarged"
            (sw, sh), (rw, rh) = self.source, self.resized
            parts.append(f"{how} from {sw}x{sh} to {rw}x{rh} (x{self.scale:.4g}, aspect ratio kept)")
        edges = (("cropped", self.cropped, ""), ("padded", self.padded, " with black"))
        for verb, (lt, t, r, b), tail in edges:
            if lt or r:
                cols = "column" if lt + r == 1 else "columns"
                parts.append(f"{verb} {lt + r} {cols} ({lt} left, {r} right){tail}")
            if t or b:
                rows = "row" if t + b == 1 else "rows"
                parts.append(f"{verb} {t + b} {rows} ({t} top, {b} bottom){tail}")
        if not parts:
            return "already the fabric's size: unchanged"
        return "; ".join(parts)

    def to_json(self) -> Dict[str, Any]:
        return {"mode": self.mode, "from": list(self.source), "to": list(self.size),
                "scale": round(self.scale, 6), "resized": list(self.resized),
                "cropped": list(self.cropped), "padded": list(self.padded), "text": self.text()}


def _centre(have: int, want: int) -> Tuple[Tuple[int, int], Tuple[int, int]]:
    """((cut before, cut after), (pad before, pad after)) putting ``have`` pixels centred in ``want``."""
    if have > want:
        before = (have - want) // 2
        return (before, have - want - before), (0, 0)
    before = (want - have) // 2
    return (0, 0), (before, want - have - before)


def plan_fit(mode: str, source: Tuple[int, int], size: Tuple[int, int]) -> Fit:
    """The :class:`Fit` that makes an image of ``source`` size the ``size`` (both ``(width, height)``).

    ``mode`` is one of :data:`FIT_MODES` (``exact`` is only valid when the sizes are
    equal: ValueError otherwise; callers refuse the upload before planning).
    """
    sw, sh = int(source[0]), int(source[1])
    w, h = _check_size(size)
    if sw <= 0 or sh <= 0:
        raise ValueError(f"source must be a positive (width, height), got {source!r}")
    if mode not in FIT_MODES:
        raise ValueError(f"mode must be one of {', '.join(FIT_MODES)}, got {mode!r}")
    if mode == "exact":
        if (sw, sh) != (w, h):
            raise ValueError(f"exact fit of {sw}x{sh} to {w}x{h}")
        return Fit("exact", (sw, sh), (w, h), 1.0, (sw, sh))
    scale, rw, rh = 1.0, sw, sh
    if mode == "scale" and (sw, sh) != (w, h):
        scale = min(w / sw, h / sh)
        rw = max(1, min(w, int(round(sw * scale))))
        rh = max(1, min(h, int(round(sh * scale))))
    (cl, cr), (pl, pr) = _centre(rw, w)
    (ct, cb), (pt, pb) = _centre(rh, h)
    return Fit(mode, (sw, sh), (w, h), scale, (rw, rh), (cl, ct, cr, cb), (pl, pt, pr, pb))


def apply_fit(image: np.ndarray, fit: Fit) -> np.ndarray:
    """``image`` (``(H, W)`` or ``(H, W, C)`` uint8 of ``fit.source`` size) made ``fit.size``: a new array."""
    h0, w0 = image.shape[:2]
    if (w0, h0) != fit.source:
        raise ValueError(f"the image is {w0}x{h0}, the fit was planned for {fit.source[0]}x{fit.source[1]}")
    if fit.resized != fit.source:
        interpolation = cv2.INTER_AREA if fit.scale < 1 else cv2.INTER_LINEAR
        image = cv2.resize(np.ascontiguousarray(image), fit.resized, interpolation=interpolation)
    rh, rw = image.shape[:2]
    cl, ct, cr, cb = fit.cropped
    image = image[ct:rh - cb, cl:rw - cr]
    w, h = fit.size
    if image.shape[:2] == (h, w):
        return np.array(image, dtype=np.uint8, copy=True)
    pl, pt, _, _ = fit.padded
    out = np.zeros((h, w) + image.shape[2:], dtype=np.uint8)
    out[pt:pt + image.shape[0], pl:pl + image.shape[1]] = image
    return out


def fit_pair(left: np.ndarray, right: np.ndarray, size: Tuple[int, int], mode: str, *,
             names: Tuple[str, str] = PAIR_FIELDS) -> Tuple[np.ndarray, np.ndarray, Fit]:
    """Both images of a pair made ``size`` by ``mode``: ``(left, right, fit)`` (new arrays).

    Raises :class:`UploadError` 400 when the two images differ in size, 422 for ``exact``
    when they are not ``size`` (the message names the image, as :func:`decode_image` does).
    """
    w, h = _check_size(size)
    (lh, lw), (rh, rw) = left.shape[:2], right.shape[:2]
    if (lw, lh) != (rw, rh):
        raise UploadError(400, f"{names[0]} is {lw}x{lh} but {names[1]} is {rw}x{rh}: the two images of a "
                               f"pair must be the same size")
    mode = parse_fit(mode)
    if mode == "exact" and (lw, lh) != (w, h):
        raise UploadError(422, f"{names[0]} is {lw}x{lh}, the fabric takes {w}x{h}{FIT_HINT}")
    fit = plan_fit(mode, (lw, lh), (w, h))
    return apply_fit(left, fit), apply_fit(right, fit), fit


def decode_pair_fitted(
    fields: Mapping[str, Any],
    *,
    size: Tuple[int, int],
    fit: str = "exact",
    max_pixels: int = MAX_IMAGE_PIXELS,
    max_bytes: int = MAX_UPLOAD_BYTES,
) -> Tuple[np.ndarray, Fit]:
    """:func:`decode_pair` with a fit: ``(stream frame, Fit)``.

    ``exact`` is :func:`decode_pair` (422 before decoding for a wrong size, its message
    ending with how to fit instead). The other modes decode any size (the limits on
    bytes and pixels still hold), then :func:`fit_pair` both images: a side-by-side
    image is split into its halves first (an odd width is 422). 400 when ``left`` and
    ``right`` differ in size; 400 for an unknown ``fit``.
    """
    width, height = _check_size(size)
    mode = parse_fit(fit)
    if mode == "exact":
        try:
            frame = decode_pair(fields, size=size, max_pixels=max_pixels, max_bytes=max_bytes)
        except UploadError as exc:
            if exc.status == 422:
                raise UploadError(422, exc.message + FIT_HINT) from None
            raise
        return frame, plan_fit("exact", (width, height), (width, height))
    kind = _check_fields(fields)

    def any_size(w: int, h: int) -> Optional[UploadError]:
        return None

    if kind == SBS_FIELD:
        both = _decode(fields[SBS_FIELD], SBS_FIELD, max_pixels, max_bytes, any_size)
        bw = both.shape[1]
        if bw % 2:
            raise UploadError(422, f"{SBS_FIELD} is {bw}x{both.shape[0]}: an odd width cannot be split into "
                                   f"two equal halves (left camera on the left)")
        left, right = both[:, :bw // 2], both[:, bw // 2:]
        names = ("the left half of sbs", "the right half")
    else:
        left = _decode(fields["left"], "left", max_pixels, max_bytes, any_size)
        right = _decode(fields["right"], "right", max_pixels, max_bytes, any_size)
        names = PAIR_FIELDS
    left, right, done = fit_pair(left, right, (width, height), mode, names=names)
    return _pack(left, right), done


def parse_json_replay_request(obj: Any) -> Tuple[str, str]:
    """``("capture", id)`` or ``("recording", id)`` from a JSON body naming one of them.

    Checks the shape and the id's form only (recordings are named like captures);
    400 otherwise.
    """
    if isinstance(obj, dict) and set(obj) == {"recording"}:
        value = obj["recording"]
        if not isinstance(value, str):
            raise UploadError(400, f'"recording" must be a recording id string like {ID_EXAMPLE}, '
                                   f'got {type(value).__name__}')
        if not valid_id(value):
            shown = value if len(value) <= 40 else value[:40] + "..."
            raise UploadError(400, f"invalid recording id {shown!r}: recording ids look like {ID_EXAMPLE}")
        return "recording", value
    if isinstance(obj, dict) and "recording" in obj:
        extra = ", ".join(repr(str(k)[:40]) for k in obj if k != "recording")
        raise UploadError(400, f'unknown key(s) {extra}: send only {{"recording": "<id>"}}')
    return "capture", parse_json_capture_request(obj)


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
    if not valid_id(value):
        shown = value if len(value) <= 40 else value[:40] + "..."
        raise UploadError(400, f"invalid capture id {shown!r}: capture ids look like {ID_EXAMPLE}")
    return value

