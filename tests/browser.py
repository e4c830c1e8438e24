"""What the browser tests share: the real daemon as a subprocess, Debian's Chromium, a watched page.

Debian's ``/usr/bin/chromium`` is driven by the ``playwright`` package (never
``playwright install``: its browser download does not work here). Every
Playwright wait is bounded (20 s unless a test says otherwise).
"""
from __future__ import annotations

import contextlib
import json
import urllib.request
from pathlib import Path
from typing import Any, Dict, Iterator, List, Sequence

from playwright.sync_api import BrowserContext, Page, sync_playwright

from stereocam.bench_serve import running_daemon

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TIMEOUT_MS = 20_000


def get_json(url: str) -> Dict[str, Any]:
    with urllib.request.urlopen(url, timeout=10) as resp:
        result: Dict[str, Any] = json.loads(resp.read())
        return result


@contextlib.contextmanager
def daemon_serving(tmp_path: Path, artifacts_dir: Path, *, fps: float, extra_args: Sequence[str] = ()
                   ) -> Iterator[str]:
    """``stereocam serve`` on a free port (emulated fabric, captures in ``tmp_path``); yields its base URL."""
    with running_daemon(fps=fps, captures=tmp_path / "captures", log_path=artifacts_dir / "daemon.log",
                        health_timeout=60.0, extra_args=extra_args) as (_proc, base):
        yield base


@contextlib.contextmanager
def chromium(profile: Path) -> Iterator[BrowserContext]:
    """Debian's Chromium, headless, with a fresh profile; every Playwright wait bounded to 20 s."""
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS,
            viewport={"width": 1400, "height": 1000})
        try:
            context.set_default_timeout(TIMEOUT_MS)
            context.set_default_navigation_timeout(TIMEOUT_MS)
            yield context
        finally:
            context.close()


@contextlib.contextmanager
def watched_page(tmp_path: Path, artifacts_dir: Path, screenshot: str, *, expected: Sequence[str] = ()
                 ) -> Iterator[Page]:
    """A page whose script errors and console errors fail the test, screenshot saved even on failure.

    ``expected``: texts of console errors the test provokes on purpose (Chromium logs every
    non-2xx fetch, e.g. "status of 409").
    """
    problems: List[str] = []
    with chromium(tmp_path / "chromium-profile") as context:
        page = context.new_page()
        page.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
        page.on("console", lambda msg: problems.append(f"console {msg.type}: {msg.text}")
                if msg.type == "error" and not any(e in msg.text for e in expected) else None)
        try:
            yield page
        finally:
            page.screenshot(path=str(artifacts_dir / screenshot), full_page=True)
    assert not problems, problems
