"""The emulated twin of the board overlay: an :class:`EmulatedFabric` with the real drivers bound to it."""
from __future__ import annotations

from typing import Any, Dict, Optional

from ...drivers.rectify import RectifyCore
from ..fabric import StereoFabric, bind
from ..spec.axis_switch import VLNV as SWITCH_VLNV
from ..spec.overlay import ADDRESS_MAP, INSTANCES, WINDOW_SIZE
from ..spec.rectify import DEFAULT_BUILD, Build
from .cameras import CameraSource
from .fabric import CLOCK_THREAD, EmulatedFabric, StreamCore
from .regblock import EmulationError, RegisterBlock


class EmulatedOverlay:
    """Emulated fabric + :class:`StereoFabric`; a context manager that starts and stops everything.

    With ``clock="stepped"`` frames move only on :meth:`step`; with
    ``"realtime"`` the fabric's clock thread runs at ``fps`` between
    :meth:`start` and :meth:`stop`.
    """

    backend = "emulated"
    # Threads that are the emulated hardware, not the daemon: the CPU budget does not count them.
    emulation_threads = (CLOCK_THREAD,)

    def __init__(self, *, source: Optional[CameraSource] = None, fps: float = 60.0, clock: str = "realtime",
                 build: Build = DEFAULT_BUILD, lb_rows: Optional[int] = None, timeout: float = 1.0,
                 core: Optional[StreamCore] = None, core_kind: str = "model") -> None:
        """``build``: the rectify core's build parameters; ``lb_rows`` overrides its line-buffer rows.

        ``core``: what stands in the rectify core's place instead of the model (the RTL, built
        for ``build``); ``core_kind`` names it in the daemon's status ("model" or "rtl").
        """
        self.core_kind = core_kind
        self.hw = EmulatedFabric(source=source, fps=fps, clock=clock, build=build, lb_rows=lb_rows, core=core)
        blocks = self.hw.blocks
        self.ip_dict: Dict[str, Dict[str, Any]] = {
            name: {
                "phys_addr": ADDRESS_MAP[name],
                "addr_range": WINDOW_SIZE,
                "type": SWITCH_VLNV if name == "mux" else INSTANCES[name][-1],
                "parameters": {"C_NUM_FSTORES": str(self.hw.num_fstores), "NUM_SI": "2"},
            }
            for name in blocks
        }
        by_address = {ADDRESS_MAP[name]: block for name, block in blocks.items()}

        def open_window(address: int, length: int) -> "RegisterBlock | StreamCore":
            try:
                return by_address[address]
            except KeyError:
                raise EmulationError(f"no emulated IP at {address:#x}") from None

        self.fabric: StereoFabric = bind(self.ip_dict, open_window, self.hw.ddr.allocate, backend=self.backend,
                                         frame_size=self.hw.frame_size, timeout=timeout)

    # Drivers, for convenience.
    @property
    def rectify(self) -> RectifyCore:
        return self.fabric.rectify

    def start(self) -> "EmulatedOverlay":
        """Start the DMA streams and (realtime) the frame clock; idempotent."""
        self.fabric.start_streams()
        self.hw.start()
        return self

    def stop(self) -> None:
        """Stop the clock, then the streams (mux back to live); idempotent."""
        self.hw.stop()
        self.fabric.stop_streams()

    def step(self, n: int = 1) -> None:
        self.hw.step(n)

    def close(self) -> None:
        self.stop()
        self.fabric.close()
        self.hw.close()

    def __enter__(self) -> "EmulatedOverlay":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
