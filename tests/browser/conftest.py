"""The page in Debian's Chromium against the real daemon: every test here is slow.

Each test starts ``stereocam serve`` as a subprocess and a browser (:mod:`.chromium`); the fast
loop (``-m "not slow"``) leaves them all out.
"""
from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).parent


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if HERE in Path(str(item.path)).parents:
            item.add_marker(pytest.mark.slow)
