"""Behavioural register blocks: the emulated side of a :class:`RegisterMap`.

A block models behaviour, not storage: read-only fields ignore writes (and a
write to a wholly read-only register raises), write-1-to-clear bits clear,
self-clearing bits call the model and drop back, unknown offsets raise.
Subclasses add behaviour in :meth:`on_write` and compute live values in
:meth:`on_read`, like QEMU's register API (``include/hw/register.h``).
"""
from __future__ import annotations

import threading
from typing import Dict, List, Tuple

from ..spec.regs import Access, Register, RegisterMap


class EmulationError(Exception):
    """Software did something the real IP would not accept."""


class UnknownRegister(EmulationError):
    def __init__(self, ip: str, offset: int, op: str) -> None:
        super().__init__(f"{ip}: {op} at offset {offset:#x}, where no register exists")


class ReadOnlyRegister(EmulationError):
    def __init__(self, ip: str, reg: Register, value: int) -> None:
        super().__init__(f"{ip}: write of {value:#x} to read-only register {reg.name} ({reg.offset:#x})")


class RegisterBlock:
    """Emulated AXI4-Lite register window with ``read(offset)``/``write(offset, value)``.

    Thread-safe: the frame clock thread and the driver may touch it at once.
    ``log`` keeps every access as ``(op, offset, value)`` when ``record`` is set.
    """

    def __init__(self, regmap: RegisterMap, ip: str | None = None) -> None:
        self.map = regmap
        self.ip = ip or regmap.name
        self.lock = threading.RLock()
        self.values: Dict[int, int] = {}
        self.record = False
        self.log: List[Tuple[str, int, int]] = []
        self.reset_registers()

    # -- storage helpers for subclasses -------------------------------------------------
    def reset_registers(self) -> None:
        with self.lock:
            for reg in self.map:
                self.values[reg.offset] = reg.reset

    def get(self, name: str) -> int:
        return self.values[self.map[name].offset]

    def set(self, name: str, value: int) -> None:
        """Hardware-side update (no access rules applied)."""
        self.values[self.map[name].offset] = value & 0xFFFFFFFF

    def get_field(self, name: str, field: str) -> int:
        return self.map[name].get(self.get(name), field)

    def set_field(self, name: str, field: str, value: int) -> None:
        reg = self.map[name]
        self.set(name, reg.encode(self.get(name), **{field: value}))

    def raise_bits(self, name: str, mask: int) -> None:
        self.set(name, self.get(name) | mask)

    # -- the bus side -------------------------------------------------------------------
    def read(self, offset: int, length: int = 4) -> int:
        with self.lock:
            reg = self.map.at(offset)
            if reg is None:
                raise UnknownRegister(self.ip, offset, "read")
            value = self.on_read(reg, self.values[offset])
            if reg.access is Access.WO and not reg.fields:
                value = 0
            value &= 0xFFFFFFFF & ~reg.unassigned_mask & ~reg.mask_of(Access.WO)
            if self.record:
                self.log.append(("r", offset, value))
            return value

    def write(self, offset: int, value: int) -> None:
        value = int(value)
        if value < 0 or value > 0xFFFFFFFF:
            raise EmulationError(f"{self.ip}: value {value} written at {offset:#x} does not fit 32 bits")
        with self.lock:
            reg = self.map.at(offset)
            if reg is None:
                raise UnknownRegister(self.ip, offset, "write")
            ro = reg.mask_of(Access.RO) | reg.unassigned_mask
            if not ~ro & 0xFFFFFFFF:  # no writable bit: wholly read-only (with or without fields)
                raise ReadOnlyRegister(self.ip, reg, value)
            if self.record:
                self.log.append(("w", offset, value))
            old = self.values[offset]
            w1c = reg.mask_of(Access.W1C)
            new = (old & ro) | (value & ~ro & ~w1c & 0xFFFFFFFF)
            new |= old & w1c & ~value  # W1C: a 1 clears, a 0 keeps
            self.values[offset] = new & 0xFFFFFFFF
            self.on_write(reg, old, value)

    # -- behaviour hooks ----------------------------------------------------------------
    def on_read(self, reg: Register, stored: int) -> int:
        """Value the bus sees; override for live values. Default: what is stored."""
        return stored

    def on_write(self, reg: Register, old: int, written: int) -> None:
        """React to a write after the stored value was updated.

        Self-clearing bits are still set in storage when this runs; the
        subclass acts on them and clears them (now, or later to model delay).
        """
        sc = reg.mask_of(Access.SC)
        if sc:
            self.values[reg.offset] &= ~sc
