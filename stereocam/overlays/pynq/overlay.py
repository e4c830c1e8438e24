"""The board overlay: a ``pynq.Overlay`` that loads our bitstream, binds our drivers and owns the fabric.

Imported only where pynq is installed (on the board, and in the board-like
test environment); :mod:`..backend` decides.

* Binding: the IP named in :data:`~..spec.overlay.INSTANCES` get the drivers
  of :mod:`.drivers` (``ov.rectify`` is a ``RectifyCore``, ``ov.vdma_raw``
  a ``VDMA``...), whatever else pynq has registered for their VLNVs, and
  :attr:`StereocamOverlay.fabric` is built from those same objects.
* Loading: the fabric is programmed only when pynq's PL state (the file in
  which every pynq process records the bitstream it loads, with its hash)
  does not already record this bitstream, so restarting the daemon does not
  glitch the cameras. pynq's own ``Overlay.is_loaded()`` cannot tell: it is
  true for any overlay constructed with ``download=False``.
* One owner: a :class:`FabricLock` (an ``flock`` on ``/run/stereocam/fabric.lock``)
  is taken before anything else; a second daemon or notebook opening a
  ``StereocamOverlay`` gets :class:`FabricBusy` naming the owner. pynq has
  no lock of its own: a plain ``pynq.Overlay("other.bit")`` still downloads.
* Losing the fabric: a :class:`PLGuard` is asked before every register
  access. When pynq's PL state stops recording our bitstream (another
  process downloaded a design, which pynq records *before* programming),
  or the rectify core's ID register stops reading as ours, it raises
  :class:`~.drivers.FabricLost` from then on and logs why, once:
  the daemon's status shows the error and nothing touches the bus (on a
  Zynq, reading IP that is not there hangs the AXI bus).
"""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional, Tuple

from ..fabric import FabricOverlay, StereoFabric, bind, from_drivers, optional_instances, require_instances
from ..interface import BackendError, FaultInjection, SensorPair
from ..spec.overlay import INSTANCES
from ..spec.rectify import CORE_ID, CORE_VERSION, RECTIFY_MAP
from . import import_pynq
from .drivers import DRIVERS, FabricLost, PynqAxisSwitch, PynqRectifyCore, PynqVDMA, pynq_allocator
from .lock import FabricBusy, FabricLock

if TYPE_CHECKING:  # pragma: no cover
    from ...calibration.file import Calibration

log = logging.getLogger(__name__)
pynq = import_pynq()

FPGA_MANAGER = Path("/sys/class/fpga_manager/fpga0")
RACY_S = 0.1  # a file stamp this close to the file's mtime may not change on the next write (coarse mtime)


def bind_pynq(ip_dict: Any, device: Any, *, frame_size: Tuple[int, int],
              timeout: float = 1.0) -> StereoFabric:
    """Our drivers on pynq's register windows (``pynq.MMIO``) and memory (``pynq.allocate``), no overlay."""
    return bind(
        ip_dict,
        lambda address, length: pynq.MMIO(address, length, device=device),
        pynq_allocator(device),
        backend="pynq", frame_size=frame_size, timeout=timeout,
    )


# -- one owner ----------------------------------------------------------------------------------

# -- what the PL holds --------------------------------------------------------------------------

@dataclass(frozen=True)
class LoadedBitstream:
    """One record of pynq's PL state: which bitstream was downloaded, its SHA-1, when."""

    bitfile_name: str
    bitfile_hash: str
    timestamp: str


class PynqPLState:
    """pynq's record of what the PL holds, read without touching the bus.

    Every pynq 3/4 process that downloads a full bitstream writes its name,
    hash and timestamp to ``state_file`` (``pynq/pl_server/global_pl_state_.json``)
    *before* programming. The FPGA manager (``fpga_manager``, a sysfs folder;
    None: not consulted) tells a programmed PL from a cold one, where the
    file may be left over from the previous boot (pynq's own rule: state
    ``unknown`` or flags ``100``).
    """

    def __init__(self, state_file: Optional[Path] = None, *,
                 fpga_manager: Optional[Path] = FPGA_MANAGER) -> None:
        if state_file is None:
            from pynq.pl_server import global_state

            state_file = Path(global_state.STATE_DIR) / "global_pl_state_.json"
        self.state_file = Path(state_file)
        self.fpga_manager = fpga_manager

    def stamp(self) -> Optional[Tuple[int, int, int]]:
        """A cheap change detector for the state file: (inode, size, mtime in ns); None when it is missing."""
        try:
            st = os.stat(self.state_file)
        except FileNotFoundError:
            return None
        return st.st_ino, st.st_size, st.st_mtime_ns

    def cold(self) -> bool:
        """True when the FPGA manager says the PL is not (or no longer) programmed."""
        if self.fpga_manager is None or not (self.fpga_manager / "state").exists():
            return False
        try:
            state = (self.fpga_manager / "state").read_text().strip()
            flags = (self.fpga_manager / "flags").read_text().strip()
        except OSError:
            return False  # unreadable: rely on pynq's record
        return state != "operating" or flags.startswith("100")

    def loaded(self) -> Optional[LoadedBitstream]:
        """What pynq records as loaded, or None (no record, or a cold PL)."""
        if self.cold():
            return None
        try:
            record = json.loads(self.state_file.read_text())
        except (FileNotFoundError, ValueError):
            return None
        return LoadedBitstream(str(record.get("bitfile_name", "")), str(record.get("bitfile_hash", "")),
                               str(record.get("timestamp", "")))

    def holds(self, bitfile_name: str, bitfile_hash: str) -> bool:
        """True when pynq records this bitstream (by hash; by path if pynq recorded no hash) as loaded."""
        rec = self.loaded()
        if rec is None:
            return False
        return rec.bitfile_hash == bitfile_hash if rec.bitfile_hash else rec.bitfile_name == bitfile_name


class PLGuard:
    """Decides, before each register access, whether the fabric may still be touched.

    :meth:`check` costs one ``stat`` of pynq's state file while nothing
    changes; when the file changes it is read again, and any record other
    than ``ours`` (what pynq recorded once our overlay was loaded; None if
    it recorded nothing) trips the guard. ``probe`` (set once the drivers exist)
    reads the rectify core's identity at most every ``probe_interval``
    seconds and returns why it is not ours, or None. Once tripped (or
    :meth:`close`\\ d) every check raises :class:`FabricLost` with the reason,
    logged once. Thread-safe.
    """

    def __init__(self, state: PynqPLState, ours: Optional[LoadedBitstream], *, probe_interval: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.state = state
        self.ours = ours
        self.probe: Optional[Callable[[], Optional[str]]] = None
        self.probe_interval = probe_interval
        self.clock = clock
        self.lost: Optional[str] = None
        self._lock = threading.RLock()
        self._stamp: Optional[Tuple[int, int, int]] = None
        self._next_probe = clock() + probe_interval

    def check(self) -> None:
        if self.lost is None and (self._stamp is None or self.state.stamp() != self._stamp):
            self._reread()
        if self.lost is None and self.probe is not None and self.clock() >= self._next_probe:
            with self._lock:
                if self.lost is None and self.clock() >= self._next_probe:
                    self._next_probe = self.clock() + self.probe_interval
                    why = self.probe()
                    if why is not None:
                        self.trip(f"{why}: the PL no longer holds the stereocam overlay")
        if self.lost is not None:
            raise FabricLost(self.lost)

    def _reread(self) -> None:
        with self._lock:
            stamp = self.state.stamp()
            now = self.state.loaded()
            if now != self.ours:
                what = "no bitstream (its record is gone or the PL is not programmed)" if now is None else \
                    f"{now.bitfile_name} since {now.timestamp}"
                was = "nothing" if self.ours is None else \
                    f"{self.ours.bitfile_name} loaded at {self.ours.timestamp}"
                self.trip(f"the fabric was re-programmed underneath stereocam: pynq records {what}, "
                          f"not {was}; stereocam stops touching the fabric (on a Zynq, reading IP that "
                          "is not there hangs the bus): restart stereocam (`systemctl restart stereocam`) "
                          "to load its overlay again")
            # Racily clean: a write within the mtime's granularity of this stat may leave the stamp unchanged.
            fresh = stamp is not None and time.time() - stamp[2] / 1e9 > RACY_S
            self._stamp = stamp if fresh else None

    def trip(self, reason: str) -> None:
        """Stop all further register access with ``reason`` (logged once); the first reason stays."""
        with self._lock:
            if self.lost is None:
                self.lost = reason
                log.error("%s", reason)

    def close(self) -> None:
        """No register access from now on (the overlay was closed); not logged as an error."""
        if self.lost is None:
            self.lost = "the stereocam overlay was closed: open a new one to use the fabric"


# -- the overlay --------------------------------------------------------------------------------

# pynq is a module object, typed Any
class StereocamOverlay(FabricOverlay, pynq.Overlay):  # type: ignore[name-defined]
    """The stereocam bitstream, owned by this process, with our drivers and :attr:`fabric` bound to its IP.

    ``bitfile`` needs its ``.hwh`` beside it (pynq reads the IP addresses and
    parameters from it). ``device`` is passed to pynq (None: the board's).
    ``lock``: the :class:`FabricLock` path (None: its default); ``pl_state``:
    where pynq records the loaded bitstream (None: pynq's own file and the
    board's FPGA manager). Raises :class:`FabricBusy` at once when another
    owner holds the fabric, before pynq reads or programs anything.
    The daemon drives it as an :class:`~..interface.Overlay` (:class:`FabricOverlay`).
    """

    backend = "pynq"
    # Class-level defaults: pynq's __getattr__ calls is_loaded() for any missing attribute, even mid-__init__.
    _pl_state: Optional[PynqPLState] = None
    _bit_hash: Optional[str] = None
    _bound = False

    fabric: StereoFabric
    guard: PLGuard
    rectify: PynqRectifyCore
    vdma_raw: PynqVDMA
    vdma_proc: PynqVDMA
    mux: PynqAxisSwitch

    # The board's sensors are reached only over I2C, its faults cannot be made, its rig is unknown.
    sensors: Optional[SensorPair] = None
    fault_injection: Optional[FaultInjection] = None

    def rig_calibration(self) -> Optional[Calibration]:
        return None

    def __init__(self, bitfile: Path, *, frame_size: Tuple[int, int] = (752, 480),
                 device: Optional[Any] = None, timeout: float = 1.0, lock: Optional[Path] = None,
                 pl_state: Optional[PynqPLState] = None,
                 probe_interval: float = 1.0) -> None:
        self._fabric_lock = FabricLock(lock)
        self._fabric_lock.acquire(str(bitfile))
        try:
            self._pl_state = pl_state or PynqPLState()
            super().__init__(str(bitfile), download=False, device=device)
            from pynq.pl_server.global_state import bitstream_hash

            self._bit_hash = str(bitstream_hash(self.bitfile_name))
            require_instances(self.ip_dict)
            if self.is_loaded():
                log.info("overlay %s is already loaded: binding without re-programming the fabric", bitfile)
            else:
                log.info("programming the fabric with %s", bitfile)
                self.download()
            ours = self._pl_state.loaded()
            if ours is None:  # pynq can lose its record (a stale one cleared after a power cycle)
                log.warning("pynq records no loaded bitstream in %s after loading %s: "
                            "watching for one to appear", self._pl_state.state_file, bitfile)
            elif not self.is_loaded():
                raise BackendError(f"pynq records {ours.bitfile_name} as loaded, not {bitfile} "
                                   f"({self._pl_state.state_file}): another process programmed the fabric "
                                   "meanwhile")
            self.guard = guard = PLGuard(self._pl_state, ours, probe_interval=probe_interval)
            # The stereo core and its channel where the .hwh has them (a ``depth`` build), else none.
            drivers = {name: DRIVERS[name](self.ip_dict[name], guard=guard, timeout=timeout)
                       for name in (*INSTANCES, *optional_instances(self.ip_dict))}
            for name, driver in drivers.items():
                setattr(self, name, driver)  # ``ov.rectify`` is this object; pynq's __getattr__ is not asked
            guard.probe = self._identity
            self.fabric = from_drivers(drivers, pynq_allocator(self.device), backend="pynq",
                                       frame_size=frame_size)
            self._bound = True
        except BaseException:
            self._fabric_lock.release()
            raise

    def is_loaded(self) -> bool:
        """True when pynq's PL state records this bitstream as loaded (pynq's own test: any overlay)."""
        if self._pl_state is None or self._bit_hash is None:
            return bool(super().is_loaded())
        return self._pl_state.holds(self.bitfile_name, self._bit_hash)

    def download(self, dtbo: Optional[str] = None) -> None:
        """Program the fabric; only while this overlay holds the lock and before its drivers are bound."""
        if not self._fabric_lock.held:
            raise FabricBusy("this overlay was closed and no longer owns the fabric "
                             f"(lock: {self._fabric_lock.path})")
        if self._bound:
            raise BackendError("the overlay's drivers are bound: re-programming would pull the IP from under "
                               "them; close() it and open a new StereocamOverlay")
        super().download(dtbo)

    def _identity(self) -> Optional[str]:
        """Why the core at our address is not ours (None: it is); reads ID and VERSION on the raw window."""
        mmio = self.rectify.mmio
        ident = int(mmio.read(RECTIFY_MAP["ID"].offset))
        if ident != CORE_ID:
            return f"the rectify core's ID register reads {ident:#010x}, not {CORE_ID:#010x}"
        major = RECTIFY_MAP["VERSION"].get(int(mmio.read(RECTIFY_MAP["VERSION"].offset)), "MAJOR")
        if major != CORE_VERSION >> 16:
            return f"the rectify core reports version {major}.x, not {CORE_VERSION >> 16}.x"
        return None

    def start(self) -> "StereocamOverlay":
        self.fabric.start_streams()
        return self

    def stop(self) -> None:
        self.fabric.stop_streams()

    def close(self) -> None:
        """Stop the streams, free the buffers (unless the fabric was lost), give up the fabric; idempotent."""
        if not self._fabric_lock.held:
            return
        try:
            if self.guard.lost is None:
                self.fabric.close()
            else:
                log.warning("closing without stopping the DMA: %s", self.guard.lost)
        except FabricLost as exc:  # lost while closing
            log.warning("closing without stopping the DMA: %s", exc)
        finally:
            self.guard.close()
            self._fabric_lock.release()

    def __enter__(self) -> "StereocamOverlay":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
