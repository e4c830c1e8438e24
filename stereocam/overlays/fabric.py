"""The fabric as software sees it: the overlay's drivers and the closed-loop operations.

:class:`StereoFabric` holds one driver per IP instance and does what the
paper's six flows need (capture raw frames, push a virtual-camera frame,
read rectified frames, switch the mux back to live) using drivers only, so
the same code runs on the board and on the emulated fabric. It is built by
:func:`bind` from an ``ip_dict`` (pynq's format) plus a way to open register
windows and an allocator, or by :func:`from_drivers` from drivers that pynq
has already bound to the overlay's IP. :class:`FabricOverlay` gives an
overlay holding one the members of :class:`~.interface.Overlay` that the
fabric answers.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable, Dict, Mapping, Optional, Protocol, Tuple, Union

import numpy as np

from ..drivers.mmio import Allocator, RegisterWindow, UnsupportedIP
from ..drivers.rectify import RectifyCore
from ..drivers.stereo import StereoCore
from ..drivers.switch import AxisSwitch
from ..drivers.vdma import VDMA, MM2SChannel, S2MMChannel
from .interface import COMMIT_TIMEOUT_S, DEPTH_CHANNEL, Channel, ChannelStatus, Choice, StoredFrame
from .model.result import CoreOptions
from .spec.axis_switch import INPUT_NAMES, LIVE, VIRTUAL
from .spec.overlay import DEPTH_PIXELS_PER_BEAT, DEPTH_VDMA, INSTANCES, OPTIONAL_INSTANCES, STEREO
from .spec.rectify import CoreConfig

log = logging.getLogger(__name__)

SOURCES = {"live": LIVE, "virtual": VIRTUAL}


DepthTake = Callable[[], np.ndarray]


class DepthStores(Protocol):
    """Where the stereo core's output lands: ``take(store)``, :meth:`.interface.Overlay.take_depth`."""

    def start(self, width: int, height: int) -> None: ...

    def stop(self) -> None: ...

    def take(self, store: int) -> Optional[DepthTake]: ...

    def close(self) -> None: ...


class VdmaDepthStores:
    """The stereo core's output through ``vdma_depth``'s S2MM (``spec/overlay.py``: two beats per pixel)."""

    def __init__(self, vdma: VDMA) -> None:
        self.vdma = vdma

    def start(self, width: int, height: int) -> None:
        if width % DEPTH_PIXELS_PER_BEAT:
            raise UnsupportedIP(f"{DEPTH_VDMA}: a frame {width} pixels wide does not fill whole stream beats "
                                f"({DEPTH_PIXELS_PER_BEAT} output beats each); use an even width")
        self.vdma.s2mm.start(width // DEPTH_PIXELS_PER_BEAT, height)

    def stop(self) -> None:
        if self.vdma.s2mm.config is not None:
            self.vdma.s2mm.stop()

    def take(self, store: int) -> Optional[DepthTake]:
        """A copy of ``store`` now (the channel overwrites it frames later), as ``(H, W)`` uint32 beats."""
        buffers = self.vdma.s2mm.buffers
        if not buffers:
            return None
        buf = np.asarray(buffers[store % len(buffers)])
        beats = buf.view(np.uint32).reshape(buf.shape[0], -1).copy()
        beats.flags.writeable = False
        return lambda: beats

    def close(self) -> None:
        self.vdma.close()


class StereoFabric:
    """Drivers of one loaded overlay; start/stop are idempotent and guarded by a lock.

    Frames handed out by :meth:`latest_raw`/:meth:`latest_processed` are
    copies owned by the caller (the DMA keeps writing its stores).
    """

    def __init__(self, *, raw_vdma: VDMA, proc_vdma: VDMA, mux: AxisSwitch, rectify: RectifyCore,
                 allocate: Allocator, backend: str, frame_size: Tuple[int, int],
                 stereo: Optional[StereoCore] = None, depth: Optional[DepthStores] = None) -> None:
        """``stereo`` and ``depth``: the optional stereo core and where its output lands (both or neither)."""
        if (stereo is None) != (depth is None):
            raise UnsupportedIP("a stereo core needs its output channel and the channel its core "
                                f"({STEREO!r} and {DEPTH_VDMA!r}): the overlay has only one of them")
        self.stereo = stereo
        self.depth = depth
        self.raw_vdma = raw_vdma
        self.proc_vdma = proc_vdma
        self.mux = mux
        self.rectify = rectify
        self.allocate = allocate
        self.backend = backend
        self.frame_size = (int(frame_size[0]), int(frame_size[1]))
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
            if self.stereo is not None and self.depth is not None:
                self.depth.start(w, h)
                try:
                    self.stereo.program(self.stereo.params(), size=(w, h), wait=False)
                except ValueError as exc:  # a replayed frame wider than the core: it flags SIZE_ERROR
                    log.warning("the stereo core cannot take %dx%d frames: %s", w, h, exc)
                self.stereo.enable()
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
                if self.stereo is not None and self.depth is not None:
                    self.stereo.disable()
                    self.depth.stop()
            finally:
                for ch in (self.raw_vdma.s2mm, self.proc_vdma.s2mm, self.proc_vdma.mm2s):
                    if ch.config is not None:
                        ch.stop()

    def close(self) -> None:
        with self.lock:
            self.stop_streams()
            self.raw_vdma.close()
            self.proc_vdma.close()
            if self.depth is not None:
                self.depth.close()

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

    def wait_processed(self, timeout: float) -> None:
        """Block until the processed channel completes a frame (:meth:`.interface.Overlay.wait_processed`)."""
        self.proc_vdma.s2mm.wait_frame(timeout=timeout)

    def processed_store(self) -> StoredFrame:
        s2mm = self.proc_vdma.s2mm
        store, buf = s2mm.latest_completed()
        return StoredFrame(store, s2mm.num_fstores, buf)

    def raw_store(self, store: Optional[int] = None) -> StoredFrame:
        s2mm = self.raw_vdma.s2mm
        if store is None:
            store, buf = s2mm.latest_completed()
        else:
            store %= s2mm.num_fstores
            buf = s2mm.buffers[store]
        return StoredFrame(store, s2mm.num_fstores, buf)

    @property
    def raw_stores(self) -> int:
        return int(self.raw_vdma.s2mm.num_fstores)

    def frame_count(self) -> int:
        """The core's ``FRAME_COUNT`` (one register read)."""
        return int(self.rectify.regs.read("FRAME_COUNT"))

    def wait_virtual_taken(self, timeout: float) -> int:
        return int(self.proc_vdma.mm2s.wait_parked(timeout=timeout))

    # -- the core -----------------------------------------------------------------------
    def core_setup(self) -> Tuple[CoreConfig, CoreOptions]:
        """``(CoreConfig, CoreOptions)`` the core runs with, read back from its registers (blocks)."""
        rectify = self.rectify
        config = rectify.read_config()
        options = rectify.read_control().options(lb_rows=rectify.lb_rows, lb_delay=config.lb_delay,
                                                 colour=rectify.colour)
        return config, options

    def take_depth(self, store: int) -> Optional[DepthTake]:
        """The stereo core's output for processed store ``store`` (:meth:`.interface.Overlay.take_depth`)."""
        return None if self.depth is None else self.depth.take(store % self.proc_vdma.s2mm.num_fstores)

    def stereo_status(self) -> Optional[Dict[str, Any]]:
        """The stereo core for ``/api/status``: build, parameters, progress; None without one."""
        if self.stereo is None:
            return None
        build = self.stereo.build
        return {"build": {"max_width": build.max_width, "max_height": build.max_height,
                          "max_disp": build.max_disp, "parallel": build.parallel},
                "params": self.stereo.params().as_json(), **self.stereo.status().as_json()}

    # -- health -------------------------------------------------------------------------
    def channel(self, name: Channel) -> Optional[Union[S2MMChannel, MM2SChannel]]:
        """The driver of one DMA channel, by its :data:`~.interface.Channel` name; None for the depth
        channel where the overlay has none (no stereo core, or an emulated core's own stores)."""
        if name == "vdma_raw.s2mm":
            return self.raw_vdma.s2mm
        if name == "vdma_proc.s2mm":
            return self.proc_vdma.s2mm
        if name == "vdma_proc.mm2s":
            return self.proc_vdma.mm2s
        if name == DEPTH_CHANNEL:
            return self.depth.vdma.s2mm if isinstance(self.depth, VdmaDepthStores) else None
        raise ValueError(f"no DMA channel {name!r}")

    def channel_status(self, name: Channel) -> ChannelStatus:
        ch = self.channel(name)
        if ch is None or ch.config is None:
            return ChannelStatus(configured=False, running=False, errors=())
        return ChannelStatus(configured=True, running=bool(ch.running), errors=tuple(ch.errors()))

    def restart_channel(self, name: Channel, timeout: Optional[float] = None) -> None:
        ch = self.channel(name)
        if ch is None:
            raise ValueError(f"this overlay has no DMA channel {name!r}")
        ch.recover(timeout)

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
            "stereo": self.stereo_status(),
            "vdma": {
                "raw_s2mm": list(self.raw_vdma.s2mm.errors()),
                "proc_s2mm": list(self.proc_vdma.s2mm.errors()),
                "proc_mm2s": list(self.proc_vdma.mm2s.errors()),
                **({"depth_s2mm": list(depth.errors())} if (depth := self.channel(DEPTH_CHANNEL)) else {}),
            },
        }


def bind(ip_dict: Mapping[str, Mapping[str, Any]], open_window: Callable[[int, int], RegisterWindow],
         allocate: Allocator, *, backend: str, frame_size: Tuple[int, int],
         timeout: float = 1.0, depth: Optional[DepthStores] = None) -> StereoFabric:
    """Drivers for the overlay described by ``ip_dict``.

    ``ip_dict`` is pynq's format: name -> phys_addr, addr_range, type, parameters.
    Refuses an overlay that lacks an instance or has the wrong IP under a name. The stereo
    core is bound where ``ip_dict`` has one; its output is read from ``vdma_depth``, or from
    ``depth`` where given (the emulated fabric's core hands its stores over directly).
    """
    require_instances(ip_dict)
    optional = optional_instances(ip_dict)
    stereo = None
    if STEREO in optional:
        desc = ip_dict[STEREO]
        stereo = StereoCore(open_window(int(desc["phys_addr"]), int(desc["addr_range"])), timeout=timeout)
        if depth is None and DEPTH_VDMA in optional:
            desc = ip_dict[DEPTH_VDMA]
            depth = VdmaDepthStores(VDMA(open_window(int(desc["phys_addr"]), int(desc["addr_range"])),
                                         allocate, num_fstores=int(desc.get("parameters", {}).get(
                                             "C_NUM_FSTORES", 3)), name=DEPTH_VDMA, timeout=timeout))
    windows = {name: open_window(int(ip_dict[name]["phys_addr"]), int(ip_dict[name]["addr_range"]))
               for name in INSTANCES}

    def fstores(name: str) -> int:
        return int(ip_dict[name].get("parameters", {}).get("C_NUM_FSTORES", 3))

    def inputs() -> int:
        return int(ip_dict["mux"].get("parameters", {}).get("NUM_SI", 2))

    return StereoFabric(
        raw_vdma=VDMA(windows["vdma_raw"], allocate, num_fstores=fstores("vdma_raw"), name="vdma_raw",
                      timeout=timeout),
        proc_vdma=VDMA(windows["vdma_proc"], allocate, num_fstores=fstores("vdma_proc"), name="vdma_proc",
                       timeout=timeout),
        mux=AxisSwitch(windows["mux"], inputs=inputs(), name="mux", timeout=timeout),
        rectify=RectifyCore(windows["rectify"], timeout=timeout),
        allocate=allocate,
        backend=backend,
        frame_size=frame_size,
        stereo=stereo,
        depth=depth if stereo is not None else None,
    )


# The driver class each instance of INSTANCES needs, for overlays whose drivers are bound elsewhere (pynq).
DRIVER_TYPES: Dict[str, type] = {"vdma_raw": VDMA, "vdma_proc": VDMA, "mux": AxisSwitch,
                                 "rectify": RectifyCore}


def require_instances(ip_dict: Mapping[str, Mapping[str, Any]]) -> None:
    """Refuse an overlay that lacks an instance or has the wrong IP under a name (checked by :func:`bind`)."""
    for name, vlnvs in INSTANCES.items():
        desc = ip_dict.get(name)
        if desc is None:
            found = ", ".join(sorted(ip_dict)) or "none"
            raise UnsupportedIP(f"the overlay has no IP named {name!r}; found {found}")
        if desc.get("type") not in vlnvs:
            raise UnsupportedIP(f"IP {name!r} is {desc.get('type')!r}, expected {' or '.join(vlnvs)}")


def optional_instances(ip_dict: Mapping[str, Mapping[str, Any]]) -> Tuple[str, ...]:
    """The optional instances (:data:`OPTIONAL_INSTANCES`) the overlay has; refuses the wrong IP under one."""
    found = []
    for name, vlnvs in OPTIONAL_INSTANCES.items():
        desc = ip_dict.get(name)
        if desc is None:
            continue
        if desc.get("type") not in vlnvs:
            raise UnsupportedIP(f"IP {name!r} is {desc.get('type')!r}, expected {' or '.join(vlnvs)}")
        found.append(name)
    return tuple(found)


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
    stereo, depth_vdma = drivers.get(STEREO), drivers.get(DEPTH_VDMA)
    return StereoFabric(raw_vdma=drivers["vdma_raw"], proc_vdma=drivers["vdma_proc"], mux=drivers["mux"],
                        rectify=drivers["rectify"], allocate=allocate, backend=backend, frame_size=frame_size,
                        stereo=stereo, depth=None if depth_vdma is None else VdmaDepthStores(depth_vdma))


class FabricOverlay:
    """The members of :class:`~.interface.Overlay` that an overlay's :attr:`fabric` answers.

    A base for the overlays: each sets :attr:`fabric` and adds ``backend``,
    ``rectify`` and its own ``start``/``stop``/``close``.
    """

    fabric: StereoFabric
    choice: Optional[Choice] = None
    core_kind: str = "hardware"
    emulation_threads: Tuple[str, ...] = ()

    @property
    def frame_size(self) -> Tuple[int, int]:
        return self.fabric.frame_size

    @property
    def raw_stores(self) -> int:
        return self.fabric.raw_stores

    @property
    def streaming(self) -> bool:
        return self.fabric.streaming

    @property
    def source(self) -> str:
        return self.fabric.source

    def select(self, source: str, timeout: float = COMMIT_TIMEOUT_S) -> None:
        self.fabric.select(source, timeout)

    def wait_processed(self, timeout: float) -> None:
        self.fabric.wait_processed(timeout)

    def processed_store(self) -> StoredFrame:
        return self.fabric.processed_store()

    def raw_store(self, store: Optional[int] = None) -> StoredFrame:
        return self.fabric.raw_store(store)

    def latest_raw(self) -> Tuple[int, np.ndarray]:
        return self.fabric.latest_raw()

    def latest_processed(self) -> Tuple[int, np.ndarray]:
        return self.fabric.latest_processed()

    def frame_count(self) -> int:
        return self.fabric.frame_count()

    def send_virtual(self, frame: np.ndarray) -> int:
        return self.fabric.send_virtual(frame)

    def wait_virtual_taken(self, timeout: float) -> int:
        return self.fabric.wait_virtual_taken(timeout)

    def core_setup(self) -> Tuple[CoreConfig, CoreOptions]:
        return self.fabric.core_setup()

    def status(self) -> Dict[str, Any]:
        return self.fabric.status()

    @property
    def stereo(self) -> Optional[StereoCore]:
        return self.fabric.stereo

    def take_depth(self, store: int) -> Optional[DepthTake]:
        return self.fabric.take_depth(store)

    def channel_status(self, channel: Channel) -> ChannelStatus:
        return self.fabric.channel_status(channel)

    def restart_channel(self, channel: Channel, timeout: Optional[float] = None) -> None:
        self.fabric.restart_channel(channel, timeout)
