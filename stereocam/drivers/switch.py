"""Driver for the AXI4-Stream Switch (PG085) that selects the rectify core's input.

``select(LIVE)`` routes the cameras, ``select(VIRTUAL)`` the virtual camera
(VDMA MM2S). The switch takes a new route only on a commit
(``CTRL.REG_UPDATE``), briefly resetting itself; :meth:`AxisSwitch.select`
waits, bounded, for the commit to finish.
"""

from __future__ import annotations

import threading
from typing import Optional

from ..overlays.spec.axis_switch import (
    INPUT_NAMES,
    LIVE,
    MAX_INTERFACES,
    VIRTUAL,
    axis_switch_map,
    mi_mux_name,
)
from .mmio import DriverError, RegisterRangeError, Registers, RegisterWindow

__all__ = ["AxisSwitch", "LIVE", "VIRTUAL", "INPUT_NAMES", "SwitchError"]


class SwitchError(DriverError):
    """Base of the switch driver's errors."""


class AxisSwitch:
    """MI0 of an AXI4-Stream switch with ``inputs`` slave interfaces, over a register window.

    The switch has no identity register; ``inputs`` comes from the overlay
    metadata (``NUM_SI``).
    """

    def __init__(
        self, window: RegisterWindow, *, inputs: int = 2, name: str = "axis_switch", timeout: float = 1.0
    ) -> None:
        if isinstance(inputs, bool) or not isinstance(inputs, int) or not 1 <= inputs <= MAX_INTERFACES:
            raise SwitchError(
                f"{name}: NUM_SI={inputs!r}; an AXI4-Stream switch has 1..{MAX_INTERFACES} inputs"
            )
        self.inputs = inputs
        self.name = name
        self.timeout = timeout
        self.map = axis_switch_map(1)
        self.regs = Registers(window, self.map, name)
        self._mux = self.map[mi_mux_name(0)]
        self._ctrl = self.map["CTRL"]
        self._lock = threading.Lock()

    def select(self, index: int, timeout: Optional[float] = None) -> None:
        """Route slave interface ``index`` to MI0; blocks (at most ``timeout`` s) until committed."""
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < self.inputs:
            raise RegisterRangeError(
                f"{self.name}: input {index!r} does not exist (0..{self.inputs - 1}: "
                f"{', '.join(f'{i}={n}' for i, n in INPUT_NAMES.items() if i < self.inputs)})"
            )
        self._commit(self._mux.encode(MUX=index, DISABLE=0), timeout)

    def disable(self, timeout: Optional[float] = None) -> None:
        """Disconnect MI0 (the rectify core then gets no frames); blocks until committed."""
        self._commit(self._mux.encode(DISABLE=1), timeout)

    def _commit(self, mux: int, timeout: Optional[float]) -> None:
        with self._lock:  # one commit at a time: a retry must not interleave with a change
            self._commit_locked(mux, timeout)

    def _commit_locked(self, mux: int, timeout: Optional[float]) -> None:
        self.regs.write(self._mux.name, mux)
        self.regs.write(self._ctrl.name, self._ctrl.encode(REG_UPDATE=1))
        self.regs.wait(
            self._ctrl.name,
            lambda v: not self._ctrl.get(v, "REG_UPDATE"),
            expected="cleared REG_UPDATE (commit never finished: is the switch clocked?)",
            timeout=self.timeout if timeout is None else timeout,
        )

    def selected(self) -> Optional[int]:
        """The input MI0 is set to (read back from ``MI0_MUX``), or None when disabled."""
        fields = self._mux.decode(self.regs.read(self._mux.name))
        return None if fields["DISABLE"] else fields["MUX"]
