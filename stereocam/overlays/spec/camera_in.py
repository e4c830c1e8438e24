"""The camera input path: two MT9V034 parallel receivers and the Bayer demosaic, as one IP.

Written once: the RTL (``stereocam/overlays/rtl/camera/``), its Python model, the
block design script and the emulated cameras read the interface from here.

The IP has no register window: it turns the two sensors' parallel outputs
into the fabric's 64-bit stereo stream (:mod:`.pixel`) and nothing else.

Ports (Verilog names, camera 0 is the left camera, camera 1 the right):

* ``cam0_pclk``, ``cam0_data[9:0]``, ``cam0_line_valid``, ``cam0_frame_valid``
  and the same for ``cam1_``: the MT9V034's PIXCLK, DOUT[9:0], LINE_VALID and
  FRAME_VALID, sampled on the rising edge of PIXCLK. The two sensors are
  hardware-synchronised (one master, one slave on the same SYSCLK), so their
  frames and lines start together; each still has its own pixel clock pin.
* ``aclk``, ``aresetn``: the stream clock and its active-low reset.
* ``m_axis_tdata[63:0]``, ``m_axis_tvalid``, ``m_axis_tready``,
  ``m_axis_tuser`` (start of frame), ``m_axis_tlast`` (end of line): the
  AXI4-Stream of :mod:`.pixel`, one beat per pixel position of both cameras.
"""
from __future__ import annotations

from typing import Dict, Tuple

from . import mt9v034 as _mt9v034
from .stream import stream_ports

VLNV = "stereocam:user:camera_in:1.0"
INSTANCE = "camera_in"  # cell name in the block design
TOP = "camera_in"  # Verilog top module
DATA_BITS = 10  # MT9V034 DOUT width
CAMERAS: Tuple[str, str] = ("cam0", "cam1")  # left, right

# Verilog parameters of the top module and their defaults.
PARAMETERS: Dict[str, int] = {
    "MAX_WIDTH": 752,  # longest line the demosaic's line buffers hold
}

# Port name -> (direction, width)
PORTS: Dict[str, Tuple[str, int]] = {
    **{f"{cam}_{sig}": ("input", width)
       for cam in CAMERAS
       for sig, width in (("pclk", 1), ("data", DATA_BITS), ("line_valid", 1), ("frame_valid", 1))},
    "aclk": ("input", 1),
    "aresetn": ("input", 1),
    **stream_ports("m_axis", master=True),
}


# =====================================================================================================
# Behaviour: what the IP computes and when (the model stereocam/overlays/model/camera_in.py, the RTL through
# the
# generated header stereocam/overlays/rtl/camera/camera_in_spec.vh, and the emulated cameras read it from
# here).
# =====================================================================================================

# -- Bayer colour filter array ------------------------------------------------------------------------
# A phase names the colours of the 2x2 cell at pixel (0, 0) of the read-out window, row by row:
# "GRBG" is G R on row 0 and B G on row 1. Its code (the index here, the Verilog parameter BAYER_PHASE)
# puts R at column ``code & 1`` and row ``code >> 1`` of every cell; B is diagonal to R, G elsewhere.
CFA_PHASES: Tuple[str, ...] = ("RGGB", "GRBG", "GBRG", "BGGR")

# The array's filter, in absolute array coordinates: a window starting at an odd column and an odd row
# reads out G R / B G ("align them to a non multiple of 2 pixels to ensure a GRBG Bayer pattern",
# [linux] mt9v032_set_crop, which reports MEDIA_BUS_FMT_SGRBG10_1X10 for the colour MT9V032/034).
ARRAY_PHASE_AT_ODD_ODD = "GRBG"

# Reset values of R0x01 COLUMN_START and R0x02 ROW_START (spec/mt9v034.py): the window our driver
# programs for a full 752 x 480 frame (column 1, row 4), so its phase is the default of the IP.
DEFAULT_COLUMN_START = _mt9v034.MT9V034_MAP["COLUMN_START"].reset
DEFAULT_ROW_START = _mt9v034.MT9V034_MAP["ROW_START"].reset


def phase_code(phase: str) -> int:
    """The code of a phase name (the Verilog parameter's value)."""
    if phase not in CFA_PHASES:
        raise ValueError(f"unknown Bayer phase {phase!r} (known: {', '.join(CFA_PHASES)})")
    return CFA_PHASES.index(phase)


def cfa_phase(column_start: int, row_start: int, width: int, height: int, *,
              column_flip: bool = False, row_flip: bool = False) -> str:
    """Phase at pixel (0, 0) of what the sensor reads out, for a window and READ_MODE's flips.

    Unflipped, the first pixel read is (COLUMN_START, ROW_START). Flipped, the MT9V034 family reads
    the window backwards from ``start + size`` down to ``start + 1`` (the Micron read-mode convention,
    "this ensures that the starting color is maintained" for even sizes: the MT9D111 data sheet's
    R0x20 words it so; the MT9V034's R0x0D is assumed to do the same, to be confirmed on the board
    with a colour chart). So a flip keeps the phase when the flipped size is even, and moves it by
    one pixel when it is odd.
    """
    first_col = column_start + (width if column_flip else 0)
    first_row = row_start + (height if row_flip else 0)
    odd_odd = phase_code(ARRAY_PHASE_AT_ODD_ODD)
    r_col = (odd_odd & 1) ^ (1 - first_col % 2)  # R's column inside the cell, from the first column read
    r_row = (odd_odd >> 1) ^ (1 - first_row % 2)
    return CFA_PHASES[2 * r_row + r_col]


#: The phase the demosaic assumes (one for both cameras): the driver's full-size window, no flips.
#: The IP has no register to change it at run time; a window whose start parity differs needs a
#: bitstream built with another BAYER_PHASE (the colours come out swapped otherwise).
BAYER_PHASE = cfa_phase(DEFAULT_COLUMN_START, DEFAULT_ROW_START, _mt9v034.ARRAY_WIDTH, _mt9v034.ARRAY_HEIGHT)
PARAMETERS["BAYER_PHASE"] = phase_code(BAYER_PHASE)

# -- 10 -> 8 bits and the demosaic --------------------------------------------------------------------
# Bilinear demosaic on the 10-bit samples, one rounding at the end. Each colour of each output pixel
# is a sum S of 10-bit samples of its 3x3 neighbourhood with integer weights adding up to
# KERNEL_SUM = 4 (so S / 4 is the bilinear estimate in 10-bit units); the 8-bit value is
# min((S + OUT_ROUND) >> OUT_SHIFT, 255): value / 4, rounded half up, saturating (S <= 4092 gives 256
# only from an estimate of 1022 or more). Gray is pixel.gray_of of the three 8-bit values.
RAW_BITS = DATA_BITS
KERNEL_SUM = 4
OUT_SHIFT = 4  # S / 16 == (S / 4) / 4
OUT_ROUND = 1 << (OUT_SHIFT - 1)
OUT_MAX = 255

Tap = Tuple[int, int, int]  # (row offset, column offset, weight)
_SAME: Tuple[Tap, ...] = ((0, 0, 4),)
_CROSS: Tuple[Tap, ...] = ((-1, 0, 1), (1, 0, 1), (0, -1, 1), (0, 1, 1))
_DIAGONAL: Tuple[Tap, ...] = ((-1, -1, 1), (-1, 1, 1), (1, -1, 1), (1, 1, 1))
_ROW_PAIR: Tuple[Tap, ...] = ((0, -1, 2), (0, 1, 2))
_COLUMN_PAIR: Tuple[Tap, ...] = ((-1, 0, 2), (1, 0, 2))

#: Site -> the taps of its (R, G, B) estimates. "Gr" is a green on a row with red, "Gb" on a row with blue.
KERNELS: Dict[str, Tuple[Tuple[Tap, ...], Tuple[Tap, ...], Tuple[Tap, ...]]] = {
    "R": (_SAME, _CROSS, _DIAGONAL),
    "B": (_DIAGONAL, _CROSS, _SAME),
    "Gr": (_ROW_PAIR, _SAME, _COLUMN_PAIR),
    "Gb": (_COLUMN_PAIR, _SAME, _ROW_PAIR),
}

#: Outside the frame the samples are mirrored about the edge pixel (OpenCV's BORDER_REFLECT_101:
#: column -1 is column 1, column W is column W - 2; rows alike), which keeps every mirrored sample's
#: colour. Frames need at least MIN_WIDTH x MIN_HEIGHT samples; smaller ones give no output.
BORDER = "reflect101"
MIN_WIDTH = 2
MIN_HEIGHT = 2

# -- timing, pairing and loss ------------------------------------------------------------------------
# Each camera's receiver samples DOUT/LINE_VALID/FRAME_VALID on its own PIXCLK and writes whole lines
# into its own asynchronous FIFO (gray-coded pointers; a line becomes visible to the aclk side only
# when LINE_VALID has fallen, so the aclk side only ever sees complete lines). The aclk side takes a
# line from both FIFOs at once when both have one and the two agree, and emits output row y while it
# takes input row y + 1 (the last row after FRAME_VALID has fallen on both cameras): LINE_LATENCY = 1
# line, plus PIPELINE_CLOCKS aclk clocks. Per input line it needs WIDTH + LINE_OVERHEAD_CLOCKS aclk
# clocks when TREADY stays high, so it keeps up with the sensors whenever
# aclk >= pclk * (WIDTH + LINE_OVERHEAD_CLOCKS) / (WIDTH + horizontal blanking).
LINE_LATENCY = 1
PIPELINE_CLOCKS = 8  # aclk clocks from the step that completes a pixel's 3x3 window to its beat on m_axis
LINE_OVERHEAD_CLOCKS = 4  # per line, about: fetching both headers, deciding, the mirrored last column
OUTPUT_FIFO_DEPTH = 16  # beats; the aclk side only starts a step that has room in it
#: Between frames FRAME_VALID must stay low for at least this many pixel clocks, and 8 aclk clocks
#: (the MT9V034's shortest vertical blanking, 2 rows, is over 1,000), so that the frame tag below
#: reaches both receivers before the next frame starts.
MIN_VBLANK_PCLK = 16
MIN_HBLANK_PCLK = 1  # LINE_VALID low between lines, pixel clocks (the MT9V034 has at least 61)

#: Frames are paired by a tag: the aclk side counts "both FRAME_VALIDs low" (the start of each
#: vertical blanking, through synchronisers) and each receiver stamps a frame's records with the
#: count it sees when the frame starts. Equal tags are the same exposure; a camera's frame whose tag
#: is behind the other's (by 1 to 2**(TAG_BITS-1) - 1, modulo 2**TAG_BITS) has no partner and is
#: dropped. This makes pairing robust to a receiver that missed a frame (reset, a FIFO that was full).
TAG_BITS = 4


def line_fifo_depth(max_width: int) -> int:
    """Words of each camera's line FIFO: a power of two holding two longest lines, their headers and an
    end-of-frame record (2048 for 752). One line's worth of TREADY low is absorbed without loss."""
    need = 2 * int(max_width) + 8
    return 1 << (need - 1).bit_length()


# Words of the line FIFOs (an internal format, not an interface: the RTL reads it from the header).
REC_BITS = 18
REC_KIND_BITS = 2
REC_PIXEL, REC_LINE, REC_EOF = 0, 1, 2
LEN_BITS = 11  # line length field: MAX_WIDTH <= 2047
MAX_WIDTH_LIMIT = (1 << LEN_BITS) - 1

# What reaches the stream (no register window: these are the rules, the counters below are internal
# and visible in simulation only):
# * A frame is emitted when both cameras deliver it with lines of one length (MIN_WIDTH..MAX_WIDTH).
#   Rows are taken while both cameras' lines agree (same length as the frame's first line, same
#   frame tag); at the first disagreement, a line longer than MAX_WIDTH, a line cut by FRAME_VALID
#   falling, or a receiver's FIFO overflowing (TREADY low for longer than the FIFOs absorb: the
#   receiver drops the rest of that frame), the frame ENDS: the rows taken so far are emitted as a
#   complete, shorter frame (TUSER on its first beat, TLAST on every line, its last row mirrored as
#   any last row), and nothing else of that frame is emitted. Fewer than MIN_HEIGHT rows: nothing.
#   The next frame starts cleanly with TUSER when both cameras start one.
# * Counters (camera_in.frames_out, camera_in.frames_cut) count emitted frames and frames that ended
#   early or were dropped.
# * A camera that stops delivering lines in mid-frame holds the output until it delivers again.
