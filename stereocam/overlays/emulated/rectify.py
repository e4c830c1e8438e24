"""Behavioural model of the rectify core's register block and datapath.

Registers follow :data:`RECTIFY_MAP`; the datapath is the fast model, so the
emulated fabric is bit-exact to the model (and the RTL) by construction, and
its tests concentrate on the register behaviour: shadow parameters latched
by APPLY between frames, sticky W1C flags, refusal of out-of-range parameter
sets, a frame counter, and the malformed-input rules for frames of the wrong
size. The co-simulation uses it as the oracle for the RTL.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Dict, Optional, Tuple

import numpy as np

from ..model.core_params import CoreParamsError, check_frame_size
from ..model.core_regs import CoreControl, read_config
from ..model.fast import RectifyModel
from ..model.frames import fit_frame, padded
from ..model.result import CoreOptions
from ..spec.rectify import DEFAULT_BUILD, RECTIFY_MAP, CoreConfig, identity_registers
from ..spec.regs import Register
from .regblock import RegisterBlock


class EmulatedRectifyCore(RegisterBlock):
    """The core as built: ``max_width`` x ``max_height``, ``lb_rows`` rows, a colour or gray datapath."""

    def __init__(
        self, *, max_width: int = DEFAULT_BUILD.max_width, max_height: int = DEFAULT_BUILD.max_height,
        lb_rows: int = DEFAULT_BUILD.lb_rows, colour: bool = DEFAULT_BUILD.colour, name: str = "rectify",
    ) -> None:
        self.max_width = max_width
        self.max_height = max_height
        self.lb_rows = lb_rows
        self.colour = colour
        super().__init__(RECTIFY_MAP, name)
        self.active: Optional[CoreConfig] = None  # None: never applied, frames pass through
        self._models: Dict[Tuple[object, ...], RectifyModel] = {}
        self.frames_dropped = 0

    def reset_registers(self) -> None:
        super().reset_registers()
        self.set("MAX_WIDTH", self.max_width)
        self.set("MAX_HEIGHT", self.max_height)
        self.set("LB_ROWS", self.lb_rows)
        self.set_field("CAPS", "COLOUR", int(self.colour))

    # -- registers ----------------------------------------------------------------------
    def on_write(self, reg: Register, old: int, written: int) -> None:
        control = RECTIFY_MAP["CONTROL"]
        if reg.name == "CONTROL" and control.get(old, "APPLY") and not control.get(written, "APPLY"):
            self.set_field("CONTROL", "APPLY", 1)  # writing 0 does not cancel a pending APPLY
        if reg.name == "CONTROL" and control.get(written, "APPLY"):
            # Between frames (or disabled): latch at once. A frame in flight: at the next frame start.
            if not self.get_field("CONTROL", "ENABLE") or not self.get_field("STATUS", "BUSY"):
                self._latch()
        self._update_status()

    def _update_status(self) -> None:
        pending = self.get_field("CONTROL", "APPLY")
        self.set_field("STATUS", "APPLY_PENDING", pending)

    def shadow_config(self) -> CoreConfig:
        """The parameter set software has written, whether or not applied."""
        return read_config(self.get)

    def _latch(self) -> None:
        """APPLY: take the shadow set if it is valid, else keep the old one and flag CONFIG_ERROR."""
        cfg = self.shadow_config()
        try:
            check_frame_size(cfg.width, cfg.height, self.max_width, self.max_height)
            if cfg.left.problems() or cfg.right.problems():
                raise CoreParamsError("a parameter is outside its register's range")
            if cfg.lb_delay >= self.max_height:
                raise CoreParamsError("LB_DELAY beyond the frame")
        except CoreParamsError:
            self.raise_bits("FLAGS", RECTIFY_MAP["FLAGS"].bit("CONFIG_ERROR"))
        else:
            self.active = cfg
        self.set_field("CONTROL", "APPLY", 0)
        self._update_status()

    # -- datapath -----------------------------------------------------------------------
    def process(self, frame: np.ndarray) -> Optional[np.ndarray]:
        """One input frame from the mux; the output frame, or None if the core emits none.

        Called by the fabric's frame thread. Parameter latching and flag
        updates happen under the register lock; the pixel work does not.
        """
        with self.lock:
            control = CoreControl.read(self.get)
            if not control.enable:
                return None
            if control.apply:
                self._latch()
            cfg = self.active
            if cfg is None:  # never applied: frames pass through
                control = replace(control, bypass=True)
            width = cfg.width if cfg else RECTIFY_MAP["WIDTH"].reset
            height = cfg.height if cfg else RECTIFY_MAP["HEIGHT"].reset
            lb_delay = cfg.lb_delay if cfg else 0
            fit = fit_frame(frame.shape, width, height, lb_delay, control.bypass)
            if fit.size_error:
                self.raise_bits("FLAGS", RECTIFY_MAP["FLAGS"].bit("SIZE_ERROR"))
            if fit.dropped:
                self.frames_dropped += 1
                return None
            options = control.options(lb_rows=self.lb_rows, lb_delay=lb_delay, colour=self.colour)
            model = self._model(cfg, width, height, options)
            self.set_field("STATUS", "BUSY", 1)
        try:
            result = model.process(np.ascontiguousarray(padded(frame, width, height)),
                                   rows=fit.rows if fit.size_error else None)
        finally:
            with self.lock:
                self.set_field("STATUS", "BUSY", 0)
        with self.lock:
            if result.lb_overflow:
                self.raise_bits("FLAGS", RECTIFY_MAP["FLAGS"].bit("LB_OVERFLOW"))
            self.set("FRAME_COUNT", (self.get("FRAME_COUNT") + 1) & 0xFFFFFFFF)
            if self.get_field("CONTROL", "APPLY"):  # written while this frame was in flight
                self._latch()
        return result.frame

    def _model(self, cfg: Optional[CoreConfig], width: int, height: int,
               options: CoreOptions) -> RectifyModel:
        key = (cfg, width, height, options)
        model = self._models.get(key)
        if model is None:
            if cfg is None:  # bypass: the parameters are not used
                dummy = identity_registers(width, height)
                model = RectifyModel(dummy, dummy, width, height, options)
            else:
                model = RectifyModel(cfg.left, cfg.right, width, height, options)
            if len(self._models) > 4:
                self._models.clear()
            self._models[key] = model
        return model
