"""The page in Debian's Chromium against the real daemon: every test here is slow.

Each test starts ``stereocam serve`` as a subprocess and a browser (:mod:`.chromium`); the fast
loop (``-m "not slow"``) leaves them all out.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import pytest

HERE = Path(__file__).parent
DAEMON_FPS = 15.0  # the emulated cameras' rate unless a test module sets its own DAEMON_FPS


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if HERE in Path(str(item.path)).parents:
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def daemon(request: pytest.FixtureRequest, tmp_path: Path, artifacts_dir: Path) -> Iterator[str]:
    """The real daemon on a free port (emulated fabric) at the test module's ``DAEMON_FPS`` (else 15)
    with its ``DAEMON_SETTINGS`` (else none); its base URL.

    A module that needs other options defines its own ``daemon``.
    """
    from .chromium import daemon_serving  # here: playwright is not in every environment that collects

    fps = float(getattr(request.module, "DAEMON_FPS", DAEMON_FPS))
    settings = dict(getattr(request.module, "DAEMON_SETTINGS", {}))
    with daemon_serving(tmp_path, artifacts_dir, fps=fps, settings=settings) as base:
        yield base
