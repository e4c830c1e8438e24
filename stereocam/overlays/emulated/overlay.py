"""The emulated twin of the board overlay: an :class:`EmulatedFabric` with the real drivers bound to it."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Dict, Optional

from ...drivers.rectify import RectifyCore
from ..fabric import FabricOverlay, StereoFabric, bind
from ..spec.axis_switch import VLNV as SWITCH_VLNV
from ..spec.overlay import ADDRESS_MAP, INSTANCES, OPTIONAL_ADDRESS_MAP, OPTIONAL_INSTANCES, WINDOW_SIZE
from ..spec.rectify import DEFAULT_BUILD, Build
from .cameras import CameraSource
from .faults import FaultInjector
from .logic import CLOCK_THREAD, EmulatedFabric, StreamCore
from .regblock import EmulationError, RegisterBlock
from .sensors import EmulatedSensorPair
from .stereo import STEREO_THREAD

if TYPE_CHECKING:  # pragma: no cover
    from ...board.profile import BoardProfile
    from ...calibration.file import Calibration

RIG_CALIBRATION = "the synthetic rig's known calibration (emulated fabric)"


class EmulatedOverlay(FabricOverlay):
    """Emulated fabric + :class:`StereoFabric`; a context manager that starts and stops everything.

    With ``clock="stepped"`` frames move only on :meth:`step`; with
    ``"realtime"`` the fabric's clock thread runs at ``fps`` between
    :meth:`start` and :meth:`stop`. The daemon drives it as an
    :class:`~..interface.Overlay` (:class:`FabricOverlay`).
    """

    backend = "emulated"
    # Threads that are the emulated hardware, not the daemon: the CPU budget does not count them.
    emulation_threads = (CLOCK_THREAD, STEREO_THREAD)

    def __init__(self, *, source: Optional[CameraSource] = None, fps: float = 60.0, clock: str = "realtime",
                 build: Build = DEFAULT_BUILD, lb_rows: Optional[int] = None, timeout: float = 1.0,
                 core: Optional[StreamCore] = None, core_kind: str = "model", stereo: bool = True) -> None:
        """``build``: the rectify core's build parameters; ``lb_rows`` overrides its line-buffer rows.

        ``stereo``: the fabric has the stereo core (a ``depth`` build); False: none, as today's bitstream.

        ``core``: what stands in the rectify core's place instead of the model (the RTL, built
        for ``build``); ``core_kind`` names it in the daemon's status ("model" or "rtl").
        """
        self.core_kind = core_kind
        # The emulated hardware itself: IP blocks, DDR, cameras and the frame clock.
        self.emulation = EmulatedFabric(source=source, fps=fps, clock=clock, build=build, lb_rows=lb_rows,
                                        core=core, stereo=stereo)
        self.sensors: Optional[EmulatedSensorPair] = None  # set by attach_sensors
        self.fault_injection: Optional[FaultInjector] = FaultInjector(self.emulation)
        blocks = {**self.emulation.blocks, **self.emulation.optional_blocks}
        addresses = {**ADDRESS_MAP, **OPTIONAL_ADDRESS_MAP}
        vlnvs = {**INSTANCES, **OPTIONAL_INSTANCES}
        self.ip_dict: Dict[str, Dict[str, Any]] = {
            name: {
                "phys_addr": addresses[name],
                "addr_range": WINDOW_SIZE,
                "type": SWITCH_VLNV if name == "mux" else vlnvs[name][-1],
                "parameters": {"C_NUM_FSTORES": str(self.emulation.num_fstores), "NUM_SI": "2"},
            }
            for name in blocks
        }
        by_address = {addresses[name]: block for name, block in blocks.items()}

        def open_window(address: int, length: int) -> "RegisterBlock | StreamCore":
            try:
                return by_address[address]
            except KeyError:
                raise EmulationError(f"no emulated IP at {address:#x}") from None

        self.fabric: StereoFabric = bind(self.ip_dict, open_window, self.emulation.ddr.allocate,
                                         backend=self.backend, frame_size=self.emulation.frame_size,
                                         timeout=timeout, depth=self.emulation.stereo)

    # Drivers, for convenience.
    @property
    def rectify(self) -> RectifyCore:
        return self.fabric.rectify

    def start(self) -> "EmulatedOverlay":
        """Start the DMA streams and (realtime) the frame clock; idempotent."""
        self.fabric.start_streams()
        self.emulation.start()
        return self

    def stop(self) -> None:
        """Stop the clock, then the streams (mux back to live); idempotent."""
        self.emulation.stop()
        self.fabric.stop_streams()

    # -- sensors, faults and the emulated rig
    def attach_sensors(self, profile: BoardProfile, **options: Any) -> EmulatedSensorPair:
        """The board's two sensors as ``profile`` describes them, driving this fabric's cameras from now on.

        ``options`` go to :class:`EmulatedSensorPair` (chip ids, read noise). Drive the pair over
        its ``bus``; :attr:`sensors` is it until the next call.
        """
        pair = EmulatedSensorPair.for_profile(profile, self.emulation.source, **options)
        self.emulation.sensors = pair
        self.sensors = pair
        return pair

    def rig_calibration(self) -> Optional[Calibration]:
        """The synthetic rig's known calibration (the cameras' true model); None for replayed frames."""
        model = getattr(self.emulation.source, "model", None)
        if model is None:
            return None
        from ...calibration.file import Calibration
        from ...calibration.stereo import rectify

        return Calibration.derive(model, rectify(model, alpha=0.0), alpha=0.0, units="m",
                                  source=RIG_CALIBRATION)

    def step(self, n: int = 1) -> None:
        self.emulation.step(n)

    def close(self) -> None:
        self.stop()
        self.fabric.close()
        self.emulation.close()

    def __enter__(self) -> "EmulatedOverlay":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
