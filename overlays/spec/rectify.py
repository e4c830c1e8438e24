"""The rectify core's AXI4-Lite register map and numeric formats: the one source of truth.

``overlays/RECTIFY_CORE.md`` explains every register and step in prose; this
module is what the driver, the emulated core and the model import. A test
checks that the document's table matches :data:`RECTIFY_MAP`.

Parameters are IEEE-754 binary64 values split over two 32-bit registers
(``_LO`` at the lower address holds bits 31:0, ``_HI`` bits 63:32). They are
*shadow* registers: the core uses them from the start of the first frame
after software sets ``CONTROL.APPLY`` (self-clearing), so a frame is never
rectified with half-written parameters.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Dict, List, Tuple

from .regs import Access, Field, Register, RegisterMap

CORE_ID = 0x52454354  # "RECT"
CORE_VERSION = 0x00010000  # 1.0: major in 31:16, minor in 15:0
VLNV = "stereocam:user:rectify:1.0"

# Build-time parameters of the bitstream we ship (read back through MAX_WIDTH,
# MAX_HEIGHT and LB_ROWS; the driver uses what it reads, never these).
DEFAULT_MAX_WIDTH = 1024
DEFAULT_MAX_HEIGHT = 1024
DEFAULT_LB_ROWS = 80  # block-RAM rows per camera, as in the paper
DEFAULT_WIDTH = 752
DEFAULT_HEIGHT = 480

# Interpolation format: 5 fractional bits for the sub-pixel position, weights
# are products of 5-bit fractions (sum 1024), result rounded half up.
FRAC_BITS = 5
FRAC_ONE = 1 << FRAC_BITS  # 32
WEIGHT_BITS = 2 * FRAC_BITS  # 10
WEIGHT_ROUND = 1 << (WEIGHT_BITS - 1)  # 512
# Fixed-point source positions are signed 16.5 (21 bits): |u * 32| < 2**20.
COORD_LIMIT = 1 << 20

CAMERAS = ("L", "R")
CAMERA_BASE = {"L": 0x100, "R": 0x200}
HINV_NAMES = tuple(f"H{r}{c}" for r in range(3) for c in range(3))
INTRINSIC_NAMES = ("FX", "FY", "CX", "CY", "K1", "K2", "P1", "P2")
PARAM_NAMES = HINV_NAMES + INTRINSIC_NAMES  # 17 binary64 values per camera, 8 bytes each

# Accepted range of each parameter (inclusive); outside it the value "does not
# fit" and the core refuses the whole parameter set on APPLY (FLAGS.CONFIG_ERROR).
PARAM_RANGE: Dict[str, Tuple[float, float]] = {
    **{n: (-1.0e9, 1.0e9) for n in HINV_NAMES},
    "FX": (1.0, 1.0e5),
    "FY": (1.0, 1.0e5),
    "CX": (-8192.0, 8192.0),
    "CY": (-8192.0, 8192.0),
    "K1": (-1000.0, 1000.0),
    "K2": (-1000.0, 1000.0),
    "P1": (-1000.0, 1000.0),
    "P2": (-1000.0, 1000.0),
}


def param_offset(camera: str, name: str) -> int:
    """Byte offset of the ``_LO`` word of a camera's binary64 parameter."""
    return CAMERA_BASE[camera] + 8 * PARAM_NAMES.index(name)


def _param_registers() -> List[Register]:
    regs: List[Register] = []
    for cam in CAMERAS:
        for name in PARAM_NAMES:
            off = param_offset(cam, name)
            doc = f"{cam} camera {name}, binary64"
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
        Register("MAX_HEIGHT", 0x00C, Access.RO, DEFAULT_MAX_HEIGHT, doc="tallest frame the row counters reach"),
        Register("LB_ROWS", 0x010, Access.RO, DEFAULT_LB_ROWS, doc="input rows buffered per camera"),
        Register("CAPS", 0x014, Access.RO, 0x1, fields=(Field("COLOUR", 0, doc="R, G, B rectified too"),)),
        Register(
            "CONTROL", 0x020, Access.RW, 0,
            fields=(
                Field("ENABLE", 0, doc="core accepts and emits frames"),
                Field("BYPASS", 1, doc="output = input, no rectification"),
                Field("GRAY", 2, doc="R, G, B outputs carry the rectified gray value"),
                Field("DEBUG_LINE", 3, doc="draw output row DEBUG_ROW white on both cameras"),
                Field("APPLY", 4, access=Access.SC, doc="latch the shadow parameters at the next frame start"),
            ),
        ),
        Register(
            "STATUS", 0x024, Access.RO, 0,
            fields=(
                Field("BUSY", 0, doc="a frame is in flight"),
                Field("APPLY_PENDING", 1, doc="shadow parameters wait for the next frame start"),
            ),
        ),
        Register(
            "FLAGS", 0x028, Access.W1C, 0,
            fields=(
                Field("LB_OVERFLOW", 0, doc="an output pixel needed a row outside the line buffer"),
                Field("SIZE_ERROR", 1, doc="an input frame did not match WIDTH x HEIGHT; it was dropped"),
                Field("CONFIG_ERROR", 2, doc="APPLY refused: a parameter out of range or WIDTH/HEIGHT/LB_DELAY invalid"),
            ),
        ),
        Register("FRAME_COUNT", 0x02C, Access.RO, 0, doc="output frames completed, wraps at 2**32"),
        Register("WIDTH", 0x030, Access.RW, DEFAULT_WIDTH, fields=(Field("VALUE", 0, 16),)),
        Register("HEIGHT", 0x034, Access.RW, DEFAULT_HEIGHT, fields=(Field("VALUE", 0, 16),)),
        Register("LB_DELAY", 0x038, Access.RW, 0, fields=(Field("VALUE", 0, 16),),
                 doc="input rows received ahead of the output row (shadowed)"),
        Register("DEBUG_ROW", 0x03C, Access.RW, 0, fields=(Field("VALUE", 0, 16),)),
        *_param_registers(),
    ],
    size=0x1000,
    doc="stereocam rectify core, AXI4-Lite slave",
)


def f64_to_words(value: float) -> Tuple[int, int]:
    """binary64 -> (lo, hi) register words."""
    (bits,) = struct.unpack("<Q", struct.pack("<d", float(value)))
    return bits & 0xFFFFFFFF, bits >> 32


def words_to_f64(lo: int, hi: int) -> float:
    (value,) = struct.unpack("<d", struct.pack("<Q", (hi << 32) | lo))
    return float(value)


@dataclass(frozen=True)
class CameraParams:
    """What the core needs for one camera: inverse homography and lens model.

    ``hinv`` maps a rectified output pixel ``(x, y, 1)`` (column vector) to
    the ideal (undistorted) pixel of the raw camera, up to scale.
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

    def values(self) -> Dict[str, float]:
        out = {n: float(v) for n, v in zip(HINV_NAMES, self.hinv)}
        out.update(FX=self.fx, FY=self.fy, CX=self.cx, CY=self.cy, K1=self.k1, K2=self.k2, P1=self.p1, P2=self.p2)
        return out

    @classmethod
    def from_values(cls, values: Dict[str, float]) -> "CameraParams":
        return cls(
            hinv=tuple(float(values[n]) for n in HINV_NAMES),
            fx=values["FX"], fy=values["FY"], cx=values["CX"], cy=values["CY"],
            k1=values["K1"], k2=values["K2"], p1=values["P1"], p2=values["P2"],
        )

    def problems(self) -> List[str]:
        """Every reason this camera's values do not fit the registers (empty if they do)."""
        out = []
        if len(self.hinv) != 9:
            out.append(f"the inverse homography has {len(self.hinv)} values, not 9")
            return out
        for name, value in self.values().items():
            lo, hi = PARAM_RANGE[name]
            if not math.isfinite(value):
                out.append(f"{name} is {value}, not a finite number")
            elif not lo <= value <= hi:
                out.append(f"{name} = {value:g} is outside the register's range {lo:g} .. {hi:g}")
        return out


@dataclass(frozen=True)
class CoreConfig:
    """Everything software programs into the core, for both cameras."""

    left: CameraParams
    right: CameraParams
    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    lb_delay: int = 0

    def camera(self, cam: str) -> CameraParams:
        return self.left if cam == "L" else self.right
