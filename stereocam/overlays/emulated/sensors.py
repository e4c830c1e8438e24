"""Emulated MT9V034 sensors: the register set of :mod:`..spec.mt9v034` with its behaviour.

:class:`EmulatedMT9V034` is one sensor behind the emulated I2C bus
(:mod:`.i2c`). It models behaviour, not storage:

* power-on values from the register table; ``CHIP_VERSION`` and the AEC/AGC
  outputs are read-only and live; a write to an unknown or read-only
  register, or of a value the table's limits refuse, raises
  :class:`.regblock.EmulationError` (a driver bug); reserved bits read 0;
* ``RESET`` bits are self-clearing: a soft reset abandons the frame and, like
  the auto-block reset, restarts the AEC/AGC from the manual exposure and
  gain (the MT9V032 data sheet: a soft reset resets the digital logic except
  the two-wire serial interface configuration, so registers keep values);
* per frame (:meth:`start_frame`), the sensor latches what is in use
  (exposure from ``R0x0B`` or the AEC, gain from ``R0x35`` or the AGC,
  flips from ``R0x0D``, the test pattern from ``R0x7F``) and sets the
  synthetic rig's sensor stage with them (:meth:`SyntheticRig.set_sensor`):
  brightness is proportional to exposure time x gain, read noise to gain;
* after the frame (:meth:`end_frame`) it measures the frame's mean
  brightness (``AGC_AEC_CURRENT_BIN``, in 64ths of full scale) and, every
  ``AEC_UPDATE_FREQUENCY + 1`` frames, moves exposure (then gain, when AGC
  is on too and the exposure is at its limit) towards the desired bin,
  with the low-pass filter the Linux driver documents for R0xA8/R0xAA.

The AEC/AGC arithmetic is this emulator's model (the chip's algorithm is not
published beyond its registers): the exposure x gain product is scaled by
``desired bin / current bin``. Brightness is referred to the reset exposure:
480 rows of 846 pixel clocks at 26.6 MHz (15.27 ms) and 1x gain render the
rig's scene as the rig renders it by itself. The window registers set the row
time (so exposure time) but do not crop the rig's frames.

:class:`EmulatedSensorPair` is the board's two sensors on one emulated bus,
and what :class:`.logic.EmulatedFabric` ticks around each camera frame.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Dict, Optional, Protocol, Sequence, Tuple

import numpy as np

from ..spec import mt9v034 as spec
from ..spec.mt9v034 import MT9V034_MAP, Register16
from ..spec.regs import Access
from .i2c import EmulatedI2CBus
from .regblock import EmulationError

log = logging.getLogger(__name__)

__all__ = ["EmulatedMT9V034", "EmulatedSensorPair", "REFERENCE_EXPOSURE_US", "SensorTarget", "pattern_image"]

REFERENCE_EXPOSURE_US = spec.SHUTTER_DEFAULT * spec.row_time_us()  # 15.27 ms: the rig's unit exposure
_MEASURE_STEP = 4  # the brightness measurement uses every 4th pixel of every 4th row
_RATIO_LIMIT = 8.0  # at most this factor per AEC/AGC update (a black frame has no finite ratio)


class SensorTarget(Protocol):
    """What the sensors drive: the synthetic rig's per-camera sensor stage."""

    @property
    def frame_size(self) -> Tuple[int, int]: ...

    def set_sensor(self, camera: int, *, gain: float = 1.0, exposure_scale: float = 1.0,
                   flip_h: bool = False, flip_v: bool = False, test_pattern: Optional[np.ndarray] = None,
                   noise: Optional[float] = None) -> None: ...


def pattern_image(name: str, size: Tuple[int, int], level: int = 0) -> np.ndarray:
    """The 8-bit gray image of test pattern ``name`` at ``size = (width, height)``.

    Gray shades ramp 0..255 across the frame: ``gray_vertical`` left to right
    (vertical bands), ``gray_horizontal`` top to bottom, ``gray_diagonal``
    along both; ``plain`` is ``level`` (10 bits) everywhere. This is the
    emulator's rendering; the sensor's own ramps are 10-bit counters.
    """
    w, h = int(size[0]), int(size[1])
    cols = (np.arange(w, dtype=np.int32) * 256 // w)[None, :]
    rows = (np.arange(h, dtype=np.int32) * 256 // h)[:, None]
    if name == "gray_vertical":
        img = np.broadcast_to(cols, (h, w))
    elif name == "gray_horizontal":
        img = np.broadcast_to(rows, (h, w))
    elif name == "gray_diagonal":
        img = (cols + rows) // 2
    elif name == "plain":
        img = np.full((h, w), int(level) >> 2, np.int32)
    else:
        raise ValueError(f"unknown test pattern {name!r} (known: {', '.join(spec.TEST_PATTERNS)})")
    return np.ascontiguousarray(img, dtype=np.uint8)


class EmulatedMT9V034:
    """One emulated MT9V034 (context A) as an I2C device, driving camera ``camera`` of ``target``.

    ``chip_id`` is what ``R0x00`` reads (give another to emulate a wrong
    part); ``answering=False`` makes the bus NACK every transaction.
    ``read_noise`` is the rig's read noise at 1x gain (DN; 0 keeps the
    rig's fast noiseless rendering). ``target`` may be None (registers and
    AEC state only) or anything with ``set_sensor`` (a :class:`SyntheticRig`).
    Thread-safe: the bus and the frame clock may call at once.
    """

    def __init__(self, *, camera: int, name: str = "", target: Optional[Any] = None,
                 chip_id: int = spec.CHIP_ID, answering: bool = True, read_noise: float = 0.0,
                 pixel_clock_hz: float = spec.PIXEL_CLOCK_HZ) -> None:
        if camera not in (0, 1):
            raise ValueError(f"camera is 0 (left) or 1 (right), not {camera!r}")
        self.camera = camera
        self.name = name or ("left", "right")[camera]
        self.map = MT9V034_MAP
        self.chip_id = int(chip_id)
        self.answering = bool(answering)
        self.read_noise = float(read_noise)
        self.pixel_clock_hz = float(pixel_clock_hz)
        self.target = target if target is not None and hasattr(target, "set_sensor") else None
        self.frames = 0
        self._lock = threading.RLock()
        self._values: Dict[int, int] = {}
        self._pattern_cache: Dict[Tuple[str, int], np.ndarray] = {}
        self._aec_rows = float(spec.SHUTTER_DEFAULT)
        self._agc_code = float(spec.GAIN_UNIT)
        self._bin = 0.0
        self._since_update = 0
        self._in_use: Tuple[int, int] = (spec.SHUTTER_DEFAULT, spec.GAIN_UNIT)
        self.power_on()

    def __repr__(self) -> str:
        return f"EmulatedMT9V034({self.name!r}, camera={self.camera})"

    # -- state --------------------------------------------------------------------------

    def power_on(self) -> None:
        """Every register at its reset value, AEC/AGC restarted (a power cycle)."""
        with self._lock:
            self._values = self.map.reset_values()
            self._restart_auto()

    def get(self, name: str) -> int:
        """A register's stored value (no bus, no live values): for tests and the model."""
        return self._values[self.map.address(name)]

    def get_field(self, name: str, field: str) -> int:
        return self.map[name].get(self.get(name), field)

    @property
    def exposure_rows_in_use(self) -> int:
        """Exposure of the last frame started, rows (the manual value or the AEC's)."""
        return self._in_use[0]

    @property
    def gain_in_use(self) -> float:
        """Analog gain of the last frame started (the manual value or the AGC's)."""
        return spec.gain_from_code(self._in_use[1])

    @property
    def sensor_mode(self) -> str:
        code = self.get_field("CHIP_CONTROL", "SENSOR_MODE")
        return next((n for n, c in spec.SENSOR_MODES.items() if c == code), f"reserved ({code})")

    def _restart_auto(self) -> None:
        self._aec_rows = float(self.get("COARSE_SHUTTER_WIDTH_TOTAL"))
        self._agc_code = float(self.get_field("ANALOG_GAIN", "GAIN"))
        self._since_update = 0

    # -- the I2C side ---------------------------------------------------------------------

    def _reg(self, register: int, op: str) -> Register16:
        reg = self.map.at(register)
        if reg is None:
            raise EmulationError(f"{self.name} (MT9V034): {op} R0x{register:02X}, where no register exists")
        return reg

    def i2c_read16(self, register: int) -> int:
        with self._lock:
            reg = self._reg(register, "read of")
            if reg.name == "CHIP_VERSION":
                return self.chip_id
            if reg.name == "AEC_OUTPUT":
                return self._in_use[0]
            if reg.name == "AGC_OUTPUT":
                return self._in_use[1]
            if reg.name == "AGC_AEC_CURRENT_BIN":
                return min(int(self._bin), spec.DESIRED_BIN_MAX - 1)
            return self._values[register] & ~reg.reserved_mask & ~reg.mask_of(Access.SC)

    def i2c_write16(self, register: int, value: int) -> None:
        value = int(value)
        with self._lock:
            reg = self._reg(register, f"write of {value:#06x} to")
            if not 0 <= value <= spec.REG_MASK:
                raise EmulationError(f"{self.name}: {value} written to {reg.name} does not fit 16 bits")
            if reg.mask_of(Access.RO) == spec.REG_MASK or (not reg.fields and reg.access is Access.RO):
                raise EmulationError(f"{self.name}: write of {value:#06x} to read-only register "
                                     f"{reg.name} (R0x{register:02X})")
            value &= ~reg.reserved_mask
            for name, lo, hi in reg.limits:
                v = value if name == reg.name else reg.get(value, name)
                if not lo <= v <= hi:
                    what = reg.name if name == reg.name else f"{reg.name}.{name}"
                    raise EmulationError(f"{self.name}: {what} = {v} is outside {lo}..{hi}, "
                                         "which the MT9V034 accepts")
            ro = reg.mask_of(Access.RO)
            self._values[register] = (self._values[register] & ro) | (value & ~ro)
            if reg.name == "RESET":
                if reg.get(value, "SOFT_RESET") or reg.get(value, "AUTO_BLOCK_SOFT_RESET"):
                    self._restart_auto()
                self._values[register] &= ~reg.mask_of(Access.SC)

    # -- the frame side -------------------------------------------------------------------

    def _row_time_us(self) -> float:
        width, hblank = self.get("WINDOW_WIDTH"), self.get("HORIZONTAL_BLANKING")
        return spec.row_time_us(width, hblank, self.pixel_clock_hz)

    def start_frame(self, index: int) -> None:
        """Latch the registers for frame ``index`` and set the target's sensor stage with them."""
        with self._lock:
            aec = self.get_field("AEC_AGC_ENABLE", "AEC_ENABLE")
            agc = self.get_field("AEC_AGC_ENABLE", "AGC_ENABLE")
            if not aec:
                self._aec_rows = float(self.get("COARSE_SHUTTER_WIDTH_TOTAL"))
            if not agc:
                self._agc_code = float(self.get_field("ANALOG_GAIN", "GAIN"))
            rows, code = int(round(self._aec_rows)), int(round(self._agc_code))
            self._in_use = (rows, code)
            if self.target is None:
                return
            tp = self.map["TEST_PATTERN"].decode(self.get("TEST_PATTERN"))
            pattern = None
            if tp["ENABLE"]:
                name = "plain" if tp["USE_DATA"] else {1: "gray_vertical", 2: "gray_horizontal",
                                                       3: "gray_diagonal"}.get(tp["GRAY"], "")
                if name:
                    pattern = self._pattern(name, tp["DATA"] if name == "plain" else 0)
            self.target.set_sensor(
                self.camera,
                gain=spec.gain_from_code(code),
                exposure_scale=rows * self._row_time_us() / REFERENCE_EXPOSURE_US,
                flip_h=bool(self.get_field("READ_MODE", "COLUMN_FLIP")),
                flip_v=bool(self.get_field("READ_MODE", "ROW_FLIP")),
                test_pattern=pattern,
                noise=self.read_noise,
            )

    def _pattern(self, name: str, level: int) -> np.ndarray:
        key = (name, level)
        if key not in self._pattern_cache:
            img = pattern_image(name, self.target.frame_size, level)  # type: ignore[union-attr]
            img.setflags(write=False)
            self._pattern_cache[key] = img
        return self._pattern_cache[key]

    def end_frame(self, index: int, frame: np.ndarray) -> None:
        """Measure this camera's part of ``frame`` ((H, W, 8) uint8) and run one AEC/AGC step."""
        gray = frame[::_MEASURE_STEP, ::_MEASURE_STEP, 4 * self.camera + 3]
        mean = float(gray.mean()) if gray.size else 0.0
        with self._lock:
            self.frames += 1
            self._bin = mean * spec.DESIRED_BIN_MAX / 256.0
            self._auto_step()

    def _auto_step(self) -> None:
        aec = bool(self.get_field("AEC_AGC_ENABLE", "AEC_ENABLE"))
        agc = bool(self.get_field("AEC_AGC_ENABLE", "AGC_ENABLE"))
        if not (aec or agc):
            return
        skip = self.get("AEC_UPDATE_FREQUENCY" if aec else "AGC_UPDATE_FREQUENCY")
        self._since_update += 1
        if self._since_update <= skip:
            return
        self._since_update = 0
        ratio = self.get("AEC_AGC_DESIRED_BIN") / max(self._bin, 1e-3)
        ratio = min(max(ratio, 1.0 / _RATIO_LIMIT), _RATIO_LIMIT)
        rows, code = self._aec_rows, self._agc_code
        product = rows * code * ratio
        max_rows = float(self.get("MAX_COARSE_SHUTTER_WIDTH"))
        max_code = float(self.get_field("MAX_ANALOG_GAIN", "GAIN"))
        if aec:  # exposure first, at the lowest gain AGC may use; gain makes up the rest
            gain_for_exposure = spec.GAIN_UNIT if agc else code
            new_rows = min(max(product / gain_for_exposure, float(spec.AEC_MAX_SHUTTER_MIN)), max_rows)
            self._aec_rows = _low_pass(rows, new_rows, self.get("AEC_LPF"))
        if agc:
            new_code = min(max(product / self._aec_rows, float(spec.GAIN_CODE_MIN)), max_code)
            self._agc_code = _low_pass(code, new_code, self.get("AGC_LPF"))


def _low_pass(current: float, new: float, lpf: int) -> float:
    """R0xA8/R0xAA: jump if the change exceeds a quarter of the value, else move 1/2**lpf of the way.

    As documented with the Linux driver's V4L2_CID_AEC_LPF / V4L2_CID_AGC_LPF controls.
    """
    if abs(new - current) > current / 4:
        return new
    return current + (new - current) / (1 << int(lpf))


class EmulatedSensorPair:
    """The board's two MT9V034s (left = camera 0, right = camera 1) on one emulated I2C bus.

    ``target`` is the camera source whose sensor stage they drive (the
    fabric's :class:`SyntheticRig` or :class:`.targets.CheckerboardTarget`;
    anything without ``set_sensor``, or None, leaves the pixels alone).
    ``addresses`` are the sensors' 7-bit I2C addresses. Attach the pair to
    the fabric (``EmulatedFabric(sensors=pair)`` or
    ``fabric.sensors = pair``) so it runs every frame; drive it over
    :attr:`bus` with :class:`stereocam.drivers.mt9v034.StereoSensors`.
    """

    def __init__(self, target: Optional[Any] = None, *, addresses: Sequence[int] = (0x48, 0x58),
                 bus: Optional[EmulatedI2CBus] = None, bus_number: int = 0,
                 chip_ids: Sequence[int] = (spec.CHIP_ID, spec.CHIP_ID), read_noise: float = 0.0,
                 pixel_clock_hz: float = spec.PIXEL_CLOCK_HZ) -> None:
        if len(addresses) != 2 or len(chip_ids) != 2:
            raise ValueError("a stereo pair has two addresses and two chip ids (left, right)")
        self.bus = bus if bus is not None else EmulatedI2CBus(bus_number)
        self.addresses = (int(addresses[0]), int(addresses[1]))
        self.left = EmulatedMT9V034(camera=0, name="left", target=target, chip_id=chip_ids[0],
                                    read_noise=read_noise, pixel_clock_hz=pixel_clock_hz)
        self.right = EmulatedMT9V034(camera=1, name="right", target=target, chip_id=chip_ids[1],
                                     read_noise=read_noise, pixel_clock_hz=pixel_clock_hz)
        self.bus.attach(self.addresses[0], self.left)
        self.bus.attach(self.addresses[1], self.right)
        self._warned: Optional[str] = None

    @classmethod
    def for_profile(cls, profile: Any, target: Optional[Any] = None, **kwargs: Any) -> "EmulatedSensorPair":
        """The pair a board profile describes (its bus number, addresses and pixel clock)."""
        return cls(target, addresses=(profile.left_address, profile.right_address),
                   bus_number=profile.i2c_bus, pixel_clock_hz=profile.pixel_clock_hz, **kwargs)

    @property
    def sensors(self) -> Tuple[EmulatedMT9V034, EmulatedMT9V034]:
        return (self.left, self.right)

    def sync_problem(self) -> Optional[str]:
        """None if the pair is set up to run in lockstep (master + slave, or both snapshot), else why not."""
        modes = (self.left.sensor_mode, self.right.sensor_mode)
        if sorted(modes) == ["master", "slave"] or modes == ("snapshot", "snapshot"):
            return None
        return (f"the sensors are not synchronised: left is {modes[0]}, right is {modes[1]} "
                "(need one master and one slave, or both snapshot)")

    def start_frame(self, index: int) -> None:
        problem = self.sync_problem()
        if problem != self._warned:  # say it once per change, not 60 times a second
            if problem:
                log.warning("emulated sensors: %s", problem)
            self._warned = problem
        self.left.start_frame(index)
        self.right.start_frame(index)

    def end_frame(self, index: int, frame: np.ndarray) -> None:
        self.left.end_frame(index, frame)
        self.right.end_frame(index, frame)
