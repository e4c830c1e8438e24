"""Refuse a bitstream download while the stereocam daemon owns the fabric, in any pynq process.

Reprogramming the PL under the running daemon ends its streams mid-transfer and can hang
the AXI bus on its next register access. pynq offers no hook for that, but every
``pynq.Overlay(...)`` imports the modules registered under the ``pynq.lib`` entry-point
group before it downloads anything (``Overlay._register_drivers``); stereocam registers this
module there (pyproject.toml's entry points). Imported, it wraps ``EmbeddedDevice.download``
so that, while another process holds the fabric lock (:mod:`.lock`), a download raises
:class:`~.lock.FabricBusy` naming the daemon and how to stop it. The daemon's own download
(it holds the lock) goes through.

It imports no driver: binding our drivers to pynq's VLNVs (:mod:`.drivers`) stays
opt-in, so a notebook's base overlay keeps pynq's own VDMA driver. A process that calls
``Bitstream(...).download()`` without ever making an ``Overlay`` is not covered.
"""
from __future__ import annotations

import functools
import warnings
from typing import Any, Callable

from .lock import FabricBusy, held_by_another_process

__all__ = ["guarded", "install"]

_MARK = "_stereocam_guarded"


def guarded(download: Callable[..., Any]) -> Callable[..., Any]:
    """``download`` that first refuses while another process holds the fabric lock."""
    if getattr(download, _MARK, False):
        return download

    @functools.wraps(download)
    def wrapper(self: Any, bitstream: Any, *args: Any, **kwargs: Any) -> Any:
        holder = held_by_another_process()
        if holder is not None:
            name = getattr(bitstream, "bitfile_name", bitstream)
            raise FabricBusy(f"refusing to load {name}: {holder._busy_message()}")
        return download(self, bitstream, *args, **kwargs)

    setattr(wrapper, _MARK, True)
    return wrapper


def install() -> bool:
    """Wrap pynq's ``EmbeddedDevice.download`` (once); False where pynq has no embedded device."""
    try:
        with warnings.catch_warnings():  # pynq's import-time warnings off the board (pkg_resources, CPU)
            warnings.simplefilter("ignore")
            from pynq.pl_server.embedded_device import EmbeddedDevice
    except ImportError:
        return False
    EmbeddedDevice.download = guarded(EmbeddedDevice.download)
    return True


install()
