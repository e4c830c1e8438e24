"""The stereo-matching core's algorithm constants, register map and stream formats: the one source of truth.

``stereocam/overlays/STEREO_CORE.md`` explains every step and register in prose; the model
(``overlays/model/stereo_*.py``), the emulated fabric, the driver and the RTL (through a
generated header) read this module. Every quantity is an integer with a stated width, so the
model and the RTL can agree bit for bit.

The pipeline, per output pixel of the rectified gray pair:

1. a 9x7 census transform of each image (62 bits: a neighbour darker than the centre is 1);
2. the matching cost ``C(x, y, d)``: the Hamming distance of the left census at ``x`` and the
   right census at ``x - d`` (0..62; :data:`COST_OOB` where ``x - d`` is left of the image);
3. semi-global aggregation along three paths a raster scan can follow (from the left, from
   above, from the upper right), with penalties P1 and P2, P2 lowered to P2_EDGE where the left
   image has an edge along the path (a fourth path, from the upper left, would need 24 more
   BRAM36 of path state for 0.4 points of bad-2.0 on Middlebury: see STEREO_CORE.md);
4. the winner (lowest summed cost, the lowest disparity on ties), a uniqueness test against the
   best cost more than one disparity away, and a confidence from the same two costs;
5. a parabola through the winner's neighbours: 4 fractional bits (1/16 px, OpenCV's unit);
6. a left-right check against the right image's winners, taken from the same costs by the
   diagonal minimum (no second pass over the images);
7. a 3x3 median of the disparity codes.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Dict, List, Tuple

from .core_common import control_register, flags_register, progress_registers, size_registers
from .regs import Access, Field, Register, RegisterMap

CORE_ID = 0x53544552  # "STER"
CORE_VERSION = 0x00010000  # 1.0: major in 31:16, minor in 15:0
VLNV = "stereocam:user:stereo:1.0"

# ---- Step 1: census transform.
CENSUS_W = 9  # window columns
CENSUS_H = 7  # window rows
CENSUS_BITS = CENSUS_W * CENSUS_H - 1  # 62: every neighbour, row by row from the top left, centre skipped
#: The window's offsets (dy, dx) in bit order: bit ``i`` of a census word compares neighbour ``i``.
CENSUS_OFFSETS: Tuple[Tuple[int, int], ...] = tuple(
    (dy, dx)
    for dy in range(-(CENSUS_H // 2), CENSUS_H // 2 + 1)
    for dx in range(-(CENSUS_W // 2), CENSUS_W // 2 + 1)
    if (dy, dx) != (0, 0)
)

# ---- Step 2: matching cost.
COST_BITS = 6  # 0..62
COST_OOB = CENSUS_BITS  # the cost of a disparity that reaches left of the right image

# ---- Step 3: aggregation.
#: The paths, as the step back to the previous pixel on the path (dx, dy): each path's previous
#: pixel is on this row (to the left) or on the previous row, so one raster pass computes all.
PATHS: Tuple[Tuple[int, int], ...] = ((-1, 0), (0, -1), (1, -1))
PATH_NAMES: Tuple[str, ...] = ("left", "above", "upper right")
PATH_BITS = 8  # L_r <= C + P2 <= 62 + P2_MAX = 255
P2_MAX = (1 << PATH_BITS) - 1 - COST_OOB  # 193
SUM_BITS = 10  # S = sum of the three L_r <= 765

# ---- Step 4: winner, uniqueness and confidence.
UNIQUENESS_ONE = 256  # UNIQUENESS counts 1/256ths: the second best must exceed the best by more
CONF_BITS = 8

# ---- Step 5: sub-pixel refinement.
SUBPIX_BITS = 4
SUBPIX_ONE = 1 << SUBPIX_BITS  # 16: a disparity code is disparity x 16

# ---- The output code.
DISP_BITS = 16
INVALID = 0xFFFF  # the disparity code of a pixel without a disparity

#: Why a pixel has none (the output beat's REASON field). The first that applies is given.
REASON_VALID = 0
REASON_BORDER = 1  # the winner matched left of the right image (x - d < 0)
REASON_UNIQUENESS = 2  # the second best cost, more than one disparity away, was too close
REASON_LR = 3  # the right image's winner at x - d disagrees by more than LR_TOL
REASON_MEDIAN = 4  # valid, but most of its 3x3 neighbourhood was not: the median is invalid
REASONS: Dict[int, str] = {
    REASON_VALID: "valid",
    REASON_BORDER: "matched outside the right image",
    REASON_UNIQUENESS: "not unique",
    REASON_LR: "left-right check",
    REASON_MEDIAN: "median of invalid neighbours",
}
REASON_BITS = 3

# ---- Stream formats.
#: In: the rectify core's 64-bit pixel (``spec/pixel.py``); the core reads the gray bytes.
IN_LEFT_GRAY_BYTE = 3
IN_RIGHT_GRAY_BYTE = 7
#: Out: one 32-bit beat per input pixel, in the same order (TUSER on the first, TLAST ending rows).
OUT_BEAT_BITS = 32
OUT_DISP_LSB, OUT_CONF_LSB, OUT_REASON_LSB = 0, 16, 24


@dataclass(frozen=True)
class Build:
    """Build-time parameters of one bitstream's stereo core (read back from MAX_WIDTH, MAX_DISP, PARALLEL)."""

    name: str
    max_width: int
    max_height: int
    max_disp: int  # disparities the path buffers hold per pixel
    parallel: int  # disparities evaluated per clock: a pixel takes max_disp / parallel clocks


BUILDS: Dict[str, Build] = {"depth": Build("depth", 752, 1024, 128, 32)}
DEFAULT_BUILD = BUILDS["depth"]
SIZE_BITS = 11
#: What a build may choose (the packaged IP's user parameters offer these ranges): a frame at least
#: the census window, sizes within the size registers, and 32 to 128 disparities, the range the
#: tests simulate. A slot is 4 clocks, so MAX_DISP must also be 4 x PARALLEL.
BUILD_LIMITS: Dict[str, Tuple[int, int]] = {
    "MAX_WIDTH": (16, (1 << SIZE_BITS) - 1),
    "MAX_HEIGHT": (16, (1 << SIZE_BITS) - 1),
    "MAX_DISP": (32, 128),
    "PARALLEL": (8, 32),
}


@dataclass(frozen=True)
class StereoParams:
    """What software programs into the core: the shadow registers NUM_DISP to LR_TOL, then
    CONTROL's switches (see STEREO_CORE.md for each)."""

    num_disp: int = 128
    p1: int = 16
    p2: int = 100
    p2_edge: int = 40
    edge_thresh: int = 24
    uniqueness: int = 13  # 1/256ths: 13 is 5.1 %
    lr_tol: int = 2
    lr_check: bool = True
    subpixel: bool = True
    median: bool = True

    def problems(self, build: Build = DEFAULT_BUILD) -> List[str]:
        """Every value the core would refuse (CONFIG_ERROR), each saying what it accepts."""
        out: List[str] = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in LIMITS:
                lo, hi = LIMITS[f.name](build)
                if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
                    out.append(f"{f.name} = {value!r}: the core takes a whole number in {lo} .. {hi}")
            elif not isinstance(value, bool):
                out.append(f"{f.name} = {value!r}: the core takes true or false")
        if out:
            return out
        if self.num_disp % build.parallel:
            out.append(f"num_disp = {self.num_disp}: the core takes a multiple of {build.parallel} "
                       f"(it evaluates {build.parallel} disparities per clock)")
        if not self.p1 <= self.p2_edge <= self.p2:
            out.append(f"the penalties must keep p1 <= p2_edge <= p2 (they are {self.p1}, "
                       f"{self.p2_edge}, {self.p2})")
        return out

    def with_values(self, **values: object) -> "StereoParams":
        return replace(self, **values)  # type: ignore[arg-type]

    def as_json(self) -> Dict[str, object]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: The range of each numeric parameter, given the build.
LIMITS = {
    "num_disp": lambda b: (b.parallel, b.max_disp),
    "p1": lambda b: (0, 63),
    "p2": lambda b: (0, P2_MAX),
    "p2_edge": lambda b: (0, P2_MAX),
    "edge_thresh": lambda b: (0, 255),
    "uniqueness": lambda b: (0, 255),
    "lr_tol": lambda b: (0, 15),
}
DEFAULT_PARAMS = StereoParams()
MIN_WIDTH = CENSUS_W
MIN_HEIGHT = CENSUS_H


def size_problems(width: int, height: int, build: Build = DEFAULT_BUILD) -> List[str]:
    """Why the core would refuse a ``width`` x ``height`` frame (SIZE_ERROR), if it would."""
    out = []
    if not MIN_WIDTH <= width <= build.max_width:
        out.append(f"width {width}: the core takes {MIN_WIDTH} .. {build.max_width} pixels")
    if not MIN_HEIGHT <= height <= build.max_height:
        out.append(f"height {height}: the core takes {MIN_HEIGHT} .. {build.max_height} rows")
    return out


#: CONTROL's switches, bits 1 up: StereoParams field -> (bit name, what it does).
_MODES: Dict[str, Tuple[str, str]] = {
    "lr_check": ("LR_CHECK", "invalidate pixels the left-right check rejects"),
    "subpixel": ("SUBPIXEL", "parabola refinement to 1/16 px; else whole pixels"),
    "median": ("MEDIAN", "3x3 median of the disparity codes"),
}

STEREO_MAP = RegisterMap(
    "stereo",
    [
        Register("ID", 0x000, Access.RO, CORE_ID, doc="identity, 'STER'"),
        Register("VERSION", 0x004, Access.RO, CORE_VERSION,
                 fields=(Field("MINOR", 0, 16), Field("MAJOR", 16, 16))),
        Register("MAX_WIDTH", 0x008, Access.RO, DEFAULT_BUILD.max_width, doc="widest frame the buffers hold"),
        Register("MAX_HEIGHT", 0x00C, Access.RO, DEFAULT_BUILD.max_height,
                 doc="tallest frame the counters reach"),
        Register("MAX_DISP", 0x010, Access.RO, DEFAULT_BUILD.max_disp,
                 doc="disparities the path buffers hold"),
        Register("PARALLEL", 0x014, Access.RO, DEFAULT_BUILD.parallel, doc="disparities evaluated per clock"),
        control_register(0xE, tuple(Field(bit, i + 1, doc=doc + " (shadowed)")
                                    for i, (bit, doc) in enumerate(_MODES.values()))),
        flags_register((
            Field("SIZE_ERROR", 0, doc="an input frame did not match WIDTH x HEIGHT"),
            Field("CONFIG_ERROR", 1, doc="APPLY refused: a parameter out of range; the previous stay"),
        )),
        *progress_registers(),
        *size_registers(752, 480),
        Register("NUM_DISP", 0x038, Access.RW, DEFAULT_PARAMS.num_disp, fields=(Field("VALUE", 0, 8),)),
        Register("P1", 0x03C, Access.RW, DEFAULT_PARAMS.p1, fields=(Field("VALUE", 0, 8),)),
        Register("P2", 0x040, Access.RW, DEFAULT_PARAMS.p2, fields=(Field("VALUE", 0, 8),)),
        Register("P2_EDGE", 0x044, Access.RW, DEFAULT_PARAMS.p2_edge, fields=(Field("VALUE", 0, 8),)),
        Register("EDGE_THRESH", 0x048, Access.RW, DEFAULT_PARAMS.edge_thresh, fields=(Field("VALUE", 0, 8),)),
        Register("UNIQUENESS", 0x04C, Access.RW, DEFAULT_PARAMS.uniqueness, fields=(Field("VALUE", 0, 8),)),
        Register("LR_TOL", 0x050, Access.RW, DEFAULT_PARAMS.lr_tol, fields=(Field("VALUE", 0, 4),)),
    ],
    size=0x1000,
    doc="stereocam stereo core, AXI4-Lite slave",
)

#: StereoParams field -> its register (the numeric ones; the flags are CONTROL's bits).
PARAM_REGISTERS: Dict[str, str] = {
    "num_disp": "NUM_DISP", "p1": "P1", "p2": "P2", "p2_edge": "P2_EDGE",
    "edge_thresh": "EDGE_THRESH", "uniqueness": "UNIQUENESS", "lr_tol": "LR_TOL",
}
CONTROL_FLAGS: Dict[str, str] = {name: bit for name, (bit, _) in _MODES.items()}


def register_values(p: StereoParams) -> Dict[str, int]:
    """The register words that program ``p`` (CONTROL without ENABLE or APPLY)."""
    out = {reg: int(getattr(p, name)) for name, reg in PARAM_REGISTERS.items()}
    control = STEREO_MAP["CONTROL"]
    out["CONTROL"] = control.encode(0, **{bit: int(getattr(p, name)) for name, bit in CONTROL_FLAGS.items()})
    return out


def params_from_registers(words: Dict[str, int]) -> StereoParams:
    """The parameters a set of register words programs (the inverse of :func:`register_values`)."""
    control = STEREO_MAP["CONTROL"]
    values: Dict[str, object] = {name: STEREO_MAP[reg].get(words[reg], "VALUE")
                                 for name, reg in PARAM_REGISTERS.items()}
    values.update({name: bool(control.get(words["CONTROL"], bit)) for name, bit in CONTROL_FLAGS.items()})
    return StereoParams(**values)  # type: ignore[arg-type]
