"""The emulated fabric through the real drivers: bit-exact to the model, live and virtual."""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from stereocam.bench.rectify import bench_calibration
from stereocam.drivers.vdma import FrameShapeError
from stereocam.overlays.backend import BackendError, choose, open_overlay
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.interface import CHANNELS, Overlay, RectifyControl
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.model.result import CoreOptions
from stereocam.overlays.spec.axis_switch import LIVE, VIRTUAL

from ..slowness import SLOWNESS

pytestmark = pytest.mark.armhf

W, H = 752, 480


@pytest.fixture(scope="module")
def calibration():
    _, _, left, right = bench_calibration()
    return left, right


@pytest.fixture
def overlay(calibration):
    ov = EmulatedOverlay(clock="stepped", source=SyntheticRig(motion=True))
    left, right = calibration
    ov.rectify.program(left, right, W, H)  # core idle: latches at once
    ov.start()
    yield ov
    ov.close()


def model_for(overlay, calibration) -> RectifyModel:
    cfg = overlay.rectify.read_config()
    options = CoreOptions(lb_rows=overlay.rectify.lb_rows, lb_delay=cfg.lb_delay)
    return RectifyModel(*calibration, W, H, options)


@pytest.mark.slow
def test_live_frames_come_out_rectified_bit_exact(overlay, calibration) -> None:
    model = model_for(overlay, calibration)
    seen = set()
    for _ in range(4):
        overlay.step()
        if overlay.emulation.counters.ticks < 2:
            continue
        raw_store, raw = overlay.fabric.latest_raw()
        proc_store, proc = overlay.fabric.latest_processed()
        np.testing.assert_array_equal(proc, model.process(raw).frame)
        seen.add(hash(raw.tobytes()))
    assert len(seen) >= 2, "the rig moves: consecutive raw frames differ"
    per_input = overlay.emulation.counters.per_input
    assert per_input[LIVE] == 4 and per_input[VIRTUAL] == 0
    assert not overlay.fabric.status()["core"]["flags"]["LB_OVERFLOW"]


def test_virtual_camera_round_trip_and_back_to_live(overlay, calibration) -> None:
    model = model_for(overlay, calibration)
    frame = np.random.default_rng(0).integers(0, 256, (H, W, 8), dtype=np.uint8)
    overlay.fabric.select("virtual")
    overlay.fabric.send_virtual(frame)
    overlay.step(2)  # one period to pick the frame up, one to complete its store
    _, proc = overlay.fabric.latest_processed()
    np.testing.assert_array_equal(proc, model.process(frame).frame)
    assert overlay.fabric.source == "virtual"
    with pytest.raises(FrameShapeError, match=r"expected \(480, 752, 8\) uint8"):
        overlay.fabric.send_virtual(frame[:100])
    overlay.fabric.select("live")
    overlay.step(2)
    _, raw = overlay.fabric.latest_raw()
    _, proc = overlay.fabric.latest_processed()
    np.testing.assert_array_equal(proc, model.process(raw).frame)
    with pytest.raises(ValueError, match="'live' or 'virtual'"):
        overlay.fabric.select("hdmi")


def test_stop_returns_the_mux_to_live_and_is_idempotent(overlay) -> None:
    overlay.fabric.select("virtual")
    overlay.step()
    overlay.stop()
    assert overlay.fabric.source == "live"
    assert not overlay.fabric.rectify.status().control["ENABLE"]
    frames = overlay.emulation.counters.proc_frames
    overlay.step(3)
    assert overlay.emulation.counters.proc_frames == frames, "a stopped fabric writes no frames"
    overlay.stop()
    overlay.start()
    overlay.step(2)
    assert overlay.emulation.counters.proc_frames > frames


def test_the_overlay_is_what_the_daemon_asks_for(overlay: EmulatedOverlay, calibration) -> None:
    """The emulated overlay satisfies the typed seam, and its members answer from the fabric."""
    seam: Overlay = overlay  # mypy checks the members; isinstance checks they exist
    assert isinstance(seam, Overlay) and isinstance(seam.rectify, RectifyControl)
    assert seam.backend == "emulated" and seam.core_kind == "model" and seam.choice is None
    assert seam.frame_size == (W, H) and seam.streaming and seam.raw_stores == 3
    config, options = seam.core_setup()
    assert config == seam.rectify.read_config() and options.lb_rows == seam.rectify.lb_rows
    assert not options.bypass and options.debug_row is None
    overlay.step(2)
    count = seam.frame_count()
    processed = seam.processed_store()
    assert processed.stores == 3 and processed.pixels.shape == (H, W, 8)
    raw = seam.raw_store()
    assert seam.raw_store(raw.store - 1).store == (raw.store - 1) % raw.stores
    overlay.step()
    seam.wait_processed(1.0)
    assert seam.frame_count() == count + 1
    for channel in CHANNELS:
        status = seam.channel_status(channel)
        assert status.configured and status.running and status.fatal == ()
    seam.select("virtual")
    frame = np.zeros((H, W, 8), dtype=np.uint8)
    store = seam.send_virtual(frame)
    overlay.step()
    assert seam.wait_virtual_taken(1.0) == store and seam.source == "virtual"
    seam.restart_channel("vdma_proc.mm2s", 1.0)
    assert seam.channel_status("vdma_proc.mm2s").running
    seam.stop()
    assert not seam.streaming and not seam.channel_status("vdma_raw.s2mm").running


def test_realtime_clock_moves_frames(calibration) -> None:
    with EmulatedOverlay(clock="realtime", fps=60.0) as ov:
        ov.rectify.program(*calibration, W, H)
        _, first = ov.fabric.proc_vdma.s2mm.wait_frame(timeout=60.0 * SLOWNESS)
        store, _ = ov.fabric.proc_vdma.s2mm.wait_frame(timeout=60.0 * SLOWNESS)
        assert ov.emulation.clock.frames >= 2
    assert ov.fabric.source == "live" and not ov.emulation.clock.running


def test_backend_choice_says_why(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("STEREOCAM_BITSTREAM", raising=False)
    assert choose("emulated").backend == "emulated"
    with pytest.raises(BackendError, match="must be one of auto, pynq, emulated"):
        choose("fpga")
    auto = choose("auto", bitstream=tmp_path / "missing.bit")
    assert auto.backend == "emulated"
    if os.environ.get("STEREOCAM_TEST_ENV") == "board":
        assert "no bitstream was found" in auto.reason
        with pytest.raises(BackendError, match="no bitstream found"):
            choose("pynq", bitstream=tmp_path / "missing.bit")
    else:
        assert "pynq is not installed" in auto.reason
        with pytest.raises(BackendError, match="pynq package is not installed"):
            choose("pynq")
    ov = open_overlay("auto", bitstream=tmp_path / "missing.bit", clock="stepped")
    try:
        assert ov.backend == "emulated" and ov.choice.reason == auto.reason
    finally:
        ov.close()


def zynq_device_tree(folder: Path) -> Path:
    """A stand-in for /proc/device-tree/compatible on a PYNQ-Z1 (NUL-separated, as Linux writes it)."""
    path = folder / "compatible"
    path.write_bytes(b"digilent,zynq-pynqz1\0xlnx,zynq-7000\0")
    return path


def test_a_board_without_its_bitstream_is_said_loudly(tmp_path, monkeypatch, caplog) -> None:
    """pynq importable (a package on disk, on sys.path) and no bitstream: the emulated fabric, with a warning
    naming the missing file and what to do, and ``board`` (the daemon keeps to the board's budget)."""
    site = tmp_path / "board-site"
    (site / "pynq").mkdir(parents=True)
    (site / "pynq" / "__init__.py").write_text("# stands for PYNQ's package: importable, never imported\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delenv("STEREOCAM_BITSTREAM", raising=False)
    missing = tmp_path / "stereocam.bit"
    monkeypatch.setenv("STEREOCAM_DEVICE_TREE", str(tmp_path / "no-such-file"))
    pc = choose("auto", bitstream=missing)
    assert pc.backend == "emulated" and not pc.board and pc.warning is None, "pynq on a PC is not a board"
    assert "not a Zynq" in pc.reason
    monkeypatch.setenv("STEREOCAM_DEVICE_TREE", str(zynq_device_tree(tmp_path)))
    auto = choose("auto", bitstream=missing)
    assert auto.backend == "emulated" and auto.board and auto.warning is not None
    assert f"stereocam.bit is not at {missing}" in auto.warning and "--backend emulated" in auto.warning
    asked = choose("emulated", bitstream=missing)
    assert asked.warning is None and not asked.board, "--backend emulated silences it"
    with caplog.at_level(logging.WARNING, logger="stereocam.overlays.backend"):
        ov = open_overlay("auto", bitstream=missing, clock="stepped")
    try:
        assert ov.choice == auto
        warned = [r for r in caplog.records if r.levelno == logging.WARNING]
        assert [r.getMessage() for r in warned] == [auto.warning]
    finally:
        ov.close()


if os.environ.get("STEREOCAM_TEST_ENV") == "board":
    # The board path: our drivers bound through pynq's own MMIO and allocate (pynq 4.0.0),
    # over a pynq.Device whose registers and memory are the emulated fabric's.

    def test_pynq_bound_fabric_is_bit_exact(calibration) -> None:
        from stereocam.overlays.pynq.overlay import bind_pynq
        from stereocam.overlays.spec.overlay import ADDRESS_MAP

        from ..pynq_device import EmulatedPynqDevice

        # Today's bitstream: no stereo core (the emulated one has no vdma_depth for pynq to bind).
        ov = EmulatedOverlay(clock="stepped", stereo=False)
        try:
            blocks = {n: (ADDRESS_MAP[n], b) for n, b in ov.emulation.blocks.items()}
            dev = EmulatedPynqDevice(ov.emulation.ddr, blocks, tick=ov.step)
            fabric = bind_pynq(ov.ip_dict, dev, frame_size=(W, H))
            assert type(fabric.rectify.regs.window).__module__ == "pynq.mmio"
            cfg, fit = fabric.rectify.program(*calibration, W, H)
            fabric.start_streams()
            fabric.select("virtual")
            frame = np.random.default_rng(1).integers(0, 256, (H, W, 8), dtype=np.uint8)
            fabric.send_virtual(frame)
            ov.step(2)
            _, proc = fabric.latest_processed()
            model = RectifyModel(*calibration, W, H, CoreOptions(lb_rows=80, lb_delay=fit.delay))
            np.testing.assert_array_equal(proc, model.process(frame).frame)
            fabric.stop_streams()
            assert fabric.source == "live"
        finally:
            ov.close()
