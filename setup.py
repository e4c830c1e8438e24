"""stereocam's folder map; everything else about the package is in pyproject.toml (PEP 621).

The repository follows the project's design card: ``board/``, ``overlays/``,
``drivers/`` and ``server/`` live at the top of the tree and are installed as
sub-packages of ``stereocam`` (``stereocam.overlays`` and so on): ``FOLDERS`` is
that map. Everything else is in ``stereocam/`` at its import path, and
``stereocam/`` holds a symbolic link to each of the four, so that the source tree
is the installed tree: mypy, IDEs and ``python -c 'import stereocam.server'`` read
it from a checkout as they are.

A setuptools older than 77 ignores or rejects pyproject.toml's metadata (before 61
it builds a package named UNKNOWN without a word): the PYNQ image's venv has 59.6.
This file stops such a build with a message; on the image, install the wheel, which
needs no build (README, "On the board").
"""
import os
import sys

import setuptools

MIN_SETUPTOOLS = (77, 0)

FOLDERS = {
    "stereocam": "stereocam",
    "stereocam.board": "board",
    "stereocam.overlays": "overlays",
    "stereocam.drivers": "drivers",
    "stereocam.server": "server",
}


def _packages() -> dict:
    """Every package under the map's folders (a folder with an ``__init__.py``), and its folder."""
    found = {}
    for package, folder in FOLDERS.items():
        for here, dirs, files in os.walk(folder):
            dirs[:] = sorted(
                d for d in dirs if d != "__pycache__" and not os.path.islink(os.path.join(here, d))
            )
            if "__init__.py" in files:
                rel = os.path.relpath(here, folder)
                found[package if rel == "." else package + "." + rel.replace(os.sep, ".")] = here
    return found


def _version(text: str) -> tuple:
    parts = []
    for piece in text.split(".")[:2]:
        digits = "".join(c for c in piece if c.isdigit())
        parts.append(int(digits or 0))
    return tuple(parts)


if _version(setuptools.__version__) < MIN_SETUPTOOLS:
    sys.exit(f"building stereocam from source needs setuptools >= {MIN_SETUPTOOLS[0]} (this one is "
             f"{setuptools.__version__}): install a stereocam wheel instead (README, 'On the board'), "
             f"or pip install 'setuptools>={MIN_SETUPTOOLS[0]}' first")

PACKAGES = _packages()
setuptools.setup(packages=list(PACKAGES), package_dir=PACKAGES)
