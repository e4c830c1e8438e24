"""ON Semiconductor (Aptina) MT9V034 image sensor: its I2C register table, limits and timing.

Shared by the driver (:mod:`stereocam.drivers.mt9v034`) and the emulated
sensor (:mod:`stereocam.overlays.emulated.sensors`), like every other table
in this package. The sensor's two-wire interface carries 8-bit register
addresses and 16-bit big-endian data, so the AXI :class:`~.regs.Register`
(32-bit, word-aligned offsets) does not fit; :class:`Register16` and
:class:`Register16Map` are its small siblings, reusing :class:`~.regs.Field`
and :class:`~.regs.Access`.

Sources (cited by register below):

* [linux] ``drivers/media/i2c/mt9v032.c`` (torvalds/linux; Laurent Pinchart),
  which drives the MT9V022/024/032/034: register addresses, chip versions
  (``MT9V034_CHIP_ID_REV1 = 0x1324``), the MT9V034's model data (minimum
  row time 690 pixel clocks, horizontal blanking >= 61, vertical blanking
  2..32288, total shutter width 0..32765, AEC maximum shutter register
  0xAD instead of the MT9V032's 0xBD), the 26.6 MHz default system clock,
  the reset sequence (write R0x0C = 1 then 0), ``READ_MODE`` bits (row flip
  bit 4, column flip bit 5, reserved bits 9:8 = 0x0300 to be preserved), the
  test pattern encodings, AEC/AGC enable bits and the AEC/AGC controls
  (desired bin 1..64, default 58; low-pass filter 0..2; update interval).
  The driver's model data does not distinguish flip bits between models:
  the MT9V034 uses the same R0x0D bits as the MT9V032.
* [openmv] ``src/omv/sensors/mt9v0xx_regs.h`` (openmv/openmv): the MT9V034's
  AGC maximum gain register 0xAB (0x36 on the MT9V032), the AEC/AGC outputs
  0xBA/0xBB, and the operating-mode field R0x07[4:3] (1 = master,
  3 = snapshot; ``MT9V0XX_CHIP_CONTROL_MODE_MASK``).
* [ds] MT9V032 data sheet (onsemi MT9V032/D rev. 7): slave addresses 0x90,
  0x98, 0xB0, 0xB8 (8-bit; 0x48, 0x4C, 0x58, 0x5C as 7-bit addresses)
  selected by S_CTRL_ADR1:0; 16-bit register writes; the AEC/AGC block
  (AEC disabled: the manual exposure R0x0B is used; AGC disabled: the manual
  gain R0x35; gain in units of 1/16). The MT9V034 data sheet keeps these.

Timing: one row takes ``WINDOW_WIDTH + HORIZONTAL_BLANKING`` pixel clocks
(at least :data:`MIN_ROW_TIME` = 690), the coarse exposure is a whole number
of rows (R0x0B), and a frame takes ``WINDOW_HEIGHT + VERTICAL_BLANKING``
rows; an exposure longer than that stretches the frame (lower frame rate).
With the reset values (752 + 94 clocks at 26.6 MHz) a row lasts 31.80 us,
480 rows of exposure are 15.27 ms and a frame is 16.70 ms (59.9 fps).
So the manual exposures the sensor takes at the timing it was set up with
(:class:`ExposureRange`, the one place that range is worked out) are one row
to one frame, within R0x0B's limits: a longer one would silently lower the
frame rate the daemon was configured for.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Iterable, Mapping, Tuple

from .regs import Access, Field, Register, RegisterMap

__all__ = [
    "Register16",
    "Register16Map",
    "MT9V034_MAP",
    "CHIP_ID",
    "KNOWN_CHIP_IDS",
    "I2C_ADDRESSES",
    "PIXEL_CLOCK_HZ",
    "ARRAY_WIDTH",
    "ARRAY_HEIGHT",
    "SENSOR_MODES",
    "TEST_PATTERNS",
    "GAIN_MIN",
    "GAIN_MAX",
    "row_time_us",
    "exposure_rows_from_us",
    "exposure_us_from_rows",
    "gain_code",
    "gain_from_code",
    "vertical_blanking_for",
    "frame_rate",
    "ExposureRange",
]

# -- identity and bus ------------------------------------------------------------------

CHIP_ID = 0x1324  # R0x00 of an MT9V034 (and MT9V024) rev1 [linux MT9V034_CHIP_ID_REV1]
KNOWN_CHIP_IDS: Mapping[int, str] = {  # [linux mt9v032_versions]
    0x1311: "MT9V022/MT9V032 rev1/2",
    0x1313: "MT9V022/MT9V032 rev3",
    0x1324: "MT9V024/MT9V034 rev1",
}
# 7-bit addresses selectable with the S_CTRL_ADR1:0 straps [ds Table 6: 0x90, 0x98, 0xB0, 0xB8].
I2C_ADDRESSES: Tuple[int, ...] = (0x48, 0x4C, 0x58, 0x5C)

# -- array and timing -------------------------------------------------------------------

PIXEL_CLOCK_HZ = 26_600_000  # default SYSCLK [linux MT9V032_SYSCLK_FREQ_DEF]
ARRAY_WIDTH = 752  # active columns [linux WINDOW_WIDTH_MAX]
ARRAY_HEIGHT = 480  # active rows [linux WINDOW_HEIGHT_MAX]
MIN_ROW_TIME = 690  # pixel clocks, MT9V034 [linux model data min_row_time]
HBLANK_MIN, HBLANK_MAX, HBLANK_DEFAULT = 61, 1023, 94  # [linux MT9V034_HORIZONTAL_BLANKING_MIN ...]
VBLANK_MIN, VBLANK_MAX, VBLANK_DEFAULT = 2, 32288, 45  # [linux MT9V034_VERTICAL_BLANKING_MIN/MAX]
SHUTTER_MIN, SHUTTER_MAX, SHUTTER_DEFAULT = 0, 32765, 480  # rows [linux MT9V034_TOTAL_SHUTTER_WIDTH_*]
AEC_MAX_SHUTTER_MIN = 1  # rows; AEC never goes below one row [ds, AEC/AGC]
# A manual exposure in microseconds is > 0 (API.md), so at least one row: the register itself also
# takes 0 (fine shutter only), which the driver's ``exposure_rows`` still writes for whoever asks in rows.
MANUAL_EXPOSURE_MIN_ROWS = 1

# -- gain ---------------------------------------------------------------------------------

GAIN_UNIT = 16  # R0x35 code of 1x gain [ds: "unity gain = 16 gain-units"]
GAIN_CODE_MIN, GAIN_CODE_MAX = 16, 64  # [linux MT9V032_ANALOG_GAIN_MIN/MAX]
GAIN_MIN, GAIN_MAX = GAIN_CODE_MIN / GAIN_UNIT, GAIN_CODE_MAX / GAIN_UNIT  # 1.0x .. 4.0x
DESIRED_BIN_MIN, DESIRED_BIN_MAX, DESIRED_BIN_DEFAULT = 1, 64, 58  # [linux V4L2_CID_AEGC_DESIRED_BIN]

# -- modes ---------------------------------------------------------------------------------

# R0x07[4:3] "sensor operating mode" [openmv MT9V0XX_CHIP_CONTROL_*_MODE; ds R0x07]. In slave
# mode the sensor's frame timing follows its partner (the master of a stereo pair); in
# snapshot mode each frame is exposed when the EXPOSURE input is pulsed, so two sensors
# wired to one trigger expose together.
SENSOR_MODES: Mapping[str, int] = {"slave": 0, "master": 1, "snapshot": 3}

# R0x7F encodings, as the Linux driver's test-pattern menu writes them [linux mt9v032_s_ctrl].
# "plain" is a flat field of ``DATA`` (10 bits); the other three are gray ramps.
TEST_PATTERNS: Tuple[str, ...] = ("gray_vertical", "gray_horizontal", "gray_diagonal", "plain")
TEST_PATTERN_GRAY_CODE: Mapping[str, int] = {"gray_vertical": 1, "gray_horizontal": 2, "gray_diagonal": 3}
TEST_PATTERN_LEVEL_MAX = 1023


# --------------------------------------------------------------------------
# 16-bit registers as data
# --------------------------------------------------------------------------

REG_BITS = 16
REG_MASK = (1 << REG_BITS) - 1
ADDRESS_MAX = 0xFF  # 8-bit register addresses


@dataclass(frozen=True)
class Register16(Register):
    """One 16-bit register of an I2C device at an 8-bit address (:class:`.regs.Register`'s rules).

    ``offset`` is the register address (``R0x..``), also readable as :attr:`address`.
    """

    BITS: ClassVar[int] = REG_BITS
    ALIGN: ClassVar[int] = 1

    def __post_init__(self) -> None:
        if not 0 <= self.offset <= ADDRESS_MAX:
            raise ValueError(f"{self.name}: address {self.offset:#x} is not an 8-bit register address")
        super().__post_init__()

    @property
    def address(self) -> int:
        return self.offset

    @property
    def reserved_mask(self) -> int:
        """Bits outside every field (none if the register has no fields)."""
        return self.unassigned_mask


class Register16Map(RegisterMap[Register16]):
    """All registers of one I2C device, looked up by name or address."""

    OFFSET_TITLE = "R0x"

    def __init__(self, name: str, registers: Iterable[Register16], *, doc: str = "") -> None:
        super().__init__(name, registers, size=ADDRESS_MAX + 1, doc=doc)

    def address(self, name: str) -> int:
        return self.offset(name)

    def _offset_text(self, r: Register16) -> str:
        return f"{r.offset:02X}"

    def _reset_text(self, r: Register16) -> str:
        return f"{r.reset:#06x}"


# --------------------------------------------------------------------------
# The MT9V034's registers (context A; the context B copies are not used)
# --------------------------------------------------------------------------

RW, RO, SC = Access.RW, Access.RO, Access.SC

MT9V034_MAP = Register16Map("mt9v034", [
    Register16("CHIP_VERSION", 0x00, RO, CHIP_ID, doc="chip identity [linux MT9V032_CHIP_VERSION]"),
    Register16("COLUMN_START", 0x01, RW, 1, limits=(("COLUMN_START", 1, 752),),
               doc="first column read out [linux MT9V032_COLUMN_START_*]"),
    Register16("ROW_START", 0x02, RW, 4, limits=(("ROW_START", 4, 482),),
               doc="first row read out; rows 0..3 are dark [linux MT9V032_ROW_START_*]"),
    Register16("WINDOW_HEIGHT", 0x03, RW, ARRAY_HEIGHT, limits=(("WINDOW_HEIGHT", 1, ARRAY_HEIGHT),),
               doc="rows per frame [linux MT9V032_WINDOW_HEIGHT_*]"),
    Register16("WINDOW_WIDTH", 0x04, RW, ARRAY_WIDTH, limits=(("WINDOW_WIDTH", 1, ARRAY_WIDTH),),
               doc="columns per row [linux MT9V032_WINDOW_WIDTH_*]"),
    Register16("HORIZONTAL_BLANKING", 0x05, RW, HBLANK_DEFAULT,
               limits=(("HORIZONTAL_BLANKING", HBLANK_MIN, HBLANK_MAX),),
               doc="pixel clocks between rows; width + blanking >= 690 [linux MT9V034_*_BLANKING_MIN]"),
    Register16("VERTICAL_BLANKING", 0x06, RW, VBLANK_DEFAULT,
               limits=(("VERTICAL_BLANKING", VBLANK_MIN, VBLANK_MAX),),
               doc="rows between frames [linux MT9V034_VERTICAL_BLANKING_MIN/MAX]"),
    Register16(
        "CHIP_CONTROL", 0x07, RW, 0x0388,
        fields=(
            Field("SCAN_MODE", 0, 3, doc="0 = progressive"),
            Field("SENSOR_MODE", 3, 2, doc="0 = slave, 1 = master, 3 = snapshot (SENSOR_MODES)"),
            Field("STEREO", 5, doc="LVDS stereoscopy mode (not used: each camera has its own port)"),
            Field("STEREO_SLAVE", 6, doc="stereoscopic master (0) / slave (1)"),
            Field("PARALLEL_OUTPUT", 7, doc="parallel data output enable [linux DOUT_ENABLE]"),
            Field("SIMULTANEOUS", 8, doc="1 = integrate while reading out [linux calls it SEQUENTIAL]"),
            Field("DEFECT_CORRECTION", 9, doc="reset 1 [openmv MT9V0X4_CHIP_CONTROL_RESERVED]"),
            Field("CONTEXT_B", 15, doc="use the context B register set"),
        ),
        limits=(("SENSOR_MODE", 0, 3),),
        doc="operating mode and output control; reset 0x0388: master, parallel output, simultaneous",
    ),
    Register16("COARSE_SHUTTER_WIDTH_TOTAL", 0x0B, RW, SHUTTER_DEFAULT,
               limits=(("COARSE_SHUTTER_WIDTH_TOTAL", SHUTTER_MIN, SHUTTER_MAX),),
               doc="manual exposure in rows, used while AEC is off [linux MT9V032_TOTAL_SHUTTER_WIDTH]"),
    Register16(
        "RESET", 0x0C, RW, 0,
        fields=(
            Field("SOFT_RESET", 0, access=SC, doc="abandon the frame and reset the sensor's logic"),
            Field("AUTO_BLOCK_SOFT_RESET", 1, access=SC, doc="reset the AEC/AGC block"),
        ),
        doc="soft resets; Linux writes 1 then 0 [linux mt9v032_power_on]",
    ),
    Register16(
        "READ_MODE", 0x0D, RW, 0x0300,
        fields=(
            Field("ROW_BIN", 0, 2),
            Field("COLUMN_BIN", 2, 2),
            Field("ROW_FLIP", 4, doc="read rows bottom to top: vertical flip"),
            Field("COLUMN_FLIP", 5, doc="read columns right to left: horizontal flip"),
            Field("DARK_COLUMNS", 6),
            Field("DARK_ROWS", 7),
            Field("RESERVED", 8, 2, doc="reset 3; keep [linux MT9V032_READ_MODE_RESERVED]"),
        ),
        limits=(("ROW_BIN", 0, 2), ("COLUMN_BIN", 0, 2)),
        doc="binning and flips [linux MT9V032_READ_MODE_*]",
    ),
    Register16("ANALOG_GAIN", 0x35, RW, GAIN_UNIT,
               fields=(Field("GAIN", 0, 7, doc="gain x16: 16 = 1x .. 64 = 4x"),),
               limits=(("GAIN", GAIN_CODE_MIN, GAIN_CODE_MAX),),
               doc="manual analog gain, used while AGC is off [linux MT9V032_ANALOG_GAIN]"),
    Register16(
        "TEST_PATTERN", 0x7F, RW, 0,
        fields=(
            Field("DATA", 0, 10, doc="level of the plain pattern (10 bits)"),
            Field("USE_DATA", 10),
            Field("GRAY", 11, 2, doc="1 vertical, 2 horizontal, 3 diagonal shade"),
            Field("ENABLE", 13),
            Field("FLIP", 14),
        ),
        doc="test pattern in place of the image [linux MT9V032_TEST_PATTERN_*]",
    ),
    Register16("AEC_AGC_DESIRED_BIN", 0xA5, RW, DESIRED_BIN_DEFAULT,
               limits=(("AEC_AGC_DESIRED_BIN", DESIRED_BIN_MIN, DESIRED_BIN_MAX),),
               doc="target brightness of AEC and AGC, in 64ths of full scale [linux AEGC_DESIRED_BIN]"),
    Register16("AEC_UPDATE_FREQUENCY", 0xA6, RW, 2, limits=(("AEC_UPDATE_FREQUENCY", 0, 16),),
               doc="frames skipped between AEC updates [linux AEC_UPDATE_INTERVAL]"),
    Register16("AEC_LPF", 0xA8, RW, 0, limits=(("AEC_LPF", 0, 2),), doc="AEC low-pass filter [linux]"),
    Register16("AGC_UPDATE_FREQUENCY", 0xA9, RW, 2, limits=(("AGC_UPDATE_FREQUENCY", 0, 16),),
               doc="frames skipped between AGC updates [linux AGC_UPDATE_INTERVAL]"),
    Register16("AGC_LPF", 0xAA, RW, 2, limits=(("AGC_LPF", 0, 2),), doc="AGC low-pass filter [linux]"),
    Register16("MAX_ANALOG_GAIN", 0xAB, RW, GAIN_CODE_MAX,
               fields=(Field("GAIN", 0, 7),), limits=(("GAIN", GAIN_CODE_MIN, GAIN_CODE_MAX),),
               doc="AGC's upper gain limit, x16 [openmv MT9V0X4_MAX_GAIN]"),
    Register16("MAX_COARSE_SHUTTER_WIDTH", 0xAD, RW, SHUTTER_DEFAULT,
               limits=(("MAX_COARSE_SHUTTER_WIDTH", AEC_MAX_SHUTTER_MIN, SHUTTER_MAX),),
               doc="AEC's upper exposure limit in rows [linux MT9V034_AEC_MAX_SHUTTER_WIDTH]"),
    Register16(
        "AEC_AGC_ENABLE", 0xAF, RW, 0x0303,
        fields=(
            Field("AEC_ENABLE", 0), Field("AGC_ENABLE", 1),
            Field("AEC_ENABLE_B", 8), Field("AGC_ENABLE_B", 9),
        ),
        doc="automatic exposure and gain, contexts A and B; both on at reset [linux, openmv]",
    ),
    Register16("AGC_OUTPUT", 0xBA, RO, GAIN_UNIT,
               doc="analog gain in use, x16 [openmv MT9V0XX_AGC_GAIN_OUTPUT]"),
    Register16("AEC_OUTPUT", 0xBB, RO, SHUTTER_DEFAULT,
               doc="exposure in use, rows [openmv MT9V0XX_AEC_EXPOSURE_OUTPUT]"),
    Register16("AGC_AEC_CURRENT_BIN", 0xBC, RO, 0, doc="brightness of the last frame, 64ths [ds Figure 27]"),
], doc="MT9V034 wide-VGA global-shutter sensor, context A")


# --------------------------------------------------------------------------
# Conversions
# --------------------------------------------------------------------------

def row_time_us(width: int = ARRAY_WIDTH, hblank: int = HBLANK_DEFAULT,
                pixel_clock_hz: float = PIXEL_CLOCK_HZ) -> float:
    """Duration of one row in microseconds: ``max(width + hblank, 690)`` pixel clocks."""
    if pixel_clock_hz <= 0:
        raise ValueError(f"pixel clock must be > 0 Hz, got {pixel_clock_hz}")
    return max(int(width) + int(hblank), MIN_ROW_TIME) * 1e6 / float(pixel_clock_hz)


def exposure_rows_from_us(us: float, row_us: float) -> int:
    """The coarse shutter width (whole rows, nearest) closest to ``us`` microseconds."""
    return int(math.floor(float(us) / row_us + 0.5))


def exposure_us_from_rows(rows: int, row_us: float) -> float:
    return int(rows) * row_us


def gain_code(gain: float) -> int:
    """R0x35 code of an analog gain: the nearest 1/16 step (16 = 1x, 64 = 4x)."""
    return int(math.floor(float(gain) * GAIN_UNIT + 0.5))


def gain_from_code(code: int) -> float:
    return int(code) / GAIN_UNIT


def frame_rate(height: int, vblank: int, row_us: float) -> float:
    """Frames per second of a free-running sensor: ``(height + vblank)`` rows per frame."""
    return 1e6 / ((int(height) + int(vblank)) * row_us)


def vertical_blanking_for(fps: float, height: int, row_us: float) -> int:
    """R0x06 that gives ``fps`` (never below the MT9V034's minimum; the caller checks the maximum)."""
    rows = int(math.floor(1e6 / (float(fps) * row_us) + 0.5))
    return max(rows - int(height), VBLANK_MIN)


@dataclass(frozen=True)
class ExposureRange:
    """The manual exposures (R0x0B, whole rows) the sensor takes at one timing, and what they last.

    From one row (:data:`MANUAL_EXPOSURE_MIN_ROWS`) to one frame (``height + vblank`` rows),
    within R0x0B's limits: beyond a frame the sensor stretches the frame and the frame rate
    drops below the one it was set up for. Built by :meth:`at` from the registers that set the
    timing; the driver refuses what is outside and the board profile checks its defaults with it.
    """

    row_us: float  # one row, microseconds
    frame_rows: int  # WINDOW_HEIGHT + VERTICAL_BLANKING
    lo: int  # rows
    hi: int  # rows

    @classmethod
    def at(cls, *, width: int, hblank: int, height: int, vblank: int,
           pixel_clock_hz: float = PIXEL_CLOCK_HZ) -> "ExposureRange":
        frame = int(height) + int(vblank)
        return cls(row_time_us(width, hblank, pixel_clock_hz), frame,
                   max(SHUTTER_MIN, MANUAL_EXPOSURE_MIN_ROWS), min(SHUTTER_MAX, frame))

    @property
    def lo_us(self) -> float:
        return exposure_us_from_rows(self.lo, self.row_us)

    @property
    def hi_us(self) -> float:
        return exposure_us_from_rows(self.hi, self.row_us)

    @property
    def fps(self) -> float:
        """The frame rate this timing gives (an exposure within the range keeps it)."""
        return 1e6 / (self.frame_rows * self.row_us)

    def rows_for(self, us: float) -> int:
        """Rows (nearest) for ``us`` microseconds, or :class:`ValueError` naming the range (message
        without the sensor's name; the caller adds it)."""
        rows = exposure_rows_from_us(us, self.row_us)
        if not self.lo <= rows <= self.hi:
            raise ValueError(f"exposure {float(us):g} us is out of range: {self.text()}")
        return rows

    def text(self) -> str:
        """The range as a user reads it, e.g. ``31.8045..16666 us (1..524 rows of 31.80 us: ...)``."""
        why = (f": at most one frame, {self.frame_rows} rows at {self.fps:.1f} fps; a longer exposure "
               "would lower the frame rate" if self.hi == self.frame_rows else "")
        return f"{self.lo_us:g}..{self.hi_us:.0f} us ({self.lo}..{self.hi} rows of {self.row_us:.2f} us{why})"
