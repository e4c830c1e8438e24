"""``stereocam calibrate``: checkerboard pairs in, a calibration the core can run out, figures to trust."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Sequence, Tuple

import cv2
import numpy as np
import pytest

from stereocam.calibration.calibrate import (
    CalibrationError,
    CalibrationInputError,
    ImagePair,
    NotEnoughPairs,
    Pattern,
    calibrate_pairs,
    core_rectified_points,
    core_source,
    find_pairs,
    pairs_from_files,
    parse_length,
    parse_pattern,
)
from stereocam.calibration.file import load_calibration
from stereocam.cli import main
from stereocam.overlays.model.reference import source_position

from ..sample import DATA, PAIRS, SYNTH_SQUARE, calibrate_sample, pair_paths, png_claiming, synthetic_views

LEFTS = [str(pair_paths(i)[0]) for i in PAIRS]
RIGHTS = [str(pair_paths(i)[1]) for i in PAIRS]


def run(capsys, argv: List[str]) -> Tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def calibrate_argv(out: Path, *options: str, square: str = "25mm",
                   inputs: Sequence[str] = ("--left", *LEFTS, "--right", *RIGHTS)) -> List[str]:
    """``stereocam calibrate`` of the 9x6 pattern with ``options``, writing ``out``, from ``inputs``
    (by default OpenCV's sample pairs)."""
    return ["calibrate", "--pattern", "9x6", "--square", square, *options, "-o", str(out), *inputs]


def error_line(capsys, argv: List[str]) -> str:
    code, out, err = run(capsys, argv)
    assert code == 2, (out, err)
    last = err.rstrip("\n").splitlines()[-1]
    assert last.startswith("stereocam calibrate: error: "), err
    assert "Traceback" not in err
    return last


# -- OpenCV's sample ---------------------------------------------------------------


def test_sample_meets_the_floor_and_reports_as_one_json_object(tmp_path, capsys) -> None:
    out = tmp_path / "calibration.yaml"
    code, stdout, stderr = run(capsys, calibrate_argv(out, "--json"))
    assert code == 0, stderr
    assert stdout.count("\n") == 1, "--json prints exactly one line: the report"
    report = json.loads(stdout)
    assert "finding corners 0/13" in stderr and "finding corners" not in stdout, (
        "progress goes to stderr only"
    )
    assert report["pairs_used"] == 13 and report["pairs_rejected"] == 0
    assert all(p["used"] and p["reason"] == "" for p in report["pairs"])
    assert [p["name"] for p in report["pairs"]] == [Path(p).name for p in LEFTS]
    assert report["rms"] <= 0.45  # OpenCV's stereo_calib reaches 0.444 with this model
    assert report["row_error_mean"] <= 0.13  # ... and 0.126
    assert report["row_error_max"] < 1.0
    assert all(0 < p["rms"] < 0.6 and p["row_error_max"] >= p["row_error_mean"] > 0 for p in report["pairs"])
    assert report["rows_needed"] == 63 and report["lb_rows"] == 80 and report["fits"] is True
    assert report["lb_delay"] == 35 and report["image_size"] == [640, 480]
    # T in metres from 25 mm squares: OpenCV's 3.338 squares.
    assert report["baseline_m"] == pytest.approx(3.338 * 0.025, rel=0.01)
    assert report["left"]["fx"] == pytest.approx(536, rel=0.01) and report["left"]["k1"] == pytest.approx(
        -0.28, abs=0.02
    )
    assert report["output"] == str(out)
    cal = load_calibration(out)
    assert cal.id == report["id"] and cal.rows_needed == 63 and cal.alpha == 0.0 and cal.units == "m"
    assert cal.quality is not None and cal.quality["rms_px"] == pytest.approx(report["rms"], abs=1e-6)
    assert len(cal.quality["pairs_used"]) == 13


def test_row_error_is_measured_through_the_core(tmp_path) -> None:
    """The figure comes from the core's mapping; OpenCV's undistortPoints agrees to within its own slack."""
    pairs = pairs_from_files(LEFTS[:6], RIGHTS[:6])
    report = calibrate_pairs(pairs, Pattern(9, 6, 0.025), min_pairs=6)
    cal = report.calibration
    m, r = cal.model, cal.rect
    left, right = pairs[0].load()
    from stereocam.calibration.calibrate import _same_order, detect_corners

    cl = detect_corners(left, report.pattern)
    cr = _same_order(cl, detect_corners(right, report.pattern))
    size = cal.image_size
    ours_l = core_rectified_points(cal.left, cl, m.K1, m.D1, r.R1, r.P1, size=size)
    ours_r = core_rectified_points(cal.right, cr, m.K2, m.D2, r.R2, r.P2, size=size)
    rows = np.abs(ours_l[:, 1] - ours_r[:, 1])
    assert rows.mean() == pytest.approx(report.pairs[0].row_error_mean, abs=1e-12)
    # Each rectified corner maps back onto its raw corner through the core's equations...
    u, v = core_source(cal.left, ours_l[:, 0], ours_l[:, 1])
    assert np.abs(u - cl[:, 0]).max() < 1e-6 and np.abs(v - cl[:, 1]).max() < 1e-6
    # ... which at integer pixels are the core model's fixed-point source positions, within their 1/32 px.
    for x, y in np.rint(ours_l).astype(int):
        su, sv = core_source(cal.left, np.float64(x), np.float64(y))
        pos = source_position(cal.left, int(x), int(y), *size)
        assert pos is not None
        assert abs(pos[0] - su * 32) <= 1.0 and abs(pos[1] - sv * 32) <= 1.0
    cv_l = cv2.undistortPoints(cl.reshape(-1, 1, 2), m.K1, m.D1, R=r.R1, P=r.P1).reshape(-1, 2)
    assert np.abs(cv_l - ours_l).max() < 0.05


def test_core_inverse_is_exact_where_opencv_is_approximate() -> None:
    """For known rectified points, the inverse through the core finds them again to 1e-6 px."""
    cal = calibrate_sample()
    m, r = cal.model, cal.rect
    rng = np.random.default_rng(1)
    xy = np.stack([rng.uniform(20, 620, 200), rng.uniform(20, 460, 200)], axis=1)
    u, v = core_source(cal.left, xy[:, 0], xy[:, 1])
    back = core_rectified_points(cal.left, np.stack([u, v], axis=1), m.K1, m.D1, r.R1, r.P1, size=(640, 480))
    assert np.abs(back - xy).max() < 1e-6
    approx = cv2.undistortPoints(np.stack([u, v], axis=1).reshape(-1, 1, 2), m.K1, m.D1, R=r.R1, P=r.P1)
    assert np.abs(approx.reshape(-1, 2) - xy).max() > 1e-4, "OpenCV's 5 iterations alone are not exact"


def test_pairs_that_fail_are_rejected_with_reasons(tmp_path, capsys) -> None:
    """Capture folders (a folder of captures); a blank view and a swapped pair are rejected, the rest used."""
    root = tmp_path / "captures"
    for k, i in enumerate(PAIRS):
        cap = root / f"capture-{k + 1:03d}"
        cap.mkdir(parents=True)
        left, right = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in pair_paths(i))
        if k == 3:
            right = np.full_like(right, 128)  # the board left the right camera's view
        if k == 7:
            right = cv2.imread(str(pair_paths(PAIRS[0])[1]), cv2.IMREAD_GRAYSCALE)  # not this pose
        cv2.imwrite(str(cap / "raw_left.png"), cv2.cvtColor(left, cv2.COLOR_GRAY2BGR))  # colour, as captured
        cv2.imwrite(str(cap / "raw_right.png"), right)
    unfinished = root / ".incoming-capture-014"  # the capture store is writing it
    unfinished.mkdir()
    cv2.imwrite(str(unfinished / "raw_left.png"), np.zeros((480, 640), np.uint8))
    out = tmp_path / "cal.yaml"
    code, stdout, stderr = run(capsys, calibrate_argv(out, square="2.5cm", inputs=[str(root)]))
    assert code == 0, stderr
    assert "pairs: 11 used, 2 rejected" in stdout
    assert "capture-004: rejected, the 9x6 pattern was not found in the right image" in stdout
    assert "capture-008: rejected, reprojection error" in stdout and "more than 4x the median" in stdout
    assert "line buffer: 63 of 80 rows needed (delay 35): fits" in stdout
    assert f"wrote {out}" in stdout
    cal = load_calibration(out)
    rejected = {p["name"]: p["reason"] for p in cal.quality["pairs_rejected"]}
    assert set(rejected) == {"capture-004", "capture-008"}
    # One capture folder alone is one pair.
    assert [p.name for p in find_pairs([root / "capture-002"])] == ["capture-002"]


def test_daemon_api_arrays_and_progress() -> None:
    """calibrate_pairs takes arrays (gray or RGB) and reports progress from the calling thread."""
    pairs = []
    for i in PAIRS[:7]:
        left, right = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in pair_paths(i))
        pairs.append(ImagePair(f"p{i}", np.repeat(left[..., None], 3, axis=2), right))
    seen: List[Tuple[str, int, int]] = []
    report = calibrate_pairs(pairs, Pattern(9, 6, 0.025), alpha=0.5, progress=lambda *a: seen.append(a))
    assert report.pairs_used == 7 and report.calibration.alpha == 0.5
    stages = [s for s, _, _ in seen]
    assert (
        stages[0] == "detect"
        and ("detect", 7, 7) in seen
        and ("calibrate", 3, 3) in seen
        and seen[-1] == ("check", 7, 7)
    )
    assert stages.index("calibrate") > stages.index("detect") and stages.index("check") > stages.index(
        "calibrate"
    )
    d = report.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert report.fits and report.rows_needed == report.calibration.fit.rows


# -- synthetic truth ---------------------------------------------------------------------


@pytest.mark.slow
def test_synthetic_rig_calibrates_back_to_its_known_model(tmp_path, capsys) -> None:
    truth, views = synthetic_views(12, 0)
    root = tmp_path / "caps"
    for k, (left, right) in enumerate(views):
        cap = root / f"{k:02d}"
        cap.mkdir(parents=True)
        cv2.imwrite(str(cap / "raw_left.png"), left)
        cv2.imwrite(str(cap / "raw_right.png"), right)
    out = tmp_path / "synthetic.yaml"
    code, stdout, stderr = run(
        capsys, calibrate_argv(out, "--json", "-q", square=f"{SYNTH_SQUARE * 1000:g}mm", inputs=[str(root)])
    )
    assert code == 0, stderr
    assert stderr == "", "-q: no progress"
    report = json.loads(stdout)
    assert report["pairs_used"] == 12
    assert report["row_error_mean"] < 0.1
    got = load_calibration(out).model
    for K, K_true in ((got.K1, truth.K1), (got.K2, truth.K2)):
        assert K[0, 0] == pytest.approx(K_true[0, 0], rel=0.005) and K[1, 1] == pytest.approx(
            K_true[1, 1], rel=0.005
        )
        assert np.abs(K[:2, 2] - K_true[:2, 2]).max() < 2.0
    assert got.baseline == pytest.approx(truth.baseline, rel=0.01)  # metres, like the rig
    assert np.abs(got.D1 - truth.D1)[:2].max() < 0.01 and np.abs(got.D2 - truth.D2)[:2].max() < 0.01
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(got.R @ truth.R.T)[0]))
    assert angle < 0.1


# -- bad inputs: one line, exit 2, nothing written --------------------------------------


def test_bad_inputs_exit_2_and_leave_the_output_alone(tmp_path, capsys) -> None:
    out = tmp_path / "calibration.yaml"
    out.write_text("previous calibration\n")
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.resize(cv2.imread(RIGHTS[0]), (320, 240)))
    corrupt = tmp_path / "corrupt.png"
    ok, buf = cv2.imencode(".png", cv2.imread(LEFTS[1]))
    corrupt.write_bytes(buf.tobytes()[:300])
    bomb = tmp_path / "bomb.png"  # OpenCV would decode its 25 megapixels; a gigapixel raised cv2.error
    bomb.write_bytes(png_claiming(5000, 5000))
    blank = tmp_path / "blank"
    for k in range(6):
        cap = blank / f"c{k}"
        cap.mkdir(parents=True)
        for name in ("raw_left.png", "raw_right.png"):
            cv2.imwrite(str(cap / name), np.full((480, 640), 128, np.uint8))
    half = tmp_path / "half" / "c0"
    half.mkdir(parents=True)
    cv2.imwrite(str(half / "raw_left.png"), np.zeros((8, 8), np.uint8))
    base = calibrate_argv(out, inputs=())
    cases = [
        (
            ["--left", *LEFTS[:3], "--right", *RIGHTS[:3]],
            "only 3 of 3 pairs show the whole pattern in both cameras and at least 5 are needed",
        ),
        ([str(blank)], "the 9x6 pattern was found in none of the 6 pairs: check the pattern (--pattern"),
        (["--left", LEFTS[0], "--right", str(small)], "left is 640x480 but right is 320x240"),
        (
            ["--left", LEFTS[0], str(corrupt), "--right", RIGHTS[0], RIGHTS[1]],
            "corrupt.png: not a readable image",
        ),
        (["--left", LEFTS[0], str(bomb), "--right", RIGHTS[0], RIGHTS[1]],
         "bomb.png: the image header claims more than the 16.8 megapixels read: 5000x5000 "
         "(25.0 megapixels; a decompression bomb?): replace it"),
        (["--left", *LEFTS[:2], "--right", RIGHTS[0]], "2 left images but 1 right images"),
        ([str(tmp_path / "half")], "has no raw_right.png"),
        ([str(small)], "is a file: give capture folders, or image files with --left"),
        ([str(tmp_path / "nowhere")], "nowhere: no such file or folder"),
    ]
    for extra, message in cases:
        assert message in error_line(capsys, base + extra)
        assert out.read_text() == "previous calibration\n"
    # Pairs of different sizes between pairs.
    odd = tmp_path / "odd"
    for k, i in enumerate(PAIRS[:5]):
        cap = odd / f"c{k}"
        cap.mkdir(parents=True)
        for name, p in zip(("raw_left.png", "raw_right.png"), pair_paths(i), strict=True):
            img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(cap / name), img if k < 4 else cv2.resize(img, (320, 240)))
    assert "pair c4 is 320x240 but the first pair (c0) is 640x480" in error_line(capsys, base + [str(odd)])
    for square, message in (("25", "give the unit"), ("-3mm", "give a length"), ("0mm", "more than 0"),
                            ("1e400mm", "'1e400mm' is not a finite length")):
        line = error_line(
            capsys, ["calibrate", "--pattern", "9x6", f"--square={square}", "-o", str(out), str(blank)]
        )
        assert message in line
    assert "COLSxROWS" in error_line(
        capsys, ["calibrate", "--pattern", "nine", "--square", "1in", "-o", str(out), str(blank)]
    )
    for rows, message in (("0", "at least 1, not 0"),
                          ("2048", "below 2048 (the core counts rows in 11 bits)")):
        with pytest.raises(SystemExit) as exited:  # argparse's usage error
            main(calibrate_argv(out, "--lb-rows", rows, square="1in", inputs=[str(blank)]))
        assert exited.value.code == 2
        assert f"error: argument --lb-rows: line-buffer rows must be {message}" in capsys.readouterr().err
    assert out.read_text() == "previous calibration\n"


def test_calibration_needing_more_rows_than_the_line_buffer_is_refused(tmp_path, capsys) -> None:
    out = tmp_path / "calibration.yaml"
    code, stdout, stderr = run(capsys, calibrate_argv(out, "--lb-rows", "40", "--json", "-q"))
    assert code == 2
    assert stderr.splitlines() == [
        "stereocam calibrate: error: this calibration needs 63 line-buffer rows but the core buffers 40: "
        "recalibrate with the cameras better aligned, use a lens with less distortion, lower alpha, "
        "or load a bitstream built with at least 63 rows"
    ]
    report = json.loads(stdout)  # the figures are still shown
    assert report["fits"] is False and report["rows_needed"] == 63 and report["output"] is None
    assert not out.exists()


def test_output_folder_must_exist_before_the_work_starts(tmp_path, capsys) -> None:
    line = error_line(capsys, calibrate_argv(tmp_path / "no" / "cal.yaml", inputs=[str(DATA)]))
    assert "folder" in line and "does not exist" in line


# -- small pieces ------------------------------------------------------------------------------


def test_pattern_and_length_parsing() -> None:
    assert parse_pattern("9x6") == (9, 6) and parse_pattern(" 7 X 5 ") == (7, 5)
    assert parse_length("25mm") == pytest.approx(0.025) and parse_length("2.5 cm") == pytest.approx(0.025)
    assert parse_length("0.03m") == pytest.approx(0.03) and parse_length("1in") == pytest.approx(0.0254)
    for bad in ("9", "9x", "2x6"):
        with pytest.raises(CalibrationError):
            parse_pattern(bad)
    with pytest.raises(CalibrationError, match="give the unit"):
        parse_length("25 furlongs")
    obj = Pattern(9, 6, 0.025).object_points()
    assert (
        obj.shape == (54, 3)
        and obj[1].tolist() == pytest.approx([0.025, 0, 0])
        and obj[9, 1] == pytest.approx(0.025)
    )


def test_find_pairs_reads_left_right_folders_and_names_what_is_missing(tmp_path) -> None:
    pairs = find_pairs([DATA])
    assert len(pairs) == 13 and pairs[0].name == "left01.jpg" and pairs[-1].name == "left14.jpg"
    (tmp_path / "left1.png").write_bytes(b"")
    with pytest.raises(CalibrationInputError, match="left1.png has no right1"):
        find_pairs([tmp_path])
    (tmp_path / "empty").mkdir()
    with pytest.raises(CalibrationInputError, match="no captures"):
        find_pairs([tmp_path / "empty"])
    with pytest.raises(NotEnoughPairs):
        calibrate_pairs(
            [ImagePair("z", np.zeros((48, 64), np.uint8), np.zeros((48, 64), np.uint8))], Pattern(9, 6, 1.0)
        )
    with pytest.raises(CalibrationInputError, match="uint8"):
        ImagePair("f", np.zeros((4, 4), np.float32), np.zeros((4, 4), np.uint8)).load()
