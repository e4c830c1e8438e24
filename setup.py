"""Stops a build by an old setuptools with a message; everything about the package is in pyproject.toml.

A setuptools older than 77 ignores or rejects pyproject.toml's metadata (before 61
it builds a package named UNKNOWN without a word): the PYNQ image's venv has 59.6.
This file stops such a build with a message; on the image, install the wheel, which
needs no build (README, "On the board").
"""
import sys

import setuptools

MIN_SETUPTOOLS = (77, 0)


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

setuptools.setup()
