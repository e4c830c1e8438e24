"""The rectify core's driver: exact register sequences, and behaviour on the emulated core."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereocam.drivers.mmio import RegisterTimeout, UnsupportedIP
from stereocam.drivers.rectify import ConfigRefused, RectifyCore
from stereocam.overlays.emulated.rectify import EmulatedRectifyCore
from stereocam.overlays.emulated.regblock import ReadOnlyRegister, UnknownRegister
from stereocam.overlays.model.core_params import FrameSizeError, LineBufferTooSmall, ParameterOutOfRange
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.model.result import CoreOptions
from stereocam.overlays.spec.rectify import (
    CAMERAS,
    CORE_ID,
    CORE_VERSION,
    DEFAULT_BUILD,
    RECTIFY_MAP,
    CameraParams,
    CoreConfig,
    camera_registers,
    i64_to_words,
    param_offset,
)

from ..doubles import RecordingWindow
from ..overlays.test_model import random_params, translate

pytestmark = pytest.mark.armhf

W, H = 48, 32


def identity_probe(lb_rows: int = 80) -> list:
    return [("r", 0x000, CORE_ID), ("r", 0x004, CORE_VERSION), ("r", 0x008, 752), ("r", 0x00C, 1024),
            ("r", 0x010, lb_rows), ("r", 0x014, 1)]


def regs(p: CameraParams, w: int = W, h: int = H):
    return camera_registers(p, w, h)


def tilted_params(rng: np.random.Generator) -> CameraParams:
    """A camera rolled by about 0.5 rad: rows y +- W sin(0.5) / 2 are needed, far more than 16."""
    a = rng.uniform(0.45, 0.55)
    K = np.array([[W, 0, W / 2], [0, W, H / 2], [0, 0, 1.0]])
    roll = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    hinv = K @ roll @ np.linalg.inv(K)
    return CameraParams(tuple(hinv.ravel()), W, W, W / 2, H / 2, -0.1, 0.0, 0.0, 0.0)


def test_driver_refuses_a_foreign_ip() -> None:
    with pytest.raises(UnsupportedIP, match="ID register reads 0xdeadbeef"):
        RectifyCore(RecordingWindow([("r", 0x000, 0xDEADBEEF)]))
    with pytest.raises(UnsupportedIP,
                       match="version 1.x is not supported by this driver .2.x.: load a bitstream"):
        RectifyCore(RecordingWindow([("r", 0x000, CORE_ID), ("r", 0x004, 0x00010000)]))


def test_load_writes_the_exact_register_sequence() -> None:
    """Frame size, delay, 2 x 17 signed 64-bit values low word first, clear CONFIG_ERROR, APPLY, poll."""
    rng = np.random.default_rng(0)
    cfg = CoreConfig(regs(random_params(rng, W, H)), regs(random_params(rng, W, H)), W, H, 7)
    win = RecordingWindow(identity_probe())
    core = RectifyCore(win)
    win.expect(("w", 0x030, W), ("w", 0x034, H), ("w", 0x038, 7))
    for cam in CAMERAS:
        for name, value in cfg.camera(cam).values().items():
            lo, hi = i64_to_words(value)
            win.expect(("w", param_offset(cam, name), lo), ("w", param_offset(cam, name) + 4, hi))
    control_enabled = RECTIFY_MAP["CONTROL"].encode(ENABLE=1)
    win.expect(
        ("w", 0x028, RECTIFY_MAP["FLAGS"].bit("CONFIG_ERROR")),
        ("r", 0x020, control_enabled),
        ("w", 0x020, control_enabled | RECTIFY_MAP["CONTROL"].bit("APPLY")),
        ("r", 0x020, control_enabled | RECTIFY_MAP["CONTROL"].bit("APPLY")),  # still pending: poll again
        ("r", 0x020, control_enabled),
        ("r", 0x028, 0),
    )
    core.load(cfg)
    win.assert_done()


def test_clear_flags_and_mode_sequences() -> None:
    win = RecordingWindow(identity_probe())
    core = RectifyCore(win)
    win.expect(("w", 0x028, 0b111))
    core.clear_flags()
    win.expect(("w", 0x03C, 12), ("r", 0x020, 0b1), ("w", 0x020, 0b1011))
    core.set_mode(bypass=True, debug_line=True, debug_row=12)
    win.assert_done()
    with pytest.raises(ValueError, match="outside 0..1023"):
        core.set_mode(debug_row=1024)


@pytest.fixture
def emulated() -> "tuple[EmulatedRectifyCore, RectifyCore]":
    hw = EmulatedRectifyCore(lb_rows=16)
    return hw, RectifyCore(hw)


def test_programmed_core_output_equals_the_model(emulated) -> None:
    hw, core = emulated
    rng = np.random.default_rng(1)
    left, right = random_params(rng, W, H), random_params(rng, W, H)
    cfg, fit = core.program(left, right, W, H)
    assert cfg.lb_delay == fit.delay and fit.rows <= 16
    core.enable()
    frame = rng.integers(0, 256, (H, W, 8), dtype=np.uint8)
    out = hw.process(frame)
    model = RectifyModel(left, right, W, H, CoreOptions(lb_rows=16, lb_delay=fit.delay))
    expected = model.process(frame).frame
    np.testing.assert_array_equal(out, expected)
    assert core.status().frame_count == 1
    assert core.read_config() == cfg


def test_apply_latches_between_frames_and_waits_for_a_frame_in_flight(emulated) -> None:
    hw, core = emulated
    a = translate(1.0, 0.0, w=W, h=H)
    b = translate(2.0, 0.0, w=W, h=H)
    core.program(a, a, W, H)
    core.enable()
    frame = np.arange(H * W * 8, dtype=np.uint32).astype(np.uint8).reshape(H, W, 8)
    frame[..., 3] = frame[..., 0]  # gray bytes unused here: compare R only
    np.testing.assert_array_equal(hw.process(frame)[:, :-1, 0], frame[:, 1:, 0])
    core.program(b, b, W, H)  # between frames: latched at once
    assert not core.status().apply_pending and hw.active is not None and hw.active.left == regs(b)
    with hw.lock:
        hw.set_field("STATUS", "BUSY", 1)  # as while the frame thread is inside process()
    core.timeout = 0.05
    with pytest.raises(RegisterTimeout, match="CONTROL never cleared APPLY"):
        core.program(a, a, W, H)
    assert core.status().apply_pending and hw.active.left == regs(b)
    with hw.lock:
        hw.set_field("STATUS", "BUSY", 0)
    # Latched at this frame's start.
    np.testing.assert_array_equal(hw.process(frame)[:, :-1, 0], frame[:, 1:, 0])
    assert not core.status().apply_pending


def test_out_of_range_parameters_are_refused_and_the_old_set_stays(emulated) -> None:
    hw, core = emulated
    good = translate(1.0, 0.0, w=W, h=H)
    core.program(good, good, W, H)
    bad = CameraParams(good.hinv, 0.5, good.fy, good.cx, good.cy, 0, 0, 0, 0)  # fx below 1.0
    with pytest.raises(ParameterOutOfRange, match="left FX = 0.5 is outside the register's range 1 .. 32768"):
        core.program(bad, good, W, H)
    bad_regs = dataclasses.replace(regs(good), fx=1 << 19)  # 0.5 px
    with pytest.raises(ConfigRefused):
        core.load(CoreConfig(bad_regs, regs(good), W, H, 0))  # the core's own check
    assert core.status().flags["CONFIG_ERROR"]
    assert hw.active is not None and hw.active.left == regs(good)
    core.clear_flags("CONFIG_ERROR")
    assert not core.status().flags["CONFIG_ERROR"]


def test_line_buffer_and_size_refusals(emulated) -> None:
    hw, core = emulated
    steep = translate(0.0, 20.5, w=W, h=H)  # fine: delay 21, 2 rows
    core.program(steep, steep, W, H)
    rng = np.random.default_rng(2)
    tilted = tilted_params(rng)
    with pytest.raises(LineBufferTooSmall, match=r"needs \d+ line-buffer rows but the core buffers 16"):
        core.program(tilted, tilted, W, H)
    with pytest.raises(FrameSizeError, match="2000x32 frame does not fit"):
        core.program(steep, steep, 2000, H)
    assert hw.active is not None and hw.active.left == regs(steep)


def test_overflow_and_size_flags_are_sticky_and_write_one_to_clear(emulated) -> None:
    hw, core = emulated
    rng = np.random.default_rng(3)
    tilted = regs(tilted_params(rng))
    core.load(CoreConfig(tilted, tilted, W, H, 0))  # skips the line-buffer check on purpose
    core.enable()
    hw.process(rng.integers(0, 256, (H, W, 8), dtype=np.uint8))
    assert core.status().flags["LB_OVERFLOW"]
    assert hw.process(np.zeros((H, W + 1, 8), np.uint8)) is None  # lines too long: dropped
    flags = core.status().flags
    assert flags["SIZE_ERROR"] and flags["LB_OVERFLOW"]
    core.clear_flags("SIZE_ERROR")
    flags = core.status().flags
    assert not flags["SIZE_ERROR"] and flags["LB_OVERFLOW"]
    assert core.status().frame_count == 1


def test_frame_size_rules(emulated) -> None:
    """RECTIFY_CORE.md "Malformed input": extra lines are ignored, missing lines give 0 rows, a wrong
    width drops."""
    hw, core = emulated
    p = translate(0.5, 3.25, w=W, h=H)
    cfg, fit = core.program(p, p, W, H)
    delay = fit.delay
    assert delay == 4  # taps at rows y + 3 and y + 4
    core.enable()
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (H, W, 8), dtype=np.uint8)
    normal = hw.process(frame)
    long = hw.process(np.concatenate([frame, frame[:3]]))
    np.testing.assert_array_equal(long, normal)
    assert core.status().flags["SIZE_ERROR"] and core.status().frame_count == 2
    core.clear_flags()
    short = hw.process(frame[:20])  # rows 0..19 arrive: output rows with y + 4 < 20 are as usual
    np.testing.assert_array_equal(short[:16], normal[:16])
    assert not short[16:].any()
    assert core.status().flags["SIZE_ERROR"] and core.status().frame_count == 3
    assert hw.process(frame[:4]) is None  # r = 4 = e(0): output row 0 never started
    assert hw.process(frame[:, :-1]) is None
    assert core.status().frame_count == 3 and hw.frames_dropped == 2
    core.set_mode(bypass=True)
    np.testing.assert_array_equal(hw.process(frame[:20])[:20], frame[:20])  # bypass: e(y) = y
    assert hw.process(np.zeros((0, W, 8), np.uint8)) is None


def test_disabled_core_emits_nothing_and_unprogrammed_core_passes_through() -> None:
    hw = EmulatedRectifyCore()
    core = RectifyCore(hw)
    build = (DEFAULT_BUILD.max_width, DEFAULT_BUILD.lb_rows, True)
    assert (core.max_width, core.lb_rows, core.colour) == build
    frame = np.random.default_rng(4).integers(0, 256, (480, 752, 8), dtype=np.uint8)
    assert hw.process(frame) is None
    core.enable()
    np.testing.assert_array_equal(hw.process(frame), frame)


def test_bus_errors_are_loud() -> None:
    hw = EmulatedRectifyCore()
    with pytest.raises(UnknownRegister, match="offset 0x40"):
        hw.read(0x040)
    with pytest.raises(ReadOnlyRegister, match="LB_ROWS"):
        hw.write(0x010, 200)
