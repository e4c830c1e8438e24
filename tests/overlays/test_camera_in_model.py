"""The camera input IP's numpy model (stereocam/overlays/model/camera_in.py) against its specification.

The RTL is co-simulated against this model in tests/hdl/test_camera_in_rtl.py; here the model is
checked against a per-pixel reference written from the words of spec/camera_in.py (not from its
KERNELS table), and the spec's Bayer phase rules against the Linux driver's.
"""
from __future__ import annotations

import time
from typing import List

import numpy as np
import pytest

from stereocam.overlays.model import camera_in as model
from stereocam.overlays.spec import camera_in as spec
from stereocam.overlays.spec import verilog
from stereocam.overlays.spec.pixel import gray_of

pytestmark = pytest.mark.armhf


def reference(raw: np.ndarray, phase: str) -> np.ndarray:
    """Bilinear demosaic pixel by pixel, as the spec says it in words: (H, W, 3) uint8."""
    h, w = raw.shape
    code = ["RGGB", "GRBG", "GBRG", "BGGR"].index(phase)  # red's column is bit 0, its row bit 1
    r_col, r_row = code & 1, code >> 1

    def at(y: int, x: int) -> int:  # mirrored about the edge pixel
        y, x = abs(y), abs(x)
        y = 2 * (h - 1) - y if y >= h else y
        x = 2 * (w - 1) - x if x >= w else x
        return int(raw[y, x])

    def to8(estimate4: int) -> int:  # 4 x the estimate in 10-bit units -> value / 4, rounded half up
        return min((estimate4 + 8) // 16, 255)

    out = np.zeros((h, w, 3), np.uint8)
    for y in range(h):
        for x in range(w):
            c = at(y, x)
            cross = at(y - 1, x) + at(y + 1, x) + at(y, x - 1) + at(y, x + 1)
            diagonal = at(y - 1, x - 1) + at(y - 1, x + 1) + at(y + 1, x - 1) + at(y + 1, x + 1)
            across = 2 * (at(y, x - 1) + at(y, x + 1))
            updown = 2 * (at(y - 1, x) + at(y + 1, x))
            red_row, red_col = (y - r_row) % 2 == 0, (x - r_col) % 2 == 0
            if red_row and red_col:
                rgb = (4 * c, cross, diagonal)
            elif not red_row and not red_col:
                rgb = (diagonal, cross, 4 * c)
            elif red_row:
                rgb = (across, 4 * c, updown)
            else:
                rgb = (updown, 4 * c, across)
            out[y, x] = [to8(v) for v in rgb]
    return out


@pytest.mark.parametrize("phase", spec.CFA_PHASES)
def test_demosaic_matches_the_reference_at_every_size_and_phase(phase: str) -> None:
    rng = np.random.default_rng(spec.phase_code(phase))
    for h, w in ((2, 2), (2, 3), (3, 2), (5, 7), (8, 6), (13, 16)):
        raw = rng.integers(0, 1024, (h, w))
        raw[rng.random((h, w)) < 0.2] = 1023
        got = model.demosaic_camera(raw, phase)
        assert got.shape == (h, w, 4) and got.dtype == np.uint8
        assert np.array_equal(got[..., :3], reference(raw, phase)), (h, w)
        assert np.array_equal(got[..., 3], gray_of(got[..., :3]))


def test_windows_are_exact_slices_of_the_whole_frame() -> None:
    rng = np.random.default_rng(4)
    raw = rng.integers(0, 1024, (37, 51))
    whole = model.demosaic_camera(raw, "GRBG")
    for _ in range(40):
        r0, c0 = int(rng.integers(0, 36)), int(rng.integers(0, 50))
        r1, c1 = int(rng.integers(r0 + 1, 38)), int(rng.integers(c0 + 1, 52))
        window = model.demosaic_window(raw, slice(r0, r1), slice(c0, c1), "GRBG")
        assert np.array_equal(window, whole[r0:r1, c0:c1]), (r0, r1, c0, c1)


def test_flat_colours_come_back_exactly_and_saturate() -> None:
    """A flat colour mosaicked with the right phase demosaics to itself (10 -> 8 bits, half up)."""
    for phase in spec.CFA_PHASES:
        for rgb10 in ((1023, 0, 0), (0, 1023, 0), (0, 0, 1023), (2, 5, 6), (1021, 1022, 1023),
                      (513, 514, 515)):
            scene = np.broadcast_to(np.array(rgb10), (6, 8, 3))
            out = model.demosaic_camera(model.mosaic(scene, phase), phase)
            want = [min((4 * v + 8) >> 4, 255) for v in rgb10]  # 2 -> 0.5 -> 1; 1021 -> 255.25 -> 255
            assert np.all(out[..., :3] == want), (phase, rgb10)
    assert [min((4 * v + 8) >> 4, 255) for v in (1, 2, 5, 6, 1021, 1022)] == [0, 1, 1, 2, 255, 255]
    # the wrong phase shows: red comes out as blue
    red = model.mosaic(np.broadcast_to(np.array((1023, 0, 0)), (6, 8, 3)), "RGGB")
    assert np.all(model.demosaic_camera(red, "BGGR")[..., :3] == (0, 0, 255))


def test_demosaic_is_mirror_symmetric_with_the_flipped_phase() -> None:
    """What the emulated rig relies on to flip after demosaicking."""
    rng = np.random.default_rng(5)
    for h, w in ((6, 8), (7, 9), (6, 9)):
        raw = rng.integers(0, 1024, (h, w))
        for fh, fv in ((True, False), (False, True), (True, True)):
            flipped_raw = raw[::-1 if fv else 1, ::-1 if fh else 1]
            for phase in spec.CFA_PHASES:
                inner = model.flipped_phase(phase, w, h, fh, fv)
                want = model.demosaic_camera(raw, inner)[::-1 if fv else 1, ::-1 if fh else 1]
                assert np.array_equal(model.demosaic_camera(flipped_raw, phase), want)
                assert model.flipped_phase(inner, w, h, fh, fv) == phase


def test_bayer_phase_follows_the_window_and_the_flips() -> None:
    # [linux] mt9v032_set_crop: odd column and row starts give GRBG
    assert spec.cfa_phase(1, 5, 752, 480) == "GRBG"
    assert spec.cfa_phase(2, 5, 752, 480) == "RGGB"
    assert spec.cfa_phase(1, 4, 752, 480) == "BGGR" == spec.BAYER_PHASE  # our driver's full window
    assert spec.PARAMETERS["BAYER_PHASE"] == spec.phase_code("BGGR") == 3
    # even sizes: the flipped read-out starts on the same colour; odd sizes: one pixel over
    for fh in (False, True):
        for fv in (False, True):
            assert spec.cfa_phase(1, 4, 752, 480, column_flip=fh, row_flip=fv) == "BGGR"
    assert spec.cfa_phase(1, 4, 751, 480, column_flip=True) == "GBRG"
    assert spec.cfa_phase(1, 4, 752, 479, row_flip=True) == "GRBG"
    with pytest.raises(ValueError, match="unknown Bayer phase"):
        spec.phase_code("GGRB")


def test_shifted_phase_and_mosaic_agree() -> None:
    rgb = np.random.default_rng(6).integers(0, 1024, (9, 10, 3))
    for phase in spec.CFA_PHASES:
        whole = model.mosaic(rgb, phase)
        for r0 in (0, 1, 2, 3):
            for c0 in (0, 1, 2):
                part = model.mosaic(rgb[r0:, c0:], model.shifted_phase(phase, r0, c0))
                assert np.array_equal(part, whole[r0:, c0:])


def test_bad_raw_frames_are_refused() -> None:
    with pytest.raises(ValueError, match="at least 2 x 2"):
        model.demosaic_camera(np.zeros((1, 5), np.uint16))
    with pytest.raises(ValueError, match="10-bit"):
        model.demosaic_camera(np.full((4, 4), 1024))
    with pytest.raises(ValueError, match="differ in size"):
        model.demosaic(np.zeros((4, 4), np.uint16), np.zeros((4, 6), np.uint16))


def lines(rng: np.random.Generator, w: int, h: int) -> List[np.ndarray]:
    return [row for row in rng.integers(0, 1024, (h, w))]


def test_frames_the_cameras_disagree_on_end_at_the_disagreement() -> None:
    rng = np.random.default_rng(7)
    a, b = lines(rng, 8, 6), lines(rng, 8, 6)
    assert len(model.expected_frames([a], [b], 16)) == 1
    assert np.array_equal(model.expected_frames([a], [b], 16)[0], model.demosaic(np.stack(a), np.stack(b)))
    cut = list(b)
    cut[3] = cut[3][:-1]  # row 3 one sample short on the right: rows 0..2 come out, as a frame of their own
    (out,) = model.expected_frames([a], [cut], 16)
    assert np.array_equal(out, model.demosaic(np.stack(a[:3]), np.stack(b[:3])))
    assert model.expected_frames([a], [[b[0][:-1]] + b[1:]], 16) == []  # the first line: no frame
    assert model.expected_frames([a[:1]], [b[:1]], 16) == []  # one row: no frame
    assert model.expected_frames([a], [b], 7) == []  # wider than MAX_WIDTH
    assert model.expected_frames([a[:4]], [b], 16)[0].shape == (4, 8, 8)  # cut short on one camera


def test_pixel_bus_is_the_mt9v034_timing() -> None:
    rng = np.random.default_rng(8)
    frame = lines(rng, 5, 3)
    bus = model.pixel_bus([frame], model.BusTiming(hblank=4, vblank=16, fv_lead=2, fv_trail=3))
    assert bus.shape == (16 + 2 + 3 * 5 + 2 * 4 + 3 + 16, 3)
    assert np.array_equal(bus[bus[:, 1] == 1, 0], np.concatenate(frame))
    assert np.all(bus[bus[:, 1] == 1, 2] == 1)  # LINE_VALID only inside FRAME_VALID
    assert np.all(bus[bus[:, 1] == 0, 0] == 0)
    edges = np.flatnonzero(np.diff(bus[:, 1]) == 1)
    assert len(edges) == 3 and np.all(np.diff(edges) == 5 + 4)


@pytest.mark.not_on_armhf("a time bound for the host's CPU, not for qemu")
def test_demosaic_is_fast_enough_for_the_live_path() -> None:
    """A 752 x 480 stereo frame well within a 60 fps frame time (the emulated rig redoes only part)."""
    rng = np.random.default_rng(9)
    left = rng.integers(0, 1024, (480, 752)).astype(np.uint16)
    right = rng.integers(0, 1024, (480, 752)).astype(np.uint16)
    model.demosaic(left, right)
    times = []
    for _ in range(5):
        # The thread's CPU time (numpy runs it in this thread): what the work costs, which the other
        # processes of a busy machine do not lengthen as they do the wall-clock time.
        start = time.thread_time()
        model.demosaic(left, right)
        times.append(time.thread_time() - start)
    best = min(times)
    print(f"752x480 stereo demosaic: {best * 1e3:.1f} ms of CPU time")
    assert best < 0.030


def test_generated_camera_header_is_up_to_date() -> None:
    """Regenerate with `python -m stereocam.overlays.spec.verilog` after changing spec/camera_in.py."""
    assert verilog.CAMERA_HEADER_NAME not in verilog.stale()
    header = verilog.camera_header()
    assert f"`define CI_BAYER_PHASE {spec.phase_code(spec.BAYER_PHASE)}" in header
    assert f"`define CI_OUT_SHIFT {spec.OUT_SHIFT}" in header
    assert f"`define CI_TAG_W {spec.TAG_BITS}" in header


def test_line_fifo_depth_holds_two_lines() -> None:
    assert spec.line_fifo_depth(752) == 2048
    assert spec.line_fifo_depth(64) == 256
    assert spec.PARAMETERS["MAX_WIDTH"] <= spec.MAX_WIDTH_LIMIT
