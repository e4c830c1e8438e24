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
  ``Authorization: Bearer <token>``, ``X-Stereocam-Token: <token>`` or the page's
  cookie (401 otherwise, compared in constant time; the cookie is ``SameSite=Strict``
  and a request from another origin is refused before it is looked at). GETs stay open.
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
  page, its scripts, ``/api/views`` and ``/healthz`` stay open, every stream, snapshot,
  capture, status and ``/ws`` wants the token as a header, the
  ``stereocam_token`` cookie, or ``?token=`` (for players
  that cannot send headers). ``protect="control"``: only changes need it.

The token follows one rule wherever it arrives (:func:`token_given`, :func:`token_matches`):
the value as sent, or that value percent-decoded (``%2B`` is ``+``, and a ``+`` stays a ``+``:
no token holds a space), so a token with ``+``, ``/`` or ``=`` works from a header, a cookie
a script wrote URI-encoded, and a URL. The page's cookie is the server's: ``/?token=<token>``
answers a redirect to the same URL without the token (out of the address bar and the history)
that sets it ``HttpOnly; SameSite=Strict`` (:func:`page_token_redirect`), and so does the sign-in
form (``/signin``, :mod:`.signin`: its POST needs the same origin, not the token). The token never
reaches a log line: :class:`AccessLog` writes aiohttp's access line with every ``token=``
value redacted, and :class:`TokenRedactor` takes the token out of any record a handler writes.
"""
from __future__ import annotations

import errno
import hmac
import ipaddress
import logging
import re
import socket
from typing import TYPE_CHECKING, Awaitable, Callable, FrozenSet, Iterable, Optional
from urllib.parse import quote, quote_plus, unquote, urlencode, urlsplit

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger
from aiohttp.web_protocol import RequestPayloadError

from ..errors import ApiError
from .errors import too_large

if TYPE_CHECKING:  # pragma: no cover
    from aiohttp.typedefs import Middleware

__all__ = ["guard", "same_origin", "STATE_CHANGING", "allowed_host_names", "PROTECT", "TOKEN_COOKIE",
           "TOKEN_PARAM", "TOKEN_GIVEN_COOKIE", "SIGNIN_PATHS", "token_given", "token_matches",
           "page_token_redirect", "set_token_cookies",
           "client_gone", "refuse_if_gone", "redact", "AccessLog", "TokenRedactor"]

STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
PROTECT = ("all", "control")  # what the access token guards
TOKEN_COOKIE = "stereocam_token"
TOKEN_GIVEN_COOKIE = "stereocam_has_token"  # set readable by earlier daemons: now only ever removed
TOKEN_PARAM = "token"  # ?token=: every GET that may need the token accepts it besides its own parameters
TOKEN_COOKIE_AGE_S = 365 * 24 * 3600
PAGE_PATHS = frozenset({"/", "/index.html"})
# No camera data, no settings (/api/views: the view registry the page builds its figures from).
# The sign-in form and its state: a POST to them needs the same origin, not the token (they take it).
SIGNIN_PATHS = frozenset({"/signin", "/signout", "/api/session"})
OPEN_PATHS = frozenset({"/", "/index.html", "/healthz", "/favicon.ico", "/api/views"}) | SIGNIN_PATHS
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


def _raw_query_token(request: web.Request) -> Optional[str]:
    """``?token=`` as it is in the URL (``request.query`` reads a ``+`` as a space)."""
    for item in request.rel_url.raw_query_string.split("&"):
        name, sep, value = item.partition("=")
        if sep and unquote(name) == TOKEN_PARAM:
            return value
    return None


def token_given(request: web.Request, *, query: bool) -> Optional[str]:
    """The token a request carries, as sent: ``Authorization: Bearer``, ``X-Stereocam-Token``, the
    ``stereocam_token`` cookie, then (``query``: reads only, a link must not carry a change)
    ``?token=``; None when there is none."""
    auth = request.headers.get("Authorization", "")
    if auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    header = request.headers.get("X-Stereocam-Token")
    if header is not None:
        return header
    cookie = request.cookies.get(TOKEN_COOKIE)
    if cookie:
        return cookie
    return _raw_query_token(request) if query else None


def token_matches(given: str, expected: bytes) -> bool:
    """The one rule: ``given`` as sent, or percent-decoded, is the token (constant time, both compared).

    Header bytes that are not UTF-8 arrive as surrogates: they are compared as the bytes sent.
    """
    candidates = {given, unquote(given, errors="surrogateescape")}
    ok = False
    for text in candidates:
        ok |= hmac.compare_digest(text.encode("utf-8", "surrogateescape"), expected)
    return ok


def set_token_cookies(resp: web.StreamResponse, token: str, *, secure: bool) -> None:
    """Set the page's cookie to ``token`` (``HttpOnly``, ``SameSite=Strict``, a year), or remove it
    (``token`` empty). Percent-encoded: any token is then a legal cookie value, sent back as it was set.
    The readable ``stereocam_has_token`` that earlier daemons set is removed: the page asks
    ``/api/session`` instead, and no cookie a script can read says anything about the token."""
    encoded = quote(token.encode("utf-8", "surrogateescape"), safe="")
    resp.set_cookie(TOKEN_COOKIE, encoded, max_age=TOKEN_COOKIE_AGE_S if token else 0, path="/",
                    samesite="Strict", httponly=True, secure=secure)
    resp.set_cookie(TOKEN_GIVEN_COOKIE, "", max_age=0, path="/", samesite="Strict", httponly=True,
                    secure=secure)


def page_token_redirect(request: web.Request) -> Optional[web.Response]:
    """``GET /?token=T``: a 303 to the same URL without ``token`` that sets the page's cookie
    (:func:`set_token_cookies`; ``/?token=`` with nothing forgets it); None for any other request.
    Set by the server, not by the page's script: the script never holds the token."""
    if request.method not in ("GET", "HEAD") or request.path not in PAGE_PATHS:
        return None
    token = _raw_query_token(request)
    if token is None:
        return None
    kept = [(k, v) for k, v in request.query.items() if k != TOKEN_PARAM]
    location = request.path + ("?" + urlencode(kept) if kept else "")
    resp = web.Response(status=303, headers={"Location": location, "Cache-Control": "no-store",
                                             "Referrer-Policy": "no-referrer"})
    set_token_cookies(resp, unquote(token, errors="surrogateescape"), secure=request.secure)
    return resp


# -- a client that went away ------------------------------------------------------------------

def client_gone(request: web.Request) -> bool:
    """True when the request's client has closed its connection (so nobody reads the answer).

    The transport may not know yet: the client's FIN can still wait in the socket, read after the
    request (a request that waited for the daemon, whose client gave up). A peek says so
    without taking a byte. Blocks nothing; False when it cannot tell.
    """
    transport = request.transport
    if transport is None or transport.is_closing():
        return True
    sock = transport.get_extra_info("socket")
    if sock is None:
        return False
    try:
        peek = socket.socket(fileno=socket.dup(sock.fileno()))  # a duplicate: closing it keeps the socket
    except OSError:
        return False  # out of fds: cannot tell
    with peek:
        try:
            return peek.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except (BlockingIOError, InterruptedError):
            return False
        except OSError as exc:
            return exc.errno in (errno.ECONNRESET, errno.EPIPE, errno.ENOTCONN, errno.ETIMEDOUT)


def refuse_if_gone(request: web.Request) -> None:
    """Raise a 400 (which nobody reads) instead of acting for a client that has gone away."""
    if client_gone(request):
        raise ApiError("the client closed the connection before its request was acted on: nothing was done",
                       status=400)


# -- the token and the log --------------------------------------------------------------------

REDACTED = "<redacted>"
_TOKEN_IN_TEXT = re.compile(r"(?i)(token=)[^&\s\"';,]+")


def redact(text: str, token: Optional[str] = None) -> str:
    """``text`` with the value of every ``token=`` (a URL's query, a cookie) and every spelling of
    ``token`` (as is, percent-encoded, form-encoded) replaced by ``<redacted>``."""
    text = _TOKEN_IN_TEXT.sub(r"\1" + REDACTED, text)
    if token:
        for spelling in {token, quote(token, safe=""), quote_plus(token, safe="")}:
            text = text.replace(spelling, REDACTED)
    return text


class AccessLog(AbstractAccessLogger):
    """aiohttp's access line (``log_level: debug``), with the token's value redacted from the URL
    and the Referer (a page opened as ``/?token=`` names itself in its requests' Referer)."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        version = request.version
        self.logger.info('%s "%s %s HTTP/%d.%d" %d %d %.3fs "%s" "%s"', request.remote or "-",
                         request.method, redact(request.path_qs), version.major, version.minor,
                         response.status, response.body_length, time,
                         redact(request.headers.get("Referer", "-")), request.headers.get("User-Agent", "-"))

    @property
    def enabled(self) -> bool:
        return self.logger.isEnabledFor(logging.INFO)  # else aiohttp does not even call log()


class TokenRedactor(logging.Filter):
    """A handler's filter: the record's message, traceback and stack, with :func:`redact` applied.

    Put on the handlers that write the daemon's log (``stereocam serve`` does): whatever logger a
    record comes from (aiohttp's, a library's, ours), the token does not reach the line.
    """

    def __init__(self, token: Optional[str]) -> None:
        super().__init__()
        self.token = token

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a record whose arguments do not fit its format: written as its parts
            message = f"{record.msg} {record.args}"
        clean = redact(message, self.token)
        if clean != message:
            record.msg, record.args = clean, None
        if record.exc_info and not record.exc_text:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = redact(record.exc_text, self.token)
        if record.stack_info:
            record.stack_info = redact(record.stack_info, self.token)
        return True


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
        redirect = page_token_redirect(request)
        if redirect is not None:
            return redirect
        changing = request.method in STATE_CHANGING
        upgrade = request.headers.get("Upgrade", "").lower() == "websocket"
        if (expected is not None and protect == "all" and not changing and request.path not in OPEN_PATHS
                and not request.path.startswith(OPEN_PREFIXES)):
            given = token_given(request, query=True)
            if given is None or not token_matches(given, expected):
                raise ApiError(f"{request.path} needs the access token: sign in at /signin, or "
                               "send 'Authorization: Bearer <token>' or add ?token=<token> to the URL"
                               + (" (the token sent is wrong)" if given is not None else ""),
                               status=401, headers=CHALLENGE)
        if (changing or upgrade) and not same_origin(request):
            origin = _shown(request.headers.get("Origin", "a cross-site page"))
            raise ApiError(f"refused: {request.method} {request.path} from another origin ({origin}); use "
                           "the daemon's own page or a script without an Origin header", status=403)
        if changing and expected is not None and request.path not in SIGNIN_PATHS:
            given = token_given(request, query=False)
            if given is None or not token_matches(given, expected):
                raise ApiError(f"{request.method} {request.path} needs the access token: send "
                               "'Authorization: Bearer <token>' or 'X-Stereocam-Token: <token>', or sign "
                               "in at /signin"
                               + (" (the token sent is wrong)" if given is not None else ""),
                               status=401, headers=CHALLENGE)
        if changing and request.content_length is not None and request.content_length > max_body:
            raise ApiError(too_large(max_body, request.content_length), status=413)
        if changing:
            refuse_if_gone(request)  # a client that gave up while the request waited: do nothing for it
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
