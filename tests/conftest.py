"""Fixtures every test module may use. Keep this file generic and small.

Tests run in two environments (see README, "Test environments");
``STEREOCAM_TEST_ENV`` says which: ``current`` or ``board`` (unset when pytest
is run by hand).
"""
from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = Path(__file__).resolve().parent / "data"
ARTIFACTS_DIR = REPO_ROOT / "test-artifacts"


@pytest.fixture(scope="session")
def test_env() -> str:
    """The test environment's name: ``current``, ``board`` or ``""`` (run by hand)."""
    return os.environ.get("STEREOCAM_TEST_ENV", "")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``tests/data``: read-only files shipped with the tests."""
    return DATA_DIR


@pytest.fixture
def artifacts_dir(request: pytest.FixtureRequest) -> Path:
    """A fresh folder for files a person may want to look at after the run.

    ``test-artifacts/<env>/<test id>/`` at the top of the checkout (ignored by
    git), e.g. browser screenshots. Emptied at the start of the test, kept after it.
    """
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", request.node.nodeid.removeprefix("tests/"))[:120]
    env = os.environ.get("STEREOCAM_TEST_ENV") or "manual"
    path = ARTIFACTS_DIR / env / name
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True, exist_ok=True)
    return path
