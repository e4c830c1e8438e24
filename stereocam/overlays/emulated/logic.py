"""The emulated programmable logic: the overlay's IP wired as the board's block design wires it.

```
 cameras ──┬──────────────────────────► vdma_raw  S2MM ──► DDR
           └─► mux SI0 ┐
 DDR ──► vdma_proc MM2S ─► mux SI1 ┴► mux ─► rectify ─┬► vdma_proc S2MM ──► DDR
                                                      └► stereo (optional) ──► its depth store
```

Each frame tick of the :class:`FrameClock` moves one frame along every path.
Software reaches the blocks only through their register windows (at the
addresses of :data:`..spec.overlay.ADDRESS_MAP`, as the board's device tree would place
them) and the DDR allocator, exactly as on the board.
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import Dict, Optional, Protocol, Tuple

import numpy as np

from ..spec.axis_switch import LIVE, VIRTUAL
from ..spec.overlay import NUM_FSTORES
from ..spec.rectify import DEFAULT_BUILD, Build
from .cameras import CameraSource
from .clock import FrameClock
from .ddr import EmulatedDDR
from .rectify import EmulatedRectifyCore
from .regblock import RegisterBlock
from .render import SyntheticRig
from .stereo import EmulatedStereoCore
from .switch import EmulatedAxisSwitch
from .vdma import EmulatedVDMA

log = logging.getLogger(__name__)

CLOSE_TIMEOUT_S = 30.0  # a full-size tick on a loaded machine can take seconds: close waits it out


CLOCK_THREAD = "emulated-fabric"  # the frame clock's thread: the emulated hardware's work happens on it

class FrameSensors(Protocol):
    """The emulated image sensors, told about every camera frame (:class:`.sensors.EmulatedSensorPair`).

    ``start_frame`` runs before the source renders frame ``index`` (the
    sensors latch their registers into the source: exposure, gain, flips,
    test pattern); ``end_frame`` gets the rendered frame (read-only) for the
    sensors' auto exposure. Both run on the frame clock's thread.
    """

    def start_frame(self, index: int) -> None: ...

    def end_frame(self, index: int, frame: np.ndarray) -> None: ...


class StreamCore(Protocol):
    """What stands in the rectify core's place: a register window plus whole frames in and out.

    :class:`.rectify.EmulatedRectifyCore` (the model) is the default;
    ``stereocam.overlays.rtl.core.RtlCore`` (the RTL under Verilator) is the other, so
    the same drivers and stream paths run in front of the core's HDL.
    ``process`` returns the output frame, or None when the core emits none.
    """

    def read(self, offset: int) -> int: ...

    def write(self, offset: int, value: int) -> None: ...

    def process(self, frame: np.ndarray) -> Optional[np.ndarray]: ...


@dataclass
class FabricCounters:
    """What happened on the stream paths, for tests and status pages."""

    ticks: int = 0
    camera_frames: int = 0
    raw_frames: int = 0
    mux_frames: int = 0  # frames that reached the core
    core_frames: int = 0  # frames the core emitted
    proc_frames: int = 0  # frames written by vdma_proc S2MM
    camera_errors: int = 0
    last_error: str = ""
    per_input: Dict[int, int] = field(default_factory=lambda: {LIVE: 0, VIRTUAL: 0})


class EmulatedFabric:
    """All emulated IP plus the camera source and the frame clock.

    ``clock="stepped"`` makes :meth:`step` the only way frames move (tests,
    benchmarks); ``"realtime"`` runs a thread at ``fps`` once :meth:`start`
    is called. ``source`` defaults to a :class:`SyntheticRig`; the fabric
    closes it on :meth:`close`. ``core`` replaces the model of the rectify
    core (e.g. with the RTL, ``stereocam.overlays.rtl.core.RtlCore``, built for ``build``);
    the fabric closes it too. ``sensors`` (optional, settable later) are
    ticked around every camera frame (:class:`FrameSensors`). ``stereo`` False builds the
    fabric without a stereo core (a bitstream without one: the daemon falls back to the ARM).
    """

    def __init__(
        self, *, source: Optional[CameraSource] = None, fps: float = 60.0, clock: str = "realtime",
        num_fstores: int = NUM_FSTORES, build: Build = DEFAULT_BUILD, lb_rows: Optional[int] = None,
        ddr_size: int = 256 << 20, sensors: Optional[FrameSensors] = None, core: Optional[StreamCore] = None,
        stereo: bool = True,
    ) -> None:
        self.ddr = EmulatedDDR(size=ddr_size)
        self.vdma_raw = EmulatedVDMA(self.ddr, num_fstores, "vdma_raw")
        self.vdma_proc = EmulatedVDMA(self.ddr, num_fstores, "vdma_proc")
        self.mux = EmulatedAxisSwitch(name="mux")
        self.core: StreamCore = core if core is not None else EmulatedRectifyCore(
            max_width=build.max_width, max_height=build.max_height,
            lb_rows=build.lb_rows if lb_rows is None else lb_rows, colour=build.colour)
        self.stereo: Optional[EmulatedStereoCore] = EmulatedStereoCore() if stereo else None
        self.num_fstores = num_fstores
        self.source: CameraSource = source if source is not None else SyntheticRig()
        self.sensors: Optional[FrameSensors] = sensors
        self.cameras_running = True  # tests: False models cameras that stopped sending
        self.counters = FabricCounters()
        self._tick_lock = threading.Lock()
        self.clock = FrameClock(fps, self.tick, mode=clock, name=CLOCK_THREAD)

    @property
    def blocks(self) -> Dict[str, "RegisterBlock | StreamCore"]:
        """The instances every bitstream has (``spec/overlay.py`` INSTANCES, at ADDRESS_MAP)."""
        return {"vdma_raw": self.vdma_raw, "vdma_proc": self.vdma_proc, "rectify": self.core, "mux": self.mux}

    @property
    def optional_blocks(self) -> Dict[str, RegisterBlock]:
        """The optional instances this fabric has (OPTIONAL_INSTANCES, at OPTIONAL_ADDRESS_MAP)."""
        return {} if self.stereo is None else {"stereo": self.stereo}

    @property
    def frame_size(self) -> Tuple[int, int]:
        return self.source.frame_size

    def tick(self, index: int, t: float) -> None:
        """One frame period on every stream path."""
        with self._tick_lock:
            c = self.counters
            c.ticks += 1
            live: Optional[np.ndarray] = None
            if self.cameras_running:
                try:
                    sensors = self.sensors
                    if sensors is not None:
                        sensors.start_frame(index)
                    live = self.source.read(index, t)
                    if sensors is not None:
                        sensors.end_frame(index, live)
                    c.camera_frames += 1
                except Exception as exc:  # a replay folder that vanished, a decode error...
                    c.camera_errors += 1
                    c.last_error = f"camera source: {exc}"
                    log.warning("camera source failed at frame %d: %s", index, exc)
            if live is not None and self.vdma_raw.s2mm_accept(live):
                c.raw_frames += 1
            selected = self.mux.selected
            virtual = self.vdma_proc.mm2s_fetch()  # MM2S runs whether or not the mux listens
            frame = live if selected == LIVE else virtual if selected == VIRTUAL else None
            if frame is None or selected is None:
                return
            c.mux_frames += 1
            c.per_input[selected] = c.per_input.get(selected, 0) + 1
            out = self.core.process(frame)
            if out is None:
                return
            c.core_frames += 1
            if self.vdma_proc.s2mm_accept(out):
                c.proc_frames += 1
                store = self.vdma_proc.s2mm.inflight
                if self.stereo is not None and store is not None:
                    self.stereo.accept(out, store)

    def step(self, n: int = 1) -> None:
        self.clock.step(n)

    def start(self) -> None:
        self.clock.start()

    def stop(self) -> None:
        self.clock.stop()

    def close(self) -> None:
        self.clock.stop(timeout=CLOSE_TIMEOUT_S)
        self.source.close()
        close_core = getattr(self.core, "close", None)
        if close_core is not None:
            close_core()
