"""The optional stereo core behind the overlay interface: bound where the overlay has it, its output
read per processed frame store, and an overlay without one saying so."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from stereocam.drivers.mmio import UnsupportedIP
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.stereo import LEFT_Y, RIGHT_Y, STEREO_THREAD
from stereocam.overlays.fabric import StereoFabric, VdmaDepthStores, optional_instances
from stereocam.overlays.interface import Overlay, StereoControl
from stereocam.overlays.model.stereo import StereoResult, compute
from stereocam.overlays.spec.overlay import (
    ADDRESS_MAP,
    DEPTH_VDMA,
    OPTIONAL_ADDRESS_MAP,
    OPTIONAL_INSTANCES,
    STEREO,
    VDMA_VLNVS,
)
from stereocam.overlays.spec.stereo import VLNV as STEREO_VLNV
from stereocam.overlays.spec.stereo import StereoParams


def test_the_optional_instances_have_their_own_addresses() -> None:
    assert set(OPTIONAL_INSTANCES) == set(OPTIONAL_ADDRESS_MAP) == {STEREO, DEPTH_VDMA}
    assert OPTIONAL_INSTANCES[STEREO] == (STEREO_VLNV,) and OPTIONAL_INSTANCES[DEPTH_VDMA] == VDMA_VLNVS
    assert not set(OPTIONAL_ADDRESS_MAP) & set(ADDRESS_MAP)
    assert not set(OPTIONAL_ADDRESS_MAP.values()) & set(ADDRESS_MAP.values())


def test_optional_instances_refuse_the_wrong_ip() -> None:
    assert optional_instances({}) == ()
    assert optional_instances({STEREO: {"type": STEREO_VLNV}}) == (STEREO,)
    with pytest.raises(UnsupportedIP, match="IP 'stereo' is 'xilinx.com:ip:axi_vdma:6.3', expected "
                                            "stereocam:user:stereo:1.0"):
        optional_instances({STEREO: {"type": "xilinx.com:ip:axi_vdma:6.3"}})


def test_a_stereo_core_without_its_channel_is_refused() -> None:
    with EmulatedOverlay(clock="stepped", source=None) as ov:
        f = ov.fabric
        with pytest.raises(UnsupportedIP, match="'stereo' and 'vdma_depth'.*only one of them"):
            StereoFabric(raw_vdma=f.raw_vdma, proc_vdma=f.proc_vdma, mux=f.mux, rectify=f.rectify,
                         allocate=f.allocate, backend="emulated", frame_size=f.frame_size, stereo=f.stereo)


def test_emulated_overlay_has_a_stereo_core_whose_output_is_the_model_of_the_processed_frame() -> None:
    with EmulatedOverlay(clock="stepped") as ov:
        assert isinstance(ov, Overlay) and isinstance(ov.stereo, StereoControl)
        assert ov.ip_dict[STEREO]["phys_addr"] == OPTIONAL_ADDRESS_MAP[STEREO]
        small = StereoParams(num_disp=64, median=False)
        ov.stereo.program(small, wait=False)
        ov.step(2)
        assert not ov.stereo.status().apply_pending and ov.stereo.params() == small
        assert ov.emulation.stereo is not None and ov.emulation.stereo.computed_frames == 0
        stored = ov.processed_store()
        take = ov.take_depth(stored.store)
        assert take is not None and ov.emulation.stereo.computed_frames == 0  # taken, not yet computed
        beats = take()
        # Computed on the emulated hardware's thread, which the daemon's CPU budget leaves out.
        assert STEREO_THREAD in ov.emulation_threads
        assert any(t.name == STEREO_THREAD for t in threading.enumerate())
        assert beats is not None and beats.shape == stored.pixels.shape[:2] and beats.dtype == np.uint32
        p = stored.pixels
        expected = compute(p[..., LEFT_Y].copy(), p[..., RIGHT_Y].copy(), small)
        assert StereoResult.from_beats(beats).equal(expected)
        status = ov.status()["stereo"]
        assert status["frame_count"] == 2 and status["params"]["num_disp"] == 64 and status["enabled"]
        assert status["build"] == {"max_width": 752, "max_height": 1024, "max_disp": 128, "parallel": 32}


def test_emulated_overlay_without_a_stereo_core() -> None:
    with EmulatedOverlay(clock="stepped", stereo=False) as ov:
        assert ov.stereo is None and STEREO not in ov.ip_dict
        ov.step(2)
        assert ov.take_depth(ov.processed_store().store) is None
        assert ov.status()["stereo"] is None


def test_vdma_depth_stores_read_two_beats_per_stream_pixel() -> None:
    """On the board the output comes through vdma_depth: a (H, W/2, 8) byte store read as (H, W) words."""
    with EmulatedOverlay(clock="stepped") as ov:
        from stereocam.drivers.vdma import VDMA
        from stereocam.overlays.emulated.vdma import EmulatedVDMA

        hw = EmulatedVDMA(ov.emulation.ddr, 3, DEPTH_VDMA)
        depth = VdmaDepthStores(VDMA(hw, ov.emulation.ddr.allocate, num_fstores=3, name=DEPTH_VDMA))
        depth.start(8, 4)
        beats = np.arange(32, dtype=np.uint32).reshape(4, 8)
        assert hw.s2mm_accept(beats.view(np.uint8).reshape(4, 4, 8))
        take = depth.take(0)
        assert take is not None and np.array_equal(take(), beats)
        with pytest.raises(UnsupportedIP, match="7 pixels wide does not fill whole stream beats"):
            depth.start(7, 4)
        depth.stop()
        depth.close()
