"""The notebook test needs Jupyter's runner (nbclient, nbformat, ipykernel): where they are not
installed it is deselected (not skipped), and the header says so, so a run without them is not
mistaken for one that ran the notebook. The client's own tests need nothing more than the daemon's env.
"""
from __future__ import annotations

import importlib.util

import pytest

NOTEBOOK_PACKAGES = ("nbclient", "nbformat", "ipykernel")
NOTEBOOK_TEST = "test_notebook.py::test_the_example_notebook_runs_green_against_a_daemon"


def missing_notebook_packages() -> list[str]:
    return [name for name in NOTEBOOK_PACKAGES if importlib.util.find_spec(name) is None]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not missing_notebook_packages():
        return
    dropped = [item for item in items if item.nodeid.endswith(NOTEBOOK_TEST)]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        gone = {id(item) for item in dropped}
        items[:] = [item for item in items if id(item) not in gone]


def pytest_report_header(config: pytest.Config) -> str | None:
    missing = missing_notebook_packages()
    if not missing:
        return None
    return (f"examples/stereocam.ipynb's test deselected: {', '.join(missing)} not installed "
            "(tests/client/conftest.py)")
