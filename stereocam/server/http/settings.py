"""The daemon's settings: one frozen :class:`Settings`, read from a YAML/JSON file and the command line.

A settings file holds a mapping whose keys are exactly the field names of
:class:`Settings` (a subset of them); an unknown key, a value of the wrong
type or out of range is a :class:`SettingsError` naming the file and the key,
with the closest known key when the name looks misspelt. Command-line options
override the file (:meth:`Settings.load`). Nothing here touches the network,
the fabric or the disk beyond reading the one file.
"""
from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple

from ...overlays.backend import BACKENDS, CORES
from ...overlays.spec.rectify import BUILDS

__all__ = ["Settings", "SettingsError", "BACKENDS", "CORES", "DEFAULT_CAPTURES", "LOG_LEVELS", "MAX_FPS"]

LOG_LEVELS = ("debug", "info", "warning", "error")  # debug adds every HTTP request (aiohttp's access log)
MAX_FPS = 120.0
DEFAULT_CAPTURES = "~/.local/share/stereocam/captures"


class SettingsError(ValueError):
    """A configuration that cannot be used; the message names the file (if any) and the key."""


@dataclass(frozen=True, kw_only=True)
class Settings:
    """Every setting of ``stereocam serve``; construct with keywords only (all have defaults).

    Network: ``host``/``port`` (the board's service listens on 0.0.0.0).
    Fabric: ``backend`` (auto|pynq|emulated), ``bitstream`` (pynq), ``source``
    (emulated cameras: ``synthetic``, the synthetic rig's scene;
    ``checkerboard``, that scene with a 9x6 board of 25 mm squares held in
    front in a new random pose every 1.5 s, for trying calibration; or a
    folder of recorded pairs to replay), ``fps`` (emulated camera rate), ``core_build``
    (the rectify core's build the emulated fabric has: ``colour`` or ``gray``), ``stereo_core``
    (the emulated fabric has the stereo core, as a ``depth`` bitstream does; false: it has none,
    as today's bitstream, and the disparity falls back to the ARM; unset: it has one where the
    core's model runs compiled (numba: ``pip install stereocam[fast]``), as its numpy path takes
    seconds a 752x480 frame), ``core`` (what
    computes the emulated fabric's rectify core: ``model``, the numpy model, or ``rtl``, the
    core's Verilog compiled with Verilator; ``rtl_dir`` builds another copy of the RTL), ``calibration``
    (``intrinsics.yml,extrinsics.yml``; default: the synthetic rig's known
    calibration on the emulated fabric). Storage: ``captures`` folder,
    ``min_free_mb`` kept free on its disk, ``state_dir`` (where the page's
    ``calibration.yaml`` and ``calibration-pairs/`` live; default: the
    captures folder's parent). Streams: ``max_streams``
    (MJPEG + WebSocket clients; more get 503), ``stream_timeout_s`` (a
    client whose frame write takes longer is dropped), ``default_fps`` /
    ``default_quality`` (when the query gives none), ``disparity_fps`` (the disparity and depth
    views' rate at most; unset: 10, and 1 where the ARM computes it within the board's budget),
    ``arm_disparity`` (where the bitstream has no stereo core, the ARM's StereoBM: ``full`` size,
    ``half`` size, an eighth of the work, or ``auto``: half within the board's budget, full elsewhere),
    ``no_signal_s`` (no frame for that long shows the no-signal frame),
    ``encode_threads``, ``cpu_budget`` (cores the daemon may spend on the views; unset: 1 core on the
    board, the whole machine off it; see ``cpu_budget.py``).
    Tests: ``allow_fault_injection`` (the ``--allow-fault-injection``
    flag of ``serve``, emulated fabric only: ``/api/faults`` injects faults). Safety:
    ``access_token`` (when set, every state-changing request needs it, and with
    ``protect: all``, the default, every stream, snapshot, capture and status read too; ``protect: control``
    leaves reads open), ``allowed_hosts`` (names besides loopback, the
    listening host and, on 0.0.0.0, the machine's own, that a request's Host
    may carry: the DNS-rebinding guard), ``max_upload_bytes``. Connections (see
    :mod:`.connections`): ``header_timeout_s`` (a request's line and headers must arrive
    within it, counted from its first byte or from the connection's opening, and a body may not
    stall for longer), ``keepalive_timeout_s`` (an idle connection between requests is closed
    after it), ``max_connections`` (open at once; lowered to stay below the fd limit: the oldest
    idle ones are shed first). Board: ``board`` (the board
    profile's file; default ``/etc/stereocam/board.yaml`` if it exists, else the packaged
    one: see :func:`stereocam.board.profile.find_profile`). Logs: ``log_level`` (one of
    :data:`LOG_LEVELS`; ``debug`` also logs every HTTP request).
    """

    host: str = "127.0.0.1"
    port: int = 8080
    backend: str = "auto"
    bitstream: Optional[str] = None
    source: str = "synthetic"
    fps: float = 60.0
    core_build: str = "colour"
    stereo_core: Optional[bool] = None
    core: str = "model"
    rtl_dir: Optional[str] = None
    calibration: Optional[str] = None
    captures: str = DEFAULT_CAPTURES
    state_dir: Optional[str] = None
    min_free_mb: float = 64.0
    max_streams: int = 32
    stream_timeout_s: float = 10.0
    default_fps: float = 60.0
    default_quality: int = 80
    disparity_fps: Optional[float] = None
    arm_disparity: str = "auto"
    no_signal_s: float = 0.5
    encode_threads: int = 2
    cpu_budget: Optional[float] = None
    access_token: Optional[str] = None
    protect: str = "all"
    allowed_hosts: Tuple[str, ...] = ()
    max_upload_bytes: int = 16 * 1024 * 1024
    header_timeout_s: float = 10.0
    keepalive_timeout_s: float = 60.0
    max_connections: int = 256
    board: Optional[str] = None
    log_level: str = "info"
    allow_fault_injection: bool = False  # the --allow-fault-injection flag only: never from a file
    extra: Mapping[str, Any] = field(default_factory=dict)  # the extensions' own sections

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _check(None, f.name, getattr(self, f.name)))
        if self.rtl_dir is not None and self.core != "rtl":  # else it would be ignored without a word
            raise SettingsError(f"rtl_dir {self.rtl_dir!r} is for the RTL core: set core to rtl "
                                "(--core rtl) as well, or leave rtl_dir out")

    @property
    def frame_wait_s(self) -> float:
        """How long a request waits for a fresh frame before answering "no signal" (503).

        Twice ``no_signal_s``, so a frame late enough to show the no-signal
        frame is still waited for, and at least a second.
        """
        return max(1.0, 2 * self.no_signal_s)

    # -- building -----------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, origin: Optional[str] = None) -> "Settings":
        """A config from a mapping of field names; ``origin`` (a file name) prefixes every message."""
        if not isinstance(data, Mapping):
            raise SettingsError(f"{_where(origin)}the configuration must be a mapping of settings, "
                              f"got {type(data).__name__}")
        known = [f.name for f in fields(cls) if f.name not in FLAG_ONLY]
        for key in data:
            if key in FLAG_ONLY:
                flag = "--" + key.replace("_", "-")
                raise SettingsError(f"{_where(origin)}{key} cannot be set in a settings file: it lets any "
                                  f"client break the fabric, so only the {flag} flag sets it")
            if not isinstance(key, str) or key not in known:
                hint = difflib.get_close_matches(str(key), known, n=1)
                suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise SettingsError(f"{_where(origin)}unknown key {key!r}{suggestion}; "
                                  f"known keys: {', '.join(known)}")
        values = dict(data)
        for key, value in values.items():
            values[key] = _check(origin, key, value)
        try:
            return cls(**values)
        except SettingsError as exc:  # pragma: no cover - _check already ran
            raise SettingsError(f"{_where(origin)}{exc}") from None

    @classmethod
    def from_file(cls, path: "str | Path") -> "Settings":
        """Read a ``.json`` file as JSON and anything else as YAML (which JSON also is)."""
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise SettingsError(f"{p}: no such file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise SettingsError(f"{p}: cannot read it ({getattr(exc, 'strerror', None) or exc})") from None
        if p.suffix.lower() == ".json":
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SettingsError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
        else:
            from ...calibration.safe_yaml import YamlRefused, load

            try:
                data = load(text)
            except YamlRefused as exc:
                raise SettingsError(f"{p}: {exc}") from None
        if data is None:
            data = {}
        return cls.from_mapping(data, origin=str(p))

    @classmethod
    def load(cls, path: "str | Path | None" = None, **overrides: Any) -> "Settings":
        """The file's settings (if ``path``), then every override that is not None."""
        base = cls.from_file(path) if path is not None else cls()
        given = {k: v for k, v in overrides.items() if v is not None}
        return base.replace(**given)

    def replace(self, **changes: Any) -> "Settings":
        known = {f.name for f in fields(self)}
        for key in changes:
            if key not in known:
                raise SettingsError(f"unknown setting {key!r}")
        return dataclasses.replace(self, **{k: _check(None, k, v) for k, v in changes.items()})

    # -- derived ------------------------------------------------------------------------
    @property
    def captures_path(self) -> Path:
        return Path(self.captures).expanduser()

    @property
    def state_path(self) -> Path:
        """``state_dir``, or the captures folder's parent (``~/.local/share/stereocam`` by default)."""
        return Path(self.state_dir).expanduser() if self.state_dir else self.captures_path.parent

    def public(self) -> Dict[str, Any]:
        """The settings as JSON, without the access token."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("access_token", "extra")}
        out["access_token"] = "set" if self.access_token else None
        return out


# -- validation -----------------------------------------------------------------------------

def _where(origin: Optional[str]) -> str:
    return f"{origin}: " if origin else ""


def _number(origin: Optional[str], key: str, value: Any, lo: float, hi: float, *, integer: bool,
            lo_open: bool = False) -> Any:
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type:
        kind = "a whole number" if integer else "a number"
        raise SettingsError(f"{_where(origin)}{key} must be {kind}, got {value!r}")
    if not math.isfinite(float(value)) or value > hi or value < lo or (lo_open and value == lo):
        lower = f"> {lo:g}" if lo_open else f">= {lo:g}"
        raise SettingsError(f"{_where(origin)}{key} must be {lower} and <= {hi:g}, got {value!r}")
    return int(value) if integer else float(value)


def _text(origin: Optional[str], key: str, value: Any, *, optional: bool) -> Optional[str]:
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value.strip():
        kind = "a non-empty string" + (" or null" if optional else "")
        raise SettingsError(f"{_where(origin)}{key} must be {kind}, got {value!r}")
    return value


_RANGES: Dict[str, Tuple[float, float, bool, bool]] = {
    # key: (low, high, integer, low is open)
    "port": (0, 65535, True, False),  # 0: any free port (tests)
    "fps": (0, 1000, False, True),
    "min_free_mb": (0, 1e7, False, False),
    "max_streams": (1, 10000, True, False),
    "stream_timeout_s": (0, 3600, False, True),
    "default_fps": (0, MAX_FPS, False, True),
    "default_quality": (1, 100, True, False),
    "disparity_fps": (0, MAX_FPS, False, True),
    "no_signal_s": (0.05, 60, False, False),
    "encode_threads": (1, 64, True, False),
    "cpu_budget": (0.05, 1024, False, False),
    "max_upload_bytes": (1024, 1 << 31, True, False),
    "header_timeout_s": (0, 3600, False, True),
    "keepalive_timeout_s": (0, 86400, False, True),
    "max_connections": (4, 65536, True, False),
}


FLAG_ONLY = ("allow_fault_injection",)
ARM_DISPARITY = ("auto", "full", "half")


def _check(origin: Optional[str], key: str, value: Any) -> Any:
    """``value`` if valid for ``key`` (ints widened to float where a float is wanted), else SettingsError."""
    if key in ("cpu_budget", "disparity_fps") and value is None:
        return None  # unset: chosen by where the daemon runs (app.py)
    if key == "arm_disparity":
        if value not in ARM_DISPARITY:
            raise SettingsError(f"{_where(origin)}arm_disparity must be one of {', '.join(ARM_DISPARITY)}, "
                                f"got {value!r}")
        return value
    if key in _RANGES:
        lo, hi, integer, lo_open = _RANGES[key]
        return _number(origin, key, value, lo, hi, integer=integer, lo_open=lo_open)
    if key == "backend":
        if value not in BACKENDS:
            raise SettingsError(f"{_where(origin)}backend must be one of {', '.join(BACKENDS)}, "
                                f"got {value!r}")
        return value
    if key == "core_build":
        if not isinstance(value, str) or value not in BUILDS:  # BUILDS is a dict: a list is unhashable
            raise SettingsError(f"{_where(origin)}core_build must be one of {', '.join(BUILDS)}, "
                                f"got {value!r}")
        return value
    if key == "core":
        if value not in CORES:
            raise SettingsError(f"{_where(origin)}core must be one of {', '.join(CORES)}, got {value!r}")
        return value
    if key in ("host", "source", "captures"):
        return _text(origin, key, value, optional=False)
    if key == "log_level":
        level = value.strip().lower() if isinstance(value, str) else value
        if level not in LOG_LEVELS:
            raise SettingsError(f"{_where(origin)}log_level must be one of {', '.join(LOG_LEVELS)}, "
                              f"got {value!r}")
        return level
    if key in ("bitstream", "calibration", "state_dir", "rtl_dir", "board"):
        return _text(origin, key, value, optional=True)
    if key == "access_token":
        token = _text(origin, key, value, optional=True)
        if token is not None and (len(token) < 8 or any(c.isspace() for c in token)):
            raise SettingsError(f"{_where(origin)}access_token must be at least 8 characters without spaces")
        return token
    if key == "protect":
        if value not in ("all", "control"):
            raise SettingsError(f"{_where(origin)}protect must be all or control, got {value!r}")
        return value
    if key == "allowed_hosts":
        if isinstance(value, str):
            value = [value]

        def name_ok(v: Any) -> bool:
            text = v.strip() if isinstance(v, str) else ""
            return bool(text) and not any(c.isspace() or c in "/:@" for c in text)

        if not isinstance(value, (list, tuple)) or not all(name_ok(v) for v in value):
            raise SettingsError(f"{_where(origin)}allowed_hosts must be a list of host names "
                              f"(no ports or spaces), got {value!r}")
        return tuple(v.strip().lower() for v in value)
    if key == "stereo_core" and value is None:
        return None  # unset: where the core's model keeps up (open_configured_overlay)
    if key in ("allow_fault_injection", "stereo_core"):
        if not isinstance(value, bool):
            raise SettingsError(f"{_where(origin)}{key} must be true or false, got {value!r}")
        return value
    if key == "extra":
        if not isinstance(value, Mapping):
            raise SettingsError(f"{_where(origin)}extra must be a mapping of extension sections, "
                                f"got {value!r}")
        return dict(value)
    raise SettingsError(f"{_where(origin)}unknown key {key!r}")  # pragma: no cover - guarded by callers
