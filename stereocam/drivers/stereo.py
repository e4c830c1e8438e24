"""Driver for the stereo-matching core (register map ``STEREO_MAP`` in ``stereocam/overlays/spec/stereo.py``).

Same code on the board (window = ``pynq.MMIO``) and on the emulated fabric. Values the core
would refuse are refused here first, with :meth:`StereoParams.problems`' text, before a register
is written, so a refused request leaves the core as it was.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Tuple

from ..overlays.spec.stereo import (
    CORE_ID,
    CORE_VERSION,
    PARAM_REGISTERS,
    STEREO_MAP,
    Build,
    StereoParams,
    params_from_registers,
    register_values,
    size_problems,
)
from .core_common import ConfigRefused, check_identity, clear_flags, wait_applied
from .mmio import Registers, RegisterWindow


class StereoConfigRefused(ConfigRefused):
    """The stereo core raised CONFIG_ERROR on APPLY: it kept its previous parameters."""


@dataclass(frozen=True)
class StereoStatus:
    """One read of the core's progress registers: what ``/api/status`` shows."""

    frame_count: int
    enabled: bool
    busy: bool
    apply_pending: bool
    flags: Dict[str, bool]

    def as_json(self) -> Dict[str, object]:
        return {"frame_count": self.frame_count, "enabled": self.enabled, "busy": self.busy,
                "apply_pending": self.apply_pending, "flags": dict(self.flags)}


class StereoCore:
    """Program and watch one stereo core.

    :meth:`program` blocks until the core latched the parameters (at the next frame start
    while frames flow, at once while the core is disabled), at most ``timeout`` s.
    """

    def __init__(self, window: RegisterWindow, *, timeout: float = 1.0) -> None:
        self.regs = Registers(window, STEREO_MAP)
        self.timeout = timeout
        check_identity(self.regs, CORE_ID, CORE_VERSION, "stereo")
        self.build = Build("read back", max_width=self.regs.read("MAX_WIDTH"),
                           max_height=self.regs.read("MAX_HEIGHT"), max_disp=self.regs.read("MAX_DISP"),
                           parallel=self.regs.read("PARALLEL"))

    def program(self, params: StereoParams, *, size: Optional[Tuple[int, int]] = None,
                wait: bool = True) -> None:
        """Write ``params`` (and ``size``, ``(width, height)``, where given) and APPLY them; ENABLE kept.

        ValueError with every problem (nothing written) for values this build refuses;
        :class:`StereoConfigRefused` if the core refuses them anyway.
        """
        problems = params.problems(self.build) + ([] if size is None else size_problems(*size, self.build))
        if problems:
            raise ValueError("; ".join(problems))
        if size is not None:
            self.regs.write("WIDTH", STEREO_MAP["WIDTH"].encode(VALUE=size[0]))
            self.regs.write("HEIGHT", STEREO_MAP["HEIGHT"].encode(VALUE=size[1]))
        words = register_values(params)
        for reg in PARAM_REGISTERS.values():
            self.regs.write(reg, words[reg])
        self.clear_flags("CONFIG_ERROR")
        control = STEREO_MAP["CONTROL"]
        modes = {f.name: control.get(words["CONTROL"], f.name) for f in control.fields
                 if f.name not in ("ENABLE", "APPLY")}
        self.regs.modify("CONTROL", APPLY=1, **modes)
        if wait:
            self.check_applied(timeout=self.timeout)

    def check_applied(self, *, timeout: float = 0.0) -> None:
        """Wait (at most ``timeout`` s) for APPLY to clear, then raise if the core refused the set."""
        try:
            wait_applied(self.regs, "stereo: the core refused the parameters (CONFIG_ERROR); "
                         "the previous ones stay active", timeout=timeout)
        except ConfigRefused as exc:
            raise StereoConfigRefused(str(exc)) from None

    def params(self) -> StereoParams:
        """The parameters the shadow registers hold (what the last :meth:`program` wrote)."""
        names = (*PARAM_REGISTERS.values(), "CONTROL")
        return params_from_registers({name: self.regs.read(name) for name in names})

    def set_enable(self, on: bool) -> None:
        """Start or stop the core taking frames (takes effect at the next frame)."""
        self.regs.modify("CONTROL", APPLY=0, ENABLE=int(on))

    def enable(self) -> None:
        self.set_enable(True)

    def disable(self) -> None:
        self.set_enable(False)

    def clear_flags(self, *names: str) -> None:
        """Write-1-to-clear the named sticky flags (all of them if none named)."""
        clear_flags(self.regs, *names)

    def frame_count(self) -> int:
        return self.regs.read("FRAME_COUNT")

    def status(self) -> StereoStatus:
        status = STEREO_MAP["STATUS"].decode(self.regs.read("STATUS"))
        return StereoStatus(
            frame_count=self.regs.read("FRAME_COUNT"),
            enabled=bool(self.regs.field("CONTROL", "ENABLE")),
            busy=bool(status["BUSY"]),
            apply_pending=bool(status["APPLY_PENDING"]),
            flags={k: bool(v) for k, v in STEREO_MAP["FLAGS"].decode(self.regs.read("FLAGS")).items()},
        )

    def dump(self) -> Dict[str, int]:
        """Every register by name: what a capture's metadata records."""
        return {reg.name: self.regs.read(reg.name) for reg in STEREO_MAP}
