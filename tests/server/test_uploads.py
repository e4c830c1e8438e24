"""Virtual-camera uploads: every accepted format decodes exactly, every bad upload gets its 4xx."""
from __future__ import annotations

import io
import struct
import threading
import warnings
from typing import Any, Dict, List

import cv2
import numpy as np
import pytest
from PIL import Image

from stereocam.overlays.spec import pixel
from stereocam.server.http import uploads
from stereocam.server.http.uploads import (
    MAX_UPLOAD_BYTES,
    UploadError,
    decode_image,
    decode_pair,
    parse_json_capture_request,
)

from ..sample import png_claiming

pytestmark = pytest.mark.armhf

W, H = 24, 16
SIZE = (W, H)


def rgb_image(seed: int, w: int = W, h: int = H) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def gray_image(seed: int, w: int = W, h: int = H) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)


def encode(array: np.ndarray, fmt: str, **params: Any) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format=fmt, **params)
    return buf.getvalue()


def bmp_claiming(w: int, h: int) -> bytes:
    """A 24-bit BMP header claiming w x h pixels, with 16 bytes of pixel data."""
    info = struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 54 + 16, 0, 0, 54) + info + b"\x00" * 16


def tiff_with_a_broken_tag() -> bytes:
    """A valid 4x2 gray TIFF whose last tag (Artist) points past the end: Pillow warns about it."""
    pix = bytes(range(0, 80, 10))
    entries = [(256, 3, 1, 4), (257, 3, 1, 2), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
               (273, 4, 1, 0), (277, 3, 1, 1), (278, 3, 1, 2), (279, 4, 1, len(pix)), (315, 2, 5000, 100000)]
    data_off = 8 + 2 + 12 * len(entries) + 4
    out = b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        value = data_off if tag == 273 else value
        if typ == 3:  # SHORT, left-justified in the 4-byte value field
            out += struct.pack("<HHIHH", tag, typ, count, value, 0)
        else:
            out += struct.pack("<HHII", tag, typ, count, value)
    return out + struct.pack("<I", 0) + pix


def refused(status: int, data: Any, **kw: Any) -> str:
    kw.setdefault("field", "left")
    with pytest.raises(UploadError) as err:
        decode_image(data, **kw)
    assert err.value.status == status, err.value.message
    assert "\n" not in err.value.message and len(err.value.message) < 300
    assert err.value.to_json() == {"error": err.value.message} and str(err.value) == err.value.message
    return err.value.message


# -- decode_image: accepted formats -------------------------------------------

@pytest.mark.parametrize("fmt, params", [
    ("PNG", {}), ("BMP", {}), ("TIFF", {}), ("TIFF", {"compression": "tiff_lzw"}),
    ("TIFF", {"compression": "tiff_adobe_deflate"}),
])
def test_lossless_formats_decode_exactly(fmt: str, params: Dict[str, Any]) -> None:
    rgb, gray = rgb_image(1), gray_image(2)
    out = decode_image(encode(rgb, fmt, **params), field="left")
    assert out.dtype == np.uint8 and out.shape == (H, W, 3) and out.flags.writeable
    assert np.array_equal(out, rgb)
    out = decode_image(encode(gray, fmt, **params), field="left")
    assert out.shape == (H, W) and np.array_equal(out, gray)


def test_jpeg_decodes_like_pillow() -> None:
    yy, xx = np.mgrid[0:H, 0:W]
    smooth = np.dstack([xx * 10, yy * 15, (xx + yy) * 6]).astype(np.uint8)
    for array in (smooth, smooth[..., 1].copy()):
        data = encode(array, "JPEG", quality=95, subsampling=0)
        out = decode_image(data, field="right")
        with Image.open(io.BytesIO(data)) as im:
            assert np.array_equal(out, np.asarray(im))
        assert out.shape == array.shape
        assert np.max(np.abs(out.astype(int) - array)) < 8


def test_opencv_encoded_files_decode_too() -> None:
    rgb = rgb_image(5)
    for ext in (".png", ".bmp", ".tiff"):
        ok, buf = cv2.imencode(ext, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        assert ok
        assert np.array_equal(decode_image(buf.tobytes(), field="left"), rgb), ext


def test_alpha_is_dropped_palette_becomes_rgb_bilevel_becomes_gray() -> None:
    rgb = rgb_image(6)
    rgba = np.dstack([rgb, np.full((H, W), 7, np.uint8)])
    assert np.array_equal(decode_image(encode(rgba, "PNG"), field="left"), rgb)
    assert np.array_equal(decode_image(encode(rgba, "TIFF"), field="left"), rgb)
    gray = gray_image(7)
    la = Image.merge("LA", [Image.fromarray(gray), Image.fromarray(np.zeros_like(gray))])
    buf = io.BytesIO()
    la.save(buf, format="PNG")
    assert np.array_equal(decode_image(buf.getvalue(), field="left"), gray)

    palette = np.array([[0, 0, 0], [255, 0, 0], [0, 255, 0], [10, 20, 30]], np.uint8)
    index = np.random.default_rng(8).integers(0, 4, (H, W), dtype=np.uint8)
    im = Image.new("P", SIZE)
    im.putdata(index.ravel().tolist())
    im.putpalette(palette.ravel().tolist() + [0] * (768 - palette.size))
    for params in ({}, {"transparency": 0}, {"transparency": bytes([0, 128, 255, 255])}):
        buf = io.BytesIO()
        im.save(buf, format="PNG", **params)
        out = decode_image(buf.getvalue(), field="left")
        assert out.shape == (H, W, 3) and np.array_equal(out, palette[index]), params

    bits = gray_image(9) > 127
    buf = io.BytesIO()
    Image.fromarray(bits).save(buf, format="PNG")
    out = decode_image(buf.getvalue(), field="left")
    assert out.shape == (H, W) and np.array_equal(out, np.where(bits, 255, 0))


def test_cmyk_jpeg_is_converted_to_rgb() -> None:
    buf = io.BytesIO()
    Image.new("CMYK", SIZE, (0, 255, 255, 0)).save(buf, format="JPEG", quality=100)
    out = decode_image(buf.getvalue(), field="left")
    assert out.shape == (H, W, 3) and abs(int(out[0, 0, 0]) - 255) < 4 and out[0, 0, 1] < 4


def test_pillow_warnings_never_escape() -> None:
    data = tiff_with_a_broken_tag()
    with pytest.raises(UserWarning):  # pytest makes warnings errors: Pillow does warn about this file
        with Image.open(io.BytesIO(data)) as im:
            im.load()
    filters = list(warnings.filters)
    out = decode_image(data, field="left")
    assert np.array_equal(out, np.arange(0, 80, 10, dtype=np.uint8).reshape(2, 4))
    assert warnings.filters == filters


# -- decode_image: refusals -----------------------------------------------------

def test_empty_field() -> None:
    assert refused(400, b"", field="sbs") == "sbs is empty: upload a PNG, BMP, JPEG or TIFF image in it"


@pytest.mark.parametrize("data, kind", [
    (encode(rgb_image(1), "GIF"), "a GIF file"),
    (b"RIFF\x24\x00\x00\x00WEBPVP8 ", "a WebP file"),
    (b"%PDF-1.7\n", "a PDF file"),
    (b"II+\x00\x08\x00\x00\x00", "a BigTIFF file"),
    (b"\x00\x00\x00\x18ftypheic", "a HEIF/AVIF file"),
    (np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes(),
     "not an image this server recognises"),
    (b"hello world", "not an image this server recognises"),
    (b"\x89PN", "not an image this server recognises"),
])
def test_unknown_formats_are_415(data: bytes, kind: str) -> None:
    assert refused(415, data) == f"left: {kind}; upload a PNG, BMP, JPEG or TIFF image"


@pytest.mark.parametrize("fmt", ["PNG", "BMP", "JPEG", "TIFF"])
@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_truncated_files_are_400(fmt: str, keep: float) -> None:
    data = encode(rgb_image(2, 64, 48), fmt)
    cut = data[: int(len(data) * keep)]
    message = refused(400, cut, field="right")
    assert message.startswith(f"right: the {fmt} image is truncated or corrupt (")


@pytest.mark.parametrize("fmt", ["PNG", "BMP", "JPEG", "TIFF"])
def test_signature_then_garbage_is_400(fmt: str) -> None:
    magic = {"PNG": b"\x89PNG\r\n\x1a\n", "BMP": b"BM", "JPEG": b"\xff\xd8\xff", "TIFF": b"II*\x00"}[fmt]
    garbage = np.random.default_rng(3).integers(0, 256, 2000, dtype=np.uint8).tobytes()
    assert refused(400, magic + garbage).startswith(f"left: the {fmt} image is truncated or corrupt (")


def test_corrupt_png_data_is_400() -> None:
    data = bytearray(encode(rgb_image(4, 64, 48), "PNG"))
    start = data.index(b"IDAT") + 4
    for i in range(start + 10, start + 200):
        data[i] ^= 0x5A
    assert refused(400, bytes(data)).startswith("left: the PNG image is truncated or corrupt (")


@pytest.mark.parametrize("data", [png_claiming(50000, 50000), bmp_claiming(50000, 50000)])
def test_decompression_bombs_are_413_before_decoding(data: bytes) -> None:
    assert len(data) < 200
    message = refused(413, data)
    assert message == (
        "left: the image header claims 50000x50000 pixels (2500.0 megapixels), more than the 16.8 megapixels "
        "accepted (a decompression bomb?); upload a smaller image"
    )


def test_max_pixels_is_the_callers() -> None:
    data = encode(rgb_image(5, 64, 48), "PNG")
    assert refused(413, data, max_pixels=64 * 48 - 1).startswith("left: the image header claims 64x48 pixels")
    assert decode_image(data, field="left", max_pixels=64 * 48).shape == (48, 64, 3)


def test_oversized_bodies_are_413() -> None:
    data = encode(rgb_image(6), "BMP")
    assert refused(413, data, max_bytes=100) == (
        f"left is {len(data)} bytes, more than the 100 accepted: upload a smaller image"
    )
    assert MAX_UPLOAD_BYTES == 16 * 1024 * 1024


def test_sixteen_bit_images_are_415_with_advice() -> None:
    for array in (np.full((H, W), 4000, np.uint16), np.full((H, W, 3), 4000, np.uint16)):
        for ext in (".png", ".tiff"):
            ok, buf = cv2.imencode(ext, array)
            assert ok
            message = refused(415, buf.tobytes())
            fmt = "PNG" if ext == ".png" else "TIFF"
            assert message.startswith(f"left is a 16-bit {fmt} image; the cameras deliver 8 bits per channel")
            assert "-depth 8" in message


def test_float_tiff_and_multi_image_files_are_415() -> None:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((H, W), np.float32)).save(buf, format="TIFF")
    assert refused(415, buf.getvalue()).startswith("left is a 32-bit TIFF image")
    buf = io.BytesIO()
    frames = [Image.fromarray(rgb_image(i)) for i in range(3)]
    frames[0].save(buf, format="TIFF", save_all=True, append_images=frames[1:])
    assert refused(415, buf.getvalue()) == "left: the TIFF file holds 3 images; upload a single image"
    buf = io.BytesIO()
    frames[0].save(buf, format="PNG", save_all=True, append_images=frames[1:])  # animated PNG
    assert refused(415, buf.getvalue()) == "left: the PNG file holds 3 images; upload a single image"


def test_wrong_size_is_422_before_decoding() -> None:
    data = encode(rgb_image(7, 20, 16), "PNG")
    assert refused(422, data, size=SIZE) == "left is 20x16, the fabric takes 24x16"
    truncated = data[: len(data) // 2]  # the size is refused from the header alone
    assert refused(422, truncated, size=SIZE, field="right") == "right is 20x16, the fabric takes 24x16"


def test_non_bytes_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="expected bytes"):
        decode_image("a string", field="left")  # type: ignore[arg-type]


# -- decode_pair --------------------------------------------------------------------

def test_pair_of_colour_images() -> None:
    left, right = rgb_image(10), rgb_image(11)
    frame = decode_pair({"left": encode(left, "PNG"), "right": encode(right, "BMP")}, size=SIZE)
    assert frame.shape == (H, W, 8) and frame.dtype == np.uint8
    assert np.array_equal(frame, pixel.pack(pixel.rgby(left), pixel.rgby(right)))
    assert np.array_equal(frame[..., 3], pixel.gray_of(left))


def test_pair_of_gray_images_and_mixed() -> None:
    gl, gr = gray_image(12), gray_image(13)
    frame = decode_pair({"left": encode(gl, "PNG"), "right": encode(gr, "TIFF")}, size=SIZE)
    assert np.array_equal(frame, pixel.pack(pixel.rgby(gl), pixel.rgby(gr)))
    colour = rgb_image(14)
    frame = decode_pair({"right": encode(colour, "PNG"), "left": encode(gl, "PNG")}, size=SIZE)
    assert np.array_equal(frame[..., pixel.LEFT], pixel.rgby(np.dstack([gl, gl, gl])))
    assert np.array_equal(frame[..., pixel.RIGHT], pixel.rgby(colour))


def test_side_by_side() -> None:
    both = rgb_image(15, 2 * W, H)
    frame = decode_pair({"sbs": encode(both, "PNG")}, size=SIZE)
    assert np.array_equal(frame, pixel.pack(pixel.rgby(both[:, :W]), pixel.rgby(both[:, W:])))
    gray = gray_image(16, 2 * W, H)
    frame = decode_pair({"sbs": bytearray(encode(gray, "TIFF"))}, size=SIZE)
    assert np.array_equal(frame[..., 0], gray[:, :W]) and np.array_equal(frame[..., 7], gray[:, W:])


def pair_refused(status: int, fields: Dict[str, Any], **kw: Any) -> str:
    with pytest.raises(UploadError) as err:
        decode_pair(fields, size=kw.pop("size", SIZE), **kw)
    assert err.value.status == status, err.value.message
    assert "\n" not in err.value.message
    return err.value.message


GOOD = encode(rgb_image(20), "PNG")
HOW = "send the fields left and right (a stereo pair) or one field sbs (a side-by-side image)"


@pytest.mark.parametrize("fields, message", [
    ({}, f"no image was sent: {HOW}"),
    ({"left": GOOD}, f"field right is missing: {HOW}"),
    ({"right": GOOD}, f"field left is missing: {HOW}"),
    ({"left": GOOD, "right": GOOD, "sbs": GOOD}, f"both sbs and left and right were sent: {HOW}, not both"),
    ({"sbs": GOOD, "left": GOOD}, f"both sbs and left were sent: {HOW}, not both"),
    ({"left": GOOD, "right": GOOD, "depth": GOOD}, f"unknown field(s) 'depth': {HOW}"),
    ({"image": GOOD}, f"unknown field(s) 'image': {HOW}"),
    ({"Left": GOOD, "RIGHT": GOOD}, f"unknown field(s) 'Left', 'RIGHT': {HOW}"),
    ({"left": b"", "right": GOOD}, "left is empty: upload a PNG, BMP, JPEG or TIFF image in it"),
    ({"left": GOOD, "right": b""}, "right is empty: upload a PNG, BMP, JPEG or TIFF image in it"),
])
def test_pair_field_errors_are_400(fields: Dict[str, bytes], message: str) -> None:
    assert pair_refused(400, fields) == message


def test_pair_wrong_sizes_are_422() -> None:
    small = encode(rgb_image(21, 20, 16), "PNG")
    assert pair_refused(422, {"left": small, "right": GOOD}) == "left is 20x16, the fabric takes 24x16"
    assert pair_refused(422, {"left": GOOD, "right": small}) == "right is 20x16, the fabric takes 24x16"
    assert pair_refused(422, {"left": GOOD, "right": GOOD}, size=(752, 480)) == (
        "left is 24x16, the fabric takes 752x480"
    )
    # a pair sent as sbs, or an sbs sent as one side
    assert pair_refused(422, {"sbs": GOOD}) == (
        "sbs is 24x16, a side-by-side image for the fabric must be 48x16 (two 24x16 halves, left camera on "
        "the left)"
    )
    odd = encode(rgb_image(22, 2 * W + 1, H), "PNG")
    assert pair_refused(422, {"sbs": odd}) == (
        "sbs is 49x16 (an odd width cannot be split into two equal halves), a side-by-side image for the "
        "fabric must be 48x16 (two 24x16 halves, left camera on the left)"
    )
    sbs = encode(rgb_image(23, 2 * W, H), "PNG")
    assert pair_refused(422, {"left": sbs, "right": GOOD}) == "left is 48x16, the fabric takes 24x16"


def test_pair_refusals_of_bad_content() -> None:
    gif = encode(rgb_image(1), "GIF")
    assert pair_refused(415, {"left": GOOD, "right": gif}).startswith("right: a GIF file")
    assert pair_refused(400, {"sbs": encode(rgb_image(2, 2 * W, H), "PNG")[:100]}).startswith(
        "sbs: the PNG image is truncated or corrupt")
    assert pair_refused(413, {"sbs": png_claiming(50000, 50000)}).startswith(
        "sbs: the image header claims 50000x50000 pixels")
    assert pair_refused(413, {"left": GOOD, "right": png_claiming(50000, 50000)}).startswith(
        "right: the image header claims 50000x50000 pixels")
    ok, buf = cv2.imencode(".png", np.zeros((H, 2 * W), np.uint16))
    assert pair_refused(415, {"sbs": buf.tobytes()}).startswith("sbs is a 16-bit PNG image")
    assert pair_refused(413, {"left": GOOD, "right": GOOD}, max_bytes=10) == (
        f"left is {len(GOOD)} bytes, more than the 10 accepted: upload a smaller image")


def test_decoding_from_many_threads_at_once() -> None:
    pairs = [(rgb_image(100 + i), gray_image(200 + i)) for i in range(8)]
    uploads_ = [{"left": encode(l_, "PNG"), "right": encode(r_, "TIFF")} for l_, r_ in pairs]
    bad = tiff_with_a_broken_tag()
    results: Dict[int, np.ndarray] = {}
    errors: List[BaseException] = []

    def work(i: int) -> None:
        try:
            for _ in range(5):
                results[i] = decode_pair(uploads_[i], size=SIZE)
                decode_image(bad, field="left")
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    filters = list(warnings.filters)
    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(pairs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors
    assert warnings.filters == filters
    for i, (left, right) in enumerate(pairs):
        assert np.array_equal(results[i], pixel.pack(pixel.rgby(left), pixel.rgby(np.dstack([right] * 3))))


# -- {"capture": id} --------------------------------------------------------------

def test_json_capture_request() -> None:
    cid = "20261122T040512Z-000123-ab12"
    assert parse_json_capture_request({"capture": cid}) == cid


CID = "20261122T040512Z-000123-ab12"
LOOK = f"capture ids look like {CID}"
ONLY = 'send only {"capture": "<id>"}'


@pytest.mark.parametrize("obj, message", [
    ([1], 'send a JSON object {"capture": "<id>"}, got list'),
    ("x", 'send a JSON object {"capture": "<id>"}, got str'),
    (None, 'send a JSON object {"capture": "<id>"}, got NoneType'),
    ({}, 'key "capture" is missing: send {"capture": "<id>"}'),
    ({"capture": CID, "x": 1}, f"unknown key(s) 'x': {ONLY}"),
    ({"id": CID}, f"unknown key(s) 'id': {ONLY}"),
    ({"capture": 5}, f'"capture" must be a capture id string like {CID}, got int'),
    ({"capture": "../x"}, f"invalid capture id '../x': {LOOK}"),
    ({"capture": "%2e%2e"}, f"invalid capture id '%2e%2e': {LOOK}"),
    ({"capture": "/etc/passwd"}, f"invalid capture id '/etc/passwd': {LOOK}"),
    ({"capture": CID + "\n"}, f"invalid capture id '{CID}\\n': {LOOK}"),
    ({"capture": "a" * 5000}, f"invalid capture id '{'a' * 40}...': {LOOK}"),
])
def test_bad_json_capture_requests_are_400(obj: Any, message: str) -> None:
    with pytest.raises(UploadError) as err:
        parse_json_capture_request(obj)
    assert err.value.status == 400 and err.value.message == message


def test_upload_error_messages_are_one_line() -> None:
    err = UploadError(400, "two\nlines  and\ttabs")
    assert err.message == "two lines and tabs" and err.status == 400
    assert uploads.ACCEPTED_FORMATS == ("PNG", "BMP", "JPEG", "TIFF")
