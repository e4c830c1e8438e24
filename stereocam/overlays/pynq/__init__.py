"""The board's binding: our drivers on pynq, the overlay that owns the fabric, its lock and guard.

:func:`import_pynq` is the one way in to pynq, for this package and the emulator's pynq device
alike. It imports pynq only when called: pynq imports :mod:`.guard` (this package) in every
process that makes an ``Overlay``, and the daemon off the board never has pynq.
"""
from __future__ import annotations

import warnings
from typing import Any

__all__ = ["import_pynq"]


def import_pynq() -> Any:
    """Import and return the ``pynq`` package (raises ImportError where it is not installed).

    pynq's import-time warnings off the board (``pkg_resources`` deprecation, "does not
    support the CPU Architecture") are silenced for that import only.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="pkg_resources is deprecated", category=DeprecationWarning)
        warnings.filterwarnings(
            "ignore", message="Pynq does not support the CPU Architecture", category=ResourceWarning
        )
        import pynq
        import pynq.lib.video.dma  # noqa: F401  (the VDMA driver the emulator's tests run)
        import pynq.pl_server.device  # noqa: F401
    return pynq
