"""Test doubles for register windows (after PYNQ's ``tests/mock_devices.py``).

:class:`RecordingWindow` is given the exact sequence of accesses a driver must
make, as ``("w", offset, value)`` and ``("r", offset, value_to_return)``
tuples. Any access out of order, or with another value, fails at once with
both sides shown; :meth:`assert_done` fails if expected accesses are left.
:class:`RecordingI2C` does the same for I2C buses (16-bit registers of devices
at 7-bit addresses).
"""
from __future__ import annotations

from typing import List, Sequence, Tuple

Op = Tuple[str, int, int]


class UnexpectedAccess(AssertionError):
    pass


class RecordingWindow:
    def __init__(self, expected: Sequence[Op] = ()) -> None:
        self.expected: List[Op] = list(expected)
        self.done: List[Op] = []

    def expect(self, *ops: Op) -> None:
        self.expected.extend(ops)

    def _next(self, op: str, offset: int) -> Op:
        if not self.expected:
            raise UnexpectedAccess(f"unexpected {op} at {offset:#x} after {len(self.done)} expected accesses")
        exp = self.expected.pop(0)
        if exp[0] != op or exp[1] != offset:
            raise UnexpectedAccess(
                f"access #{len(self.done)}: driver did {op} at {offset:#x}, expected {exp[0]} at {exp[1]:#x}"
            )
        return exp

    def read(self, offset: int, length: int = 4) -> int:
        exp = self._next("r", offset)
        self.done.append(exp)
        return exp[2]

    def write(self, offset: int, value: int) -> None:
        exp = self._next("w", offset)
        if exp[2] != value:
            raise UnexpectedAccess(
                f"access #{len(self.done)}: driver wrote {value:#010x} at {offset:#x}, "
                f"expected {exp[2]:#010x}"
            )
        self.done.append(("w", offset, value))

    def assert_done(self) -> None:
        if self.expected:
            raise AssertionError(
                f"{len(self.expected)} expected accesses never happened, first: {self.expected[0]}"
            )


I2COp = Tuple[str, int, int, object]


class RecordingI2C:
    """An I2C bus double: the exact transactions a driver must make, in order.

    Expected transactions are ``("w", address, register, value)`` and
    ``("r", address, register, value_to_return)``; ``value_to_return`` may be
    an exception instance, which the read raises (a NACK, say). Any other
    transaction, or another value written, fails at once with both sides
    shown; :meth:`assert_done` fails if expected transactions are left.
    """

    def __init__(self, expected: Sequence[I2COp] = ()) -> None:
        self.expected: List[I2COp] = list(expected)
        self.done: List[I2COp] = []

    def expect(self, *ops: I2COp) -> None:
        self.expected.extend(ops)

    def _next(self, op: str, address: int, register: int) -> I2COp:
        if not self.expected:
            raise UnexpectedAccess(f"unexpected {op} of R0x{register:02X} at {address:#04x} "
                                   f"after {len(self.done)} expected transactions")
        exp = self.expected.pop(0)
        if exp[0] != op or exp[1] != address or exp[2] != register:
            raise UnexpectedAccess(
                f"transaction #{len(self.done)}: driver did {op} R0x{register:02X} at {address:#04x}, "
                f"expected {exp[0]} R0x{exp[2]:02X} at {exp[1]:#04x}")
        return exp

    def read16(self, address: int, register: int) -> int:
        exp = self._next("r", address, register)
        self.done.append(exp)
        if isinstance(exp[3], BaseException):
            raise exp[3]
        return int(exp[3])  # type: ignore[call-overload]

    def write16(self, address: int, register: int, value: int) -> None:
        exp = self._next("w", address, register)
        if exp[3] != value:
            raise UnexpectedAccess(
                f"transaction #{len(self.done)}: driver wrote {value:#06x} to R0x{register:02X} at "
                f"{address:#04x}, expected {exp[3]:#06x}")
        self.done.append(("w", address, register, value))

    def assert_done(self) -> None:
        if self.expected:
            raise AssertionError(
                f"{len(self.expected)} expected transactions never happened, first: {self.expected[0]}")
