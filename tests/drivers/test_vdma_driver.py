"""The VDMA driver's delicate sequences, access by access (PG020 register-direct mode).

Values are built from the register table; the first tests pin the table
itself to PG020 and to the literal words pynq's driver writes, so the
sequences below are anchored to the datasheet, not to themselves.
"""

from __future__ import annotations

from typing import List, Tuple

import numpy as np
import pytest

from stereocam.drivers.mmio import RegisterRangeError, UnsupportedIP
from stereocam.drivers.vdma import (
    VDMA,
    ChannelFault,
    ChannelNotStarted,
    FrameShapeError,
    NoFrameYet,
    Recovery,
    VDMAError,
)
from stereocam.overlays.emulated.ddr import PAGE, EmulatedDDR
from stereocam.overlays.spec.vdma import VDMA_MAP, reg, start_address

from ..doubles import RecordingWindow

pytestmark = pytest.mark.armhf

Op = Tuple[str, int, int]
VERSION = 0x6300_0000  # v6.3
PARK = VDMA_MAP["PARK_PTR_REG"]
W, H = 4, 3  # 32-byte lines, 96-byte frames: one DDR page per store
DDR_BASE = 0x1000_0000


def cr(ch: str) -> int:
    return reg(ch, "VDMACR").offset


def sr(ch: str) -> int:
    return reg(ch, "VDMASR").offset


def sr_word(ch: str, **fields: int) -> int:
    return reg(ch, "VDMASR").encode(reg(ch, "VDMASR").reset, **fields)


# -- the table against PG020 and pynq ------------------------------------------------------
def test_register_offsets_follow_pg020_table_2_5() -> None:
    expected = {
        "MM2S_VDMACR": 0x00,
        "MM2S_VDMASR": 0x04,
        "MM2S_REG_INDEX": 0x14,
        "PARK_PTR_REG": 0x28,
        "VDMA_VERSION": 0x2C,
        "S2MM_VDMACR": 0x30,
        "S2MM_VDMASR": 0x34,
        "S2MM_VDMA_IRQ_MASK": 0x3C,
        "S2MM_REG_INDEX": 0x44,
        "MM2S_VSIZE": 0x50,
        "MM2S_HSIZE": 0x54,
        "MM2S_FRMDLY_STRIDE": 0x58,
        "MM2S_START_ADDRESS1": 0x5C,
        "MM2S_START_ADDRESS16": 0x98,
        "S2MM_VSIZE": 0xA0,
        "S2MM_HSIZE": 0xA4,
        "S2MM_FRMDLY_STRIDE": 0xA8,
        "S2MM_START_ADDRESS1": 0xAC,
        "S2MM_START_ADDRESS16": 0xE8,
    }
    assert {name: VDMA_MAP.offset(name) for name in expected} == expected
    assert start_address("S2MM", 17) == (1, VDMA_MAP["S2MM_START_ADDRESS2"])


def test_field_layout_reproduces_the_words_pynq_writes() -> None:
    s2mm_cr, mm2s_cr = reg("S2MM", "VDMACR"), reg("MM2S", "VDMACR")
    assert s2mm_cr.encode(RS=1, Circular_Park=1, GenlockSrc=1, FrmCnt_IrqEn=1, IRQFrameCount=1) == 0x0001_1083
    assert mm2s_cr.encode(RS=1, GenlockEn=1, GenlockSrc=1, FrmCnt_IrqEn=1, IRQFrameCount=1) == 0x0001_1089
    assert s2mm_cr.encode(Reset=1, GenlockSrc=1, FrmCnt_IrqEn=1, IRQFrameCount=1) == 0x0001_1084
    s2mm_sr = reg("S2MM", "VDMASR")
    assert s2mm_sr.encode(SOFEarlyErr=1, EOLEarlyErr=1, SOFLateErr=1, EOLLateErr=1) == 0x8980
    assert s2mm_sr.encode(VDMAIntErr=1, SOFEarlyErr=1, Err_Irq=1) == 0x4090
    assert s2mm_sr.bit("FrmCnt_Irq") == 0x1000 and s2mm_sr.bit("Halted") == 0x1
    assert [PARK.field(f).mask for f in ("RdFrmPtrRef", "WrFrmPtrRef", "RdFrmStore", "WrFrmStore")] == [
        0x1F,
        0x1F00,
        0x1F_0000,
        0x1F00_0000,
    ]
    version = VDMA_MAP["VDMA_VERSION"]
    assert [version.field(f).mask for f in ("Major", "Minor", "Revision")] == [
        0xF000_0000,
        0x0FF0_0000,
        0x000F_0000,
    ]
    assert VDMA_MAP["MM2S_VDMASR"].reset == 0x0001_0001  # Halted, IRQFrameCntSts = 1
    assert VDMA_MAP["S2MM_VDMACR"].reset == 0x0001_0000  # IRQFrameCount = 1
    assert "EOLLateErr" not in {f.name for f in VDMA_MAP["MM2S_VDMASR"].fields}


# -- construction ----------------------------------------------------------------------------
def make(num_fstores: int = 3, size: int = 64) -> Tuple[RecordingWindow, VDMA, EmulatedDDR]:
    win = RecordingWindow([("r", 0x2C, VERSION)])
    ddr = EmulatedDDR(DDR_BASE, size * PAGE)
    return win, VDMA(win, ddr, num_fstores=num_fstores, name="raw"), ddr


def test_constructor_binds_by_version_and_refuses_what_it_cannot_drive() -> None:
    win, vdma, _ = make()
    win.assert_done()
    assert vdma.version == (6, 0x30, 0)
    with pytest.raises(UnsupportedIP, match=r"raw: VDMA_VERSION reads 0x52454354 \(major 5\)"):
        VDMA(RecordingWindow([("r", 0x2C, 0x5245_4354)]), EmulatedDDR(), num_fstores=3, name="raw")
    for bad in (0, 33, True, 2.0):
        with pytest.raises(UnsupportedIP, match="1..32 frame stores"):
            VDMA(RecordingWindow(), EmulatedDDR(), num_fstores=bad)  # type: ignore[arg-type]
    with pytest.raises(UnsupportedIP, match="64-bit addressing"):
        VDMA(RecordingWindow(), EmulatedDDR(), num_fstores=3, addr_width=64)


def reset_ops(ch: str) -> List[Op]:
    """Soft reset: write Reset, poll VDMACR until the bit has cleared itself (here: one extra poll)."""
    reset = reg(ch, "VDMACR").encode(Reset=1)
    return [("w", cr(ch), reset), ("r", cr(ch), reset), ("r", cr(ch), reg(ch, "VDMACR").reset)]


def program_ops(
    ch: str,
    addresses: List[int],
    *,
    circular: bool,
    park_before: int,
    park_after: int,
    width: int = W,
    height: int = H,
) -> List[Op]:
    control = reg(ch, "VDMACR").encode(
        RS=1, Circular_Park=int(circular), FrmCnt_IrqEn=1, Err_IrqEn=1, IRQFrameCount=1
    )
    ops: List[Op] = [
        ("r", 0x28, park_before),
        ("w", 0x28, park_after),
        ("w", cr(ch), control),
        ("r", sr(ch), sr_word(ch)),  # still halted: poll again
        ("r", sr(ch), sr_word(ch, Halted=0)),
    ]
    banked = len(addresses) > 16
    for store, address in enumerate(addresses):
        bank, start = start_address(ch, store)
        if banked and store % 16 == 0:
            ops.append(("w", reg(ch, "REG_INDEX").offset, bank))
        ops.append(("w", start.offset, address))
    if banked:
        ops.append(("w", reg(ch, "REG_INDEX").offset, 0))
    ops += [
        ("w", reg(ch, "FRMDLY_STRIDE").offset, 0x0100_0000 | width * 8),  # PG020 default frame delay kept
        ("w", reg(ch, "HSIZE").offset, width * 8),
        ("w", reg(ch, "VSIZE").offset, height),  # last: starts the transfers
    ]
    return ops


def test_start_s2mm_circular_exact_sequence() -> None:
    win, vdma, ddr = make()
    win.expect(*reset_ops("S2MM"))
    # the MM2S park pointer (2) is preserved, S2MM's set to 0, read-only store fields not written back
    win.expect(
        *program_ops(
            "S2MM",
            [DDR_BASE, DDR_BASE + PAGE, DDR_BASE + 2 * PAGE],
            circular=True,
            park_before=PARK.encode(RdFrmPtrRef=2, WrFrmPtrRef=1, WrFrmStore=1, RdFrmStore=2),
            park_after=PARK.encode(RdFrmPtrRef=2),
        )
    )
    vdma.s2mm.start(W, H)
    win.assert_done()
    assert program_ops("S2MM", [0], circular=True, park_before=0, park_after=0)[2] == ("w", 0x30, 0x0001_5003)
    assert [b.shape for b in vdma.s2mm.buffers] == [(H, W, 8)] * 3
    assert vdma.s2mm.config is not None and vdma.s2mm.config.stride == 32
    assert ddr.num_buffers == 3


def test_start_mm2s_parked_exact_sequence_with_given_buffers() -> None:
    win, vdma, ddr = make()
    wide = ddr.allocate((3, H, 2 * W, 8))  # lines of 64 bytes, frames use the first 32
    buffers = [wide[i, :, :W] for i in range(3)]
    win.expect(*reset_ops("MM2S"))
    win.expect(
        *program_ops(
            "MM2S",
            [b.physical_address for b in buffers],
            circular=False,
            park_before=PARK.encode(WrFrmPtrRef=2),
            park_after=PARK.encode(WrFrmPtrRef=2),
        )
    )
    win.expected[-3] = ("w", 0x58, 0x0100_0000 | 64)  # stride from the buffers, not the width
    vdma.mm2s.start(W, H, buffers=buffers, circular=False)
    win.assert_done()
    assert program_ops("MM2S", [0], circular=False, park_before=0, park_after=0)[2] == (
        "w",
        0x00,
        0x0001_5001,
    )
    assert vdma.mm2s.buffers == tuple(buffers) and ddr.num_buffers == 1  # nothing allocated


def test_start_with_more_than_16_stores_switches_register_banks() -> None:
    win, vdma, _ = make(num_fstores=20)
    win.expect(*reset_ops("S2MM"))
    ops = program_ops(
        "S2MM", [DDR_BASE + i * PAGE for i in range(20)], circular=True, park_before=0, park_after=0
    )
    win.expect(*ops)
    vdma.s2mm.start(W, H)
    win.assert_done()
    index_writes = [op for op in ops if op[1] == 0x44]
    assert index_writes == [("w", 0x44, 0), ("w", 0x44, 1), ("w", 0x44, 0)]
    assert ("w", 0xAC, DDR_BASE + 16 * PAGE) in ops  # store 17 through START_ADDRESS1 in bank 1


@pytest.mark.parametrize("ch", ["MM2S", "S2MM"])
def test_stop_and_reset_exact_sequences(ch: str) -> None:
    win, vdma, _ = make()
    channel = vdma.channels[ch]
    running = reg(ch, "VDMACR").encode(RS=1, Circular_Park=1, FrmCnt_IrqEn=1, Err_IrqEn=1, IRQFrameCount=1)
    win.expect(
        ("r", cr(ch), running),
        ("w", cr(ch), running & ~1),  # only RS changes
        ("r", sr(ch), sr_word(ch, Halted=0)),  # finishing the frame in flight
        ("r", sr(ch), sr_word(ch)),
    )
    channel.stop()
    win.assert_done()
    win.expect(*reset_ops(ch))
    channel.reset()
    win.assert_done()


def started(ch: str = "S2MM", num_fstores: int = 3) -> Tuple[RecordingWindow, VDMA]:
    win, vdma, _ = make(num_fstores)
    win.expect(*reset_ops(ch))
    addresses = [DDR_BASE + i * PAGE for i in range(num_fstores)]
    win.expect(*program_ops(ch, addresses, circular=True, park_before=0, park_after=0))
    vdma.channels[ch].start(W, H)
    win.assert_done()
    return win, vdma


@pytest.mark.parametrize("ch, w1c", [("S2MM", 0xC980), ("MM2S", 0x4080)])
def test_recover_exact_sequence(ch: str, w1c: int) -> None:
    """Stop, reset, write 1 to every W1C error bit and Err_Irq, start again with the same config."""
    win, vdma = started(ch)
    faulted = sr_word(ch, VDMADecErr=1, Err_Irq=1)
    running_cr = reg(ch, "VDMACR").encode(Circular_Park=1, FrmCnt_IrqEn=1, Err_IrqEn=1, IRQFrameCount=1)
    win.expect(
        ("r", sr(ch), faulted),
        ("r", cr(ch), running_cr),  # no reset in progress (an earlier one that timed out is only awaited)
        ("r", cr(ch), running_cr),
        (
            "w",
            cr(ch),
            reg(ch, "VDMACR").encode(Circular_Park=1, FrmCnt_IrqEn=1, Err_IrqEn=1, IRQFrameCount=1),
        ),
        ("r", sr(ch), faulted),  # a fatal error already halted the channel
        *reset_ops(ch),
        ("w", sr(ch), w1c),
        *program_ops(
            ch, [DDR_BASE, DDR_BASE + PAGE, DDR_BASE + 2 * PAGE], circular=True, park_before=0, park_after=0
        ),
    )
    assert vdma.channels[ch].recover() == Recovery(("VDMADecErr",), True)
    win.assert_done()


def test_errors_and_clear_errors() -> None:
    win, vdma = started()
    win.expect(("r", 0x34, sr_word("S2MM", Halted=0, SOFEarlyErr=1, EOLLateErr=1, Err_Irq=1)))
    assert vdma.s2mm.errors() == ("SOFEarlyErr", "EOLLateErr")
    win.expect(("w", 0x34, 0xC980), ("r", 0x34, sr_word("S2MM", VDMASlvErr=1, Err_Irq=1)))
    assert vdma.s2mm.clear_errors() == ("VDMASlvErr",)  # fatal: only a reset clears it
    win.assert_done()


def test_latest_completed_is_never_the_store_in_flight() -> None:
    win, vdma = started()
    win.expect(("r", 0x34, sr_word("S2MM", Halted=0)))
    with pytest.raises(NoFrameYet, match="no frame has completed since start"):
        vdma.s2mm.latest_completed()
    win.expect(("r", 0x34, sr_word("S2MM", Halted=0, FrmCnt_Irq=1)), ("r", 0x28, PARK.encode(WrFrmStore=0)))
    store, buf = vdma.s2mm.latest_completed()
    assert store == 2 and buf is vdma.s2mm.buffers[2]  # store 0 is in flight
    win.expect(("r", 0x34, sr_word("S2MM")), ("r", 0x28, PARK.encode(WrFrmStore=1)))
    assert vdma.s2mm.latest_completed()[0] == 1  # halted: the last store completed
    win.expect(("r", 0x34, sr_word("S2MM", VDMADecErr=1, Err_Irq=1)))
    with pytest.raises(ChannelFault, match="halted on VDMADecErr; call recover") as err:
        vdma.s2mm.latest_completed()
    assert err.value.errors == ("VDMADecErr",)
    win.assert_done()


def test_wait_frame_acknowledges_frmcnt_irq() -> None:
    win, vdma = started()
    irq = reg("S2MM", "VDMASR").encode(FrmCnt_Irq=1)
    win.expect(
        ("w", 0x34, irq),  # fresh: forget frames completed before the call
        ("r", 0x34, sr_word("S2MM", Halted=0)),
        ("r", 0x34, sr_word("S2MM", Halted=0, FrmCnt_Irq=1)),
        ("w", 0x34, irq),  # acknowledge
        ("r", 0x34, sr_word("S2MM", Halted=0)),
        ("r", 0x28, PARK.encode(WrFrmStore=2)),
    )
    assert vdma.s2mm.wait_frame(fresh=True)[0] == 1
    win.assert_done()
    win.expect(("r", 0x34, sr_word("S2MM")))
    with pytest.raises(ChannelFault, match="halted while waiting for a frame \\(stopped\\)"):
        vdma.s2mm.wait_frame()
    win.assert_done()


def test_write_frame_fills_a_free_store_then_parks_on_it() -> None:
    win, vdma = started("MM2S")
    frame = np.arange(H * W * 8, dtype=np.uint8).reshape(H, W, 8)
    win.expect(
        ("r", 0x28, PARK.encode(RdFrmPtrRef=0, RdFrmStore=1, WrFrmPtrRef=2)),  # 0 is next, 1 being read
        ("w", 0x28, PARK.encode(RdFrmPtrRef=2, WrFrmPtrRef=2)),
        ("r", 0x00, 0x0001_5003),
        ("w", 0x00, 0x0001_5001),  # circular -> parked
    )
    ddr = vdma.allocator
    flushes = ddr.flushes
    assert vdma.mm2s.write_frame(frame) == 2
    win.assert_done()
    assert np.array_equal(vdma.mm2s.buffers[2], frame) and ddr.flushes == flushes + 1
    assert vdma.mm2s.config is not None and not vdma.mm2s.config.circular
    win.expect(("r", 0x28, PARK.encode(RdFrmPtrRef=2, RdFrmStore=2)), ("w", 0x28, PARK.encode(RdFrmPtrRef=0)))
    assert vdma.mm2s.write_frame(frame) == 0  # parked now: no VDMACR access
    win.assert_done()


def test_write_frame_with_two_stores_waits_for_the_pending_switch() -> None:
    win, vdma = started("MM2S", num_fstores=2)
    frame = np.zeros((H, W, 8), np.uint8)
    win.expect(
        ("r", 0x28, PARK.encode(RdFrmPtrRef=1, RdFrmStore=0)),  # switch to 1 not picked up yet
        ("r", 0x28, PARK.encode(RdFrmPtrRef=1, RdFrmStore=0)),
        ("r", 0x28, PARK.encode(RdFrmPtrRef=1, RdFrmStore=1)),
        ("w", 0x28, PARK.encode(RdFrmPtrRef=0)),
        ("r", 0x00, 0x0001_5003),
        ("w", 0x00, 0x0001_5001),
    )
    assert vdma.mm2s.write_frame(frame) == 0
    win.assert_done()


def test_arguments_are_checked_before_any_register_access() -> None:
    win, vdma, ddr = make()
    with pytest.raises(RegisterRangeError, match="height 0 is outside 1..8191"):
        vdma.s2mm.start(W, 0)
    with pytest.raises(RegisterRangeError, match=r"width 8192 is outside 1..8191"):
        vdma.s2mm.start(8192, H)
    with pytest.raises(FrameShapeError, match="2 buffers given, the VDMA has 3 frame stores"):
        vdma.s2mm.start(W, H, buffers=[ddr.allocate((H, W, 8)) for _ in range(2)])
    with pytest.raises(FrameShapeError, match=r"buffer 1 is \(3, 5, 8\) uint8"):
        vdma.s2mm.start(
            W, H, buffers=[ddr.allocate((H, W, 8)), ddr.allocate((H, W + 1, 8)), ddr.allocate((H, W, 8))]
        )
    with pytest.raises(FrameShapeError, match="contiguous lines"):
        vdma.s2mm.start(W, H, buffers=[ddr.allocate((H, 2 * W, 8))[:, ::2] for _ in range(3)])
    with pytest.raises(ChannelNotStarted, match="call start"):
        vdma.mm2s.write_frame(np.zeros((H, W, 8), np.uint8))
    with pytest.raises(ChannelNotStarted):
        vdma.s2mm.recover()
    win.assert_done()
    _, one = started("MM2S", num_fstores=1)
    with pytest.raises(VDMAError, match="needs 2 or more frame stores"):
        one.mm2s.write_frame(np.zeros((H, W, 8), np.uint8))
    with pytest.raises(FrameShapeError, match=r"frame is \(3, 4, 4\) uint8"):
        one.mm2s.write_frame(np.zeros((H, W, 4), np.uint8))
