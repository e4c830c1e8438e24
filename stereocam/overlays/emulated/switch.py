"""Behavioural model of the AXI4-Stream Switch (PG085) in control-register routing mode.

Registers follow :func:`~stereocam.overlays.spec.axis_switch.axis_switch_map`.
The ``MIx_MUX`` registers are double buffered (PG085, "Control Register"):
writes are staged and read back as written, but routing changes only when
``CTRL.REG_UPDATE`` is written; the switch then soft-resets, and the bit
reads 1 for ``settle_reads`` register reads before it clears itself, so a
driver has to poll it. Selecting a slave interface the switch does not have,
or setting a reserved bit, raises: the real switch would silently misroute.
"""

from __future__ import annotations

from typing import List, Optional

from ..spec.axis_switch import MAX_INTERFACES, NUM_INPUTS, NUM_OUTPUTS, axis_switch_map, mi_mux_name
from ..spec.regs import Register
from .regblock import EmulationError, RegisterBlock


class EmulatedAxisSwitch(RegisterBlock):
    """A switch with ``inputs`` slave and ``outputs`` master interfaces."""

    def __init__(
        self,
        inputs: int = NUM_INPUTS,
        outputs: int = NUM_OUTPUTS,
        name: str = "axis_switch",
        *,
        settle_reads: int = 2,
    ) -> None:
        if not 1 <= inputs <= MAX_INTERFACES:
            raise ValueError(f"an AXI4-Stream switch has 1..{MAX_INTERFACES} slave interfaces, not {inputs}")
        if settle_reads < 1:
            raise ValueError("settle_reads must be at least 1")
        self.inputs = inputs
        self.outputs = outputs
        self.settle_reads = settle_reads
        self._active: List[Optional[int]] = [None] * outputs
        self._update_countdown: Optional[int] = None
        self.commits = 0  # completed REG_UPDATEs
        self.hang_update = False  # tests: REG_UPDATE never clears
        super().__init__(axis_switch_map(outputs), name)

    @property
    def selected(self) -> Optional[int]:
        """Slave interface routed to MI0 now (None: disabled). What the fabric reads each frame."""
        return self.active(0)

    def active(self, mi: int) -> Optional[int]:
        with self.lock:
            return self._active[mi]

    def reset_registers(self) -> None:
        with self.lock:
            super().reset_registers()
            self._active = [None] * self.outputs
            self._update_countdown = None

    def read(self, offset: int, length: int = 4) -> int:
        with self.lock:
            if self._update_countdown is not None and not self.hang_update:
                self._update_countdown -= 1
                if self._update_countdown <= 0:
                    self._commit()
            return super().read(offset, length)

    def write(self, offset: int, value: int) -> None:
        with self.lock:
            reg = self.map.at(offset)
            if reg is not None:
                reserved = int(value) & reg.unassigned_mask
                if reserved:
                    raise EmulationError(
                        f"{self.ip}: write of {int(value):#x} to {reg.name} sets reserved bits {reserved:#x}"
                    )
                if reg.name.endswith("_MUX"):
                    fields = reg.decode(int(value))
                    if not fields["DISABLE"] and fields["MUX"] >= self.inputs:
                        raise EmulationError(
                            f"{self.ip}: {reg.name} selects SI{fields['MUX']}, but the switch has "
                            f"{self.inputs} slave interfaces (SI0..SI{self.inputs - 1})"
                        )
            super().write(offset, value)

    def on_write(self, reg: Register, old: int, written: int) -> None:
        if reg.name == "CTRL" and reg.get(written, "REG_UPDATE"):
            self._update_countdown = self.settle_reads  # REG_UPDATE stays 1 until the commit is done

    def _commit(self) -> None:
        for mi in range(self.outputs):
            fields = self.map[mi_mux_name(mi)].decode(self.get(mi_mux_name(mi)))
            self._active[mi] = None if fields["DISABLE"] else fields["MUX"]
        self.set_field("CTRL", "REG_UPDATE", 0)
        self._update_countdown = None
        self.commits += 1
