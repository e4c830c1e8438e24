"""The fabric as software sees it: the overlay's drivers and the closed-loop operations.

:class:`StereoFabric` holds one driver per IP instance and does what the
paper's six flows need (capture raw frames, push a virtual-camera frame,
read rectified frames, switch the mux back to live) using drivers only, so
the same code runs on the board and on the emulated fabric. It is built by
:func:`bind` from an ``ip_dict`` (pynq's format) plus a way to open register
windows and an allocator, or by :func:`from_drivers` from drivers that pynq
has already bound to the overlay's IP.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable, Dict, Mapping, Tuple

import numpy as np

from ..drivers.mmio import Allocator, RegisterWindow, UnsupportedIP
from ..drivers.rectify import RectifyCore
from ..drivers.switch import AxisSwitch
from ..drivers.vdma import VDMA
from .spec.axis_switch import INPUT_NAMES, LIVE, VIRTUAL
from .spec.overlay import INSTANCES

log = logging.getLogger(__name__)

SOURCES = {"live": LIVE, "virtual": VIRTUAL}
COMMIT_TIMEOUT_S = 0.5  # a mux commit waits for the end of a packet (a line): microseconds when healthy


class StereoFabric:
    """Drivers of one loaded overlay; start/stop are idempotent and guarded by a lock.

    Frames handed out by :meth:`latest_raw`/:meth:`latest_processed` are
    copies owned by the caller (the DMA keeps writing its stores).
    """

    def __init__(self, *, raw_vdma: VDMA, proc_vdma: VDMA, mux: AxisSwitch, rectify: RectifyCore,
                 allocate: Allocator, backend: str, frame_size: Tuple[int, int]) -> None:
        self.raw_vdma = raw_vdma
        self.proc_vdma = proc_vdma
        self.mux = mux
        self.rectify = rectify
        self.allocate = allocate
        self.backend = backend
        self.frame_size = frame_size
        self.lock = threading.RLock()
        self.streaming = False

    # -- lifecycle ----------------------------------------------------------------------
    def start_streams(self) -> None:
        """Start all DMA channels, route the live cameras to the core and enable it."""
        with self.lock:
            if self.streaming:
                return
            w, h = self.frame_size
            self.raw_vdma.s2mm.start(w, h)
            self.proc_vdma.s2mm.start(w, h)
            self.proc_vdma.mm2s.start(w, h, circular=False)
            self.mux.select(LIVE)
            self.rectify.enable()
            self.streaming = True

    def stop_streams(self) -> None:
        """Flow 6 and shutdown: mux back to live, core off, every channel stopped."""
        with self.lock:
            if not self.streaming:
                return
            self.streaming = False
            try:
                self.mux.select(LIVE)
                self.rectify.disable()
            finally:
                for ch in (self.raw_vdma.s2mm, self.proc_vdma.s2mm, self.proc_vdma.mm2s):
                    if ch.config is not None:
                        ch.stop()

    def close(self) -> None:
        with self.lock:
            self.stop_streams()
            self.raw_vdma.close()
            self.proc_vdma.close()

    # -- the mux ------------------------------------------------------------------------
    @property
    def source(self) -> str:
        sel = self.mux.selected()
        return "off" if sel is None else INPUT_NAMES.get(sel, str(sel))

    def select(self, source: str, timeout: float = COMMIT_TIMEOUT_S) -> None:
        """Route ``source`` to the core; :class:`RegisterTimeout` when the mux does not commit in time."""
        if source not in SOURCES:
            raise ValueError(f"source must be 'live' or 'virtual', not {source!r}")
        self.mux.select(SOURCES[source], timeout=timeout)

    # -- frames -------------------------------------------------------------------------
    def send_virtual(self, frame: np.ndarray) -> int:
        """Put a ``(H, W, 8)`` frame on the virtual camera (MM2S); returns the frame store used."""
        return self.proc_vdma.mm2s.write_frame(frame)

    def latest_raw(self) -> Tuple[int, np.ndarray]:
        store, buf = self.raw_vdma.s2mm.latest_completed()
        return store, np.array(buf)

    def latest_processed(self) -> Tuple[int, np.ndarray]:
        store, buf = self.proc_vdma.s2mm.latest_completed()
        return store, np.array(buf)

    def status(self) -> Dict[str, Any]:
        core = self.rectify.status()
        return {
            "backend": self.backend,
            "source": self.source,
            "streaming": self.streaming,
            "frame_size": list(self.frame_size),
            "core": {"frame_count": core.frame_count, "flags": core.flags, "control": core.control,
                     "lb_rows": self.rectify.lb_rows, "max_width": self.rectify.max_width,
                     "colour": self.rectify.colour},
            "vdma": {
                "raw_s2mm": list(self.raw_vdma.s2mm.errors()),
                "proc_s2mm": list(self.proc_vdma.s2mm.errors()),
                "proc_mm2s": list(self.proc_vdma.mm2s.errors()),
            },
        }


def bind(ip_dict: Mapping[str, Mapping[str, Any]], open_window: Callable[[int, int], RegisterWindow],
         allocate: Allocator, *, backend: str, frame_size: Tuple[int, int], timeout: float = 1.0) -> StereoFabric:
    """Drivers for the overlay described by ``ip_dict`` (pynq's format: name -> phys_addr, addr_range, type, parameters).

    Refuses an overlay that lacks an instance or has the wrong IP under a name.
    """
    windows: Dict[str, RegisterWindow] = {}
    for name, vlnvs in INSTANCES.items():
        desc = ip_dict.get(name)
        if desc is None:
            raise UnsupportedIP(f"the overlay has no IP named {name!r}; found {', '.join(sorted(ip_dict)) or 'none'}")
        if desc.get("type") not in vlnvs:
            raise UnsupportedIP(f"IP {name!r} is {desc.get('type')!r}, expected {' or '.join(vlnvs)}")
        windows[name] = open_window(int(desc["phys_addr"]), int(desc["addr_range"]))

    def fstores(name: str) -> int:
        return int(ip_dict[name].get("parameters", {}).get("C_NUM_FSTORES", 3))

    def inputs() -> int:
        return int(ip_dict["mux"].get("parameters", {}).get("NUM_SI", 2))

    return StereoFabric(
        raw_vdma=VDMA(windows["vdma_raw"], allocate, num_fstores=fstores("vdma_raw"), name="vdma_raw", timeout=timeout),
        proc_vdma=VDMA(windows["vdma_proc"], allocate, num_fstores=fstores("vdma_proc"), name="vdma_proc", timeout=timeout),
        mux=AxisSwitch(windows["mux"], inputs=inputs(), name="mux", timeout=timeout),
        rectify=RectifyCore(windows["rectify"], timeout=timeout),
        allocate=allocate,
        backend=backend,
        frame_size=frame_size,
    )


# The driver class each instance of INSTANCES needs, for overlays whose drivers are bound elsewhere (pynq).
DRIVER_TYPES: Dict[str, type] = {"vdma_raw": VDMA, "vdma_proc": VDMA, "mux": AxisSwitch, "rectify": RectifyCore}


def require_instances(ip_dict: Mapping[str, Mapping[str, Any]]) -> None:
    """Refuse an overlay that lacks an instance or has the wrong IP under a name (the checks of :func:`bind`)."""
    for name, vlnvs in INSTANCES.items():
        desc = ip_dict.get(name)
        if desc is None:
            raise UnsupportedIP(f"the overlay has no IP named {name!r}; found {', '.join(sorted(ip_dict)) or 'none'}")
        if desc.get("type") not in vlnvs:
            raise UnsupportedIP(f"IP {name!r} is {desc.get('type')!r}, expected {' or '.join(vlnvs)}")


def from_drivers(drivers: Mapping[str, Any], allocate: Allocator, *, backend: str,
                 frame_size: Tuple[int, int]) -> StereoFabric:
    """A :class:`StereoFabric` over drivers already bound, by instance name (e.g. by pynq's overlay).

    The fabric uses these very objects (it does not open windows of its own).
    Refuses a missing instance or a driver of the wrong class.
    """
    for name, cls in DRIVER_TYPES.items():
        driver = drivers.get(name)
        if driver is None:
            raise UnsupportedIP(f"no driver bound to {name!r}; bound: {', '.join(sorted(drivers)) or 'none'}")
        if not isinstance(driver, cls):
            raise UnsupportedIP(f"{name!r} is bound to {type(driver).__name__}, not a {cls.__name__} driver")
    return StereoFabric(raw_vdma=drivers["vdma_raw"], proc_vdma=drivers["vdma_proc"], mux=drivers["mux"],
                        rectify=drivers["rectify"], allocate=allocate, backend=backend, frame_size=frame_size)
