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
  upload reader. A body that cannot be read as sent (a ``Content-Encoding``
  that does not decode) is a 400, and so is a request whose client went away
  in the middle of it (nobody reads that answer: it keeps a handler's
  ``ConnectionResetError`` out of the log as a failure).
- Every request's ``Host`` must be one of the daemon's names (421
  otherwise): DNS rebinding points an attacker's name at this address, so
  the browser sends the attacker's name; an IP literal cannot be rebound
  and is always accepted. See :func:`allowed_host_names`.
- ``protect="all"`` (the default): with a token, reads need it too: the
  page, its scripts and ``/healthz`` stay open, every stream, snapshot,
  capture, status and ``/ws`` wants the token as a header, the
  ``stereocam_token`` cookie the page sets, or ``?token=`` (for players
  that cannot send headers). ``protect="control"``: only changes need it.
"""
from __future__ import annotations

import hmac
import ipaddress
import socket
from typing import TYPE_CHECKING, Awaitable, Callable, FrozenSet, Iterable, Optional
from urllib.parse import urlsplit

from aiohttp import web
from aiohttp.web_protocol import RequestPayloadError

from ..frames.errors import ApiError
from .errors import too_large

if TYPE_CHECKING:  # pragma: no cover
    from aiohttp.typedefs import Middleware

__all__ = ["guard", "same_origin", "STATE_CHANGING", "allowed_host_names", "PROTECT", "TOKEN_COOKIE"]

STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
PROTECT = ("all", "control")  # what the access token guards
TOKEN_COOKIE = "stereocam_token"
OPEN_PATHS = frozenset({"/", "/index.html", "/healthz", "/favicon.ico"})  # no camera data, no settings
OPEN_PREFIXES = ("/static/",)
LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})
WILDCARDS = frozenset({"0.0.0.0", "::", ""})
CHALLENGE = {"WWW-Authenticate": 'Bearer realm="stereocam"'}


def allowed_host_names(host: str, extra: Iterable[str] = ()) -> FrozenSet[str]:
    """The names a request's ``Host`` may carry: loopback, the listening host, ``extra``, the machine's names.

    Listening on every interface (``0.0.0.0``, as the board's service does) adds this
    machine's host name, its ``.local`` (mDNS) name and its fully qualified name; its
    addresses need no listing (IP literals are always accepted).
    """
    names = set(LOOPBACK_NAMES) | {n.strip().lower().rstrip(".") for n in extra if n.strip()}
    if host not in WILDCARDS:
        names.add(host.lower())
    else:
        hostname = socket.gethostname().lower()
        names |= {hostname, f"{hostname}.local", socket.getfqdn().lower()}
    return frozenset(names)


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name.strip("[]"))
    except ValueError:
        return False
    return True
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


def _token_of(request: web.Request, *, reads: bool = False) -> Optional[str]:
    """The token a request carries: a header; for reads also the page's cookie or ``?token=``."""
    auth = request.headers.get("Authorization", "")
    if auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    header = request.headers.get("X-Stereocam-Token")
    if header is not None or not reads:
        return header
    return request.cookies.get(TOKEN_COOKIE) or request.query.get("token")


def _host_allowed(request: web.Request, names: FrozenSet[str]) -> bool:
    host = request.headers.get("Host")
    if host is None:  # HTTP/1.0 without Host: no browser sends that
        return True
    parts = _split_host("http", host)
    if parts is None:
        return False
    name = parts[1].rstrip(".")
    return name in names or _is_ip(name)


def guard(*, access_token: Optional[str], max_body: int, allowed_hosts: Optional[FrozenSet[str]] = None,
          protect: str = "all") -> "Middleware":
    """The safety middleware for a daemon with these settings (refusals are raised as ApiError).

    ``allowed_hosts``: the names :func:`allowed_host_names` gives (None: loopback names only).
    """
    expected = access_token.encode("utf-8") if access_token else None
    names = allowed_hosts if allowed_hosts is not None else LOOPBACK_NAMES
    if protect not in PROTECT:
        raise ValueError(f"protect must be one of {', '.join(PROTECT)}, not {protect!r}")

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        if not _host_allowed(request, names):
            host = _shown(request.headers.get("Host", ""))
            raise ApiError(f"refused: Host '{host}' is not a name of this daemon "
                           "(a page that renamed this address, or a new name: add it to allowed_hosts)",
                           status=421)
        changing = request.method in STATE_CHANGING
        upgrade = request.headers.get("Upgrade", "").lower() == "websocket"
        if (expected is not None and protect == "all" and not changing and request.path not in OPEN_PATHS
                and not request.path.startswith(OPEN_PREFIXES)):
            given = _token_of(request, reads=True)
            if given is None or not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), expected):
                raise ApiError(f"{request.path} needs the access token: open the page as /?token=<token>, or "
                               "send 'Authorization: Bearer <token>' or add ?token=<token> to the URL"
                               + (" (the token sent is wrong)" if given is not None else ""),
                               status=401, headers=CHALLENGE)
        if (changing or upgrade) and not same_origin(request):
            origin = _shown(request.headers.get("Origin", "a cross-site page"))
            raise ApiError(f"refused: {request.method} {request.path} from another origin ({origin}); use "
                           "the daemon's own page or a script without an Origin header", status=403)
        if changing and expected is not None:
            given = _token_of(request)
            # Header bytes that are not UTF-8 arrive as surrogates: compare them as the bytes sent.
            if given is None or not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), expected):
                raise ApiError(f"{request.method} {request.path} needs the access token: send "
                               "'Authorization: Bearer <token>' or 'X-Stereocam-Token: <token>'"
                               + (" (the token sent is wrong)" if given is not None else ""),
                               status=401, headers=CHALLENGE)
        if changing and request.content_length is not None and request.content_length > max_body:
            raise ApiError(too_large(max_body, request.content_length), status=413)
        try:
            return await handler(request)
        except RequestPayloadError as exc:  # the body cannot be read as sent (a corrupt gzip body, ...)
            raise ApiError(_unreadable_body(exc), status=400) from None
        except ConnectionResetError:
            transport = request.transport
            if transport is not None and not transport.is_closing():
                raise
            # The client went away in the middle of its request (a body cut short): nobody reads the
            # answer, and aiohttp would log a handler's ConnectionResetError as a failure with a traceback.
            raise ApiError("the client closed the connection before its request was read", status=400) \
                from None

    return middleware


def _shown(text: str, limit: int = 80) -> str:
    """``text`` from a request fit for a one-line message: at most ``limit`` characters, and the bytes
    that were not UTF-8 (which arrive as surrogates, and no response can encode) as ``\\xNN``."""
    text = text[:limit]
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _unreadable_body(exc: RequestPayloadError) -> str:
    cause = exc.__cause__ or exc  # aiohttp's ContentEncodingError, ... with the reason as its message
    lines = str(getattr(cause, "message", None) or cause).strip().splitlines()
    detail = lines[0][:200] if lines else type(cause).__name__
    return (f"malformed request: the body cannot be read ({detail}); send it uncompressed, or encoded as "
            "its Content-Encoding says")
