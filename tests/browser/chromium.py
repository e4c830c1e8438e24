"""What the browser tests share: the real daemon as a subprocess, Debian's Chromium, a watched page.

Debian's ``/usr/bin/chromium`` is driven by the ``playwright`` package (never
``playwright install``: its browser download does not work here). Every
Playwright wait, ``expect()`` assertions included, waits for its condition, bounded by
:data:`TIMEOUT_MS` (60 s): a generous last-resort bound, so that a busy machine makes a
browser test slower, not red. A browser test module sets :data:`BROWSER_TEST_TIMEOUT` as its
per-test timeout (pytestmark), as its many bounded waits add up to more than the default's.

The daemon runs with :data:`DAEMON_SETTINGS` (a settings file, ``--config``): see there why.
"""
from __future__ import annotations

import contextlib
import json
import urllib.request
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Sequence, Set, Tuple

import pytest
from playwright.sync_api import BrowserContext, Locator, Page, expect, sync_playwright

from stereocam.bench.serve import running_daemon

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TIMEOUT_MS = 60_000
# pytest-timeout for a whole browser test (pyproject's 120 s is for one test that does not start
# a daemon and Chromium and wait for dozens of page conditions).
BROWSER_TEST_TIMEOUT = pytest.mark.timeout(900)


# On a busy machine the emulated fabric may deliver under a frame a second. With the default
# no_signal_s (0.5 s) a capture, a calibration pair or a snapshot then waits only 1 s for a fresh
# frame and answers 503 "no signal: no frame came within 1 s" (the daemon waits max(1 s,
# 2 * no_signal_s)), and the streams show the no-signal frame between frames. 15 s: they wait up
# to 30 s, a last resort that only a stopped fabric reaches (what the daemon itself does for its
# slow simulated core: stereocam/server/http/app.py, RTL_NO_SIGNAL_S). No browser test is about no-signal
# timing.
DAEMON_SETTINGS: Dict[str, Any] = {"no_signal_s": 15.0}


def daemon_config(folder: Path, **settings: Any) -> Path:
    """A settings file for ``stereocam serve --config``: :data:`DAEMON_SETTINGS` and ``settings``."""
    path = folder / "stereocam.yaml"
    lines = [f"{key}: {json.dumps(value)}\n" for key, value in {**DAEMON_SETTINGS, **settings}.items()]
    path.write_text("".join(lines))
    return path


def get_json(url: str) -> Dict[str, Any]:
    with urllib.request.urlopen(url, timeout=60) as resp:
        result: Dict[str, Any] = json.loads(resp.read())
        return result


@contextlib.contextmanager
def daemon_serving(tmp_path: Path, artifacts_dir: Path, *, fps: float, extra_args: Sequence[str] = (),
                   settings: Optional[Dict[str, Any]] = None) -> Iterator[str]:
    """``stereocam serve`` on a free port; yields its base URL.

    Emulated fabric, captures in ``tmp_path``, :data:`DAEMON_SETTINGS` and ``settings``.
    """
    args = ["--config", str(daemon_config(tmp_path, **(settings or {}))), *extra_args]
    with running_daemon(fps=fps, captures=tmp_path / "captures", log_path=artifacts_dir / "daemon.log",
                        health_timeout=TIMEOUT_MS / 1000, extra_args=args) as (_proc, base):
        yield base


@contextlib.contextmanager
def chromium(profile: Path, viewport: Tuple[int, int] = (1400, 1000), device_scale_factor: float = 1
             ) -> Iterator[BrowserContext]:
    """Debian's Chromium, headless, with a fresh profile; every Playwright wait bounded to ``TIMEOUT_MS``.

    ``device_scale_factor``: the window's device pixel ratio (2: a HiDPI screen).
    """
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS,
            viewport={"width": viewport[0], "height": viewport[1]}, timeout=TIMEOUT_MS,
            device_scale_factor=device_scale_factor)
        try:
            context.set_default_timeout(TIMEOUT_MS)
            context.set_default_navigation_timeout(TIMEOUT_MS)
            # expect() has its own default (5 s), which the context's does not change.
            expect.set_options(timeout=TIMEOUT_MS)
            yield context
        finally:
            context.close()


@contextlib.contextmanager
def daemon_and_page(tmp_path: Path, artifacts_dir: Path, *, fps: float, viewport: Tuple[int, int],
                    settings: Dict[str, Any]) -> Iterator[Tuple[str, BrowserContext, Page]]:
    """A daemon with ``settings`` and a new page in Chromium at ``viewport``: (base URL, context, page).

    A script error on the page fails the test; console errors do not (a page of a daemon with an
    access token provokes 401s on purpose, which Chromium logs as errors).
    """
    problems: List[str] = []
    with daemon_serving(tmp_path, artifacts_dir, fps=fps, settings=settings) as base:
        with chromium(tmp_path / "chromium-profile", viewport=viewport) as context:
            page = context.new_page()
            page.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
            yield base, context, page
    assert not problems, problems


@contextlib.contextmanager
def live_page(tmp_path: Path, artifacts_dir: Path, screenshot: str, *, fps: float,
              viewport: Dict[str, int]) -> Iterator[Tuple[str, Page]]:
    """A daemon and its page loaded at ``viewport`` (a :func:`watched_page`): (base URL, page)."""
    with daemon_serving(tmp_path, artifacts_dir, fps=fps) as base:
        with watched_page(tmp_path, artifacts_dir, screenshot) as page:
            page.set_viewport_size(viewport)  # type: ignore[arg-type]
            page.goto(base + "/")
            yield base, page


def record_in_page(page: Page, seconds: int) -> Locator:
    """Record ``seconds`` from the page's Record panel; the recording's list item, once done."""
    expect(page.get_by_test_id("conn")).to_have_text("live")
    page.get_by_test_id("record-seconds").fill(str(seconds))
    page.get_by_test_id("btn-record").click()
    item = page.locator("[data-testid=recording]").first
    expect(item).to_have_attribute("data-state", "done")
    return item


def wait_frames(page: Page, views: Sequence[str]) -> None:
    """Until each view's <img> has shown a frame.

    The figures are built by views.js after GET /api/views answers, which may be after the page's
    load event: a predicate must treat a missing element as "not yet", never throw on it.
    """
    for view in views:
        page.wait_for_function(
            "id => { const f = document.getElementById(id)?.dataset.frame;"
            " return f !== undefined && f !== '' && Number(f) >= 0; }", arg="view-" + view)


def wait_new_frames(page: Page, view: str, count: int = 2) -> None:
    """Wait until the view's <img> has shown ``count`` different frames from now on."""
    seen: Set[Optional[str]] = set()
    for _ in range(count):
        page.wait_for_function(
            "([id, seen]) => { const f = document.getElementById(id)?.dataset.frame;"
            " return f !== '' && f !== undefined && !seen.includes(f); }",
            arg=[f"view-{view}", sorted(f for f in seen if f)])
        seen.add(page.get_attribute(f"#view-{view}", "data-frame"))


@contextlib.contextmanager
def watched_page(tmp_path: Path, artifacts_dir: Path, screenshot: str, *, expected: Sequence[str] = (),
                 device_scale_factor: float = 1) -> Iterator[Page]:
    """A page whose script errors and console errors fail the test, screenshot saved even on failure.

    ``expected``: texts of console errors the test provokes on purpose (Chromium logs every
    non-2xx fetch, e.g. "status of 409").
    """
    problems: List[str] = []
    with chromium(tmp_path / "chromium-profile", device_scale_factor=device_scale_factor) as context:
        page = context.new_page()
        page.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
        page.on("console", lambda msg: problems.append(f"console {msg.type}: {msg.text}")
                if msg.type == "error" and not any(e in msg.text for e in expected) else None)
        try:
            yield page
        finally:
            page.screenshot(path=str(artifacts_dir / screenshot), full_page=True)
    assert not problems, problems


# The two windows issue 24's check names: a laptop and a phone.
DESKTOP = {"width": 1440, "height": 900}
PHONE = {"width": 375, "height": 812}


def open_in_window(page: Page, base: str, views: Sequence[str], window: Dict[str, int] = DESKTOP) -> None:
    """The daemon's page at ``base`` in a ``window``-sized viewport (:data:`DESKTOP` unless given), once
    each of ``views`` has shown a frame (:func:`wait_frames`)."""
    page.set_viewport_size(window)  # type: ignore[arg-type]
    page.goto(base + "/")
    wait_frames(page, views)


def assert_no_sideways_scroll(page: Page, state: str) -> None:
    """The page is at most as wide as the window in ``state``: nothing pushes the views sideways.

    Issue 24's check (a 1504 px fit preview made the page 2708 px wide); ``state`` names what the
    test did, for the failure's message.
    """
    wide, window = page.evaluate("() => [document.scrollingElement.scrollWidth, window.innerWidth]")
    assert wide <= window, f"{state}: the page is {wide} px wide in a {window} px window"


def assert_messages_clear_of_views(page: Page) -> None:
    """No message box overlaps a live view (messages must not cover the views)."""
    overlaps = page.evaluate("""() => {
      const hit = [];
      for (const m of document.querySelectorAll('#messages .msg')) {
        const a = m.getBoundingClientRect();
        for (const v of document.querySelectorAll('#views figure')) {
          const b = v.getBoundingClientRect();
          const meet = a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom;
          if (meet) hit.push(v.id || 'view');
        }
      }
      return hit; }""")
    assert overlaps == [], f"messages cover the views {overlaps}"
