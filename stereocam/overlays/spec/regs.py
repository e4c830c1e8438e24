"""Registers described as data: one table per IP, read by drivers and emulators alike.

A :class:`RegisterMap` lists every register of one IP block with its offset,
access kind, reset value and bit fields. Drivers encode and decode values
through it (no hex literals in driver code); the emulated fabric builds its
behavioural models from the same tables, so the two cannot drift apart.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import ClassVar, Dict, Generic, Iterable, Iterator, Optional, Tuple, TypeVar


class Access(enum.Enum):
    """How software may touch a register or a field."""

    RW = "rw"  # read/write
    RO = "ro"  # read-only: writes to a wholly read-only register are an error
    W1C = "w1c"  # read; writing 1 clears the bit (sticky status)
    SC = "sc"  # self-clearing: reads back 0 once the hardware has acted on it
    WO = "wo"  # write-only: reads return 0


@dataclass(frozen=True)
class Field:
    """A bit field inside a register. ``access`` defaults to the register's."""

    name: str
    lsb: int
    width: int = 1
    access: Optional[Access] = None
    doc: str = ""

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.lsb

    @property
    def max(self) -> int:
        return (1 << self.width) - 1


@dataclass(frozen=True)
class Register:
    """One register: offset (or address), access, reset value, fields and the values the device accepts.

    32-bit and word aligned here (AXI4-Lite); :class:`.mt9v034.Register16`
    sets :attr:`BITS` and :attr:`ALIGN` for an I2C device's 16-bit registers.
    ``limits`` lists ``(name, lo, hi)``: what the device accepts for a field
    (``name`` a field name) or for the whole register (``name`` the
    register's own name), beyond what the bits can hold.
    """

    name: str
    offset: int
    access: Access = Access.RW
    reset: int = 0
    fields: Tuple[Field, ...] = ()
    doc: str = ""
    limits: Tuple[Tuple[str, int, int], ...] = ()
    _by_name: Dict[str, Field] = field(default_factory=dict, init=False, repr=False, compare=False)

    BITS: ClassVar[int] = 32
    ALIGN: ClassVar[int] = 4

    @property
    def word_mask(self) -> int:
        return (1 << self.BITS) - 1

    def __post_init__(self) -> None:
        if self.offset % self.ALIGN:
            raise ValueError(f"{self.name}: offset {self.offset:#x} is not word aligned")
        if not 0 <= self.reset <= self.word_mask:
            raise ValueError(f"{self.name}: reset value {self.reset:#x} does not fit {self.BITS} bits")
        used = 0
        for f in self.fields:
            if f.mask & used:
                raise ValueError(f"{self.name}: field {f.name} overlaps another field")
            if f.lsb + f.width > self.BITS:
                raise ValueError(f"{self.name}: field {f.name} runs past bit {self.BITS - 1}")
            used |= f.mask
            self._by_name[f.name] = f
        for name, lo, hi in self.limits:
            width_max = self.word_mask if name == self.name else self.field(name).max
            if not 0 <= lo <= hi <= width_max:
                raise ValueError(f"{self.name}: limits of {name} ({lo}..{hi}) do not fit its bits")

    def field(self, name: str) -> Field:
        try:
            return self._by_name[name]
        except KeyError:
            known = ", ".join(self._by_name) or "none"
            raise KeyError(f"register {self.name} has no field {name!r} (fields: {known})") from None

    def field_access(self, f: Field) -> Access:
        return f.access if f.access is not None else self.access

    def mask_of(self, access: Access) -> int:
        """Bits of this register whose access is ``access`` (whole word if no fields)."""
        if not self.fields:
            return self.word_mask if self.access is access else 0
        m = 0
        for f in self.fields:
            if self.field_access(f) is access:
                m |= f.mask
        return m

    @property
    def unassigned_mask(self) -> int:
        """Bits not covered by any field (reserved: read 0, writes ignored)."""
        if not self.fields:
            return 0
        m = 0
        for f in self.fields:
            m |= f.mask
        return self.word_mask & ~m

    def limit(self, name: Optional[str] = None) -> Tuple[int, int]:
        """``(lo, hi)`` the device accepts for field ``name`` (or the whole register)."""
        key = self.name if name is None else name
        for n, lo, hi in self.limits:
            if n == key:
                return lo, hi
        if key == self.name:
            return 0, self.word_mask
        return 0, self.field(key).max

    def encode(self, base: int = 0, **values: int) -> int:
        """``base`` with the named fields replaced; a value too wide for its field is refused."""
        word = int(base)
        for name, value in values.items():
            f = self.field(name)
            value = int(value)
            if value < 0 or value > f.max:
                raise ValueError(
                    f"{self.name}.{name} takes 0..{f.max}, not {value}"
                )
            word = (word & ~f.mask) | (value << f.lsb)
        return word & self.word_mask

    def decode(self, word: int) -> Dict[str, int]:
        return {f.name: (int(word) >> f.lsb) & f.max for f in self.fields}

    def get(self, word: int, name: str) -> int:
        f = self.field(name)
        return (int(word) >> f.lsb) & f.max

    def bit(self, name: str) -> int:
        """The mask of a field (handy for 1-bit flags)."""
        return self.field(name).mask


R = TypeVar("R", bound=Register)


class RegisterMap(Generic[R]):
    """All registers of one IP block, looked up by name or offset.

    ``size`` is the register window in bytes (every offset must lie inside it).
    """

    def __init__(self, name: str, registers: Iterable[R], *, size: int, doc: str = "") -> None:
        self.name = name
        self.size = size
        self.doc = doc
        self._by_name: Dict[str, R] = {}
        self._by_offset: Dict[int, R] = {}
        for r in registers:
            if r.name in self._by_name:
                raise ValueError(f"{name}: register {r.name} defined twice")
            if r.offset in self._by_offset:
                other = self._by_offset[r.offset].name
                raise ValueError(f"{name}: offset {r.offset:#x} used by {other} and {r.name}")
            if r.offset >= size:
                raise ValueError(f"{name}: {r.name} at {r.offset:#x} lies outside the {size:#x}-byte window")
            self._by_name[r.name] = r
            self._by_offset[r.offset] = r

    def __getitem__(self, name: str) -> R:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.name} has no register {name!r}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __iter__(self) -> Iterator[R]:
        return iter(sorted(self._by_offset.values(), key=lambda r: r.offset))

    def __len__(self) -> int:
        return len(self._by_name)

    def at(self, offset: int) -> Optional[R]:
        return self._by_offset.get(offset)

    def offset(self, name: str) -> int:
        return self[name].offset

    def reset_values(self) -> Dict[int, int]:
        return {r.offset: r.reset for r in self}

    # How the Markdown table shows a register's place and reset value (subclasses change them).
    OFFSET_TITLE = "offset"

    def _offset_text(self, r: R) -> str:
        return f"{r.offset:#05x}"

    def _reset_text(self, r: R) -> str:
        return f"{r.reset:#x}"

    def table_markdown(self) -> str:
        """The map as a Markdown table, so the document can be checked against the code."""
        lines = [f"| {self.OFFSET_TITLE} | name | access | reset | fields |", "|---|---|---|---|---|"]
        for r in self:
            fields = "; ".join(
                f"{f.name}[{f.lsb + f.width - 1}:{f.lsb}]" if f.width > 1 else f"{f.name}[{f.lsb}]"
                for f in r.fields
            )
            lines.append(f"| {self._offset_text(r)} | {r.name} | {r.access.value} | {self._reset_text(r)} "
                         f"| {fields} |")
        return "\n".join(lines)
