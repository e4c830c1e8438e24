"""The stereo core's model: one entry point over the compiled and the numpy path.

``compute(left, right, params)`` returns the integers the core's RTL emits for a rectified gray
pair (``STEREO_CORE.md``). ``path="auto"`` takes the compiled path where numba runs and numpy
elsewhere (the board); both are tested equal to the per-pixel reference, so the choice changes
speed, never a result.
"""
from __future__ import annotations

import importlib.util
from typing import Callable, Dict

import numpy as np

from ..spec import stereo as spec
from . import stereo_fast, stereo_jit, stereo_reference
from .stereo_result import StereoResult, check_pair

__all__ = ["PATHS", "StereoResult", "check_pair", "compiled_path_installed", "compute", "fastest_path"]

PATHS: Dict[str, Callable[[np.ndarray, np.ndarray, spec.StereoParams], StereoResult]] = {
    "jit": stereo_jit.compute,
    "numpy": stereo_fast.compute,
    "reference": stereo_reference.compute,
}


def compiled_path_installed() -> bool:
    """Whether numba is installed, without importing it (a second at start-up): what the daemon decides
    its emulated stereo core by; :func:`fastest_path` then builds the kernels on first use."""
    return importlib.util.find_spec("numba") is not None


def fastest_path() -> str:
    """``jit`` where numba runs, else ``numpy``."""
    return "jit" if stereo_jit.available() else "numpy"


def compute(left: np.ndarray, right: np.ndarray, params: spec.StereoParams = spec.DEFAULT_PARAMS,
            *, path: str = "auto") -> StereoResult:
    """The core's output for a rectified gray pair (``uint8``, same shape). ValueError for bad input."""
    name = fastest_path() if path == "auto" else path
    if name not in PATHS:
        raise ValueError(f"unknown model path {path!r} (auto, {', '.join(PATHS)})")
    return PATHS[name](left, right, params)
