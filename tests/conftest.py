"""Fixtures every test module may use. Keep this file generic and small.

Tests run in three environments (see README, "Test environments");
``STEREOCAM_TEST_ENV`` says which: ``current``, ``board`` or ``armhf`` (unset when
pytest is run by hand).
"""
from __future__ import annotations

import os
import re
import shutil
import sys
from pathlib import Path

import pytest

from .slowness import SLOWNESS

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = Path(__file__).resolve().parent / "data"
ARTIFACTS_DIR = REPO_ROOT / "test-artifacts"


@pytest.fixture(autouse=True)
def _clear_aiohttp_middleware_cache():
    """Let each test's aiohttp application go when the test ends.

    aiohttp keeps a module-level ``lru_cache`` of built middleware chains
    (``aiohttp.web_app._cached_build_middleware``, 1024 entries), whose keys hold the
    handler and the application: every test's app, and its overlay, fabric and emulated
    DDR with it, would otherwise stay alive until the end of the run. A 32-bit process
    (the armhf env) runs out of address space long before. Versions without the cache
    have nothing to clear; a test that never imported aiohttp has nothing there either.
    """
    yield
    web_app = sys.modules.get("aiohttp.web_app")
    cache = getattr(web_app, "_cached_build_middleware", None)
    if cache is not None and hasattr(cache, "cache_clear"):
        cache.cache_clear()


@pytest.fixture(scope="session")
def test_env() -> str:
    """The test environment's name: ``current``, ``board``, ``armhf`` or ``""`` (run by hand)."""
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


# -- markers -------------------------------------------------------------------------------------
# `slow`: the fast loop (`./scripts/test --fast`: the current env, `-m "not slow"`) leaves these out.
# A module or test says so itself (`pytestmark = pytest.mark.slow`, `@pytest.mark.slow`): those that
# start another program (the daemon, a browser, a player, a simulator, yosys, pip), drive the daemon
# through many frames, or time something. tests/browser and tests/hdl mark all their tests in
# their own conftest. A test given a longer timeout than the default is slow too. A run without
# `-m` runs every test. Chosen from `pytest --durations=0 -m "not slow" tests/`: keep the fast loop
# under a minute.
# `armhf`: the module takes part in the armhf env's subset (below); `not_on_armhf(reason)`: this test
# of such a module cannot pass there, and is deselected in that subset.
MARKERS = (
    "armhf: the module runs in the armhf env's subset (tests/conftest.py)",
    "not_on_armhf(reason): deselected in the armhf env's subset, for the reason given",
    "not_on_board_env(reason): deselected in the board env (what the board lacks by design, e.g. numba)",
)


def pytest_configure(config: pytest.Config) -> None:
    for line in MARKERS:
        config.addinivalue_line("markers", line)


def _mark_slow(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark slow every test whose timeout is longer than the default (a long timeout says: slow)."""
    try:
        default_timeout = float(config.getini("timeout") or 0)
    except ValueError:  # no pytest-timeout: no timeout marks to compare either
        return
    for item in items:
        timeout = item.get_closest_marker("timeout")
        if timeout and timeout.args and float(timeout.args[0]) > default_timeout:
            item.add_marker(pytest.mark.slow)


def _scale_timeouts(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test's timeout (its mark's, or the ini's) times the environment's slowness.

    The timeouts are written as what an idle host needs, with room; pytest-timeout's is a hang
    detector, and a busy machine or qemu must never trip it (tests/slowness.py).
    """
    try:
        default = float(config.getini("timeout") or 0)
    except ValueError:  # no pytest-timeout
        return
    for item in items:
        mark = item.get_closest_marker("timeout")
        kwargs = dict(mark.kwargs) if mark else {}
        given = mark.args[0] if mark and mark.args else kwargs.pop("timeout", None)
        base = float(given) if given is not None else default
        if base > 0:
            item.add_marker(pytest.mark.timeout(base * SLOWNESS, **kwargs), append=False)


# -- the armhf env's subset ---------------------------------------------------------------------
# The armhf env (README, "Test environments") runs Debian's armhf Python under qemu-user, many
# times slower than the host. When pytest gets no test paths there (./scripts/test, CI), it runs
# the modules marked `armhf` (`pytestmark`): what 32-bit numpy, an older numpy and OpenCV could
# break, needing no browser, ffmpeg, VLC, systemd-analyze, Verilator, Icarus or pynq. The other
# modules are not even imported (under qemu an import costs seconds, and some need packages armhf
# lacks): a module's text is read for the mark first. Tests marked `not_on_armhf` are deselected:
# nothing there is skipped at run time. Any module runs there when named:
# STEREOCAM_ENVS=armhf ./scripts/test tests/server/test_x.py.
ARMHF_MARK = "pytest.mark.armhf"


def _armhf_subset_run(config: pytest.Config) -> bool:
    """Whether this run is the armhf env's subset: armhf, and no test paths on the command line."""
    if os.environ.get("STEREOCAM_TEST_ENV") != "armhf":
        return False
    args_source = getattr(pytest.Config, "ArgsSource", None)
    return args_source is None or config.args_source != args_source.ARGS


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if collection_path.is_dir() or not collection_path.name.startswith("test_"):
        return None
    if not _armhf_subset_run(config):
        return None
    return True if ARMHF_MARK not in collection_path.read_text(encoding="utf-8") else None


def _deselect_not_on_board(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In the board env, the tests of what the board does not have (marked not_on_board_env)."""
    if os.environ.get("STEREOCAM_TEST_ENV") != "board":
        return
    dropped = [item for item in items if item.get_closest_marker("not_on_board_env")]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        gone = {id(item) for item in dropped}
        items[:] = [item for item in items if id(item) not in gone]


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    _mark_slow(config, items)
    _scale_timeouts(config, items)
    _deselect_not_on_board(config, items)
    if not _armhf_subset_run(config):
        return
    # The text check above only spares imports: the marks decide.
    dropped = [item for item in items
               if item.get_closest_marker("armhf") is None or item.get_closest_marker("not_on_armhf")]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        gone = {id(item) for item in dropped}
        items[:] = [item for item in items if id(item) not in gone]


def pytest_report_header(config: pytest.Config) -> str | None:
    if not _armhf_subset_run(config):
        return None
    return ("armhf subset: the modules marked armhf, less the tests marked not_on_armhf "
            "(tests/conftest.py); name test paths to run others")
