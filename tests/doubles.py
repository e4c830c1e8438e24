"""Test doubles for register windows (after PYNQ's ``tests/mock_devices.py``).

:class:`RecordingWindow` is given the exact sequence of accesses a driver must
make, as ``("w", offset, value)`` and ``("r", offset, value_to_return)``
tuples. Any access out of order, or with another value, fails at once with
both sides shown; :meth:`assert_done` fails if expected accesses are left.
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
                f"access #{len(self.done)}: driver wrote {value:#010x} at {offset:#x}, expected {exp[2]:#010x}"
            )
        self.done.append(("w", offset, value))

    def assert_done(self) -> None:
        if self.expected:
            raise AssertionError(f"{len(self.expected)} expected accesses never happened, first: {self.expected[0]}")
