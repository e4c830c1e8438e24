"""Downloads streamed from a store (a capture's or a recording's zip), chunks made off the loop.

A client that goes away mid-download (a cancelled download, a closed tab) is the
normal end of a stream, not a failure: aiohttp's ``drain()`` then raises a
``ConnectionError`` (``ConnectionResetError``, ``BrokenPipeError``, or plain
"Connection lost"), which is ended quietly here instead of reaching aiohttp's
"Error handling request" traceback in the log.
"""
from __future__ import annotations

import logging
from typing import Any, Awaitable, Callable, Iterator

from aiohttp import web

log = logging.getLogger(__name__)

__all__ = ["stream_download"]

Run = Callable[..., Awaitable[Any]]


async def stream_download(request: web.Request, chunks: Iterator[bytes], *, filename: str, content_type: str,
                          run: Run) -> web.StreamResponse:
    """Send ``chunks`` (each made by ``run(next, chunks, b"")`` on a work thread) as an attachment.

    ``chunks`` is closed at the end whatever happens (a generator: that closes its files). A
    client gone mid-way ends the response quietly; the connection is closed so that it never
    looks like a whole, shorter file.
    """
    resp = web.StreamResponse(headers={"Content-Type": content_type,
                                       "Content-Disposition": f'attachment; filename="{filename}"'})
    try:
        await resp.prepare(request)
        while True:
            chunk = await run(next, chunks, b"")
            if not chunk:
                break
            await resp.write(chunk)
        await resp.write_eof()
    except ConnectionError as exc:
        log.debug("download of %s ended: the client went away (%s)", filename, exc)
        transport = request.transport
        if transport is not None:
            transport.close()
    finally:
        close = getattr(chunks, "close", None)
        if close is not None:
            close()
    return resp
