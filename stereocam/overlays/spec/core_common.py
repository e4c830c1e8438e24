"""Registers every stereocam core has in the same place and meaning (the rectify and stereo cores).

A driver, the daemon's status page and a test bench can then read a core's progress the same way:
STATUS at 0x024 (BUSY, APPLY_PENDING), FRAME_COUNT at 0x02C, the frame size at 0x030 and 0x034.
"""
from __future__ import annotations

from typing import Tuple

from .regs import Access, Field, Register

APPLY_DOC = "latch the shadow parameters at the next frame start"


def progress_registers() -> Tuple[Register, Register]:
    """STATUS and FRAME_COUNT."""
    return (
        Register("STATUS", 0x024, Access.RO, 0,
                 fields=(Field("BUSY", 0, doc="a frame is in flight"),
                         Field("APPLY_PENDING", 1, doc="shadow parameters wait for the next frame start"))),
        Register("FRAME_COUNT", 0x02C, Access.RO, 0, doc="output frames completed, wraps at 2**32"),
    )


def size_registers(width: int, height: int) -> Tuple[Register, Register]:
    """WIDTH and HEIGHT (shadowed), reset to ``width`` x ``height``."""
    return (Register("WIDTH", 0x030, Access.RW, width, fields=(Field("VALUE", 0, 16),)),
            Register("HEIGHT", 0x034, Access.RW, height, fields=(Field("VALUE", 0, 16),)))


def control_register(reset: int, modes: Tuple[Field, ...]) -> Register:
    """CONTROL: ENABLE in bit 0, the core's own mode bits, APPLY (self-clearing) in bit 4."""
    return Register("CONTROL", 0x020, Access.RW, reset,
                    fields=(Field("ENABLE", 0, doc="core accepts and emits frames"), *modes,
                            Field("APPLY", 4, access=Access.SC, doc=APPLY_DOC)))


def flags_register(flags: Tuple[Field, ...]) -> Register:
    """FLAGS: sticky errors, write 1 to clear."""
    return Register("FLAGS", 0x028, Access.W1C, 0, fields=flags)
