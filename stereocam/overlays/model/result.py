"""Inputs and outputs shared by the reference and the fast model."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..spec.rectify import DEFAULT_LB_ROWS


@dataclass(frozen=True)
class CoreOptions:
    """Control state of the core that changes what a frame turns into."""

    lb_rows: int = DEFAULT_LB_ROWS  # rows the bitstream buffers (LB_ROWS register)
    lb_delay: int = 0  # LB_DELAY register
    gray: bool = False  # CONTROL.GRAY
    bypass: bool = False  # CONTROL.BYPASS
    debug_row: Optional[int] = None  # DEBUG_ROW when CONTROL.DEBUG_LINE is set
    colour: bool = True  # CAPS.COLOUR of the build: False for the gray-only build

    def __post_init__(self) -> None:
        if self.lb_rows < 1:
            raise ValueError(f"lb_rows must be at least 1, not {self.lb_rows}")
        if self.lb_delay < 0:
            raise ValueError(f"lb_delay must not be negative, not {self.lb_delay}")


@dataclass
class ModelResult:
    """An output frame and the sticky flags the frame raised."""

    frame: np.ndarray  # (H, W, 8) uint8
    lb_overflow: bool = False
