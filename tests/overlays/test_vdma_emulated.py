"""The VDMA driver against the emulated VDMA and DDR: behaviour, not register sequences."""

from __future__ import annotations

import threading
import time
from typing import Iterator, List, Tuple

import numpy as np
import pytest

from stereocam.drivers.mmio import RegisterTimeout
from stereocam.drivers.vdma import VDMA, ChannelFault, NoFrameYet, Recovery
from stereocam.overlays.emulated.ddr import PAGE, EmulatedDDR
from stereocam.overlays.emulated.regblock import EmulationError, ReadOnlyRegister, UnknownRegister
from stereocam.overlays.emulated.vdma import EmulatedVDMA
from stereocam.overlays.spec.vdma import VDMA_MAP, reg

from ..slowness import SLOWNESS

pytestmark = pytest.mark.armhf

W, H = 6, 4
PARK = VDMA_MAP["PARK_PTR_REG"]


def frame(value: int, h: int = H, w: int = W) -> np.ndarray:
    """A frame whose every byte says which frame it is (and row/column, to catch misplacement)."""
    f = np.full((h, w, 8), value, np.uint8)
    f[..., 1] = np.arange(h, dtype=np.uint8)[:, None]
    f[..., 2] = np.arange(w, dtype=np.uint8)[None, :]
    return f


@pytest.fixture
def rig() -> Tuple[EmulatedVDMA, VDMA, EmulatedDDR]:
    ddr = EmulatedDDR(size=256 * PAGE)
    hw = EmulatedVDMA(ddr, num_fstores=3, name="raw")
    # A generous default bound: what these tests wait for does happen (a timeout's tests pass their own).
    return hw, VDMA(hw, ddr, num_fstores=3, name="raw", timeout=10.0 * SLOWNESS), ddr


def bus(hw: EmulatedVDMA, name: str) -> int:
    return hw.read(VDMA_MAP.offset(name))


def test_reset_values_on_the_bus(rig) -> None:
    hw, _, _ = rig
    assert bus(hw, "S2MM_VDMACR") == 0x0001_0000
    assert bus(hw, "MM2S_VDMASR") == 0x0001_0001
    assert bus(hw, "MM2S_FRMDLY_STRIDE") == 0x0100_0000
    assert VDMA_MAP["VDMA_VERSION"].decode(bus(hw, "VDMA_VERSION"))["Major"] == 6


def test_rs_runs_the_channel_but_only_vsize_starts_transfers(rig) -> None:
    hw, _, ddr = rig
    buf = ddr.allocate((H, W, 8))
    hw.write(0xAC, buf.physical_address)
    hw.write(0xA8, W * 8)
    hw.write(0xA4, W * 8)
    hw.write(0xA0, H)  # VSIZE while halted: stored, starts nothing
    hw.write(0x30, reg("S2MM", "VDMACR").encode(RS=1))
    assert not reg("S2MM", "VDMASR").get(bus(hw, "S2MM_VDMASR"), "Halted")
    assert hw.s2mm_accept(frame(1)) is False and not buf.any()
    hw.write(0xA0, H)  # written last while running: starts
    assert hw.s2mm_accept(frame(1)) is True
    assert np.array_equal(buf, frame(1))
    assert (hw.s2mm.frames, hw.s2mm.dropped) == (1, 1)


def test_circular_capture_walks_the_stores_and_reads_only_completed_ones(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    with pytest.raises(NoFrameYet):
        vdma.s2mm.latest_completed()
    assert hw.s2mm_accept(frame(10))
    assert vdma.s2mm.current_store() == 0  # in flight, not complete
    with pytest.raises(NoFrameYet):
        vdma.s2mm.latest_completed()
    for i in range(1, 7):
        assert hw.s2mm_accept(frame(10 + i))
        in_flight = i % 3
        assert vdma.s2mm.current_store() == in_flight
        store, buf = vdma.s2mm.latest_completed()
        assert store == (in_flight - 1) % 3
        assert np.array_equal(buf, frame(10 + i - 1))  # the previous frame, whole
        assert np.array_equal(vdma.s2mm.buffers[in_flight], frame(10 + i))
    assert (hw.frames_written, hw.s2mm.completed_frames) == (7, 6)


def test_park_mode_keeps_writing_one_store(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H, circular=False)
    for i in range(3):
        hw.s2mm_accept(frame(i))
    assert np.array_equal(vdma.s2mm.buffers[0], frame(2)) and not vdma.s2mm.buffers[1].any()
    vdma.s2mm.park(2)
    hw.s2mm_accept(frame(7))
    assert vdma.s2mm.current_store() == 2 and np.array_equal(vdma.s2mm.buffers[2], frame(7))
    with pytest.raises(Exception, match="circular mode"):
        vdma.s2mm.latest_completed()


def test_mm2s_streams_what_write_frame_wrote(rig) -> None:
    hw, vdma, ddr = rig
    vdma.mm2s.start(W, H, circular=False)
    assert np.array_equal(hw.mm2s_fetch(), np.zeros((H, W, 8), np.uint8))  # parked on store 0, blank
    store = vdma.mm2s.write_frame(frame(5))
    assert store == 1 and ddr.flushes >= 1
    out = hw.mm2s_fetch()
    assert out.shape == (H, W, 8) and np.array_equal(out, frame(5))
    assert vdma.mm2s.wait_parked() == 1
    assert np.array_equal(hw.mm2s_fetch(), frame(5))  # parked: the same frame again
    assert vdma.mm2s.write_frame(frame(6)) == 2
    assert np.array_equal(hw.mm2s_fetch(), frame(6))
    assert hw.frames_read == 4


def test_mm2s_circular_cycles_and_write_frame_parks_it(rig) -> None:
    hw, vdma, _ = rig
    vdma.mm2s.start(W, H)
    for i, b in enumerate(vdma.mm2s.buffers):
        b[:] = frame(i)
    assert [int(hw.mm2s_fetch()[0, 0, 0]) for _ in range(4)] == [0, 1, 2, 0]
    vdma.mm2s.write_frame(frame(9))  # RdFrmStore 0, RdFrmPtrRef 0: store 1
    assert [int(hw.mm2s_fetch()[0, 0, 0]) for _ in range(2)] == [9, 9]


def test_status_bits_are_write_one_to_clear_and_maskable(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    hw.s2mm_accept(frame(1, h=H - 1))  # SOF came early: one line short
    assert vdma.s2mm.errors() == ("SOFEarlyErr",)
    sr = reg("S2MM", "VDMASR")
    assert sr.get(bus(hw, "S2MM_VDMASR"), "Err_Irq")
    hw.write(0x34, 0)  # writing 0 clears nothing
    assert vdma.s2mm.errors() == ("SOFEarlyErr",)
    assert vdma.s2mm.clear_errors() == ()
    assert not sr.get(bus(hw, "S2MM_VDMASR"), "Err_Irq")
    hw.s2mm_accept(frame(2, w=W + 1))  # lines too long; the overlapping part is written
    assert vdma.s2mm.errors() == ("EOLLateErr",)
    assert np.array_equal(vdma.s2mm.buffers[1], frame(2, w=W + 1)[:, :W])
    vdma.s2mm.clear_errors()
    hw.write(0x3C, VDMA_MAP["S2MM_VDMA_IRQ_MASK"].encode(IRQMaskEOLEarlyErr=1))
    hw.s2mm_accept(frame(3, w=W - 1))
    value = bus(hw, "S2MM_VDMASR")
    assert sr.get(value, "EOLEarlyErr") and not sr.get(value, "Err_Irq")  # flagged, no interrupt
    assert vdma.s2mm.running  # frame-size errors do not stop the channel


def test_soft_reset_self_clears_after_polling_and_restores_reset_values(rig) -> None:
    hw, vdma, _ = rig
    vdma.mm2s.start(W, H, circular=False)
    vdma.mm2s.write_frame(frame(1))  # MM2S parks on store 1
    vdma.s2mm.start(W, H)
    hw.record = True
    vdma.s2mm.reset()
    cr_reads = [v for op, off, v in hw.log if op == "r" and off == 0x30]
    assert [reg("S2MM", "VDMACR").get(v, "Reset") for v in cr_reads] == [1] * (hw.settle_reads - 1) + [0]
    assert bus(hw, "S2MM_HSIZE") == 0 and bus(hw, "S2MM_START_ADDRESS1") == 0
    assert bus(hw, "S2MM_VDMASR") == VDMA_MAP["S2MM_VDMASR"].reset
    park = PARK.decode(bus(hw, "PARK_PTR_REG"))
    assert park["RdFrmPtrRef"] == 1 and park["WrFrmPtrRef"] == 0  # only this channel's half
    assert bus(hw, "MM2S_HSIZE") == W * 8  # the other channel is untouched


def test_writes_during_a_soft_reset_fail_loudly(rig) -> None:
    hw, _, _ = rig
    hw.write(0x30, reg("S2MM", "VDMACR").encode(Reset=1))
    with pytest.raises(EmulationError, match="S2MM_HSIZE while the S2MM soft reset is in progress; poll"):
        hw.write(0xA4, 8)
    hw.write(0x54, 8)  # the other channel is fine


def test_unknown_offsets_read_only_registers_and_missing_stores_fail_loudly(rig) -> None:
    hw, _, _ = rig
    with pytest.raises(UnknownRegister, match="read at offset 0x8"):
        hw.read(0x08)
    with pytest.raises(UnknownRegister, match="write at offset 0x9c"):
        hw.write(0x9C, 0)
    with pytest.raises(ReadOnlyRegister, match="VDMA_VERSION"):
        hw.write(0x2C, 0)
    hw.write(0x34, 0)  # Halted is read-only inside a writable register: ignored
    assert reg("S2MM", "VDMASR").get(bus(hw, "S2MM_VDMASR"), "Halted")
    with pytest.raises(EmulationError, match="frame store 4, but this VDMA has 3 frame stores"):
        hw.write(reg("S2MM", "START_ADDRESS4").offset, 0x1000_0000)
    hw.write(0x44, 1)
    with pytest.raises(EmulationError, match="frame store 17"):
        hw.write(reg("S2MM", "START_ADDRESS1").offset, 0x1000_0000)
    with pytest.raises(EmulationError, match="WrFrmPtrRef=3"):
        hw.write(0x28, PARK.encode(WrFrmPtrRef=3))


def test_decode_error_halts_until_recovered(rig) -> None:
    hw, vdma, ddr = rig
    vdma.s2mm.start(W, H)
    hw.s2mm_accept(frame(1))
    vdma.s2mm.buffers[1].freebuffer()  # the DMA still points at it
    assert hw.s2mm_accept(frame(2)) is False
    assert vdma.s2mm.errors() == ("VDMADecErr",) and not vdma.s2mm.running
    assert not reg("S2MM", "VDMACR").get(bus(hw, "S2MM_VDMACR"), "RS")
    assert vdma.s2mm.current_store() == 1  # the store where the error happened
    assert vdma.s2mm.clear_errors() == ("VDMADecErr",)  # read-only: needs a reset
    with pytest.raises(ChannelFault, match="VDMADecErr"):
        vdma.s2mm.latest_completed()
    with pytest.raises(ChannelFault, match="halted on VDMADecErr"):
        vdma.s2mm.wait_frame()  # frame 1 completed before the fault; its store is not handed out
    hw.write(0x30, reg("S2MM", "VDMACR").encode(RS=1))
    assert not vdma.s2mm.running  # a fatal error keeps it halted
    assert vdma.s2mm.recover() == Recovery(("VDMADecErr",), True)
    assert vdma.s2mm.errors() == () and vdma.s2mm.running
    # recover keeps the configuration, freed store included: it faults again there
    assert hw.s2mm_accept(frame(3)) and hw.s2mm_accept(frame(4)) is False
    assert vdma.s2mm.errors() == ("VDMADecErr",)
    vdma.s2mm.start(W, H)  # a restart replaces the freed buffer
    assert not any(b.freed for b in vdma.s2mm.buffers)
    for i in range(4):
        assert hw.s2mm_accept(frame(20 + i))
    assert np.array_equal(vdma.s2mm.latest_completed()[1], frame(22))


def test_recover_restores_the_previous_configuration(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    hw.write(0xAC, 0x0)  # a stray write: store 0 now points nowhere
    hw.s2mm_accept(frame(1))
    assert vdma.s2mm.errors() == ("VDMADecErr",)
    assert vdma.s2mm.recover() == Recovery(("VDMADecErr",), True)
    assert vdma.s2mm.running and vdma.s2mm.errors() == ()
    for i in range(3):
        hw.s2mm_accept(frame(30 + i))
    assert [int(b[0, 0, 0]) for b in vdma.s2mm.buffers] == [30, 31, 32]


def test_internal_error_for_a_size_the_stream_cannot_carry(rig) -> None:
    hw, _, _ = rig
    hw.write(0x30, reg("S2MM", "VDMACR").encode(RS=1))
    hw.write(0xA4, 12)  # one and a half 8-byte beats
    hw.write(0xA0, H)
    sr = VDMA_MAP["S2MM_VDMASR"].decode(bus(hw, "S2MM_VDMASR"))
    assert sr["VDMAIntErr"] and sr["Err_Irq"] and sr["Halted"]


def test_stop_finishes_the_frame_in_flight(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    hw.s2mm_accept(frame(1))
    hw.write(0x30, reg("S2MM", "VDMACR").encode(bus(hw, "S2MM_VDMACR"), RS=0))
    assert hw.s2mm.halt_countdown is not None and hw.s2mm.completed is None  # still finishing
    assert hw.s2mm_accept(frame(2)) is False  # the next frame tick ends it
    assert not vdma.s2mm.running and hw.s2mm.completed == 0
    store, buf = vdma.s2mm.latest_completed()
    assert store == 0 and np.array_equal(buf, frame(1))
    # without a frame tick, bus time ends it too
    vdma.s2mm.start(W, H)
    hw.s2mm_accept(frame(3))
    vdma.s2mm.stop()
    assert not vdma.s2mm.running and hw.s2mm.completed == 0
    vdma.s2mm.stop()  # idempotent


def test_frame_count_interrupt_and_frame_count_enable(rig) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    cr = reg("S2MM", "VDMACR")
    sr = reg("S2MM", "VDMASR")
    hw.write(0x30, cr.encode(bus(hw, "S2MM_VDMACR"), IRQFrameCount=2))
    assert sr.get(bus(hw, "S2MM_VDMASR"), "IRQFrameCntSts") == 2
    counts = []
    for i in range(4):
        hw.s2mm_accept(frame(i))
        value = bus(hw, "S2MM_VDMASR")
        counts.append((sr.get(value, "IRQFrameCntSts"), sr.get(value, "FrmCnt_Irq")))
    assert counts == [(2, 0), (1, 0), (2, 1), (1, 1)]  # a frame completes at the tick after it was written
    assert hw.interrupt("S2MM")
    hw.write(0x30, cr.encode(bus(hw, "S2MM_VDMACR"), IRQFrameCount=0))
    assert cr.get(bus(hw, "S2MM_VDMACR"), "IRQFrameCount") == 1  # 0 is stored as 1
    hw.write(0x30, cr.encode(bus(hw, "S2MM_VDMACR"), FrameCntEn=1))
    hw.write(0x34, sr.encode(FrmCnt_Irq=1))
    assert not hw.interrupt("S2MM")
    assert hw.s2mm_accept(frame(9)) is False  # completes frame 3: count reached, the channel halts
    assert not vdma.s2mm.running and not cr.get(bus(hw, "S2MM_VDMACR"), "RS")
    assert sr.get(bus(hw, "S2MM_VDMASR"), "FrmCnt_Irq") and hw.s2mm.completed_frames == 4


@pytest.mark.slow
def test_timeouts_name_the_register_that_never_changed(rig) -> None:
    hw, vdma, _ = rig
    hw.hang("S2MM", "reset")
    with pytest.raises(RegisterTimeout, match="raw: S2MM_VDMACR never cleared Reset") as err:
        vdma.s2mm.reset(timeout=0.02)
    assert err.value.register == "S2MM_VDMACR"
    hw.hang("S2MM", "reset", False)
    hw.hang("MM2S", "run")
    with pytest.raises(RegisterTimeout, match="MM2S_VDMASR never cleared Halted after RS=1"):
        # ample for the reset, which does finish, even on a busy machine
        vdma.mm2s.start(W, H, timeout=2.0 * SLOWNESS)
    hw.hang("MM2S", "run", False)
    vdma.s2mm.start(W, H)
    with pytest.raises(RegisterTimeout, match="S2MM_VDMASR never set FrmCnt_Irq"):
        vdma.s2mm.wait_frame(timeout=0.02)
    hw.s2mm_accept(frame(1))
    hw.hang("S2MM", "halt")
    with pytest.raises(RegisterTimeout, match="S2MM_VDMASR never set Halted after RS=0"):
        vdma.s2mm.stop(timeout=0.02)
    recovery = vdma.s2mm.recover(timeout=2.0 * SLOWNESS)  # the reset ends what the stop could not
    assert recovery == Recovery((), False) and vdma.s2mm.running
    vdma.mm2s.start(W, H, circular=False)
    assert vdma.mm2s.wait_parked() == 0
    vdma.mm2s.write_frame(frame(1))
    with pytest.raises(RegisterTimeout, match="PARK_PTR_REG never showed RdFrmStore == RdFrmPtrRef"):
        vdma.mm2s.wait_parked(timeout=0.02)  # no frame tick fetches the new store


def tick_frame(tick: int) -> np.ndarray:
    """A frame carrying a 16-bit tick number in bytes 0 and 3 of every pixel."""
    f = frame(tick & 0xFF)
    f[..., 3] = tick >> 8
    return f


def tick_of(buf: np.ndarray) -> int:
    return int(buf[0, 0, 0]) | int(buf[0, 0, 3]) << 8


@pytest.fixture
def clock(rig) -> Iterator[List[int]]:
    """A frame clock thread: every millisecond an S2MM frame carrying the tick number, and an MM2S fetch."""
    hw = rig[0]
    ticks = [0]
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            ticks[0] += 1
            hw.s2mm_accept(tick_frame(ticks[0]))
            hw.mm2s_fetch()
            time.sleep(0.001)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield ticks
    stop.set()
    thread.join()


def test_wait_frame_returns_whole_fresh_frames_while_the_clock_runs(rig, clock) -> None:
    hw, vdma, _ = rig
    vdma.s2mm.start(W, H)
    seen = []
    for _ in range(5):
        before = clock[0]
        store, buf = vdma.s2mm.wait_frame(fresh=True)
        tick = tick_of(buf)
        assert np.array_equal(buf, tick_frame(tick)), "torn or partial frame"
        assert tick >= before  # completed after the call, so written at or after the tick seen before it
        seen.append(tick)
    assert seen == sorted(set(seen))  # every call returned a newer frame


def test_write_frame_with_two_stores_waits_for_the_channel_to_catch_up() -> None:
    ddr = EmulatedDDR(size=64 * PAGE)
    hw = EmulatedVDMA(ddr, num_fstores=2)
    vdma = VDMA(hw, ddr, num_fstores=2)
    vdma.mm2s.start(W, H, circular=False)
    assert vdma.mm2s.write_frame(frame(1)) == 1
    with pytest.raises(RegisterTimeout, match="MM2S never reached its park store"):
        vdma.mm2s.write_frame(frame(2), timeout=0.02)  # store 0 is read, store 1 is next: none is free
    timer = threading.Timer(0.01, hw.mm2s_fetch)  # a frame tick later the channel reads store 1
    timer.start()
    try:
        assert vdma.mm2s.write_frame(frame(3)) == 0
    finally:
        timer.join()
    assert np.array_equal(hw.mm2s_fetch(), frame(3))


def test_close_frees_what_the_driver_allocated_and_restart_reuses_buffers(rig) -> None:
    hw, vdma, ddr = rig
    vdma.s2mm.start(W, H)
    addresses = [b.physical_address for b in vdma.s2mm.buffers]
    vdma.s2mm.start(W, H)  # same size: same buffers
    assert [b.physical_address for b in vdma.s2mm.buffers] == addresses and ddr.num_buffers == 3
    vdma.s2mm.start(W + 1, H)  # new size: new buffers, old ones freed
    assert ddr.num_buffers == 3
    given = [ddr.allocate((H, W, 8)) for _ in range(3)]
    vdma.mm2s.start(W, H, buffers=given)
    with vdma:
        pass
    assert ddr.num_buffers == 3 and not any(b.freed for b in given)  # the caller's buffers stay
    assert not vdma.s2mm.running and not vdma.mm2s.running
