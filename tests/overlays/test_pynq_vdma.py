"""pynq's own ``AxiVDMA`` driver, unmodified, on our emulated VDMA and DDR.

pynq's driver was written against the real IP, independently of our model:
if it can start both channels and round-trip a frame through the emulation,
the model behaves like the hardware where pynq depends on it.

Gating, decided when the module is collected (CI forbids skipped tests, so
nothing here is ever skipped): with ``STEREOCAM_TEST_ENV=board`` pynq must
import (a failure is a collection error) and every test runs; in any other
environment the tests exist only if pynq imports, so where pynq is absent
(the dev env) this module simply defines no tests.
"""

from __future__ import annotations

import asyncio
from typing import Any, Iterator, Optional, Tuple

import numpy as np
import pytest

from stereocam.drivers.vdma import VDMA
from stereocam.overlays.emulated.ddr import EmulatedBuffer, EmulatedDDR
from stereocam.overlays.emulated.regblock import EmulationError
from stereocam.overlays.emulated.vdma import EmulatedVDMA
from stereocam.overlays.spec.pixel import pack, rgby
from stereocam.overlays.spec.vdma import VDMA_MAP

from .. import pynq_device as pd
from ..pynq_hwh import pynq_for_tests

pynq: Optional[Any] = pynq_for_tests()

BASE = 0x4300_0000
W, H = 64, 48


def stereo_frame(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    right = np.roll(left, 3, axis=1)
    return pack(rgby(left), rgby(right))


if pynq is not None:
    from pynq.lib.video.common import VideoMode

    @pytest.fixture
    def event_loop_for_pynq() -> Iterator[asyncio.AbstractEventLoop]:
        """pynq's blocking calls use ``asyncio.get_event_loop()``: give them a loop, then close it."""
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        yield loop
        asyncio.set_event_loop(None)
        loop.close()

    @pytest.fixture
    def board(event_loop_for_pynq: Any) -> Tuple[EmulatedDDR, EmulatedVDMA, Any, Any]:
        ddr = EmulatedDDR(size=64 << 20)
        hw = EmulatedVDMA(ddr, num_fstores=3, name="vdma")
        dev = pd.EmulatedPynqDevice(ddr, {"vdma": (BASE, hw)}, tick=pd.loopback_tick(hw))
        vdma = pd.pynq_axi_vdma(dev, "vdma")
        mode = VideoMode(W, H, 64)  # one 8-byte stereo pixel
        vdma.readchannel.mode = mode
        vdma.writechannel.mode = mode
        return ddr, hw, dev, vdma

    def test_pynq_starts_both_channels(board) -> None:
        ddr, hw, _, vdma = board
        vdma.readchannel.start()
        vdma.writechannel.start()
        assert vdma.readchannel.running and vdma.writechannel.running
        assert hw.s2mm.started and hw.mm2s.started
        assert vdma.framecount == 3  # from C_NUM_FSTORES in our description
        assert hw.get_field("S2MM_HSIZE", "HSIZE") == W * 8 and hw.get_field("S2MM_VSIZE", "VSIZE") == H
        assert (
            hw.get_field("S2MM_VDMACR", "Circular_Park") == 1
            and hw.get_field("MM2S_VDMACR", "Circular_Park") == 0
        )
        assert hw.s2mm.addresses[:3] == [vdma.readchannel._frames[i].physical_address for i in range(3)]
        assert all(isinstance(vdma.readchannel._frames[i], EmulatedBuffer) for i in range(3))
        assert ddr.num_buffers == 4  # three S2MM stores, one MM2S frame

    def test_pynq_writeframe_then_readframe_round_trips_a_stereo_frame(board) -> None:
        _, hw, _, vdma = board
        vdma.readchannel.start()
        vdma.writechannel.start()
        sent = stereo_frame(1)
        out = vdma.writechannel.newframe()
        out[:] = sent
        vdma.writechannel.writeframe(out)
        got = vdma.readchannel.readframe()
        assert isinstance(got, EmulatedBuffer) and got.shape == (H, W, 8)
        assert np.array_equal(got, sent)
        again = vdma.readchannel.readframe()
        assert np.array_equal(again, sent) and again.physical_address != got.physical_address
        second = stereo_frame(2)
        out2 = vdma.writechannel.newframe()
        out2[:] = second
        vdma.writechannel.writeframe(out2)
        vdma.readchannel.readframe()  # pynq: "read an additional time" for an up-to-date frame
        assert np.array_equal(vdma.readchannel.readframe(), second)
        assert hw.s2mm.frames == hw.mm2s.frames > 4
        assert vdma.readchannel.activeframe == hw.get_field("PARK_PTR_REG", "WrFrmStore")
        assert vdma.readchannel._interrupt.waits > 0  # pynq waited on our interrupt, which ran the clock

    def test_pynq_stop_and_reset_terminate_and_a_dead_stream_does_not_hang(board) -> None:
        _, hw, _, vdma = board
        vdma.readchannel.start()
        vdma.writechannel.start()
        vdma.writechannel.stop()  # pynq busy-waits on Halted: our model halts within a few reads
        assert not vdma.writechannel.running
        with pytest.raises(pd.InterruptTimeout, match="vdma/s2mm_introut stayed low for 64 emulated frames"):
            vdma.readchannel.readframe()  # nothing feeds S2MM now
        vdma.readchannel.reset()
        assert not vdma.readchannel.running
        assert hw.get("S2MM_VDMACR") == VDMA_MAP["S2MM_VDMACR"].reset
        with pytest.raises(RuntimeError, match="DMA channel not started"):
            vdma.readchannel.readframe()

    def test_pynq_mmio_and_allocate_reach_the_emulation(board) -> None:
        ddr, hw, dev, _ = board
        mmio = pynq.MMIO(BASE, VDMA_MAP.size, device=dev)
        assert mmio.read(VDMA_MAP.offset("VDMA_VERSION")) == VDMA_MAP["VDMA_VERSION"].reset
        mmio.write(VDMA_MAP.offset("S2MM_HSIZE"), 512)
        assert hw.get("S2MM_HSIZE") == 512
        with pytest.raises(EmulationError, match="no emulated IP at 0x43010000"):
            pynq.MMIO(BASE + VDMA_MAP.size, 4, device=dev).read(0)
        buf = pynq.allocate((4, 4), np.uint16, target=dev.default_memory)
        assert isinstance(buf, EmulatedBuffer) and ddr.contains(buf.physical_address, buf.nbytes)
        assert isinstance(pynq.allocate((8,), np.uint8, target=dev), EmulatedBuffer)

    def test_our_driver_over_a_pynq_mmio_window(board) -> None:
        """The same driver code as on the board: handed a pynq.MMIO, not an emulated block."""
        ddr, hw, dev, _ = board
        ours = VDMA(pynq.MMIO(BASE, VDMA_MAP.size, device=dev), ddr, num_fstores=3, name="vdma")
        ours.mm2s.start(W, H, circular=False)
        ours.s2mm.start(W, H)
        sent = stereo_frame(3)
        ours.mm2s.write_frame(sent)
        for _ in range(3):
            dev.tick()
        store, buf = ours.s2mm.wait_frame()
        assert np.array_equal(buf, sent)
        ours.close()
        assert not hw.s2mm_accept(sent)
