"""Driver for the MT9V034 image sensor over I2C, and the stereo pair the daemon controls.

:class:`MT9V034` is handed an :class:`~.i2c.I2CBus` and the sensor's 7-bit
address (it never opens a bus itself) and speaks in the register table of
:mod:`stereocam.overlays.spec.mt9v034`: no register numbers in this file.
Every setter validates before it writes and raises
:class:`SensorRangeError` with the allowed range; every bus failure is the
bus's :class:`~.i2c.I2CError` (a :class:`I2CNack` names the address).

Sequences (the exact transactions are pinned by ``tests/drivers/test_mt9v034_driver.py``):

``reset``             write ``RESET.SOFT_RESET=1``, then ``RESET=0`` (as Linux's mt9v032 driver)
``check_id``          read ``CHIP_VERSION``; anything but 0x1324 raises :class:`ChipIdError`
``configure_window``  ``COLUMN_START``, ``ROW_START`` (window centred), ``WINDOW_WIDTH``,
                      ``WINDOW_HEIGHT``, ``HORIZONTAL_BLANKING`` (94, or more to keep a row
                      at least 690 pixel clocks)
``set_frame_rate``    read width, blanking, height; write ``VERTICAL_BLANKING``
exposure (µs)         read: ``WINDOW_WIDTH`` and ``HORIZONTAL_BLANKING`` (the row time), then
                      ``COARSE_SHUTTER_WIDTH_TOTAL``; write: those two, ``WINDOW_HEIGHT`` and
                      ``VERTICAL_BLANKING`` (the frame: the range is one row to one frame,
                      :class:`~stereocam.overlays.spec.mt9v034.ExposureRange`), then
                      ``COARSE_SHUTTER_WIDTH_TOTAL`` (whole rows, nearest)
``gain``              ``ANALOG_GAIN.GAIN`` = gain x 16 (nearest 1/16)
``set_aec``/``set_agc``  limits first (``MAX_COARSE_SHUTTER_WIDTH``, ``AEC_AGC_DESIRED_BIN``,
                      ``MAX_ANALOG_GAIN``), then a read-modify-write of ``AEC_AGC_ENABLE``
``flip``              read-modify-write of ``READ_MODE`` (reserved bits kept)
``test_pattern``      one write of ``TEST_PATTERN``
``set_sync``          read-modify-write of ``CHIP_CONTROL.SENSOR_MODE``

:class:`StereoSensors` is the pair and the service the daemon's
``/api/cameras`` calls (the board profile makes it, handing it the bus, the two
sensors and their settings): :meth:`~StereoSensors.start` brings both sensors up
without ever raising for a sensor that fails (it is
marked, logged and reported by :meth:`~StereoSensors.health` and
:meth:`~StereoSensors.faults`), :meth:`~StereoSensors.apply` /
:meth:`~StereoSensors.read` set and report the controls, and
:meth:`~StereoSensors.check`, called periodically, notices a sensor that
stops answering and sets one that answers again up as :meth:`start` did,
with the controls last applied. Its error contract: :class:`ValueError`
(``SettingsError``, ``SensorRangeError``) for a request to refuse,
:class:`SensorUnavailable` for a sensor that does not answer.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

from ..overlays.spec import mt9v034 as spec
from ..overlays.spec.mt9v034 import MT9V034_MAP
from .i2c import I2CBus, I2CError
from .mmio import DriverError, RegisterRangeError

log = logging.getLogger(__name__)

__all__ = [
    "MT9V034",
    "StereoSensors",
    "SensorSettings",
    "SensorError",
    "ChipIdError",
    "SensorRangeError",
    "SettingsError",
    "SensorUnavailable",
    "CAMERAS",
    "SYNC_MODES",
    "SETTINGS_FIELDS",
]

CAMERAS = ("left", "right")
SYNC_MODES = ("master-slave", "snapshot")
TEST_PATTERN_OFF = "off"


class SensorError(DriverError):
    """Base of the sensor driver's errors."""


class ChipIdError(SensorError):
    """``CHIP_VERSION`` is not the MT9V034's: another part, or no part, answers at that address."""


class SensorRangeError(SensorError, RegisterRangeError):
    """A setting outside what the sensor accepts; the message gives the allowed range."""


class SettingsError(SensorError, ValueError):
    """A camera settings request that is malformed (unknown key, wrong type, unknown camera)."""


class SensorUnavailable(SensorError):
    """A sensor the request needs is not answering (or failed its identity check)."""


def _flag(value: Any, what: str) -> bool:
    if not isinstance(value, bool):
        raise SettingsError(f"{what} must be true or false, not {value!r}")
    return value


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SettingsError(f"{what} must be a finite number, not {value!r}")
    return float(value)


class MT9V034:
    """One MT9V034 at 7-bit ``address`` on ``bus``.

    ``name`` (e.g. ``"left"``) starts every error message. ``pixel_clock_hz``
    is the sensor's SYSCLK (board profile), used for exposure times. Calls
    block for a few I2C transactions; they are not serialised here (the bus
    serialises transactions, :class:`StereoSensors` serialises sequences).
    """

    def __init__(self, bus: I2CBus, address: int, *, name: str = "mt9v034",
                 pixel_clock_hz: float = spec.PIXEL_CLOCK_HZ) -> None:
        if address not in spec.I2C_ADDRESSES:
            raise SensorRangeError(
                f"{name}: I2C address {address!r} is not one an MT9V034 can be strapped to "
                f"({', '.join(f'{a:#04x}' for a in spec.I2C_ADDRESSES)})")
        if not 13e6 <= pixel_clock_hz <= 27e6:
            raise SensorRangeError(f"{name}: pixel clock {pixel_clock_hz} Hz is out of range: 13..27 MHz")
        self.bus = bus
        self.address = address
        self.name = name
        self.pixel_clock_hz = float(pixel_clock_hz)
        self.map = MT9V034_MAP

    def __repr__(self) -> str:
        return f"MT9V034({self.name!r} at {self.address:#04x} on {self.bus!r})"

    # -- register access ----------------------------------------------------------------

    def read(self, name: str) -> int:
        return int(self.bus.read16(self.address, self.map.address(name)))

    def write(self, name: str, value: int) -> None:
        self.bus.write16(self.address, self.map.address(name), int(value))

    def _modify(self, name: str, **fields_: int) -> int:
        reg = self.map[name]
        word = reg.encode(self.read(name), **fields_)
        self.write(name, word)
        return word

    def _range_error(self, what: str, value: Any, lo: Any, hi: Any, unit: str = "", extra: str = "") -> None:
        raise SensorRangeError(f"{self.name}: {what} {value}{unit} is out of range: {lo}..{hi}{unit}{extra}")

    def _int_in(self, value: Any, what: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SensorRangeError(f"{self.name}: {what} must be a whole number in {lo}..{hi}, not {value!r}")
        if not lo <= value <= hi:
            self._range_error(what, value, lo, hi)
        return value

    # -- identity and reset ---------------------------------------------------------------

    def reset(self) -> None:
        """Soft reset: the sensor abandons its frame and resets its logic and AEC/AGC."""
        reg = self.map["RESET"]
        self.write("RESET", reg.encode(SOFT_RESET=1))
        self.write("RESET", 0)

    def check_id(self) -> int:
        """Read ``CHIP_VERSION``; returns 0x1324 or raises :class:`ChipIdError` naming what was found."""
        found = self.read("CHIP_VERSION")
        if found != spec.CHIP_ID:
            known = spec.KNOWN_CHIP_IDS.get(found)
            what = (f"that is an {known}, which this driver does not drive" if known else
                    "no known Aptina sensor reads that: check the board profile's address and the wiring")
            raise ChipIdError(
                f"{self.name}: R0x00 CHIP_VERSION at I2C address {self.address:#04x} reads {found:#06x}, "
                f"not the MT9V034's {spec.CHIP_ID:#06x}: {what}")
        return found

    # -- window and timing ------------------------------------------------------------------

    def configure_window(self, width: int, height: int) -> None:
        """A ``width`` x ``height`` window centred on the array; blanking keeps rows >= 690 clocks."""
        width = self._int_in(width, "window width", 1, spec.ARRAY_WIDTH)
        height = self._int_in(height, "window height", 1, spec.ARRAY_HEIGHT)
        col_lo, _ = self.map["COLUMN_START"].limit()
        row_lo, _ = self.map["ROW_START"].limit()
        self.write("COLUMN_START", col_lo + (spec.ARRAY_WIDTH - width) // 2)
        self.write("ROW_START", row_lo + (spec.ARRAY_HEIGHT - height) // 2)
        self.write("WINDOW_WIDTH", width)
        self.write("WINDOW_HEIGHT", height)
        self.write("HORIZONTAL_BLANKING", max(spec.HBLANK_DEFAULT, spec.MIN_ROW_TIME - width))

    def row_time_us(self) -> float:
        """Duration of one row now (reads ``WINDOW_WIDTH`` and ``HORIZONTAL_BLANKING``)."""
        width, hblank = self.read("WINDOW_WIDTH"), self.read("HORIZONTAL_BLANKING")
        return spec.row_time_us(width, hblank, self.pixel_clock_hz)

    def frame_rate_range(self) -> Tuple[float, float]:
        """Slowest and fastest frame rates of the current window (reads width, blanking, height)."""
        row_us = self.row_time_us()
        height = self.read("WINDOW_HEIGHT")
        slowest = spec.frame_rate(height, spec.VBLANK_MAX, row_us)
        return slowest, spec.frame_rate(height, spec.VBLANK_MIN, row_us)

    def set_frame_rate(self, fps: float) -> float:
        """Program ``VERTICAL_BLANKING`` for ``fps`` with the current window; returns the rate set.

        An exposure longer than the frame stretches it: the rate is then lower.
        """
        fps = _number(fps, f"{self.name}: frame rate")
        row_us = self.row_time_us()
        height = self.read("WINDOW_HEIGHT")
        lo = spec.frame_rate(height, spec.VBLANK_MAX, row_us)
        hi = spec.frame_rate(height, spec.VBLANK_MIN, row_us)
        if not lo <= fps <= hi + 1e-9:
            self._range_error("frame rate", f"{fps:g}", f"{lo:.2f}", f"{hi:.2f}", " fps",
                              f" for a window {height} rows high")
        vblank = spec.vertical_blanking_for(fps, height, row_us)
        self.write("VERTICAL_BLANKING", vblank)
        return spec.frame_rate(height, vblank, row_us)

    # -- exposure --------------------------------------------------------------------------

    @property
    def exposure_rows(self) -> int:
        """The manual exposure (``COARSE_SHUTTER_WIDTH_TOTAL``), in rows; used while AEC is off."""
        return self.read("COARSE_SHUTTER_WIDTH_TOTAL")

    @exposure_rows.setter
    def exposure_rows(self, rows: int) -> None:
        lo, hi = self.map["COARSE_SHUTTER_WIDTH_TOTAL"].limit()
        self.write("COARSE_SHUTTER_WIDTH_TOTAL", self._int_in(rows, "exposure (rows)", lo, hi))

    def exposure_range(self) -> spec.ExposureRange:
        """The manual exposures the sensor takes at its timing now: one row to one frame
        (reads ``WINDOW_WIDTH``, ``HORIZONTAL_BLANKING``, ``WINDOW_HEIGHT``, ``VERTICAL_BLANKING``)."""
        width, hblank = self.read("WINDOW_WIDTH"), self.read("HORIZONTAL_BLANKING")
        height, vblank = self.read("WINDOW_HEIGHT"), self.read("VERTICAL_BLANKING")
        return spec.ExposureRange.at(width=width, hblank=hblank, height=height, vblank=vblank,
                                     pixel_clock_hz=self.pixel_clock_hz)

    def exposure_rows_for(self, us: float, *, limit: str = "exposure") -> int:
        """Rows (nearest) for ``us`` microseconds; refuses what does not fit with the range.

        ``limit`` "exposure" (the manual exposure): within :meth:`exposure_range`, so that it never
        stretches the frame. "max_exposure" (the AEC's ceiling): within ``MAX_COARSE_SHUTTER_WIDTH``'s
        limits at the current row time.
        """
        us = _number(us, f"{self.name}: {limit}_us")
        if limit == "exposure":
            try:
                return self.exposure_range().rows_for(us)
            except ValueError as exc:
                raise SensorRangeError(f"{self.name}: {exc}") from None
        row_us = self.row_time_us()
        lo, hi = self.map["MAX_COARSE_SHUTTER_WIDTH"].limit()
        rows = spec.exposure_rows_from_us(us, row_us)
        if not lo <= rows <= hi:
            lo_us, hi_us = spec.exposure_us_from_rows(lo, row_us), spec.exposure_us_from_rows(hi, row_us)
            self._range_error(limit, f"{us:g}", f"{lo_us:g}", f"{hi_us:.0f}", " us",
                              f" ({lo}..{hi} rows of {row_us:.2f} us)")
        return rows

    @property
    def exposure_us(self) -> float:
        """The manual exposure in microseconds (rows x row time)."""
        row_us = self.row_time_us()
        return spec.exposure_us_from_rows(self.exposure_rows, row_us)

    @exposure_us.setter
    def exposure_us(self, us: float) -> None:
        self.write("COARSE_SHUTTER_WIDTH_TOTAL", self.exposure_rows_for(us))

    # -- gain ----------------------------------------------------------------------------------

    def _gain_code(self, gain: Any, what: str) -> int:
        g = _number(gain, f"{self.name}: {what}")
        if not spec.GAIN_MIN <= g <= spec.GAIN_MAX:
            self._range_error(what, f"{g:g}", spec.GAIN_MIN, spec.GAIN_MAX)
        return spec.gain_code(g)

    @property
    def gain(self) -> float:
        """The manual analog gain, 1.0..4.0 in steps of 1/16; used while AGC is off."""
        return spec.gain_from_code(self.map["ANALOG_GAIN"].get(self.read("ANALOG_GAIN"), "GAIN"))

    @gain.setter
    def gain(self, gain: float) -> None:
        self.write("ANALOG_GAIN", self.map["ANALOG_GAIN"].encode(GAIN=self._gain_code(gain, "gain")))

    # -- automatic exposure and gain -------------------------------------------------------------

    def set_aec(self, on: bool, *, max_exposure_us: Optional[float] = None,
                target: Optional[int] = None) -> None:
        """Automatic exposure on or off; optionally its upper limit and target brightness first.

        ``target`` is the desired bin shared with AGC, 1..64 (64ths of full
        scale; the sensor's reset value is 58). AEC never goes below 1 row.
        """
        on = _flag(on, f"{self.name}: aec")
        if max_exposure_us is not None:
            rows = self.exposure_rows_for(max_exposure_us, limit="max_exposure")
            self.write("MAX_COARSE_SHUTTER_WIDTH", rows)
        if target is not None:
            self.set_auto_target(target)
        self._modify("AEC_AGC_ENABLE", AEC_ENABLE=int(on))

    def set_auto_target(self, target: int) -> None:
        """The brightness AEC and AGC aim for: desired bin 1..64 (64ths of full scale)."""
        lo, hi = self.map["AEC_AGC_DESIRED_BIN"].limit()
        self.write("AEC_AGC_DESIRED_BIN", self._int_in(target, "AEC/AGC target bin", lo, hi))

    def set_agc(self, on: bool, *, max_gain: Optional[float] = None) -> None:
        """Automatic gain on or off; optionally its upper limit (1.0..4.0) first."""
        on = _flag(on, f"{self.name}: agc")
        if max_gain is not None:
            reg = self.map["MAX_ANALOG_GAIN"]
            self.write("MAX_ANALOG_GAIN", reg.encode(GAIN=self._gain_code(max_gain, "max_gain")))
        self._modify("AEC_AGC_ENABLE", AGC_ENABLE=int(on))

    def auto(self) -> Tuple[bool, bool]:
        """``(aec, agc)``: which automatic controls are on."""
        fields_ = self.map["AEC_AGC_ENABLE"].decode(self.read("AEC_AGC_ENABLE"))
        return bool(fields_["AEC_ENABLE"]), bool(fields_["AGC_ENABLE"])

    # -- readout ----------------------------------------------------------------------------------

    def flip(self, h: Optional[bool] = None, v: Optional[bool] = None) -> None:
        """Mirror the columns read out (``h``) and/or the rows (``v``); None leaves that one alone."""
        change: Dict[str, int] = {}
        if h is not None:
            change["COLUMN_FLIP"] = int(_flag(h, f"{self.name}: flip_h"))
        if v is not None:
            change["ROW_FLIP"] = int(_flag(v, f"{self.name}: flip_v"))
        if change:
            self._modify("READ_MODE", **change)

    def flips(self) -> Tuple[bool, bool]:
        fields_ = self.map["READ_MODE"].decode(self.read("READ_MODE"))
        return bool(fields_["COLUMN_FLIP"]), bool(fields_["ROW_FLIP"])

    def test_pattern(self, name: Optional[str], *, level: int = 512) -> None:
        """Replace the image by test pattern ``name`` (:data:`spec.TEST_PATTERNS`); None or "off": the image.

        ``level`` (0..1023) is the value of the ``"plain"`` pattern.
        """
        self.write("TEST_PATTERN", self._pattern_word(name, level))

    def _pattern_word(self, name: Optional[str], level: int = 512) -> int:
        reg = self.map["TEST_PATTERN"]
        if name is None or name == TEST_PATTERN_OFF:
            return 0
        if name == "plain":  # encoded as the Linux driver's "Plain" menu entry
            level = self._int_in(level, "test pattern level", 0, spec.TEST_PATTERN_LEVEL_MAX)
            return reg.encode(DATA=level, USE_DATA=1, ENABLE=1, FLIP=1)
        if name in spec.TEST_PATTERN_GRAY_CODE:
            return reg.encode(GRAY=spec.TEST_PATTERN_GRAY_CODE[name], ENABLE=1)
        raise SensorRangeError(f"{self.name}: test pattern {name!r} is not one of: "
                               f"{', '.join(spec.TEST_PATTERNS)} (or None for the image)")

    def test_pattern_in_use(self) -> Optional[str]:
        tp = self.map["TEST_PATTERN"].decode(self.read("TEST_PATTERN"))
        if not tp["ENABLE"]:
            return None
        if tp["USE_DATA"]:
            return "plain"
        return next((n for n, c in spec.TEST_PATTERN_GRAY_CODE.items() if c == tp["GRAY"]), None)

    # -- synchronisation ------------------------------------------------------------------------------

    def set_sync(self, mode: str) -> None:
        """Operating mode: ``"master"`` (free-running, drives its partner), ``"slave"`` or ``"snapshot"``."""
        if mode not in spec.SENSOR_MODES:
            raise SensorRangeError(
                f"{self.name}: sync mode {mode!r} is not one of: {', '.join(spec.SENSOR_MODES)}")
        self._modify("CHIP_CONTROL", SENSOR_MODE=spec.SENSOR_MODES[mode])

    def sync_mode(self) -> str:
        code = self.map["CHIP_CONTROL"].get(self.read("CHIP_CONTROL"), "SENSOR_MODE")
        return next((n for n, c in spec.SENSOR_MODES.items() if c == code), f"reserved ({code})")

    # -- everything in use -------------------------------------------------------------------------------

    def settings(self) -> Dict[str, Any]:
        """The values in use now: the AEC's exposure and the AGC's gain when those are on.

        Keys: ``exposure_us``, ``exposure_rows``, ``exposure_range_us`` (the manual exposures the
        timing takes, ``[lo, hi]``: a page's slider ends there), ``gain``, ``aec``, ``agc``,
        ``flip_h``, ``flip_v``, ``test_pattern`` (None when off).
        """
        aec, agc = self.auto()
        exposures = self.exposure_range()
        rows = self.read("AEC_OUTPUT") if aec else self.exposure_rows
        gain = spec.gain_from_code(self.read("AGC_OUTPUT")) if agc else self.gain
        flip_h, flip_v = self.flips()
        return {
            "exposure_us": round(spec.exposure_us_from_rows(rows, exposures.row_us), 3),
            "exposure_rows": rows,
            "exposure_range_us": [round(exposures.lo_us, 3), round(exposures.hi_us, 3)],
            "gain": gain,
            "aec": aec,
            "agc": agc,
            "flip_h": flip_h,
            "flip_v": flip_v,
            "test_pattern": self.test_pattern_in_use(),
        }


# --------------------------------------------------------------------------
# What /api/cameras takes
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SensorSettings:
    """Camera controls to apply; a field left None is left as it is.

    ``exposure_us`` (> 0; the sensor's range, one row to one frame, depends on its timing),
    ``gain`` 1.0..4.0, ``aec``/``agc`` booleans, ``flip_h``/``flip_v``
    booleans, ``test_pattern`` one of :data:`spec.TEST_PATTERNS` or ``"off"``
    (:meth:`from_dict` also takes JSON ``null`` for off).
    """

    exposure_us: Optional[float] = None
    gain: Optional[float] = None
    aec: Optional[bool] = None
    agc: Optional[bool] = None
    flip_h: Optional[bool] = None
    flip_v: Optional[bool] = None
    test_pattern: Optional[str] = None

    def __post_init__(self) -> None:
        if self.exposure_us is not None:
            us = _number(self.exposure_us, "exposure_us")
            if not us > 0:
                raise SettingsError(f"exposure_us must be > 0 microseconds, not {self.exposure_us!r}")
        if self.gain is not None:
            g = _number(self.gain, "gain")
            if not spec.GAIN_MIN <= g <= spec.GAIN_MAX:
                raise SensorRangeError(f"gain {g:g} is out of range: {spec.GAIN_MIN}..{spec.GAIN_MAX}")
        for name in ("aec", "agc", "flip_h", "flip_v"):
            value = getattr(self, name)
            if value is not None:
                _flag(value, name)
        tp = self.test_pattern
        if tp is not None and tp != TEST_PATTERN_OFF and tp not in spec.TEST_PATTERNS:
            raise SettingsError(f"test_pattern {tp!r} is not one of: {', '.join(spec.TEST_PATTERNS)}, "
                                f"or null/{TEST_PATTERN_OFF!r} for the camera image")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "SensorSettings":
        """Validate a request body: unknown keys are named, ``test_pattern: null`` means off."""
        if not isinstance(data, Mapping):
            raise SettingsError(f"camera settings must be an object with fields "
                                f"{', '.join(SETTINGS_FIELDS)}, not {type(data).__name__}")
        unknown = [k for k in data if k not in SETTINGS_FIELDS]
        if unknown:
            raise SettingsError(f"unknown camera setting(s): {', '.join(map(repr, unknown))} "
                                f"(known: {', '.join(SETTINGS_FIELDS)})")
        values = dict(data)
        if "test_pattern" in values and values["test_pattern"] is None:
            values["test_pattern"] = TEST_PATTERN_OFF
        for key in ("exposure_us", "gain", "aec", "agc", "flip_h", "flip_v"):
            if key in values and values[key] is None:
                raise SettingsError(f"{key} may not be null (leave it out to keep the current value)")
        return cls(**values)

    def given(self) -> Dict[str, Any]:
        """The fields set, in apply order."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


SETTINGS_FIELDS: Tuple[str, ...] = tuple(f.name for f in fields(SensorSettings))


@dataclass
class _SensorState:
    ok: bool = False
    error: Optional[str] = "not started"
    chip_id: Optional[int] = None
    answering: bool = True  # False while the last failure was on the bus (not a wrong part, say)
    since: Optional[float] = None  # time.time() when it became unavailable; None while up
    lost_at: float = 0.0  # time.monotonic() of the same moment, for the "back after" line


class StereoSensors:
    """The left and right MT9V034 of the board: bring-up, controls, read-back, health, recovery.

    ``sync`` is ``"master-slave"`` (``master`` names the sensor whose timing
    the other follows) or ``"snapshot"`` (both expose on the fabric's common
    trigger). ``frame_size``/``fps`` program the window and frame rate;
    ``defaults`` are the controls :meth:`start` applies; ``aec_target`` the
    AEC/AGC desired bin it writes. Every call blocks for its I2C
    transactions (a few ms on the board; :meth:`start` somewhat more): call
    it from a worker thread, not the event loop. Thread-safe: every public
    call holds one lock for its whole I2C sequence, so the two sensors never
    get half of a request each from two callers.

    Per camera it remembers the controls in effect: the defaults, with what
    each successful :meth:`apply` set on top (a refused request changes
    nothing). A sensor that stops answering loses nothing the user chose:
    when :meth:`check` finds it answering again, it is brought up exactly as
    :meth:`start` does and given those controls back.
    """

    def __init__(self, left: MT9V034, right: MT9V034, *, sync: str = "master-slave", master: str = "left",
                 frame_size: Tuple[int, int] = (spec.ARRAY_WIDTH, spec.ARRAY_HEIGHT), fps: float = 60.0,
                 defaults: Union[SensorSettings, Mapping[str, Any], None] = None,
                 aec_target: Optional[int] = None) -> None:
        if sync not in SYNC_MODES:
            raise SettingsError(f"sync {sync!r} is not one of: {', '.join(SYNC_MODES)}")
        if master not in CAMERAS:
            raise SettingsError(f"master {master!r} is not one of: {', '.join(CAMERAS)}")
        self.sensors: Dict[str, MT9V034] = {"left": left, "right": right}
        self.sync = sync
        self.master = master
        self.frame_size = (int(frame_size[0]), int(frame_size[1]))
        self.fps = float(fps)
        self.defaults = (defaults if isinstance(defaults, SensorSettings)
                         else SensorSettings.from_dict(defaults or {}))
        self.aec_target = aec_target
        self._state = {c: _SensorState() for c in CAMERAS}
        self._controls: Dict[str, Dict[str, Any]] = {c: self.defaults.given() for c in CAMERAS}
        self._started = False
        self._lock = threading.RLock()

    @property
    def left(self) -> MT9V034:
        return self.sensors["left"]

    @property
    def right(self) -> MT9V034:
        return self.sensors["right"]

    def _mode_of(self, camera: str) -> str:
        if self.sync == "snapshot":
            return "snapshot"
        return "master" if camera == self.master else "slave"

    def _targets(self, camera: str) -> Tuple[str, ...]:
        if camera == "both":
            return CAMERAS
        if camera in CAMERAS:
            return (camera,)
        raise SettingsError(f"camera {camera!r} is not one of: both, left, right")

    def _fail(self, camera: str, exc: Exception) -> None:
        """Mark ``camera`` unavailable because of ``exc``; one log line when it goes, not one per re-probe.

        While it stays down, a bus error (the usual re-probe answer) is not
        logged again; a sensor that answers but fails its checks is, once per
        distinct message (that is news: another part, a wrong strap).
        """
        state = self._state[camera]
        down_already = not state.ok and state.since is not None
        message = str(exc)
        if not down_already:
            log.error("camera sensor %s: %s", camera, _unnamed(camera, message))
            state.since, state.lost_at = time.time(), time.monotonic()
        elif not isinstance(exc, I2CError) and message != state.error:
            log.error("camera sensor %s: %s", camera, _unnamed(camera, message))
        else:
            log.debug("camera sensor %s: still unavailable: %s", camera, exc)
        state.ok, state.error, state.answering = False, message, not isinstance(exc, I2CError)

    # -- bring-up ---------------------------------------------------------------------------

    def start(self) -> Dict[str, Any]:
        """Bring both sensors up; returns :meth:`health`. Never raises for a sensor that fails.

        Per sensor: soft reset, identity check, window, frame rate, sync
        mode, AEC target, then the default controls (what :meth:`apply` set
        before is forgotten: this is a fresh start). A sensor that does not
        answer or is not an MT9V034 is marked unavailable with the reason
        (logged, and in :meth:`health`); the other one is still brought up.
        Calling it again retries (a reseated cable, a power cycle);
        :meth:`check` retries an unavailable sensor by itself.
        """
        with self._lock:
            self._started = True
            for camera in CAMERAS:
                self._controls[camera] = self.defaults.given()
                self._set_up(camera)
            return self.health()

    def _set_up(self, camera: str) -> bool:
        """The bring-up of one sensor with its remembered controls; False (and marked) if it fails."""
        sensor = self.sensors[camera]
        state = self._state[camera]
        was_down = state.since is not None
        try:
            sensor.reset()
            state.chip_id = sensor.check_id()
            sensor.configure_window(*self.frame_size)
            sensor.set_frame_rate(self.fps)
            sensor.set_sync(self._mode_of(camera))
            if self.aec_target is not None:
                sensor.set_auto_target(self.aec_target)
            self._write(sensor, self._plan(sensor, SensorSettings(**self._controls[camera])))
        except (I2CError, SensorError) as exc:
            self._fail(camera, exc)
            return False
        if was_down:
            log.info("camera sensor %s: answers again after %.1f s; MT9V034 at %#04x set up again (%s) "
                     "with the controls last applied", camera, time.monotonic() - state.lost_at,
                     sensor.address, self._mode_of(camera))
        elif not state.ok:
            log.info("camera sensor %s: MT9V034 at %#04x ready (%s)", camera, sensor.address,
                     self._mode_of(camera))
        state.ok, state.error, state.answering, state.since = True, None, True, None
        return True

    def check(self) -> Dict[str, Any]:
        """The periodic check: notice a sensor that stopped answering, restore one that answers again.

        Returns :meth:`health`; never raises for a sensor. Per sensor that is
        up: one read of ``CHIP_VERSION`` (it answers, and is still an
        MT9V034). Per sensor that is unavailable: the same one read, and
        only when that succeeds, the whole bring-up of :meth:`start` followed
        by the controls last applied (about 30 transactions, a few ms on the
        board). So a check costs two register reads (~0.2 ms on the board's
        bus, or one adapter timeout per silent sensor), cheap enough to run
        several times a second; :meth:`read` (14 reads) is the costlier
        call. Does nothing before :meth:`start`.
        """
        with self._lock:
            if not self._started:
                return self.health()
            for camera in CAMERAS:
                state = self._state[camera]
                try:
                    self.sensors[camera].check_id()
                except (I2CError, SensorError) as exc:
                    self._fail(camera, exc)
                    continue
                if not state.ok:
                    self._set_up(camera)
            return self.health()

    # -- controls ----------------------------------------------------------------------------

    def _plan(self, sensor: MT9V034, s: SensorSettings) -> Dict[str, Any]:
        """The writes of ``s`` for ``sensor``, checked against the sensor (reads only)."""
        plan: Dict[str, Any] = s.given()
        if s.exposure_us is not None:
            plan["exposure_rows"] = sensor.exposure_rows_for(s.exposure_us)
        return plan

    @staticmethod
    def _write(sensor: MT9V034, plan: Mapping[str, Any]) -> None:
        # Manual values before the switches, so turning AEC/AGC off never shows a stale value.
        if "exposure_rows" in plan:
            sensor.exposure_rows = plan["exposure_rows"]
        if "gain" in plan:
            sensor.gain = plan["gain"]
        if "aec" in plan:
            sensor.set_aec(plan["aec"])
        if "agc" in plan:
            sensor.set_agc(plan["agc"])
        if "flip_h" in plan or "flip_v" in plan:
            sensor.flip(plan.get("flip_h"), plan.get("flip_v"))
        if "test_pattern" in plan:
            sensor.test_pattern(plan["test_pattern"])

    def apply(self, settings: Union[SensorSettings, Mapping[str, Any]], camera: str = "both"
              ) -> Dict[str, Optional[Dict[str, Any]]]:
        """Apply ``settings`` (a :class:`SensorSettings` or a request dict) to ``camera``.

        ``camera`` is ``"both"`` (default), ``"left"`` or ``"right"``.
        Everything is validated (types, ranges against each sensor's timing:
        an exposure is one row to one frame) before the first write, so a
        refused request changes nothing and the previous settings stay.
        Raises :class:`SettingsError`/:class:`SensorRangeError` (both
        ``ValueError``) for a bad request, :class:`SensorUnavailable` if a
        target sensor is not answering (it is then marked in :meth:`health`).
        What a sensor took is remembered (:meth:`controls`) and given back
        when it is set up again. Returns :meth:`read`: the values in use afterwards.
        """
        s = settings if isinstance(settings, SensorSettings) else SensorSettings.from_dict(settings)
        with self._lock:
            targets = self._targets(camera)
            down = [c for c in targets if not self._state[c].ok]
            if down:
                hints = []
                if any(not self._state[c].answering for c in down):
                    hints.append("a sensor is set up again, with the settings last applied, as soon as "
                                 "it answers: check its cable and power")
                if len(down) < len(targets):
                    hints.append("set the other camera alone with camera='left' or 'right'")
                raise SensorUnavailable("; ".join(
                    f"{c} sensor (I2C {self.sensors[c].address:#04x}) is unavailable: {self._state[c].error}"
                    for c in down) + "".join(f". {h[0].upper()}{h[1:]}" for h in hints))
            plans = {c: self._guarded(c, lambda sensor: self._plan(sensor, s)) for c in targets}
            for c, plan in plans.items():
                self._guarded(c, lambda sensor, plan=plan: self._write(sensor, plan))
                self._controls[c].update(s.given())
            return self.read()

    def controls(self, camera: str) -> Dict[str, Any]:
        """What ``camera`` is set up with when it answers again: the defaults, with what apply() set."""
        if camera not in CAMERAS:
            raise SettingsError(f"camera {camera!r} is not one of: {', '.join(CAMERAS)}")
        with self._lock:
            return dict(self._controls[camera])

    def _guarded(self, camera: str, action: Any) -> Any:
        try:
            return action(self.sensors[camera])
        except I2CError as exc:
            self._fail(camera, exc)
            raise SensorUnavailable(f"{camera} sensor stopped answering: {exc}") from exc

    def read(self) -> Dict[str, Optional[Dict[str, Any]]]:
        """The values in use per camera (see :meth:`MT9V034.settings`); None for an unavailable sensor.

        Never raises for a sensor that stops answering: it is marked in
        :meth:`health` and reads None. It does not re-probe: :meth:`check` does.
        """
        with self._lock:
            out: Dict[str, Optional[Dict[str, Any]]] = {}
            for c in CAMERAS:
                out[c] = None
                if self._state[c].ok:
                    try:
                        out[c] = self.sensors[c].settings()
                    except I2CError as exc:
                        self._fail(c, exc)
            return out

    def health(self) -> Dict[str, Any]:
        """Overall ``ok``; per sensor ``ok``, ``address``, ``chip_id``, ``mode``, ``error`` (or None)."""
        with self._lock:
            out: Dict[str, Any] = {"ok": all(self._state[c].ok for c in CAMERAS), "sync": self.sync,
                                   "master": self.master if self.sync == "master-slave" else None}
            for c in CAMERAS:
                st = self._state[c]
                out[c] = {
                    "ok": st.ok,
                    "address": f"{self.sensors[c].address:#04x}",
                    "chip_id": None if st.chip_id is None else f"{st.chip_id:#06x}",
                    "mode": self._mode_of(c),
                    "error": st.error,
                }
            slave = self._other(self.master)
            if self.sync == "master-slave" and not self._state[self.master].ok and self._state[slave].ok:
                out[slave]["warning"] = f"its master ({self.master}) is unavailable: it gets no frame timing"
            return out

    def faults(self) -> List[Dict[str, Any]]:
        """The sensors unavailable now, as faults: ``what`` (``"sensor.left"``), ``text``, ``since``.

        ``since`` is the ``time.time()`` it became unavailable (kept while
        re-probes fail). A sensor never started is not a fault.
        """
        with self._lock:
            out: List[Dict[str, Any]] = []
            for c in CAMERAS:
                st = self._state[c]
                if st.ok or st.since is None:
                    continue
                how = "is unavailable" if st.answering else "is not answering"
                text = f"{c} sensor (I2C {self.sensors[c].address:#04x}) {how}: {_unnamed(c, st.error or '')}"
                if self.sync == "master-slave" and c == self.master:
                    text += f"; the {self._other(c)} sensor, its slave, gets no frame timing"
                out.append({"what": f"sensor.{c}", "text": text, "since": st.since})
            return out

    @staticmethod
    def _other(camera: str) -> str:
        return "right" if camera == "left" else "left"


def _unnamed(camera: str, message: str) -> str:
    """``message`` without the ``"left: "`` an :class:`MT9V034` error starts with (the caller names it)."""
    prefix = f"{camera}: "
    return message[len(prefix):] if message.startswith(prefix) else message
