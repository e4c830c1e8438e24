"""stereocam's folder map; everything else about the package is in pyproject.toml (PEP 621).

The repository follows the design card in SYSTEM.md: ``board/``, ``overlays/``,
``drivers/`` and ``server/`` live at the top of the tree and are installed as
sub-packages of ``stereocam`` (``stereocam.overlays`` and so on). ``SUBPACKAGES``
is that map, here because ``scripts/typecheck`` reads it to lay out the tree for mypy.

A setuptools older than 77 ignores or rejects pyproject.toml's metadata (before 61
it builds a package named UNKNOWN without a word): the PYNQ image's venv has 59.6.
This file stops such a build with a message; on the image, install the wheel, which
needs no build (README, "On the board").
"""
import sys

import setuptools

MIN_SETUPTOOLS = (77, 0)

SUBPACKAGES = {
    "stereocam": "stereocam",
    "stereocam.board": "board",
    "stereocam.overlays": "overlays",
    "stereocam.overlays.spec": "overlays/spec",
    "stereocam.overlays.model": "overlays/model",
    "stereocam.overlays.emulated": "overlays/emulated",
    "stereocam.drivers": "drivers",
    "stereocam.server": "server",
}


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

setuptools.setup(packages=list(SUBPACKAGES), package_dir=SUBPACKAGES)
