"""A Python process of the test environment starts and imports stereocam without a word on stderr.

In the armhf env the package is not installed: a ``.pth`` file in the rootfs imports
``scripts/_stereocam_checkout.py`` at every start, which reads setup.py's folder map. When that
broke, every Python start there printed a traceback while the tests still passed (they import
through ``stereocam/``'s symbolic links): this module runs in every environment, armhf included.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _python(code: str) -> subprocess.CompletedProcess:
    # Generous: Python under qemu-user takes seconds to start and more to import numpy and OpenCV.
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)


def test_a_bare_python_start_prints_nothing() -> None:
    done = _python("pass")
    assert (done.returncode, done.stderr) == (0, "")


def test_importing_the_package_prints_nothing_and_finds_every_top_level_folder() -> None:
    done = _python("import stereocam.board, stereocam.drivers, stereocam.overlays\n"
                   "import os, stereocam.server, stereocam.server.frames.pipeline\n"
                   "print(os.path.realpath(stereocam.server.__file__))")
    assert (done.returncode, done.stderr) == (0, "")
    assert Path(done.stdout.strip()) == REPO / "server" / "__init__.py"


def test_the_checkout_finder_reads_setup_pys_folder_map() -> None:
    """The armhf rootfs's finder maps each package of setup.py's map to its folder."""
    sys.path.insert(0, str(REPO / "scripts"))
    try:
        import _stereocam_checkout as checkout
    finally:
        sys.path.remove(str(REPO / "scripts"))
    folders = checkout._folders(str(REPO))
    assert folders["stereocam.server"] == str(REPO / "server")
    assert folders["stereocam"] == str(REPO / "stereocam")
    spec = checkout.CheckoutFinder(folders).find_spec("stereocam.drivers")
    assert spec is not None and spec.origin == str(REPO / "drivers" / "__init__.py")
