"""Point clouds and disparity images (stereocam/calibration/cloud.py, disparity_images.py), read back
with parsers that are not ours: trimesh for the PLY, Pillow and OpenCV for the PNGs."""
from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image

from stereocam.calibration import cloud, disparity_images
from stereocam.overlays.spec.stereo import INVALID

from ..sample import calibrate_sample

F, CX, CY, TX_MM = 500.0, 3.0, 2.0, -60.0  # a rig 60 mm apart; Q in millimetres
Q = np.array([[1, 0, 0, -CX], [0, 1, 0, -CY], [0, 0, 0, F], [0, 0, -1 / TX_MM, 0]])


def codes() -> np.ndarray:
    d = np.full((4, 6), INVALID, np.uint16)
    d[0, 0] = 20 * 16  # 20 px: Z = 500 * 60 / 20 mm = 1.5 m
    d[1, 4] = 16 * 16 + 8  # 16.5 px
    d[3, 5] = 3  # 3/16 px: far away
    d[2, 2] = 0  # 0 px: at infinity, dropped
    return d


def hand(x: int, y: int, d: float) -> "list[float]":
    """reprojectImageTo3D by hand for this Q: Z = f B / d, X = (x - cx) B / d, in metres."""
    b_m = -TX_MM / 1000.0
    return [(x - CX) * b_m / d, (y - CY) * b_m / d, F * b_m / d]


def test_points_are_q_times_pixel_in_metres_invalid_and_infinite_dropped() -> None:
    colour = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    pc = cloud.reproject(codes(), Q, 0.001, colour)
    assert len(pc) == 3
    assert pc.pixels.tolist() == [[0, 0], [4, 1], [5, 3]]
    expected = [hand(0, 0, 20.0), hand(4, 1, 16.5), hand(5, 3, 3 / 16)]
    np.testing.assert_allclose(pc.points, np.array(expected, np.float32), rtol=1e-6)
    assert pc.points[0, 2] == pytest.approx(1.5)
    assert pc.colours.tolist() == [colour[0, 0].tolist(), colour[1, 4].tolist(), colour[3, 5].tolist()]


def test_points_agree_with_opencv_for_a_real_calibration() -> None:
    cal = calibrate_sample()
    rng = np.random.default_rng(1)
    d = rng.integers(100 * 16, 200 * 16, size=(48, 64)).astype(np.uint16)
    d[rng.random(d.shape) < 0.3] = INVALID
    pc = cloud.reproject(d, cal.rect.Q, 1.0)
    ref = cv2.reprojectImageTo3D(d.astype(np.float32) / 16, cal.rect.Q)
    xs, ys = pc.pixels[:, 0], pc.pixels[:, 1]
    assert len(pc) == np.count_nonzero(d != INVALID)
    np.testing.assert_allclose(pc.points, ref[ys, xs], rtol=1e-5)


def test_ply_reads_back_with_trimesh(tmp_path) -> None:
    gray = np.full((4, 6), 77, np.uint8)
    pc = cloud.reproject(codes(), Q, 0.001, gray)
    data = cloud.ply_bytes(pc, "frame 12 of\nthe test")
    header = data[:data.index(b"end_header\n")].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    assert header[2] == "comment stereocam point cloud; frame 12 of the test"
    assert "metres" in header[3] and header[4] == "element vertex 3"
    path = tmp_path / "cloud.ply"
    path.write_bytes(data)
    mesh = trimesh.load(path)
    assert isinstance(mesh, trimesh.PointCloud)
    np.testing.assert_allclose(mesh.vertices, [hand(0, 0, 20.0), hand(4, 1, 16.5), hand(5, 3, 3 / 16)],
                               rtol=1e-6)
    assert mesh.colors[:, :3].tolist() == [[77, 77, 77]] * 3


def test_empty_cloud_is_a_valid_ply(tmp_path) -> None:
    pc = cloud.reproject(np.full((3, 3), INVALID, np.uint16), Q, 1.0)
    data = cloud.ply_bytes(pc, "nothing valid")
    assert b"element vertex 0\n" in data and data.endswith(b"end_header\n")


@pytest.mark.parametrize("bad, message", [
    (np.zeros((4, 4)), "Q\\[3\\]\\[2\\] is 0"),
    (np.zeros((3, 4)), "finite 4x4"),
])
def test_a_q_without_depth_is_refused(bad, message) -> None:
    with pytest.raises(ValueError, match=message):
        cloud.reproject(codes(), bad, 1.0)


def test_disparity_png_is_exact_16_bit(tmp_path) -> None:
    rng = np.random.default_rng(0)
    d = rng.integers(0, 128 * 16, size=(30, 40)).astype(np.uint16)
    d[::3, ::5] = INVALID
    path = tmp_path / "disparity.png"
    path.write_bytes(disparity_images.disparity_png(d))
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16 and np.array_equal(back, d)
    with Image.open(path) as im:
        assert np.array_equal(np.asarray(im).astype(np.int64), d.astype(np.int64))


def test_confidence_png_and_colour_rendering(tmp_path) -> None:
    conf = np.arange(256, dtype=np.uint8).reshape(16, 16)
    back = cv2.imdecode(np.frombuffer(disparity_images.confidence_png(conf), np.uint8), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint8 and np.array_equal(back, conf)
    d = np.array([[INVALID, 0, 64 * 16, 128 * 16]], np.uint16)
    rgb = disparity_images.colour_disparity(d, 128)
    assert rgb[0, 0].tolist() == [0, 0, 0]
    jet = cv2.applyColorMap(np.array([[0, 128, 255]], np.uint8), cv2.COLORMAP_JET)[0, :, ::-1]
    assert rgb[0, 1:].tolist() == jet.tolist()
    img = Image.open(io.BytesIO(disparity_images.colour_png(d, 128)))
    assert img.mode == "RGB" and np.array_equal(np.asarray(img), rgb)
