"""Behavioural model of the Xilinx AXI VDMA v6.3 (PG020) in register direct mode.

Registers follow :data:`~stereocam.overlays.spec.vdma.VDMA_MAP`. What is
modelled (PG020 section references in brackets):

* Reset values; ``VDMASR.Halted`` is 1 while ``VDMACR.RS`` is 0 [Table 2-7].
* ``RS=1`` makes the channel run (Halted drops at once) but it moves no
  data until ``VSIZE`` is written [Programming Sequence, "Register Direct
  Mode": VSIZE is written last and starts the transfers]. A VSIZE written
  while the channel is halted is stored and starts nothing. A VSIZE
  written while started reloads: the new sizes, addresses and park
  pointers apply from the next frame, the frame-store sequence continues.
* ``RS=0`` stops the channel after the frame in flight: Halted rises after
  ``settle_reads`` register reads (bus time) or at the next frame tick,
  whichever comes first; the frame in flight then counts as completed.
  A channel with no frame in flight halts at once.
* ``VDMACR.Reset`` (self-clearing) aborts the frame in flight, halts the
  channel and reads 1 for ``settle_reads`` register reads; then every
  register of that channel (and its half of PARK_PTR_REG) is back at its
  reset value and the bit reads 0. Writing that channel's registers while
  the reset is in progress raises: poll ``Reset`` first.
* ``IRQFrameCount`` frames completed raise ``FrmCnt_Irq`` (W1C);
  ``IRQFrameCntSts`` counts down; writing IRQFrameCount 0 stores 1; with
  ``FrameCntEn`` the channel halts (RS cleared) when the count is reached.
* Errors: a frame store whose 2-D extent is not inside one live DDR
  allocation gives ``VDMADecErr``; HSIZE or VSIZE 0, or an HSIZE that is
  not a whole number of 8-byte beats, at start gives ``VDMAIntErr``. Both
  are fatal: RS is cleared, the channel halts, the frame is lost and only a
  soft reset clears the bit. An S2MM frame with fewer/more lines than VSIZE
  gives ``SOFEarlyErr``/``SOFLateErr``, with shorter/longer lines than
  HSIZE ``EOLEarlyErr``/``EOLLateErr`` (sticky W1C, not fatal; the
  overlapping part of the frame is written). Every error raises
  ``Err_Irq`` unless masked in ``S2MM_VDMA_IRQ_MASK``.
* Circular mode walks the stores 0, 1, ..., N-1, 0, ... starting at store 0
  after each start; park mode uses ``RdFrmPtrRef``/``WrFrmPtrRef`` at each
  frame start. ``RdFrmStore``/``WrFrmStore`` report the store of the frame
  in flight (or the last one, once halted).
* Start-address registers are banked by ``REG_INDEX``; touching one beyond
  ``num_fstores``, or parking on a store that does not exist, raises.

The stream side, called by the fabric once per frame tick:

``s2mm_accept(frame)``: first the frame in flight (if any) completes (it is
now the *latest completed* store), then the channel advances to the next
store (circular) or the park store, and the new frame is written there at
the programmed START_ADDRESS/HSIZE/STRIDE. That store is *in flight* until
the next tick: ``WrFrmStore`` names it and software must not read it. The
most recently completed store is therefore ``WrFrmStore - 1`` (mod N) in
circular mode while running, and ``WrFrmStore`` itself once halted.

``mm2s_fetch()`` works the same way: it completes the previous frame,
advances (or re-reads the park store) and returns the new store's contents,
which are "being sent" until the next tick.

Thread-safe through the block's lock; the pixel copy happens under it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Set, Tuple, TypeVar

import numpy as np

from ..spec.regs import Register
from ..spec.vdma import (
    BANK_SIZE,
    CHANNELS,
    FATAL_ERRORS,
    MAX_FSTORES,
    PARK_REF,
    PARK_STORE,
    S2MM_IRQ_MASK_OF,
    STREAM_BYTES,
    VDMA_MAP,
)
from .ddr import DecodeError, EmulatedDDR
from .regblock import EmulationError, RegisterBlock

HANGS = ("reset", "halt", "run")  # what a test can make a channel never finish
_T = TypeVar("_T")


@dataclass
class ChannelState:
    """The hardware state of one channel that registers do not hold, plus test counters.

    Counters survive resets: ``frames`` counts frames moved (S2MM: written
    to DDR, MM2S: read from DDR), ``completed_frames`` frames completed,
    ``dropped`` frame ticks the channel refused (not running or started).
    """

    name: str
    addresses: List[int] = field(default_factory=lambda: [0] * MAX_FSTORES)
    started: bool = False
    inflight: Optional[int] = None  # store of the frame in flight
    last: Optional[int] = None  # store of the most recent frame (sequence position)
    completed: Optional[int] = None  # store of the most recently completed frame
    frame_counter: int = 1  # IRQFrameCntSts
    halt_countdown: Optional[int] = None
    reset_countdown: Optional[int] = None
    hangs: Set[str] = field(default_factory=set)
    injected: Optional[str] = None  # tests: a fatal error raised on every frame the channel starts
    frames: int = 0
    completed_frames: int = 0
    dropped: int = 0

    def clear(self) -> None:
        self.addresses = [0] * MAX_FSTORES
        self.started = False
        self.inflight = self.last = self.completed = None
        self.frame_counter = 1
        self.halt_countdown = self.reset_countdown = None


class EmulatedVDMA(RegisterBlock):
    """An AXI VDMA with both channels and ``num_fstores`` frame stores, moving frames in ``ddr``."""

    def __init__(
        self, ddr: EmulatedDDR, num_fstores: int = 3, name: str = "vdma", *, settle_reads: int = 3
    ) -> None:
        if not 1 <= num_fstores <= MAX_FSTORES:
            raise ValueError(f"an AXI VDMA has 1..{MAX_FSTORES} frame stores, not {num_fstores}")
        if settle_reads < 1:
            raise ValueError("settle_reads must be at least 1")
        self.ddr = ddr
        self.num_fstores = num_fstores
        self.settle_reads = settle_reads
        self.channels: Dict[str, ChannelState] = {ch: ChannelState(ch) for ch in CHANNELS}
        self._where: Dict[int, Tuple[str, str, int]] = {}
        for ch in CHANNELS:
            for reg in VDMA_MAP:
                if reg.name.startswith(ch + "_"):
                    kind = reg.name[len(ch) + 1 :]
                    index = 0
                    if kind.startswith("START_ADDRESS"):
                        index = int(kind[len("START_ADDRESS") :]) - 1
                        kind = "START_ADDRESS"
                    self._where[reg.offset] = (ch, kind, index)
        super().__init__(VDMA_MAP, name)

    @property
    def mm2s(self) -> ChannelState:
        return self.channels["MM2S"]

    @property
    def s2mm(self) -> ChannelState:
        return self.channels["S2MM"]

    @property
    def frames_written(self) -> int:
        """Frames the S2MM channel has written to DDR."""
        return self.s2mm.frames

    @property
    def frames_read(self) -> int:
        """Frames the MM2S channel has read from DDR."""
        return self.mm2s.frames

    def hang(self, channel: str, what: str, hang: bool = True) -> None:
        """Make a channel's soft ``reset``, its ``halt`` after RS=0 or its ``run`` after RS=1 never finish."""
        if what not in HANGS:
            raise ValueError(f"can hang one of {HANGS}, not {what!r}")
        hangs = self.channels[channel].hangs
        if hang:
            hangs.add(what)
        else:
            hangs.discard(what)

    def inject(self, channel: str, error: Optional[str]) -> None:
        """Fault injection: raise the fatal ``error`` on every frame ``channel`` starts (None: stop).

        Like a bus error that persists (a slave that keeps answering SLVERR,
        an address that stays undecoded): every restart of the channel halts
        again on its next frame until the fault ends.
        """
        if error is not None and error not in FATAL_ERRORS:
            raise ValueError(f"can inject one of {FATAL_ERRORS}, not {error!r}")
        with self.lock:
            self.channels[channel].injected = error

    def interrupt(self, channel: str) -> bool:
        """Level of the channel's interrupt output (``mm2s_introut``/``s2mm_introut``)."""
        with self.lock:
            sr = VDMA_MAP[f"{channel}_VDMASR"].decode(self.get(f"{channel}_VDMASR"))
            cr = VDMA_MAP[f"{channel}_VDMACR"].decode(self.get(f"{channel}_VDMACR"))
            return bool(
                (sr["FrmCnt_Irq"] and cr["FrmCnt_IrqEn"])
                or (sr["DlyCnt_Irq"] and cr["DlyCnt_IrqEn"])
                or (sr["Err_Irq"] and cr["Err_IrqEn"])
            )

    # -- registers ----------------------------------------------------------------------
    def reset_registers(self) -> None:
        with self.lock:
            super().reset_registers()
            for ch in self.channels.values():
                ch.clear()

    def _reset_channel(self, ch: ChannelState) -> None:
        for reg in VDMA_MAP:
            if reg.name.startswith(ch.name + "_"):
                self.values[reg.offset] = reg.reset
        self.set_field("PARK_PTR_REG", PARK_REF[ch.name], 0)
        self.set_field("PARK_PTR_REG", PARK_STORE[ch.name], 0)
        ch.clear()

    def _bus_time(self) -> None:
        """One register read worth of time: pending resets and halts make progress."""
        for ch in self.channels.values():
            if ch.reset_countdown is not None and "reset" not in ch.hangs:
                ch.reset_countdown -= 1
                if ch.reset_countdown <= 0:
                    self._reset_channel(ch)
            if ch.halt_countdown is not None and "halt" not in ch.hangs:
                ch.halt_countdown -= 1
                if ch.halt_countdown <= 0:
                    self._halt(ch)

    def read(self, offset: int, length: int = 4) -> int:
        with self.lock:
            self._bus_time()
            return super().read(offset, length)

    def on_read(self, reg: Register, stored: int) -> int:
        where = self._where.get(reg.offset)
        if where is not None and where[1] == "START_ADDRESS":
            ch = self.channels[where[0]]
            return ch.addresses[self._store_of(ch, where[2])]
        return stored

    def _store_of(self, ch: ChannelState, index: int) -> int:
        return self.get_field(f"{ch.name}_REG_INDEX", "RegIndex") * BANK_SIZE + index

    def write(self, offset: int, value: int) -> None:
        with self.lock:
            where = self._where.get(offset)
            if where is not None:
                ch = self.channels[where[0]]
                reg = self.map.at(offset)
                assert reg is not None
                if ch.reset_countdown is not None:
                    raise EmulationError(
                        f"{self.ip}: write of {int(value):#x} to {reg.name} while the {ch.name} soft reset "
                        f"is in progress; poll {ch.name}_VDMACR.Reset until it reads 0 first"
                    )
                if where[1] == "START_ADDRESS":
                    store = self._store_of(ch, where[2])
                    if store >= self.num_fstores:
                        raise EmulationError(
                            f"{self.ip}: {reg.name} with REG_INDEX={store // BANK_SIZE} is frame store "
                            f"{store + 1}, but this VDMA has {self.num_fstores} frame stores (C_NUM_FSTORES)"
                        )
            elif offset == VDMA_MAP.offset("PARK_PTR_REG"):
                refs = VDMA_MAP["PARK_PTR_REG"].decode(int(value))
                for ref in PARK_REF.values():
                    if refs[ref] >= self.num_fstores:
                        raise EmulationError(
                            f"{self.ip}: PARK_PTR_REG.{ref}={refs[ref]}, but this VDMA has "
                            f"{self.num_fstores} frame stores (0..{self.num_fstores - 1})"
                        )
            super().write(offset, value)

    def on_write(self, reg: Register, old: int, written: int) -> None:
        where = self._where.get(reg.offset)
        if where is None:
            return
        ch = self.channels[where[0]]
        kind = where[1]
        if kind == "VDMACR":
            self._on_control(ch, reg, old, written)
        elif kind == "VSIZE":
            self._on_vsize(ch)
        elif kind == "START_ADDRESS":
            ch.addresses[self._store_of(ch, where[2])] = written & 0xFFFFFFFF

    def _on_control(self, ch: ChannelState, reg: Register, old: int, written: int) -> None:
        if reg.get(written, "Reset"):
            ch.reset_countdown = self.settle_reads
            ch.started = False
            ch.inflight = None
            ch.halt_countdown = None
            self.set_field(f"{ch.name}_VDMASR", "Halted", 1)
            return
        count = reg.get(written, "IRQFrameCount")
        if count == 0:
            self.set_field(reg.name, "IRQFrameCount", 1)
            count = 1
        if count != reg.get(old, "IRQFrameCount"):
            ch.frame_counter = count
            self.set_field(f"{ch.name}_VDMASR", "IRQFrameCntSts", count)
        run_old, run_new = reg.get(old, "RS"), reg.get(written, "RS")
        if run_new and not run_old:
            self._run(ch)
        elif run_old and not run_new:
            self._stop(ch)

    def _sr(self, ch: ChannelState) -> Dict[str, int]:
        return VDMA_MAP[f"{ch.name}_VDMASR"].decode(self.get(f"{ch.name}_VDMASR"))

    def _run(self, ch: ChannelState) -> None:
        sr = self._sr(ch)
        if any(sr[e] for e in FATAL_ERRORS) or "run" in ch.hangs:
            return  # a fatal error keeps the channel halted until a soft reset
        self.set_field(f"{ch.name}_VDMASR", "Halted", 0)
        ch.started = False
        ch.inflight = ch.last = None
        ch.halt_countdown = None

    def _stop(self, ch: ChannelState) -> None:
        if ch.inflight is not None:
            ch.halt_countdown = self.settle_reads
        else:
            self._halt(ch)

    def _halt(self, ch: ChannelState) -> None:
        """The channel comes to rest: the frame in flight completes, Halted rises."""
        ch.halt_countdown = None
        self._complete(ch)
        self.set_field(f"{ch.name}_VDMASR", "Halted", 1)
        ch.started = False

    def _running(self, ch: ChannelState) -> bool:
        return (
            ch.reset_countdown is None
            and ch.halt_countdown is None
            and bool(self.get_field(f"{ch.name}_VDMACR", "RS"))
            and not self.get_field(f"{ch.name}_VDMASR", "Halted")
        )

    def _on_vsize(self, ch: ChannelState) -> None:
        if not self._running(ch):
            return  # stored; a halted channel starts nothing
        hsize = self.get_field(f"{ch.name}_HSIZE", "HSIZE")
        vsize = self.get_field(f"{ch.name}_VSIZE", "VSIZE")
        if hsize == 0 or vsize == 0 or hsize % STREAM_BYTES:
            self._fatal(ch, "VDMAIntErr")
            return
        ch.started = True

    # -- errors and frame accounting ----------------------------------------------------
    def _fatal(self, ch: ChannelState, error: str) -> None:
        sr = VDMA_MAP[f"{ch.name}_VDMASR"]
        self.raise_bits(sr.name, sr.bit(error) | sr.bit("Err_Irq"))
        self.set_field(f"{ch.name}_VDMACR", "RS", 0)
        self.set_field(sr.name, "Halted", 1)
        ch.started = False
        ch.inflight = None
        ch.halt_countdown = None

    def _error(self, ch: ChannelState, error: str) -> None:
        sr = VDMA_MAP[f"{ch.name}_VDMASR"]
        bits = sr.bit(error)
        masked = ch.name == "S2MM" and self.get_field("S2MM_VDMA_IRQ_MASK", S2MM_IRQ_MASK_OF[error])
        if not masked:
            bits |= sr.bit("Err_Irq")
        self.raise_bits(sr.name, bits)

    def _complete(self, ch: ChannelState) -> None:
        if ch.inflight is None:
            return
        ch.completed, ch.inflight = ch.inflight, None
        ch.completed_frames += 1
        ch.frame_counter -= 1
        if ch.frame_counter <= 0:
            cr = f"{ch.name}_VDMACR"
            self.raise_bits(f"{ch.name}_VDMASR", VDMA_MAP[f"{ch.name}_VDMASR"].bit("FrmCnt_Irq"))
            ch.frame_counter = self.get_field(cr, "IRQFrameCount")
            if self.get_field(cr, "FrameCntEn"):
                self.set_field(cr, "RS", 0)
                self.set_field(f"{ch.name}_VDMASR", "Halted", 1)
                ch.started = False
                ch.halt_countdown = None
        self.set_field(f"{ch.name}_VDMASR", "IRQFrameCntSts", ch.frame_counter)

    def _begin_frame(self, ch: ChannelState) -> Optional[Tuple[int, np.ndarray]]:
        """Frame tick bookkeeping shared by both channels; the store and its DDR view, or None."""
        if ch.halt_countdown is not None and "halt" not in ch.hangs:
            self._halt(ch)
        if not (ch.started and self._running(ch)):
            ch.dropped += 1
            return None
        if ch.injected is not None:
            self._fatal(ch, ch.injected)
            ch.dropped += 1
            return None
        self._complete(ch)
        if not (ch.started and self._running(ch)):  # FrameCntEn reached its count
            ch.dropped += 1
            return None
        if self.get_field(f"{ch.name}_VDMACR", "Circular_Park"):
            store = 0 if ch.last is None else (ch.last + 1) % self.num_fstores
        else:
            store = self.get_field("PARK_PTR_REG", PARK_REF[ch.name])
        ch.last = store
        self.set_field("PARK_PTR_REG", PARK_STORE[ch.name], store)
        vsize = self.get_field(f"{ch.name}_VSIZE", "VSIZE")
        hsize = self.get_field(f"{ch.name}_HSIZE", "HSIZE")
        stride = self.get_field(f"{ch.name}_FRMDLY_STRIDE", "Stride")
        try:
            view = self.ddr.view2d(ch.addresses[store], vsize, hsize, max(stride, 1))
        except DecodeError:
            self._fatal(ch, "VDMADecErr")
            ch.dropped += 1
            return None
        return store, view

    # -- the stream side (called by the fabric once per frame tick) ---------------------
    def s2mm_accept(self, frame: np.ndarray) -> bool:
        """Write one incoming ``(H, W, 8)`` uint8 stream frame; False if the channel took none.

        See the module docstring for which store is in flight and which is
        completed after this call.
        """
        if frame.ndim != 3 or frame.shape[2] != STREAM_BYTES or frame.dtype != np.uint8:
            raise ValueError(
                f"a stream frame is (H, W, {STREAM_BYTES}) uint8, got {frame.shape} {frame.dtype}"
            )
        return self._frame_tick(self.s2mm, lambda dst: self._s2mm_write(frame, dst)) is not None

    def _s2mm_write(self, frame: np.ndarray, dst: np.ndarray) -> bool:
        """Copy ``frame`` into the store's view ``dst``, flagging a frame or lines of another size."""
        lines, line_bytes = frame.shape[0], frame.shape[1] * STREAM_BYTES
        vsize, hsize = dst.shape
        if lines < vsize:
            self._error(self.s2mm, "SOFEarlyErr")
        elif lines > vsize:
            self._error(self.s2mm, "SOFLateErr")
        if line_bytes < hsize:
            self._error(self.s2mm, "EOLEarlyErr")
        elif line_bytes > hsize:
            self._error(self.s2mm, "EOLLateErr")
        rows, cols = min(lines, vsize), min(line_bytes, hsize)
        dst[:rows, :cols] = frame.reshape(lines, line_bytes)[:rows, :cols]
        return True

    def mm2s_fetch(self) -> Optional[np.ndarray]:
        """Read the next outgoing frame as a ``(VSIZE, HSIZE // 8, 8)`` uint8 copy, or None if not running."""
        return self._frame_tick(self.mm2s, lambda src: np.array(src).reshape(
            src.shape[0], src.shape[1] // STREAM_BYTES, STREAM_BYTES))

    def _frame_tick(self, ch: ChannelState, move: Callable[[np.ndarray], _T]) -> Optional[_T]:
        """One frame of ``ch``: :meth:`_begin_frame` (None: the channel took no frame), ``move`` the
        frame into or out of its store's DDR view, then that store is in flight."""
        with self.lock:
            begun = self._begin_frame(ch)
            if begun is None:
                return None
            store, view = begun
            moved = move(view)
            ch.inflight = store
            ch.frames += 1
            return moved
