"""Signing in with the access token: a form the daemon serves, the page's cookie, a limit on guessing.

- ``GET /signin``: a plain HTML form (no script: it works whatever state the page is in) with one
  password field. ``POST /signin`` (form field ``token``) with the right token answers ``303`` to
  ``/`` and sets the page's ``HttpOnly; SameSite=Strict`` cookie (:func:`.security.set_token_cookies`);
  the token travels in the body only, so it is never in an address bar, the history or a log line.
  A wrong token answers ``401`` with the form again, saying so. Same-origin rules hold (the guard
  refuses another origin's POST with 403 before this handler runs: a cross-site form cannot sign a
  browser in with the attacker's token).
- Guessing: every wrong token waits :data:`WRONG_DELAY_S` (an ``asyncio.sleep``: the loop serves
  everyone else meanwhile), and a client (its address) with :data:`MAX_WRONG` wrong tokens within
  :data:`WINDOW_S` gets ``429`` (``Retry-After``) until the oldest of them is that old, whatever it
  sends, the right token included: a guesser learns nothing while it is held.
- ``POST /signout``: removes the cookie, ``303`` to ``/signin``.
- ``GET /api/session``: ``{"token_required", "signed_in", "token_sent", "protect"}``, for the page to
  show one "sign in" state instead of a failure per request (it cannot read its HttpOnly cookie).
"""
from __future__ import annotations

import asyncio
import html
import time
from collections import OrderedDict, deque
from typing import Callable, Deque, Optional

from aiohttp import web

from .security import set_token_cookies, token_given, token_matches
from .state import SETTINGS

__all__ = ["GuessLimit", "setup", "MAX_WRONG", "WINDOW_S", "WRONG_DELAY_S", "SIGNIN_LIMIT"]

MAX_WRONG = 5  # wrong tokens a client may send within WINDOW_S
WINDOW_S = 60.0
WRONG_DELAY_S = 0.5  # each wrong token's answer waits this long
MAX_CLIENTS = 1024  # addresses remembered (the oldest forgotten first): a flood cannot grow memory


class GuessLimit:
    """Wrong tokens per client address over a sliding window; ``clock`` is for tests."""

    def __init__(self, *, max_wrong: int = MAX_WRONG, window_s: float = WINDOW_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.max_wrong = max_wrong
        self.window_s = window_s
        self.clock = clock
        self._wrong: "OrderedDict[str, Deque[float]]" = OrderedDict()

    def _recent(self, client: str) -> Deque[float]:
        times = self._wrong.get(client)
        if times is None:
            return deque()
        cutoff = self.clock() - self.window_s
        while times and times[0] <= cutoff:
            times.popleft()
        if not times:
            del self._wrong[client]
        return times

    def held_for(self, client: str) -> float:
        """Seconds until ``client`` may try again (0: it may now)."""
        times = self._recent(client)
        if len(times) < self.max_wrong:
            return 0.0
        return max(0.0, times[-self.max_wrong] + self.window_s - self.clock())

    def wrong(self, client: str) -> None:
        times = self._recent(client)
        self._wrong[client] = times
        self._wrong.move_to_end(client)
        times.append(self.clock())
        while len(self._wrong) > MAX_CLIENTS:
            self._wrong.popitem(last=False)

    def right(self, client: str) -> None:
        self._wrong.pop(client, None)


SIGNIN_LIMIT: "web.AppKey[GuessLimit]" = web.AppKey("stereocam.signin_limit", GuessLimit)

_STYLE = """body{font:16px system-ui,sans-serif;max-width:28rem;margin:4rem auto;padding:0 1rem}
input,button{font:inherit;padding:.4rem .6rem}input{width:100%;box-sizing:border-box;margin:.4rem 0 .8rem}
.bad{color:#b00020;font-weight:600}@media(prefers-color-scheme:dark){body{background:#111;color:#eee}
.bad{color:#ff6b6b}}"""


def _page(body: str, status: int, headers: Optional[dict] = None) -> web.Response:
    text = ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            "<meta name=\"color-scheme\" content=\"light dark\"><title>stereocam: sign in</title>"
            f"<link rel=\"icon\" href=\"/static/favicon.svg\" type=\"image/svg+xml\"><style>{_STYLE}</style>"
            f"</head><body><h1>stereocam</h1>{body}</body></html>")
    # Referrer-Policy same-origin, not no-referrer: under no-referrer Chromium sends its form's POST
    # with "Origin: null", which the same-origin rule refuses.
    return web.Response(text=text, status=status, content_type="text/html", headers={
        "Cache-Control": "no-store", "Referrer-Policy": "same-origin", "X-Frame-Options": "DENY",
        "Content-Security-Policy": "default-src 'none'; style-src 'unsafe-inline'; img-src 'self'; "
                                   "form-action 'self'; frame-ancestors 'none'", **(headers or {})})


def _form(message: str = "", kind: str = "") -> str:
    said = (f"<p id=\"signin-message\" data-testid=\"signin-{kind}\" class=\"bad\" role=\"alert\">"
            f"{html.escape(message)}</p>") if message else ""
    return (f"{said}<form method=\"post\" action=\"/signin\" data-testid=\"signin-form\">"
            "<label for=\"signin-token\">Access token (the daemon's <code>access_token</code> setting, "
            "or <code>stereocam serve --access-token</code>)</label>"
            "<input id=\"signin-token\" data-testid=\"signin-token\" name=\"token\" type=\"password\" "
            "autocomplete=\"current-password\" required autofocus>"
            "<button type=\"submit\" data-testid=\"signin-submit\">Sign in</button></form>"
            "<p>The token is kept in a cookie this browser sends only to this daemon; no script can read "
            "it. Sign out from the page to remove it.</p>")


def _client(request: web.Request) -> str:
    return request.remote or "?"


def _expected(request: web.Request) -> Optional[bytes]:
    token = request.app[SETTINGS].access_token
    return token.encode("utf-8") if token else None


async def signin_form(request: web.Request) -> web.Response:
    """The form; or, when the daemon has no token or this browser's cookie is right, a link to the page."""
    expected = _expected(request)
    if expected is None:
        return _page("<p data-testid=\"signin-none\">This daemon has no access token: there is nothing "
                     "to sign in to. <a href=\"/\">Open the page</a>.</p>", 200)
    given = token_given(request, query=False)
    if given is not None and token_matches(given, expected):
        return _page("<p data-testid=\"signin-done\">This browser is signed in. <a href=\"/\">Open the "
                     "page</a>.</p><form method=\"post\" action=\"/signout\"><button type=\"submit\" "
                     "data-testid=\"signout\">Sign out</button></form>", 200)
    if given is not None:
        return _page(_form("The token this browser holds is wrong (the daemon's token may have changed): "
                           "type the current one.", "wrong"), 200)
    return _page(_form(), 200)


async def signin(request: web.Request) -> web.Response:
    """Check the posted token: the cookie and ``303 /`` when right, the form saying why otherwise."""
    expected = _expected(request)
    if expected is None:
        return _page("<p data-testid=\"signin-none\">This daemon has no access token: there is nothing "
                     "to sign in to. <a href=\"/\">Open the page</a>.</p>", 409)
    limit = request.app[SIGNIN_LIMIT]
    client = _client(request)
    held = limit.held_for(client)
    if held > 0:
        return _too_many(held)
    form = await request.post()
    token = form.get("token")
    if not isinstance(token, str) or not token.strip():
        return _page(_form("Type the access token, then sign in.", "missing"), 400)
    if not token_matches(token, expected):
        limit.wrong(client)
        await asyncio.sleep(WRONG_DELAY_S)  # slows a guesser; the loop serves everyone else meanwhile
        held = limit.held_for(client)
        if held > 0:
            return _too_many(held)
        return _page(_form("Wrong token: check it (it is case-sensitive) and type it again.", "wrong"), 401)
    limit.right(client)
    resp = web.Response(status=303, headers={"Location": "/", "Cache-Control": "no-store",
                                             "Referrer-Policy": "no-referrer"})
    set_token_cookies(resp, token, secure=request.secure)
    return resp


def _too_many(held: float) -> web.Response:
    wait = max(1, int(held + 0.999))
    return _page(_form(f"Too many wrong tokens from this computer: wait {wait} s, then try again.", "held"),
                 429, {"Retry-After": str(wait)})


async def signout(request: web.Request) -> web.Response:
    """Remove the page's cookie and go to the form."""
    resp = web.Response(status=303, headers={"Location": "/signin", "Cache-Control": "no-store"})
    set_token_cookies(resp, "", secure=request.secure)
    return resp


async def session(request: web.Request) -> web.Response:
    """Whether this daemon wants a token and whether this request carries the right one (no query:
    the page asks with its cookie)."""
    expected = _expected(request)
    given = token_given(request, query=False)
    signed_in = expected is None or (given is not None and token_matches(given, expected))
    return web.json_response({"token_required": expected is not None, "signed_in": signed_in,
                              "token_sent": given is not None, "protect": request.app[SETTINGS].protect},
                             headers={"Cache-Control": "no-store"})


def setup(app: web.Application) -> None:
    """Add the sign-in routes (part of every daemon: the page relies on ``/api/session``)."""
    app[SIGNIN_LIMIT] = GuessLimit()
    app.router.add_get("/signin", signin_form)
    app.router.add_post("/signin", signin)
    app.router.add_post("/signout", signout)
    app.router.add_get("/api/session", session)
