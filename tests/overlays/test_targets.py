"""Emulated calibration targets: a checkerboard held up to the synthetic rig, pose after pose."""
from __future__ import annotations

import math
import threading
from typing import Any, Iterator, List, Tuple

import cv2
import numpy as np
import pytest

from stereocam.board.profile import load_profile
from stereocam.calibration.calibrate import ImagePair, Pattern, calibrate_pairs, detect_corners
from stereocam.calibration.stereo import StereoModel
from stereocam.overlays.emulated.cameras import CameraSource, SourceClosedError
from stereocam.overlays.emulated.lens import rig_model
from stereocam.overlays.emulated.logic import EmulatedFabric
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.emulated.sensors import EmulatedSensorPair
from stereocam.overlays.emulated.targets import (
    CheckerboardTarget,
    board_corners,
    board_image,
    board_size_m,
    random_board_poses,
)
from stereocam.overlays.spec import pixel

PATTERN = Pattern.parse("9x6", "25mm")


@pytest.fixture(scope="module")
def target() -> Iterator[CheckerboardTarget]:
    with CheckerboardTarget() as t:
        yield t


def mid_hold(target: CheckerboardTarget, k: int) -> float:
    """A time well inside hold ``k`` (away from float rounding at its edges)."""
    return (k + 0.5) * target.hold_s


def views(frame: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(frame[..., 3]), np.ascontiguousarray(frame[..., 7])


def projected(model: StereoModel, pose: Tuple[np.ndarray, np.ndarray]) -> Tuple[np.ndarray, np.ndarray]:
    """Where the true model puts the board's inner corners in the left and right images."""
    R, t = pose
    corners = board_corners(PATTERN.size, PATTERN.square)
    left = cv2.projectPoints(corners, cv2.Rodrigues(R)[0], t, model.K1, model.D1)[0]
    right = cv2.projectPoints(corners, cv2.Rodrigues(model.R @ R)[0], model.R @ t + model.T,
                              model.K2, model.D2)[0]
    return left.reshape(-1, 2), right.reshape(-1, 2)


# -- the printed board and its poses -----------------------------------------------------------

def test_board_image_is_the_printed_board() -> None:
    board = board_image(9, 6, px=10)
    assert board.shape == (90, 120) and board.dtype == np.uint8
    assert set(np.unique(board)) == {0, 255}
    assert board[:10].min() == 255 and board[:, -10:].min() == 255  # one-square white margin
    assert board[15, 15] == 0 and board[15, 25] == 255 and board[25, 25] == 0  # black top-left square
    found, _ = cv2.findChessboardCorners(cv2.copyMakeBorder(board, 20, 20, 20, 20, cv2.BORDER_CONSTANT,
                                                            value=255), (9, 6))
    assert found
    assert board_size_m((9, 6), 0.025) == pytest.approx((0.3, 0.225))
    corners = board_corners((9, 6), 0.025)
    assert corners.shape == (54, 3) and corners[0] == pytest.approx([0.05, 0.05, 0.0])
    assert corners[1] - corners[0] == pytest.approx([0.025, 0.0, 0.0])
    assert corners[9] - corners[0] == pytest.approx([0.0, 0.025, 0.0])


def test_random_board_poses_are_seeded_and_show_the_whole_board() -> None:
    m = rig_model()
    a = random_board_poses(m, (9, 6), 0.025, n=5, rng=np.random.default_rng(3))
    b = random_board_poses(m, (9, 6), 0.025, n=5, rng=np.random.default_rng(3))
    assert len(a) == 5
    assert all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) for x, y in zip(a, b, strict=True))
    w, h = board_size_m((9, 6), 0.025)
    outline = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], float)
    for R, t in a:
        assert np.allclose(R.T @ R, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert 0.3 < np.linalg.norm(R @ [w / 2, h / 2, 0] + t) < 0.75
        for K, D, Rc, tc in ((m.K1, m.D1, R, t), (m.K2, m.D2, m.R @ R, m.R @ t + m.T)):
            p = cv2.projectPoints(outline, cv2.Rodrigues(Rc)[0], tc, K, D)[0].reshape(-1, 2)
            assert np.all(p >= 4) and np.all(p <= np.array(m.image_size) - 5)
    assert random_board_poses(m, n=0, rng=np.random.default_rng(0)) == []


# -- the camera source -------------------------------------------------------------------------

@pytest.mark.slow
def test_target_is_a_camera_source_of_the_rigs_true_model(target: CheckerboardTarget) -> None:
    assert isinstance(target, CameraSource)
    assert target.frame_size == (752, 480)
    assert isinstance(target.model, StereoModel) and target.model is target.rig.model
    assert target.pattern == (9, 6) and target.square == 0.025 and target.hold_s == 1.5
    frame = target.read(0, 0.0)
    assert frame.shape == (480, 752, 8) and frame.dtype == np.uint8 and frame.flags.writeable
    for base in (0, 4):  # a gray print through colour sensors: Y is the gray of the demosaiced R, G, B
        assert np.array_equal(frame[..., base + 3], pixel.gray_of(frame[..., base:base + 3]))
        assert abs(frame[..., base].mean() - frame[..., base + 2].mean()) < 3  # no colour cast
    assert not np.array_equal(frame[..., 3], frame[..., 7])


def test_corners_are_where_the_true_model_projects_them(target: CheckerboardTarget) -> None:
    for k in range(3):
        frame = target.read(k, mid_hold(target, k))
        for view, proj in zip(views(frame), projected(target.model, target.pose(k)), strict=True):
            found = detect_corners(view, PATTERN)
            assert found is not None, f"pose {k}: no board found"
            if np.linalg.norm(found[0] - proj[0]) > np.linalg.norm(found[-1] - proj[0]):
                found = found[::-1]  # the detector may start from the other end
            err = np.linalg.norm(found - proj, axis=1)
            assert err.max() < 0.3, (k, err.max())


def test_the_board_holds_still_then_moves_to_the_next_pose(target: CheckerboardTarget) -> None:
    hold = target.hold_s
    assert [target.pose_index(t) for t in (0.0, hold - 1e-6, hold, 2.5 * hold, 10 * hold + 0.1)] == [
        0, 0, 1, 2, 10]
    first = target.read(0, 0.0)
    for index, t in ((1, 1 / 60), (30, 0.5 * hold), (89, hold - 1e-3)):
        assert np.array_equal(target.read(index, t), first), t
    second = target.read(90, hold)
    assert np.abs(second.astype(int) - first).mean() > 5  # a new pose, not noise
    assert np.array_equal(target.read(95, hold + 0.05), second)
    assert not np.array_equal(target.pose(0)[1], target.pose(1)[1])
    again = CheckerboardTarget(target.rig, seed=target.seed)  # same seed: same poses
    assert all(np.array_equal(a, b) for a, b in zip(again.pose(7), target.pose(7), strict=True))


def test_more_exposure_makes_a_brighter_picture(target: CheckerboardTarget) -> None:
    t = mid_hold(target, 4)
    before = target.read(0, t)
    try:
        target.set_sensor(0, exposure_scale=1.5)
        brighter = target.read(1, t)
        assert brighter[..., 3].mean() > 1.3 * before[..., 3].mean()
        assert np.array_equal(brighter[..., 4:], before[..., 4:])  # the right camera kept its setting
        target.set_sensor(0, exposure_scale=1.5, flip_h=True)
        flipped = target.read(2, t)[..., :4].astype(int)  # resampled by the Bayer filter: nearly the mirror
        mirror = brighter[:, ::-1, :4].astype(int)
        assert np.abs(flipped - mirror).mean() < 0.5 * np.abs(flipped - brighter[..., :4]).mean()
        assert flipped.mean() == pytest.approx(mirror.mean(), abs=1.0)
    finally:
        target.set_sensor(0)
    assert np.array_equal(target.read(3, t), before)


def test_the_emulated_sensors_drive_the_target() -> None:
    profile = load_profile()
    target = CheckerboardTarget(SyntheticRig(size=(188, 120)), hold_s=0.1)
    pair = EmulatedSensorPair.for_profile(profile, target)
    sensors = profile.stereo_sensors(pair.bus)
    assert sensors.start()["ok"]
    fabric = EmulatedFabric(source=target, clock="stepped", sensors=pair, fps=60.0, ddr_size=16 << 20)
    try:
        sensors.apply({"exposure_us": 6000})  # doubled below, still within a frame (16.7 ms at 60 fps)
        fabric.step(3)
        dim = target.read(3, 3 / 60)
        sensors.apply({"exposure_us": 2 * sensors.read()["left"]["exposure_us"]})
        fabric.step(1)
        assert target.read(4, 4 / 60)[..., 3].mean() > 1.5 * dim[..., 3].mean()
        fabric.step(20)  # past a few holds
        assert fabric.counters.camera_frames == 24 and fabric.counters.camera_errors == 0
    finally:
        fabric.close()  # closes the target and its rig
    with pytest.raises(SourceClosedError):
        target.read(0, 0.0)


def test_reads_from_several_threads_agree(target: CheckerboardTarget) -> None:
    t = mid_hold(target, 5)
    out: List[np.ndarray] = []
    threads = [threading.Thread(target=lambda: out.append(target.read(0, t))) for _ in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(out) == 4 and all(np.array_equal(f, out[0]) for f in out)


@pytest.mark.slow
def test_eight_holds_calibrate_back_to_the_rigs_truth(target: CheckerboardTarget) -> None:
    pairs = [ImagePair(f"hold{k}", *views(target.read(k, mid_hold(target, k)))) for k in range(8)]
    report = calibrate_pairs(pairs, PATTERN)
    assert report.pairs_used == 8
    got, truth = report.calibration.model, target.model
    for K, K_true in ((got.K1, truth.K1), (got.K2, truth.K2)):
        assert K[0, 0] == pytest.approx(K_true[0, 0], rel=0.005)
        assert K[1, 1] == pytest.approx(K_true[1, 1], rel=0.005)
        assert np.abs(K[:2, 2] - K_true[:2, 2]).max() < 2.0
    assert got.baseline == pytest.approx(truth.baseline, rel=0.01)
    assert report.row_error_mean < 0.1


# -- bad arguments -----------------------------------------------------------------------------

@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(hold_s=0), "hold_s .*seconds \\(> 0\\)"),
    (dict(hold_s=-1.5), "hold_s .*seconds \\(> 0\\)"),
    (dict(hold_s=math.nan), "hold_s .*seconds \\(> 0\\)"),
    (dict(hold_s=math.inf), "hold_s .*seconds \\(> 0\\)"),
    (dict(pattern=(2, 6)), "pattern .* >= 3"),
    (dict(pattern=(9.5, 6)), "whole numbers"),
    (dict(pattern=(9, 6, 1)), "pattern is \\(cols, rows\\)"),
    (dict(square=0), "square .* metres"),
    (dict(square=-0.025), "square .* metres"),
    (dict(supersample=0), "supersample"),
    (dict(supersample=1.5), "supersample"),
    (dict(seed=-1), "seed"),
    (dict(square=0.2), "no pose .* fits"),
])
def test_bad_arguments_say_what_is_wrong(target: CheckerboardTarget, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CheckerboardTarget(target.rig, **kwargs)


def test_bad_calls_say_what_is_wrong(target: CheckerboardTarget) -> None:
    not_a_rig: Any = "synthetic"
    for call, match in (
        (lambda: target.read(-1, 0.0), "frame index"),
        (lambda: target.read(0, -0.1), "time .* >= 0"),
        (lambda: target.read(0, math.nan), "time .* finite"),
        (lambda: target.pose_index(math.inf), "time .* finite"),
        (lambda: target.pose(-1), "pose index"),
        (lambda: target.set_sensor(2), "camera is 0"),
        (lambda: CheckerboardTarget(rig=not_a_rig), "rig must be a SyntheticRig"),
        (lambda: board_image(0, 6), "pattern"),
        (lambda: board_image(9, 6, px=0), "px"),
        (lambda: random_board_poses(target.model, n=-1, rng=np.random.default_rng(0)), "n is"),
        (lambda: random_board_poses(target.model, n=1, rng=np.random.default_rng(0), distance=(0.7, 0.3)),
         "distance"),
    ):
        with pytest.raises(ValueError, match=match):
            call()


def test_closed_target_refuses_to_read() -> None:
    target = CheckerboardTarget(SyntheticRig(size=(188, 120)))
    target.close()
    target.close()  # idempotent
    with pytest.raises(SourceClosedError, match="closed"):
        target.read(0, 0.0)
