"""Signing in with the access token: the daemon's form, its HttpOnly cookie, the wrong-token answer,
the same-origin rule for the POST, the limit on guessing, signing out, and /api/session."""
from __future__ import annotations

from typing import List

import aiohttp

from stereocam.server.http.signin import MAX_WRONG, SIGNIN_LIMIT, WINDOW_S, GuessLimit

TOKEN = "s3cret+sign/in=="


def _jar(d):  # noqa: ANN001, ANN202 - a daemon's browser-like session (keeps cookies of an IP address)
    return d.session(cookie_jar=aiohttp.CookieJar(unsafe=True))


def _origin(d) -> dict:  # noqa: ANN001
    return {"Origin": f"http://127.0.0.1:{d.port}"}


async def test_the_form_signs_in_with_the_right_token_and_sets_only_an_httponly_cookie(start_daemon) -> None:
    d = await start_daemon(access_token=TOKEN)
    jar = _jar(d)
    async with jar.get("/signin") as resp:
        assert resp.status == 200 and resp.content_type == "text/html"
        text = await resp.text()
        assert 'method="post" action="/signin"' in text and 'type="password"' in text
        assert resp.headers["Cache-Control"] == "no-store" and resp.headers["X-Frame-Options"] == "DENY"
    async with jar.get("/api/session") as resp:
        assert resp.status == 200
        assert await resp.json() == {"token_required": True, "signed_in": False, "token_sent": False,
                                     "protect": "all"}
    async with jar.post("/signin", data={"token": TOKEN}, headers=_origin(d), allow_redirects=False) as resp:
        assert resp.status == 303 and resp.headers["Location"] == "/"
        cookies = {c.split("=", 1)[0]: c for c in resp.headers.getall("Set-Cookie")}
    token_cookie = cookies["stereocam_token"].lower()
    for attribute in ("httponly", "samesite=strict", "path=/", "max-age=31536000"):
        assert attribute in token_cookie, token_cookie
    assert TOKEN not in cookies["stereocam_token"]  # percent-encoded
    assert "max-age=0" in cookies["stereocam_has_token"].lower()  # no script-readable cookie is set
    async with jar.get("/api/session") as resp:
        assert (await resp.json())["signed_in"] is True
    async with jar.get("/api/status") as resp:
        assert resp.status == 200
    async with jar.post("/api/captures", headers=_origin(d)) as resp:
        assert resp.status == 201, await resp.text()
    async with jar.get("/signin") as resp:
        assert 'data-testid="signin-done"' in await resp.text()
    # Sign out: the cookie goes, reads and changes want the token again.
    async with jar.post("/signout", headers=_origin(d), allow_redirects=False) as resp:
        assert resp.status == 303 and resp.headers["Location"] == "/signin"
        assert all("max-age=0" in c.lower() for c in resp.headers.getall("Set-Cookie"))
    async with jar.get("/api/status") as resp:
        assert resp.status == 401
        assert "sign in at /signin" in (await resp.json())["error"]
    async with jar.get("/api/session") as resp:
        assert (await resp.json())["signed_in"] is False


async def test_a_wrong_or_missing_token_answers_the_form_saying_so_and_sets_no_cookie(start_daemon) -> None:
    d = await start_daemon(access_token=TOKEN, protect="control")
    jar = _jar(d)
    for token in ("wrong-token-123", TOKEN[:-1], TOKEN + "x"):
        async with jar.post("/signin", data={"token": token}, headers=_origin(d),
                            allow_redirects=False) as resp:
            assert resp.status == 401, token
            text = await resp.text()
            assert 'data-testid="signin-wrong"' in text and "Wrong token" in text
            assert "Set-Cookie" not in resp.headers
            assert token not in text  # never echoed
    for data in ({"token": ""}, {"token": "   "}, {}):
        async with jar.post("/signin", data=data, headers=_origin(d), allow_redirects=False) as resp:
            assert resp.status == 400, data
            assert 'data-testid="signin-missing"' in await resp.text()
    async with jar.post("/api/captures", headers=_origin(d)) as resp:
        assert resp.status == 401
    # A cookie that is wrong (the daemon's token changed): the form and the session say so.
    async with d.http.get("/signin", headers={"Cookie": "stereocam_token=stale-token-1"}) as resp:
        assert resp.status == 200 and 'data-testid="signin-wrong"' in await resp.text()
    async with d.http.get("/api/session", headers={"Cookie": "stereocam_token=stale-token-1"}) as resp:
        assert await resp.json() == {"token_required": True, "signed_in": False, "token_sent": True,
                                     "protect": "control"}


async def test_a_cross_site_form_cannot_sign_a_browser_in_or_out(start_daemon) -> None:
    d = await start_daemon(access_token=TOKEN)
    jar = _jar(d)
    for headers in ({"Origin": "http://evil.example"}, {"Origin": "null"}, {"Sec-Fetch-Site": "cross-site"},
                    {"Sec-Fetch-Site": "same-site"}):
        async with jar.post("/signin", data={"token": TOKEN}, headers=headers, allow_redirects=False) as resp:
            assert resp.status == 403, headers
            assert "another origin" in (await resp.json())["error"]
            assert "Set-Cookie" not in resp.headers
    async with jar.get("/api/session") as resp:
        assert (await resp.json())["signed_in"] is False
    async with jar.post("/signin", data={"token": TOKEN}, headers=_origin(d), allow_redirects=False) as resp:
        assert resp.status == 303
    async with jar.post("/signout", headers={"Origin": "http://evil.example"}, allow_redirects=False) as resp:
        assert resp.status == 403 and "Set-Cookie" not in resp.headers
    async with jar.get("/api/session") as resp:
        assert (await resp.json())["signed_in"] is True


async def test_guessing_is_held_after_a_few_wrong_tokens_without_holding_anyone_else(start_daemon) -> None:
    d = await start_daemon(access_token=TOKEN)
    jar = _jar(d)
    statuses: List[int] = []
    for i in range(MAX_WRONG):
        async with jar.post("/signin", data={"token": f"guess-{i:04d}"}, headers=_origin(d),
                            allow_redirects=False) as resp:
            statuses.append(resp.status)
    assert statuses == [401] * (MAX_WRONG - 1) + [429]
    # Held: even the right token is refused (a guesser learns nothing), and the answer says how long.
    async with jar.post("/signin", data={"token": TOKEN}, headers=_origin(d), allow_redirects=False) as resp:
        assert resp.status == 429
        assert 0 < int(resp.headers["Retry-After"]) <= WINDOW_S
        text = await resp.text()
        assert 'data-testid="signin-held"' in text and "Too many wrong tokens" in text
        assert "Set-Cookie" not in resp.headers
    # Once the window has passed (the daemon's limit, told the time has moved on), signing in works.
    limit = d.app[SIGNIN_LIMIT]
    now = limit.clock()
    limit.clock = lambda: now + WINDOW_S + 1
    async with jar.post("/signin", data={"token": TOKEN}, headers=_origin(d), allow_redirects=False) as resp:
        assert resp.status == 303


def test_the_guess_limit_slides_and_forgets_a_client_that_signed_in() -> None:
    t = [100.0]
    limit = GuessLimit(max_wrong=3, window_s=10.0, clock=lambda: t[0])
    for _ in range(2):
        limit.wrong("a")
        t[0] += 1
    assert limit.held_for("a") == 0.0
    limit.wrong("a")  # third within 10 s: held until the first is 10 s old
    assert limit.held_for("a") == 8.0 and limit.held_for("b") == 0.0
    t[0] += 8.0
    assert limit.held_for("a") == 0.0  # the first fell out of the window
    limit.wrong("a")
    assert limit.held_for("a") > 0
    limit.right("a")
    assert limit.held_for("a") == 0.0


async def test_without_a_token_there_is_nothing_to_sign_in_to(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/api/session") as resp:
        assert await resp.json() == {"token_required": False, "signed_in": True, "token_sent": False,
                                     "protect": "all"}
    async with d.http.get("/signin") as resp:
        assert resp.status == 200 and 'data-testid="signin-none"' in await resp.text()
    async with d.http.post("/signin", data={"token": "anything-1"}, allow_redirects=False) as resp:
        assert resp.status == 409 and "Set-Cookie" not in resp.headers
