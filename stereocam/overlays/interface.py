"""What the daemon may ask of an overlay: the one typed seam between ``stereocam/server/`` and the hardware.

The board's overlay (:mod:`.pynq.overlay`), the emulated one
(:mod:`.emulated.overlay`) and any later one (the RTL under a simulator)
satisfy :class:`Overlay`; the daemon holds nothing else of theirs, so it
never drives a DMA channel, reads a register by name or decodes one. The
errors the members raise, and the two cameras' sensors as the daemon reads
and sets them over the bus :func:`.backend.sensor_bus` gives, are re-exported
here, so the daemon imports them from this module and not from the drivers.

Blocking: every method that touches the fabric blocks for register reads
(and, where it says so, for a bounded wait); call them off the event loop.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import (
    TYPE_CHECKING,
    Any,
    Callable,
    Dict,
    Literal,
    Mapping,
    Optional,
    Protocol,
    Sequence,
    Tuple,
    Union,
    runtime_checkable,
)

import numpy as np

from ..drivers.i2c import I2CBus, I2CDenied, I2CError
from ..drivers.mmio import DriverError, RegisterTimeout
from ..drivers.mt9v034 import CAMERAS, SensorUnavailable, StereoSensors
from ..drivers.stereo import StereoConfigRefused, StereoStatus
from ..drivers.vdma import ChannelFault, ChannelNotStarted, NoFrameYet, VDMAError
from .model.linebuffer import LineBufferFit
from .model.result import CoreOptions
from .spec.rectify import CameraParams, CameraRegs, CoreConfig
from .spec.stereo import Build as StereoBuild
from .spec.stereo import StereoParams
from .spec.vdma import FATAL_ERRORS

if TYPE_CHECKING:  # pragma: no cover
    from ..calibration.file import Calibration

__all__ = [
    "Overlay", "RectifyControl", "Choice", "ChannelStatus", "StoredFrame", "Channel", "CHANNELS",
    "DEPTH_CHANNEL", "Source",
    "COMMIT_TIMEOUT_S", "DriverError", "RegisterTimeout", "ChannelFault", "ChannelNotStarted", "NoFrameYet",
    "VDMAError", "BackendError", "I2CBus", "I2CDenied", "I2CError", "CAMERAS", "SensorUnavailable",
    "StereoSensors", "StereoControl", "StereoConfigRefused", "StereoStatus", "StereoBuild", "StereoParams",
]

# The DMA channels, named ``<vdma instance>.<direction>``: the three every overlay has, and the
# stereo core's output channel where the bitstream has one (``DEPTH_CHANNEL``).
Channel = Literal["vdma_raw.s2mm", "vdma_proc.s2mm", "vdma_proc.mm2s", "vdma_depth.s2mm"]
CHANNELS: Tuple[Channel, ...] = ("vdma_raw.s2mm", "vdma_proc.s2mm", "vdma_proc.mm2s")
DEPTH_CHANNEL: Channel = "vdma_depth.s2mm"
Source = Literal["live", "virtual"]
COMMIT_TIMEOUT_S = 0.5  # a mux commit waits for the end of a packet (a line): microseconds when healthy
Camera = Union[CameraParams, CameraRegs]


class BackendError(RuntimeError):
    """The backend asked for cannot be used, or the fabric is not ours; the message says what is missing."""


@dataclass(frozen=True)
class Choice:
    """Which backend an overlay is and why it was chosen (the daemon logs and shows ``reason``)."""

    backend: str
    reason: str
    bitstream: Optional[Path] = None
    # True on a board (pynq importable), even when the emulated fabric was chosen: the board's CPU budget.
    board: bool = False
    # What the user must be told loudly (log, /api/status, the page): e.g. a board without its bitstream.
    warning: Optional[str] = None


@dataclass(frozen=True)
class ChannelStatus:
    """One DMA channel as its status register shows it; ``configured`` False: never started."""

    configured: bool
    running: bool
    errors: Tuple[str, ...]

    @property
    def fatal(self) -> Tuple[str, ...]:
        """The errors that halt the channel until it is restarted."""
        return tuple(e for e in self.errors if e in FATAL_ERRORS)


@dataclass(frozen=True)
class StoredFrame:
    """A completed frame store as the DMA left it: ``pixels`` is the store itself, not a copy.

    Valid until the channel comes round to ``store`` again (``stores``
    completions later): copy it before then and never write to it.
    """

    store: int
    stores: int
    pixels: np.ndarray


@runtime_checkable
class RectifyControl(Protocol):
    """The rectify core's parameters: check, write and read back a configuration (blocking calls)."""

    @property
    def lb_rows(self) -> int: ...
    @property
    def max_width(self) -> int: ...
    @property
    def max_height(self) -> int: ...
    @property
    def colour(self) -> bool: ...

    def plan(self, left: Camera, right: Camera, width: int,
             height: int) -> "tuple[CoreConfig, LineBufferFit]":
        """The configuration for a calibration, checked against this core; raises ``CoreParamsError``."""

    def program(self, left: Camera, right: Camera, width: int, height: int, *,
                wait: bool = True) -> "tuple[CoreConfig, LineBufferFit]":
        """:meth:`plan`, then write it and wait until the core latched it."""

    def load(self, config: CoreConfig, *, wait: bool = True) -> None:
        """Write and latch ``config`` as it is (the core may refuse it: ``ConfigRefused``)."""

    def read_config(self) -> CoreConfig:
        """The configuration the core holds."""

    def dump(self) -> Dict[str, int]:
        """Every register by name, for a capture's metadata."""


@runtime_checkable
class StereoControl(Protocol):
    """The stereo core's parameters and progress (blocking register reads and writes)."""

    @property
    def build(self) -> StereoBuild:
        """The core's build parameters, read back from it: what :meth:`StereoParams.problems` checks."""

    def params(self) -> StereoParams:
        """The parameters the core holds (written by the last :meth:`program`)."""

    def program(self, params: StereoParams, *, size: Optional[Tuple[int, int]] = None,
                wait: bool = True) -> None:
        """Write and APPLY ``params`` (and the frame ``size`` where given).

        ValueError with the problems (nothing written) for values the core refuses.

        With ``wait`` it blocks until the core latched them (the next frame start), at most the
        driver's timeout (:class:`RegisterTimeout`); :class:`StereoConfigRefused` if the core refused.
        """

    def status(self) -> StereoStatus:
        """Frame count, enable, busy, apply pending and the sticky flags (register reads)."""


@runtime_checkable
class Overlay(Protocol):
    """One loaded overlay as the daemon drives it; see the module doc.

    ``start``/``stop``/``close`` are idempotent; the frame, source and
    health members work between ``start`` and ``stop``.
    """

    # -- what it is -----------------------------------------------------------------------
    choice: Optional[Choice]  # set by whoever chose the backend; None when built directly

    @property
    def backend(self) -> str:
        """``"pynq"`` or ``"emulated"``."""

    @property
    def core_kind(self) -> str:
        """What computes the rectify core: ``"hardware"``, or off the board ``"model"`` or ``"rtl"``."""

    @property
    def emulation_threads(self) -> Tuple[str, ...]:
        """Names of the threads that are emulated hardware, not the daemon (none on the board)."""

    @property
    def frame_size(self) -> Tuple[int, int]:
        """``(width, height)`` of every frame the fabric takes and gives."""

    @property
    def raw_stores(self) -> int:
        """Frame stores of the raw channel: a raw frame is overwritten this many frames later."""

    @property
    def streaming(self) -> bool:
        """True between :meth:`start` and :meth:`stop`."""

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> object:
        """Start every DMA channel, the cameras on the core, the core enabled (blocks)."""

    def stop(self) -> None:
        """Mux back to live, core off, every channel stopped (blocks)."""

    def close(self) -> None:
        """:meth:`stop`, then free the buffers and give up the fabric."""

    # -- frames ---------------------------------------------------------------------------
    def wait_processed(self, timeout: float) -> None:
        """Block until the processed channel completes a frame (one not waited for before).

        Raises :class:`RegisterTimeout` when none completes within ``timeout`` s,
        :class:`ChannelFault` when the channel halted, :class:`ChannelNotStarted`
        when the fabric does not stream.
        """

    def processed_store(self) -> StoredFrame:
        """The latest completed processed frame, in place (:class:`NoFrameYet`, :class:`ChannelFault`)."""

    def raw_store(self, store: Optional[int] = None) -> StoredFrame:
        """The latest completed raw frame in place; with ``store``, that store as it is now."""

    def latest_raw(self) -> Tuple[int, np.ndarray]:
        """``(store, copy)`` of the latest completed raw frame, owned by the caller."""

    def latest_processed(self) -> Tuple[int, np.ndarray]:
        """``(store, copy)`` of the latest completed processed frame, owned by the caller."""

    def frame_count(self) -> int:
        """Frames the core has emitted (wraps at 2**32): what numbers frames and latches calibrations."""

    # -- the source -----------------------------------------------------------------------
    @property
    def source(self) -> str:
        """What the mux feeds the core: ``"live"``, ``"virtual"`` or ``"off"``."""

    def select(self, source: str, timeout: float = COMMIT_TIMEOUT_S) -> None:
        """Route ``source`` to the core; :class:`RegisterTimeout` when the mux does not commit in time."""

    # -- the virtual camera ---------------------------------------------------------------
    def send_virtual(self, frame: np.ndarray) -> int:
        """Put a ``(H, W, 8)`` frame on the virtual camera; returns the frame store it went to."""

    def wait_virtual_taken(self, timeout: float) -> int:
        """Block until the virtual camera reads the frame last sent (at most ``timeout`` s); its store."""

    # -- the rectify core -----------------------------------------------------------------
    @property
    def rectify(self) -> RectifyControl:
        """The core's parameters."""

    def core_setup(self) -> Tuple[CoreConfig, CoreOptions]:
        """What the core runs with, read back from it, as the model takes it (blocks)."""

    def status(self) -> Dict[str, Any]:
        """JSON for ``/api/status``: backend, source, streaming, frame size, core and channel state."""

    # -- the stereo core (optional) --------------------------------------------------------
    @property
    def stereo(self) -> Optional[StereoControl]:
        """The stereo core's control; None where the bitstream has no stereo core."""

    def take_depth(self, store: int) -> Optional[Callable[[], np.ndarray]]:
        """The stereo core's output for the processed frame in ``store``, taken now; None without one.

        Call it right after reading that processed store. Taking is cheap (the board copies the
        core's frame store; the emulated core notes the frame); the call it returns gives the
        ``(H, W)`` uint32 output beats, owned by the caller and read-only, and blocks while the
        emulated core computes them (once, on the first call).
        """

    # -- health ---------------------------------------------------------------------------
    def channel_status(self, channel: Channel) -> ChannelStatus:
        """One DMA channel's state (one register read); ``configured`` False for a channel this
        overlay has not started or does not have (``vdma_depth.s2mm`` without a stereo core, or
        where the emulated core hands its output over without a DMA channel)."""

    def restart_channel(self, channel: Channel, timeout: Optional[float] = None) -> None:
        """Get a halted channel running again as it was configured (:class:`RegisterTimeout` if it won't)."""

    # -- sensors, faults and the emulated rig ----------------------------------------------
    @property
    def sensors(self) -> Optional[SensorPair]:
        """The emulated image sensors once brought up (:func:`.backend.sensor_bus`); None on the board."""

    @property
    def fault_injection(self) -> Optional[FaultInjection]:
        """Faults made on request (the emulated fabric's); None where they cannot be made (the board)."""

    def rig_calibration(self) -> Optional[Calibration]:
        """The emulated camera rig's known calibration; None on the board and for replayed frames."""


class SensorPair(Protocol):
    """The board's two image sensors as the emulator models them, behind their I2C bus."""

    @property
    def bus(self) -> I2CBus: ...

    def sync_problem(self) -> Optional[str]:
        """None when the pair is set up to run in lockstep, else why not."""


class FaultError(ValueError):
    """A fault that cannot be injected (unknown kind or target, or one on that part already)."""


class InjectedFault(Protocol):
    """One fault in force: what it is, on which part, since when."""

    @property
    def id(self) -> int: ...
    @property
    def kind(self) -> str: ...
    @property
    def target(self) -> Optional[str]: ...

    def to_json(self) -> Dict[str, Any]: ...


class FaultInjection(Protocol):
    """Makes and ends the faults the daemon must survive (:class:`FaultError` for one it cannot make)."""

    @property
    def kinds(self) -> Mapping[str, Optional[Tuple[str, ...]]]:
        """Each kind and the targets it takes (None: it takes none)."""

    def active(self) -> Sequence[InjectedFault]: ...

    def inject(self, kind: str, target: Optional[str] = None) -> InjectedFault: ...

    def end(self, fault_id: int) -> InjectedFault:
        """End one fault; KeyError for one not in force."""

    def end_all(self) -> Sequence[InjectedFault]: ...


class Replay(Protocol):
    """Recorded stereo frames read back from a folder (:func:`.backend.open_replay`): virtual camera input."""

    @property
    def frame_size(self) -> Tuple[int, int]: ...
    @property
    def is_recording(self) -> bool:
        """True for a stereocam recording (``recording.json``): it has a rate and frame slots."""
    @property
    def slots(self) -> Sequence[int]: ...
    @property
    def duration_s(self) -> Optional[float]: ...

    fps: Optional[float]

    def __len__(self) -> int: ...

    def frame(self, k: int) -> np.ndarray:
        """Recorded frame ``k`` as ``(H, W, 8)``, whatever the time (blocks while it is decoded)."""

    def close(self) -> None: ...
