"""The stereocam calibration file: one YAML a person can read, checked on every load.

A :class:`Calibration` is a stereo model (both cameras' intrinsics and
distortion, the pose of the right camera), its stereo rectification, and
what follows from them for the rectify core: per camera the 17 binary64
values the core's registers are derived from
(:class:`~stereocam.overlays.spec.rectify.CameraParams`: inverse homography
and lens) and the line-buffer figures (``LB_DELAY`` and the rows needed). Its ``id`` is the
first 12 hex digits of the SHA-256 of a canonical serialisation of the model
and rectification numbers, so two files with the same id program the core
identically.

Layout (schema_version 1)::

    schema_version: 1
    id: 0123456789ab            # sha256 of model + rectification, first 12 hex digits
    source: "..."               # where it came from (free text, not hashed)
    units: m                    # unit of T (and of P2[0][3] and Q); "unknown" if not known
    model:
      image_size: [640, 480]    # width, height
      K1: [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]   (one row per line)
      D1: [k1, k2, p1, p2]
      K2: ...  D2: ...
      R: 3x3  T: [x, y, z]      # X_right = R X_left + T
    rectification:
      alpha: 0.0                # null when the source gave the rectification
      R1, R2: 3x3   P1, P2: 3x4   Q: 4x4
    core:                       # derived from the above; checked on load
      width: 640
      height: 480
      lb_delay: 35              # LB_DELAY (derived again on load)
      rows_needed: 63           # line-buffer rows this calibration needs (derived again on load)
      left:                     # camera of register block 0x100; value = binary64, lo/hi = its bits
        H00: {value: 1.02, lo: 0x..., hi: 0x...}
        ... (H00..H22, FX, FY, CX, CY, K1, K2, P1, P2)
      right: ...                # register block 0x200
    quality: {...}              # optional: figures of `stereocam calibrate` (not checked)

Floats are written with the shortest text that reads back as the same
double, so saving and loading is exact. :func:`load_calibration` reads this
file and every format :mod:`.formats` imports, and validates what it
reads: schema version, known and complete fields, finite values and shapes,
register ranges, frame size, the line-buffer fit against a bitstream, and,
for this format, that ``core`` and ``id`` are what the model gives (a file
edited in one place but not the other is refused, not half trusted).
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from ..overlays.model.core_params import LineBufferTooSmall, check_frame_size, check_params
from ..overlays.model.linebuffer import LineBufferFit, rows_needed
from ..overlays.spec.rectify import (
    CAMERA_BASE,
    DEFAULT_LB_ROWS,
    DEFAULT_MAX_HEIGHT,
    DEFAULT_MAX_WIDTH,
    HINV_NAMES,
    INTRINSIC_NAMES,
    CameraParams,
    CoreConfig,
    camera_registers,
)
from .formats import (
    CalibrationFileError,
    atomic_write_text,
    load_matlab,
    load_opencv_pair,
    load_ros_pair,
    ros_scale,
    write_opencv_pair,
    write_ros_pair,
)
from .stereo import Rectification, StereoModel, camera_params, rectify

SCHEMA_VERSION = 1
ID_LENGTH = 12
# The core block lists each camera's calibration values (CameraParams) as binary64 with their bits.
PARAM_NAMES = HINV_NAMES + INTRINSIC_NAMES

TOP_FIELDS = ("schema_version", "id", "source", "units", "model", "rectification", "core", "quality")
TOP_REQUIRED = ("schema_version", "id", "model", "rectification", "core")
MODEL_FIELDS = ("image_size", "K1", "D1", "K2", "D2", "R", "T")
RECT_FIELDS = ("alpha", "R1", "R2", "P1", "P2", "Q")
RECT_REQUIRED = ("R1", "R2", "P1", "P2", "Q")
CORE_FIELDS = ("width", "height", "lb_delay", "rows_needed", "left", "right")
WORD_FIELDS = ("value", "lo", "hi")
SHAPES: Dict[str, Tuple[int, ...]] = {
    "K1": (3, 3),
    "K2": (3, 3),
    "D1": (4,),
    "D2": (4,),
    "R": (3, 3),
    "T": (3,),
    "R1": (3, 3),
    "R2": (3, 3),
    "P1": (3, 4),
    "P2": (3, 4),
    "Q": (4, 4),
}
# Register values in the file may differ from what this machine derives by
# rounding in the last bits (another LAPACK inverts P*R); an edit does not.
REL_TOL = 1e-9
ABS_TOL = 1e-12
# A calibration with figures for 100 pairs is about 100 KB; anything far larger is not one, and
# parsing 1 MB would hold the calibration lock for tens of seconds on the board's A9.
MAX_FILE_CHARS = 256 << 10

PathLike = Union[str, Path]


# --------------------------------------------------------------------------
# The calibration
# --------------------------------------------------------------------------


def f64_to_words(value: float) -> Tuple[int, int]:
    """binary64 -> (bits 31:0, bits 63:32): how the file spells a value exactly."""
    (bits,) = struct.unpack("<Q", struct.pack("<d", float(value)))
    return bits & 0xFFFFFFFF, bits >> 32


def _model_numbers(model: StereoModel, rect: Rectification) -> Dict[str, Any]:
    # "+ 0.0" turns -0.0 into 0.0: other tools do not keep the sign of zero (OpenCV writes Q's -0 as 0).
    out: Dict[str, Any] = {"image_size": [int(v) for v in model.image_size]}
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        out[name] = [float(v) + 0.0 for v in np.asarray(getattr(model, name), dtype=np.float64).ravel()]
    for name in ("R1", "R2", "P1", "P2", "Q"):
        out[name] = [float(v) + 0.0 for v in np.asarray(getattr(rect, name), dtype=np.float64).ravel()]
    return out


def calibration_id(model: StereoModel, rect: Rectification) -> str:
    """First 12 hex digits of the SHA-256 of the canonical JSON of the model and rectification numbers.

    Canonical: keys sorted, no spaces, matrices flattened row-major, floats as
    Python's shortest round-trip text, -0.0 as 0.0. Units, source and alpha are not
    hashed: the id names what the core is programmed with.
    """
    text = json.dumps(
        {"schema_version": SCHEMA_VERSION, **_model_numbers(model, rect)},
        sort_keys=True,
        separators=(",", ":"),
        allow_nan=False,
    )
    return hashlib.sha256(text.encode("ascii")).hexdigest()[:ID_LENGTH]


ROTATION_TOL = 1e-6  # |R^T R - I| and |det R - 1| of a rotation written with 17 significant digits
RECTIFY_TOL = 1e-3  # R2 R R1^T against I: rectifications from other tools agree to about 1e-9
MAX_BASELINE = 1e6  # in the file's units (m, mm or squares): a million of them is no stereo rig


def _check_rotation(where: str, name: str, R: np.ndarray) -> None:
    # A rotation's entries are within [-1, 1]; checking that first keeps R^T R from overflowing.
    if (np.abs(R).max() > 1.0 + ROTATION_TOL or np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOL
            or abs(np.linalg.det(R) - 1.0) > ROTATION_TOL):
        raise CalibrationFileError(f"{where}: {name} is not a rotation matrix (R^T R must be I and det R 1); "
                                   "the file is not a valid calibration")


def check_physical(model: StereoModel, rect: Rectification, alpha: Optional[float], where: str) -> None:
    """Refuse numbers no stereo rig has: the register check alone let zero matrices and 1e308 through.

    Positive focal lengths, rotations that are rotations, a baseline that is neither zero nor
    astronomical, rectifying rotations that agree with the model's R (R2 R R1^T = I), projection
    matrices of the rectified pair, and alpha in [0, 1].
    """
    for name, K in (("model.K1", model.K1), ("model.K2", model.K2)):
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise CalibrationFileError(f"{where}: {name} has focal lengths {K[0, 0]:g}, {K[1, 1]:g}: "
                                       "both must be > 0")
    for name, R in (("model.R", model.R), ("rectification.R1", rect.R1), ("rectification.R2", rect.R2)):
        _check_rotation(where, name, R)
    largest = float(np.abs(model.T).max())  # before the norm, which overflows for 1e308
    baseline = float(np.linalg.norm(model.T)) if largest <= MAX_BASELINE else largest
    if not 0 < baseline <= MAX_BASELINE:
        raise CalibrationFileError(f"{where}: model.T gives a baseline of {baseline:g}: a stereo rig's "
                                   f"cameras are apart, by at most {MAX_BASELINE:g} units")
    if np.abs(rect.R2 @ model.R @ rect.R1.T - np.eye(3)).max() > RECTIFY_TOL:
        raise CalibrationFileError(f"{where}: rectification R1, R2 do not match model.R (R2 R R1^T must be "
                                   "I): the rectification is of another rig; rectify again")
    for name, P in (("rectification.P1", rect.P1), ("rectification.P2", rect.P2)):
        if not (P[0, 0] > 0 and P[1, 1] > 0) or not np.array_equal(P[2], [0.0, 0.0, 1.0, 0.0]):
            raise CalibrationFileError(f"{where}: {name} is not the projection of a rectified camera "
                                       "([[f, 0, cx, Tx f], [0, f, cy, 0], [0, 0, 1, 0]])")
    if not np.any(rect.Q):
        raise CalibrationFileError(f"{where}: rectification.Q is all zeros: rectify again")
    if alpha is not None and not 0.0 <= alpha <= 1.0:
        raise CalibrationFileError(f"{where}: rectification.alpha is {alpha:g}: it must be from 0 (only "
                                   "valid pixels) to 1 (every source pixel)")


def _check_intrinsics(where: str, name: str, K: np.ndarray) -> None:
    if K[0, 1] != 0.0 or K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise CalibrationFileError(
            f"{where}: {name} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (the core models no skew), "
            f"is {np.asarray(K).tolist()}"
        )


@dataclass(frozen=True, eq=False)
class Calibration:
    """A stereo calibration and the rectify core's registers derived from it.

    Make one with :meth:`derive` (or :func:`load_calibration`); the derived
    fields are then consistent with ``model`` and ``rect`` by construction.
    Immutable; safe to share between threads. Two calibrations are equal
    when their ids (the model and rectification numbers), registers,
    line-buffer figures, alpha, units and source are.
    """

    model: StereoModel
    rect: Rectification
    left: CameraParams
    right: CameraParams
    fit: LineBufferFit  # LB_DELAY and the rows this calibration needs
    id: str
    alpha: Optional[float] = None  # the alpha the rectification was computed with, if known
    units: str = "unknown"  # unit of T
    source: str = ""
    quality: Optional[Mapping[str, Any]] = field(default=None, compare=False)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Calibration):
            return NotImplemented
        return (self.id, self.left, self.right, self.fit, self.alpha, self.units, self.source) == (
            other.id,
            other.left,
            other.right,
            other.fit,
            other.alpha,
            other.units,
            other.source,
        )

    __hash__ = object.__hash__

    # -- construction -------------------------------------------------------

    @classmethod
    def derive(
        cls,
        model: StereoModel,
        rect: Rectification,
        *,
        alpha: Optional[float] = None,
        units: str = "unknown",
        source: str = "",
        quality: Optional[Mapping[str, Any]] = None,
        max_width: int = DEFAULT_MAX_WIDTH,
        max_height: int = DEFAULT_MAX_HEIGHT,
        where: str = "calibration",
    ) -> "Calibration":
        """Core parameters, line-buffer figures and id of ``model`` and ``rect``.

        Refuses (``CalibrationFileError`` or a ``CoreParamsError`` subclass,
        both ``ValueError``): skewed intrinsics, a frame larger than
        ``max_width`` x ``max_height``, a singular rectification, values
        that do not fit the registers. ``where`` prefixes the messages
        (a file name). Takes tens of milliseconds (one source map per camera).
        """
        for name in ("K1", "K2"):
            _check_intrinsics(where, name, getattr(model, name))
        if tuple(rect.image_size) != tuple(model.image_size):
            raise CalibrationFileError(f"{where}: the rectification is for another image size than the model")
        check_physical(model, rect, alpha, where)
        w, h = model.image_size
        check_frame_size(w, h, max_width, max_height)
        try:
            left = camera_params(model.K1, model.D1, rect.R1, rect.P1)
            right = camera_params(model.K2, model.D2, rect.R2, rect.P2)
        except np.linalg.LinAlgError:
            raise CalibrationFileError(
                f"{where}: the rectification (P1*R1 or P2*R2) is singular; "
                "the file is not a valid calibration"
            ) from None
        check_params(left, right, w, h)
        fit = rows_needed([left, right], w, h)
        return cls(
            model,
            rect,
            left,
            right,
            fit,
            calibration_id(model, rect),
            alpha=alpha,
            units=units,
            source=source,
            quality=quality,
        )

    # -- figures --------------------------------------------------------------

    @property
    def image_size(self) -> Tuple[int, int]:
        return self.model.image_size

    @property
    def rows_needed(self) -> int:
        return self.fit.rows

    @property
    def lb_delay(self) -> int:
        return self.fit.delay

    def core_config(self) -> CoreConfig:
        """The register set to program (both parameter blocks, WIDTH, HEIGHT, LB_DELAY)."""
        w, h = self.image_size
        return CoreConfig(camera_registers(self.left, w, h), camera_registers(self.right, w, h), w, h,
                          self.fit.delay)

    def check_fits(self, lb_rows: int) -> None:
        """Raise :class:`LineBufferTooSmall` if a bitstream of ``lb_rows`` rows cannot run this."""
        if not self.fit.fits(lb_rows):
            raise LineBufferTooSmall(self.fit, lb_rows)

    # -- writing --------------------------------------------------------------

    def to_yaml(self) -> str:
        """The calibration file's text (see the module doc for the layout)."""
        return _emit(self)

    def save(self, path: PathLike) -> Path:
        """Write :meth:`to_yaml` to ``path`` atomically (temporary file, then rename); returns the path."""
        path = Path(path)
        atomic_write_text(path, self.to_yaml())
        return path

    def to_opencv(self, outdir: PathLike) -> Tuple[Path, Path]:
        """Write OpenCV stereo_calib files ``outdir/intrinsics.yml`` and ``outdir/extrinsics.yml``."""
        return write_opencv_pair(self.model, self.rect, Path(outdir))

    def to_ros(self, outdir: PathLike) -> Tuple[Path, Path]:
        """Write ROS camera_info files ``outdir/left.yaml`` and ``outdir/right.yaml``.

        ROS lengths are metres: T (in the projection matrices) is converted
        from :attr:`units` when that is a known length, and written as it is
        otherwise (``units`` unknown: say so to the user, :attr:`ros_units_known`).
        """
        return write_ros_pair(self.model, self.rect, Path(outdir), scale=ros_scale(self.units) or 1.0)

    @property
    def ros_units_known(self) -> bool:
        """Whether :meth:`to_ros` can give T in metres (the calibration's ``units`` is a known length)."""
        return ros_scale(self.units) is not None

    def summary(self) -> str:
        """One line for people: id, size, baseline, line-buffer rows."""
        w, h = self.image_size
        unit = "" if self.units == "unknown" else f" {self.units}"
        return (
            f"calibration {self.id}: {w}x{h}, baseline {self.model.baseline:.6g}{unit}, "
            f"line buffer {self.fit.rows} rows (delay {self.fit.delay})"
        )


# --------------------------------------------------------------------------
# YAML writer
# --------------------------------------------------------------------------


def _num(value: float) -> str:
    """Shortest round-trip text of a double that YAML 1.1 (PyYAML) reads as a float."""
    v = float(value)
    if not math.isfinite(v):
        raise CalibrationFileError(f"cannot write {v} to a calibration file: values must be finite")
    text = repr(v)
    mantissa, sep, exp = text.partition("e")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + sep + exp


def _row(values: Iterable[float]) -> str:
    return "[" + ", ".join(_num(v) for v in values) + "]"


def _matrix(lines: List[str], indent: str, name: str, value: np.ndarray) -> None:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1:
        note = "  # k1, k2, p1, p2" if name.startswith("D") else ""
        lines.append(f"{indent}{name}: {_row(arr)}{note}")
        return
    lines.append(f"{indent}{name}:")
    for r in arr:
        lines.append(f"{indent}  - {_row(r)}")


def _emit(cal: Calibration) -> str:
    import yaml

    m, r = cal.model, cal.rect
    w, h = m.image_size
    lines = [
        "# stereocam calibration. Written by stereocam; read by `stereocam rectify --calibration` and",
        "# `stereocam serve --calibration`. `model` and `rectification` are the calibration; `core` is",
        "# derived from them (the rectify core's registers, stereocam/overlays/RECTIFY_CORE.md) and",
        "# checked on load: edit the model, and the file is refused until `core` and `id` are made again",
        "# (delete both, then `stereocam calibration import FILE -o NEW`).",
        f"schema_version: {SCHEMA_VERSION}",
        f"id: {json.dumps(cal.id)}  # sha256 of model + rectification, first {ID_LENGTH} hex digits",
        f"source: {json.dumps(cal.source)}",
        f"units: {json.dumps(cal.units)}  # unit of T, P2[0][3] and Q",
        "model:",
        f"  image_size: [{int(w)}, {int(h)}]  # width, height",
    ]
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        _matrix(lines, "  ", name, getattr(m, name))
    lines.append("rectification:")
    lines.append(f"  alpha: {'null' if cal.alpha is None else _num(cal.alpha)}")
    for name in ("R1", "R2", "P1", "P2", "Q"):
        _matrix(lines, "  ", name, getattr(r, name))
    lines += [
        "core:",
        f"  width: {int(w)}",
        f"  height: {int(h)}",
        f"  lb_delay: {cal.fit.delay}  # LB_DELAY",
        f"  rows_needed: {cal.fit.rows}  # line-buffer rows (LB_ROWS) this calibration needs",
    ]
    for side, cam, params in (("left", "L", cal.left), ("right", "R", cal.right)):
        lines.append(
            f"  {side}:  # camera of register block {CAMERA_BASE[cam]:#05x}: binary64 value, lo/hi = its bits"
        )
        for name, value in params.values().items():
            lo, hi = f64_to_words(value)
            lines.append(f"    {name}: {{value: {_num(value)}, lo: {lo:#010x}, hi: {hi:#010x}}}")
    if cal.quality is not None:
        body = yaml.safe_dump(_plain(cal.quality), default_flow_style=None, sort_keys=False, width=100)
        lines.append("quality:  # figures of `stereocam calibrate`, for people; not checked on load")
        lines += ["  " + ln for ln in body.rstrip("\n").splitlines()]
    return "\n".join(lines) + "\n"


def _plain(value: Any) -> Any:
    """JSON/YAML-safe copy: numpy scalars to Python, tuples to lists."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# --------------------------------------------------------------------------
# YAML reader
# --------------------------------------------------------------------------


def _fields(
    where: str, node: Any, name: str, known: Sequence[str], required: Sequence[str]
) -> Dict[str, Any]:
    if not isinstance(node, dict):
        raise CalibrationFileError(f"{where}: {name} must be a mapping")
    unknown = [str(k) for k in node if k not in known]
    if unknown:
        label = f"{name}." if name != "the file" else ""
        raise CalibrationFileError(
            f"{where}: unknown field{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(label + k for k in unknown)} "
            f"(known: {', '.join(known)})"
        )
    missing = [k for k in required if k not in node]
    if missing:
        label = f"{name}." if name != "the file" else ""
        raise CalibrationFileError(f"{where}: missing {', '.join(label + k for k in missing)}")
    return node


def _number(where: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CalibrationFileError(f"{where}: {name} must be a number, is {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise CalibrationFileError(f"{where}: {name} has values that are not finite numbers")
    return v


def _integer(where: str, name: str, value: Any, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise CalibrationFileError(f"{where}: {name} must be a whole number >= {minimum}, is {value!r}")
    return int(value)


def _array(where: str, name: str, value: Any, shape: Tuple[int, ...]) -> np.ndarray:
    def bad() -> CalibrationFileError:
        want = (
            f"{shape[0]} numbers" if len(shape) == 1 else f"{shape[0]}x{shape[1]} (a list of {shape[0]} rows)"
        )
        return CalibrationFileError(f"{where}: {name} must be {want}")

    if not isinstance(value, list):
        raise bad()
    if len(shape) == 1:
        rows = [value]
    else:
        if len(value) != shape[0] or not all(isinstance(r, list) and len(r) == shape[1] for r in value):
            raise bad()
        rows = value
    if len(shape) == 1 and len(value) != shape[0]:
        raise bad()
    out = np.array([[_number(where, name, v) for v in r] for r in rows], dtype=np.float64)
    return out.reshape(shape)


def _close(a: float, b: float) -> bool:
    return a == b or abs(a - b) <= REL_TOL * max(abs(a), abs(b)) + ABS_TOL


def _core_params(where: str, side: str, node: Any, derived: CameraParams) -> CameraParams:
    block = _fields(where, node, f"core.{side}", PARAM_NAMES, PARAM_NAMES)
    values: Dict[str, float] = {}
    want = derived.values()
    for name in PARAM_NAMES:
        entry = _fields(where, block[name], f"core.{side}.{name}", WORD_FIELDS, WORD_FIELDS)
        value = _number(where, f"core.{side}.{name}.value", entry["value"])
        lo = _integer(where, f"core.{side}.{name}.lo", entry["lo"])
        hi = _integer(where, f"core.{side}.{name}.hi", entry["hi"])
        if (lo, hi) != f64_to_words(value):
            exp_lo, exp_hi = f64_to_words(value)
            raise CalibrationFileError(
                f"{where}: core.{side}.{name}: value {value!r} is lo {exp_lo:#010x} hi {exp_hi:#010x}, "
                f"but the file says lo {lo:#010x} hi {hi:#010x}: the file was edited inconsistently; "
                "delete core and id and run `stereocam calibration import FILE -o NEW` to derive them again"
            )
        if not _close(value, want[name]):
            raise CalibrationFileError(
                f"{where}: core.{side}.{name} is {value!r} but the model and rectification give "
                f"{want[name]!r}: the file was edited inconsistently; delete core and id and run "
                "`stereocam calibration import FILE -o NEW` to derive them again"
            )
        values[name] = value
    return CameraParams.from_values(values)


def parse_yaml(
    text: str,
    *,
    where: str = "calibration",
    max_width: int = DEFAULT_MAX_WIDTH,
    max_height: int = DEFAULT_MAX_HEIGHT,
    derive_missing: bool = False,
) -> Calibration:
    """A :class:`Calibration` from the text of a stereocam calibration file, fully validated.

    With ``derive_missing`` a file without ``core`` and ``id`` (a model
    edited by hand) is accepted and they are derived; otherwise both must
    be present and equal to what the model gives. Does not check the
    line-buffer fit against a bitstream (see :meth:`Calibration.check_fits`).
    """
    from .safe_yaml import YamlRefused, load

    try:
        data = load(text, max_chars=MAX_FILE_CHARS)
    except YamlRefused as exc:
        raise CalibrationFileError(f"{where}: {exc}") from None
    required = (
        TOP_REQUIRED if not derive_missing else tuple(f for f in TOP_REQUIRED if f not in ("id", "core"))
    )
    if not isinstance(data, dict) or "schema_version" not in data:
        raise CalibrationFileError(f"{where}: not a stereocam calibration file (no schema_version)")
    version = data["schema_version"]
    if version != SCHEMA_VERSION or isinstance(version, bool):  # true == 1 in Python, not in the schema
        if isinstance(version, int) and not isinstance(version, bool) and version > SCHEMA_VERSION:
            raise CalibrationFileError(
                f"{where}: schema_version {version} is newer than this stereocam reads ({SCHEMA_VERSION}): "
                "upgrade stereocam"
            )
        raise CalibrationFileError(f"{where}: schema_version must be {SCHEMA_VERSION}, is {version!r}")
    top = _fields(where, data, "the file", TOP_FIELDS, required)
    mnode = _fields(where, top["model"], "model", MODEL_FIELDS, MODEL_FIELDS)
    rnode = _fields(where, top["rectification"], "rectification", RECT_FIELDS, RECT_REQUIRED)
    size = mnode["image_size"]
    if not (isinstance(size, list) and len(size) == 2):
        raise CalibrationFileError(f"{where}: model.image_size must be [width, height]")
    w = _integer(where, "model.image_size width", size[0], 1)
    h = _integer(where, "model.image_size height", size[1], 1)
    arr = {n: _array(where, f"model.{n}", mnode[n], SHAPES[n]) for n in ("K1", "D1", "K2", "D2", "R", "T")}
    arr.update({n: _array(where, f"rectification.{n}", rnode[n], SHAPES[n]) for n in RECT_REQUIRED})
    alpha = rnode.get("alpha")
    if alpha is not None:
        alpha = _number(where, "rectification.alpha", alpha)
    for name in ("source", "units"):
        if name in top and not isinstance(top[name], str):
            raise CalibrationFileError(f"{where}: {name} must be a string")
    quality = top.get("quality")
    if quality is not None and not isinstance(quality, dict):
        raise CalibrationFileError(f"{where}: quality must be a mapping")
    model = StereoModel(arr["K1"], arr["D1"], arr["K2"], arr["D2"], arr["R"], arr["T"], (w, h))
    rect = Rectification(arr["R1"], arr["R2"], arr["P1"], arr["P2"], arr["Q"], (w, h))
    cal = Calibration.derive(
        model,
        rect,
        alpha=alpha,
        units=top.get("units", "unknown"),
        source=top.get("source", ""),
        quality=quality,
        max_width=max_width,
        max_height=max_height,
        where=where,
    )
    if "core" not in top and "id" not in top:
        return cal
    if "core" not in top or "id" not in top:
        raise CalibrationFileError(f"{where}: missing {'core' if 'core' not in top else 'id'}")
    core = _fields(where, top["core"], "core", CORE_FIELDS, CORE_FIELDS)
    for name, want in (("width", w), ("height", h)):
        got = _integer(where, f"core.{name}", core[name])
        if got != want:
            raise CalibrationFileError(
                f"{where}: core.{name} is {got} but the model gives {want}: "
                "the file was edited inconsistently; "
                "delete core and id and run `stereocam calibration import FILE -o NEW` to derive them again"
            )
    # lb_delay and rows_needed are figures of the core version that wrote the file (1.0 computed
    # positions in binary64, 2.0 in fixed point); they are read for form and derived again.
    for name in ("lb_delay", "rows_needed"):
        _integer(where, f"core.{name}", core[name])
    left = _core_params(where, "left", core["left"], cal.left)
    right = _core_params(where, "right", core["right"], cal.right)
    if top["id"] != cal.id:
        raise CalibrationFileError(
            f"{where}: id is {top['id']!r} but the model and rectification hash to {cal.id!r}: the file was "
            "edited; delete core and id and run `stereocam calibration import FILE -o NEW` "
            "to derive them again"
        )
    # The file's register values are what was checked and shown: program those.
    return Calibration(
        model,
        rect,
        left,
        right,
        cal.fit,
        cal.id,
        alpha=alpha,
        units=cal.units,
        source=cal.source,
        quality=quality,
    )


# --------------------------------------------------------------------------
# Loading any supported format
# --------------------------------------------------------------------------


def _sniff(path: Path) -> str:
    """'stereocam', 'opencv', 'ros', 'matlab' or 'unknown' from a file's first bytes."""
    with open(path, "rb") as f:
        head = f.read(4096)
    if head.startswith(b"MATLAB") or path.suffix.lower() == ".mat":
        return "matlab"
    text = head.decode("utf-8", errors="replace").lstrip()
    if (
        text.startswith("%YAML:")
        or text.startswith("<?xml")
        or text.startswith("<opencv_storage")
        or "!!opencv-matrix" in text
    ):  # OpenCV 4 writes "%YAML:1.0", OpenCV 5 "%YAML 1.2"
        return "opencv"
    if "schema_version" in text:
        return "stereocam"
    if "camera_matrix" in text or "projection_matrix" in text:
        return "ros"
    return "unknown"


def _split_source(source: Union[PathLike, Sequence[PathLike]]) -> List[Path]:
    if isinstance(source, str):
        return [Path(p) for p in source.split(",") if p]
    if isinstance(source, Path):
        return [source]
    return [Path(p) for p in source]


USAGE = (
    "a stereocam calibration.yaml, a MATLAB stereoParameters .mat, or two files separated by a comma: "
    "intrinsics.yml,extrinsics.yml (OpenCV) or left.yaml,right.yaml (ROS camera_info)"
)


def load_calibration(
    source: Union[PathLike, Sequence[PathLike]],
    *,
    image_size: Optional[Tuple[int, int]] = None,
    alpha: float = 0.0,
    lb_rows: Optional[int] = DEFAULT_LB_ROWS,
    max_width: int = DEFAULT_MAX_WIDTH,
    max_height: int = DEFAULT_MAX_HEIGHT,
    derive_missing: bool = False,
) -> Calibration:
    """Read and validate a calibration in any supported format.

    ``source`` is a path, a ``"first,second"`` string (what ``--calibration``
    takes) or a sequence of one or two paths: a stereocam YAML file, a
    MATLAB ``.mat`` (``toStruct`` of ``stereoParameters``), an OpenCV pair
    ``intrinsics.yml,extrinsics.yml`` or a ROS pair ``left.yaml,right.yaml``
    (recognised by content). ``image_size`` (width, height) is required
    where the files do not record it and otherwise must match. ``alpha``
    rectifies a MATLAB model (which has no rectification). ``lb_rows``
    checks the line-buffer fit against a bitstream (None: don't).
    ``derive_missing`` accepts a stereocam file without ``core``/``id``.

    Blocking (file reads and tens of milliseconds of numpy). Raises
    ``CalibrationFileError`` or a ``CoreParamsError`` subclass (both
    ``ValueError``) with a message naming the file and field.
    """
    paths = _split_source(source)
    if len(paths) not in (1, 2):
        raise CalibrationFileError(f"--calibration takes {USAGE}; got {len(paths)} files")
    for p in paths:
        if not p.is_file():
            raise CalibrationFileError(f"{p}: no such file; --calibration takes {USAGE}")
    kinds = [_sniff(p) for p in paths]
    if len(paths) == 1:
        path, kind = paths[0], kinds[0]
        if kind == "stereocam":
            try:
                text = path.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise CalibrationFileError(f"{path}: cannot read ({exc})") from None
            cal = parse_yaml(
                text,
                where=str(path),
                derive_missing=derive_missing,
                max_width=max_width,
                max_height=max_height,
            )
            if image_size is not None and tuple(image_size) != cal.image_size:
                cw, ch = cal.image_size
                raise CalibrationFileError(
                    f"{path}: the calibration is for {cw}x{ch} images, not {image_size[0]}x{image_size[1]}: "
                    "use images from the cameras that were calibrated"
                )
        elif kind == "matlab":
            model, units = load_matlab(path, image_size)
            rect = rectify(model, alpha=alpha)
            cal = Calibration.derive(
                model,
                rect,
                alpha=alpha,
                units=units,
                source=f"MATLAB {path.name}",
                where=str(path),
                max_width=max_width,
                max_height=max_height,
            )
        elif kind in ("opencv", "ros"):
            pair = "intrinsics.yml,extrinsics.yml" if kind == "opencv" else "left.yaml,right.yaml"
            raise CalibrationFileError(f"{path}: one file of a pair; give both, separated by a comma: {pair}")
        else:
            raise CalibrationFileError(f"{path}: not a calibration file stereocam knows; it reads {USAGE}")
    else:
        if kinds[0] != kinds[1] or kinds[0] not in ("opencv", "ros"):
            raise CalibrationFileError(
                f"{paths[0]},{paths[1]}: a pair must be two OpenCV files "
                "(intrinsics.yml,extrinsics.yml) or two "
                f"ROS camera_info files (left.yaml,right.yaml); these look like {kinds[0]} and {kinds[1]}"
            )
        if kinds[0] == "opencv":
            model, rect = load_opencv_pair(paths[0], paths[1], image_size)
            source_text = f"OpenCV {paths[0].name},{paths[1].name}"
            units = "unknown"
        else:
            model, rect = load_ros_pair(paths[0], paths[1])
            if image_size is not None and tuple(image_size) != model.image_size:
                raise CalibrationFileError(
                    f"{paths[0]}: the calibration is for {model.image_size[0]}x{model.image_size[1]} images, "
                    f"not {image_size[0]}x{image_size[1]}"
                )
            source_text = f"ROS {paths[0].name},{paths[1].name}"
            units = "m"
        cal = Calibration.derive(
            model,
            rect,
            units=units,
            source=source_text,
            where=str(paths[1]),
            max_width=max_width,
            max_height=max_height,
        )
    if lb_rows is not None:
        cal.check_fits(lb_rows)
    return cal


load = load_calibration
