"""A Python process of the test environment starts and imports stereocam without a word on stderr,
and every module of the package is read from the one path git knows it by.

In the armhf env the package is not installed: the checkout is on ``PYTHONPATH`` there. In the
others it is an editable install. Either way ``stereocam/`` is the package as it is in git (no
links, no folder map): a traceback, mypy, import-linter, ruff, an IDE and ``git blame`` all name
a file the same way. This module runs in every environment, armhf included.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.armhf

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "stereocam"

_ORIGINS = """
import importlib.util, pkgutil, stereocam
names = ["stereocam"] + [m.name for m in pkgutil.walk_packages(stereocam.__path__, "stereocam.",
                                                                  onerror=lambda name: None)]
for name in names:
    print(name, importlib.util.find_spec(name).origin)
"""


def _python(code: str) -> subprocess.CompletedProcess:
    # Generous: Python under qemu-user takes seconds to start and more to import numpy and OpenCV.
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)


def test_a_bare_python_start_prints_nothing() -> None:
    done = _python("pass")
    assert (done.returncode, done.stderr) == (0, "")


def test_importing_the_package_prints_nothing_and_finds_every_top_level_folder() -> None:
    done = _python("import stereocam.board, stereocam.drivers, stereocam.overlays\n"
                   "import stereocam.server, stereocam.server.frames.pipeline\n"
                   "print(stereocam.server.frames.pipeline.__file__)")
    assert (done.returncode, done.stderr) == (0, "")
    assert Path(done.stdout.strip()) == PACKAGE / "server" / "frames" / "pipeline.py"


def test_every_module_is_imported_from_its_file_in_the_tree() -> None:
    """The path a traceback shows for each module is the file under ``stereocam/``, not a link."""
    done = _python(_ORIGINS)
    assert done.returncode == 0, done.stderr
    origins = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    files = {p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts
             and (p.parent / "__init__.py").exists()}
    assert {Path(o) for o in origins.values()} == files
    assert not any(p.is_symlink() for p in PACKAGE.rglob("*")), "a link gives a file a second path"
    assert len(origins) > 100
