"""Fault injection into the emulated fabric: what the daemon must survive, on demand.

Each kind is a fault the board can have, made the way the hardware would
show it, so the daemon has to notice it through its registers and buses as
it would on the board (nothing here tells the daemon about a fault):

- ``camera_stall``: the cameras stop sending frames (a loose ribbon cable);
- ``dma_internal``, ``dma_slave``, ``dma_decode`` on a VDMA channel: the
  channel halts on ``VDMAIntErr``/``VDMASlvErr``/``VDMADecErr`` on every
  frame it starts while the fault lasts (a bus error that persists);
- ``reset_hang`` on a VDMA channel: the channel halts on ``VDMAIntErr`` and
  its soft reset does not finish while the fault lasts;
- ``sensor_silent`` on ``left``/``right``: the MT9V034 NACKs every I2C
  transaction (a sensor lost its power or its bus);
- ``mux_refuse``: the AXI4-Stream switch does not finish a commit
  (``REG_UPDATE`` stays 1) while the fault lasts; one pending at its end lands then.

A fault lasts from :meth:`FaultInjector.inject` until :meth:`FaultInjector.end`.
Thread-safe. The daemon reaches it over HTTP only when started with
``--allow-fault-injection`` on the emulated backend (``stereocam/server/http/routes_faults.py``).
"""
from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Tuple

from ..interface import FaultError

if TYPE_CHECKING:  # pragma: no cover
    from .logic import EmulatedFabric

__all__ = ["KINDS", "CHANNELS", "Fault", "FaultInjector", "FaultError"]

DMA_ERRORS = {"dma_internal": "VDMAIntErr", "dma_slave": "VDMASlvErr", "dma_decode": "VDMADecErr"}
CHANNELS: Dict[str, Tuple[str, str]] = {
    "vdma_raw.s2mm": ("vdma_raw", "S2MM"),
    "vdma_proc.s2mm": ("vdma_proc", "S2MM"),
    "vdma_proc.mm2s": ("vdma_proc", "MM2S"),
}
SENSORS = ("left", "right")
# kind -> the targets it takes (None: the kind has no target)
KINDS: Dict[str, Optional[Tuple[str, ...]]] = {
    "camera_stall": None,
    **{kind: tuple(CHANNELS) for kind in DMA_ERRORS},
    "reset_hang": tuple(CHANNELS),
    "sensor_silent": SENSORS,
    "mux_refuse": None,
}


@dataclass(frozen=True)
class Fault:
    id: int
    kind: str
    target: Optional[str]
    since: float  # wall clock

    @property
    def part(self) -> str:
        """What the fault sits on: two faults on one part at a time would undo each other."""
        if self.kind in DMA_ERRORS or self.kind == "reset_hang":
            return str(self.target)
        if self.kind == "sensor_silent":
            return f"sensor.{self.target}"
        return "cameras" if self.kind == "camera_stall" else "mux"

    def to_json(self) -> Dict[str, Any]:
        return {"id": self.id, "kind": self.kind, "target": self.target, "since": self.since}


class FaultInjector:
    """Injects and ends faults on an :class:`~.logic.EmulatedFabric` (its sensors, once attached).

    The emulated overlay's :attr:`~..interface.Overlay.fault_injection`.
    """

    kinds = KINDS

    def __init__(self, fabric: EmulatedFabric) -> None:
        self.fabric = fabric
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._active: Dict[int, Fault] = {}

    def active(self) -> List[Fault]:
        with self._lock:
            return list(self._active.values())

    def inject(self, kind: str, target: Optional[str] = None) -> Fault:
        """Start a fault; raises :class:`FaultError` for a kind, target or part that cannot take it."""
        if kind not in KINDS:
            raise FaultError(f"unknown fault kind {kind!r}; known: {', '.join(KINDS)}")
        targets = KINDS[kind]
        if targets is None and target is not None:
            raise FaultError(f"{kind} takes no target, got {target!r}")
        if targets is not None and target not in targets:
            raise FaultError(f"{kind} needs a target, one of: {', '.join(targets)} (got {target!r})")
        with self._lock:
            fault = Fault(next(self._ids), kind, target, time.time())
            busy = [f for f in self._active.values() if f.part == fault.part]
            if busy:
                other = busy[0]
                raise FaultError(f"{fault.part} already has fault {other.id} ({other.kind}): end it first")
            self._apply(fault, on=True)
            self._active[fault.id] = fault
            return fault

    def end(self, fault_id: int) -> Fault:
        """End a fault; raises KeyError for one that is not active."""
        with self._lock:
            fault = self._active.pop(fault_id)
            self._apply(fault, on=False)
            return fault

    def end_all(self) -> List[Fault]:
        with self._lock:
            ended = list(self._active.values())
            for fault in ended:
                self._apply(fault, on=False)
            self._active.clear()
            return ended

    def _apply(self, fault: Fault, *, on: bool) -> None:
        fabric = self.fabric
        if fault.kind == "camera_stall":
            fabric.cameras_running = not on
        elif fault.kind in DMA_ERRORS or fault.kind == "reset_hang":
            vdma_name, channel = CHANNELS[str(fault.target)]
            vdma = getattr(fabric, vdma_name)
            if fault.kind == "reset_hang":
                vdma.hang(channel, "reset", on)
                vdma.inject(channel, "VDMAIntErr" if on else None)
            else:
                vdma.inject(channel, DMA_ERRORS[fault.kind] if on else None)
        elif fault.kind == "sensor_silent":
            self._sensor(str(fault.target)).answering = not on
        elif fault.kind == "mux_refuse":
            fabric.mux.hang_update = on

    def _sensor(self, camera: str) -> Any:
        pair = getattr(self.fabric, "sensors", None)
        sensors = getattr(pair, "sensors", None)
        if not sensors:
            raise FaultError("the emulated fabric has no camera sensors attached to make silent")
        return sensors[SENSORS.index(camera)]
