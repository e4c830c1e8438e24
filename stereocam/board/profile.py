"""The board profile: which I2C bus and addresses the sensors are on, how they are synchronised,
which overlay to load, the frame size and rate, and the camera controls at start.

One YAML file per board; :data:`DEFAULT_PROFILE` (``zynq-stereo.yaml``, next
to this module) is ours. :func:`load_profile` reads and validates it once,
at start: every key is required, an unknown or missing key is named with
its path (``i2c.left``), and every value is checked against what the board
and the MT9V034 can do, so a wrong profile stops the daemon at once with a
:class:`ProfileError` saying what to fix, instead of a hang or a timeout at
the first frame. (Whether a sensor really answers at the address given is
found at start by :meth:`stereocam.drivers.mt9v034.StereoSensors.start`.)

Which file (:func:`find_profile`, what ``stereocam serve`` does at start):
``--board FILE`` (or the settings file's ``board`` key), else ``board.yaml``
in the machine's settings folder (``/etc/stereocam``, or ``$STEREOCAM_ETC``)
if it exists, else the packaged default. The machine's copy is what an
upgrade of the package never touches.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple, Union

from ..calibration.safe_yaml import YamlRefused, load
from ..drivers.i2c import I2CBus
from ..drivers.mt9v034 import MT9V034, SETTINGS_FIELDS, SYNC_MODES, SensorSettings, StereoSensors
from ..overlays.spec import mt9v034 as spec

__all__ = ["BoardProfile", "ProfileError", "DEFAULT_PROFILE", "ETC_ENV", "DEFAULT_ETC", "BOARD_FILE",
           "etc_dir", "find_profile", "load_board_profile", "load_profile", "profile_from_dict"]

DEFAULT_PROFILE = Path(__file__).resolve().with_name("zynq-stereo.yaml")
ETC_ENV = "STEREOCAM_ETC"  # the machine's settings folder; tests point it at a temporary one
DEFAULT_ETC = Path("/etc/stereocam")
BOARD_FILE = "board.yaml"  # the machine's own profile in that folder

_KEYS: Dict[str, Tuple[str, ...]] = {
    "": ("name", "overlay", "frame", "i2c", "sensors", "controls"),
    "frame": ("width", "height", "fps"),
    "i2c": ("bus", "left", "right", "timeout_s"),
    "sensors": ("pixel_clock_hz", "sync", "master", "aec_target_bin"),
    "controls": SETTINGS_FIELDS,
}
_OPTIONAL = {"sensors": ("master",)}  # required or refused depending on sensors.sync
PIXEL_CLOCK_RANGE = (13_000_000, 27_000_000)  # MT9V034 SYSCLK, Hz


class ProfileError(ValueError):
    """A board profile that cannot be used; the message names the file, the key and what to do."""


@dataclass(frozen=True)
class BoardProfile:
    """A validated board profile (see ``zynq-stereo.yaml`` for the meaning of each value)."""

    name: str
    overlay: str
    width: int
    height: int
    fps: float
    i2c_bus: int
    left_address: int
    right_address: int
    i2c_timeout: float
    pixel_clock_hz: int
    sync: str
    master: Optional[str]
    aec_target_bin: int
    controls: Dict[str, Any] = field(default_factory=dict)
    source: str = "<dict>"

    @property
    def frame_size(self) -> Tuple[int, int]:
        return (self.width, self.height)

    @property
    def i2c_device(self) -> str:
        return f"/dev/i2c-{self.i2c_bus}"

    def stereo_sensors(self, bus: I2CBus) -> StereoSensors:
        """The sensor pair this profile describes, on ``bus``; nothing is sent until its ``start()``.

        On the board ``bus`` is ``LinuxI2CBus(profile.i2c_bus, timeout=profile.i2c_timeout)``;
        emulated, ``EmulatedSensorPair.for_profile(profile, rig).bus``.
        """
        def make(camera: str, address: int) -> MT9V034:
            return MT9V034(bus, address, name=camera, pixel_clock_hz=self.pixel_clock_hz)

        return StereoSensors(make("left", self.left_address), make("right", self.right_address),
                             sync=self.sync, master=self.master or "left",
                             frame_size=(self.width, self.height), fps=self.fps,
                             defaults=self.controls, aec_target=self.aec_target_bin)


def load_profile(path: Union[str, "os.PathLike[str]", None] = None) -> BoardProfile:
    """Read and validate the profile at ``path`` (default :data:`DEFAULT_PROFILE`)."""
    p = Path(path) if path is not None else DEFAULT_PROFILE
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ProfileError(f"board profile {p} does not exist: give the path of a profile (--board FILE or "
                           f"the settings' board key; without one, {etc_dir() / BOARD_FILE} if it exists, "
                           f"else {DEFAULT_PROFILE})") from None
    except IsADirectoryError:
        raise ProfileError(f"board profile {p} is a folder: give the profile's file, "
                           f"e.g. {p / BOARD_FILE}") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ProfileError(f"cannot read board profile {p}: {reason}") from None
    try:
        data = load(text)
    except YamlRefused as exc:
        raise ProfileError(f"board profile {p}: {exc}") from None
    return profile_from_dict(data, source=str(p))


def etc_dir(env: Optional[Mapping[str, str]] = None) -> Path:
    """The machine's settings folder: ``$STEREOCAM_ETC`` if set, else ``/etc/stereocam``."""
    value = (os.environ if env is None else env).get(ETC_ENV)
    return Path(value) if value else DEFAULT_ETC


def find_profile(board: Union[str, "os.PathLike[str]", None] = None, *,
                 etc: Union[str, "os.PathLike[str]", None] = None) -> Path:
    """The profile to use: ``board`` if given, else ``<etc>/board.yaml`` if it exists, else the default.

    ``etc`` defaults to :func:`etc_dir`. Only stats files; :func:`load_profile`
    reads and checks the one returned (a ``board`` that does not exist is
    reported there, with this search order).
    """
    if board is not None and str(board) != "":
        return Path(board)
    machine = Path(etc if etc is not None else etc_dir()) / BOARD_FILE
    return machine if machine.exists() else DEFAULT_PROFILE


def load_board_profile(board: Union[str, "os.PathLike[str]", None] = None, *,
                       etc: Union[str, "os.PathLike[str]", None] = None) -> BoardProfile:
    """:func:`load_profile` of :func:`find_profile`: what ``stereocam serve`` checks at start."""
    return load_profile(find_profile(board, etc=etc))


def profile_from_dict(data: Any, *, source: str = "<dict>") -> BoardProfile:
    """Validate an already parsed profile (a mapping as in the YAML file)."""
    v = _Validator(source)
    top = v.section(data, "")
    frame, i2c, sensors = v.section(top["frame"], "frame"), v.section(top["i2c"], "i2c"), \
        v.section(top["sensors"], "sensors")
    controls = v.section(top["controls"], "controls")

    name = v.text(top["name"], "name")
    overlay = v.text(top["overlay"], "overlay")
    if not overlay.endswith(".bit"):
        v.fail("overlay", f"{overlay!r} is not a bitstream file name (*.bit)")

    width = v.integer(frame["width"], "frame.width", 1, spec.ARRAY_WIDTH)
    height = v.integer(frame["height"], "frame.height", 1, spec.ARRAY_HEIGHT)
    pclk = v.integer(sensors["pixel_clock_hz"], "sensors.pixel_clock_hz", *PIXEL_CLOCK_RANGE)
    hblank = max(spec.HBLANK_DEFAULT, spec.MIN_ROW_TIME - width)  # as MT9V034.configure_window sets it
    row_us = spec.row_time_us(width, hblank, pclk)
    fps_lo = spec.frame_rate(height, spec.VBLANK_MAX, row_us)
    fps_hi = spec.frame_rate(height, spec.VBLANK_MIN, row_us)
    fps = v.number(frame["fps"], "frame.fps")
    if not fps_lo <= fps <= fps_hi:
        v.fail("frame.fps", f"{fps:g} is out of range: {fps_lo:.2f}..{fps_hi:.2f} "
                            f"for a {width}x{height} window at {pclk / 1e6:g} MHz")

    bus = v.integer(i2c["bus"], "i2c.bus", 0, 255)
    addresses = ", ".join(f"{a:#04x}" for a in spec.I2C_ADDRESSES)
    left = v.integer(i2c["left"], "i2c.left", 0, 0x7F)
    right = v.integer(i2c["right"], "i2c.right", 0, 0x7F)
    for key, addr in (("i2c.left", left), ("i2c.right", right)):
        if addr not in spec.I2C_ADDRESSES:
            v.fail(key, f"{addr:#04x} is not an address an MT9V034 can be strapped to ({addresses})")
    if left == right:
        v.fail("i2c.right", f"both sensors at {left:#04x}: they need different address straps")
    timeout = v.number(i2c["timeout_s"], "i2c.timeout_s")
    if not 0.01 <= timeout <= 10:
        v.fail("i2c.timeout_s", f"{timeout:g} s is out of range: 0.01..10")

    sync = v.text(sensors["sync"], "sensors.sync")
    if sync not in SYNC_MODES:
        v.fail("sensors.sync", f"{sync!r} is not one of: {', '.join(SYNC_MODES)}")
    master: Optional[str] = None
    if sync == "master-slave":
        if "master" not in sensors:
            v.fail("sensors.master",
                   "missing: with sync master-slave, say which sensor is master (left or right)")
        master = v.text(sensors["master"], "sensors.master")
        if master not in ("left", "right"):
            v.fail("sensors.master", f"{master!r} is not one of: left, right")
    elif "master" in sensors:
        v.fail("sensors.master", f"applies to sync master-slave only (sync is {sync}): remove it")
    target = v.integer(sensors["aec_target_bin"], "sensors.aec_target_bin", spec.DESIRED_BIN_MIN,
                       spec.DESIRED_BIN_MAX)

    try:
        defaults = SensorSettings.from_dict(controls)
    except ValueError as exc:
        v.fail("controls", str(exc))
    if defaults.exposure_us is not None:  # what the sensors take once set up with this window and rate
        exposures = spec.ExposureRange.at(width=width, hblank=hblank, height=height,
                                          vblank=spec.vertical_blanking_for(fps, height, row_us),
                                          pixel_clock_hz=pclk)
        try:
            exposures.rows_for(defaults.exposure_us)
        except ValueError as exc:
            v.fail("controls.exposure_us", str(exc))

    return BoardProfile(
        name=name, overlay=overlay, width=width, height=height, fps=fps, i2c_bus=bus, left_address=left,
        right_address=right, i2c_timeout=timeout, pixel_clock_hz=pclk, sync=sync, master=master,
        aec_target_bin=target, controls=dict(controls), source=source)


class _Validator:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, message: str) -> None:
        raise ProfileError(f"board profile {self.source}: {key or 'top level'}: {message}")

    def section(self, data: Any, path: str) -> Mapping[str, Any]:
        if not isinstance(data, Mapping):
            kind = "empty" if data is None else f"a {type(data).__name__}"
            self.fail(path, f"must be a mapping with keys {', '.join(_KEYS[path])}, but is {kind}")
        known = _KEYS[path]
        prefix = f"{path}." if path else ""
        unknown = [str(k) for k in data if k not in known]
        if unknown:
            self.fail(path, f"unknown key(s) {', '.join(prefix + k for k in unknown)} "
                            f"(known: {', '.join(known)})")
        missing = [k for k in known if k not in data and k not in _OPTIONAL.get(path, ())]
        if missing:
            self.fail(path, f"missing key(s) {', '.join(prefix + k for k in missing)}")
        return data

    def text(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value.strip():
            self.fail(key, f"must be a non-empty string, not {value!r}")
        return str(value)

    def integer(self, value: Any, key: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be a whole number in {lo}..{hi}, not {value!r}")
        if not lo <= value <= hi:
            self.fail(key, f"{value} is out of range: {lo}..{hi}")
        return int(value)

    def number(self, value: Any, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(key, f"must be a number, not {value!r}")
        return float(value)
