"""Reading (and writing) calibrations in the formats users already have.

- OpenCV's ``stereo_calib`` sample: ``intrinsics.yml`` (M1, D1, M2, D2) and
  ``extrinsics.yml`` (R, T, R1, R2, P1, P2, Q). These files do not record the
  image size; :func:`write_opencv_pair` adds ``image_width`` and
  ``image_height`` to ``intrinsics.yml`` (as OpenCV's ``calibration`` sample
  does), and :func:`load_opencv_pair` uses them when present.
- MATLAB's ``stereoParameters``, saved with ``s = toStruct(stereoParams);
  save('stereo.mat', 's')`` (or ``save(..., '-struct', 's')``), read with
  :func:`load_matlab`.
- ROS ``camera_info`` YAML files, one per camera (``left.yaml``,
  ``right.yaml``), read with :func:`load_ros_pair` and written with
  :func:`write_ros_pair`.

Every problem is a :class:`CalibrationFileError` whose message names the file
and the field, so the CLI can print it on one line.
"""
from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .stereo import Rectification, StereoModel

INTRINSIC_FIELDS = ("M1", "D1", "M2", "D2")
EXTRINSIC_FIELDS = ("R", "T", "R1", "R2", "P1", "P2", "Q")
SHAPES: Dict[str, Tuple[int, ...]] = {
    "M1": (3, 3), "M2": (3, 3), "R": (3, 3), "T": (3,), "R1": (3, 3), "R2": (3, 3),
    "P1": (3, 4), "P2": (3, 4), "Q": (4, 4),
}


class CalibrationFileError(ValueError):
    """A calibration file that cannot be used; the message says which and why."""


def _read_opencv_file(path: Path, fields: Sequence[str]) -> Dict[str, np.ndarray]:
    import cv2

    if not path.is_file():
        raise CalibrationFileError(f"{path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 5 wraps parse errors in SystemError
        cause = exc.__cause__ or exc
        lines = str(cause).strip().splitlines()
        reason = lines[-1].split("error: ", 1)[-1] if lines else "parse error"
        raise CalibrationFileError(f"{path}: not an OpenCV YAML/XML file ({reason})") from None
    try:
        if not fs.isOpened():
            raise CalibrationFileError(f"{path}: not an OpenCV YAML/XML file")
        out: Dict[str, np.ndarray] = {}
        missing = []
        for name in fields:
            node = fs.getNode(name)
            if node.empty() or node.isNone():
                missing.append(name)
                continue
            mat = node.mat()
            if mat is None:
                raise CalibrationFileError(f"{path}: {name} is not a matrix")
            out[name] = np.asarray(mat, dtype=np.float64)
        if missing:
            raise CalibrationFileError(f"{path}: missing {', '.join(missing)} (expected {', '.join(fields)})")
        return out
    finally:
        fs.release()


def _shaped(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(value)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    want = SHAPES[name]
    if want == (3,):
        if value.size != 3:
            raise CalibrationFileError(f"{path}: {name} must have 3 values, has {value.size}")
        return value.reshape(3)
    if value.shape != want:
        shape = "x".join(map(str, value.shape))
        raise CalibrationFileError(f"{path}: {name} must be {want[0]}x{want[1]}, is {shape}")
    return value


def _distortion(path: Path, name: str, value: np.ndarray) -> np.ndarray:
    d = value.reshape(-1)
    if not np.all(np.isfinite(d)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    if d.size not in (4, 5, 8, 12, 14):
        raise CalibrationFileError(
            f"{path}: {name} has {d.size} coefficients; expected k1, k2, p1, p2[, k3...]"
        )
    extra = [(DISTORTION_NAMES[i], float(v)) for i, v in enumerate(d) if i >= 4 and v != 0]
    if extra:
        terms = ", ".join(f"{n} = {v:g}" for n, v in extra)
        raise CalibrationFileError(
            f"{path}: {name} has {terms} but the core models only k1, k2, p1, p2: "
            f"recalibrate {_distortion_fix([n for n, _ in extra])}"
        )
    return d[:4]


# OpenCV's distortion coefficients, in order (4, 5, 8, 12 or 14 of them).
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")


def _distortion_fix(names: Sequence[str]) -> str:
    """The calibration flags that zero the terms ``names``, e.g. ``k6``.

    OpenCV's own stereo_calib sample calibrates with CALIB_RATIONAL_MODEL and fixes
    k3, k4 and k5, so the term its files carry is k6: the advice names the flags for
    the terms actually present, not k3 alone.
    """
    advice = []
    if "k3" in names:
        advice.append("with k3 fixed at 0 (cv2.CALIB_FIX_K3)")
    rational = [n for n in ("k4", "k5", "k6") if n in names]
    if rational:
        flags = " | ".join(f"cv2.CALIB_FIX_{n.upper()}" for n in rational)
        advice.append(f"without cv2.CALIB_RATIONAL_MODEL (or with {flags})")
    if any(n.startswith("s") for n in names):
        advice.append("without cv2.CALIB_THIN_PRISM_MODEL")
    if any(n.startswith("t") for n in names):
        advice.append("without cv2.CALIB_TILTED_MODEL")
    return " and ".join(advice)


def _read_opencv_size(path: Path) -> Optional[Tuple[int, int]]:
    """``(image_width, image_height)`` if the file records them (OpenCV's calibration sample does)."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        got = []
        for name in ("image_width", "image_height"):
            node = fs.getNode(name)
            if node.empty() or node.isNone():
                return None
            value = node.real()
            if not (math.isfinite(value) and value == int(value) and value >= 1):
                raise CalibrationFileError(f"{path}: {name} must be a positive whole number, is {value:g}")
            got.append(int(value))
        return got[0], got[1]
    finally:
        fs.release()


def load_opencv_pair(
    intrinsics: Path, extrinsics: Path, image_size: Optional[Tuple[int, int]] = None,
) -> Tuple[StereoModel, Rectification]:
    """The stereo model and rectification from OpenCV stereo_calib files.

    The image size (width, height) is read from ``intrinsics.yml``'s
    ``image_width`` and ``image_height`` when the file has them; otherwise
    ``image_size`` must give it (from the images: stereo_calib does not
    record it). Both given and different is an error.
    """
    intr = _read_opencv_file(intrinsics, INTRINSIC_FIELDS)
    extr = _read_opencv_file(extrinsics, EXTRINSIC_FIELDS)
    m = {n: _shaped(intrinsics, n, intr[n]) for n in ("M1", "M2")}
    d = {n: _distortion(intrinsics, n, intr[n]) for n in ("D1", "D2")}
    e = {n: _shaped(extrinsics, n, v) for n, v in extr.items()}
    recorded = _read_opencv_size(intrinsics)
    if recorded is not None and image_size is not None and tuple(image_size) != recorded:
        raise CalibrationFileError(
            f"{intrinsics}: the calibration is for {recorded[0]}x{recorded[1]} images, "
            f"not {image_size[0]}x{image_size[1]}: use images from the cameras that were calibrated"
        )
    size = recorded if recorded is not None else image_size
    if size is None:
        raise CalibrationFileError(
            f"{intrinsics}: the file does not record the image size (image_width, image_height): "
            "give it, e.g. --size 752x480"
        )
    model = StereoModel(m["M1"], d["D1"], m["M2"], d["D2"], e["R"], e["T"], size)
    rect = Rectification(e["R1"], e["R2"], e["P1"], e["P2"], e["Q"], model.image_size)
    return model, rect


def opencv_pair_text(model: StereoModel, rect: Rectification) -> Tuple[str, str]:
    """The text of ``intrinsics.yml`` and ``extrinsics.yml`` (OpenCV FileStorage YAML).

    Doubles are written with 17 significant digits, so reading them back
    gives the very same values. ``D1``/``D2`` have five coefficients
    (k3 = 0), as stereo_calib writes them; ``image_width`` and
    ``image_height`` record the image size.
    """
    import cv2

    def text(items: Sequence[Tuple[str, object]]) -> str:
        fs = cv2.FileStorage("calibration.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
        for name, value in items:
            if isinstance(value, int):
                fs.write(name, value)
            else:
                fs.write(name, np.asarray(value, dtype=np.float64))
        return str(fs.releaseAndGetString())

    w, h = model.image_size
    intr = text([
        ("image_width", int(w)), ("image_height", int(h)),
        ("M1", model.K1), ("D1", np.append(model.D1, 0.0).reshape(1, 5)),
        ("M2", model.K2), ("D2", np.append(model.D2, 0.0).reshape(1, 5)),
    ])
    extr = text([
        ("R", model.R), ("T", model.T.reshape(3, 1)), ("R1", rect.R1), ("R2", rect.R2),
        ("P1", rect.P1), ("P2", rect.P2), ("Q", rect.Q),
    ])
    return intr, extr


def write_opencv_pair(model: StereoModel, rect: Rectification, outdir: Path) -> Tuple[Path, Path]:
    """Write ``outdir/intrinsics.yml`` and ``outdir/extrinsics.yml``; returns their paths.

    Each file is written to a temporary name and renamed into place, so a
    failure never leaves a half-written file. Raises
    :class:`CalibrationFileError` if the folder cannot be written.
    """
    return _write_pair(Path(outdir), ("intrinsics.yml", "extrinsics.yml"), opencv_pair_text(model, rect))


def _write_pair(outdir: Path, names: Tuple[str, str], texts: Tuple[str, str]) -> Tuple[Path, Path]:
    """Write two texts into ``outdir`` (created if missing), each atomically; their paths."""
    paths = (outdir / names[0], outdir / names[1])
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CalibrationFileError(f"cannot create {outdir}: {exc.strerror}") from None
    for path, content in zip(paths, texts, strict=True):
        atomic_write_text(path, content)
    return paths


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same folder and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise CalibrationFileError(f"cannot write {path}: {exc.strerror or exc}") from None


# --------------------------------------------------------------------------
# MATLAB stereoParameters (toStruct, saved to a .mat file)
# --------------------------------------------------------------------------

# Metres per MATLAB WorldUnits; T is stored in metres when the unit is known.
WORLD_UNITS = {
    "mm": 1e-3, "millimeter": 1e-3, "millimeters": 1e-3, "millimetre": 1e-3, "millimetres": 1e-3,
    "cm": 1e-2, "centimeter": 1e-2, "centimeters": 1e-2, "centimetre": 1e-2, "centimetres": 1e-2,
    "m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0,
    "in": 0.0254, "inch": 0.0254, "inches": 0.0254,
}


def _mat_number_array(
    path: Path, name: str, value: object, size: Optional[Sequence[int]] = None,
) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationFileError(f"{path}: {name} is not a numeric array") from None
    if size is not None and arr.size not in size:
        raise CalibrationFileError(
            f"{path}: {name} has {arr.size} values, expected {' or '.join(map(str, size))}"
        )
    if not np.all(np.isfinite(arr)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    return arr


def _mat_field(path: Path, struct: Dict[str, object], prefix: str, name: str) -> object:
    if name not in struct:
        raise CalibrationFileError(
            f"{path}: missing {prefix}{name} (fields there: {', '.join(sorted(struct)) or 'none'})"
        )
    return struct[name]


def _mat_camera(
    path: Path, cam: object, prefix: str,
) -> Tuple[np.ndarray, np.ndarray, Optional[Tuple[int, int]]]:
    """(K in OpenCV's convention, (k1, k2, p1, p2), (width, height) or None) of a cameraParameters struct."""
    if not isinstance(cam, dict):
        raise CalibrationFileError(f"{path}: {prefix.rstrip('.')} is not a struct")
    if "K" in cam:
        K = _mat_number_array(path, f"{prefix}K", cam["K"], (9,)).reshape(3, 3)
    elif "IntrinsicMatrix" in cam:  # before R2022b: the transpose of K
        K = _mat_number_array(path, f"{prefix}IntrinsicMatrix", cam["IntrinsicMatrix"], (9,)).reshape(3, 3).T
    else:
        raise CalibrationFileError(
            f"{path}: missing {prefix}K (or {prefix}IntrinsicMatrix before R2022b) "
            f"(fields there: {', '.join(sorted(cam))})"
        )
    if K[0, 1] != 0.0:
        raise CalibrationFileError(
            f"{path}: {prefix}K has skew {K[0, 1]:g} but the core models none: "
            "recalibrate in MATLAB with EstimateSkew false"
        )
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise CalibrationFileError(f"{path}: {prefix}K is not an intrinsic matrix [fx 0 cx; 0 fy cy; 0 0 1]")
    K = K.copy()
    K[0, 2] -= 1.0  # MATLAB's first pixel centre is (1, 1), OpenCV's and the core's (0, 0)
    K[1, 2] -= 1.0
    radial = _mat_number_array(
        path, f"{prefix}RadialDistortion", _mat_field(path, cam, prefix, "RadialDistortion"), (2, 3, 6)
    ).reshape(-1)
    if np.any(radial[2:] != 0):
        raise CalibrationFileError(
            f"{path}: {prefix}RadialDistortion has {radial.size} coefficients and k3 = {radial[2]:g} (or a "
            "higher term) is not 0, but the core models only k1, k2: recalibrate in MATLAB with "
            "NumRadialDistortionCoefficients 2"
        )
    tangential = _mat_number_array(
        path, f"{prefix}TangentialDistortion", _mat_field(path, cam, prefix, "TangentialDistortion"), (2,)
    ).reshape(-1)
    size: Optional[Tuple[int, int]] = None
    if "ImageSize" in cam:
        raw = np.asarray(cam["ImageSize"], dtype=np.float64).reshape(-1)
        if raw.size == 2:
            if not (np.all(np.isfinite(raw)) and np.all(raw >= 1) and np.all(raw == np.round(raw))):
                raise CalibrationFileError(f"{path}: {prefix}ImageSize must be two positive whole numbers")
            size = (int(raw[1]), int(raw[0]))  # MATLAB: [rows, cols]
        elif raw.size:
            raise CalibrationFileError(
                f"{path}: {prefix}ImageSize must be [rows, cols], has {raw.size} values"
            )
    return K, np.array([radial[0], radial[1], tangential[0], tangential[1]]), size


def _find_stereo_struct(path: Path, data: Dict[str, object]) -> Tuple[str, Dict[str, object]]:
    if "CameraParameters1" in data:  # saved with save(..., '-struct', 's')
        return "", data
    found = [(k, v) for k, v in data.items() if isinstance(v, dict) and "CameraParameters1" in v]
    names = [k for k in data if not k.startswith("__")]
    if len(found) == 1:
        return f"{found[0][0]}.", found[0][1]
    if not found:
        raise CalibrationFileError(
            f"{path}: no stereoParameters struct in the file (variables: {', '.join(names) or 'none'}): "
            "in MATLAB run s = toStruct(stereoParams); save('stereo.mat', 's')"
        )
    raise CalibrationFileError(
        f"{path}: several stereoParameters structs ({', '.join(k for k, _ in found)}): save only one"
    )


def load_matlab(path: Path, image_size: Optional[Tuple[int, int]] = None) -> Tuple[StereoModel, str]:
    """The stereo model of a MATLAB ``stereoParameters`` struct (``toStruct``) in a .mat file, and T's unit.

    MATLAB's conventions are converted to OpenCV's: ``K`` (or the
    transposed ``IntrinsicMatrix`` of releases before R2022b) with the
    principal point moved by -1 pixel (MATLAB's first pixel is at (1, 1)),
    ``R = RotationOfCamera2'``, ``T = TranslationOfCamera2``, converted to
    metres when ``WorldUnits`` is a known length unit (the unit returned is
    then ``"m"``, else MATLAB's string). The image size comes from
    ``ImageSize`` ([rows, cols]) or, if the struct has none, ``image_size``.
    The file has no rectification: the caller computes it.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationFileError(f"{path}: no such file")
    with open(path, "rb") as f:
        head = f.read(128)
    if head.startswith(b"MATLAB 7.3"):
        raise CalibrationFileError(
            f"{path}: a MATLAB v7.3 (HDF5) file, which this reader does not support: "
            "save it again with save('stereo.mat', 's', '-v7')"
        )
    try:
        import scipy.io
    except ImportError:
        raise CalibrationFileError(
            f"{path}: reading MATLAB files needs scipy: pip install scipy"
        ) from None
    try:
        data = scipy.io.loadmat(str(path), simplify_cells=True)
    except Exception as exc:  # scipy raises ValueError, TypeError, MatReadError, ... for a bad file
        raise CalibrationFileError(f"{path}: not a readable MATLAB .mat file ({exc})") from None
    prefix, st = _find_stereo_struct(path, data)
    cam1, cam2 = (_mat_field(path, st, prefix, f"CameraParameters{k}") for k in (1, 2))
    K1, D1, size1 = _mat_camera(path, cam1, f"{prefix}CameraParameters1.")
    K2, D2, size2 = _mat_camera(path, cam2, f"{prefix}CameraParameters2.")
    if "RotationOfCamera2" in st or "PoseCamera2" not in st:
        R = _mat_number_array(
            path, f"{prefix}RotationOfCamera2", _mat_field(path, st, prefix, "RotationOfCamera2"), (9,)
        ).reshape(3, 3).T
        T = _mat_number_array(
            path, f"{prefix}TranslationOfCamera2", _mat_field(path, st, prefix, "TranslationOfCamera2"), (3,)
        ).reshape(3)
    else:  # PoseCamera2 (rigidtform3d as a struct): R is OpenCV's R, Translation is T
        pose = st["PoseCamera2"]
        if not isinstance(pose, dict):
            raise CalibrationFileError(f"{path}: {prefix}PoseCamera2 is not a struct with R and Translation")
        where = f"{prefix}PoseCamera2."
        R = _mat_number_array(path, f"{where}R", _mat_field(path, pose, where, "R"), (9,)).reshape(3, 3)
        T = _mat_number_array(
            path, f"{where}Translation", _mat_field(path, pose, where, "Translation"), (3,)
        ).reshape(3)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or abs(np.linalg.det(R) - 1.0) > 1e-6:
        raise CalibrationFileError(f"{path}: {prefix}RotationOfCamera2 is not a rotation matrix")
    if size1 is not None and size2 is not None and size1 != size2:
        raise CalibrationFileError(
            f"{path}: camera 1 is {size1[0]}x{size1[1]} but camera 2 is {size2[0]}x{size2[1]}: "
            "both cameras must have the same image size"
        )
    size = size1 or size2
    if size is not None and image_size is not None and tuple(image_size) != size:
        raise CalibrationFileError(
            f"{path}: the calibration is for {size[0]}x{size[1]} images, not {image_size[0]}x{image_size[1]}"
        )
    size = size or (tuple(image_size) if image_size is not None else None)  # type: ignore[assignment]
    if size is None:
        raise CalibrationFileError(
            f"{path}: {prefix}CameraParameters1.ImageSize is empty: give the image size, e.g. --size 752x480"
        )
    unit = "unknown"
    world = cam1.get("WorldUnits") if isinstance(cam1, dict) else None
    if isinstance(world, str) and world.strip():
        scale = WORLD_UNITS.get(world.strip().lower())
        if scale is None:
            unit = world.strip()
        else:
            T = T * scale
            unit = "m"
    return StereoModel(K1, D1, K2, D2, R, T, size), unit


# --------------------------------------------------------------------------
# ROS camera_info YAML, one file per camera
# --------------------------------------------------------------------------

ROS_FIELDS = (
    "image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
    "distortion_coefficients", "rectification_matrix", "projection_matrix",
)
ROS_REQUIRED = tuple(f for f in ROS_FIELDS if f != "camera_name")


def _ros_matrix(path: Path, data: Dict[str, object], name: str, shape: Tuple[int, int]) -> np.ndarray:
    node = data[name]
    if not isinstance(node, dict) or "data" not in node:
        raise CalibrationFileError(f"{path}: {name} must be a mapping with rows, cols and data")
    unknown = sorted(set(node) - {"rows", "cols", "data"})
    if unknown:
        raise CalibrationFileError(f"{path}: unknown field {name}.{unknown[0]} (known: rows, cols, data)")
    values = node["data"]
    numbers = isinstance(values, list) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
    )
    if not numbers:
        raise CalibrationFileError(f"{path}: {name}.data must be a list of numbers")
    arr = np.asarray(values, dtype=np.float64)
    rows, cols = node.get("rows", shape[0]), node.get("cols", shape[1])
    if not isinstance(rows, int) or not isinstance(cols, int) or rows * cols != arr.size:
        raise CalibrationFileError(f"{path}: {name} says {rows}x{cols} but has {arr.size} values")
    if not np.all(np.isfinite(arr)):
        raise CalibrationFileError(f"{path}: {name} has values that are not finite numbers")
    if shape[0] == 1:  # distortion: any length, checked by the caller
        return arr
    if (rows, cols) != shape:
        raise CalibrationFileError(f"{path}: {name} must be {shape[0]}x{shape[1]}, is {rows}x{cols}")
    return arr.reshape(shape)


def _read_ros(path: Path) -> Dict[str, object]:
    from .safe_yaml import YamlRefused, load

    path = Path(path)
    if not path.is_file():
        raise CalibrationFileError(f"{path}: no such file")
    try:
        data = load(path.read_text(encoding="utf-8"))
    except YamlRefused as exc:
        raise CalibrationFileError(f"{path}: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationFileError(f"{path}: not a YAML file ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise CalibrationFileError(f"{path}: not a ROS camera_info file (no mapping at the top)")
    unknown = sorted(set(data) - set(ROS_FIELDS))
    if unknown:
        raise CalibrationFileError(
            f"{path}: unknown field{'s' if len(unknown) > 1 else ''} {', '.join(map(str, unknown))} "
            f"(a ROS camera_info file has {', '.join(ROS_FIELDS)})"
        )
    missing = [f for f in ROS_REQUIRED if f not in data]
    if missing:
        raise CalibrationFileError(f"{path}: missing {', '.join(missing)}")
    model = data["distortion_model"]
    if model != "plumb_bob":
        raise CalibrationFileError(
            f"{path}: distortion_model is {model!r}; the core models plumb_bob (k1, k2, p1, p2, k3 = 0) only"
        )
    for name in ("image_width", "image_height"):
        v = data[name]
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise CalibrationFileError(f"{path}: {name} must be a positive whole number, is {v!r}")
    return data


def load_ros_pair(left: Path, right: Path) -> Tuple[StereoModel, Rectification]:
    """The stereo model and rectification of two ROS ``camera_info`` YAML files (left, right).

    ROS files carry each camera's rectification rotation and projection; the
    stereo pose follows from them: ``R = R2' R1``, ``T = R2' (P2[0,3]/f,
    P2[1,3]/f, 0)``, and ``Q`` is rebuilt as OpenCV's ``stereoRectify``
    makes it. ROS units are metres (REP 103).
    """
    cams = []
    for path in (Path(left), Path(right)):
        data = _read_ros(path)
        K = _ros_matrix(path, data, "camera_matrix", (3, 3))
        coefficients = _ros_matrix(path, data, "distortion_coefficients", (1, 0))
        D = _distortion(path, "distortion_coefficients", coefficients)
        Rr = _ros_matrix(path, data, "rectification_matrix", (3, 3))
        P = _ros_matrix(path, data, "projection_matrix", (3, 4))
        size = (int(str(data["image_width"])), int(str(data["image_height"])))
        cams.append((path, K, D, Rr, P, size))
    (lp, K1, D1, R1, P1, s1), (rp, K2, D2, R2, P2, s2) = cams
    if s1 != s2:
        raise CalibrationFileError(
            f"{lp} is for {s1[0]}x{s1[1]} images but {rp} for {s2[0]}x{s2[1]}: "
            "give the two cameras of one rig"
        )
    f = P2[0, 0]
    if f == 0 or P2[1, 1] == 0:
        raise CalibrationFileError(f"{rp}: projection_matrix has a zero focal length")
    t_rect = np.array([P2[0, 3] / f, P2[1, 3] / P2[1, 1], 0.0])
    if abs(t_rect[0]) <= abs(t_rect[1]):
        raise CalibrationFileError(
            f"{rp}: projection_matrix describes a vertical (or no) baseline; "
            "the core rectifies side-by-side pairs"
        )
    R = R2.T @ R1
    T = R2.T @ t_rect
    tx = t_rect[0]
    Q = np.array([
        [1.0, 0.0, 0.0, -P1[0, 2]],
        [0.0, 1.0, 0.0, -P1[1, 2]],
        [0.0, 0.0, 0.0, P1[0, 0]],
        [0.0, 0.0, -1.0 / tx, (P1[0, 2] - P2[0, 2]) / tx],
    ])
    model = StereoModel(K1, D1, K2, D2, R, T, s1)
    return model, Rectification(R1, R2, P1, P2, Q, s1)


ROS_UNIT = "m"  # REP 103: ROS lengths are metres


def ros_scale(units: str) -> Optional[float]:
    """Metres per unit of a calibration's T (``units``), or None when the unit is not a known length."""
    if units == ROS_UNIT:
        return 1.0
    return WORLD_UNITS.get(units.strip().lower())


def _yaml_float(value: float) -> str:
    """Shortest round-trip text of a double that YAML 1.1 parsers (PyYAML) read as a float, not a string."""
    v = float(value)
    if not math.isfinite(v):
        raise CalibrationFileError(f"cannot write {v} to a ROS camera_info file: values must be finite")
    mantissa, sep, exp = repr(v).partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + sep + exp


def ros_pair_text(
    model: StereoModel, rect: Rectification, *, scale: float = 1.0,
    names: Tuple[str, str] = ("left", "right"),
) -> Tuple[str, str]:
    """``left.yaml`` and ``right.yaml``: ROS ``camera_info`` text as camera_calibration_parsers writes it.

    One file per camera: ``image_width``, ``image_height``, ``camera_name``,
    ``camera_matrix`` (K), ``distortion_model: plumb_bob`` with five
    coefficients (k3 = 0), ``rectification_matrix`` (R1/R2) and
    ``projection_matrix`` (P1/P2, the right one's Tx in metres: its fourth
    column times ``scale``, the metres per unit of T). Doubles are written
    so that reading them back gives the very same values.
    """
    w, h = model.image_size

    def matrix(name: str, value: np.ndarray, rows: int, cols: int) -> List[str]:
        data = ", ".join(_yaml_float(v) for v in np.asarray(value, dtype=np.float64).reshape(-1))
        return [f"{name}:", f"  rows: {rows}", f"  cols: {cols}", f"  data: [{data}]"]

    texts = []
    for name, K, D, R, P in ((names[0], model.K1, model.D1, rect.R1, rect.P1),
                             (names[1], model.K2, model.D2, rect.R2, rect.P2)):
        P = np.array(P, dtype=np.float64)
        P[:, 3] *= scale
        lines = [f"image_width: {int(w)}", f"image_height: {int(h)}", f"camera_name: {name}"]
        lines += matrix("camera_matrix", K, 3, 3)
        lines.append("distortion_model: plumb_bob")
        lines += matrix("distortion_coefficients", np.append(np.asarray(D, dtype=np.float64), 0.0), 1, 5)
        lines += matrix("rectification_matrix", R, 3, 3)
        lines += matrix("projection_matrix", P, 3, 4)
        texts.append("\n".join(lines) + "\n")
    return texts[0], texts[1]


def write_ros_pair(
    model: StereoModel, rect: Rectification, outdir: Path, *, scale: float = 1.0,
) -> Tuple[Path, Path]:
    """Write ``outdir/left.yaml`` and ``outdir/right.yaml`` (:func:`ros_pair_text`); returns their paths.

    Written atomically, like :func:`write_opencv_pair`; :func:`load_ros_pair`
    reads them back to the same cameras (T in metres).
    """
    return _write_pair(Path(outdir), ("left.yaml", "right.yaml"), ros_pair_text(model, rect, scale=scale))


def parse_calibration_arg(arg: str) -> Tuple[Path, Path]:
    """``intrinsics.yml,extrinsics.yml`` -> two paths."""
    parts = [p for p in arg.split(",") if p]
    if len(parts) != 2:
        raise CalibrationFileError(
            f"--calibration takes two files separated by a comma, intrinsics.yml,extrinsics.yml; got {arg!r}"
        )
    return Path(parts[0]), Path(parts[1])
