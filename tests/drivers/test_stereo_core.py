"""The stereo core's driver: exact register sequences, and behaviour on the emulated core."""
from __future__ import annotations

import numpy as np
import pytest

from stereocam.drivers.mmio import RegisterTimeout, UnsupportedIP
from stereocam.drivers.stereo import StereoConfigRefused, StereoCore
from stereocam.overlays.emulated.regblock import ReadOnlyRegister
from stereocam.overlays.emulated.stereo import LEFT_Y, RIGHT_Y, EmulatedStereoCore
from stereocam.overlays.model.stereo import StereoResult, compute
from stereocam.overlays.spec.stereo import CORE_ID, CORE_VERSION, DEFAULT_PARAMS, STEREO_MAP, StereoParams

from ..doubles import RecordingWindow

pytestmark = pytest.mark.armhf

W, H = 64, 24
SMALL = StereoParams(num_disp=32)
CONTROL = STEREO_MAP["CONTROL"]
FLAGS = STEREO_MAP["FLAGS"]


def identity_probe() -> list:
    return [("r", 0x000, CORE_ID), ("r", 0x004, CORE_VERSION), ("r", 0x008, 752), ("r", 0x00C, 1024),
            ("r", 0x010, 128), ("r", 0x014, 32)]


def test_driver_refuses_a_foreign_ip() -> None:
    with pytest.raises(UnsupportedIP, match="ID register reads 0x52454354, expected 0x53544552"):
        StereoCore(RecordingWindow([("r", 0x000, 0x52454354)]))
    with pytest.raises(UnsupportedIP, match="version 2.x is not supported by this driver .1.x.: load a"):
        StereoCore(RecordingWindow([("r", 0x000, CORE_ID), ("r", 0x004, 0x00020000)]))


def test_driver_reads_the_build_back() -> None:
    win = RecordingWindow(identity_probe())
    core = StereoCore(win)
    win.assert_done()
    assert (core.build.max_width, core.build.max_height, core.build.max_disp, core.build.parallel) == (
        752, 1024, 128, 32)


def test_program_writes_the_exact_register_sequence() -> None:
    """Size, the seven parameters in map order, clear CONFIG_ERROR, CONTROL with the modes and APPLY, poll."""
    p = StereoParams(num_disp=64, p1=10, p2=120, p2_edge=30, edge_thresh=20, uniqueness=9, lr_tol=1,
                     lr_check=True, subpixel=False, median=True)
    win = RecordingWindow(identity_probe())
    core = StereoCore(win)
    enabled = CONTROL.encode(ENABLE=1, LR_CHECK=1, SUBPIXEL=1, MEDIAN=1)
    written = CONTROL.encode(ENABLE=1, LR_CHECK=1, SUBPIXEL=0, MEDIAN=1, APPLY=1)
    win.expect(
        ("w", 0x030, 640), ("w", 0x034, 360),
        ("w", 0x038, 64), ("w", 0x03C, 10), ("w", 0x040, 120), ("w", 0x044, 30), ("w", 0x048, 20),
        ("w", 0x04C, 9), ("w", 0x050, 1),
        ("w", 0x028, FLAGS.bit("CONFIG_ERROR")),
        ("r", 0x020, enabled),
        ("w", 0x020, written),
        ("r", 0x020, written),  # still pending: poll again
        ("r", 0x020, written & ~CONTROL.bit("APPLY")),
        ("r", 0x028, 0),
    )
    core.program(p, size=(640, 360))
    win.assert_done()


def test_refused_values_write_nothing_and_say_what_the_core_takes() -> None:
    win = RecordingWindow(identity_probe())
    core = StereoCore(win)
    with pytest.raises(ValueError, match=r"num_disp = 200: the core takes a whole number in 32 \.\. 128"):
        core.program(StereoParams(num_disp=200))
    with pytest.raises(ValueError, match="num_disp = 40: the core takes a multiple of 32"):
        core.program(StereoParams(num_disp=40))
    with pytest.raises(ValueError, match=r"p1 <= p2_edge <= p2 .they are 16, 120, 100."):
        core.program(StereoParams(p2_edge=120))
    with pytest.raises(ValueError, match=r"width 4: the core takes 9 \.\. 752 pixels"):
        core.program(DEFAULT_PARAMS, size=(4, 480))
    win.assert_done()  # nothing was written


def test_config_error_is_reported() -> None:
    win = RecordingWindow(identity_probe())
    core = StereoCore(win)
    win.expect(("w", STEREO_MAP.offset("NUM_DISP"), 32))
    for reg in ("P1", "P2", "P2_EDGE", "EDGE_THRESH", "UNIQUENESS", "LR_TOL"):
        win.expect(("w", STEREO_MAP.offset(reg), 0))
    win.expect(("w", 0x028, 2), ("r", 0x020, 0), ("w", 0x020, CONTROL.encode(APPLY=1)), ("r", 0x020, 0),
               ("r", 0x028, FLAGS.bit("CONFIG_ERROR")))
    with pytest.raises(StereoConfigRefused, match="CONFIG_ERROR.*previous ones stay active"):
        core.program(StereoParams(num_disp=32, p1=0, p2=0, p2_edge=0, edge_thresh=0, uniqueness=0, lr_tol=0,
                                  lr_check=False, subpixel=False, median=False))
    win.assert_done()


def test_enable_status_and_flags_sequences() -> None:
    win = RecordingWindow(identity_probe())
    core = StereoCore(win)
    win.expect(("r", 0x020, 0xE), ("w", 0x020, 0xF))
    core.enable()
    win.expect(("r", 0x020, 0xF), ("w", 0x020, 0xE))
    core.disable()
    win.expect(("w", 0x028, 0b11))
    core.clear_flags()
    win.expect(("r", 0x024, 0b10), ("r", 0x02C, 7), ("r", 0x020, 0x1F), ("r", 0x028, 0b01))
    status = core.status()
    assert status.as_json() == {"frame_count": 7, "enabled": True, "busy": False, "apply_pending": True,
                                "flags": {"SIZE_ERROR": True, "CONFIG_ERROR": False}}
    win.assert_done()


# ---- behaviour against the emulated core ----------------------------------------------------

@pytest.fixture
def emulated() -> "tuple[EmulatedStereoCore, StereoCore]":
    hw = EmulatedStereoCore()
    return hw, StereoCore(hw)


def pair_frame(rng: np.random.Generator, shift: int = 5) -> np.ndarray:
    frame = np.zeros((H, W, 8), np.uint8)
    left = rng.integers(0, 256, (H, W), dtype=np.uint8)
    frame[..., LEFT_Y] = left
    frame[..., RIGHT_Y] = np.roll(left, -shift, axis=1)
    return frame


def test_output_is_the_model_on_the_gray_pair_computed_only_when_read(emulated) -> None:
    hw, core = emulated
    core.program(SMALL, size=(W, H))  # disabled: latched at once
    core.enable()
    rng = np.random.default_rng(3)
    frames = [pair_frame(rng) for _ in range(4)]
    for store, frame in enumerate(frames[:3]):
        assert hw.accept(frame, store)
    assert hw.accept(frames[3], 0)  # store 0 comes round again
    assert hw.computed_frames == 0  # nobody read a store yet
    beats = hw.output(0)
    assert beats is not None and beats.dtype == np.uint32 and beats.shape == (H, W)
    expected = compute(frames[3][..., LEFT_Y].copy(), frames[3][..., RIGHT_Y].copy(), SMALL)
    assert StereoResult.from_beats(beats).equal(expected)
    assert hw.output(0) is beats and hw.computed_frames == 1  # read twice, computed once
    assert hw.output(5) is None
    assert core.status().frame_count == 4 and hw.frame_number(0) == 4


def test_apply_waits_for_the_next_frame_and_a_refused_set_keeps_the_old(emulated) -> None:
    hw, core = emulated
    core.program(SMALL, size=(W, H))
    core.enable()
    new = SMALL.with_values(p1=8, median=False)
    core.program(new, wait=False)
    assert core.status().apply_pending and hw.active == SMALL  # shadowed until a frame starts
    core.timeout = 0.05
    with pytest.raises(RegisterTimeout, match="CONTROL never cleared APPLY"):
        core.check_applied(timeout=0.05)
    hw.accept(pair_frame(np.random.default_rng(0)), 0)
    core.check_applied()
    assert hw.active == new and core.params() == new
    # Written around the driver's check: the core refuses it at the frame start and keeps ``new``.
    hw.write(STEREO_MAP.offset("NUM_DISP"), 40)
    hw.write(STEREO_MAP.offset("CONTROL"), hw.read(STEREO_MAP.offset("CONTROL")) | CONTROL.bit("APPLY"))
    hw.accept(pair_frame(np.random.default_rng(0)), 1)
    with pytest.raises(StereoConfigRefused):
        core.check_applied()
    assert hw.active == new and core.status().flags["CONFIG_ERROR"]


def test_a_frame_of_another_size_sets_size_error_and_gives_no_output(emulated) -> None:
    hw, core = emulated
    core.program(SMALL, size=(W, H))
    core.enable()
    assert not hw.accept(np.zeros((H + 1, W, 8), np.uint8), 0)
    assert core.status().flags["SIZE_ERROR"] and hw.output(0) is None and core.frame_count() == 0
    core.clear_flags("SIZE_ERROR")
    assert not core.status().flags["SIZE_ERROR"]


def test_disabled_core_takes_no_frames_and_identity_is_read_only(emulated) -> None:
    hw, core = emulated
    assert not hw.accept(pair_frame(np.random.default_rng(0)), 0)
    with pytest.raises(ReadOnlyRegister):
        hw.write(0x000, 0)
