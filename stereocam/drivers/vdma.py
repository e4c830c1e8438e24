"""Driver for the Xilinx AXI VDMA v6.x (PG020), register direct mode, both channels.

Why not ``pynq.lib.video.AxiVDMA``: its polls have no timeout (a VDMA whose
stream stopped hangs the caller forever), it writes magic numbers, and its
frame hand-off assumes four stores. This driver is the same few sequences,
written from the register table (:mod:`stereocam.overlays.spec.vdma`), with
every poll bounded (:func:`~stereocam.drivers.mmio.wait_for`) and every
failure a named exception.

Sequences (exact register accesses are pinned by ``tests/drivers/test_vdma_driver.py``):

``start``   soft reset (write ``VDMACR.Reset``, poll until it clears), then
            PG020's register-direct programming sequence: park pointer,
            ``VDMACR`` with ``RS=1`` (poll ``VDMASR.Halted`` to 0),
            ``START_ADDRESS1..N`` (``REG_INDEX`` banks beyond 16 stores),
            ``FRMDLY_STRIDE``, ``HSIZE``, and ``VSIZE`` last, which starts
            the transfers.
``stop``    ``RS=0`` (read-modify-write), poll ``Halted`` to 1. The channel
            finishes the frame in flight first.
``reset``   ``Reset=1``, poll until it reads 0; the channel is halted with
            every register at its reset value.
``recover`` stop (a channel that does not halt is reset anyway), reset,
            write 1 to every W1C status bit, then the start sequence with
            the previous configuration and buffers.

Frame ownership: the buffers of a channel belong to the DMA while it runs.
``S2MMChannel.latest_completed`` returns the most recently *completed*
store (never the one ``WrFrmStore`` names, which is in flight); its buffer
stays valid for about ``num_fstores - 1`` frame periods, until the channel
comes round to it again, so copy what you keep. ``MM2SChannel.write_frame``
copies into a store the channel is neither reading nor about to read, then
parks the channel on it. Buffers the driver allocated are freed by
:meth:`VDMA.close`; buffers passed to ``start`` stay the caller's.

Each channel serialises its own calls with a lock, and the read-modify-write
of the shared ``PARK_PTR_REG`` is serialised across channels, so the two
channels may be driven from different threads.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Dict, Optional, Sequence, Tuple

import numpy as np

from ..overlays.spec.vdma import (
    BANK_SIZE,
    CHANNELS,
    ERROR_FIELDS,
    FATAL_ERRORS,
    MAX_FSTORES,
    MAX_HSIZE,
    MAX_STRIDE,
    MAX_VSIZE,
    PARK_REF,
    PARK_STORE,
    STREAM_BYTES,
    SUPPORTED_MAJOR,
    VDMA_MAP,
    reg,
    start_address,
)
from .mmio import (
    Allocator,
    DriverError,
    RegisterRangeError,
    Registers,
    RegisterTimeout,
    RegisterWindow,
    UnsupportedIP,
)

ADDRESS_LIMIT = 1 << 32  # 32-bit start-address registers


class VDMAError(DriverError):
    """Base of the VDMA driver's errors."""


class ChannelNotStarted(VDMAError):
    """The operation needs a channel this driver has started."""


class ChannelFault(VDMAError):
    """The channel reports errors that stop it (``errors`` lists them)."""

    def __init__(self, message: str, errors: Tuple[str, ...]) -> None:
        super().__init__(message)
        self.errors = errors


class NoFrameYet(VDMAError):
    """No frame has completed since the channel was started."""


class FrameShapeError(VDMAError, ValueError):
    """A frame or buffer does not match the channel's ``(height, width, 8)`` uint8 layout."""


@dataclass(frozen=True)
class ChannelConfig:
    """What ``start`` programmed: restored as is by ``recover``."""

    width: int  # pixels (8-byte beats) per line
    height: int  # lines
    circular: bool
    stride: int  # bytes between line starts
    addresses: Tuple[int, ...]  # physical start address of each frame store

    @property
    def hsize(self) -> int:
        return self.width * STREAM_BYTES


@dataclass(frozen=True)
class Recovery:
    """What ``recover`` found: the errors before it acted and whether the channel halted on its own."""

    errors: Tuple[str, ...]
    halted_cleanly: bool


class _Channel:
    """One VDMA channel; use :class:`S2MMChannel` or :class:`MM2SChannel` through :class:`VDMA`."""

    def __init__(self, vdma: "VDMA", name: str) -> None:
        self.vdma = vdma
        self.name = name
        self.regs = vdma.regs
        self.CR = reg(name, "VDMACR")
        self.SR = reg(name, "VDMASR")
        self.num_fstores = vdma.num_fstores
        self.lock = threading.RLock()
        self.config: Optional[ChannelConfig] = None
        self.buffers: Tuple[Any, ...] = ()
        self.parked: Optional[int] = None  # the store a parked channel was told to show (kept by recover)
        self._owned = False  # buffers allocated (and to be freed) by the driver

    def __repr__(self) -> str:
        return f"<{self.vdma.name} {self.name} {self.config}>"

    def _timeout(self, timeout: Optional[float]) -> float:
        return self.vdma.timeout if timeout is None else timeout

    def _require_config(self) -> ChannelConfig:
        if self.config is None:
            raise ChannelNotStarted(f"{self.vdma.name} {self.name}: channel not started; call start() first")
        return self.config

    # -- status -------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        """True while ``VDMASR.Halted`` is 0."""
        return not self.regs.field(self.SR.name, "Halted")

    def _errors_in(self, sr: int) -> Tuple[str, ...]:
        return tuple(e for e in ERROR_FIELDS[self.name] if self.SR.get(sr, e))

    def errors(self) -> Tuple[str, ...]:
        """Names of the error flags set in ``VDMASR``, in bit order; empty when healthy.

        ``VDMAIntErr``, ``VDMASlvErr`` and ``VDMADecErr`` halt the channel
        and only a reset clears them (:meth:`recover`); the frame-size errors
        are sticky W1C flags (:meth:`clear_errors`).
        """
        return self._errors_in(self.regs.read(self.SR.name))

    def _w1c_word(self) -> int:
        return self.SR.encode(**{e: 1 for e in ERROR_FIELDS[self.name] if e not in FATAL_ERRORS}, Err_Irq=1)

    def clear_errors(self) -> Tuple[str, ...]:
        """Write 1 to the W1C error flags and ``Err_Irq``; return the errors still set (the fatal ones)."""
        with self.lock:
            self.regs.write(self.SR.name, self._w1c_word())
            return self.errors()

    def current_store(self) -> int:
        """The store ``PARK_PTR_REG`` says the channel operates on (in flight while running)."""
        return self.regs.field("PARK_PTR_REG", PARK_STORE[self.name])

    # -- lifecycle ----------------------------------------------------------------------
    def start(
        self,
        width: int,
        height: int,
        *,
        buffers: Optional[Sequence[Any]] = None,
        circular: bool = True,
        timeout: Optional[float] = None,
    ) -> None:
        """(Re)start the channel on ``num_fstores`` frame buffers of ``(height, width, 8)`` uint8.

        ``buffers`` (one per store, in DMA-able memory) stay the caller's;
        without them the driver allocates its own (reused across restarts
        of the same size, freed by :meth:`VDMA.close`). ``circular`` walks
        the stores in turn; otherwise the channel parks on store 0. Blocks
        for the soft reset and for ``Halted`` to clear, each at most
        ``timeout`` seconds (:class:`RegisterTimeout`).
        """
        if isinstance(width, bool) or isinstance(height, bool):
            raise TypeError("width and height are pixel counts")
        width, height = int(width), int(height)
        if not 1 <= height <= MAX_VSIZE:
            raise RegisterRangeError(
                f"{self.vdma.name} {self.name}: height {height} is outside 1..{MAX_VSIZE} (VSIZE)"
            )
        if not 1 <= width * STREAM_BYTES <= MAX_HSIZE:
            raise RegisterRangeError(
                f"{self.vdma.name} {self.name}: width {width} is outside 1..{MAX_HSIZE // STREAM_BYTES} "
                f"({STREAM_BYTES}-byte pixels, HSIZE)"
            )
        given = None if buffers is None else self._check_buffers(buffers, width, height)
        with self.lock:
            self.reset(timeout)
            self.parked = None
            if given is not None:
                self._free_owned()
                self.buffers, self._owned = given, False
            elif not (
                self._owned
                and self.buffers
                and self.buffers[0].shape == (height, width, STREAM_BYTES)
                and not any(getattr(b, "freed", False) for b in self.buffers)
            ):
                self._free_owned()
                self.buffers = tuple(
                    self.vdma.allocator((height, width, STREAM_BYTES), np.uint8)
                    for _ in range(self.num_fstores)
                )
                self._owned = True
                self._check_buffers(self.buffers, width, height)
            stride = int(self.buffers[0].strides[0])
            addresses = tuple(int(b.physical_address) for b in self.buffers)
            self._program(ChannelConfig(width, height, bool(circular), stride, addresses), timeout)

    def _check_buffers(self, buffers: Sequence[Any], width: int, height: int) -> Tuple[Any, ...]:
        bufs = tuple(buffers)
        where = f"{self.vdma.name} {self.name}"
        if len(bufs) != self.num_fstores:
            raise FrameShapeError(
                f"{where}: {len(bufs)} buffers given, the VDMA has {self.num_fstores} frame stores"
            )
        strides = {int(b.strides[0]) for b in bufs}
        for i, b in enumerate(bufs):
            if b.shape != (height, width, STREAM_BYTES) or b.dtype != np.uint8:
                raise FrameShapeError(
                    f"{where}: buffer {i} is {b.shape} {b.dtype}, "
                    f"expected ({height}, {width}, {STREAM_BYTES}) uint8"
                )
            if b.strides[1:] != (STREAM_BYTES, 1):
                raise FrameShapeError(f"{where}: buffer {i} must have contiguous lines (strides {b.strides})")
            address = int(b.physical_address)
            if address % STREAM_BYTES or not 0 <= address < ADDRESS_LIMIT:
                raise RegisterRangeError(
                    f"{where}: buffer {i} at {address:#x} is not an {STREAM_BYTES}-byte aligned "
                    "32-bit address"
                )
        if len(strides) != 1:
            raise FrameShapeError(f"{where}: all buffers need the same line stride, got {sorted(strides)}")
        stride = strides.pop()
        if stride % STREAM_BYTES or not width * STREAM_BYTES <= stride <= MAX_STRIDE:
            raise RegisterRangeError(
                f"{where}: line stride {stride} must be a multiple of {STREAM_BYTES} "
                f"in {width * STREAM_BYTES}..{MAX_STRIDE}"
            )
        return bufs

    def _program(self, cfg: ChannelConfig, timeout: Optional[float]) -> None:
        """PG020 register-direct start: park pointer, RS=1, addresses, stride, HSIZE, VSIZE last."""
        self._set_park_ref(0)
        self.regs.write(
            self.CR.name,
            self.CR.encode(
                RS=1, Circular_Park=int(cfg.circular), FrmCnt_IrqEn=1, Err_IrqEn=1, IRQFrameCount=1
            ),
        )
        self.regs.wait(
            self.SR.name,
            lambda v: not self.SR.get(v, "Halted"),
            expected="cleared Halted after RS=1 (fatal error pending, or the IP is not clocked?)",
            timeout=self._timeout(timeout),
        )
        banked = self.num_fstores > BANK_SIZE
        index = reg(self.name, "REG_INDEX")
        for store, address in enumerate(cfg.addresses):
            bank, start = start_address(self.name, store)
            if banked and store % BANK_SIZE == 0:
                self.regs.write(index.name, index.encode(RegIndex=bank))
            self.regs.write(start.name, address)
        if banked:
            self.regs.write(index.name, index.encode(RegIndex=0))
        stride = reg(self.name, "FRMDLY_STRIDE")
        self.regs.write(stride.name, stride.encode(stride.reset, Stride=cfg.stride))
        hsize = reg(self.name, "HSIZE")
        self.regs.write(hsize.name, hsize.encode(HSIZE=cfg.hsize))
        vsize = reg(self.name, "VSIZE")
        self.regs.write(vsize.name, vsize.encode(VSIZE=cfg.height))
        self.config = cfg
        self._forget_frames()

    def _forget_frames(self) -> None:
        """Hook: the channel was reset or (re)started; frames seen before are gone."""

    def stop(self, timeout: Optional[float] = None) -> None:
        """Clear ``RS`` and wait (at most ``timeout`` s) for ``Halted``; idempotent.

        The channel finishes its frame in flight first, so this takes up to
        one frame period while the stream runs. The configuration is kept
        for :meth:`recover` and the buffers for reading.
        """
        with self.lock:
            self.regs.modify(self.CR.name, RS=0)
            self.regs.wait(
                self.SR.name,
                lambda v: bool(self.SR.get(v, "Halted")),
                expected="set Halted after RS=0 (the frame in flight never finished?)",
                timeout=self._timeout(timeout),
            )

    def reset(self, timeout: Optional[float] = None) -> None:
        """Soft-reset the channel: write ``VDMACR.Reset`` and wait for it to clear itself.

        Afterwards the channel is halted and all its registers hold their
        reset values (error flags included). Keeps the configuration.
        """
        with self.lock:
            self.regs.write(self.CR.name, self.CR.encode(Reset=1))
            self._wait_reset(timeout)

    def _wait_reset(self, timeout: Optional[float]) -> None:
        with self.lock:
            self._forget_frames()
            self.regs.wait(
                self.CR.name,
                lambda v: not self.CR.get(v, "Reset"),
                expected="cleared Reset (soft reset never completed)",
                timeout=self._timeout(timeout),
            )

    def resetting(self) -> bool:
        """True while a soft reset is in progress (``VDMACR.Reset`` reads 1)."""
        return bool(self.regs.field(self.CR.name, "Reset"))

    def recover(self, timeout: Optional[float] = None) -> Recovery:
        """Get a faulted channel running again with its previous configuration and buffers.

        Stop, soft reset, clear the W1C status bits, start again; a parked
        channel is parked again on the store it showed. A channel
        that does not halt within ``timeout`` is reset regardless (the
        returned :class:`Recovery` says so); a reset that does not complete
        raises :class:`RegisterTimeout`.
        """
        with self.lock:
            cfg = self._require_config()
            errors = self.errors()
            if self.resetting():  # an earlier reset timed out: the IP takes no write until it ends
                self._wait_reset(timeout)
                halted = False
            else:
                try:
                    self.stop(timeout)
                    halted = True
                except RegisterTimeout:
                    halted = False  # the reset below ends whatever the channel was doing
                self.reset(timeout)
            self.regs.write(self.SR.name, self._w1c_word())
            self._program(cfg, timeout)
            if not cfg.circular and self.parked is not None:  # the reset parked it on store 0
                self._set_park_ref(self.parked)
            return Recovery(errors, halted)

    def _set_park_ref(self, store: int) -> None:
        park = VDMA_MAP["PARK_PTR_REG"]
        with self.vdma.park_lock:
            word = self.regs.read(park.name)
            refs = {f: park.get(word, f) for f in PARK_REF.values()}
            refs[PARK_REF[self.name]] = store
            self.regs.write(park.name, park.encode(**refs))

    def park(self, store: int) -> None:
        """Park the channel on ``store`` (from the next frame on): it stops walking the stores."""
        with self.lock:
            cfg = self._require_config()
            if not 0 <= store < self.num_fstores:
                raise RegisterRangeError(
                    f"{self.vdma.name} {self.name}: store {store} is outside 0..{self.num_fstores - 1}"
                )
            self._set_park_ref(store)
            self.parked = store
            if cfg.circular:
                self.regs.modify(self.CR.name, Circular_Park=0)
                self.config = ChannelConfig(cfg.width, cfg.height, False, cfg.stride, cfg.addresses)

    def _free_owned(self) -> None:
        if self._owned:
            for b in self.buffers:
                b.freebuffer()
            self.buffers, self._owned = (), False

    def close(self, timeout: Optional[float] = None) -> None:
        """Stop a started channel and free the buffers the driver allocated."""
        with self.lock:
            if self.config is not None:
                self.stop(timeout)
                self.config = None
            self._free_owned()


class S2MMChannel(_Channel):
    """Stream to memory: frames from the fabric land in the frame stores."""

    def __init__(self, vdma: "VDMA", name: str = "S2MM") -> None:
        super().__init__(vdma, name)
        self._have_frame = False

    def _forget_frames(self) -> None:
        self._have_frame = False

    def latest_completed(self) -> Tuple[int, Any]:
        """``(store, buffer)`` of the most recently completed frame; does not block.

        Never the store in flight: while the channel runs that is
        ``WrFrmStore``, so the latest complete one is the store before it;
        once halted, ``WrFrmStore`` itself has completed. Raises
        :class:`NoFrameYet` before the first frame completes,
        :class:`ChannelFault` after a fatal error, and :class:`VDMAError`
        in park mode or with one store (every store is then in flight).
        The buffer is invalidated for the CPU; see the module docstring for
        how long it stays valid.
        """
        with self.lock:
            cfg = self._require_config()
            where = f"{self.vdma.name} S2MM"
            if not cfg.circular or self.num_fstores < 2:
                raise VDMAError(
                    f"{where}: frames can only be read in circular mode with 2 or more stores "
                    f"(the parked or only store is always being written)"
                )
            sr = self.regs.read(self.SR.name)
            fatal = tuple(e for e in self._errors_in(sr) if e in FATAL_ERRORS)
            if fatal:
                raise ChannelFault(f"{where} halted on {', '.join(fatal)}; call recover()", fatal)
            if self.SR.get(sr, "FrmCnt_Irq"):
                self._have_frame = True
            if not self._have_frame:
                raise NoFrameYet(f"{where}: no frame has completed since start")
            current = self.current_store()
            store = current if self.SR.get(sr, "Halted") else (current - 1) % self.num_fstores
            buf = self.buffers[store]
            buf.invalidate()
            return store, buf

    def wait_frame(self, timeout: Optional[float] = None, *, fresh: bool = False) -> Tuple[int, Any]:
        """Block until a frame completes, then return :meth:`latest_completed`.

        Waits on ``FrmCnt_Irq`` (set at every completed frame; sticky) and
        acknowledges it, so consecutive calls return consecutive or newer
        frames. With ``fresh`` the flag is cleared first, so the frame
        returned completed after the call (it may have *started* before:
        call twice for a frame that started after). Raises
        :class:`RegisterTimeout` naming ``S2MM_VDMASR`` if nothing completes
        within ``timeout`` s, :class:`ChannelFault` if the channel halts.
        """
        with self.lock:
            self._require_config()
            irq = self.SR.encode(FrmCnt_Irq=1)
            if fresh:
                self.regs.write(self.SR.name, irq)
            sr = self.regs.wait(
                self.SR.name,
                lambda v: bool(self.SR.get(v, "FrmCnt_Irq") or self.SR.get(v, "Halted")),
                expected="set FrmCnt_Irq (no frame completed: is the stream running, the channel started?)",
                timeout=self._timeout(timeout),
            )
            if not self.SR.get(sr, "FrmCnt_Irq"):
                errors = self._errors_in(sr)
                raise ChannelFault(
                    f"{self.vdma.name} S2MM halted while waiting for a frame"
                    f"{' on ' + ', '.join(errors) if errors else ' (stopped)'}",
                    errors,
                )
            self.regs.write(self.SR.name, irq)
            self._have_frame = True
            return self.latest_completed()


class MM2SChannel(_Channel):
    """Memory to stream: the virtual camera, streaming the store it is parked on."""

    def __init__(self, vdma: "VDMA", name: str = "MM2S") -> None:
        super().__init__(vdma, name)

    def write_frame(self, frame: np.ndarray, timeout: Optional[float] = None) -> int:
        """Copy ``frame`` into a free store and park the channel on it; returns the store.

        The store chosen is neither the one being read (``RdFrmStore``) nor
        the one the channel would read next (``RdFrmPtrRef``), so nothing
        tears; with two stores and a switch still pending this waits (at
        most ``timeout`` s) for the channel to pick it up. A circular
        channel is switched to park mode. The frame is on the stream from
        the next frame period; :meth:`wait_parked` waits for that.
        """
        with self.lock:
            cfg = self._require_config()
            where = f"{self.vdma.name} MM2S"
            frame = np.asarray(frame)
            if frame.shape != (cfg.height, cfg.width, STREAM_BYTES) or frame.dtype != np.uint8:
                raise FrameShapeError(
                    f"{where}: frame is {frame.shape} {frame.dtype}, expected "
                    f"({cfg.height}, {cfg.width}, {STREAM_BYTES}) uint8"
                )
            if self.num_fstores < 2:
                raise VDMAError(f"{where}: needs 2 or more frame stores to change frames without tearing")
            park = VDMA_MAP["PARK_PTR_REG"]
            with self.vdma.park_lock:
                ptr = self.regs.read(park.name)
                target = self._free_store(ptr)
                if target is None:
                    ptr = self.regs.wait(
                        park.name,
                        lambda v: park.get(v, "RdFrmStore") == park.get(v, "RdFrmPtrRef"),
                        expected="showed RdFrmStore == RdFrmPtrRef (MM2S never reached its park store)",
                        timeout=self._timeout(timeout),
                    )
                    target = self._free_store(ptr)
                    assert target is not None
                buf = self.buffers[target]
                np.copyto(buf, frame)
                buf.flush()
                self.regs.write(
                    park.name, park.encode(RdFrmPtrRef=target, WrFrmPtrRef=park.get(ptr, "WrFrmPtrRef"))
                )
                self.parked = target
            if cfg.circular:
                self.regs.modify(self.CR.name, Circular_Park=0)
                self.config = ChannelConfig(cfg.width, cfg.height, False, cfg.stride, cfg.addresses)
            return target

    def _free_store(self, ptr: int) -> Optional[int]:
        park = VDMA_MAP["PARK_PTR_REG"]
        ref, reading = park.get(ptr, "RdFrmPtrRef"), park.get(ptr, "RdFrmStore")
        for i in range(1, self.num_fstores + 1):
            store = (ref + i) % self.num_fstores
            if store not in (ref, reading):
                return store
        return None

    def wait_parked(self, timeout: Optional[float] = None) -> int:
        """Block (at most ``timeout`` s) until the channel reads the store it is parked on; return it."""
        with self.lock:
            self._require_config()
            park = VDMA_MAP["PARK_PTR_REG"]
            ptr = self.regs.wait(
                park.name,
                lambda v: park.get(v, "RdFrmStore") == park.get(v, "RdFrmPtrRef"),
                expected="showed RdFrmStore == RdFrmPtrRef (is the MM2S channel running?)",
                timeout=self._timeout(timeout),
            )
            return park.get(ptr, "RdFrmStore")


class VDMA:
    """One AXI VDMA: ``s2mm`` and ``mm2s`` channels over a register window.

    ``window`` is the IP's register window (``pynq.MMIO`` or an emulated
    block); ``allocator`` makes frame buffers (``pynq.allocate`` or an
    ``EmulatedDDR``). ``num_fstores`` and ``addr_width`` come from the
    overlay metadata (``C_NUM_FSTORES``, ``C_M_AXI_*_ADDR_WIDTH``). The
    constructor reads ``VDMA_VERSION`` and refuses anything but v6.x.
    """

    def __init__(
        self,
        window: RegisterWindow,
        allocator: Allocator,
        *,
        num_fstores: int,
        name: str = "vdma",
        timeout: float = 1.0,
        addr_width: int = 32,
    ) -> None:
        if (
            isinstance(num_fstores, bool)
            or not isinstance(num_fstores, int)
            or not 1 <= num_fstores <= MAX_FSTORES
        ):
            raise UnsupportedIP(
                f"{name}: C_NUM_FSTORES={num_fstores!r}; an AXI VDMA has 1..{MAX_FSTORES} frame stores"
            )
        if addr_width != 32:
            raise UnsupportedIP(
                f"{name}: {addr_width}-bit addressing is not supported (32-bit start addresses only)"
            )
        self.name = name
        self.num_fstores = num_fstores
        self.allocator = allocator
        self.timeout = timeout
        self.regs = Registers(window, VDMA_MAP, name)
        self.park_lock = threading.RLock()  # PARK_PTR_REG is shared by both channels
        version = self.regs.read("VDMA_VERSION")
        fields = VDMA_MAP["VDMA_VERSION"].decode(version)
        if fields["Major"] != SUPPORTED_MAJOR:
            raise UnsupportedIP(
                f"{name}: VDMA_VERSION reads {version:#010x} (major {fields['Major']}); this driver drives "
                f"AXI VDMA v{SUPPORTED_MAJOR}.x: is there a VDMA at this address?"
            )
        self.version = (fields["Major"], fields["Minor"], fields["Revision"])
        self.s2mm = S2MMChannel(self)
        self.mm2s = MM2SChannel(self)

    @property
    def channels(self) -> Dict[str, _Channel]:
        return {"MM2S": self.mm2s, "S2MM": self.s2mm}

    def close(self, timeout: Optional[float] = None) -> None:
        """Stop both channels (if started) and free the buffers the driver allocated."""
        for ch in CHANNELS:
            self.channels[ch].close(timeout)

    def __enter__(self) -> "VDMA":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
