"""The one narrow interface through which drivers touch hardware.

A driver is handed a *register window* (anything with ``read(offset)`` and
``write(offset, value)``: ``pynq.MMIO`` on the board, an emulated register
block off it) and, where it needs frame memory, an *allocator* (``pynq.allocate``
or the emulated DDR). Drivers never look up a device themselves.

Every poll of hardware goes through :func:`wait_for`, which has a timeout and
raises :class:`RegisterTimeout` naming the register that never changed.
"""
from __future__ import annotations

import time
from typing import Any, Callable, Optional, Protocol, Tuple, runtime_checkable

import numpy as np

from ..overlays.spec.regs import Register, RegisterMap


@runtime_checkable
class RegisterWindow(Protocol):
    """32-bit register access at byte offsets (the subset of ``pynq.MMIO`` we use)."""

    def read(self, offset: int) -> int: ...

    def write(self, offset: int, value: int) -> None: ...


class PhysicalBuffer(Protocol):
    """A numpy array in DMA-able memory (``pynq.buffer.PynqBuffer`` or the emulated one)."""

    physical_address: int
    shape: Tuple[int, ...]

    def flush(self) -> None: ...

    def invalidate(self) -> None: ...

    def freebuffer(self) -> None: ...


class Allocator(Protocol):
    """``pynq.allocate``-compatible: ``allocate(shape, dtype)`` gives a :class:`PhysicalBuffer`."""

    def __call__(self, shape: Any, dtype: Any = np.uint8) -> Any: ...


class DriverError(Exception):
    """Base of every error a driver raises on purpose."""


class RegisterTimeout(DriverError):
    """A register never reached the expected value within the timeout."""

    def __init__(self, ip: str, register: str, expected: str, last: int, timeout: float) -> None:
        super().__init__(
            f"{ip}: {register} never {expected} within {timeout:g} s (last read {last:#010x}); "
            "is the overlay loaded and the IP clocked?"
        )
        self.ip = ip
        self.register = register
        self.last = last


class UnsupportedIP(DriverError):
    """The IP found is not one this driver can drive (wrong identity or configuration)."""


class RegisterRangeError(DriverError, ValueError):
    """A value does not fit the register or field it is meant for."""


def wait_for(
    window: RegisterWindow,
    ip: str,
    reg: Register,
    predicate: Callable[[int], bool],
    *,
    expected: str,
    timeout: float = 1.0,
    poll: float = 0.0005,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> int:
    """Poll ``reg`` until ``predicate(value)`` holds; return the value.

    Blocks for at most ``timeout`` seconds, then raises :class:`RegisterTimeout`
    whose message says which register never showed ``expected``. The first
    read happens immediately, so hardware that is already in the right state
    costs one read.
    """
    deadline = clock() + timeout
    value = window.read(reg.offset)
    while not predicate(value):
        if clock() >= deadline:
            raise RegisterTimeout(ip, reg.name, expected, value, timeout)
        sleep(poll)
        value = window.read(reg.offset)
    return value


class Registers:
    """Named access to one IP's registers through a window: ``regs.read('VDMACR')``."""

    def __init__(self, window: RegisterWindow, regmap: RegisterMap, ip: Optional[str] = None) -> None:
        self.window = window
        self.map = regmap
        self.ip = ip or regmap.name

    def read(self, name: str) -> int:
        return int(self.window.read(self.map[name].offset)) & 0xFFFFFFFF

    def write(self, name: str, value: int) -> None:
        if value < 0 or value > 0xFFFFFFFF:
            raise RegisterRangeError(f"{self.ip}.{name}: {value} does not fit 32 bits")
        self.window.write(self.map[name].offset, int(value))

    def field(self, name: str, field: str) -> int:
        return self.map[name].get(self.read(name), field)

    def modify(self, name: str, **fields: int) -> int:
        """Read-modify-write of named fields; returns the word written."""
        reg = self.map[name]
        word = reg.encode(self.read(name), **fields)
        self.write(name, word)
        return word

    def wait(
        self, name: str, predicate: Callable[[int], bool], *, expected: str, timeout: float = 1.0
    ) -> int:
        return wait_for(self.window, self.ip, self.map[name], predicate, expected=expected, timeout=timeout)
