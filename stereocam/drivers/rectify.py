"""Driver for the rectify core (register map in ``stereocam/overlays/spec/rectify.py``).

Same code on the board (window = ``pynq.MMIO``) and on the emulated fabric.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Union

from ..overlays.model.core_params import plan
from ..overlays.model.core_regs import CoreControl, config_words, read_config
from ..overlays.model.linebuffer import LineBufferFit
from ..overlays.spec.rectify import CORE_ID, CORE_VERSION, RECTIFY_MAP, CameraParams, CameraRegs, CoreConfig
from .core_common import ConfigRefused, check_identity, clear_flags, wait_applied
from .mmio import Registers, RegisterWindow

__all__ = ["ConfigRefused", "CoreStatus", "RectifyCore"]


@dataclass(frozen=True)
class CoreStatus:
    frame_count: int
    busy: bool
    apply_pending: bool
    flags: Dict[str, bool]
    control: Dict[str, int]


class RectifyCore:
    """Program and watch one rectify core.

    :meth:`program` blocks until the core has latched the new parameters
    (at the next frame start while frames flow, at once when disabled), at
    most ``timeout`` seconds.
    """

    def __init__(self, window: RegisterWindow, *, timeout: float = 1.0) -> None:
        self.regs = Registers(window, RECTIFY_MAP)
        self.timeout = timeout
        check_identity(self.regs, CORE_ID, CORE_VERSION, "rectify")
        self.max_width = self.regs.read("MAX_WIDTH")
        self.max_height = self.regs.read("MAX_HEIGHT")
        self.lb_rows = self.regs.read("LB_ROWS")
        self.colour = bool(self.regs.field("CAPS", "COLOUR"))  # False: a gray-only build

    def plan(self, left: Union[CameraParams, CameraRegs], right: Union[CameraParams, CameraRegs], width: int,
             height: int) -> "tuple[CoreConfig, LineBufferFit]":
        """Check a calibration against this core; raises ``CoreParamsError`` with what to change."""
        return plan(left, right, width, height, lb_rows=self.lb_rows,
                    max_width=self.max_width, max_height=self.max_height)

    def program(self, left: Union[CameraParams, CameraRegs], right: Union[CameraParams, CameraRegs],
                width: int, height: int, *, wait: bool = True) -> "tuple[CoreConfig, LineBufferFit]":
        """Check a calibration, then write and APPLY it; a refused one leaves the core untouched."""
        config, fit = self.plan(left, right, width, height)
        self.load(config, wait=wait)
        return config, fit

    def load(self, config: CoreConfig, *, wait: bool = True) -> None:
        """Write a config to the shadow registers and APPLY it, without the line-buffer check.

        The core itself still refuses out-of-range values (CONFIG_ERROR ->
        :class:`ConfigRefused`); prefer :meth:`program`. With ``wait=False``
        it returns after setting APPLY (for a clock the caller steps itself);
        :meth:`check_applied` then confirms. Between frames the core latches at once.
        """
        for name, word in config_words(config).items():
            self.regs.write(name, word)
        self.clear_flags("CONFIG_ERROR")
        self.regs.modify("CONTROL", APPLY=1)
        if wait:
            self.check_applied(timeout=self.timeout)

    def check_applied(self, *, timeout: float = 0.0) -> None:
        """Wait (at most ``timeout`` s) for APPLY to clear, then raise if the core refused the set."""
        wait_applied(self.regs, "rectify: the core refused the parameters (CONFIG_ERROR); "
                     "previous ones stay active", timeout=timeout)

    def read_config(self) -> CoreConfig:
        """The shadow parameter set as the registers hold it."""
        return read_config(self.regs.read)

    def read_control(self) -> CoreControl:
        """CONTROL and DEBUG_ROW as the registers hold them."""
        return CoreControl.read(self.regs.read)

    def set_mode(self, *, enable: Optional[bool] = None, bypass: Optional[bool] = None,
                 gray: Optional[bool] = None, debug_row: Optional[int] = None,
                 debug_line: Optional[bool] = None) -> None:
        """Change control bits; ``None`` leaves a setting as it is. Takes effect at the next frame."""
        if debug_row is not None:
            limit = self.max_height - 1
            if not 0 <= debug_row <= limit:
                raise ValueError(f"debug row {debug_row} is outside 0..{limit}")
            self.regs.write("DEBUG_ROW", RECTIFY_MAP["DEBUG_ROW"].encode(VALUE=debug_row))
        bits = (("ENABLE", enable), ("BYPASS", bypass), ("GRAY", gray), ("DEBUG_LINE", debug_line))
        fields = {name: int(value) for name, value in bits if value is not None}
        if fields:
            self.regs.modify("CONTROL", APPLY=0, **fields)

    def enable(self) -> None:
        self.set_mode(enable=True)

    def disable(self) -> None:
        self.set_mode(enable=False)

    def clear_flags(self, *names: str) -> None:
        """Write-1-to-clear the named sticky flags (all of them if none named)."""
        clear_flags(self.regs, *names)

    def status(self) -> CoreStatus:
        status = RECTIFY_MAP["STATUS"].decode(self.regs.read("STATUS"))
        return CoreStatus(
            frame_count=self.regs.read("FRAME_COUNT"),
            busy=bool(status["BUSY"]),
            apply_pending=bool(status["APPLY_PENDING"]),
            flags={k: bool(v) for k, v in RECTIFY_MAP["FLAGS"].decode(self.regs.read("FLAGS")).items()},
            control=RECTIFY_MAP["CONTROL"].decode(self.regs.read("CONTROL")),
        )

    def dump(self) -> Dict[str, int]:
        """Every register by name: what a capture's metadata records."""
        return {reg.name: self.regs.read(reg.name) for reg in RECTIFY_MAP}
