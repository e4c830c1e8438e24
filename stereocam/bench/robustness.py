"""``stereocam bench robustness``: the daemon under hostile and slow clients, each figure against its floor.

The floors, measured on ``stereocam serve`` run as a subprocess on the
emulated fabric (its log and its resident memory are its own):

``barrage``
    ``requests`` malformed requests (2,000 by default) from :func:`malformed_requests`
    (multipart uploads, JSON bodies, YAML calibrations, headers, request lines, on
    every endpoint that takes them), sent as raw bytes over ``concurrency``
    connections at once while one MJPEG client reads ``/stream/rect_left``.
    ``stream_max_gap_s`` (floor 1 s): the longest time that client went without a
    part, from the first request sent to the last answer received (``stream_parts``
    parts, ``no_signal_parts`` of them "NO SIGNAL" frames); ``status_5xx`` (floor 0):
    answers 500-599; ``tracebacks`` (floor 0): lines of the daemon's log holding
    ``Traceback``; ``rss_delta_mb`` (floor 50): the daemon's resident memory after the
    barrage (``rss_end_mb``, waiting up to ``settle_s`` for it to come down) less the
    memory it had after a warm-up round (``rss_start_mb``, one request of each kind:
    lazy imports and first-use buffers are not a leak); ``rss_peak_mb`` is the most
    seen during the barrage. ``statuses`` counts the answers by status, ``unexpected``
    lists requests whose answer is not one the case allows (:meth:`Case.complaint`).
``alias_bomb``
    ``PUT /api/calibration`` of three "billion laughs" calibrations (the classic one;
    a valid calibration followed by one; one after 240 KB of valid YAML), ``rounds``
    each: ``ms_max`` (floor 100 ms) and ``ms_median``, wall time per request on this
    side; ``statuses`` (400 expected).
``slow_reader``
    One client reads ``/stream/rect_right`` one part per ``read_interval_s`` through a
    4 KB receive buffer, ``reads`` times. The daemon records, for each frame it sends a
    client, how far that frame lagged the newest frame it had (``/api/status``,
    ``streams[].lag_max_frames`` and ``lag_max_s``): ``lag_max_periods`` (floor 2) is the
    largest in frame periods of the cameras (frame numbers count the cameras' frames, so a
    machine too busy for ``--fps`` does not inflate it), ``lag_max_s`` the same in seconds;
    ``read_age_max_s`` is the age of the parts when this client read them (from their
    ``X-Timestamp``), for comparison: a reader that takes one part every 0.5 s holds frames
    about that long in its own buffers.

``meets_floor`` is true when every floor is met; the command exits 1 otherwise (2
when the daemon does not start). Machines are shared: the figures are measured under
whatever load there is (``loadavg_1m`` says how much).

Blocking: :func:`measure_robustness` blocks (it runs its own event loop); the
``async`` functions here are for callers that have a daemon already (the tests).
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import io
import json
import os
import random
import socket
import statistics
import struct
import sys
import tempfile
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, FrozenSet, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from . import serve as bench_serve

FLOOR_STREAM_GAP_S = 1.0
FLOOR_RSS_DELTA_MB = 50.0
FLOOR_ALIAS_BOMB_MS = 100.0
FLOOR_LAG_PERIODS = 2.0
FLOOR_5XX = 0
FLOOR_TRACEBACKS = 0

TOKEN = "hostile-bench-token"
MAX_UPLOAD_BYTES = 16 * 1024 * 1024  # the daemon's default max_upload_bytes
REQUEST_TIMEOUT_S = 120.0  # one answer; a busy machine is slow, never wrong
STALL_TIMEOUT_S = 30.0  # the monitored stream sends nothing for this long: it stalled


class RobustnessBenchError(Exception):
    """The daemon did not start, or a client could not do its part; the message says which."""


# -- requests as bytes ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Case:
    """One malformed request: ``data`` is every byte sent, ``expect`` the statuses it may get.

    An empty ``expect`` allows any 4xx. ``answered=False`` allows the daemon to close the
    connection without answering (a request cut short has nothing to answer).
    """

    kind: str  # upload | json | yaml | header | line
    name: str
    data: bytes = field(repr=False)
    expect: FrozenSet[int] = frozenset()
    answered: bool = True

    def complaint(self, status: Optional[int]) -> Optional[str]:
        """None when ``status`` (None: no answer) is one this case allows, else what is wrong."""
        if status is None:
            return None if not self.answered else "no answer"
        if status >= 500:
            return f"answered {status}"
        if self.expect:
            return None if status in self.expect else f"answered {status}, not {sorted(self.expect)}"
        return None if 400 <= status < 500 else f"answered {status}, not a 4xx"


STATE_CHANGING = (b"POST", b"PUT", b"PATCH", b"DELETE")
ANSWERED = tuple(range(400, 500)) + (200,)  # a request that is odd but valid may be taken


def http_request(method: bytes, path: bytes, body: bytes = b"", *,
                 headers: Sequence[Tuple[bytes, bytes]] = (), host: Optional[bytes] = b"127.0.0.1",
                 token: Optional[str] = None, length: bool = True,
                 version: bytes = b"HTTP/1.1") -> bytes:
    """The bytes of one request: ``Host``, ``headers``, ``Content-Length`` (``length`` and a body or
    a state-changing method), ``Authorization: Bearer token`` (a state-changing method and a
    ``token``), ``Connection: close``."""
    lines = [method + b" " + path + b" " + version]
    if host is not None:
        lines.append(b"Host: " + host)
    if token is not None and method in STATE_CHANGING:
        lines.append(b"Authorization: Bearer " + token.encode())
    lines.extend(name + b": " + value for name, value in headers)
    if length and (body or method in STATE_CHANGING):
        lines.append(b"Content-Length: " + str(len(body)).encode())
    lines.append(b"Connection: close")
    return b"\r\n".join(lines) + b"\r\n\r\n" + body


def multipart(parts: Sequence[Tuple[bytes, bytes]], boundary: bytes = b"hostileBoundary",
              *, end: bool = True) -> bytes:
    """A multipart body of ``(part headers, data)`` (headers as one block without the blank line)."""
    out = b"".join(b"--" + boundary + b"\r\n" + head + b"\r\n\r\n" + data + b"\r\n" for head, data in parts)
    return out + (b"--" + boundary + b"--\r\n" if end else b"")


def form_part(name: bytes, data: bytes, *, filename: bytes = b"image.png",
              ctype: bytes = b"application/octet-stream") -> Tuple[bytes, bytes]:
    return (b'Content-Disposition: form-data; name="' + name + b'"; filename="' + filename + b'"\r\n'
            b"Content-Type: " + ctype, data)


# -- images ---------------------------------------------------------------------------------------

def _picture(w: int, h: int, seed: int) -> np.ndarray:
    """A smooth random RGB picture (JPEG keeps it recognisable, PNG compresses it somewhat)."""
    import cv2

    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (max(1, h // 16), max(1, w // 16), 3), dtype=np.uint8)
    return np.ascontiguousarray(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR))


def _encode(image: np.ndarray, fmt: str) -> bytes:
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


def _pil_bytes(save: Callable[[io.BytesIO], None]) -> bytes:
    buf = io.BytesIO()
    save(buf)
    return buf.getvalue()


# -- the malformed requests -------------------------------------------------------------------------

class _Builder:
    """Collects cases; ``token`` goes on every state-changing request unless a case says otherwise."""

    def __init__(self, token: Optional[str]) -> None:
        self.token = token
        self.cases: List[Case] = []

    def add(self, kind: str, name: str, data: bytes, expect: Sequence[int] = (), *,
            answered: bool = True) -> None:
        self.cases.append(Case(kind, name, data, frozenset(expect), answered))

    def request(self, kind: str, name: str, method: bytes, path: bytes, body: bytes = b"",
                expect: Sequence[int] = (), *, headers: Sequence[Tuple[bytes, bytes]] = (),
                auth: bool = True, **kwargs: Any) -> None:
        data = http_request(method, path, body, headers=headers, token=self.token if auth else None, **kwargs)
        self.add(kind, name, data, expect)

    def upload(self, name: str, body: bytes, expect: Sequence[int] = (),
               ctype: bytes = b"multipart/form-data; boundary=hostileBoundary") -> None:
        self.request("upload", name, b"POST", b"/api/virtual-camera", body, expect,
                     headers=[(b"Content-Type", ctype)])


def _flips(data: bytes, rng: random.Random, n: int, start: int) -> bytes:
    """``data`` with ``n`` bits flipped at or after byte ``start``."""
    out = bytearray(data)
    for _ in range(n):
        i = rng.randrange(min(start, len(out) - 1), len(out))
        out[i] ^= 1 << rng.randrange(8)
    return bytes(out)


def _upload_cases(b: _Builder, frame_size: Tuple[int, int], rng: random.Random) -> None:
    from PIL import Image

    w, h = frame_size
    picture = _picture(w, h, 1)
    good = {fmt: _encode(picture, fmt) for fmt in (".png", ".jpg", ".bmp", ".tiff")}
    png, jpg = good[".png"], good[".jpg"]

    def pair(left: bytes, right: bytes) -> bytes:
        return multipart([form_part(b"left", left), form_part(b"right", right)])

    def sbs(data: bytes) -> bytes:
        return multipart([form_part(b"sbs", data)])

    # Wrong sizes: refused from the header (422), in every format and either field.
    sizes = [(w - 1, h), (w, h - 1), (w + 1, h), (w, h + 1), (w // 2, h // 2), (h, w), (1, 1), (2 * w, h),
             (w, 1), (1, h), (16, 16), (w + 16, h + 16), (3, 2), (w * 2, h * 2), (640, 480), (1280, 720)]
    for i, (sw, sh) in enumerate(sizes):
        small = _picture(sw, sh, 10 + i)
        for fmt in (".png", ".jpg", ".bmp", ".tiff"):
            wrong = _encode(small, fmt)
            b.upload(f"{fmt[1:]} {sw}x{sh} as left", pair(wrong, good[fmt]), [422])
            b.upload(f"{fmt[1:]} {sw}x{sh} as right", pair(good[fmt], wrong), [422])
    for sw, sh in ((w, h), (2 * w + 1, h), (2 * w, h + 1), (2 * w - 1, h), (2 * w - 2, h), (4 * w, h)):
        b.upload(f"side by side {sw}x{sh}", sbs(_encode(_picture(sw, sh, 3), ".png")), [422])
    # Truncated images: 400 (415 while the cut leaves less than the format's magic bytes).
    for fmt, data in good.items():
        for cut in sorted({1, 2, 3, 7, 16, 33, 100} | {rng.randrange(8, len(data) - 1) for _ in range(12)}):
            b.upload(f"{fmt[1:]} cut to {cut} bytes", pair(data[:cut], data), [400, 415])
    # Bytes flipped past the header: the image may still decode (200) or be refused (4xx), never a 5xx.
    for fmt, data in good.items():
        for i in range(12):
            flipped = _flips(data, rng, 1 + i % 4, 64)
            b.upload(f"{fmt[1:]} with {1 + i % 4} flipped bytes", pair(flipped, data),
                     [200, 400, 413, 415, 422])
    for i in range(8):  # flips anywhere, headers too
        fmt = (".png", ".jpg")[i % 2]
        b.upload(f"{fmt[1:]} with a flipped header byte", pair(_flips(good[fmt], rng, 1, 0), good[fmt]),
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
    zeros = _encode(np.zeros((4096, 4096), np.uint8), ".png")
    b.upload("a 4096x4096 PNG of zeros", pair(zeros, jpg), [413, 422])
    b.upload("a 4096x4096 PNG of zeros as sbs", sbs(zeros), [413, 422])
    # Formats the fabric does not take.
    gif = _pil_bytes(lambda f: Image.fromarray(picture).convert("P").save(f, format="GIF"))
    pages = _pil_bytes(lambda f: Image.fromarray(picture).save(
        f, format="TIFF", save_all=True, append_images=[Image.fromarray(picture)]))
    deep_png = _encode(picture.astype(np.uint16) * 257, ".png")
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


JSON_ENDPOINTS = [(b"PUT", b"/api/source"), (b"PUT", b"/api/cameras"), (b"PUT", b"/api/calibration/session"),
                  (b"POST", b"/api/calibration/compute"), (b"POST", b"/api/calibration/apply"),
                  (b"POST", b"/api/virtual-camera"), (b"PUT", b"/api/calibration")]


def _json_cases(b: _Builder) -> None:
    deep = [(b"[" * n + b"]" * n) for n in (100, 1000, 100_000)] + [(b'{"a":' * n + b"1" + b"}" * n)
                                                                   for n in (1000, 50_000)]
    broken = [b"{", b"}", b"{\"source\":}", b"[1,]", b"{'source': 'live'}", b"{\"source\": \"live\",}",
              b"{} x", b"\xff\xfe", b'{"source": "\xff"}', b"NaN", b"Infinity", b"-", b"1" * 5000,
              b"\"" + b"a" * 100_000,
              b"{\"a\": 1e99999}", b"{\"a\": " + b"9" * 5000 + b"}", b"\x00", b"   ", b"\t\n", b"[" * 50,
              b"{\"a\": \"\\ud800\"}", b"{\"a\" 1}", b"{\"a\": tru}", b"{\"a\": nul}", b"{{}}", b"[}",
              b"/* comment */ {}", b"{\"a\": 0x10}", b"{\"a\": .5}", b"{\"a\": 01}", b"{\"a\": +1}",
              b"{" + b",".join(b'"k%d": %d' % (i, i) for i in range(20_000)) + b"}"]
    wrong_top = [b"[]", b"\"live\"", b"1", b"true", b"null", b"[{\"source\": \"live\"}]", b"3.5"]
    lenient = ['{"source": "live"}'.encode("utf-16"), '{"source": "live"}'.encode("utf-32"),
               b"\xef\xbb\xbf{\"source\": \"live\"}"]  # JSON in another encoding: Python reads it
    for method, path in JSON_ENDPOINTS:
        for body in lenient:
            b.request("json", f"{path.decode()} {body[:30]!r}", method, path, body, ANSWERED,
                      headers=[(b"Content-Type", b"application/json")])
        for body in deep + broken + wrong_top:
            if path == b"/api/calibration/compute" and body == b"null":
                continue  # "no body" and null: compute reads both as "no settings" (then 422, no pairs)
            b.request("json", f"{path.decode()} {body[:30]!r}", method, path, body,
                      headers=[(b"Content-Type", b"application/json")])
        for ctype in (b"text/html", b"application/json; charset=bogus", b"application/json; charset=utf-16",
                      b"application/xml", b"\xff"):
            b.request("json", f"{path.decode()} as {ctype!r}", method, path, b"{\"x\": 1}",
                      headers=[(b"Content-Type", ctype)])
    values = [b"1", b"null", b"[]", b"{}", b"true", b"\"\"", b"\"x\"", b"1.5", b"-1", b"NaN", b"Infinity",
              b"-Infinity", b"1e309", b"\"" + b"x" * 10000 + b"\"", b"[\"live\"]", b"{\"a\": 1}", b"0",
              b"100000000000000000000000000000"]
    endpoint_fields = {
        (b"PUT", b"/api/source"): {b"source": values + [b"\"LIVE\"", b"\"live \"", b"\"live\\u0000\"",
                                                          b"\"virtual\\n\""]},
        (b"PUT", b"/api/cameras"): {
            b"gain": [v for v in values if v not in (b"1", b"1.5")] + [b"\"2\"", b"99", b"0.5", b"4.0001"],
            b"exposure_us": [v for v in values if v not in (b"1", b"1.5", b"0")] + [b"\"100\"", b"1e12"],
            b"flip_h": [b"\"yes\"", b"1", b"0", b"null", b"0.5", b"[]"], b"flip_v": [b"2", b"\"no\"", b"{}"],
            b"aec": [b"\"on\"", b"1", b"[]"], b"agc": [b"2", b"\"off\"", b"null"],
            b"test_pattern": [b"5", b"\"nope\"", b"[]", b"{\"a\": 1}", b"true", b"\"" + b"p" * 5000 + b"\""],
            b"camera": [b"\"middle\"", b"1", b"null", b"[\"left\"]", b"\"LEFT\"", b"\"\""],
            b"bogus": [b"1"]},
        (b"PUT", b"/api/calibration/session"): {
            b"pattern": [b"\"0x0\"", b"\"9x6x3\"", b"\"x\"", b"96", b"null", b"\"-9x6\"", b"\"9x-6\"",
                         b"\"99999999999999999999x6\"", b"\"\"", b"[9, 6]", b"\"1000x1000\""],
            b"square_mm": [b"0", b"-1", b"1001", b"NaN", b"Infinity", b"\"25\"", b"null", b"true", b"[]",
                           b"1e309"],
            b"alpha": [b"-0.1", b"1.1", b"NaN", b"\"0.5\"", b"null", b"true", b"Infinity", b"[]",
                       b"-Infinity"],
            b"bogus": [b"1", b"null"]},
        (b"POST", b"/api/calibration/compute"): {
            b"alpha": [b"2", b"NaN", b"\"x\"", b"-1"], b"pattern": [b"5", b"\"x\"", b"null"],
            b"square_mm": [b"0", b"\"25\"", b"-5"], b"bogus": [b"1", b"{}"]},
        (b"POST", b"/api/calibration/apply"): {
            b"id": [b"1", b"null", b"[]", b"{}", b"\"\"", b"\"" + b"x" * 1000 + b"\"", b"\"../x\"", b"true"],
            b"bogus": [b"1"]},
        (b"PUT", b"/api/calibration"): {b"yaml": [b"1", b"null", b"[]", b"{}", b"true", b"\"\"", b"\" \""],
                                        b"yml": [b"\"x\""], b"bogus": [b"\"x\""]},
    }
    for (method, path), fields in endpoint_fields.items():
        for name, options in fields.items():
            for value in options:
                body = b"{\"" + name + b"\": " + value + b"}"
                b.request("json", f"{path.decode()} {body[:40]!r}", method, path, body,
                          headers=[(b"Content-Type", b"application/json")])
    for method, path in ((b"PUT", b"/api/cameras"), (b"PUT", b"/api/calibration/session")):  # one bad of many
        body = (b"{\"gain\": 2.0, \"flip_h\": \"maybe\"}" if b"cameras" in path
                else b"{\"alpha\": 0.5, \"square_mm\": -3}")
        b.request("json", f"{path.decode()} good and bad fields", method, path, body,
                  headers=[(b"Content-Type", b"application/json")])


def _alias_bomb(levels: int = 12, width: int = 10, indent: str = "", prefix: str = "a") -> str:
    """The "billion laughs": ``width ** levels`` leaves from a few hundred bytes."""
    lines = [f"{indent}{prefix}0: &{prefix}0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"{indent}{prefix}{i}: &{prefix}{i} [{', '.join([f'*{prefix}{i - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


def alias_bombs(calibration_yaml: str) -> Dict[str, str]:
    """The three calibrations the ``alias_bomb`` figure times (see the module doc)."""
    filler = "notes:\n" + "".join(f"  - [{i}.5, {i}.25, {i}.125, {i}.0625]\n" for i in range(9000))
    return {"classic": _alias_bomb(),
            "after a calibration": calibration_yaml + "bomb:\n" + _alias_bomb(indent="  "),
            "after 240 KB": calibration_yaml + filler[:240_000 - len(calibration_yaml)].rsplit("\n", 1)[0]
            + "\nbomb:\n" + _alias_bomb(indent="  ")}


def _with_field(doc: Dict[str, Any], path: Sequence[str], raw: str) -> str:
    """The calibration ``doc`` as YAML with the value at ``path`` written as the YAML text ``raw``."""
    import yaml

    copy = json.loads(json.dumps(doc))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = "@@HOSTILE@@"
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return str(yaml.dump(copy, Dumper=dumper, sort_keys=False)).replace("'@@HOSTILE@@'", raw)


# Values that no field of a calibration takes, each refused while the file is read (before the
# line-buffer check, which takes seconds): every path of the model and rectification gets them.
HOSTILE_VALUES = ["!!binary AAAA", "!!set {a, b}", "null", "true", "[]", "{}", "'x'", "2001-01-01",
                  "[[1, 2], [3, 4]]", "{a: 1}", "[1, 'a', null]", "[[1, 2, 3], [4, 5], [6]]", "!!bool maybe",
                  "!!int xyz", "1" * 5000, "0x" + "f" * 5000, "1.0e+400", ".nan", "-.inf", "!!float abc",
                  "!!timestamp 2001-13-45", "!!python/object/apply:os.system ['true']",
                  "!!python/name:os.system",
                  "!custom 5", "[.nan, .nan, .nan, .nan]", "[[1.0e+308, 0, 0], [0, 1.0e+308, 0], [0, 0, 1]]",
                  "*undefined", "&anchor [1, 2]"]


def _yaml_cases(b: _Builder, calibration_yaml: Optional[str], rng: random.Random) -> None:
    import yaml

    good = calibration_yaml or "schema_version: 1\nmodel: {}\n"
    texts: List[Tuple[str, str]] = []
    for levels, width in ((12, 10), (9, 9), (30, 2), (4, 1000)):
        texts.append((f"alias bomb {width}^{levels}", _alias_bomb(levels, width)))
    texts.extend((f"{name} alias bomb", text) for name, text in alias_bombs(good).items())
    texts += [("an alias in K1", good.replace("K1:", "K0: &k [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n  K1:", 1)
               .replace("K2:", "K2: *k\n  K3:", 1)),
              ("a merge key", "base: &b {schema_version: 1}\n<<: *b\n"),
              ("an alias as a key", "a: &k key\n*k : 1\n"),
              ("a self-referencing alias", "a: &a [*a]\n")]
    for depth in (33, 100, 1000, 100_000):
        texts.append((f"flow lists {depth} deep", "deep: " + "[" * depth + "]" * depth + "\n"))
        texts.append((f"flow maps {depth} deep", "deep: " + "{a: " * depth + "1" + "}" * depth + "\n"))
    for depth in (40, 300):
        texts.append((f"block maps {depth} deep", "".join(f"{' ' * i}k:\n" for i in range(depth))
                      + " " * depth + "v\n"))
        texts.append((f"block lists {depth} deep", "".join(f"{' ' * (2 * i)}- \n" for i in range(depth))
                      + " " * (2 * depth) + "- x\n"))
    texts.append(("a deep value in a calibration", good + "deep: " + "[" * 5000 + "]" * 5000 + "\n"))
    texts += [("tabs", "schema_version: 1\nmodel:\n\tK1: 1\n"),
              ("an unclosed list", "schema_version: [1, 2\n"),
              ("bad indentation", "schema_version: 1\n  model: 2\n model: 3\n"),
              ("two documents", good + "---\n" + good), ("an end marker only", "...\n"),
              ("a NUL", "schema_version: 1\nmodel: \x00\n"), ("a bell", "schema_version: 1\x07\n"),
              ("a BOM and broken YAML", "\ufeffschema_version: [\n"),
              ("comments only", "# nothing\n# here\n"),
              ("a scalar", "calibration\n"), ("a list", "- 1\n- 2\n"), ("a number", "42\n"),
              ("over 256 KiB", "schema_version: 1\npad: '" + "x" * 300_000 + "'\n"),
              ("a 4 MB line", "x" * 4_200_000), ("mapping values in a scalar", "a: b: c\n"),
              ("an unhashable key", "? [a, b]\n: c\n"), ("a duplicate anchor", "a: &x 1\nb: &x 2\n"),
              ("a directive", "%YAML 9.9\n--- 1\n"), ("a tag directive", "%TAG ! tag:evil,2000:\n--- !x 1\n"),
              ("schema_version 2", good.replace("schema_version: 1", "schema_version: 2", 1)),
              ("schema_version 10**100",
               good.replace("schema_version: 1", "schema_version: 1" + "0" * 100, 1)),
              ("schema_version true", good.replace("schema_version: 1", "schema_version: true", 1)),
              ("no schema_version", good.replace("schema_version: 1", "schema: 1", 1)),
              ("no model", "schema_version: 1\n"),
              ("a model that is a list", "schema_version: 1\nmodel: [1]\n")]
    if calibration_yaml is not None:
        doc = yaml.safe_load(calibration_yaml)
        paths: List[Tuple[str, ...]] = [(section, key) for section in ("model", "rectification")
                                        for key in doc.get(section) or {}]
        paths += [(key,) for key in ("model", "rectification", "schema_version") if key in doc]
        for path in paths:
            original: Any = doc
            for key in path:
                original = original[key]
            for raw in rng.sample(HOSTILE_VALUES, 9):
                with contextlib.suppress(yaml.YAMLError, ValueError, KeyError, TypeError):
                    if yaml.safe_load(raw) == original:
                        continue  # the value it has: a calibration the daemon takes (and seconds to check)
                texts.append((f"{'.'.join(path)}: {raw[:30]}", _with_field(doc, path, raw)))
    for name, text in texts:
        data = text.encode("utf-8")
        b.request("yaml", f"{name} (application/yaml)", b"PUT", b"/api/calibration", data,
                  headers=[(b"Content-Type", b"application/yaml")])
        if len(data) < 300_000 and rng.random() < 0.3:
            b.request("yaml", f"{name} (text/plain)", b"PUT", b"/api/calibration", data,
                      headers=[(b"Content-Type", b"text/plain")])
        if len(data) < 300_000 and rng.random() < 0.3:
            b.request("yaml", f"{name} (JSON)", b"PUT", b"/api/calibration",
                      json.dumps({"yaml": text}).encode(), headers=[(b"Content-Type", b"application/json")])
    for body in (b"\xff\xfe\x00", b"schema_version: 1\n\x80\x81", "schéma: 1".encode("latin-1"), b"",
                 "schema_version: 1".encode("utf-16")):
        b.request("yaml", f"not UTF-8: {body[:20]!r}", b"PUT", b"/api/calibration", body,
                  headers=[(b"Content-Type", b"application/yaml")])


def _header_cases(b: _Builder) -> None:
    # Tokens that are wrong, not UTF-8, or in the wrong place: 401 (the daemon has an access token).
    changing = [(b"PUT", b"/api/source", b"{\"source\": \"live\"}"), (b"POST", b"/api/captures", b""),
                (b"PUT", b"/api/calibration", b"x: 1"), (b"POST", b"/api/virtual-camera", b""),
                (b"DELETE", b"/api/captures/20260101T000000Z-000001-abcd", b""),
                (b"PUT", b"/api/cameras", b"{}")]
    auths = [b"Bearer \xff\xfe\x80", b"Bearer ", b"Bearer", b"Basic aG9zdGlsZTp0b2tlbg==", b"bearer wrong",
             b"Bearer " + b"t" * 7000, b"Bearer hostile-bench-token\xff", b"Bearer \x7f", b"\xff",
             b"Bearer hostile-bench-toke", b"Bearer  hostile", b"Digest x"]
    for method, path, body in changing:
        json_type = [(b"Content-Type", b"application/json")]
        what = f"{method.decode()} {path.decode()}"
        for auth in auths:
            b.request("header", f"{what} Authorization {auth[:24]!r}", method, path, body, [401, 400],
                      headers=[(b"Authorization", auth)] + json_type, auth=False)
        for token in (b"\xff\xfe", b"", b"x" * 7000, b"hostile-bench-token\x00"):
            b.request("header", f"{what} X-Stereocam-Token {token[:24]!r}", method, path, body, [401, 400],
                      headers=[(b"X-Stereocam-Token", token)] + json_type, auth=False)
        # Another origin: 403 whatever the token.
        for origin in (b"null", b"http://evil.example", b"\xff\xfe", b"http://[", b"javascript:alert(1)",
                       b"http://127.0.0.1:1", b"https://127.0.0.1", b"http://" + b"a" * 5000, b"file://",
                       b"http://127.0.0.1.evil.example"):
            b.request("header", f"{what} Origin {origin[:30]!r}", method, path, body, [403],
                      headers=[(b"Origin", origin)] + json_type)
        for site in (b"cross-site", b"same-site", b"CROSS-SITE"):
            b.request("header", f"{what} Sec-Fetch-Site {site!r}", method, path, body, [403],
                      headers=[(b"Sec-Fetch-Site", site)] + json_type)
    # Names that are not the daemon's: 421 (DNS rebinding), or 400 from the HTTP parser.
    for host in (b"evil.example", b"127.0.0.1.evil.example", b"[::1", b"\xff\xfe", b"a b", b"127.0.0.1:99999",
                 b"127.0.0.1:abc", b"localhost.evil", b"", b":::::", b"x" * 5000, b"evil.example:8080",
                 b"0x7f.1", b"[1::2::3]", b"%00", b"localhost\x01"):
        for method, path in ((b"GET", b"/api/status"), (b"POST", b"/api/captures"), (b"GET", b"/")):
            b.request("header", f"{method.decode()} {path.decode()} Host {host[:30]!r}", method, path,
                      expect=[400, 421], host=host)
    for method, path in ((b"GET", b"/api/status"), (b"PUT", b"/api/source")):
        b.add("header", f"{method.decode()} {path.decode()} two Hosts",
              http_request(method, path, headers=[(b"Host", b"evil.example")], token=b.token), [400, 421])
        b.add("header", f"{method.decode()} {path.decode()} no Host", http_request(method, path, host=None,
                                                                                     token=b.token), [400])
    # Headers the HTTP parser refuses: 400.
    bad_lines = [b"X: " + b"a" * 9000, b"X-" + b"a" * 9000 + b": 1", b"X : a", b"X\x01: a", b"X: a\x00b",
                 b" folded", b"NoColon", b": no name", b"Content-Length: -1", b"Content-Length: abc",
                 b"Content-Length: 99999999999999999999999999", b"Content-Length: 1, 2",
                 b"Transfer-Encoding: chunked, gzip", b"Transfer-Encoding: foo", b"Transfer-Encoding: gzip",
                 b"X: \r"]
    for line in bad_lines:
        for method, path in ((b"GET", b"/api/status"), (b"PUT", b"/api/source")):
            head = http_request(method, path, token=b.token, length=False)
            b.add("header", f"{method.decode()} {path.decode()} header {line[:30]!r}",
                  head.replace(b"Connection: close", line + b"\r\nConnection: close"), [400, 417])
    many = b"".join(b"X-H%d: v\r\n" % i for i in range(200))
    b.add("header", "200 headers", b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n" + many + b"\r\n", [400])
    b.add("header", "two Content-Lengths", b"PUT /api/source HTTP/1.1\r\nHost: 127.0.0.1\r\n"
          b"Content-Length: 2\r\nContent-Length: 3\r\nConnection: close\r\n\r\n{}", [400])
    b.add("header", "chunked and Content-Length", b"PUT /api/source HTTP/1.1\r\nHost: 127.0.0.1\r\n"
          b"Transfer-Encoding: chunked\r\nContent-Length: 3\r\nConnection: close\r\n\r\n0\r\n\r\n", [400])
    for chunks in (b"zz\r\n", b"-1\r\n", b"ffffffffffffffffff\r\nx", b"2\r\nabc\r\n0\r\n\r\n",
                   b"2;\xff\r\n{}\r\n0\r\n\r\n", b"1\r\n{\r\n", b"0\r\nX-Trailer: \x00\r\n\r\n"):
        b.add("header", f"chunks {chunks[:20]!r}", http_request(
            b"PUT", b"/api/source", token=b.token, length=False,
            headers=[(b"Content-Type", b"application/json"), (b"Transfer-Encoding", b"chunked")]) + chunks,
            [400], answered=False)
    # Expectations and upgrades.
    b.add("header", "Expect: bogus", http_request(b"GET", b"/api/status", headers=[(b"Expect", b"bogus")]),
          [417])
    b.add("header", "Expect 100-continue, 1 TB", http_request(
        b"PUT", b"/api/source", token=b.token, length=False,
        headers=[(b"Expect", b"100-continue"), (b"Content-Length", b"1099511627776")]), [413])
    for key, version in ((b"bad", b"13"), (b"dGhlIHNhbXBsZSBub25jZQ==", b"99"), (b"", b"13"),
                         (b"\xff", b"13")):
        b.add("header", f"WebSocket key {key[:10]!r} version {version!r}", http_request(
            b"GET", b"/ws", headers=[(b"Upgrade", b"websocket"), (b"Connection", b"Upgrade"),
                                     (b"Sec-WebSocket-Key", key), (b"Sec-WebSocket-Version", version)]),
              [400])
    b.add("header", "WebSocket from another origin", http_request(
        b"GET", b"/ws", headers=[(b"Upgrade", b"websocket"), (b"Origin", b"http://evil.example"),
                                 (b"Sec-WebSocket-Key", b"dGhlIHNhbXBsZSBub25jZQ=="),
                                 (b"Sec-WebSocket-Version", b"13")]), [403])
    for value in (b"bytes=99999-1", b"bytes=abc", b"bytes=-0", b"bytes=0-1,2-3,4-5,6-7,8-9,10-11,12-13"):
        b.request("header", f"Range {value!r} of a capture", b"GET",
                  b"/api/captures/20260101T000000Z-000001-abcd.zip", expect=[404, 416],
                  headers=[(b"Range", value)])
    for name, value in ((b"Cookie", b"\xff=\xfe; stereocam_token=\xff"), (b"If-Modified-Since", b"\xff"),
                        (b"Accept-Encoding", b"\xff"), (b"X-Forwarded-For", b"\xff"),
                        (b"Accept", b"*/*;q=\xff")):
        b.request("header", f"{name.decode()} {value!r} on a missing capture", b"GET",
                  b"/api/captures/20260101T000000Z-000001-abcd", expect=[404], headers=[(name, value)])
    # Request bodies the daemon does not read as sent: 400.
    gzip_bomb = zlib.compress(b"\0" * (64 << 20), 9)  # deflate: 64 MiB from 64 KB
    for ctype, path in ((b"application/json", b"/api/source"), (b"application/yaml", b"/api/calibration")):
        b.request("header", f"{path.decode()} Content-Encoding br", b"PUT", path, b"abcd", [400],
                  headers=[(b"Content-Type", ctype), (b"Content-Encoding", b"br")])
        b.request("header", f"{path.decode()} Content-Encoding deflate, 64 MiB of zeros", b"PUT", path,
                  gzip_bomb, [400, 413],
                  headers=[(b"Content-Type", ctype), (b"Content-Encoding", b"deflate")])
        b.request("header", f"{path.decode()} Content-Encoding zstd", b"PUT", path, b"abcd", [400, 415],
                  headers=[(b"Content-Type", ctype), (b"Content-Encoding", b"zstd")])


def corrupt_encoding_cases(token: Optional[str]) -> List[Case]:
    """Bodies whose ``Content-Encoding`` does not decode (a "gzip" body that is not gzip): 400.

    Not part of :func:`malformed_requests` by default: aiohttp logs a traceback for each
    (see ``tests/test_hostile_clients.py``, which checks these on their own).
    """
    b = _Builder(token)
    for ctype, method, path in ((b"application/json", b"PUT", b"/api/source"),
                                (b"application/yaml", b"PUT", b"/api/calibration"),
                                (b"multipart/form-data; boundary=b", b"POST", b"/api/virtual-camera")):
        for coding in (b"gzip", b"deflate"):
            b.request("header", f"{path.decode()} Content-Encoding {coding.decode()} that is not",
                      method, path, b"abcd" * 10, [400],
                      headers=[(b"Content-Type", ctype), (b"Content-Encoding", coding)])
    return b.cases


def _line_cases(b: _Builder, rng: random.Random) -> None:
    raw = [b"GARBAGE\r\n\r\n", b"GET /\x00\x01 HTTP/1.1\r\nHost: x\r\n\r\n",
           b"GET / HTTP/9.9\r\nHost: x\r\n\r\n",
           b"GET / HTTP/1.1\r\nBad Header\r\n\r\n", b"G\xffT / HTTP/1.1\r\n\r\n",
           b"get / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", b"FOO / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
           b"GET\r\n\r\n", b"GET / HTTP/1.1 extra\r\nHost: 127.0.0.1\r\n\r\n",
           b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
           b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n", b"GET / HTTP/1.1\nHost: 127.0.0.1\n\n",
           b"GET /\nHost: 127.0.0.1\n\n", b"\x16\x03\x01\x02\x00\x01\x00",
           b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\x00\r\n\r\n",
           b" GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
           b"GET / HTTP/1.1\r\r\nHost: 127.0.0.1\r\n\r\n",
           b"GET / HTTP/\r\nHost: 127.0.0.1\r\n\r\n", b"GET / HTTP/1.x\r\nHost: 127.0.0.1\r\n\r\n",
           b"GET / FTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", b"\xff" * 100 + b"\r\n\r\n",
           bytes(rng.randrange(256) for _ in range(300)) + b"\r\n\r\n", b"GET /%zz%\xff HTTP/1.1\r\n\r\n"]
    for data in raw:  # a request without its blank line is cut short: the daemon waits for the rest
        b.add("line", f"raw {data[:30]!r}", data, [400, 405, 505], answered=data.endswith(b"\r\n\r\n"))
    for data in (b"GET /\r\n\r\n", b"GET  /  HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"):  # lenient: the page
        b.add("line", f"raw {data[:30]!r}", data, [200, 400])
    b.add("line", "blank lines only", b"\r\n\r\n\r\n", answered=False)
    b.add("line", "a POST without its body", b"POST /api/captures HTTP/1.1\r\nHost: 127.0.0.1\r\n"
          b"Content-Length: 5\r\n\r\n", [401])
    # Cut short and closed: nothing to answer, nothing to log but one line.
    for data in (b"GET / HT", b"POST /api/captures HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Len",
                 b"PUT /api/source HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\n{\"sou"):
        # the last one's headers are whole: the token check may answer 401 before the body is missed
        b.add("line", f"cut short {data[:30]!r}", data, [400, 401] if b"\r\n\r\n" in data else [400],
              answered=False)
    # Well-formed lines asking for what is not there, or with bad parameters: 4xx.
    paths = [b"/stream/unknown", b"/stream/%ff%fe", b"/stream/rect_left/extra", b"/snapshot/raw_left.gif",
             b"/snapshot/nothing.jpg", b"/snapshot/rect_left.jpg?fps=abc", b"/snapshot/rect_left.jpg?fps=0",
             b"/snapshot/rect_left.jpg?fps=-1", b"/snapshot/rect_left.jpg?fps=1e999",
             b"/snapshot/rect_left.jpg?fps=nan", b"/snapshot/rect_left.jpg?fps=121",
             b"/snapshot/rect_left.jpg?quality=0", b"/snapshot/rect_left.jpg?quality=101",
             b"/snapshot/rect_left.jpg?quality=" + b"9" * 5000, b"/snapshot/rect_left.jpg?quality=abc",
             b"/snapshot/rect_left.jpg?gray=2", b"/snapshot/rect_left.png?gray=maybe",
             b"/snapshot/rect_left.jpg?bogus=1", b"/snapshot/rect_left.jpg?fps=%zz",
             b"/stream/rect_left?fps=0", b"/stream/rect_left?quality=-5", b"/stream/rect_left?x=1",
             b"/stream/rect_left?gray=%ff", b"/stream/rect_left?fps=" + b"1" * 5000,
             b"/api/captures/..%2f..%2fetc%2fpasswd", b"/api/captures/%00", b"/api/captures/x",
             b"/api/captures/20260101T000000Z-000001-abcd", b"/api/captures/20260101T000000Z-000001-abcd.zip",
             b"/api/captures/20260101T000000Z-000001-abcd/raw_left.png",
             b"/api/captures/20260101T000000Z-000001-abcd/..%2f..%2fx", b"/api/captures/" + b"9" * 5000,
             b"/static/..%2f..%2fapp.py", b"/static/%00", b"/static/../../../etc/passwd", b"/static/",
             b"/api/virtual-camera/result/middle.png", b"/api/verify/difference.png",
             b"/api/calibration/candidate", b"/api/calibration/candidate.yaml",
             b"/api/calibration/candidate/rectified.png?pair=%ff", b"/nothing", b"/api/status/",
             b"/%2e%2e/%2e%2e/etc/passwd", b"/api/%ff", b"//api//status", b"/api/status%00",
             b"/snapshot/rect_left.jpg?fps=1&fps=abc&quality=0"]
    for path in paths:
        b.request("line", f"GET {path[:40]!r}", b"GET", path)
    for method, path in ((b"POST", b"/api/status"), (b"DELETE", b"/api/source"), (b"PUT", b"/api/captures"),
                         (b"PATCH", b"/api/calibration"), (b"POST", b"/stream/rect_left"), (b"TRACE", b"/"),
                         (b"OPTIONS", b"*"), (b"DELETE", b"/api/calibration/pairs/%ff"),
                         (b"DELETE", b"/api/calibration/pairs/x"), (b"DELETE", b"/api/captures/x"),
                         (b"DELETE", b"/api/captures/20260101T000000Z-000001-abcd"),
                         (b"CONNECT", b"127.0.0.1:80"),
                         (b"GET", b"*"), (b"PUT", b"/")):
        b.request("line", f"{method.decode()} {path[:40]!r}", method, path)


def malformed_requests(count: int = 2000, *, frame_size: Tuple[int, int] = (752, 480),
                       calibration_yaml: Optional[str] = None, token: Optional[str] = TOKEN,
                       seed: int = 10) -> List[Case]:
    """``count`` malformed requests for a daemon of ``frame_size``, in a shuffled order.

    Every kind (``upload``, ``json``, ``yaml``, ``header``, ``line``) and every endpoint that
    takes a body is there (about 1,600 structured cases); random mutations of them (a bit
    flipped in the request line, cut short) fill up to ``count``, and a ``count`` below the
    structured cases takes a seeded sample of them. ``calibration_yaml`` is a
    calibration the daemon would accept (``GET /api/calibration``'s ``yaml``): its fields
    are each replaced by hostile values. ``token`` is the daemon's access token (it goes
    on every state-changing request but the ones about tokens). Deterministic for a seed.
    """
    rng = random.Random(seed)
    b = _Builder(token)
    _upload_cases(b, frame_size, rng)
    _json_cases(b)
    _yaml_cases(b, calibration_yaml, rng)
    _header_cases(b)
    _line_cases(b, rng)
    cases = list(b.cases)
    structured = [c for c in cases
                  if c.kind in ("json", "line", "header") and c.answered and len(c.data) < 20_000]
    while len(cases) < count:  # a bit flipped in the request line, or the request cut short and closed
        base = rng.choice(structured)
        line_end = base.data.find(b"\r\n")
        if rng.random() < 0.5 and line_end > 0:
            data = _flips(base.data[:line_end], rng, 1, 0) + base.data[line_end:]
            cases.append(Case(base.kind, "a flipped bit in the request line of " + base.name, data,
                              frozenset(ANSWERED)))
        else:
            data = base.data[:rng.randrange(1, len(base.data))]
            cases.append(Case(base.kind, "cut short: " + base.name, data, frozenset(), answered=False))
    if len(cases) > count:
        return rng.sample(cases, count)
    rng.shuffle(cases)
    return cases


def warmup_requests(cases: Sequence[Case]) -> List[Case]:
    """One request of each kind and leading word of its name: what a warm-up round sends."""
    seen: Dict[Tuple[str, str], Case] = {}
    for c in cases:
        seen.setdefault((c.kind, c.name.split(" ")[0]), c)
    return list(seen.values())


# -- sending, watching, measuring ------------------------------------------------------------------

async def send_raw(port: int, data: bytes, *, host: str = "127.0.0.1", half_close: bool = False,
                   timeout: float = REQUEST_TIMEOUT_S) -> Tuple[Optional[int], bytes]:
    """Send ``data`` as it is (then, with ``half_close``, end the sending side, as a client that
    gives up does); the final status (1xx skipped) and the answer's head and body, or
    ``(None, b"")`` when the connection closes without an answer."""
    reader, writer = await asyncio.open_connection(host, port)
    try:
        try:
            writer.write(data)
            await asyncio.wait_for(writer.drain(), timeout)
            if half_close:
                writer.write_eof()
        except (ConnectionError, OSError):
            pass  # the daemon answered early (413) and closed: its answer may still be there
        buffer = b""
        deadline = time.monotonic() + timeout
        while True:
            end = buffer.find(b"\r\n\r\n")
            if end >= 0:
                status_line = buffer.split(b"\r\n", 1)[0]
                parts = status_line.split(b" ", 2)
                status = int(parts[1]) if len(parts) > 1 and parts[1].isdigit() else None
                if status is not None and 100 <= status < 200:
                    buffer = buffer[end + 4:]
                    continue
                head, body = buffer[:end], buffer[end + 4:]
                length = _content_length(head)
                while length is not None and len(body) < min(length, 1 << 20):
                    chunk = await _read(reader, deadline)
                    if not chunk:
                        break
                    body += chunk
                return status, head + b"\r\n\r\n" + body
            chunk = await _read(reader, deadline)
            if not chunk:
                return None, buffer
            buffer += chunk
    finally:
        writer.close()
        with contextlib.suppress(ConnectionError, OSError):
            await writer.wait_closed()


def _content_length(head: bytes) -> Optional[int]:
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length" and value.strip().isdigit():
            return int(value.strip())
    return None


async def _read(reader: asyncio.StreamReader, deadline: float) -> bytes:
    try:
        return await asyncio.wait_for(reader.read(65536), max(0.0, deadline - time.monotonic()))
    except (ConnectionError, OSError):
        return b""
    except asyncio.TimeoutError:
        raise RobustnessBenchError(f"no answer within {REQUEST_TIMEOUT_S:g} s") from None


@dataclass
class Outcome:
    case: Case
    status: Optional[int]
    answer: bytes = field(repr=False, default=b"")
    started: float = 0.0  # monotonic
    seconds: float = 0.0

    @property
    def complaint(self) -> Optional[str]:
        problem = self.case.complaint(self.status)
        if problem is None and b"Traceback" in self.answer:
            problem = "a traceback in the answer"
        return problem


async def send_all(port: int, cases: Sequence[Case], *, concurrency: int = 6) -> List[Outcome]:
    """Send every case, ``concurrency`` at a time; their outcomes in the order of ``cases``."""
    gate = asyncio.Semaphore(concurrency)

    async def one(case: Case) -> Outcome:
        async with gate:
            t0 = time.monotonic()
            status, answer = await send_raw(port, case.data, half_close=not case.answered)
            return Outcome(case, status, answer, t0, time.monotonic() - t0)

    return list(await asyncio.gather(*(one(c) for c in cases)))


WS_MESSAGES: List[Tuple[str, Any]] = [
    ("not JSON", "views please"), ("deep JSON", "[" * 30_000 + "]" * 30_000), ("a list", "[]"),
    ("null", "null"), ("a string", '"rect_left"'), ("views a string", '{"views": "rect_left"}'),
    ("a view number", '{"views": [1]}'),
    ("an unknown view", '{"views": ["nope"]}'), ("fps 0", '{"views": ["rect_left"], "fps": 0}'),
    ("fps text", '{"views": ["rect_left"], "fps": "x"}'), ("fps NaN", '{"views": ["rect_left"], "fps": NaN}'),
    ("quality 1000", '{"views": ["rect_left"], "quality": 1000}'), ("an unknown key", '{"bogus": 1}'),
    ("gray maybe", '{"views": ["rect_left"], "gray": "maybe"}'),
    ("20 views", json.dumps({"views": ["rect_left"] * 20})),
    ("a huge number", '{"views": ["rect_left"], "fps": ' + "9" * 5000 + "}"), ("binary", b"\x00\x01\x02"),
    ("over 64 KB", "x" * 70_000),
]


async def websocket_abuse(port: int, *, repeat: int = 2) -> List[Tuple[str, str]]:
    """Send each of :data:`WS_MESSAGES` on ``/ws`` ``repeat`` times: ``(message, what came back)``, where
    what came back is ``error`` (a text ``{"error": ...}``), ``closed <code>`` or what else it was.
    A socket the daemon closes (a message over its 64 KB limit) is opened again."""
    import aiohttp

    out: List[Tuple[str, str]] = []
    async with aiohttp.ClientSession(f"http://127.0.0.1:{port}") as session:
        ws = await session.ws_connect("/ws")
        try:
            for _ in range(repeat):
                for name, message in WS_MESSAGES:
                    if ws.closed:
                        ws = await session.ws_connect("/ws")
                    if isinstance(message, bytes):
                        await ws.send_bytes(message)
                    else:
                        await ws.send_str(message)
                    reply = await ws.receive(timeout=STALL_TIMEOUT_S)
                    if reply.type == aiohttp.WSMsgType.TEXT and "error" in json.loads(reply.data):
                        out.append((name, "error"))
                    elif reply.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                                        aiohttp.WSMsgType.CLOSING):
                        out.append((name, f"closed {ws.close_code}"))
                    else:
                        out.append((name, f"{reply.type.name} {str(reply.data)[:60]}"))
        finally:
            await ws.close()
    return out


@dataclass
class StreamWatch:
    """Parts of one MJPEG stream as they arrive: ``(monotonic time, frame number, signal)``."""

    parts: List[Tuple[float, int, bool]] = field(default_factory=list)
    error: Optional[str] = None

    def max_gap(self, start: float, end: float) -> float:
        """The longest time without a part between ``start`` and ``end`` (monotonic)."""
        times = [start] + [t for t, _, _ in self.parts if start < t < end] + [end]
        return max(b - a for a, b in zip(times, times[1:], strict=False))

    def between(self, start: float, end: float) -> List[Tuple[float, int, bool]]:
        return [p for p in self.parts if start <= p[0] <= end]


async def watch_stream(port: int, path: str, watch: StreamWatch, stop: asyncio.Event,
                       *, token: Optional[str] = None) -> None:
    """Read the MJPEG stream at ``path`` until ``stop``, recording each part in ``watch``."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        auth = f"Authorization: Bearer {token}\r\n" if token else ""
        writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{auth}\r\n".encode())
        await writer.drain()
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
        if not head.startswith(b"HTTP/1.1 200"):
            watch.error = f"GET {path}: {_first_line(head)!r}"
            return
        while not stop.is_set():
            block = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
            headers = bench_serve.part_headers(block)
            if b"content-length" not in headers:
                continue
            await asyncio.wait_for(reader.readexactly(int(headers[b"content-length"]) + 2), STALL_TIMEOUT_S)
            watch.parts.append((time.monotonic(), int(headers.get(b"x-frame-number", b"-1")),
                                headers.get(b"x-signal") != b"none"))
    except asyncio.TimeoutError:
        watch.error = f"GET {path}: no part for {STALL_TIMEOUT_S:g} s"
    except (ConnectionError, asyncio.IncompleteReadError, ValueError) as exc:
        if not stop.is_set():
            watch.error = f"GET {path}: {type(exc).__name__}: {exc}"
    finally:
        writer.close()


def _first_line(data: bytes) -> bytes:
    return data.split(b"\r\n", 1)[0]


def rss_mb(pid: int) -> float:
    """The resident memory of process ``pid`` (``VmRSS``), in MB (10^6 bytes)."""
    with open(f"/proc/{pid}/status", "rb") as f:
        for line in f:
            if line.startswith(b"VmRSS:"):
                return int(line.split()[1]) * 1024 / 1e6
    raise RobustnessBenchError(f"/proc/{pid}/status has no VmRSS")


def log_tracebacks(text: str) -> List[str]:
    """The lines of a daemon log that start a traceback, with the line before (what logged it)."""
    lines = text.splitlines()
    return [" | ".join(lines[max(0, i - 1):i + 1]) for i, line in enumerate(lines) if "Traceback" in line]


@dataclass
class Barrage:
    """What :func:`run_barrage` saw; ``figures()`` is its part of the bench's JSON."""

    outcomes: List[Outcome]
    watch: StreamWatch
    start: float
    end: float
    rss_ready_mb: float
    rss_start_mb: float
    rss_peak_mb: float
    rss_end_mb: float
    warmup: int
    websocket: List[Tuple[str, str]] = field(default_factory=list)

    @property
    def websocket_unexpected(self) -> List[Tuple[str, str]]:
        """WebSocket messages not answered as they should be: an error, or (over 64 KB) a close 1009."""
        return [(name, got) for name, got in self.websocket
                if got != ("closed 1009" if name == "over 64 KB" else "error")]

    @property
    def unexpected(self) -> List[Outcome]:
        return [o for o in self.outcomes if o.complaint is not None]

    @property
    def status_5xx(self) -> List[Outcome]:
        return [o for o in self.outcomes if o.status is not None and o.status >= 500]

    def figures(self) -> Dict[str, Any]:
        statuses: Dict[str, int] = {}
        kinds: Dict[str, int] = {}
        for o in self.outcomes:
            key = "none" if o.status is None else str(o.status)
            statuses[key] = statuses.get(key, 0) + 1
            kinds[o.case.kind] = kinds.get(o.case.kind, 0) + 1
        during = self.watch.between(self.start, self.end)
        return {
            "requests": len(self.outcomes),
            "kinds": dict(sorted(kinds.items())),
            "warmup_requests": self.warmup,
            "seconds": round(self.end - self.start, 2),
            "statuses": dict(sorted(statuses.items())),
            "status_5xx": len(self.status_5xx),
            "unexpected": [f"{o.case.kind}: {o.case.name}: {o.complaint}" for o in self.unexpected][:20],
            "websocket_messages": len(self.websocket),
            "websocket_unexpected": [f"{name}: {got}" for name, got in self.websocket_unexpected][:20],
            "stream_parts": len(during),
            "no_signal_parts": sum(1 for _, _, signal in during if not signal),
            "stream_max_gap_s": round(self.watch.max_gap(self.start, self.end), 3),
            "rss_ready_mb": round(self.rss_ready_mb, 1),
            "rss_start_mb": round(self.rss_start_mb, 1),
            "rss_peak_mb": round(self.rss_peak_mb, 1),
            "rss_end_mb": round(self.rss_end_mb, 1),
            "rss_delta_mb": round(self.rss_end_mb - self.rss_start_mb, 1),
        }


async def run_barrage(port: int, pid: int, cases: Sequence[Case], *, concurrency: int = 6,
                      settle_s: float = 30.0, warmup: Optional[Sequence[Case]] = None,
                      view: str = "rect_left") -> Barrage:
    """Warm up, then send ``cases`` while watching ``/stream/<view>`` and the daemon's memory.

    After the last answer, waits up to ``settle_s`` for the daemon's memory to come back within
    :data:`FLOOR_RSS_DELTA_MB` of where it started (a condition, not a fixed time).
    """
    rss_ready = rss_mb(pid)
    watch = StreamWatch()
    stop = asyncio.Event()
    watcher = asyncio.ensure_future(watch_stream(port, f"/stream/{view}", watch, stop))
    try:
        warm = list(warmup if warmup is not None else warmup_requests(cases))
        await send_all(port, warm, concurrency=concurrency)
        deadline = time.monotonic() + STALL_TIMEOUT_S
        while not watch.parts and watch.error is None:  # the stream runs before the barrage starts
            if time.monotonic() > deadline:
                raise RobustnessBenchError(f"/stream/{view} sent no part in {STALL_TIMEOUT_S:g} s")
            await asyncio.sleep(0.05)
        rss_start = rss_mb(pid)
        peak = [rss_start]

        async def sample() -> None:
            while True:
                peak[0] = max(peak[0], rss_mb(pid))
                await asyncio.sleep(0.1)

        sampler = asyncio.ensure_future(sample())
        start = time.monotonic()
        try:
            outcomes, websocket = await asyncio.gather(send_all(port, cases, concurrency=concurrency),
                                                       websocket_abuse(port))
        finally:
            end = time.monotonic()
            sampler.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sampler
        settle_until = time.monotonic() + settle_s
        rss_end = rss_mb(pid)
        while rss_end - rss_start > FLOOR_RSS_DELTA_MB and time.monotonic() < settle_until:
            await asyncio.sleep(0.5)
            rss_end = rss_mb(pid)
        # The stream goes on after the barrage: one more part.
        parts = len(watch.parts)
        deadline = time.monotonic() + STALL_TIMEOUT_S
        while len(watch.parts) == parts and watch.error is None and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
    finally:
        stop.set()
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watcher
    if watch.error is not None:
        raise RobustnessBenchError(f"the monitored stream failed: {watch.error}")
    return Barrage(outcomes=outcomes, watch=watch, start=start, end=end, rss_ready_mb=rss_ready,
                   rss_start_mb=rss_start, rss_peak_mb=max(peak[0], rss_end), rss_end_mb=rss_end,
                   warmup=len(warm), websocket=websocket)


async def time_alias_bombs(port: int, calibration_yaml: str, *, rounds: int = 5,
                           token: Optional[str] = TOKEN) -> Dict[str, Any]:
    """PUT each of :func:`alias_bombs` ``rounds`` times: wall time per answer and the statuses."""
    times: Dict[str, List[float]] = {}
    statuses: Dict[str, int] = {}
    for _ in range(rounds):
        for name, text in alias_bombs(calibration_yaml).items():
            data = http_request(b"PUT", b"/api/calibration", text.encode(), token=token,
                                headers=[(b"Content-Type", b"application/yaml")])
            t0 = time.perf_counter()
            status, answer = await send_raw(port, data)
            times.setdefault(name, []).append(time.perf_counter() - t0)
            key = str(status)
            statuses[key] = statuses.get(key, 0) + 1
    every = [t for ts in times.values() for t in ts]
    return {
        "rounds": rounds,
        "ms_max": round(1000 * max(every), 2),
        "ms_median": round(1000 * statistics.median(every), 2),
        "ms_max_by_file": {name: round(1000 * max(ts), 2) for name, ts in times.items()},
        "ms_median_by_file": {name: round(1000 * statistics.median(ts), 2) for name, ts in times.items()},
        "bytes_by_file": {name: len(text.encode()) for name, text in alias_bombs(calibration_yaml).items()},
        "statuses": statuses,
    }


async def slow_reader(port: int, *, view: str = "rect_right", reads: int = 12, read_interval_s: float = 0.5,
                      rcvbuf: int = 4096) -> Dict[str, Any]:
    """One client reading ``/stream/<view>`` a part every ``read_interval_s`` through a ``rcvbuf``-byte
    receive buffer: the frames it read, their age on arrival, and the daemon's record of the
    client (``/api/status`` ``streams``) while it was still connected."""
    loop = asyncio.get_running_loop()
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.setblocking(False)
    await loop.sock_connect(sock, ("127.0.0.1", port))
    reader, writer = await asyncio.open_connection(sock=sock, limit=rcvbuf)
    frames: List[int] = []
    ages: List[float] = []
    try:
        writer.write(f"GET /stream/{view} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        await writer.drain()
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
        if not head.startswith(b"HTTP/1.1 200"):
            raise RobustnessBenchError(f"GET /stream/{view}: {_first_line(head)!r}")
        for _ in range(reads):
            await asyncio.sleep(read_interval_s)  # the reader's pace: what makes it slow
            await asyncio.wait_for(reader.readuntil(b"--frame\r\n"), STALL_TIMEOUT_S)
            part = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
            headers = dict(line.split(": ", 1) for line in part.decode().strip().split("\r\n"))
            ages.append(time.time() - float(headers["X-Timestamp"]))
            frames.append(int(headers["X-Frame-Number"]))
            await asyncio.wait_for(reader.readexactly(int(headers["Content-Length"]) + 2), STALL_TIMEOUT_S)
        status = await get_json(port, "/api/status")
    finally:
        writer.close()
    mine = [s for s in status.get("streams", []) if s.get("kind") == "mjpeg" and s.get("view") == view]
    if len(mine) != 1:
        raise RobustnessBenchError(f"/api/status lists {len(mine)} clients of /stream/{view}, "
                                   "not the slow reader alone")
    return {"view": view, "reads": reads, "read_interval_s": read_interval_s, "frames": frames,
            "read_age_max_s": round(max(ages), 3), "client": mine[0],
            "camera_fps": status["fps"].get("camera")}


# -- the whole bench ------------------------------------------------------------------------------

def _config_file(folder: Path) -> Path:
    path = folder / "stereocam.yaml"
    path.write_text(f"access_token: {TOKEN}\nprotect: control\n")
    return path


@contextlib.contextmanager
def daemon(*, fps: float, log_path: Path, folder: Optional[Path] = None,
           health_timeout: float = 60.0) -> Iterator[Tuple[Any, str]]:
    """``stereocam serve`` at ``fps`` with an access token (``protect: control``), its log in ``log_path``,
    its settings file, captures (``captures/``) and state in ``folder`` (a temporary one when None):
    ``(process, base URL)``."""
    from .serve import ServeBenchError, running_daemon

    with contextlib.ExitStack() as stack:
        if folder is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="stereocam-robustness-")))
        config = _config_file(folder)
        try:
            with running_daemon(fps=fps, log_path=log_path, health_timeout=health_timeout,
                                captures=folder / "captures", extra_args=["--config", str(config)]) as run:
                yield run
        except ServeBenchError as exc:
            raise RobustnessBenchError(str(exc)) from None


async def get_json(port: int, path: str) -> Any:
    """``GET path`` on the daemon: its JSON (RobustnessBenchError unless it answers 200)."""
    status, answer = await send_raw(port, http_request(b"GET", path.encode()))
    if status != 200:
        raise RobustnessBenchError(f"GET {path}: {status}: {answer[-200:]!r}")
    return json.loads(answer.split(b"\r\n\r\n", 1)[1])


async def daemon_facts(port: int) -> Tuple[Tuple[int, int], str]:
    """The daemon's frame size and the calibration it runs (``GET /api/calibration``'s ``yaml``)."""
    status = await get_json(port, "/api/status")
    cal = await get_json(port, "/api/calibration")
    w, h = status["frame_size"]
    return (int(w), int(h)), str(cal["yaml"] or "")


def measure_robustness(*, requests: int = 2000, fps: float = 60.0, concurrency: int = 6, rounds: int = 5,
                       reads: int = 12, settle_s: float = 30.0) -> Dict[str, Any]:
    """Start the daemon, run the three measurements, stop it; one JSON-able dict (see the module doc)."""
    with tempfile.TemporaryDirectory(prefix="stereocam-bench-robustness-log-") as tmp:
        log_path = Path(tmp) / "daemon.log"
        with daemon(fps=fps, log_path=log_path) as (proc, base):
            port = int(base.rsplit(":", 1)[1])

            async def run() -> Dict[str, Any]:
                frame_size, calibration = await daemon_facts(port)
                cases = malformed_requests(requests, frame_size=frame_size, calibration_yaml=calibration)
                barrage = await run_barrage(port, proc.pid, cases, concurrency=concurrency, settle_s=settle_s)
                bombs = await time_alias_bombs(port, calibration, rounds=rounds)
                reader = await slow_reader(port, reads=reads)
                return {"barrage": barrage.figures(), "alias_bomb": bombs, "slow_reader": reader}

            result = asyncio.run(run())
            if proc.poll() is not None:
                raise RobustnessBenchError(f"the daemon exited with code {proc.returncode} during the bench")
        tracebacks = log_tracebacks(log_path.read_text(errors="replace"))
    result["barrage"]["tracebacks"] = len(tracebacks)
    result["barrage"]["traceback_lines"] = tracebacks[:10]
    client = result["slow_reader"]["client"]
    result["slow_reader"]["lag_max_s"] = client["lag_max_s"]
    result["slow_reader"]["lag_max_frames"] = client["lag_max_frames"]
    result["slow_reader"]["lag_max_periods"] = int(client["lag_max_frames"])
    result["fps"] = fps
    result["loadavg_1m"] = round(os.getloadavg()[0], 2)
    result["floor"] = {"stream_max_gap_s": FLOOR_STREAM_GAP_S, "status_5xx": FLOOR_5XX,
                       "tracebacks": FLOOR_TRACEBACKS, "rss_delta_mb": FLOOR_RSS_DELTA_MB,
                       "alias_bomb_ms": FLOOR_ALIAS_BOMB_MS, "slow_reader_lag_periods": FLOOR_LAG_PERIODS}
    result["meets"] = meets(result)
    result["meets_floor"] = all(result["meets"].values())
    return result


def meets(result: Dict[str, Any]) -> Dict[str, bool]:
    """Each floor against its figure in ``result``."""
    barrage, bomb, reader = result["barrage"], result["alias_bomb"], result["slow_reader"]
    return {
        "stream_max_gap_s": barrage["stream_max_gap_s"] <= FLOOR_STREAM_GAP_S,
        "status_5xx": barrage["status_5xx"] <= FLOOR_5XX,
        "tracebacks": barrage["tracebacks"] <= FLOOR_TRACEBACKS,
        "rss_delta_mb": barrage["rss_delta_mb"] <= FLOOR_RSS_DELTA_MB,
        "requests": barrage["requests"] >= 2000,
        "alias_bomb_ms": bomb["ms_max"] < FLOOR_ALIAS_BOMB_MS and set(bomb["statuses"]) == {"400"},
        "slow_reader_lag_periods": reader["lag_max_periods"] <= FLOOR_LAG_PERIODS,
    }


def text_lines(result: Dict[str, Any]) -> List[str]:
    """One line per figure: the figure, its floor, and whether it is met."""
    ok = result["meets"]
    barrage, bomb, reader = result["barrage"], result["alias_bomb"], result["slow_reader"]

    def mark(key: str) -> str:
        return "ok" if ok[key] else "MISSED"

    kinds = ", ".join(f"{k} {v}" for k, v in barrage["kinds"].items())

    return [
        f"malformed requests {barrage['requests']} in {barrage['seconds']} s ({kinds}); "
        f"answers {barrage['statuses']}: floor 2000 [{mark('requests')}]",
        f"5xx answers        {barrage['status_5xx']}: floor 0 [{mark('status_5xx')}]",
        f"log tracebacks     {barrage['tracebacks']}: floor 0 [{mark('tracebacks')}]",
        f"stream max gap     {barrage['stream_max_gap_s']} s ({barrage['stream_parts']} parts, "
        f"{barrage['no_signal_parts']} NO SIGNAL): floor {FLOOR_STREAM_GAP_S:g} s "
        f"[{mark('stream_max_gap_s')}]",
        f"memory             {barrage['rss_delta_mb']:+} MB ({barrage['rss_start_mb']} MB after the warm-up, "
        f"peak {barrage['rss_peak_mb']}, end {barrage['rss_end_mb']}): floor +{FLOOR_RSS_DELTA_MB:g} MB "
        f"[{mark('rss_delta_mb')}]",
        f"alias bomb         {bomb['ms_max']} ms at most, {bomb['ms_median']} ms median "
        f"({bomb['statuses']}): "
        f"floor {FLOOR_ALIAS_BOMB_MS:g} ms [{mark('alias_bomb_ms')}]",
        f"slow reader        frames lag the newest by {reader['lag_max_periods']} frame periods at most when "
        f"sent ({reader['lag_max_s']} s; parts {reader['read_age_max_s']} s old when read): "
        f"floor {FLOOR_LAG_PERIODS:g} [{mark('slow_reader_lag_periods')}]",
        f"machine            load {result['loadavg_1m']}, camera {result['fps']:g} fps",
    ]


def run_robustness(args: argparse.Namespace) -> int:
    """``stereocam bench robustness``: print the figures (text or ``--json``); exit 1 below a floor."""
    try:
        result = measure_robustness(requests=args.requests, fps=args.fps, concurrency=args.concurrency,
                                    rounds=args.rounds, reads=args.reads, settle_s=args.settle)
    except RobustnessBenchError as exc:
        print(f"stereocam bench robustness: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        print("\n".join(text_lines(result)))
    sys.stdout.flush()
    return 0 if result["meets_floor"] else 1


def add_robustness_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench robustness``, a suite of ``stereocam bench`` (``sub`` is its subparsers)."""
    p = sub.add_parser("robustness",
                       help="the daemon under hostile and slow clients, against issue 10's floors",
                       description="Malformed requests, a YAML alias bomb and a slow stream reader against "
                                   "`stereocam serve` on the emulated fabric; each figure against its floor "
                                   "(exit 1 when one is missed).")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_arguments(p)
    p.set_defaults(func=run_robustness)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``stereocam bench robustness``."""
    p.add_argument("--requests", type=int, default=2000, metavar="N",
                   help="malformed requests (default 2000)")
    p.add_argument("--fps", type=float, default=60.0, help="the emulated cameras' rate (default 60)")
    p.add_argument("--concurrency", type=int, default=6, metavar="N", help="requests in flight (default 6)")
    p.add_argument("--rounds", type=int, default=5, metavar="N", help="PUTs of each alias bomb (default 5)")
    p.add_argument("--reads", type=int, default=12, metavar="N",
                   help="parts the slow reader reads (default 12)")
    p.add_argument("--settle", type=float, default=30.0, metavar="S",
                   help="seconds to wait for the memory to come down after the barrage (default 30)")
