"""The rectify core's writable registers as the objects software computes with, and back: decoded once.

The shadow registers (WIDTH, HEIGHT, LB_DELAY and both cameras' 64-bit
parameters) hold a :class:`~..spec.rectify.CoreConfig`; CONTROL and
DEBUG_ROW hold a :class:`CoreControl`, which with the build's LB_ROWS and
CAPS.COLOUR and the active LB_DELAY gives the :class:`~.result.CoreOptions` a
frame is processed with. The driver, the fabric and the emulated core all
decode through this module, and the driver encodes through it, so a register
added to :data:`~..spec.rectify.RECTIFY_MAP` is handled here or nowhere
(``tests/overlays/test_core_regs.py`` checks that every writable field round-trips).

Decoding takes ``read``: a function from register name to its 32-bit word
(``Registers.read`` of the driver, ``RegisterBlock.get`` of the emulated
core). Encoding returns register name -> word, in the order the words are to
be written.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict

from ..spec.rectify import (
    CAMERAS,
    PARAM_NAMES,
    RECTIFY_MAP,
    CameraRegs,
    CoreConfig,
    i64_to_words,
    words_to_i64,
)
from .result import CoreOptions

Read = Callable[[str], int]  # register name -> its word

#: Shadow registers holding one 16-bit value each, by :class:`CoreConfig` attribute, in write order.
SIZE_REGISTERS = {"width": "WIDTH", "height": "HEIGHT", "lb_delay": "LB_DELAY"}


def config_words(config: CoreConfig) -> Dict[str, int]:
    """The shadow registers' words for ``config``: frame size, delay, then each camera's parameters.

    Each 64-bit parameter is its ``_LO`` word then its ``_HI`` word; a value
    too wide for its register raises :class:`ValueError`.
    """
    words = {reg: RECTIFY_MAP[reg].encode(VALUE=getattr(config, attr))
             for attr, reg in SIZE_REGISTERS.items()}
    for cam in CAMERAS:
        for name, value in config.camera(cam).values().items():
            words[f"{cam}_{name}_LO"], words[f"{cam}_{name}_HI"] = i64_to_words(value)
    return words


def read_config(read: Read) -> CoreConfig:
    """The parameter set the shadow registers hold, whether or not applied (reads every shadow register)."""
    cams = {}
    for cam in CAMERAS:
        values = {n: words_to_i64(read(f"{cam}_{n}_LO"), read(f"{cam}_{n}_HI")) for n in PARAM_NAMES}
        cams[cam] = CameraRegs.from_values(values)
    sizes = {attr: RECTIFY_MAP[reg].get(read(reg), "VALUE") for attr, reg in SIZE_REGISTERS.items()}
    return CoreConfig(cams["L"], cams["R"], **sizes)


@dataclass(frozen=True)
class CoreControl:
    """CONTROL and DEBUG_ROW as software sees them: every field, decoded."""

    enable: bool = False  # CONTROL.ENABLE
    bypass: bool = False  # CONTROL.BYPASS
    gray: bool = False  # CONTROL.GRAY
    debug_line: bool = False  # CONTROL.DEBUG_LINE
    apply: bool = False  # CONTROL.APPLY: shadow parameters wait to be latched
    debug_row: int = 0  # DEBUG_ROW.VALUE, drawn only while debug_line is set

    @classmethod
    def from_words(cls, control: int, debug_row: int) -> "CoreControl":
        c = RECTIFY_MAP["CONTROL"].decode(control)
        return cls(enable=bool(c["ENABLE"]), bypass=bool(c["BYPASS"]), gray=bool(c["GRAY"]),
                   debug_line=bool(c["DEBUG_LINE"]), apply=bool(c["APPLY"]),
                   debug_row=RECTIFY_MAP["DEBUG_ROW"].get(debug_row, "VALUE"))

    @classmethod
    def read(cls, read: Read) -> "CoreControl":
        """Reads CONTROL, then DEBUG_ROW."""
        control = read("CONTROL")
        return cls.from_words(control, read("DEBUG_ROW"))

    def words(self) -> Dict[str, int]:
        """``{"CONTROL": word, "DEBUG_ROW": word}``; a debug row that does not fit raises ValueError."""
        control = RECTIFY_MAP["CONTROL"].encode(ENABLE=int(self.enable), BYPASS=int(self.bypass),
                                                GRAY=int(self.gray), DEBUG_LINE=int(self.debug_line),
                                                APPLY=int(self.apply))
        return {"CONTROL": control, "DEBUG_ROW": RECTIFY_MAP["DEBUG_ROW"].encode(VALUE=self.debug_row)}

    def options(self, *, lb_rows: int, lb_delay: int, colour: bool) -> CoreOptions:
        """What a frame is processed with under this control state.

        ``lb_rows`` and ``colour`` are the build's (LB_ROWS, CAPS.COLOUR);
        ``lb_delay`` the LB_DELAY of the parameter set in use.
        """
        return CoreOptions(lb_rows=lb_rows, lb_delay=lb_delay, gray=self.gray, bypass=self.bypass,
                           debug_row=self.debug_row if self.debug_line else None, colour=colour)
