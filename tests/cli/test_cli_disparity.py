"""``stereocam disparity``: real pairs in, the stereo core's model out as PNGs and a PLY read back
with other parsers, one-line errors with exit code 2 and nothing written for bad input."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from stereocam.cli import main
from stereocam.overlays.model.stereo import compute
from stereocam.overlays.spec.pixel import gray_of
from stereocam.overlays.spec.stereo import DEFAULT_PARAMS, INVALID

from ..sample import calibrate_sample, pair_paths, write_opencv_files
from .one_line import run_error

OUTPUTS = ["confidence.png", "disparity.png", "disparity_colour.png"]


@pytest.fixture(scope="module")
def cal_arg(tmp_path_factory) -> str:
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path_factory.mktemp("cal"))
    return f"{intr},{extr}"


def read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None, path
    return image


def test_rectified_pair_gives_the_models_codes(tmp_path, capsys) -> None:
    left, right = pair_paths(1)
    out = tmp_path / "out"
    assert main(["disparity", "--rectified", "--num-disp", "64", "--no-median", "-o", str(out),
                 str(left), str(right)]) == 0
    assert "640x480" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == OUTPUTS
    params = DEFAULT_PARAMS.with_values(num_disp=64, median=False)
    expected = compute(read(left), read(right), params)
    disp = read(out / "disparity.png")
    assert disp.dtype == np.uint16 and np.array_equal(disp, expected.disp)
    assert np.array_equal(read(out / "confidence.png"), expected.conf)
    colour = read(out / "disparity_colour.png")
    assert colour.shape == (480, 640, 3)
    assert np.all(colour[expected.disp == INVALID] == 0)
    assert 0 < np.count_nonzero(expected.disp == INVALID) < expected.disp.size


def test_colour_pair_is_matched_on_the_cores_gray(tmp_path) -> None:
    paths = []
    for i, p in enumerate(pair_paths(2)):
        img = cv2.applyColorMap(read(p)[:200, :300], cv2.COLORMAP_TURBO)
        paths.append(tmp_path / f"c{i}.png")
        cv2.imwrite(str(paths[-1]), img)
    argv = ["disparity", "--rectified", "--num-disp", "32", "-o", str(tmp_path / "o"), *map(str, paths)]
    assert main(argv) == 0
    gray = [gray_of(cv2.cvtColor(read(p), cv2.COLOR_BGR2RGB)) for p in paths]
    expected = compute(gray[0], gray[1], DEFAULT_PARAMS.with_values(num_disp=32))
    assert np.array_equal(read(tmp_path / "o" / "disparity.png"), expected.disp)


def test_calibrated_pair_is_rectified_as_rectify_does_and_gives_a_cloud_in_metres(tmp_path, cal_arg) -> None:
    left, right = pair_paths(3)
    rect = ["rectify", "--calibration", cal_arg, "-o", str(tmp_path / "rect"), str(left), str(right)]
    assert main(rect) == 0
    out = tmp_path / "out"
    assert main(["disparity", "--calibration", cal_arg, "--units", "mm", "-o", str(out),
                 str(left), str(right)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS + ["cloud.ply"])
    rect_left, rect_right = read(tmp_path / "rect" / "left.png"), read(tmp_path / "rect" / "right.png")
    expected = compute(rect_left, rect_right)
    disp = read(out / "disparity.png")
    assert np.array_equal(disp, expected.disp)

    # The cloud by hand: [X Y Z W] = Q [x y d 1], the point (X, Y, Z) / W in the unit of T (here mm).
    Q = calibrate_sample().rect.Q
    ys, xs = np.nonzero(disp != INVALID)
    d = disp[ys, xs] / 16.0
    X, Y, Z, W = Q @ np.stack([xs, ys, d, np.ones_like(d)])
    keep = W != 0  # d = 0: at infinity, dropped
    assert np.count_nonzero(~keep) > 0
    hand = np.stack([X[keep], Y[keep], Z[keep]], axis=1) / W[keep, None] / 1000.0
    ply = (out / "cloud.ply").read_bytes()
    assert ply.startswith(b"ply\nformat binary_little_endian 1.0\ncomment stereocam")
    cloud = trimesh.load(out / "cloud.ply")
    assert isinstance(cloud, trimesh.PointCloud) and len(cloud.vertices) == len(hand) > 1000
    np.testing.assert_allclose(cloud.vertices, hand, rtol=1e-5)
    assert np.array_equal(cloud.colors[:, 0], rect_left[ys, xs][keep])
    assert np.all(cloud.vertices[:, 2] > 0)


def test_units_are_asked_for_when_the_calibration_does_not_say(tmp_path, cal_arg, capsys) -> None:
    err = run_error(capsys, ["disparity", "--calibration", cal_arg, "-o", str(tmp_path / "o"),
                             *map(str, pair_paths(1))])
    assert "--units" in err
    assert not (tmp_path / "o").exists()


def test_bad_input_is_one_line_and_writes_nothing(tmp_path, cal_arg, capsys) -> None:
    left, right = map(str, pair_paths(1))
    out = tmp_path / "o"
    not_image = tmp_path / "notes.png"
    not_image.write_text("not an image")
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), read(Path(left))[:100, :100])
    wide = [tmp_path / "wl.png", tmp_path / "wr.png"]
    for p in wide:
        cv2.imwrite(str(p), np.zeros((20, 800), np.uint8))
    broken = tmp_path / "broken.yaml"
    broken.write_text("schema_version: 1\nid: nonsense\n")
    cases = [
        (["--rectified", str(tmp_path / "missing.png"), right], "no such file"),
        (["--rectified", str(not_image), right], "not a readable image"),
        (["--rectified", left, str(small)], "the pair must have the same size"),
        (["--rectified", *map(str, wide)], "width 800: the core takes 9 .. 752 pixels"),
        (["--calibration", str(broken), left, right], "broken.yaml"),
        (["--rectified", "--num-disp", "100", left, right], "num_disp = 100"),
        (["--rectified", "--p1", "50", "--p2-edge", "20", left, right], "p1 <= p2_edge <= p2"),
    ]
    for argv, message in cases:
        err = run_error(capsys, ["disparity", "-o", str(out), *argv])
        assert message in err, (argv, err)
        assert not out.exists(), argv


def test_an_output_that_is_a_file_is_refused(tmp_path, capsys) -> None:
    target = tmp_path / "taken"
    target.write_text("keep")
    err = run_error(capsys, ["disparity", "--rectified", "-o", str(target), *map(str, pair_paths(1))])
    assert "is a file" in err and target.read_text() == "keep"


def test_rectified_and_calibration_exclude_each_other(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["disparity", "-o", "x", "a.png", "b.png"])
    assert exc.value.code == 2
    assert "one of the arguments --calibration --rectified is required" in capsys.readouterr().err


def test_a_calibration_that_says_its_unit_needs_no_units_option(tmp_path, cal_arg) -> None:
    yaml = tmp_path / "cal.yaml"
    assert main(["calibration", "import", *cal_arg.split(","), "--size", "640x480", "-o", str(yaml)]) == 0
    text = yaml.read_text()
    assert 'units: "unknown"' in text
    yaml.write_text(text.replace('units: "unknown"', 'units: "m"'))  # units are not hashed: still valid
    left, right = map(str, pair_paths(4))
    assert main(["disparity", "--calibration", str(yaml), "-o", str(tmp_path / "m"), left, right]) == 0
    argv = ["disparity", "--calibration", cal_arg, "--units", "mm", "-o", str(tmp_path / "mm"), left, right]
    assert main(argv) == 0
    in_m, in_mm = (trimesh.load(tmp_path / d / "cloud.ply").vertices for d in ("m", "mm"))
    np.testing.assert_allclose(in_m, in_mm * 1000, rtol=1e-6)
