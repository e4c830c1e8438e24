"""Malformed headers (tokens, origins, hosts, lengths, encodings, upgrades) and request lines."""
from __future__ import annotations

import random
import zlib
from typing import List, Optional

from .malformed_case import Case, CaseBuilder
from .raw_http import http_request


def header_cases(b: CaseBuilder) -> None:
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
    (see ``tests/server/test_hostile_clients.py``, which checks these on their own).
    """
    b = CaseBuilder(token)
    for ctype, method, path in ((b"application/json", b"PUT", b"/api/source"),
                                (b"application/yaml", b"PUT", b"/api/calibration"),
                                (b"multipart/form-data; boundary=b", b"POST", b"/api/virtual-camera")):
        for coding in (b"gzip", b"deflate"):
            b.request("header", f"{path.decode()} Content-Encoding {coding.decode()} that is not",
                      method, path, b"abcd" * 10, [400],
                      headers=[(b"Content-Type", ctype), (b"Content-Encoding", coding)])
    return b.cases


def line_cases(b: CaseBuilder, rng: random.Random) -> None:
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
