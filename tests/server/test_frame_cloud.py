"""A frame set's depth files (stereocam/server/frames/cloud.py) without a daemon: what a capture
stores and why a file is missing, the refusals of the live cloud, and the store's extra files."""
from __future__ import annotations

import io
from datetime import datetime, timezone
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from stereocam.overlays.model.stereo import compute
from stereocam.server.errors import ApiError, Kind
from stereocam.server.frames.cloud import depth_files, frame_cloud
from stereocam.server.frames.pipeline import FrameSet
from stereocam.server.stores.captures import FRAME_NAMES, CaptureStore
from stereocam.server.stores.frame_calibration import FrameCalibration

Q_MM = np.array([[1, 0, 0, -40.0], [0, 1, 0, -15.0], [0, 0, 0, 300.0], [0, 0, 1 / 60.0, 0]])


def frame_set(width: int, height: int = 30, seed: int = 0, stereo: bool = True) -> FrameSet:
    """A rectified pair whose right image is the left shifted by 8 pixels: disparity 8 where it matches;
    with ``stereo``, from an overlay whose stereo core's output (its model's beats, as the emulated core
    gives them) was taken with it."""
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, (height, width + 8), dtype=np.uint8)
    processed = np.zeros((height, width, 8), np.uint8)
    processed[..., 0:4] = left[:, :-8, None]
    processed[..., 4:8] = left[:, 8:, None]

    def core_output() -> np.ndarray:
        return compute(processed[..., 3].copy(), processed[..., 7].copy()).beats()

    return FrameSet(seq=0, frame=7, fabric_count=7, timestamp=0.0, monotonic=0.0, source="test",
                    processed=processed, raw=None, stereo=stereo, depth=core_output if stereo else None)


def calibration(Q: np.ndarray, units: str) -> FrameCalibration:
    cal = SimpleNamespace(rect=SimpleNamespace(Q=Q), units=units)
    return FrameCalibration.of(cal, id="abc", description="test")


def test_depth_files_of_a_calibrated_frame() -> None:
    files, section = depth_files(frame_set(64), calibration(Q_MM, "mm"), "frame 7")
    assert set(files) == {"disparity.png", "confidence.png", "cloud.ply"}
    assert section["cloud"] == "cloud.ply" and section["cloud_unavailable"] is None
    cloud = trimesh.load(io.BytesIO(files["cloud.ply"]), file_type="ply")
    assert 0 < len(cloud.vertices) <= section["valid_pixels"]  # d = 0 is at infinity: not a point
    # Disparity 8 px: Z = f B / d = 300 * 60 mm / 8 = 2.25 m.
    assert np.median(cloud.vertices[:, 2]) == pytest.approx(2.25)


@pytest.mark.parametrize("cal, why", [
    (None, "the calibration changed"),
    (FrameCalibration(), "no calibration is known"),
    (calibration(Q_MM, "unknown"), "does not say the unit"),
    (calibration(np.zeros((4, 4)), "mm"), "gives no depth"),
])
def test_no_cloud_says_why(cal, why) -> None:
    files, section = depth_files(frame_set(64), cal, "frame 7")
    assert set(files) == {"disparity.png", "confidence.png"}
    assert section["cloud"] is None and why in section["cloud_unavailable"]
    with pytest.raises(ApiError) as exc:
        frame_cloud(frame_set(64), cal, "frame 7")
    assert exc.value.kind is Kind.CONFLICT and why in exc.value.message


def test_a_frame_too_wide_for_the_core_has_no_depth() -> None:
    fs = frame_set(760)
    with pytest.raises(ApiError) as exc:
        frame_cloud(fs, calibration(Q_MM, "mm"), "frame 7")
    assert exc.value.kind is Kind.UNUSABLE
    assert "width 760: the core takes 9 .. 752 pixels" in exc.value.message
    files, section = depth_files(fs, calibration(Q_MM, "mm"), "frame 7")
    assert files == {} and "width 760" in section["unavailable"]


def test_the_store_keeps_extra_files_and_refuses_clashing_names(tmp_path) -> None:
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=lambda: datetime(2026, 1, 1, tzinfo=timezone.utc))
    frames = {n: np.full((4, 6), 9, np.uint8) for n in FRAME_NAMES}
    info = store.save(frames, {"frame": 1}, [("cloud.ply", b"ply\n")])
    assert store.read_file(info.id, "cloud.ply") == b"ply\n"
    assert "cloud.ply" in [f["name"] for f in info.meta["files"]]
    for name in ("raw_left.png", "meta.json", "../x.ply", "sub/x.png", ".hidden.ply"):
        with pytest.raises(ValueError):
            store.save(frames, {"frame": 2}, [(name, b"x")])
    assert [i.id for i in store.list()] == [info.id]


def test_without_a_stereo_core_a_frame_has_no_depth_and_says_so() -> None:
    files, section = depth_files(frame_set(64, stereo=False), calibration(Q_MM, "mm"), "frame 7")
    assert files == {} and "no stereo core" in section["unavailable"]
    with pytest.raises(ApiError) as exc:
        frame_cloud(frame_set(64, stereo=False), calibration(Q_MM, "mm"), "frame 7")
    assert exc.value.kind is Kind.CONFLICT and "no stereo core" in exc.value.message
