"""The calibration file: exact YAML round trip, validation on load, import/export of other formats."""

from __future__ import annotations

import copy
import hashlib
import json
import re
from pathlib import Path
from typing import Any, Dict

import cv2
import numpy as np
import pytest
import scipy.io
import yaml

from stereocam.calibration.file import (
    PARAM_NAMES,
    Calibration,
    calibration_id,
    f64_to_words,
    load_calibration,
    parse_yaml,
)
from stereocam.calibration.formats import CalibrationFileError
from stereocam.calibration.stereo import rectify
from stereocam.cli import main
from stereocam.overlays.model.core_params import (
    CoreParamsError,
    FrameSizeError,
    LineBufferTooSmall,
    ParameterOutOfRange,
)
from stereocam.overlays.spec.rectify import camera_registers

from ..sample import PAIRS, calibrate_sample, pair_paths, write_opencv_files

pytestmark = pytest.mark.armhf


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> Path:
    """A calibration written by `stereocam calibrate` from OpenCV's sample pairs."""
    out = tmp_path_factory.mktemp("written") / "calibration.yaml"
    lefts = [str(pair_paths(i)[0]) for i in PAIRS]
    rights = [str(pair_paths(i)[1]) for i in PAIRS]
    assert (
        main(
            [
                "calibrate",
                "--pattern",
                "9x6",
                "--square",
                "25mm",
                "-q",
                "-o",
                str(out),
                "--left",
                *lefts,
                "--right",
                *rights,
            ]
        )
        == 0
    )
    return out


@pytest.fixture(scope="module")
def sample_cal() -> Calibration:
    s = calibrate_sample()
    return Calibration.derive(s.model, s.rect, alpha=0.0, units="squares", source="tests.sample")


def cli(capsys, argv) -> "tuple[int, str, str]":
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def cli_error(capsys, argv) -> str:
    code, out, err = cli(capsys, argv)
    assert code == 2, (out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# -- the YAML format ----------------------------------------------------------------------


def test_yaml_round_trip_is_exact_and_readable(tmp_path, sample_cal) -> None:
    path = sample_cal.save(tmp_path / "cal.yaml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"], "no temporary file left behind"
    text = path.read_text()
    back = load_calibration(path)
    assert back == sample_cal  # model, rectification, registers, fit, id, alpha, units, source
    assert np.array_equal(back.model.K1, sample_cal.model.K1) and np.array_equal(
        back.rect.Q, sample_cal.rect.Q
    )
    assert back.to_yaml() == text, "writing what was read gives the same file"
    data = yaml.safe_load(text)
    assert data["schema_version"] == 1 and data["id"] == sample_cal.id and len(sample_cal.id) == 12
    assert data["core"]["rows_needed"] == 63 and data["core"]["lb_delay"] == 35
    assert data["core"]["width"] == 640 and data["core"]["height"] == 480
    for side, params in (("left", sample_cal.left), ("right", sample_cal.right)):
        block = data["core"][side]
        assert list(block) == list(PARAM_NAMES)
        for name, value in params.values().items():
            assert block[name]["value"] == value
            assert (block[name]["lo"], block[name]["hi"]) == f64_to_words(value)
    fx = sample_cal.left.fx
    lo, hi = f64_to_words(fx)
    assert f"    FX: {{value: {fx!r}, lo: {lo:#010x}, hi: {hi:#010x}}}" in text, (
        "hex register words, one line each"
    )
    assert re.search(r"^  D1: \[[^\]]+\]  # k1, k2, p1, p2$", text, re.M)


def test_id_is_a_hash_of_the_model_numbers(sample_cal) -> None:
    m, r = sample_cal.model, sample_cal.rect
    numbers: Dict[str, Any] = {"schema_version": 1, "image_size": [640, 480]}
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        numbers[name] = [float(v) + 0.0 for v in np.ravel(getattr(m, name))]
    for name in ("R1", "R2", "P1", "P2", "Q"):
        numbers[name] = [float(v) + 0.0 for v in np.ravel(getattr(r, name))]
    canonical = json.dumps(numbers, sort_keys=True, separators=(",", ":"))
    assert sample_cal.id == hashlib.sha256(canonical.encode()).hexdigest()[:12]
    other = rectify(m, alpha=1.0)
    assert calibration_id(m, other) != sample_cal.id


def _edit(text: str, change) -> str:
    data = yaml.safe_load(text)
    change(data)
    return yaml.safe_dump(data, sort_keys=False)


def _set_value(data: dict, side: str, name: str, value: float) -> None:
    lo, hi = f64_to_words(value)
    data["core"][side][name] = {"value": value, "lo": lo, "hi": hi}


EDITS = {
    "core_value": (
        lambda d: _set_value(d, "left", "FX", d["core"]["left"]["FX"]["value"] * 1.001),
        "core.left.FX is",
    ),
    "core_words": (
        lambda d: d["core"]["left"]["CX"].update(lo=d["core"]["left"]["CX"]["lo"] ^ 1),
        "core.left.CX: value",
    ),
    "model_value": (
        lambda d: d["model"]["K1"][0].__setitem__(0, d["model"]["K1"][0][0] + 1.0),
        "core.left.H00 is",
    ),
    "id": (
        lambda d: d.update(id="000000000000"),
        "id is '000000000000' but the model and rectification hash to",
    ),
    "width": (lambda d: d["core"].update(width=641), "core.width is 641 but the model gives 640"),
}


def test_line_buffer_figures_in_the_file_are_derived_again(sample_cal) -> None:
    """Files written by core 1.0 hold its figures (binary64 positions); 2.0 loads them and derives its own."""
    old = parse_yaml(_edit(sample_cal.to_yaml(), lambda d: d["core"].update(lb_delay=36, rows_needed=62)))
    assert (old.lb_delay, old.rows_needed) == (sample_cal.lb_delay, sample_cal.rows_needed)
    assert old == sample_cal


@pytest.mark.parametrize("case", sorted(EDITS))
def test_a_file_edited_inconsistently_is_refused(sample_cal, case) -> None:
    change, message = EDITS[case]
    with pytest.raises(CalibrationFileError) as err:
        parse_yaml(_edit(sample_cal.to_yaml(), change), where="cal.yaml")
    assert message in str(err.value) and str(err.value).startswith("cal.yaml: ")
    assert "edited" in str(err.value) and "stereocam calibration import" in str(err.value)


INVALID = {
    "schema_newer": (
        lambda d: d.update(schema_version=2),
        "schema_version 2 is newer than this stereocam reads (1)",
    ),
    "schema_wrong": (lambda d: d.update(schema_version="one"), "schema_version must be 1, is 'one'"),
    "unknown_top": (lambda d: d.update(modle={}), "unknown field modle (known: schema_version, id,"),
    "unknown_nested": (lambda d: d["model"].update(K3=[1.0]), "unknown field model.K3"),
    "unknown_param": (
        lambda d: d["core"]["right"].update(H33={"value": 1.0, "lo": 0, "hi": 0}),
        "unknown field core.right.H33",
    ),
    "missing": (lambda d: d["rectification"].pop("P2"), "missing rectification.P2"),
    "missing_core": (lambda d: d.pop("core"), "missing core"),
    "nan": (
        lambda d: d["model"]["D1"].__setitem__(0, float("nan")),
        "model.D1 has values that are not finite numbers",
    ),
    "shape": (lambda d: d["model"].update(K1=d["model"]["K1"][:2]), "model.K1 must be 3x3"),
    "not_number": (lambda d: d["model"]["T"].__setitem__(1, "zero"), "model.T must be a number, is 'zero'"),
    "size": (lambda d: d["model"].update(image_size=[640]), "model.image_size must be [width, height]"),
    "skew": (lambda d: d["model"]["K2"][0].__setitem__(1, 0.5), "the core models no skew"),
}


@pytest.mark.parametrize("case", sorted(INVALID))
def test_invalid_files_name_the_field(sample_cal, case) -> None:
    change, message = INVALID[case]
    with pytest.raises(CalibrationFileError, match=re.escape(message)):
        parse_yaml(_edit(sample_cal.to_yaml(), change), where="cal.yaml")


def test_register_range_frame_size_and_line_buffer_are_checked_on_load(tmp_path, sample_cal) -> None:
    def huge_fx(d: dict) -> None:
        d["model"]["K1"][0][0] = 1e6

    with pytest.raises(ParameterOutOfRange, match=r"left FX = 1e\+06 is outside the register's range"):
        parse_yaml(_edit(sample_cal.to_yaml(), huge_fx))
    with pytest.raises(FrameSizeError, match="a 640x480 frame does not fit the core"):
        parse_yaml(sample_cal.to_yaml(), max_width=320)
    path = sample_cal.save(tmp_path / "cal.yaml")
    with pytest.raises(LineBufferTooSmall, match="needs 63 line-buffer rows but the core buffers 40"):
        load_calibration(path, lb_rows=40)
    assert load_calibration(path, lb_rows=63).rows_needed == 63
    with pytest.raises(
        CalibrationFileError, match=r"not valid YAML: line 3, column 1: could not find expected ':'"
    ):
        parse_yaml("schema_version: 1\nmodel {\nid: 1\n")
    with pytest.raises(CalibrationFileError, match="is for 640x480 images, not 752x480"):
        load_calibration(path, image_size=(752, 480))
    with pytest.raises(CoreParamsError):
        load_calibration(path, lb_rows=10)


def test_save_failure_names_the_path(tmp_path, sample_cal) -> None:
    with pytest.raises(CalibrationFileError, match="cannot write .*missing/cal.yaml"):
        sample_cal.save(tmp_path / "missing" / "cal.yaml")


# -- OpenCV -------------------------------------------------------------------------------------


def test_written_exported_to_opencv_and_imported_again_gives_the_same_registers(
    tmp_path, written, capsys
) -> None:
    code, out, err = cli(capsys, ["calibration", "export", str(written), "--opencv", str(tmp_path / "cv")])
    assert code == 0, err
    intr, extr = tmp_path / "cv" / "intrinsics.yml", tmp_path / "cv" / "extrinsics.yml"
    assert f"wrote {intr} and {extr}" in out
    fs = cv2.FileStorage(str(intr), cv2.FILE_STORAGE_READ)
    assert fs.getNode("M1").mat().shape == (3, 3) and fs.getNode("D1").mat().shape == (1, 5)
    assert int(fs.getNode("image_width").real()) == 640
    fs.release()
    again = tmp_path / "again.yaml"
    code, out, err = cli(capsys, ["calibration", "import", str(intr), str(extr), "-o", str(again)])
    assert code == 0, err
    a, b = load_calibration(written), load_calibration(again)
    assert (a.left, a.right, a.fit) == (b.left, b.right, b.fit)
    assert a.id == b.id, "the same numbers, so the same id"
    core = lambda p: p.read_text().split("\ncore:\n")[1].split("\nquality:")[0].strip()  # noqa: E731
    assert core(written) == core(again)
    assert f"wrote {again}: calibration {a.id}: 640x480" in out


def test_rectify_reads_the_yaml_file_like_the_opencv_pair(tmp_path, written, capsys) -> None:
    Path(tmp_path / "cv").mkdir()
    intr, extr = load_calibration(written).to_opencv(tmp_path / "cv")
    left, right = pair_paths(4)
    code, out, _ = cli(
        capsys, ["rectify", "--calibration", str(written), "-o", str(tmp_path / "a"), str(left), str(right)]
    )
    assert code == 0 and "line buffer: 63 of 80 rows needed (delay 35)" in out
    code, _, _ = cli(
        capsys,
        ["rectify", "--calibration", f"{intr},{extr}", "-o", str(tmp_path / "b"), str(left), str(right)],
    )
    assert code == 0
    for name in ("left.png", "right.png"):
        a = cv2.imread(str(tmp_path / "a" / name), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(tmp_path / "b" / name), cv2.IMREAD_UNCHANGED)
        assert a.shape == (480, 640) and np.array_equal(a, b)
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((240, 320), np.uint8))
    err = cli_error(
        capsys, ["rectify", "--calibration", str(written), "-o", str(tmp_path / "c"), str(small), str(small)]
    )
    assert "the calibration is for 640x480 images, not 320x240" in err
    err = cli_error(
        capsys,
        [
            "rectify",
            "--lb-rows",
            "50",
            "--calibration",
            str(written),
            "-o",
            str(tmp_path / "c"),
            str(left),
            str(right),
        ],
    )
    assert "needs 63 line-buffer rows but the core buffers 50" in err
    assert not (tmp_path / "c").exists()


def test_opencv_pair_without_image_size_needs_size(tmp_path, capsys) -> None:
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)  # as stereo_calib writes them: no size
    out = tmp_path / "cal.yaml"
    err = cli_error(capsys, ["calibration", "import", f"{intr},{extr}", "-o", str(out)])
    assert "does not record the image size (image_width, image_height): give it, e.g. --size 752x480" in err
    assert not out.exists()
    code, _, err = cli(
        capsys, ["calibration", "import", str(intr), str(extr), "--size", "640x480", "-o", str(out)]
    )
    assert code == 0, err
    cal = load_calibration(out)
    s = calibrate_sample()
    assert (cal.left, cal.right) == (s.left, s.right) and cal.units == "unknown"


# -- MATLAB ---------------------------------------------------------------------------------------


def matlab_struct(*, new_style: bool = True) -> Dict[str, Any]:
    """What MATLAB's toStruct(stereoParams) holds for the sample calibration (25 mm squares, mm units)."""
    m = calibrate_sample().model
    cams = []
    for K, D in ((m.K1, m.D1), (m.K2, m.D2)):
        K_ml = K.copy()
        K_ml[0, 2] += 1.0  # MATLAB's first pixel is (1, 1)
        K_ml[1, 2] += 1.0
        cam: Dict[str, Any] = {
            "RadialDistortion": np.array([[D[0], D[1]]]),
            "TangentialDistortion": np.array([[D[2], D[3]]]),
            "ImageSize": np.array([[480.0, 640.0]]),
            "WorldUnits": "mm",
            "EstimateSkew": False,
            "NumRadialDistortionCoefficients": 2.0,
            "EstimateTangentialDistortion": True,
            "RotationVectors": np.zeros((13, 3)),
            "TranslationVectors": np.zeros((13, 3)),
            "WorldPoints": np.zeros((54, 2)),
            "Version": {"Name": "Computer Vision Toolbox", "Version": "9.0"},
        }
        if new_style:
            cam["K"] = K_ml
        else:
            cam["IntrinsicMatrix"] = K_ml.T
        cams.append(cam)
    return {
        "CameraParameters1": cams[0],
        "CameraParameters2": cams[1],
        "RotationOfCamera2": m.R.T,
        "TranslationOfCamera2": (m.T * 25.0).reshape(1, 3),
        "Version": {"Name": "vision"},
        "RectificationParams": {"Initialized": False},
    }


@pytest.mark.parametrize("new_style", [True, False], ids=["K", "IntrinsicMatrix"])
def test_matlab_stereo_parameters_import(tmp_path, capsys, new_style) -> None:
    mat = tmp_path / "stereo.mat"
    scipy.io.savemat(str(mat), {"stereoParams": matlab_struct(new_style=new_style)})
    out = tmp_path / "cal.yaml"
    code, stdout, err = cli(capsys, ["calibration", "import", str(mat), "-o", str(out)])
    assert code == 0, err
    cal = load_calibration(out)
    s = calibrate_sample()
    assert np.allclose(cal.model.K1, s.model.K1, rtol=0, atol=1e-9) and np.allclose(
        cal.model.K2, s.model.K2, atol=1e-9
    )
    assert np.array_equal(cal.model.R, s.model.R) and np.array_equal(cal.model.D2, s.model.D2)
    assert np.allclose(cal.model.T, s.model.T * 0.025, rtol=1e-12), "millimetres to metres"
    assert cal.units == "m" and cal.alpha == 0.0 and cal.source == "MATLAB stereo.mat"
    for got, want in ((cal.left, s.left), (cal.right, s.right)):
        assert np.allclose(got.hinv, want.hinv, rtol=1e-9, atol=1e-12)
    assert cal.rows_needed == 63
    # Saved with save(..., '-struct', 's') and rectified with another alpha.
    scipy.io.savemat(str(mat), matlab_struct(new_style=new_style))
    wide = load_calibration(mat, alpha=1.0, lb_rows=None)
    assert wide.alpha == 1.0 and wide.left.hinv != cal.left.hinv


MATLAB_ERRORS = {
    "missing": (
        lambda s: s["CameraParameters1"].pop("TangentialDistortion"),
        "missing stereoParams.CameraParameters1.TangentialDistortion",
    ),
    "no_K": (lambda s: s["CameraParameters2"].pop("K"), "missing stereoParams.CameraParameters2.K (or"),
    "k3": (
        lambda s: s["CameraParameters1"].update(RadialDistortion=np.array([[-0.28, 0.06, 0.01]])),
        "RadialDistortion has 3 coefficients and k3 = 0.01",
    ),
    "skew": (lambda s: s["CameraParameters1"]["K"].__setitem__((0, 1), 0.3), "K has skew 0.3"),
    "rotation": (
        lambda s: s.update(RotationOfCamera2=2 * np.eye(3)),
        "RotationOfCamera2 is not a rotation matrix",
    ),
    "no_size": (
        lambda s: [
            c.update(ImageSize=np.zeros((0, 2))) for c in (s["CameraParameters1"], s["CameraParameters2"])
        ],
        "ImageSize is empty: give the image size, e.g. --size 752x480",
    ),
}


@pytest.mark.parametrize("case", sorted(MATLAB_ERRORS))
def test_matlab_problems_name_the_field(tmp_path, capsys, case) -> None:
    st = matlab_struct()
    change, message = MATLAB_ERRORS[case]
    change(st)
    mat = tmp_path / "stereo.mat"
    scipy.io.savemat(str(mat), {"stereoParams": st})
    err = cli_error(capsys, ["calibration", "import", str(mat), "-o", str(tmp_path / "cal.yaml")])
    assert err.startswith("stereocam calibration import: error: ") and message in err
    assert not (tmp_path / "cal.yaml").exists()


def test_unreadable_matlab_files(tmp_path) -> None:
    v73 = tmp_path / "v73.mat"
    v73.write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64" + bytes(200))
    with pytest.raises(CalibrationFileError, match=r"v7.3 \(HDF5\).*save\('stereo.mat', 's', '-v7'\)"):
        load_calibration(v73)
    junk = tmp_path / "junk.mat"
    junk.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(CalibrationFileError, match="junk.mat: not a readable MATLAB .mat file"):
        load_calibration(junk)
    other = tmp_path / "other.mat"
    scipy.io.savemat(str(other), {"x": np.eye(3)})
    with pytest.raises(
        CalibrationFileError, match=r"no stereoParameters struct in the file \(variables: x\)"
    ):
        load_calibration(other)


# -- ROS -------------------------------------------------------------------------------------------


def write_ros(folder: Path, **override: Any) -> "tuple[Path, Path]":
    s = calibrate_sample()
    paths = []
    for name, K, D, R, P in (
        ("left", s.model.K1, s.model.D1, s.rect.R1, s.rect.P1),
        ("right", s.model.K2, s.model.D2, s.rect.R2, s.rect.P2),
    ):
        data = {
            "image_width": 640,
            "image_height": 480,
            "camera_name": name,
            "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in K.ravel()]},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [float(v) for v in D] + [0.0]},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in R.ravel()]},
            "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in P.ravel()]},
        }
        if name == "right":
            data.update(override)
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        paths.append(path)
    return paths[0], paths[1]


def test_ros_camera_info_pair_import(tmp_path, capsys) -> None:
    left, right = write_ros(tmp_path)
    out = tmp_path / "cal.yaml"
    code, _, err = cli(capsys, ["calibration", "import", f"{left},{right}", "-o", str(out)])
    assert code == 0, err
    cal = load_calibration(out)
    s = calibrate_sample()
    assert (cal.left, cal.right) == (s.left, s.right), "the registers follow from K, D, R1/R2, P1/P2 exactly"
    assert np.allclose(cal.model.R, s.model.R, atol=1e-12)
    assert np.allclose(cal.model.T, s.model.T, rtol=1e-9, atol=1e-12)
    assert np.allclose(cal.rect.Q, s.rect.Q, rtol=1e-9, atol=1e-12)
    assert cal.units == "m" and cal.rows_needed == 63


@pytest.mark.parametrize(
    "override, message",
    [
        ({"distortion_model": "equidistant"}, "distortion_model is 'equidistant'; the core models plumb_bob"),
        ({"binning_x": 1}, "right.yaml: unknown field binning_x"),
        ({"image_width": 752}, "left.yaml is for 640x480 images but"),
        (
            {"projection_matrix": {"rows": 3, "cols": 3, "data": [1.0] * 9}},
            "projection_matrix must be 3x4, is 3x3",
        ),
        (
            {"distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.1, 0.0, 0.0, 0.0, 0.2]}},
            "has k3 = 0.2",
        ),
    ],
)
def test_ros_problems_name_the_field(tmp_path, override, message) -> None:
    left, right = write_ros(tmp_path, **override)
    with pytest.raises(CalibrationFileError, match=re.escape(message)):
        load_calibration([left, right])


def test_missing_ros_field_is_named(tmp_path) -> None:
    left, right = write_ros(tmp_path)
    data = yaml.safe_load(right.read_text())
    del data["rectification_matrix"]
    right.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationFileError, match="right.yaml: missing rectification_matrix"):
        load_calibration(f"{left},{right}")


# -- dispatch and the CLI ----------------------------------------------------------------------------


def test_source_kinds_are_recognised_and_mixups_explained(tmp_path, capsys, written) -> None:
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)
    left, right = write_ros(tmp_path)
    out = tmp_path / "x.yaml"
    for argv, message in (
        (
            [str(intr)],
            "intrinsics.yml: one file of a pair; give both, separated by a comma: "
            "intrinsics.yml,extrinsics.yml",
        ),
        ([str(left)], "one file of a pair; give both, separated by a comma: left.yaml,right.yaml"),
        ([str(intr), str(right)], "these look like opencv and ros"),
        (
            [str(tmp_path / "nope.yaml")],
            "nope.yaml: no such file; --calibration takes a stereocam calibration.yaml",
        ),
        ([str(written), str(written)], "these look like stereocam and stereocam"),
    ):
        err = cli_error(capsys, ["calibration", "import", *argv, "-o", str(out)])
        assert message in err and err.startswith("stereocam calibration import: error: ")
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    assert "not a calibration file stereocam knows" in cli_error(
        capsys, ["calibration", "export", str(text), "--opencv", str(tmp_path / "cv")]
    )
    assert not out.exists() and not (tmp_path / "cv").exists()


def test_an_edited_model_is_refused_until_its_core_is_derived_again(tmp_path, capsys, written) -> None:
    def edit(d: dict) -> None:
        d["model"]["K1"][0][0] += 0.5

    edited = tmp_path / "edited.yaml"
    edited.write_text(_edit(written.read_text(), edit))
    assert "edited inconsistently" in cli_error(
        capsys, ["calibration", "import", str(edited), "-o", str(tmp_path / "n.yaml")]
    )

    def strip(d: dict) -> None:
        edit(d)
        del d["core"], d["id"]

    edited.write_text(_edit(written.read_text(), strip))
    code, out, err = cli(capsys, ["calibration", "import", str(edited), "-o", str(tmp_path / "n.yaml")])
    assert code == 0, err
    new, old = load_calibration(tmp_path / "n.yaml"), load_calibration(written)
    assert new.id != old.id and new.left.fx == old.left.fx + 0.5 and new.right == old.right
    assert new.quality == old.quality, "the free-form quality section is carried over"
    with pytest.raises(CalibrationFileError, match="missing id, core"):
        load_calibration(edited)  # only import derives what is missing


def test_loaded_calibration_feeds_the_core(written) -> None:
    cal = load_calibration(written)
    config = cal.core_config()
    assert (config.width, config.height, config.lb_delay) == (640, 480, 35)
    assert config.left == camera_registers(cal.left, 640, 480)
    assert config.right == camera_registers(cal.right, 640, 480)
    assert cal.summary() == (
        f"calibration {cal.id}: 640x480, baseline {cal.model.baseline:.6g} m, line buffer 63 rows (delay 35)"
    )
    assert cal.model.baseline == pytest.approx(3.338 * 0.025, rel=0.01)
    copied = copy.deepcopy(cal)
    assert copied == cal


def _edited(path: Path, change) -> str:
    """The file at ``path`` with ``change(doc)`` applied, its derived core and id dropped (a hand edit)."""
    doc = yaml.safe_load(path.read_text())
    change(doc)
    doc.pop("core", None)
    doc.pop("id", None)
    return yaml.safe_dump(doc)


def _set(section: str, name: str, value: Any):
    def change(doc: Dict[str, Any]) -> None:
        doc[section][name] = json.loads(json.dumps(value))  # fresh lists: safe_dump would write aliases
    return change


@pytest.mark.parametrize("change,message", [
    (_set("model", "R", [[0.0] * 3] * 3), "model.R is not a rotation matrix"),
    (_set("model", "R", [[1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]]), "model.R is not a rotation matrix"),
    (_set("rectification", "R1", [[2.0, 0, 0], [0, 2.0, 0], [0, 0, 2.0]]),
     "rectification.R1 is not a rotation"),
    (_set("model", "T", [0.0, 0.0, 0.0]), "baseline of 0"),
    (_set("model", "T", [1e308, 0.0, 0.0]), "baseline of 1e+308"),
    (_set("model", "K1", [[-700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]]),
     "model.K1 has focal lengths -700"),
    (_set("rectification", "Q", [[0.0] * 4] * 4), "rectification.Q is all zeros"),
    (_set("rectification", "alpha", 5), "rectification.alpha is 5"),
    (_set("rectification", "alpha", -1), "rectification.alpha is -1"),
    (_set("rectification", "P2", [[700.0, 0, 320, -70], [0, 700.0, 240, 0], [0, 0, 2.0, 0]]),
     "rectification.P2 is not the projection"),
])
def test_physically_meaningless_calibrations_are_refused(written, change, message) -> None:
    """Numbers that fit the registers but describe no stereo rig."""
    text = _edited(written, change)
    with pytest.raises(CalibrationFileError, match=re.escape(message)):
        parse_yaml(text, where="cal", derive_missing=True)
    assert parse_yaml(_edited(written, lambda doc: None), where="cal", derive_missing=True)  # unchanged: fine


@pytest.mark.parametrize("section,name,row,col,message", [
    ("rectification", "P1", 0, 1, "the rectification (P1*R1 or P2*R2) is singular"),
    ("rectification", "P2", 1, 2, "the rectification (P1*R1 or P2*R2) is singular"),
    ("model", "R", 0, 1, "model.R is not a rotation matrix"),
    ("rectification", "R2", 2, 2, "rectification.R2 is not a rotation matrix"),
])
@pytest.mark.parametrize("value", [1e308, -1e308, 1e154])
def test_huge_numbers_are_refused_without_overflowing(written, tmp_path, capsys, section, name, row, col,
                                                      message, value) -> None:
    """A hostile file's 1e308 in a projection or a rotation: its check must not overflow on the
    way (an OverflowError was a traceback from ``calibration import`` and a 500 from the daemon;
    numpy's overflow warnings are errors here)."""
    def change(doc: Dict[str, Any]) -> None:
        doc[section][name][row][col] = value

    text = _edited(written, change)
    with pytest.raises(CalibrationFileError, match=re.escape(message)):
        parse_yaml(text, where="cal", derive_missing=True)
    hostile = tmp_path / "hostile.yaml"
    hostile.write_text(text)
    err = cli_error(capsys, ["calibration", "import", str(hostile), "-o", str(tmp_path / "out.yaml")])
    assert message in err
    assert not (tmp_path / "out.yaml").exists()


def test_a_rectification_of_another_rig_is_refused(written) -> None:
    # Turn the right camera 3 degrees behind the rectification's back.
    def rotate(doc: Dict[str, Any]) -> None:
        R = np.array(doc["model"]["R"]) @ cv2.Rodrigues(np.array([0.0, np.radians(3), 0.0]))[0]
        doc["model"]["R"] = R.tolist()

    with pytest.raises(CalibrationFileError, match=r"R1, R2 do not match model.R"):
        parse_yaml(_edited(written, rotate), where="cal", derive_missing=True)


def test_schema_version_true_is_not_1(written) -> None:
    text = written.read_text().replace("schema_version: 1", "schema_version: true", 1)
    assert text != written.read_text()
    with pytest.raises(CalibrationFileError, match="schema_version must be 1, is True"):
        parse_yaml(text, where="cal")
