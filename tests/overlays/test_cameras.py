"""Emulated live cameras: the synthetic rig of known calibration, and replay of recorded frames."""
from __future__ import annotations

from pathlib import Path
from typing import Tuple

import cv2
import numpy as np
import pytest

from stereocam.calibration.stereo import StereoModel
from stereocam.overlays.emulated.cameras import CameraSource, SourceClosedError
from stereocam.overlays.emulated.lens import rig_model, undistort_normalized
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.emulated.replay import ReplayEnded, ReplayError, ReplaySource
from stereocam.overlays.emulated.scene import SCENE
from stereocam.overlays.emulated.targets import board_corners, board_image, board_size_m
from stereocam.overlays.model import camera_in as camera_model
from stereocam.overlays.spec import camera_in as camera_spec
from stereocam.overlays.spec.pixel import gray_of, pack, rgby

from ..sample import png_claiming

DATA = Path(__file__).parents[1] / "data" / "opencv-stereo-calib"


@pytest.fixture(scope="module")
def rig() -> SyntheticRig:
    return SyntheticRig()


@pytest.fixture(scope="module")
def small_rig() -> SyntheticRig:
    return SyntheticRig(size=(188, 120))


# -- the rig's model ---------------------------------------------------------

def test_rig_model_is_a_realistic_non_trivial_stereo_pair() -> None:
    m = rig_model()
    assert isinstance(m, StereoModel) and m.image_size == (752, 480)
    assert m.K1[0, 0] == 420.0 and m.K2[0, 0] != m.K1[0, 0]
    assert m.D1[0] == -0.15 and np.all(m.D1 != 0) and np.all(m.D2 != 0)
    assert m.baseline == pytest.approx(0.06, abs=1e-3)  # metres
    centre_right = -m.R.T @ m.T
    assert centre_right[0] == pytest.approx(0.060)  # the right camera is 60 mm to the right
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(m.R)[0]))
    assert 0.8 < angle < 1.5


def test_rig_model_scales_with_the_image_size() -> None:
    small, full = rig_model((376, 240)), rig_model()
    assert small.image_size == (376, 240)
    assert small.K1[0, 0] == pytest.approx(full.K1[0, 0] / 2)
    assert small.K1[0, 2] == pytest.approx((full.K1[0, 2] + 0.5) / 2 - 0.5)
    assert np.array_equal(small.D1, full.D1) and np.array_equal(small.T, full.T)
    with pytest.raises(ValueError, match="too small"):
        rig_model((8, 8))


def test_undistortion_is_the_exact_inverse_of_the_distortion() -> None:
    m = rig_model()
    u, v = np.meshgrid(np.linspace(-0.5, 751.5, 41), np.linspace(-0.5, 479.5, 27))
    x, y = undistort_normalized(m.K1, m.D1, u, v)
    uv, _ = cv2.projectPoints(np.stack([x.ravel(), y.ravel(), np.ones(x.size)], -1), np.zeros(3), np.zeros(3),
                              m.K1, m.D1)
    assert np.abs(uv[:, 0, 0] - u.ravel()).max() < 1e-9
    assert np.abs(uv[:, 0, 1] - v.ravel()).max() < 1e-9
    # cv2.undistortPoints alone (5 fixed-point steps) would not be exact in the corners:
    assert np.hypot(x[0, 0], y[0, 0]) > 1.2  # and the corner ray is far off axis (wide lens)


# -- frames ------------------------------------------------------------------

def test_rig_frames_are_stereo_stream_frames(rig: SyntheticRig) -> None:
    assert isinstance(rig, CameraSource)
    assert rig.frame_size == (752, 480)
    frame = rig.read(0, 0.0)
    assert frame.shape == (480, 752, 8) and frame.dtype == np.uint8
    assert frame.flags.writeable and frame.flags.c_contiguous
    assert 60 < frame[..., 3].mean() < 200 and frame[..., 3].std() > 20  # exposed and textured
    assert not np.array_equal(frame[..., 0:4], frame[..., 4:8])


def test_gray_channel_is_exactly_the_demosaic_gray(rig: SyntheticRig) -> None:
    frame = rig.read(7, 2.5)
    for cam in (slice(0, 4), slice(4, 8)):
        view = frame[..., cam]
        assert np.array_equal(view[..., 3], gray_of(view[..., :3]))
    assert not np.array_equal(frame[..., 0], frame[..., 1])  # colour


def test_gray_rig_is_a_gray_world_through_the_bayer_filter() -> None:
    """A gray scene seen by the colour sensors: no colour cast, colour fringes only at fine detail."""
    rig = SyntheticRig(size=(188, 120), colour=False)
    frame = rig.read(0, 0.0)
    assert np.array_equal(frame, camera_model.demosaic(*rig.raw))
    for c in (1, 2, 4, 5, 6):
        assert abs(float(frame[..., c].mean()) - float(frame[..., 0].mean())) < 1.0
    # every camera sample is the gray radiance: a flat gray world gives R = G = B = Y exactly
    flat = SyntheticRig(size=(188, 120), colour=False)
    flat.set_sensor(0, test_pattern=np.full((120, 188), 77, np.uint8))
    assert np.all(flat.read(0, 0.0)[..., :4] == 77)


def test_rig_frames_move_but_are_deterministic(rig: SyntheticRig, small_rig: SyntheticRig) -> None:
    a = rig.read(3, 1.5)
    assert np.array_equal(a, rig.read(3, 1.5))
    b = rig.read(4, 2.5)
    changed = np.any(a != b, axis=2)
    assert changed.mean() > 0.03  # the objects moved ...
    assert not changed[-40:].any()  # ... the floor did not
    small = small_rig.read(3, 1.5)
    assert np.array_equal(small, SyntheticRig(size=(188, 120), seed=0).read(3, 1.5))  # a new rig, same seed
    assert not np.array_equal(small, SyntheticRig(size=(188, 120), seed=1).read(3, 1.5))


def test_a_still_rig_ignores_time(small_rig: SyntheticRig) -> None:
    still = SyntheticRig(size=(188, 120), motion=False)
    a = still.read(0, 0.0)
    assert np.array_equal(a, still.read(9, 4.0))
    assert np.array_equal(a, small_rig.read(0, 0.0))  # the moving rig at rest is the still rig
    a[:] = 0  # the caller owns the frame
    assert still.read(1, 1.0).any()


def test_fast_rendering_equals_full_rendering(small_rig: SyntheticRig) -> None:
    """Redoing only the moving region (and the demosaic's one pixel of reach) is exact."""
    for t in (0.0, 1.7, 5.2):
        full = [camera_model.demosaic_camera(small_rig._sensor(small_rig._radiance(cam, t)[0], cam, 0))
                for cam in (0, 1)]
        assert np.array_equal(small_rig.read(0, t), pack(full[0], full[1]))


# -- the Bayer path: what the camera input IP outputs for the sensors' samples --

def test_rig_frames_are_the_camera_input_model_of_their_bayer_samples(small_rig: SyntheticRig) -> None:
    """Every frame is model.demosaic of the 10-bit mosaic the two sensors read out (the RTL's output)."""
    for t in (0.0, 2.3):
        frame = small_rig.read(1, t)
        left, right = small_rig.raw
        assert left is not None and right is not None
        assert left.dtype == np.uint16 and left.shape == (120, 188) and int(left.max()) <= 1023
        assert np.array_equal(frame, camera_model.demosaic(left, right))
    # the mosaic samples each pixel's own colour: where a red sample sits, it is 4 x the 8-bit red level
    r_col, r_row = camera_model.phase_cell(camera_spec.BAYER_PHASE)
    red = left[r_row::2, r_col::2].astype(int)
    assert abs(red.mean() / 4 - frame[r_row::2, r_col::2, 0].mean()) < 1.0


def test_sensor_gain_flips_and_noise_stay_on_the_bayer_path() -> None:
    rig = SyntheticRig(size=(188, 120), motion=False)
    plain = rig.read(0, 0.0)
    for kw in ({"gain": 1.5}, {"flip_h": True}, {"flip_v": True, "flip_h": True}, {"noise": 2.0}):
        rig.set_sensor(1, **kw)  # type: ignore[arg-type]
        frame = rig.read(3, 0.0)
        assert np.array_equal(frame, camera_model.demosaic(*rig.raw)), kw
        rig.set_sensor(1)
        rig.set_sensor(1, noise=0.0)
    # an even-sized flipped read-out keeps the first pixel's colour (spec.camera_in.cfa_phase), so the
    # mirrored image has the right colours: it differs from the mirrored frame only by resampling
    rig.set_sensor(0, flip_h=True, flip_v=True)
    flipped = rig.read(4, 0.0).astype(int)
    means, flipped_means = plain[..., :3].mean(axis=(0, 1)), flipped[..., :3].mean(axis=(0, 1))
    assert abs(means[0] - means[2]) > 3  # the scene is tinted: swapped R and B would show
    assert np.abs(flipped_means - means).max() < 1.0
    assert np.array_equal(flipped[..., 1], plain[::-1, ::-1, 1])  # green sites map onto green sites
    assert np.abs(flipped[..., :3] - plain[::-1, ::-1, :3]).mean() < 12  # R, B: one pixel over
    assert np.array_equal(flipped[..., 4:], plain[..., 4:])


def test_test_patterns_go_through_the_demosaic() -> None:
    rig = SyntheticRig(size=(188, 120), motion=False)
    ramp = np.tile((np.arange(188) * 256 // 188).astype(np.uint8), (120, 1))
    rig.set_sensor(0, test_pattern=ramp, flip_h=True)  # patterns are not flipped
    frame = rig.read(0, 0.0)
    assert np.array_equal(frame[..., :4], camera_model.demosaic_camera(ramp.astype(np.uint16) << 2))
    assert np.abs(frame[..., 3].astype(int) - ramp).max() <= 1
    assert rig.raw[0] is None and rig.raw[1] is not None


def test_replayed_frames_are_not_mosaicked_again(tmp_path: Path) -> None:
    """Recordings are the IP's output already: they play back exactly as recorded."""
    img = np.random.default_rng(3).integers(0, 256, (24, 32, 3), np.uint8)
    cv2.imwrite(str(tmp_path / "left0.png"), img[..., ::-1])
    cv2.imwrite(str(tmp_path / "right0.png"), img)
    frame = ReplaySource(tmp_path).read(0)
    assert np.array_equal(frame[..., :3], img) and np.array_equal(frame[..., 4:7], img[..., ::-1])


def test_sensor_noise_is_seeded_by_the_frame_index() -> None:
    clean = SyntheticRig(size=(188, 120)).read(2, 1.0).astype(np.int16)
    noisy = SyntheticRig(size=(188, 120), noise=3.0)
    a, b = noisy.read(2, 1.0), noisy.read(3, 1.0)
    assert np.array_equal(a, noisy.read(2, 1.0))
    diff = a.astype(np.int16) - clean
    assert abs(diff.mean()) < 0.2 and 2.0 < diff[..., 0].std() < 4.0
    assert not np.array_equal(a, b)
    assert np.array_equal(a[..., 3], gray_of(a[..., :3]))
    with pytest.raises(ValueError, match="noise"):
        SyntheticRig(size=(188, 120), noise=-1.0)


def test_read_validates_and_close_ends_the_source() -> None:
    rig = SyntheticRig(size=(188, 120))
    with pytest.raises(ValueError, match="index"):
        rig.read(-1, 0.0)
    with pytest.raises(ValueError, match="finite"):
        rig.read(0, float("nan"))
    with rig:
        rig.read(0, 0.0)
    rig.close()
    with pytest.raises(SourceClosedError, match="closed"):
        rig.read(0, 0.0)


def test_rig_accepts_a_given_model() -> None:
    base = rig_model((188, 120))
    T = np.array([-0.1, 0.0, 0.0])
    model = StereoModel(base.K1, base.D1 * 0.5, base.K2, base.D2, np.eye(3), T, (188, 120))
    rig = SyntheticRig(model=model)
    assert rig.model is model and rig.frame_size == (188, 120)
    with pytest.raises(ValueError, match="disagrees"):
        SyntheticRig(size=(200, 100), model=model)


def _match(left: np.ndarray, right: np.ndarray, at: Tuple[int, int], search: int = 45) -> Tuple[float, float]:
    """Where the 21x21 patch of ``left`` centred on pixel ``at`` is in ``right`` (sub-pixel)."""
    half = 10
    u, v = at
    patch = left[v - half:v + half + 1, u - half:u + half + 1]
    x0, y0 = u - half - search, v - half - search
    area = right[y0:y0 + 2 * half + 1 + 2 * search, x0:x0 + 2 * half + 1 + 2 * search]
    score = cv2.matchTemplate(area, patch, cv2.TM_CCOEFF_NORMED)
    _, best, _, (bx, by) = cv2.minMaxLoc(score)
    assert best > 0.8

    def peak(a: float, b: float, c: float) -> float:
        return 0.5 * (a - c) / (a - 2 * b + c)

    dx = peak(*score[by, bx - 1:bx + 2])
    dy = peak(*score[by - 1:by + 2, bx])
    return x0 + bx + dx + half, y0 + by + dy + half


def test_left_and_right_views_agree_with_the_calibration(rig: SyntheticRig) -> None:
    """Points on the box face (1.0 m) and the wall appear in the right view where the model projects them."""
    frame = rig.read(0, 0.0)  # t = 0: the box is at its rest position
    left, right = frame[..., 3], frame[..., 7]
    box = next(p for p in SCENE if p.name == "box")
    ox, oy, oz = box.origin
    m = rig.model
    rvec2, _ = cv2.Rodrigues(m.R)
    for point, expected_disparity in (((ox - 0.08, oy - 0.05, oz), 25.0), ((ox + 0.1, oy + 0.07, oz), 25.0)):
        X = np.array([point], np.float64)
        pl, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), m.K1, m.D1)
        pr, _ = cv2.projectPoints(X, rvec2, m.T, m.K2, m.D2)
        ul, vl = pl[0, 0]
        at = (int(round(ul)), int(round(vl)))
        found = np.array(_match(left, right, at))
        expected = pr[0, 0] + (np.array(at) - pl[0, 0])  # the patch is centred on the rounded pixel
        assert np.abs(found - expected).max() < 0.6, (point, found, expected)
        # f B / Z = 420 * 0.06 / 1.0, give or take the distortion
        assert ul - found[0] == pytest.approx(expected_disparity, abs=6)
    # a wall pixel (about 3 m away): small positive disparity
    wl = (100, 60)
    wall_u, _ = _match(left, right, wl, search=30)
    assert 0 < wl[0] - wall_u < 15


# -- calibration targets -----------------------------------------------------

def test_rendered_checkerboard_corners_are_where_the_model_projects_them(rig: SyntheticRig) -> None:
    cols, rows, square = 9, 6, 0.03
    board = board_image(cols, rows)
    size_m = board_size_m((cols, rows), square)
    corners = board_corners((cols, rows), square)
    m = rig.model
    poses = (((0.3, -0.4, 0.1), (-0.2, -0.12, 0.55)), ((-0.2, 0.5, 0.6), (0.0, -0.1, 0.65)))
    for rvec, tvec in poses:
        pose_R, _ = cv2.Rodrigues(np.array(rvec))
        pose_t = np.array(tvec)
        views = rig.render_plane_views(board, size_m, pose_R, pose_t)
        expected = (
            cv2.projectPoints(corners, np.array(rvec), pose_t, m.K1, m.D1)[0],
            cv2.projectPoints(corners, cv2.Rodrigues(m.R @ pose_R)[0], m.R @ pose_t + m.T, m.K2, m.D2)[0],
        )
        for view, proj in zip(views, expected, strict=True):
            assert view.shape == (480, 752) and view.dtype == np.uint8
            found, found_corners = cv2.findChessboardCorners(view, (cols, rows))
            assert found
            refined = cv2.cornerSubPix(view, found_corners, (5, 5), (-1, -1),
                                       (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
            err = np.linalg.norm(refined.reshape(-1, 2) - proj.reshape(-1, 2), axis=1)
            assert err.max() < 0.3, err.max()


def test_plane_views_background_and_validation(small_rig: SyntheticRig) -> None:
    target = np.full((10, 10, 3), 200, np.uint8)
    R = np.eye(3)
    left, right = small_rig.render_plane_views(target, (0.2, 0.2), R, (-0.1, -0.1, 0.5), background=30,
                                               supersample=1)
    assert left[60, 94] == 200 and left[2, 2] == 30 and right[2, 2] == 30
    far = small_rig.render_plane_views(target, (0.2, 0.2), R, (-0.1, -0.1, 5.0), background="scene",
                                       supersample=1)
    assert far[0][60, 94] != 200  # behind the wall: hidden by the scene
    full = small_rig.render_plane_views(target, (0.2, 0.2), R, (-0.1, -0.1, 0.5), background=30,
                                        supersample=1, rgby=True)  # the IP's whole output: Y is the gray view
    assert full[0].shape == left.shape + (4,)
    assert np.array_equal(full[0][..., 3], left) and np.array_equal(full[1][..., 3], right)
    edge = full[0][:, 80:110].astype(int)  # where the print meets the background the CFA shows in R, G, B
    assert (edge[..., 0] != edge[..., 2]).any() and edge[60, 14, 0] == 200
    for kwargs, match in (
        (dict(background="sky"), "background"), (dict(background=300), "0..255"),
        (dict(supersample=9), "supersample"),
    ):
        with pytest.raises(ValueError, match=match):
            small_rig.render_plane_views(target, (0.2, 0.2), R, (0, 0, 1), **kwargs)
    with pytest.raises(ValueError, match="rotation"):
        small_rig.render_plane_views(target, (0.2, 0.2), 2 * R, (0, 0, 1))
    with pytest.raises(ValueError, match="uint8"):
        small_rig.render_plane_views(target.astype(np.float32), (0.2, 0.2), R, (0, 0, 1))
    with pytest.raises(ValueError, match="metres, both > 0"):
        small_rig.render_plane_views(target, (0.0, 0.2), R, (0, 0, 1))


# -- replay ------------------------------------------------------------------

def _images(seed: int, n: int, shape: Tuple[int, ...] = (24, 32, 3)) -> list:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(n)]


def _write(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
    assert cv2.imwrite(str(path), image)


def test_replay_of_left_right_pairs_round_trips_and_loops(tmp_path: Path) -> None:
    lefts, rights = _images(1, 3), _images(2, 3)
    for suffix, lft, rgt in zip(("_2", "_10", "_1"), lefts, rights, strict=True):
        _write(tmp_path / f"left{suffix}.png", lft)
        _write(tmp_path / f"Right{suffix}.PNG", rgt)
    (tmp_path / "notes.txt").write_text("ignored")
    order = [2, 0, 1]  # natural order of the suffixes: _1, _2, _10
    with ReplaySource(tmp_path) as src:
        assert isinstance(src, CameraSource)
        assert src.frame_size == (32, 24) and len(src) == 3
        assert src.names[0] == "left_1.png+Right_1.PNG"
        for index in range(7):
            k = order[index % 3]
            frame = src.read(index, index / 30)
            assert np.array_equal(frame, pack(rgby(lefts[k]), rgby(rights[k])))
        assert src.read(1, 0.0) is src.read(4, 0.0)  # cached
        assert not src.read(0, 0.0).flags.writeable
    with pytest.raises(SourceClosedError):
        src.read(0, 0.0)
    once = ReplaySource(tmp_path, loop=False)
    once.read(2, 0.0)
    with pytest.raises(ReplayEnded, match="has 3 frames"):
        once.read(3, 0.0)


def test_replay_of_gray_jpeg_and_bmp_pairs(tmp_path: Path) -> None:
    grays = _images(3, 2, (24, 32))
    _write(tmp_path / "left0.bmp", grays[0])
    _write(tmp_path / "right0.bmp", grays[1])
    frame = ReplaySource(tmp_path).read(0, 0.0)
    assert np.array_equal(frame, pack(rgby(grays[0]), rgby(grays[1])))


def test_replay_of_the_opencv_sample_pairs() -> None:
    src = ReplaySource(DATA)
    assert len(src) == 13 and src.frame_size == (640, 480)
    frame = src.read(0, 0.0)
    gray = cv2.imread(str(DATA / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    assert gray is not None
    assert np.array_equal(frame[..., 3], gray) and np.array_equal(frame[..., 0], gray)


def test_replay_of_capture_folders(tmp_path: Path) -> None:
    lefts, rights = _images(4, 2), _images(5, 2)
    for name, lft, rgt in zip(("capture-0002", "capture-0001"), lefts, rights, strict=True):
        _write(tmp_path / name / "raw_left.png", lft)
        _write(tmp_path / name / "raw_right.png", rgt)
    (tmp_path / "empty-dir").mkdir()
    src = ReplaySource(tmp_path)
    assert src.names == ["capture-0001", "capture-0002"]
    assert np.array_equal(src.read(0, 0.0), pack(rgby(lefts[1]), rgby(rights[1])))


def test_replay_of_side_by_side_images(tmp_path: Path) -> None:
    images = _images(6, 2, (24, 64, 3))
    _write(tmp_path / "sbs_b.png", images[1])
    _write(tmp_path / "sbs_a.png", images[0])
    src = ReplaySource(tmp_path)
    assert src.frame_size == (32, 24)
    assert np.array_equal(src.read(1, 0.0), pack(rgby(images[1][:, :32]), rgby(images[1][:, 32:])))


def _error(folder: Path) -> str:
    with pytest.raises(ReplayError) as info:
        ReplaySource(folder).read(0, 0.0)
    assert isinstance(info.value, ValueError)
    return str(info.value)


def test_replay_errors_say_what_is_wrong_and_what_to_do(tmp_path: Path) -> None:
    assert "does not exist" in _error(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    assert "holds no recordings" in _error(tmp_path / "empty")

    img = _images(7, 1)[0]
    unmatched = tmp_path / "unmatched"
    _write(unmatched / "left1.png", img)
    _write(unmatched / "right1.png", img)
    _write(unmatched / "left2.png", img)
    msg = _error(unmatched)
    assert "left2.png" in msg and "no partner" in msg and "right<suffix>" in msg

    sizes = tmp_path / "sizes"
    _write(sizes / "left1.png", img)
    _write(sizes / "right1.png", img[:20])
    assert "left1.png is 32x24 but right1.png is 32x20" in _error(sizes)

    drift = tmp_path / "drift"
    for name in ("left1.png", "right1.png"):
        _write(drift / name, img)
    for name in ("left2.png", "right2.png"):
        _write(drift / name, img[:, :30])
    msg = _error(drift)
    assert "left2.png is 30x24" in msg and "same size" in msg

    corrupt = tmp_path / "corrupt"
    _write(corrupt / "left1.png", img)
    (corrupt / "right1.png").write_bytes(b"this is not an image")
    msg = _error(corrupt)
    assert "cannot read image" in msg and "right1.png" in msg and "replace or remove" in msg

    mixed = tmp_path / "mixed"
    _write(mixed / "left1.png", img)
    _write(mixed / "right1.png", img)
    _write(mixed / "sbs1.png", img)
    assert "mixes left/right pairs and side-by-side" in _error(mixed)

    odd = tmp_path / "odd"
    _write(odd / "sbs1.png", img[:, :31])
    assert "odd number" in _error(odd)

    half = tmp_path / "half"
    _write(half / "cap1" / "raw_left.png", img)
    assert "has raw_left.png but no raw_right.png" in _error(half)

    twice = tmp_path / "twice"
    for name in ("left1.png", "left1.bmp", "right1.png"):
        _write(twice / name, img)
    assert "same frame in two files" in _error(twice)

    deep = tmp_path / "deep"
    _write(deep / "left1.png", img)
    assert cv2.imwrite(str(deep / "right1.png"), img.astype(np.uint16) * 256)
    assert "uint16" in _error(deep) and "8 bits" in _error(deep)


TOO_MANY_PIXELS = "the image header claims more than the 16.8 megapixels read"


def test_replay_refuses_an_image_whose_header_claims_too_many_pixels(tmp_path: Path) -> None:
    img = _images(9, 1, (48, 64, 3))[0]
    _write(tmp_path / "left1.png", img)
    (tmp_path / "right1.png").write_bytes(png_claiming(5000, 5000))  # 25 megapixels, before any decode
    msg = _error(tmp_path)
    assert f"right1.png: {TOO_MANY_PIXELS}: 5000x5000" in msg and "replace or remove it" in msg


def test_replay_names_a_file_truncated_after_its_header(tmp_path: Path) -> None:
    img = _images(8, 1, (48, 64, 3))[0]
    _write(tmp_path / "left1.png", img)
    _write(tmp_path / "right1.png", img)
    data = (tmp_path / "right1.png").read_bytes()
    (tmp_path / "right1.png").write_bytes(data[: len(data) // 2])
    src = ReplaySource(tmp_path)  # the header is fine
    with pytest.raises(ReplayError, match=r"cannot decode image .*right1\.png .*replace or remove"):
        src.read(0, 0.0)
