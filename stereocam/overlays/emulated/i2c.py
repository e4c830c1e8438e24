"""An emulated I2C bus: 16-bit register transactions routed to emulated devices by address.

It is an :class:`~stereocam.drivers.i2c.I2CBus`, so the sensor drivers run on
it unchanged. An address with no device, or a device whose ``answering`` is
False (a sensor unplugged, unpowered or strapped elsewhere), gets the same
:class:`~stereocam.drivers.i2c.I2CNack` the Linux bus raises for a missing
acknowledge. A device that rejects a transaction (an unknown register, a
write to a read-only one) raises its own :class:`.regblock.EmulationError`:
that is a driver bug, and fails loudly.
"""
from __future__ import annotations

import threading
from typing import Dict, List, Optional, Protocol, Tuple, runtime_checkable

from ...drivers.i2c import check_transaction, nack_error
from .regblock import EmulationError

__all__ = ["EmulatedI2CBus", "I2CDevice"]


@runtime_checkable
class I2CDevice(Protocol):
    """What the bus needs from an emulated device: an ``answering`` flag and 16-bit register access."""

    answering: bool

    def i2c_read16(self, register: int) -> int: ...

    def i2c_write16(self, register: int, value: int) -> None: ...


class EmulatedI2CBus:
    """Emulated ``/dev/i2c-<bus>``: :meth:`attach` devices at 7-bit addresses, then read and write.

    Transactions are serialised by a lock, like the kernel's adapter lock.
    With ``record`` set, :attr:`log` keeps ``(op, address, register, value)``
    for every acknowledged transaction (``op`` is ``"r"`` or ``"w"``).
    """

    def __init__(self, bus: int = 0) -> None:
        self.bus = int(bus)
        self.path = f"emulated /dev/i2c-{self.bus}"
        self.record = False
        self.log: List[Tuple[str, int, int, int]] = []
        self._devices: Dict[int, I2CDevice] = {}
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"EmulatedI2CBus({self.bus}, devices at {[hex(a) for a in sorted(self._devices)]})"

    def attach(self, address: int, device: I2CDevice) -> None:
        check_transaction(address, 0)
        with self._lock:
            if address in self._devices:
                raise EmulationError(f"{self.path}: address {address:#04x} already has a device")
            self._devices[address] = device

    def detach(self, address: int) -> None:
        with self._lock:
            self._devices.pop(address, None)

    def device(self, address: int) -> Optional[I2CDevice]:
        return self._devices.get(address)

    def read16(self, address: int, register: int) -> int:
        check_transaction(address, register)
        with self._lock:
            value = int(self._answering(address, register, "reading").i2c_read16(register))
            if self.record:
                self.log.append(("r", address, register, value))
            return value

    def write16(self, address: int, register: int, value: int) -> None:
        check_transaction(address, register, value)
        with self._lock:
            self._answering(address, register, f"writing {value:#06x} to").i2c_write16(register, value)
            if self.record:
                self.log.append(("w", address, register, value))

    def _answering(self, address: int, register: int, doing: str) -> I2CDevice:
        device = self._devices.get(address)
        if device is None or not device.answering:
            raise nack_error(self.path, address, register, doing)
        return device
