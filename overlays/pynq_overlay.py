"""The board overlay: a ``pynq.Overlay`` that loads the stereocam bitstream and binds our drivers.

Imported only where pynq is installed (on the board, and in the board-like
test environment); :mod:`.backend` decides. The fabric is not re-programmed
when the bitstream is already loaded, so restarting the daemon does not
glitch the cameras.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Optional, Tuple

from .emulated.pynq_device import import_pynq
from .fabric import StereoFabric, bind

log = logging.getLogger(__name__)
pynq = import_pynq()


def bind_pynq(ip_dict: Any, device: Any, *, frame_size: Tuple[int, int], timeout: float = 1.0) -> StereoFabric:
    """Our drivers on pynq's register windows (``pynq.MMIO``) and memory (``pynq.allocate``)."""
    return bind(
        ip_dict,
        lambda address, length: pynq.MMIO(address, length, device=device),
        lambda shape, dtype="u1": pynq.allocate(shape, dtype, target=device.default_memory),
        backend="pynq", frame_size=frame_size, timeout=timeout,
    )


class StereocamOverlay(pynq.Overlay):  # type: ignore[name-defined]  # pynq: a module object, typed Any
    """The stereocam bitstream with :attr:`fabric` (a :class:`StereoFabric`) bound to its IP.

    ``bitfile`` needs its ``.hwh`` beside it (pynq reads the IP addresses and
    parameters from it). ``device`` is passed to pynq (None: the board's).
    """

    def __init__(self, bitfile: Path, *, frame_size: Tuple[int, int] = (752, 480), device: Optional[Any] = None,
                 timeout: float = 1.0) -> None:
        super().__init__(str(bitfile), download=False, device=device)
        if self.is_loaded():
            log.info("overlay %s is already loaded: binding without re-programming the fabric", bitfile)
        else:
            log.info("programming the fabric with %s", bitfile)
            self.download()
        self.fabric: StereoFabric = bind_pynq(self.ip_dict, self.device, frame_size=frame_size, timeout=timeout)

    backend = "pynq"

    def start(self) -> "StereocamOverlay":
        self.fabric.start_streams()
        return self

    def stop(self) -> None:
        self.fabric.stop_streams()

    def close(self) -> None:
        self.fabric.close()
