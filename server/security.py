"""Request safety: same-origin for state changes, the optional access token, the body limit.

One middleware, :func:`guard`, applied before any handler reads a byte of
the body:

- State-changing requests (POST, PUT, PATCH, DELETE) and WebSocket upgrades
  from another origin get 403: an ``Origin`` header that is not this
  daemon's own scheme://host:port, ``Origin: null``, or (without Origin) a
  browser's ``Sec-Fetch-Site: cross-site``/``same-site``. Requests without
  those headers (curl, scripts) pass. WebSockets are checked because the
  socket hands camera frames to whatever page opened it.
- With ``access_token`` set, state-changing requests need
  ``Authorization: Bearer <token>`` or ``X-Stereocam-Token: <token>`` (401
  otherwise, compared in constant time). GETs stay open.
- A declared ``Content-Length`` over ``max_upload_bytes`` gets 413 at once;
  bodies without one are cut by aiohttp's ``client_max_size`` and the
  upload reader.
"""
from __future__ import annotations

import hmac
from typing import TYPE_CHECKING, Awaitable, Callable, Optional
from urllib.parse import urlsplit

from aiohttp import web

if TYPE_CHECKING:  # pragma: no cover
    from aiohttp.typedefs import Middleware

__all__ = ["guard", "same_origin", "STATE_CHANGING"]

STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
_DEFAULT_PORTS = {"http": 80, "https": 443, "ws": 80, "wss": 443}

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _split_host(scheme: str, host: str) -> Optional[tuple]:
    try:
        parts = urlsplit(f"{scheme}://{host}")
        port = parts.port or _DEFAULT_PORTS.get(scheme)
    except ValueError:
        return None
    if not parts.hostname:
        return None
    return scheme, parts.hostname.lower(), port


def same_origin(request: web.Request) -> bool:
    """False when the browser says the request comes from a page of another origin."""
    origin = request.headers.get("Origin")
    if origin is None:
        return request.headers.get("Sec-Fetch-Site", "same-origin").lower() not in ("cross-site", "same-site")
    try:
        o = urlsplit(origin.strip())
    except ValueError:
        return False
    if o.scheme not in ("http", "https") or not o.netloc:
        return False  # "null" (sandboxed frames, file: pages) and anything odd
    theirs = _split_host(o.scheme, o.netloc)
    ours = _split_host(request.scheme, request.host)
    return theirs is not None and theirs == ours


def _token_of(request: web.Request) -> Optional[str]:
    auth = request.headers.get("Authorization", "")
    if auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    return request.headers.get("X-Stereocam-Token")


def guard(*, access_token: Optional[str], max_body: int) -> "Middleware":
    """The safety middleware for a daemon with these settings (errors are raised as HTTP exceptions)."""
    expected = access_token.encode("utf-8") if access_token else None

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        changing = request.method in STATE_CHANGING
        upgrade = request.headers.get("Upgrade", "").lower() == "websocket"
        if (changing or upgrade) and not same_origin(request):
            origin = request.headers.get("Origin", "a cross-site page")
            raise web.HTTPForbidden(reason="cross-origin request refused",
                                    text=f"refused: {request.method} {request.path} from another origin "
                                         f"({origin}); use the daemon's own page or a script without "
                                         "an Origin header")
        if changing and expected is not None:
            given = _token_of(request)
            # Header bytes that are not UTF-8 arrive as surrogates: compare them as the bytes sent.
            if given is None or not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), expected):
                raise web.HTTPUnauthorized(
                    headers={"WWW-Authenticate": 'Bearer realm="stereocam"'},
                    text=f"{request.method} {request.path} needs the access token: send "
                         "'Authorization: Bearer <token>' or 'X-Stereocam-Token: <token>'"
                         + (" (the token sent is wrong)" if given is not None else ""))
        if changing and request.content_length is not None and request.content_length > max_body:
            raise web.HTTPRequestEntityTooLarge(max_size=max_body, actual_size=request.content_length,
                                                text=_too_large(max_body, request.content_length))
        return await handler(request)

    return middleware


def _too_large(limit: int, size: Optional[int] = None) -> str:
    got = f" ({size} bytes)" if size is not None else ""
    return f"the request body is too large{got}: the limit is {limit} bytes (max_upload_bytes)"
