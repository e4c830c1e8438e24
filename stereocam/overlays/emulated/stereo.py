"""Behavioural model of the stereo core: its register block, and its output computed on demand.

Registers follow :data:`STEREO_MAP` (identity, build, shadow parameters latched by APPLY at the
next frame start, CONFIG_ERROR keeping the previous parameters, SIZE_ERROR, FRAME_COUNT); the
datapath is the bit-exact model (``overlays/model/stereo.py``) on the rectified gray pair.

The board's core streams every frame into its own frame store; here a frame is only noted
(the rectify core's output, by reference, with the parameters active for it), and its beats are
computed the first time software reads that store. A frame nobody reads costs nothing, which
keeps the emulation's CPU bounded, and what a read returns is what the core would have written.
The model runs on a thread of the emulated hardware (:data:`STEREO_THREAD`), not the reader's:
it is the fabric's work, which the daemon's CPU budget does not count.
"""
from __future__ import annotations

import concurrent.futures
import threading
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Tuple

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
from .regblock import EmulationError, RegisterBlock

STEREO_THREAD = "emulated-stereo"  # where the emulated core computes its output
LEFT_Y = pixel.LEFT.start + pixel.Y
RIGHT_Y = pixel.RIGHT.start + pixel.Y


@dataclass(frozen=True)
class _Noted:
    """One frame the core took: the rectified frame (not copied, never written) and its parameters."""

    frame: np.ndarray
    params: StereoParams
    number: int


class EmulatedStereoCore(RegisterBlock):
    """The stereo core as built (``build``); :meth:`accept` on every rectified frame, :meth:`take` to read."""

    def __init__(self, build: Build = DEFAULT_BUILD, *, name: str = "stereo") -> None:
        self.build = build
        super().__init__(STEREO_MAP, name)
        self.active = params_from_registers({reg: self.get(reg) for reg in (*PARAM_REGISTERS.values(),
                                                                              "CONTROL")})
        self.active_size: Tuple[int, int] = (self.get("WIDTH"), self.get("HEIGHT"))
        self._noted: Dict[int, _Noted] = {}
        self._computed: Dict[int, Tuple[int, np.ndarray]] = {}  # store -> (frame number, beats)
        self._compute_lock = threading.Lock()
        self._worker: Optional[concurrent.futures.ThreadPoolExecutor] = None  # made at the first read
        self._closed = False
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
    def accept(self, frame: np.ndarray, store: int) -> bool:
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

    def take(self, store: int) -> Optional[Callable[[], np.ndarray]]:
        """The frame in ``store`` now (None if none): a call that gives its ``(H, W)`` uint32 beats.

        The call computes them the first time anyone reads that frame (it blocks while the model
        runs) and hands the same read-only array to every later reader.
        """
        with self.lock:
            noted = self._noted.get(store)
        if noted is None:
            return None
        return lambda: self._beats(store, noted)

    def output(self, store: int) -> Optional[np.ndarray]:
        """The beats of the frame in ``store`` now (None if none): :meth:`take` and read at once."""
        take = self.take(store)
        return None if take is None else take()

    def _beats(self, store: int, noted: _Noted) -> np.ndarray:
        """Compute on :data:`STEREO_THREAD` and wait for it (blocks the reader meanwhile)."""
        with self.lock:
            if self._closed:
                raise EmulationError("the emulated stereo core was closed with its overlay: nothing to read")
            if self._worker is None:
                self._worker = concurrent.futures.ThreadPoolExecutor(
                    1, initializer=lambda: setattr(threading.current_thread(), "name", STEREO_THREAD))
            worker = self._worker
        return worker.submit(self._compute, store, noted).result()

    def _compute(self, store: int, noted: _Noted) -> np.ndarray:
        with self._compute_lock:
            done = self._computed.get(store)
            if done is not None and done[0] == noted.number:
                return done[1]
            # A reader late by more than the stores' round: computed again (the frame is kept with it).
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
            self._closed = True
            worker, self._worker = self._worker, None
        if worker is not None:
            worker.shutdown(wait=True)
        with self._compute_lock:
            self._computed.clear()

    def frame_number(self, store: int) -> Optional[int]:
        """FRAME_COUNT of the frame in ``store`` (None if none): tells a fresh store from an old one."""
        with self.lock:
            noted = self._noted.get(store)
        return None if noted is None else noted.number
