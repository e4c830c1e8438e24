"""Malformed uploads to ``POST /api/virtual-camera``: wrong sizes, broken images, bombs, bad multipart."""
from __future__ import annotations

import base64
import random
from typing import Tuple

import numpy as np

from .malformed_case import CaseBuilder, flip_bits
from .malformed_images import (
    bmp_claiming,
    encode_image,
    jpeg_claiming,
    pil_bytes,
    png_claiming,
    smooth_picture,
    tiff_claiming,
)
from .raw_http import form_part, http_request, multipart

MAX_UPLOAD_BYTES = 16 * 1024 * 1024  # the daemon's default max_upload_bytes


def upload_cases(b: CaseBuilder, frame_size: Tuple[int, int], rng: random.Random) -> None:
    from PIL import Image

    w, h = frame_size
    picture = smooth_picture(w, h, 1)
    good = {fmt: encode_image(picture, fmt) for fmt in (".png", ".jpg", ".bmp", ".tiff")}
    png, jpg = good[".png"], good[".jpg"]

    def pair(left: bytes, right: bytes) -> bytes:
        return multipart([form_part(b"left", left), form_part(b"right", right)])

    def sbs(data: bytes) -> bytes:
        return multipart([form_part(b"sbs", data)])

    # Wrong sizes: refused from the header (422), in every format and either field.
    sizes = [(w - 1, h), (w, h - 1), (w + 1, h), (w, h + 1), (w // 2, h // 2), (h, w), (1, 1), (2 * w, h),
             (w, 1), (1, h), (16, 16), (w + 16, h + 16), (3, 2), (w * 2, h * 2), (640, 480), (1280, 720)]
    for i, (sw, sh) in enumerate(sizes):
        small = smooth_picture(sw, sh, 10 + i)
        for fmt in (".png", ".jpg", ".bmp", ".tiff"):
            wrong = encode_image(small, fmt)
            b.upload(f"{fmt[1:]} {sw}x{sh} as left", pair(wrong, good[fmt]), [422])
            b.upload(f"{fmt[1:]} {sw}x{sh} as right", pair(good[fmt], wrong), [422])
    for sw, sh in ((w, h), (2 * w + 1, h), (2 * w, h + 1), (2 * w - 1, h), (2 * w - 2, h), (4 * w, h)):
        b.upload(f"side by side {sw}x{sh}", sbs(encode_image(smooth_picture(sw, sh, 3), ".png")), [422])
    # Truncated images: 400 (415 while the cut leaves less than the format's magic bytes).
    for fmt, data in good.items():
        for cut in sorted({1, 2, 3, 7, 16, 33, 100} | {rng.randrange(8, len(data) - 1) for _ in range(12)}):
            b.upload(f"{fmt[1:]} cut to {cut} bytes", pair(data[:cut], data), [400, 415])
    # Bytes flipped past the header: the image may still decode (200) or be refused (4xx), never a 5xx.
    for fmt, data in good.items():
        for i in range(12):
            flipped = flip_bits(data, rng, 1 + i % 4, 64)
            b.upload(f"{fmt[1:]} with {1 + i % 4} flipped bytes", pair(flipped, data),
                     [200, 400, 413, 415, 422])
    for i in range(8):  # flips anywhere, headers too
        fmt = (".png", ".jpg")[i % 2]
        b.upload(f"{fmt[1:]} with a flipped header byte", pair(flip_bits(good[fmt], rng, 1, 0), good[fmt]),
                 [200, 400, 413, 415, 422])
    # Decompression bombs: headers claiming more than 16.8 megapixels, refused before decoding.
    claims = [(4097, 4097), (60000, 60000), (65535, 65535), (100000, 200), (2 ** 31 - 1, 1), (8192, 8192)]
    for cw, ch in claims:
        b.upload(f"PNG claiming {cw}x{ch}", pair(png_claiming(cw, ch), jpg), [400, 413])
        b.upload(f"PNG claiming {cw}x{ch} as sbs", sbs(png_claiming(cw, ch)), [400, 413])
        if cw <= 65535 and ch <= 65535:
            b.upload(f"JPEG claiming {cw}x{ch}", pair(jpg, jpeg_claiming(jpg, cw, ch)), [400, 413])
        b.upload(f"BMP claiming {cw}x{ch}", pair(bmp_claiming(cw, ch), jpg), [400, 413])
        b.upload(f"TIFF claiming {cw}x{ch}", pair(tiff_claiming(cw, ch), jpg), [400, 413])
    b.upload("PNG claiming 0x0", pair(png_claiming(0, 0), jpg), [400])
    b.upload("BMP claiming -1x-1", pair(bmp_claiming(-1, -1), jpg), [400, 413, 415, 422])
    # Real bombs: 4096x4096 of zeros is 50 KB of PNG; right size for nothing, refused before decoding.
    zeros = encode_image(np.zeros((4096, 4096), np.uint8), ".png")
    b.upload("a 4096x4096 PNG of zeros", pair(zeros, jpg), [413, 422])
    b.upload("a 4096x4096 PNG of zeros as sbs", sbs(zeros), [413, 422])
    # Formats the fabric does not take.
    gif = pil_bytes(lambda f: Image.fromarray(picture).convert("P").save(f, format="GIF"))
    pages = pil_bytes(lambda f: Image.fromarray(picture).save(
        f, format="TIFF", save_all=True, append_images=[Image.fromarray(picture)]))
    deep_png = encode_image(picture.astype(np.uint16) * 257, ".png")
    others = {"GIF": gif, "WebP magic": b"RIFF\0\0\0\0WEBPVP8 " + b"\0" * 64,
              "PDF": b"%PDF-1.4\n" + b"x" * 64, "JPEG 2000": b"\x00\x00\x00\x0cjP  \r\n\x87\n" + b"\0" * 64,
              "ICO": b"\x00\x00\x01\x00" + b"\0" * 64,
              "PPM": b"P6\n752 480\n255\n" + b"\0" * 64, "SVG": b"<svg xmlns='http://www.w3.org/2000/svg'/>",
              "HTML": b"<html><script>alert(1)</script></html>", "text": b"hello",
              "random bytes": bytes(rng.randrange(256) for _ in range(4096)), "zeros": b"\0" * 4096,
              "HEIF": b"\0\0\0\x18ftypheic" + b"\0" * 64, "BigTIFF": b"II+\x00" + b"\0" * 64,
              "16-bit PNG": deep_png, "two-page TIFF": pages,
              "16-bit PNG header": png_claiming(w, h, depth=16)}
    for name, data in others.items():
        b.upload(f"{name} as left", pair(data, jpg), [400, 415])
        b.upload(f"{name} as sbs", sbs(data), [400, 415, 422])  # 422: a camera-sized image is no sbs
    b.upload("an empty left", pair(b"", jpg), [400])
    b.upload("an empty right", pair(jpg, b""), [400])
    # Broken multipart structure.
    left = form_part(b"left", jpg)
    right = form_part(b"right", jpg)
    b.upload("no boundary parameter", pair(jpg, jpg), [400], ctype=b"multipart/form-data")
    b.upload("an empty boundary", pair(jpg, jpg), [400], ctype=b"multipart/form-data; boundary=")
    b.upload("another boundary", pair(jpg, jpg), [400], ctype=b"multipart/form-data; boundary=other")
    b.upload("no closing boundary", multipart([left, right], end=False), [400])
    b.upload("cut in the middle of a part", pair(jpg, jpg)[:len(jpg) // 2], [400])
    b.upload("no parts", b"--hostileBoundary--\r\n", [400])
    b.upload("an empty body", b"", [400])
    b.upload("a part without Content-Disposition", multipart([(b"Content-Type: image/png", jpg), right]),
             [400])
    b.upload("a part without a name", multipart([(b'Content-Disposition: form-data; filename="a.png"', jpg),
                                                 right]), [400])
    b.upload("a part header over 8 KB", multipart([(left[0] + b"\r\nX-Pad: " + b"a" * 9000, jpg), right]),
             [400])
    b.upload("200 unknown parts", multipart([form_part(b"f%d" % i, b"x") for i in range(200)]), [400])
    b.upload("a nested multipart", multipart([(b'Content-Disposition: form-data; name="left"\r\n'
                                               b"Content-Type: multipart/mixed; boundary=inner",
                                               multipart([left], b"inner")), right]), [400])
    b.upload("left twice", multipart([left, left, right]), [400])
    b.upload("left only", multipart([left]), [400])
    b.upload("right only", multipart([right]), [400])
    b.upload("sbs with left", multipart([form_part(b"sbs", jpg), left]), [400])
    b.upload("an unknown field", multipart([form_part(b"middle", jpg)]), [400])
    b.upload("a field name that is not UTF-8", multipart([form_part(b"\xff\xfe", jpg), right]), [400])
    b.upload("a field name of 5000 bytes", multipart([form_part(b"l" * 5000, jpg), right]), [400])
    b.upload("LF line ends", pair(jpg, jpg).replace(b"\r\n", b"\n"), [400])
    b.upload("a base64 part", multipart([(left[0] + b"\r\nContent-Transfer-Encoding: base64",
                                          base64.b64encode(jpg)), right]), [400, 415])
    b.upload("a preamble and wrong sizes", b"preamble\r\n" + pair(png_claiming(8, 8), jpg), [400, 422])
    for ctype in (b"text/plain", b"application/x-www-form-urlencoded", b"image/png",
                  b"application/octet-stream", b"multipart/", b"x/y; boundary=hostileBoundary", b"\xff\xfe"):
        b.upload(f"Content-Type {ctype[:30]!r}", pair(jpg, jpg), [400, 415], ctype=ctype)
    b.request("upload", "no Content-Type", b"POST", b"/api/virtual-camera", pair(jpg, jpg), [400, 415])
    # JSON replays of captures that are not there or not capture ids.
    for body in (b'{"capture": "../../etc/passwd"}', b'{"capture": 1}', b'{"capture": null}',
                 b'{"capture": []}', b'{"capture": "20260101T000000Z-000001-abcd"}',
                 b'{"capture": "' + b"x" * 10000 + b'"}', b"{}", b"[]",
                 b'{"capture": "20260101T000000Z-000001-abcd", "x": 1}', b'{"capture": "\\u0000"}',
                 b'{"capture": "20260101T000000Z-000001-abc/"}', b'"capture"', b"{", b"null"):
        b.request("upload", f"replay {body[:40]!r}", b"POST", b"/api/virtual-camera", body, [400, 404],
                  headers=[(b"Content-Type", b"application/json")])
    # Bodies over max_upload_bytes, declared: 413 before a byte of them is read.
    for size in (MAX_UPLOAD_BYTES + 1, 2 ** 31, 2 ** 40):
        head = http_request(b"POST", b"/api/virtual-camera", token=b.token, length=False,
                            headers=[(b"Content-Type", b"multipart/form-data; boundary=hostileBoundary"),
                                     (b"Content-Length", str(size).encode())])
        b.add("upload", f"Content-Length {size}", head + png[:1024], [413], answered=True)
