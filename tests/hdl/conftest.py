"""Fixtures for the simulator tests; ``cocotb_run.run_cocotb`` does the work.

These tests run in the ``current`` env only (``scripts/test`` passes ``--ignore=tests/hdl``
to the board env): they exercise the RTL and the simulators, not numpy or OpenCV.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from stereocam import hdl


@pytest.fixture(params=hdl.SIMULATORS)
def sim(request: pytest.FixtureRequest) -> str:
    """Each simulator cocotb drives here in turn: a test taking ``sim`` runs under all of them."""
    return str(request.param)


@pytest.fixture
def cocotb_dir(artifacts_dir: Path) -> Path:
    """Where a run's ``results.xml`` and ``sim.log`` go: the test's own, kept, artifacts folder."""
    return artifacts_dir
