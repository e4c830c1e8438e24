"""AXI Video DMA v6.3 register table (Xilinx PG020), shared by the VDMA driver and its emulation.

One table describes both channels of the IP: MM2S (memory to stream, the
"read" channel; our virtual camera) and S2MM (stream to memory, the "write"
channel; raw and processed frame capture). Offsets, fields, access kinds and
reset values follow PG020 v6.3, chapter 2 "Register Space" (Table 2-5,
"Register Address Map", and the per-register tables 2-6 to 2-22).

Notes on how PG020 maps onto :mod:`.regs`:

* PG020's "R/WC" (read, write 1 to clear) is :attr:`Access.W1C`.
* ``VDMACR.Reset`` is :attr:`Access.SC`: it reads 1 while the soft reset is
  in progress and drops to 0 when the channel's registers are back at their
  reset values (PG020, VDMACR bit 2).
* The frame-store start addresses are banked: offsets 0x5C..0x98 (MM2S) and
  0xAC..0xE8 (S2MM) hold 16 registers; ``*_REG_INDEX.RegIndex`` selects
  whether they reach stores 1-16 (0) or 17-32 (1) (PG020, "Start Addresses").
  The table names the 16 offsets ``<CH>_START_ADDRESS1..16``; use
  :func:`start_address` to find the register and bank of a store.
* The FRMSTORE/debug registers (0x18, 0x48, ...) exist only with
  ``C_ENABLE_DEBUG_INFO_*`` and are not part of this table: the number of
  frame stores comes from the overlay metadata (``C_NUM_FSTORES``).
* Our overlay's stream is 64 bits wide (one stereo pixel per beat, see
  :mod:`.pixel`), so ``HSIZE`` and ``STRIDE`` are multiples of 8 bytes.
"""

from __future__ import annotations

from typing import Dict, List, Tuple

from .pixel import BYTES_PER_PIXEL
from .regs import Access, Field, Register, RegisterMap

VLNV = ("xilinx.com:ip:axi_vdma:6.2", "xilinx.com:ip:axi_vdma:6.3")
SUPPORTED_MAJOR = 6  # VDMA_VERSION.Major the driver accepts
EMULATED_VERSION = (6, 0x30, 0)  # (Major, Minor, Revision) the emulator reports: v6.3 rev 0

CHANNELS = ("MM2S", "S2MM")
MAX_FSTORES = 32  # PG020: C_NUM_FSTORES is 1..32
BANK_SIZE = 16  # start-address registers reachable per REG_INDEX bank
STREAM_BYTES = BYTES_PER_PIXEL  # bytes per beat of our 64-bit video stream

MAX_VSIZE = (1 << 13) - 1  # VSIZE[12:0]
MAX_HSIZE = (1 << 16) - 1  # HSIZE[15:0], bytes
MAX_STRIDE = (1 << 16) - 1  # FRMDLY_STRIDE.Stride[15:0], bytes

# Error flags of each channel's VDMASR, in bit order. The first three halt the
# channel and are read-only: only a soft reset clears them (PG020 Table 2-7 and
# 2-12: "VDMA channel halts"). The others are sticky W1C frame-size errors.
FATAL_ERRORS = ("VDMAIntErr", "VDMASlvErr", "VDMADecErr")
ERROR_FIELDS: Dict[str, Tuple[str, ...]] = {
    "MM2S": FATAL_ERRORS + ("SOFEarlyErr",),
    "S2MM": FATAL_ERRORS + ("SOFEarlyErr", "EOLEarlyErr", "SOFLateErr", "EOLLateErr"),
}
# S2MM_VDMA_IRQ_MASK bit that keeps each frame-size error from raising Err_Irq.
S2MM_IRQ_MASK_OF = {
    "SOFEarlyErr": "IRQMaskSOFEarlyErr",
    "EOLEarlyErr": "IRQMaskEOLEarlyErr",
    "SOFLateErr": "IRQMaskSOFLateErr",
    "EOLLateErr": "IRQMaskEOLLateErr",
}

# PARK_PTR_REG fields of each channel: the store to park on (RW) and the store
# the channel is operating on (RO).
PARK_REF = {"MM2S": "RdFrmPtrRef", "S2MM": "WrFrmPtrRef"}
PARK_STORE = {"MM2S": "RdFrmStore", "S2MM": "WrFrmStore"}

BASE = {"MM2S": 0x00, "S2MM": 0x30}  # VDMACR/VDMASR/REG_INDEX block of each channel
ADDR_BASE = {"MM2S": 0x50, "S2MM": 0xA0}  # VSIZE/HSIZE/FRMDLY_STRIDE/START_ADDRESS block


def _vdmacr(ch: str) -> Register:
    """PG020 Table 2-6 (MM2S_VDMACR, 00h) and Table 2-11 (S2MM_VDMACR, 30h)."""
    pntr = "RdPntrNum" if ch == "MM2S" else "WrPntrNum"
    return Register(
        f"{ch}_VDMACR",
        BASE[ch] + 0x00,
        Access.RW,
        reset=0x0001_0000,
        fields=(
            Field("RS", 0, doc="run/stop: 1 runs the channel; 0 halts it after the current frame"),
            Field("Circular_Park", 1, doc="1 = circular through all frame stores, 0 = park on PARK_PTR_REG"),
            Field("Reset", 2, access=Access.SC, doc="soft reset of this channel; reads 1 until done"),
            Field("GenlockEn", 3, doc="genlock synchronisation with the other channel"),
            Field("FrameCntEn", 4, doc="halt after IRQFrameCount frames"),
            Field("FsyncSrcSelect", 5, 2, doc="frame sync source"),
            Field("GenlockSrc", 7, doc="1 = internal genlock"),
            Field(pntr, 8, 4, doc="genlock master to follow"),
            Field("FrmCnt_IrqEn", 12, doc="interrupt on frame count"),
            Field("DlyCnt_IrqEn", 13, doc="interrupt on delay count"),
            Field("Err_IrqEn", 14, doc="interrupt on error"),
            Field("Repeat_En", 15, doc="repeat the previous frame on frame errors (genlock master)"),
            Field("IRQFrameCount", 16, 8, doc="frames per FrmCnt_Irq; writing 0 sets 1"),
            Field("IRQDelayCount", 24, 8, doc="delay-timer interrupt threshold; 0 disables"),
        ),
        doc=f"{ch} VDMA control register (PG020)",
    )


def _vdmasr(ch: str) -> Register:
    """PG020 Table 2-7 (MM2S_VDMASR, 04h) and Table 2-12 (S2MM_VDMASR, 34h)."""
    fields = [
        Field("Halted", 0, access=Access.RO, doc="1 = channel halted (RS=0 and idle, or a fatal error)"),
        Field("VDMAIntErr", 4, access=Access.RO, doc="internal error (e.g. HSIZE/VSIZE 0); halts"),
        Field("VDMASlvErr", 5, access=Access.RO, doc="AXI slave error on the memory side; halts"),
        Field("VDMADecErr", 6, access=Access.RO, doc="address decode error (no memory there); halts"),
        Field("SOFEarlyErr", 7, access=Access.W1C, doc="start of frame arrived before VSIZE lines"),
    ]
    if ch == "S2MM":
        fields += [
            Field("EOLEarlyErr", 8, access=Access.W1C, doc="end of line before HSIZE bytes"),
            Field("SOFLateErr", 11, access=Access.W1C, doc="more than VSIZE lines before start of frame"),
        ]
    fields += [
        Field("FrmCnt_Irq", 12, access=Access.W1C, doc="IRQFrameCount frames completed"),
        Field("DlyCnt_Irq", 13, access=Access.W1C, doc="delay timer expired"),
        Field("Err_Irq", 14, access=Access.W1C, doc="an error was detected"),
    ]
    if ch == "S2MM":
        fields.append(Field("EOLLateErr", 15, access=Access.W1C, doc="line longer than HSIZE bytes"))
    fields += [
        Field("IRQFrameCntSts", 16, 8, access=Access.RO, doc="frames left before the next FrmCnt_Irq"),
        Field("IRQDelayCntSts", 24, 8, access=Access.RO, doc="current delay-timer value"),
    ]
    return Register(
        f"{ch}_VDMASR",
        BASE[ch] + 0x04,
        Access.RO,
        reset=0x0001_0001,
        fields=tuple(fields),
        doc=f"{ch} VDMA status register (PG020)",
    )


def _reg_index(ch: str) -> Register:
    """PG020 "MM2S_REG_INDEX" (14h) and "S2MM_REG_INDEX" (44h)."""
    return Register(
        f"{ch}_REG_INDEX",
        BASE[ch] + 0x14,
        Access.RW,
        0,
        fields=(Field("RegIndex", 0, doc="0: start addresses 1-16, 1: 17-32"),),
    )


def _frame_registers(ch: str) -> List[Register]:
    """PG020 Tables 2-15..2-22: VSIZE, HSIZE, FRMDLY_STRIDE and START_ADDRESS1..16."""
    base = ADDR_BASE[ch]
    regs = [
        Register(
            f"{ch}_VSIZE",
            base + 0x0,
            Access.RW,
            0,
            fields=(Field("VSIZE", 0, 13, doc="lines per frame; writing it (last) starts the transfers"),),
        ),
        Register(
            f"{ch}_HSIZE", base + 0x4, Access.RW, 0, fields=(Field("HSIZE", 0, 16, doc="bytes per line"),)
        ),
        Register(
            f"{ch}_FRMDLY_STRIDE",
            base + 0x8,
            Access.RW,
            0x0100_0000,
            fields=(
                Field("Stride", 0, 16, doc="bytes between the first pixels of two lines"),
                Field("FrameDelay", 24, 5, doc="genlock slave frame delay"),
            ),
        ),
    ]
    for i in range(BANK_SIZE):
        regs.append(
            Register(
                f"{ch}_START_ADDRESS{i + 1}",
                base + 0xC + 4 * i,
                Access.RW,
                0,
                doc=f"{ch} frame store {i + 1} (or {i + 17} with REG_INDEX=1) start address",
            )
        )
    return regs


VDMA_MAP = RegisterMap(
    "axi_vdma",
    [
        _vdmacr("MM2S"),
        _vdmasr("MM2S"),
        _reg_index("MM2S"),
        Register(
            "PARK_PTR_REG",
            0x28,
            Access.RW,
            0,
            fields=(
                Field("RdFrmPtrRef", 0, 5, doc="MM2S store to park on"),
                Field("WrFrmPtrRef", 8, 5, doc="S2MM store to park on"),
                Field("RdFrmStore", 16, 5, access=Access.RO, doc="store MM2S is operating on"),
                Field("WrFrmStore", 24, 5, access=Access.RO, doc="store S2MM is operating on"),
            ),
            doc="park pointers and current frame stores of both channels (PG020 Table 2-9)",
        ),
        Register(
            "VDMA_VERSION",
            0x2C,
            Access.RO,
            reset=(EMULATED_VERSION[0] << 28) | (EMULATED_VERSION[1] << 20) | (EMULATED_VERSION[2] << 16),
            fields=(
                Field("XilinxInternal", 0, 16),
                Field("Revision", 16, 4),
                Field("Minor", 20, 8, doc="two BCD digits"),
                Field("Major", 28, 4),
            ),
            doc="IP version (PG020 Table 2-10)",
        ),
        _vdmacr("S2MM"),
        _vdmasr("S2MM"),
        Register(
            "S2MM_VDMA_IRQ_MASK",
            0x3C,
            Access.RW,
            0,
            fields=tuple(Field(name, bit) for bit, name in enumerate(S2MM_IRQ_MASK_OF.values())),
            doc="1 keeps a frame-size error from raising Err_Irq (PG020 Table 2-13)",
        ),
        _reg_index("S2MM"),
        *_frame_registers("MM2S"),
        *_frame_registers("S2MM"),
    ],
    size=0x1_0000,
    doc="Xilinx AXI VDMA v6.3 (PG020), register direct mode, both channels",
)


def reg(channel: str, suffix: str) -> Register:
    """The register ``<channel>_<suffix>``, e.g. ``reg("S2MM", "VDMACR")``."""
    if channel not in CHANNELS:
        raise KeyError(f"VDMA channel must be one of {CHANNELS}, not {channel!r}")
    return VDMA_MAP[f"{channel}_{suffix}"]


def start_address(channel: str, store: int) -> Tuple[int, Register]:
    """``(REG_INDEX bank, START_ADDRESS register)`` that holds frame store ``store`` (0-based)."""
    if not 0 <= store < MAX_FSTORES:
        raise ValueError(f"frame store {store} is outside 0..{MAX_FSTORES - 1}")
    return store // BANK_SIZE, reg(channel, f"START_ADDRESS{store % BANK_SIZE + 1}")
