"""Behavioural model of the rectify core's register block and datapath.

Registers follow :data:`RECTIFY_MAP`; the datapath is the fast model, so the
emulated fabric is bit-exact to the model by construction and the tests can
concentrate on the register behaviour: shadow parameters latched by APPLY at
a frame start, sticky W1C flags, refusal of out-of-range parameter sets, a
frame counter, and dropping frames of the wrong size.
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from ..model.config import ConfigError, check_frame_size, check_params
from ..model.fast import RectifyModel
from ..model.result import CoreOptions
from ..spec.rectify import (
    CAMERAS,
    DEFAULT_LB_ROWS,
    DEFAULT_MAX_HEIGHT,
    DEFAULT_MAX_WIDTH,
    PARAM_NAMES,
    RECTIFY_MAP,
    CameraParams,
    CoreConfig,
    words_to_f64,
)
from ..spec.regs import Register
from .regblock import RegisterBlock


class EmulatedRectifyCore(RegisterBlock):
    """The core as built with ``max_width`` x ``max_height`` and ``lb_rows`` buffered rows."""

    def __init__(
        self, *, max_width: int = DEFAULT_MAX_WIDTH, max_height: int = DEFAULT_MAX_HEIGHT,
        lb_rows: int = DEFAULT_LB_ROWS, name: str = "rectify",
    ) -> None:
        self.max_width = max_width
        self.max_height = max_height
        self.lb_rows = lb_rows
        super().__init__(RECTIFY_MAP, name)
        self.active: Optional[CoreConfig] = None  # None: never applied, frames pass through
        self._models: Dict[Tuple[object, ...], RectifyModel] = {}
        self.frames_dropped = 0

    def reset_registers(self) -> None:
        super().reset_registers()
        self.set("MAX_WIDTH", self.max_width)
        self.set("MAX_HEIGHT", self.max_height)
        self.set("LB_ROWS", self.lb_rows)

    # -- registers ----------------------------------------------------------------------
    def on_write(self, reg: Register, old: int, written: int) -> None:
        if reg.name == "CONTROL" and RECTIFY_MAP["CONTROL"].get(written, "APPLY"):
            # Idle core: latch at once. Running core: at the next frame start.
            if not self.get_field("CONTROL", "ENABLE"):
                self._latch()
        self._update_status()

    def _update_status(self) -> None:
        pending = self.get_field("CONTROL", "APPLY")
        self.set_field("STATUS", "APPLY_PENDING", pending)

    def shadow_config(self) -> CoreConfig:
        """The parameter set software has written, whether or not applied."""
        cams = {}
        for cam in CAMERAS:
            values = {n: words_to_f64(self.get(f"{cam}_{n}_LO"), self.get(f"{cam}_{n}_HI")) for n in PARAM_NAMES}
            cams[cam] = CameraParams.from_values(values)
        return CoreConfig(
            cams["L"], cams["R"],
            self.get_field("WIDTH", "VALUE"), self.get_field("HEIGHT", "VALUE"), self.get_field("LB_DELAY", "VALUE"),
        )

    def _latch(self) -> None:
        """APPLY: take the shadow set if it is valid, else keep the old one and flag CONFIG_ERROR."""
        cfg = self.shadow_config()
        try:
            check_frame_size(cfg.width, cfg.height, self.max_width, self.max_height)
            check_params(cfg.left, cfg.right)
            if cfg.lb_delay >= self.max_height:
                raise ConfigError("LB_DELAY beyond the frame")
        except ConfigError:
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
            control = RECTIFY_MAP["CONTROL"].decode(self.get("CONTROL"))
            if not control["ENABLE"]:
                return None
            if control["APPLY"]:
                self._latch()
            cfg = self.active
            width = cfg.width if cfg else self.get_field("WIDTH", "VALUE")
            height = cfg.height if cfg else self.get_field("HEIGHT", "VALUE")
            if frame.shape != (height, width, 8):
                self.raise_bits("FLAGS", RECTIFY_MAP["FLAGS"].bit("SIZE_ERROR"))
                self.frames_dropped += 1
                return None
            options = CoreOptions(
                lb_rows=self.lb_rows,
                lb_delay=cfg.lb_delay if cfg else 0,
                gray=bool(control["GRAY"]),
                bypass=bool(control["BYPASS"]) or cfg is None,
                debug_row=self.get_field("DEBUG_ROW", "VALUE") if control["DEBUG_LINE"] else None,
            )
            model = self._model(cfg, width, height, options)
            self.set_field("STATUS", "BUSY", 1)
        try:
            result = model.process(frame)
        finally:
            with self.lock:
                self.set_field("STATUS", "BUSY", 0)
        with self.lock:
            if result.lb_overflow:
                self.raise_bits("FLAGS", RECTIFY_MAP["FLAGS"].bit("LB_OVERFLOW"))
            self.set("FRAME_COUNT", (self.get("FRAME_COUNT") + 1) & 0xFFFFFFFF)
        return result.frame

    def _model(self, cfg: Optional[CoreConfig], width: int, height: int, options: CoreOptions) -> RectifyModel:
        key = (cfg, width, height, options)
        model = self._models.get(key)
        if model is None:
            if cfg is None:
                dummy = CameraParams((1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0), 1.0, 1.0, 0, 0, 0, 0, 0, 0)
                model = RectifyModel(dummy, dummy, width, height, options)
            else:
                model = RectifyModel(cfg.left, cfg.right, width, height, options)
            if len(self._models) > 4:
                self._models.clear()
            self._models[key] = model
        return model
