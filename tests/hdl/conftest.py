"""Fixtures for the simulator tests; ``cocotb_run.run_cocotb`` does the work.

These tests run in the ``current`` env only (``scripts/test`` passes ``--ignore=tests/hdl``
to the board env): they exercise the RTL and the simulators, not numpy or OpenCV.
"""
from __future__ import annotations

from pathlib import Path
from typing import List

import pytest

from stereocam.overlays.rtl import toolchain as hdl

HDL_TIMEOUT_S = 1800.0
"""The least per-test timeout of a simulator test (pyproject's 120 s is for quick tests).

A simulation or a synthesis is all CPU: on a busy machine it takes several times as long as
on an idle one, and the timeout is only the last-resort bound of a hang.
"""


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(items: List[pytest.Item]) -> None:
    """Mark every test under ``tests/hdl`` slow, with a timeout of at least :data:`HDL_TIMEOUT_S`."""
    here = Path(__file__).parent
    for item in items:
        if here not in Path(str(item.path)).parents:
            continue
        item.add_marker(pytest.mark.slow)
        marker = item.get_closest_marker("timeout")
        current = None
        if marker is not None:
            current = marker.args[0] if marker.args else marker.kwargs.get("timeout")
        if current is None or float(current) < HDL_TIMEOUT_S:
            item.add_marker(pytest.mark.timeout(HDL_TIMEOUT_S), append=False)


@pytest.fixture(params=hdl.SIMULATORS)
def sim(request: pytest.FixtureRequest) -> str:
    """Each simulator cocotb drives here in turn: a test taking ``sim`` runs under all of them."""
    return str(request.param)


@pytest.fixture
def cocotb_dir(artifacts_dir: Path) -> Path:
    """Where a run's ``results.xml`` and ``sim.log`` go: the test's own, kept, artifacts folder."""
    return artifacts_dir
