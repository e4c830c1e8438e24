"""Signing in on the page, in Chromium at 1440x900, against ``stereocam serve`` with an access token.

Without the token the page shows ONE sign-in state (no stacked 401 messages, no broken images, no
request retried behind it): the views say they wait for the sign-in. A wrong token gets the
daemon's wrong-token answer; the right one brings the live views. Afterwards nothing token-like is
anywhere a script or the history can read: the address, the history's entries, localStorage,
sessionStorage, document.cookie (the daemon's cookie is HttpOnly and SameSite=Strict). Signing out
brings the sign-in state back; a wrong cookie (``/?token=`` with the wrong one) says "wrong".
"""
from __future__ import annotations

import urllib.parse
from pathlib import Path
from typing import List

from playwright.sync_api import Page, expect

from stereocam.server.frames import views

from .chromium import BROWSER_TEST_TIMEOUT, daemon_and_page, wait_new_frames

pytestmark = BROWSER_TEST_TIMEOUT

VIEWS = list(views.VIEWS)
TOKEN = "browser+sign/in=="  # +, / and =: as base64 makes them
SPELLINGS = (TOKEN, urllib.parse.quote(TOKEN, safe=""), urllib.parse.quote_plus(TOKEN, safe=""),
             "sign/in", "sign%2Fin")
VIEWPORT = (1440, 900)


def _wait_new_frames(page: Page, names: List[str], count: int = 2) -> None:
    """Each view's <img> has shown ``count`` different frames from now on."""
    for view in names:
        wait_new_frames(page, view, count)


def _assert_waiting_for_signin(page: Page, state: str, why: str) -> None:
    box = page.get_by_test_id("signin-state")
    expect(box).to_be_visible()
    expect(box).to_have_attribute("data-state", state)
    expect(page.get_by_test_id("signin-why")).to_contain_text(why)
    expect(page.get_by_test_id("conn")).to_have_text("waiting for sign-in")
    expect(page.locator("#views figure.view[data-waiting=sign-in]")).to_have_count(len(VIEWS))
    for view in VIEWS:
        expect(page.locator(f"#frame-{view}")).to_have_text("waiting for sign-in")
    page.wait_for_function("document.body.dataset.ready === '1'")
    # One state: no error message, no image asked for (so none broken).
    assert page.get_by_test_id("message-error").count() == 0
    assert page.evaluate("[...document.querySelectorAll('#views img')].every(i => !i.getAttribute('src'))")
    expect(page.get_by_test_id("signout-form")).to_be_hidden()


def _nothing_token_like(page: Page, visited: List[str]) -> None:
    found = page.evaluate("""() => ({
        href: location.href,
        nav: performance.getEntriesByType('navigation').map(e => e.name).join(' '),
        local: JSON.stringify(Object.entries(localStorage)),
        session: JSON.stringify(Object.entries(sessionStorage)),
        cookie: document.cookie,
        history: JSON.stringify(history.state)})""")
    assert found["cookie"] == "", found  # no cookie a script can read at all
    for where, text in {**found, "visited": " ".join(visited)}.items():
        for spelling in SPELLINGS:
            assert spelling not in text, (where, text)
        assert "token=" not in text, (where, text)


def test_signin_shows_one_state_then_live_views_and_leaves_no_token_a_script_can_read(
        tmp_path: Path, artifacts_dir: Path) -> None:
    with daemon_and_page(tmp_path, artifacts_dir, fps=5.0, viewport=VIEWPORT,
                         settings={"access_token": TOKEN}) as (base, context, page):
        refused: List[str] = []
        page.on("response", lambda r: refused.append(r.url) if r.status == 401 else None)
        visited: List[str] = []
        page.on("framenavigated", lambda f: visited.append(f.url) if f == page.main_frame else None)
        try:
            # 1. No token: the sign-in state, the views waiting; nothing was refused (not even once).
            page.goto(base + "/")
            _assert_waiting_for_signin(page, "missing", "needs its access token")
            assert refused == [], refused
            page.screenshot(path=str(artifacts_dir / "signin-waiting.png"))

            # 2. A wrong token: the daemon's answer says so (and the URL holds no token).
            page.get_by_test_id("signin-token").fill("not-the-token-1")
            page.get_by_test_id("signin-submit").click()
            expect(page.get_by_test_id("signin-wrong")).to_contain_text("Wrong token")
            assert page.url == base + "/signin"
            page.screenshot(path=str(artifacts_dir / "signin-wrong.png"))

            # 3. The right token (the daemon's own form, typed again): the live views.
            page.get_by_test_id("signin-token").fill(TOKEN)
            page.get_by_test_id("signin-submit").click()
            page.wait_for_url(base + "/")
            expect(page.get_by_test_id("signin-state")).to_be_hidden()
            expect(page.get_by_test_id("signout-form")).to_be_visible()
            _wait_new_frames(page, VIEWS)
            expect(page.get_by_test_id("conn")).to_have_text("live")
            page.get_by_test_id("btn-capture").click()  # a change goes through with the cookie
            expect(page.locator("[data-testid=capture]")).to_have_count(1)
            assert page.get_by_test_id("message-error").count() == 0
            _nothing_token_like(page, visited)
            cookies = {c["name"]: c for c in context.cookies()}
            assert cookies["stereocam_token"]["httpOnly"], cookies
            assert cookies["stereocam_token"]["sameSite"] == "Strict", cookies
            assert "stereocam_has_token" not in cookies
            page.screenshot(path=str(artifacts_dir / "signin-live.png"))

            # 4. Sign out: back to the form; the page waits for a sign-in again.
            page.get_by_test_id("signout").click()
            page.wait_for_url(base + "/signin")
            assert "stereocam_token" not in {c["name"] for c in context.cookies()}
            refused.clear()
            page.goto(base + "/")
            _assert_waiting_for_signin(page, "missing", "needs its access token")
            assert refused == [], refused

            # 5. A wrong token given by link: it leaves the address bar, and the page says it is wrong.
            page.goto(base + "/?token=wrong-token-2")
            assert page.url == base + "/"
            _assert_waiting_for_signin(page, "wrong", "is wrong")
            _nothing_token_like(page, visited)
        finally:
            page.screenshot(path=str(artifacts_dir / "signin.png"))


def test_with_protect_control_the_views_run_and_a_change_points_at_the_signin_form(
        tmp_path: Path, artifacts_dir: Path) -> None:
    """``protect: control``: reads are open, so the views run; the sign-in form says the token is for
    changes, and a change without it brings the keyboard to that form instead of a 401 message."""
    with daemon_and_page(tmp_path, artifacts_dir, fps=5.0, viewport=VIEWPORT,
                         settings={"access_token": TOKEN, "protect": "control"}) as (base, _context, page):
        try:
            page.goto(base + "/")
            box = page.get_by_test_id("signin-state")
            expect(box).to_be_visible()
            expect(page.get_by_test_id("signin-why")).to_contain_text("for changes")
            _wait_new_frames(page, VIEWS[:2])
            expect(page.locator("#views figure.view[data-waiting]")).to_have_count(0)
            page.get_by_test_id("btn-capture").click()
            expect(page.get_by_test_id("signin-token")).to_be_focused()
            assert page.get_by_test_id("message-error").count() == 0
            expect(page.locator("[data-testid=capture]")).to_have_count(0)
            page.get_by_test_id("signin-token").fill(TOKEN)
            with page.expect_navigation(url=base + "/"):
                page.get_by_test_id("signin-token").press("Enter")
            page.wait_for_function("document.body.dataset.ready === '1'")
            expect(box).to_be_hidden()
            page.get_by_test_id("btn-capture").click()
            expect(page.locator("[data-testid=capture]")).to_have_count(1)
            assert page.evaluate("document.cookie") == ""
        finally:
            page.screenshot(path=str(artifacts_dir / "signin-control.png"))
