"""Requests and answers as raw bytes: what a hostile client sends, as it is, and what comes back.

The robustness bench writes its requests byte by byte (an HTTP client library would refuse
or repair most of them) and reads the answers the same way.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import time
from typing import Any, Optional, Sequence, Tuple

REQUEST_TIMEOUT_S = 120.0  # one answer; a busy machine is slow, never wrong
STALL_TIMEOUT_S = 30.0  # the monitored stream sends nothing for this long: it stalled


class RobustnessBenchError(Exception):
    """The daemon did not start, or a client could not do its part; the message says which."""


STATE_CHANGING = (b"POST", b"PUT", b"PATCH", b"DELETE")


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


async def get_json(port: int, path: str) -> Any:
    """``GET path`` on the daemon: its JSON (RobustnessBenchError unless it answers 200)."""
    status, answer = await send_raw(port, http_request(b"GET", path.encode()))
    if status != 200:
        raise RobustnessBenchError(f"GET {path}: {status}: {answer[-200:]!r}")
    return json.loads(answer.split(b"\r\n\r\n", 1)[1])


def first_line(data: bytes) -> bytes:
    return data.split(b"\r\n", 1)[0]
