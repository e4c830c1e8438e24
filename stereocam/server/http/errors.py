"""Errors as answers: every refusal, whoever raised it, becomes the same JSON answer here and nowhere else.

Handlers, the frame path and the other middlewares raise: an :class:`~..errors.ApiError`
(``kind``, ``message``, ``headers``; handlers may set its ``status`` themselves) for a refusal of
theirs, or aiohttp's ``web.HTTPException`` (its own 404, 405, 413, ...). The frame path never
names a status: :data:`STATUS` says which each :class:`~..errors.Kind` answers with
(:func:`status_of`). :func:`json_errors`, the app's outermost middleware, answers both as
``{"error": message}`` with that status, and anything unexpected as a 500 that names the
exception (the traceback goes to the daemon's log, once, never to the client).
"""
from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING, Awaitable, Callable, Dict, Optional, Protocol

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestPayloadError

from ..errors import ApiError, Kind
from .state import SETTINGS

if TYPE_CHECKING:  # pragma: no cover
    from aiohttp.typedefs import Middleware

log = logging.getLogger(__name__)

__all__ = ["json_error", "json_errors", "too_large", "BAD_REQUEST_LINES", "STATUS", "status_of"]

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
KEPT_HEADERS = ("WWW-Authenticate", "Allow", "Retry-After")  # of an aiohttp HTTPException's, in the answer


class Counts(Protocol):
    """What :func:`json_errors` counts answers in (:class:`.metrics.Metrics`; callable from any thread)."""

    def request(self, status: int) -> None: ...

    def error(self, text: str, where: str = ...) -> None: ...


STATUS: Dict[Kind, int] = {
    Kind.BAD_REQUEST: 400,
    Kind.NOT_FOUND: 404,
    Kind.CONFLICT: 409,
    Kind.TOO_LARGE: 413,
    Kind.UNSUPPORTED: 415,
    Kind.UNUSABLE: 422,
    Kind.TOO_MANY: 429,
    Kind.FAILED: 500,
    Kind.UNAVAILABLE: 503,
    Kind.TIMEOUT: 504,
    Kind.NO_SPACE: 507,
}
"""The HTTP status each kind of :class:`~..errors.ApiError` answers with."""


def status_of(exc: ApiError) -> int:
    """The status to answer ``exc`` with: the one a handler set, else its kind's."""
    return exc.status if exc.status is not None else STATUS[exc.kind]


def shutting_down() -> ApiError:
    """What a request that needs the frame path gets once the daemon has begun to stop."""
    return ApiError("the daemon is shutting down", status=503)


def json_error(status: int, message: str, **headers: str) -> web.Response:
    """The daemon's error answer: ``{"error": message}`` (on one line) with ``status``."""
    return web.json_response({"error": " ".join(message.split())}, status=status, headers=headers or None)


def too_large(limit: int, size: Optional[int] = None) -> str:
    """The message of a 413: a body over ``max_upload_bytes`` (``size`` when it was declared)."""
    got = f" ({size} bytes)" if size is not None else ""
    return f"the request body is too large{got}: the limit is {limit} bytes (max_upload_bytes)"


def _message(exc: web.HTTPException, request: web.Request) -> str:
    """What an aiohttp HTTPException says: its text, else a sentence for its status."""
    text = exc.text or ""
    default = f"{exc.status}: {exc.reason}"
    if text and text != default:
        return text
    if exc.status == 404:
        return f"no such resource: {request.path}"
    if exc.status == 405:
        allowed = exc.headers.get("Allow", "")
        return f"{request.method} is not allowed on {request.path}" + (f"; use {allowed}" if allowed else "")
    if exc.status == 413:
        return too_large(request.app[SETTINGS].max_upload_bytes)
    return exc.reason


class _BadRequestLines(logging.Filter):
    """aiohttp logs a malformed request line or header with a traceback: make it one warning line."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, RequestPayloadError) and isinstance(exc.__cause__, HttpProcessingError):
            exc = exc.__cause__  # a body that does not decode, read again by aiohttp after our 400
        if isinstance(exc, HttpProcessingError):
            record.msg = "refused a malformed request (%s %s): %s"
            record.args = (exc.code, type(exc).__name__, str(exc.message).splitlines()[0][:200])
            record.exc_info = None
            record.exc_text = None
            record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


BAD_REQUEST_LINES = _BadRequestLines()
"""Add to the ``aiohttp.server`` logger (a filter set: adding it twice keeps one)."""


def json_errors(metrics: Counts) -> "Middleware":
    """The middleware that answers every error (install it first: outermost); counts every answer."""

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            response = await handler(request)
        except ApiError as exc:
            status = status_of(exc)
            metrics.request(status)
            return json_error(status, exc.message or str(exc), **exc.headers)
        except web.HTTPException as exc:
            if exc.status < 400:
                raise
            metrics.request(exc.status)
            keep = {k: v for k, v in exc.headers.items() if k in KEPT_HEADERS}
            return json_error(exc.status, _message(exc, request), **keep)
        except (asyncio.CancelledError, ConnectionError):
            raise
        except HttpProcessingError as exc:  # a malformed body found while reading it (e.g. a part header)
            status = exc.code if 400 <= exc.code < 500 else 400
            metrics.request(status)
            return json_error(status, f"malformed request: {str(exc.message).splitlines()[0][:200]}")
        except Exception as exc:
            log.exception("%s %s failed", request.method, request.path)
            metrics.error(f"{request.method} {request.path}: {type(exc).__name__}: {exc}", "http")
            metrics.request(500)
            return json_error(500, f"internal error ({type(exc).__name__}: {exc}); see the daemon's log")
        metrics.request(response.status)
        return response

    return middleware
