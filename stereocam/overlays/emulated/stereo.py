"""Behavioural model of the stereo core: its register block, and its output computed on demand.

Registers follow :data:`STEREO_MAP` (identity, build, shadow parameters latched by APPLY at the
next frame start, CONFIG_ERROR keeping the previous parameters, SIZE_ERROR, FRAME_COUNT); the
datapath is the bit-exact model (``overlays/model/stereo.py``) on the rectified gray pair.

The board's core streams every frame into its own frame store; here a frame is only noted
(the rectify core's output, by reference, with the parameters active for it), and its beats are
computed the first time software reads that store. A frame nobody reads costs nothing, which
keeps the emulation's CPU bounded, and what a read returns is what the core would have written.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

import numpy as np

from ..model.stereo import compute
from ..spec import pixel
from ..spec.regs import Register
from ..spec.stereo import (
    DEFAULT_BUILD,
    PARAM_REGISTERS,
    STEREO_MAP,
    Build,
    StereoParams,
    params_from_registers,
    size_problems,
)
from .regblock import RegisterBlock

LEFT_Y = pixel.LEFT.start + pixel.Y
RIGHT_Y = pixel.RIGHT.start + pixel.Y


@dataclass(frozen=True)
class _Noted:
    """One frame the core took: the rectified frame (not copied, never written) and its parameters."""

    frame: np.ndarray
    params: StereoParams
    number: int


class EmulatedStereoCore(RegisterBlock):
    """The stereo core as built (``build``); :meth:`take` on every rectified frame, :meth:`output` to read."""

    def __init__(self, build: Build = DEFAULT_BUILD, *, name: str = "stereo") -> None:
        self.build = build
        super().__init__(STEREO_MAP, name)
        self.active = params_from_registers({reg: self.get(reg) for reg in (*PARAM_REGISTERS.values(),
                                                                              "CONTROL")})
        self.active_size: Tuple[int, int] = (self.get("WIDTH"), self.get("HEIGHT"))
        self._noted: Dict[int, _Noted] = {}
        self._computed: Dict[int, Tuple[int, np.ndarray]] = {}  # store -> (frame number, beats)
        self._compute_lock = threading.Lock()
        self.computed_frames = 0  # frames whose beats were computed: tests check reads are lazy

    def reset_registers(self) -> None:
        super().reset_registers()
        self.set("MAX_WIDTH", self.build.max_width)
        self.set("MAX_HEIGHT", self.build.max_height)
        self.set("MAX_DISP", self.build.max_disp)
        self.set("PARALLEL", self.build.parallel)

    # -- registers ----------------------------------------------------------------------
    def on_write(self, reg: Register, old: int, written: int) -> None:
        control = STEREO_MAP["CONTROL"]
        if reg.name == "CONTROL":
            if control.get(old, "APPLY") and not control.get(written, "APPLY"):
                self.set_field("CONTROL", "APPLY", 1)  # writing 0 does not cancel a pending APPLY
            if control.get(written, "APPLY") and not self.get_field("CONTROL", "ENABLE"):
                self._latch()  # disabled: no frame start to wait for
        self.set_field("STATUS", "APPLY_PENDING", self.get_field("CONTROL", "APPLY"))

    def shadow_params(self) -> StereoParams:
        return params_from_registers({reg: self.get(reg) for reg in (*PARAM_REGISTERS.values(), "CONTROL")})

    def _latch(self) -> None:
        """APPLY: take the shadow set if the core accepts it, else keep the old one and flag CONFIG_ERROR."""
        params = self.shadow_params()
        size = (self.get_field("WIDTH", "VALUE"), self.get_field("HEIGHT", "VALUE"))
        if params.problems(self.build) or size_problems(*size, self.build):
            self.raise_bits("FLAGS", STEREO_MAP["FLAGS"].bit("CONFIG_ERROR"))
        else:
            self.active, self.active_size = params, size
        self.set_field("CONTROL", "APPLY", 0)
        self.set_field("STATUS", "APPLY_PENDING", 0)

    # -- datapath -----------------------------------------------------------------------
    def take(self, frame: np.ndarray, store: int) -> bool:
        """A frame start: latch a pending APPLY, note the rectified ``(H, W, 8)`` frame for ``store``.

        Called by the fabric's frame thread with the frame the processed channel wrote to
        ``store`` (the stereo core's channel is genlocked to it). False when the core emits
        nothing for it (disabled, or a frame of the wrong size: SIZE_ERROR).
        """
        with self.lock:
            if not self.get_field("CONTROL", "ENABLE"):
                return False
            if self.get_field("CONTROL", "APPLY"):
                self._latch()
            if (frame.shape[1], frame.shape[0]) != self.active_size:
                self.raise_bits("FLAGS", STEREO_MAP["FLAGS"].bit("SIZE_ERROR"))
                self._noted.pop(store, None)
                return False
            number = (self.get("FRAME_COUNT") + 1) & 0xFFFFFFFF
            self.set("FRAME_COUNT", number)
            self._noted[store] = _Noted(frame, self.active, number)
            return True

    def output(self, store: int) -> Optional[np.ndarray]:
        """The ``(H, W)`` uint32 beats in ``store`` (computed now if nobody read them yet); None if none.

        Blocks while the model runs; the array is the core's store: copy it, never write it.
        """
        with self.lock:
            noted = self._noted.get(store)
        if noted is None:
            return None
        with self._compute_lock:
            done = self._computed.get(store)
            if done is not None and done[0] == noted.number:
                return done[1]
            f = noted.frame
            beats = compute(np.ascontiguousarray(f[..., LEFT_Y]), np.ascontiguousarray(f[..., RIGHT_Y]),
                            noted.params).beats()
            beats.setflags(write=False)
            self._computed[store] = (noted.number, beats)
            self.computed_frames += 1
            return beats

    # -- its output channel (DepthStores): the stores are the core's own, nothing to start --------
    def start(self, width: int, height: int) -> None:
        """Frames of another size than the core's WIDTH x HEIGHT set SIZE_ERROR (as on the board)."""

    def stop(self) -> None:
        """The last frames stay readable, as a stopped VDMA's stores do."""

    def close(self) -> None:
        with self.lock:
            self._noted.clear()
        with self._compute_lock:
            self._computed.clear()

    def frame_number(self, store: int) -> Optional[int]:
        """FRAME_COUNT of the frame in ``store`` (None if none): tells a fresh store from an old one."""
        with self.lock:
            noted = self._noted.get(store)
        return None if noted is None else noted.number
