"""The stereo core's output channel (``vdma_depth``'s S2MM) is watched like the other DMA channels
where the bitstream has one: a halt is a fault in /api/status and /metrics until a restart gets it
going again. The channel here is a real VDMA driver over the emulated VDMA, as the board binds it."""
from __future__ import annotations

import time
from typing import Any, Callable, Optional

import numpy as np

from stereocam.drivers.vdma import VDMA
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.vdma import EmulatedVDMA
from stereocam.overlays.fabric import StereoFabric, VdmaDepthStores
from stereocam.overlays.interface import DEPTH_CHANNEL, ChannelStatus
from stereocam.overlays.spec.overlay import DEPTH_VDMA
from stereocam.server.frames.fabric_health import FabricHealth

WAIT_S = 60.0  # a bound for a broken health thread only: a busy machine makes the waits longer


class BoardLike:
    """The members FabricHealth uses, answered by a StereoFabric whose depth channel is a VDMA."""

    def __init__(self, fabric: StereoFabric) -> None:
        self.fabric = fabric
        self.streaming = True
        self.stereo = fabric.stereo

    def channel_status(self, name: Any) -> ChannelStatus:
        return self.fabric.channel_status(name)

    def restart_channel(self, name: Any, timeout: Optional[float] = None) -> None:
        self.fabric.restart_channel(name, timeout)


def until(what: str, check: Callable[[], bool], tick: Callable[[], None]) -> None:
    deadline = time.monotonic() + WAIT_S
    while not check():
        assert time.monotonic() < deadline, what
        tick()
        time.sleep(0.02)


def test_a_halted_depth_channel_is_a_fault_until_a_restart_gets_it_going() -> None:
    with EmulatedOverlay(clock="stepped") as ov:
        f = ov.fabric
        assert ov.channel_status(DEPTH_CHANNEL).configured is False, "the emulated core has no DMA channel"
        hw = EmulatedVDMA(ov.emulation.ddr, 3, DEPTH_VDMA)
        fabric = StereoFabric(raw_vdma=f.raw_vdma, proc_vdma=f.proc_vdma, mux=f.mux, rectify=f.rectify,
                              allocate=f.allocate, backend="pynq", frame_size=(8, 4), stereo=f.stereo,
                              depth=VdmaDepthStores(VDMA(hw, ov.emulation.ddr.allocate, num_fstores=3,
                                                         name=DEPTH_VDMA)))
        never = ChannelStatus(configured=False, running=False, errors=())
        assert fabric.channel_status(DEPTH_CHANNEL) == never
        assert fabric.depth is not None
        fabric.depth.start(8, 4)
        frame = np.zeros((4, 4, 8), np.uint8)
        assert hw.s2mm_accept(frame)
        status = fabric.channel_status(DEPTH_CHANNEL)
        assert status.configured and status.running and status.fatal == ()
        assert "depth_s2mm" in fabric.status()["vdma"]

        health = FabricHealth(BoardLike(fabric), source=lambda: "live", frame_age=lambda: 0.0,
                              period=lambda: 0.05, no_signal_s=10.0)
        assert DEPTH_CHANNEL in health.channels
        health.start()
        try:
            hw.inject("S2MM", "VDMASlvErr")
            hw.s2mm_accept(frame)  # the next frame halts the channel
            until("the halt is reported",
                  lambda: any("disparity channel" in x["text"] for x in health.faults()),
                  lambda: hw.s2mm_accept(frame))
            assert health.faults()[0]["what"] == DEPTH_CHANNEL
            until("the channel is restarted", lambda: health.channels[DEPTH_CHANNEL].restarts > 0,
                  lambda: hw.s2mm_accept(frame))
            hw.inject("S2MM", None)  # the fault ends: the next restart stays up
            until("the channel runs again", lambda: health.faults() == [], lambda: hw.s2mm_accept(frame))
            assert fabric.channel_status(DEPTH_CHANNEL).running
            metrics = {m.name: {s.labels["part"]: s.value for s in m.samples} for m in health.metrics()}
            assert metrics["stereocam_fabric_faults"][DEPTH_CHANNEL] == 1
        finally:
            health.stop()
            fabric.depth.close()


def test_without_a_stereo_core_the_depth_channel_is_not_watched() -> None:
    with EmulatedOverlay(clock="stepped", stereo=False) as ov:
        health = FabricHealth(ov, source=lambda: "live", frame_age=lambda: 0.0, period=lambda: 0.05,
                              no_signal_s=10.0)
        assert DEPTH_CHANNEL not in health.channels
        assert "depth_s2mm" not in ov.status()["vdma"]
