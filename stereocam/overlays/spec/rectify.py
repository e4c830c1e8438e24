"""The rectify core's register map, numeric formats and build parameters: the one source of truth.

``stereocam/overlays/RECTIFY_CORE.md`` explains every register and step in prose; this
module is what the driver, the emulated core, the model and the RTL (through
the generated header ``stereocam/overlays/rtl/rectify_spec.vh``) read. Tests check that
the document's tables and the header match this module.

Version 2.0 computes steps 1-4 in fixed point, as an RTL datapath does at
pixel rate: an exact integer homography evaluated incrementally, two dividers
and 13 rounded products. Its parameters are therefore integers: each is a
signed 64-bit two's complement value split over two 32-bit registers
(``_LO`` bits 31:0 at the lower address, ``_HI`` bits 63:32), accepted on
APPLY only inside its format's range. Software turns a calibration
(:class:`CameraParams`, floats) into those integers with
:func:`camera_registers`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from .core_common import control_register, flags_register, progress_registers, size_registers
from .regs import Access, Field, Register, RegisterMap

CORE_ID = 0x52454354  # "RECT"
CORE_VERSION = 0x00020000  # 2.0: major in 31:16, minor in 15:0
VLNV = "stereocam:user:rectify:2.0"


@dataclass(frozen=True)
class Build:
    """Build-time parameters of one bitstream's core (read back from MAX_WIDTH, MAX_HEIGHT, LB_ROWS, CAPS)."""

    name: str
    max_width: int
    max_height: int
    lb_rows: int  # input rows an output row may read (LB_ROWS register)
    colour: bool  # CAPS.COLOUR: R, G, B rectified too; else gray only


# The paper's configuration (gray, 80 rows, 752 wide) and a colour build of both cameras that
# leaves block RAM for the VDMAs, the switch and the camera inputs (see RECTIFY_CORE.md).
BUILDS: Dict[str, Build] = {
    "gray": Build("gray", 752, 1024, 80, colour=False),
    "colour": Build("colour", 752, 1024, 80, colour=True),
}
DEFAULT_BUILD = BUILDS["colour"]
DEFAULT_MAX_WIDTH = DEFAULT_BUILD.max_width
DEFAULT_MAX_HEIGHT = DEFAULT_BUILD.max_height
DEFAULT_LB_ROWS = DEFAULT_BUILD.lb_rows
DEFAULT_WIDTH = 752
DEFAULT_HEIGHT = 480
SIZE_BITS = 11  # column and row counters: MAX_WIDTH and MAX_HEIGHT are below 2**SIZE_BITS
#: The range each build parameter may take (the packaged IP's user parameters, which the Vivado GUI
#: enforces): sizes below 2**SIZE_BITS and of at least 2 (a 2x2 Bayer cell), at least one line-buffer
#: row, COLOUR 0 (gray build) or 1 (colour build).
BUILD_LIMITS: Dict[str, Tuple[int, int]] = {
    "MAX_WIDTH": (2, (1 << SIZE_BITS) - 1),
    "MAX_HEIGHT": (2, (1 << SIZE_BITS) - 1),
    "LB_ROWS": (1, (1 << SIZE_BITS) - 1),
    "COLOUR": (0, 1),
}
#: Clocks per beat on the stream ports: the coordinate engine serves the two cameras on alternate
#: clocks (RECTIFY_CORE.md, "Latency and rates"; measured by tests/hdl/test_rectify_core_rtl.py).
CLOCKS_PER_BEAT = 2

# ---- Step 5: interpolation. 5 fractional bits per source coordinate, integer weights (sum 1024),
# result rounded half up: exactly OpenCV's fixed-point bilinear remap with CV_16SC2 maps.
FRAC_BITS = 5
FRAC_ONE = 1 << FRAC_BITS  # 32
WEIGHT_BITS = 2 * FRAC_BITS  # 10
WEIGHT_ROUND = 1 << (WEIGHT_BITS - 1)  # 512
# Source positions are signed 16.5 fixed point: a position with |iu| or |iv| >= 2**20 gives 0.
COORD_LIMIT = 1 << 20
POS_BITS = 21


@dataclass(frozen=True)
class Fixed:
    """A signed fixed-point format: ``bits`` two's complement bits, ``frac`` of them fractional."""

    bits: int
    frac: int

    @property
    def lo(self) -> int:
        return -(1 << (self.bits - 1))

    @property
    def hi(self) -> int:
        return (1 << (self.bits - 1)) - 1

    def fits(self, value: int) -> bool:
        return self.lo <= value <= self.hi


# ---- Steps 1-4 (see RECTIFY_CORE.md for the equations these widths belong to).
F = 30  # fractional bits of normalised coordinates and of every step-2/3 intermediate
ACC_BITS = 48  # homography accumulators X, Y, Z: two's complement, wrapping modulo 2**48
N_FMT = Fixed(44, 0)  # normalised homography entries: integers, |N| < 2**43 (the scale is free)
K_FMT = Fixed(36, 32)  # k1, k2: |k| < 8
P_FMT = Fixed(33, 32)  # p1, p2: |p| < 1
FXY_FMT = Fixed(36, 20)  # fx, fy (at least 1 px, below 32768 px) and cx, cy (|c| < 32768 px)
FXY_MIN = 1 << FXY_FMT.frac  # 1.0 px

# Validity limits (a pixel whose value reaches one gives 0); see "Validity" in the document.
XN_LIMIT = 4  # |xn|, |yn| < 4 (|X| < 4 Z)
R2_LIMIT = 8  # r2 < 8
RADIAL_LIMIT = 8  # |radial| < 8
XD_LIMIT = 16  # |xd|, |yd| < 16
DIV_QBITS = 2 + F + 1  # quotient bits of floor(|X| * 2**(F+1) / Z) < 4 * 2**(F+1)

# Width of every intermediate, signed, large enough for every value a valid pixel can take.
WIDTHS: Dict[str, int] = {
    "XN": F + 4,  # |xn| <= 4 * 2**F after rounding
    "X2": F + 6,  # x2, y2 < 16 before the r2 check
    "XY": F + 4,
    "R2": F + 4,  # after the check: 0 <= r2 < 8
    "T": K_FMT.frac + 7,  # k2 * r2, 32 fractional bits, |t| < 64
    "S": K_FMT.frac + 8,  # k1 + t, |s| < 72
    "M": F + 11,  # s * r2, |m| < 576
    "RADIAL": F + 4,  # after the check: |radial| < 8
    "A": F + 6,  # xn * radial, |a| < 32
    "XY2": F + 5,  # 2 xy, exact
    "Q": F + 6,  # r2 + 2 x2, < 24
    "C": F + 6,  # p-products, |c| < 24
    "XD": F + 5,  # after the check: |xd| < 16
    "SU": FXY_FMT.frac + F + 21,  # fx * xd + cx * 2**F, |su| < 2**20 px
}
SU_SHIFT = FXY_FMT.frac + F - FRAC_BITS  # su (50 fractional bits) -> iu (5 fractional bits)

CAMERAS = ("L", "R")
CAMERA_BASE = {"L": 0x100, "R": 0x200}
N_NAMES = tuple(f"N{r}{c}" for r in range(3) for c in range(3))
HINV_NAMES = tuple(f"H{r}{c}" for r in range(3) for c in range(3))  # a calibration's inverse homography
INTRINSIC_NAMES = ("FX", "FY", "CX", "CY", "K1", "K2", "P1", "P2")
PARAM_NAMES = N_NAMES + INTRINSIC_NAMES  # 17 signed 64-bit integers per camera, 8 bytes each
PARAM_FORMAT: Dict[str, Fixed] = {
    **{n: N_FMT for n in N_NAMES},
    "FX": FXY_FMT, "FY": FXY_FMT, "CX": FXY_FMT, "CY": FXY_FMT,
    "K1": K_FMT, "K2": K_FMT, "P1": P_FMT, "P2": P_FMT,
}
# Accepted range of each parameter's integer (inclusive); outside it the core refuses the whole
# parameter set on APPLY (FLAGS.CONFIG_ERROR) and keeps the previous one.
PARAM_RANGE: Dict[str, Tuple[int, int]] = {name: (fmt.lo, fmt.hi) for name, fmt in PARAM_FORMAT.items()}
PARAM_RANGE.update(FX=(FXY_MIN, FXY_FMT.hi), FY=(FXY_MIN, FXY_FMT.hi))


def param_offset(camera: str, name: str) -> int:
    """Byte offset of the ``_LO`` word of a camera's 64-bit parameter."""
    return CAMERA_BASE[camera] + 8 * PARAM_NAMES.index(name)


def _param_registers() -> List[Register]:
    regs: List[Register] = []
    for cam in CAMERAS:
        for name in PARAM_NAMES:
            off = param_offset(cam, name)
            doc = f"{cam} camera {name}, signed 64-bit"
            regs.append(Register(f"{cam}_{name}_LO", off, Access.RW, 0, doc=doc + " bits 31:0"))
            regs.append(Register(f"{cam}_{name}_HI", off + 4, Access.RW, 0, doc=doc + " bits 63:32"))
    return regs


RECTIFY_MAP = RegisterMap(
    "rectify",
    [
        Register("ID", 0x000, Access.RO, CORE_ID, doc="identity, 'RECT'"),
        Register(
            "VERSION", 0x004, Access.RO, CORE_VERSION,
            fields=(Field("MINOR", 0, 16), Field("MAJOR", 16, 16)),
        ),
        Register("MAX_WIDTH", 0x008, Access.RO, DEFAULT_MAX_WIDTH, doc="widest frame the line buffer holds"),
        Register("MAX_HEIGHT", 0x00C, Access.RO, DEFAULT_MAX_HEIGHT,
                 doc="tallest frame the row counters reach"),
        Register("LB_ROWS", 0x010, Access.RO, DEFAULT_LB_ROWS, doc="input rows an output row may read"),
        Register("CAPS", 0x014, Access.RO, int(DEFAULT_BUILD.colour),
                 fields=(Field("COLOUR", 0, doc="R, G, B rectified too"),)),
        control_register(0, (
            Field("BYPASS", 1, doc="output = input, no rectification"),
            Field("GRAY", 2, doc="R, G, B outputs carry the rectified gray value"),
            Field("DEBUG_LINE", 3, doc="draw output row DEBUG_ROW white on both cameras"),
        )),
        flags_register((
            Field("LB_OVERFLOW", 0, doc="an output pixel needed a row outside the line buffer"),
            Field("SIZE_ERROR", 1, doc="an input frame did not match WIDTH x HEIGHT"),
            Field("CONFIG_ERROR", 2,
                  doc="APPLY refused: a parameter out of range or WIDTH/HEIGHT/LB_DELAY invalid"),
        )),
        *progress_registers(),
        *size_registers(DEFAULT_WIDTH, DEFAULT_HEIGHT),
        Register("LB_DELAY", 0x038, Access.RW, 0, fields=(Field("VALUE", 0, 16),),
                 doc="input rows received ahead of the output row (shadowed)"),
        Register("DEBUG_ROW", 0x03C, Access.RW, 0, fields=(Field("VALUE", 0, 16),)),
        *_param_registers(),
    ],
    size=0x1000,
    doc="stereocam rectify core, AXI4-Lite slave",
)


def i64_to_words(value: int) -> Tuple[int, int]:
    """Signed 64-bit integer -> (lo, hi) register words."""
    value = int(value)
    if not -(1 << 63) <= value < (1 << 63):
        raise ValueError(f"{value} does not fit a signed 64-bit register pair")
    bits = value & ((1 << 64) - 1)
    return bits & 0xFFFFFFFF, bits >> 32


def words_to_i64(lo: int, hi: int) -> int:
    bits = ((int(hi) & 0xFFFFFFFF) << 32) | (int(lo) & 0xFFFFFFFF)
    return bits - (1 << 64) if bits >> 63 else bits


def _intrinsics(camera: Any) -> Dict[str, Any]:
    """A camera's lens values by name, ``FX``..``P2`` (:data:`INTRINSIC_NAMES`), from its ``fx``..``p2``."""
    return {name: getattr(camera, name.lower()) for name in INTRINSIC_NAMES}


def _intrinsic_fields(values: Mapping[str, Any]) -> Dict[str, Any]:
    """The keyword arguments ``fx``..``p2`` of :class:`CameraParams` and :class:`CameraRegs` from
    lens values by name (``FX``..``P2``)."""
    return {name.lower(): values[name] for name in INTRINSIC_NAMES}


@dataclass(frozen=True)
class CameraParams:
    """One camera's calibration as the core needs it, in real numbers (what calibration files hold).

    ``hinv`` maps a rectified output pixel ``(x, y, 1)`` (column vector) to
    the ideal (undistorted) pixel of the raw camera, up to scale. The core's
    registers are derived from it by :func:`camera_registers`.
    """

    hinv: Tuple[float, ...]  # 9 values, row-major
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float
    k2: float
    p1: float
    p2: float

    def lens(self) -> Dict[str, float]:
        return _intrinsics(self)

    def values(self) -> Dict[str, float]:
        """``H00``..``H22`` then the lens values, by name (what calibration files store)."""
        out = {n: float(v) for n, v in zip(HINV_NAMES, self.hinv, strict=True)}
        out.update(self.lens())
        return out

    @classmethod
    def from_values(cls, values: Dict[str, float]) -> "CameraParams":
        return cls(
            hinv=tuple(float(values[n]) for n in HINV_NAMES), **_intrinsic_fields(values),
        )


@dataclass(frozen=True)
class CameraRegs:
    """One camera's parameter registers: the integers the core computes with."""

    n: Tuple[int, ...]  # N00..N22, row-major
    fx: int
    fy: int
    cx: int
    cy: int
    k1: int
    k2: int
    p1: int
    p2: int

    def values(self) -> Dict[str, int]:
        out = {name: int(v) for name, v in zip(N_NAMES, self.n, strict=True)}
        out.update(_intrinsics(self))
        return out

    @classmethod
    def from_values(cls, values: Dict[str, int]) -> "CameraRegs":
        return cls(
            n=tuple(int(values[name]) for name in N_NAMES), **_intrinsic_fields(values),
        )

    def problems(self) -> List[str]:
        """Every register value outside its accepted range (empty when the core accepts them all)."""
        out = []
        if len(self.n) != 9:
            return [f"the homography has {len(self.n)} values, not 9"]
        for name, value in self.values().items():
            lo, hi = PARAM_RANGE[name]
            if not lo <= value <= hi:
                out.append(f"register {name} = {value} is outside {lo} .. {hi}")
        return out


def _describe(name: str, value: float, lo: int, hi: int, frac: int) -> str:
    scale = float(1 << frac)
    return f"{name} = {value:g} is outside the register's range {lo / scale:g} .. {hi / scale:g}"


def _corners(width: int, height: int) -> Sequence[Tuple[int, int]]:
    return ((0, 0), (width - 1, 0), (0, height - 1), (width - 1, height - 1))


def normalised_homography(p: CameraParams) -> List[float]:
    """``N = K^-1 H^-1``: output pixel -> normalised ray of the raw camera, so ``X/Z, Y/Z`` are ``xn, yn``."""
    h = [float(v) for v in p.hinv]
    n = [(h[c] - p.cx * h[6 + c]) / p.fx for c in range(3)]
    n += [(h[3 + c] - p.cy * h[6 + c]) / p.fy for c in range(3)]
    n += h[6:9]
    return n


def camera_registers(p: CameraParams, width: int, height: int) -> CameraRegs:
    """Turn one camera's calibration into the core's register integers for a ``width`` x ``height`` frame.

    ``N`` is scaled by the largest power of two that keeps every entry below
    2**43 and every accumulator at the frame's corners below 2**47 (the
    accumulators are linear, so the corners bound the frame), and its sign
    is chosen so that Z is positive at the frame's centre. Raises
    :class:`ValueError` listing every value that does not fit.
    """
    problems: List[str] = []
    if len(p.hinv) != 9:
        raise ValueError(f"the inverse homography has {len(p.hinv)} values, not 9")
    for name, value in p.values().items():
        if not math.isfinite(value):
            problems.append(f"{name} is {value}, not a finite number")
    if not problems and not (p.fx > 0 and p.fy > 0):
        problems.append(f"the focal lengths must be positive (fx = {p.fx:g}, fy = {p.fy:g})")
    if problems:
        raise ValueError("; ".join(problems))
    lens: Dict[str, int] = {}
    for name, value in p.lens().items():
        fmt = PARAM_FORMAT[name]
        lo, hi = PARAM_RANGE[name]
        scaled = value * (1 << fmt.frac)
        if not lo <= scaled <= hi:
            problems.append(_describe(name, value, lo, hi, fmt.frac))
        else:
            lens[name] = int(round(scaled))
    n = normalised_homography(p)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    zc = n[6] * cx + n[7] * cy + n[8]
    biggest = max(abs(v) for v in n)
    if not all(math.isfinite(v) for v in n) or biggest == 0.0 or not math.isfinite(zc):
        problems.append("the homography is degenerate (all zero or not finite)")
    elif zc == 0.0:
        problems.append("the homography sends the image centre to infinity (Z = 0)")
    if problems:
        raise ValueError("; ".join(problems))
    if zc < 0:
        n = [-v for v in n]
    shift = math.floor(math.log2(N_FMT.hi / biggest))
    acc_limit = 1 << (ACC_BITS - 1)
    while True:
        nq = [int(round(math.ldexp(v, shift))) for v in n]
        big = max(abs(v) for v in nq)
        acc = max(abs(nq[3 * r] * x + nq[3 * r + 1] * y + nq[3 * r + 2])
                  for r in range(3) for x, y in _corners(width, height))
        if big <= N_FMT.hi and acc < acc_limit:
            break
        shift -= 1
    return CameraRegs(tuple(nq), **{k.lower(): v for k, v in lens.items()})


@dataclass(frozen=True)
class CoreConfig:
    """Everything software programs into the core's shadow registers, for both cameras."""

    left: CameraRegs
    right: CameraRegs
    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    lb_delay: int = 0

    def camera(self, cam: str) -> CameraRegs:
        return self.left if cam == "L" else self.right


def as_registers(p: "CameraParams | CameraRegs", width: int, height: int) -> CameraRegs:
    """Registers for a calibration (converted for this frame size) or registers as they are."""
    return p if isinstance(p, CameraRegs) else camera_registers(p, width, height)


def identity_registers(width: int, height: int, focal: Optional[float] = None) -> CameraRegs:
    """Registers that map every output pixel to itself (no distortion): a neutral parameter set."""
    f = float(focal or max(width, height))
    return camera_registers(CameraParams((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), f, f,
                                         (width - 1) / 2.0, (height - 1) / 2.0, 0.0, 0.0, 0.0, 0.0),
                            width, height)
