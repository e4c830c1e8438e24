"""Opening an overlay: the one place that chooses the fabric, its cameras and its rectify core, and brings up
the image sensors.

``auto`` takes pynq when it is importable *and* the bitstream is present,
otherwise the emulated fabric, and :attr:`Choice.reason` says why (the
daemon logs it), so nobody wonders which one they are looking at. On a board
(pynq importable) without the bitstream the choice carries a :attr:`Choice.warning`
(logged as a warning, shown by ``/api/status`` and the page) and ``board``, so the
daemon keeps to the board's CPU budget. The
daemon holds what :func:`open_overlay` returns as an :class:`~.interface.Overlay`
and never imports a backend itself: the emulated cameras, the RTL core, the
sensors' bus and recorded frames all come from here.
"""
from __future__ import annotations

import difflib
import importlib.util
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, Union

from .interface import BackendError, Choice, Overlay, Replay
from .spec.overlay import BITSTREAM
from .spec.rectify import BUILDS, DEFAULT_BUILD, Build

if TYPE_CHECKING:  # pragma: no cover
    from ..board.profile import BoardProfile
    from ..drivers.i2c import I2CBus
    from .emulated.cameras import CameraSource
    from .emulated.logic import StreamCore

log = logging.getLogger(__name__)

__all__ = ["BACKENDS", "SCENES", "CORES", "RTL_TIMEOUT_S", "BackendError", "SourceError", "Choice", "choose",
           "no_bitstream_warning", "find_bitstream", "open_overlay", "camera_source", "open_rtl_core",
           "sensor_bus", "open_replay"]

BACKENDS = ("auto", "pynq", "emulated")
SCENES = ("synthetic", "checkerboard")  # the emulated cameras' built-in scenes; anything else is a folder
CORES = ("model", "rtl")  # what computes the emulated fabric's rectify core
RTL_TIMEOUT_S = 30.0  # driver waits with the RTL core: a frame of simulation takes a large part of a second
DEFAULT_BITSTREAM_DIRS = (Path(__file__).parent, Path("/usr/local/share/stereocam"))
#: What the machine is, as Linux lists it: a Zynq-7000 names ZYNQ_COMPATIBLE there. pynq alone does not
#: make a board (it installs on a PC too); STEREOCAM_DEVICE_TREE names another file (the tests' stand-in).
DEVICE_TREE_COMPATIBLE = Path("/proc/device-tree/compatible")
ZYNQ_COMPATIBLE = b"xlnx,zynq-7000"


def on_zynq() -> bool:
    """Whether this machine is a Zynq-7000 (its device tree says so)."""
    path = Path(os.environ.get("STEREOCAM_DEVICE_TREE") or DEVICE_TREE_COMPATIBLE)
    try:
        return ZYNQ_COMPATIBLE in path.read_bytes()
    except OSError:
        return False


class SourceError(ValueError):
    """Recorded frames that cannot be read back (a folder that is not a recording, a damaged one)."""


def find_bitstream(explicit: Optional[Path] = None) -> Optional[Path]:
    if explicit is not None:
        return explicit if explicit.is_file() else None
    env = os.environ.get("STEREOCAM_BITSTREAM")
    candidates = [Path(env)] if env else [d / BITSTREAM for d in DEFAULT_BITSTREAM_DIRS]
    return next((p for p in candidates if p.is_file()), None)


def choose(backend: str = "auto", *, bitstream: Optional[Path] = None) -> Choice:
    """Decide which fabric to use, without touching any hardware."""
    if backend not in BACKENDS:
        raise BackendError(f"--backend must be one of {', '.join(BACKENDS)}, not {backend!r}")
    if backend == "emulated":
        return Choice("emulated", "--backend emulated was asked for")
    has_pynq = importlib.util.find_spec("pynq") is not None
    bit = find_bitstream(bitstream)
    where = str(bitstream) if bitstream else \
        f"$STEREOCAM_BITSTREAM or {' or '.join(str(d / BITSTREAM) for d in DEFAULT_BITSTREAM_DIRS)}"
    if backend == "pynq":
        if not has_pynq:
            raise BackendError("--backend pynq: the pynq package is not installed "
                               "(run on the board's PYNQ image)")
        if bit is None:
            raise BackendError(f"--backend pynq: no bitstream found at {where}")
        return Choice("pynq", "--backend pynq was asked for", bit)
    if not has_pynq:
        return Choice("emulated", "pynq is not installed, so this is not a board")
    if bit is None and not on_zynq():
        return Choice("emulated", f"pynq is installed but no bitstream was found at {where}, and this is "
                                  f"not a Zynq ({DEVICE_TREE_COMPATIBLE} does not name it)")
    if bit is None:
        return Choice("emulated", f"pynq is installed but no bitstream was found at {where}", board=True,
                      warning=no_bitstream_warning(where))
    return Choice("pynq", f"pynq is installed and the bitstream is at {bit}", bit, board=True)


def no_bitstream_warning(where: str) -> str:
    """What ``auto`` on a board without the overlay's bitstream says: what runs instead, and what to do."""
    return (f"no bitstream: this is a board (a Zynq with pynq) but {BITSTREAM} is not at {where}, so the "
            "daemon runs the EMULATED fabric (synthetic cameras, not the board's) within the board's CPU "
            f"budget. Build {BITSTREAM} and {BITSTREAM.replace('.bit', '.hwh')} with Vivado "
            "(stereocam/overlays/vivado/README.md) and put them there (or give --bitstream FILE), or "
            "start with --backend emulated if emulation is what you want (this warning then goes)")


def open_overlay(backend: str = "auto", *, bitstream: Optional[Path] = None, source: Optional[str] = None,
                 fps: float = 60.0, clock: str = "realtime", build: Union[str, Build] = DEFAULT_BUILD,
                 lb_rows: Optional[int] = None, core: str = "model",
                 rtl_dir: Optional[str] = None, stereo: bool = True) -> Overlay:
    """The overlay for these settings (``stereocam serve``'s), not started; raises :class:`BackendError`.

    ``source`` (the emulated cameras, :func:`camera_source`), ``fps``, ``clock``, ``build`` (a
    :data:`~.spec.rectify.BUILDS` name or a build), ``lb_rows`` and ``core`` (``model`` or
    ``rtl``: the core's RTL under Verilator, from ``rtl_dir`` or the packaged copy) apply to
    the emulated fabric only; ``core="rtl"`` always takes it, and refuses ``backend="pynq"``.
    ``stereo`` False gives the emulated fabric no stereo core (the board's bitstream says for itself).
    """
    if core not in CORES:
        raise BackendError(f"--core must be one of {', '.join(CORES)}, not {core!r}")
    the_build = BUILDS[build] if isinstance(build, str) else build
    rtl: Optional[StreamCore] = None
    if core == "rtl":
        if backend == "pynq":
            raise BackendError("--core rtl simulates the core's RTL on the emulated fabric; the pynq backend "
                               "runs the board's own core: use --backend emulated (or auto) with --core rtl")
        choice = Choice("emulated", "--core rtl: the rectify core is its RTL under Verilator")
        rtl = open_rtl_core(the_build, rtl_dir)
    else:
        choice = choose(backend, bitstream=bitstream)
    overlay: Overlay
    cameras: Optional[CameraSource] = None
    try:
        if choice.backend == "pynq":
            log.info("fabric backend: %s (%s)", choice.backend, choice.reason)
            from .pynq.overlay import StereocamOverlay

            assert choice.bitstream is not None
            overlay = StereocamOverlay(choice.bitstream)
        else:
            cameras = camera_source(source)  # a source that cannot be read stops the start before the log
            log.info("fabric backend: %s (%s)", choice.backend, choice.reason)
            if choice.warning:
                log.warning("%s", choice.warning)
            from .emulated.overlay import EmulatedOverlay

            overlay = EmulatedOverlay(source=cameras, fps=fps, clock=clock, build=the_build,
                                      lb_rows=lb_rows, core=rtl, core_kind=core, stereo=stereo,
                                      timeout=RTL_TIMEOUT_S if rtl is not None else 1.0)
    except BaseException:
        if cameras is not None:
            cameras.close()
        if rtl is not None:
            close = getattr(rtl, "close", None)
            if close is not None:
                close()
        raise
    overlay.choice = choice
    return overlay


def camera_source(source: Optional[str]) -> Optional[CameraSource]:
    """The emulated cameras ``source`` names: a scene of :data:`SCENES` or a folder of recorded pairs.

    None and ``synthetic`` give None (the fabric's default synthetic rig); ``checkerboard``
    the rig with a 9x6 board (25 mm squares) held in a new pose every 1.5 s. Raises
    :class:`BackendError` for a folder that cannot be replayed, suggesting a scene name.
    """
    if source is None or source == "synthetic":
        return None
    if source == "checkerboard":
        from .emulated.targets import CheckerboardTarget

        return CheckerboardTarget()
    from .emulated.replay import ReplayError, ReplaySource

    try:
        return ReplaySource(Path(source).expanduser())
    except ReplayError as exc:
        close = difflib.get_close_matches(source, SCENES, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise BackendError(f"--source {source!r}: {hint}give {' or '.join(SCENES)}, or a folder of "
                           f"recorded pairs ({exc})") from None


def open_rtl_core(build: Build, rtl_dir: Optional[str] = None) -> StreamCore:
    """The rectify core's RTL (or the copy in ``rtl_dir``) compiled for ``build``; BackendError if not."""
    from .rtl.core import RtlCore, RtlError, rtl_sources
    from .rtl.toolchain import ToolMissing

    sources = None
    if rtl_dir is not None:
        folder = Path(rtl_dir).expanduser()
        sources = sorted([*folder.glob("*.v"), *folder.glob("*.vh")])
        if not (folder / "rectify_core.v").is_file():
            raise BackendError(f"--rtl-dir {folder}: no rectify_core.v there; "
                               "give a copy of stereocam/overlays/rtl")
    where = rtl_dir or str(rtl_sources()[0].parent)
    log.info("rectify core: the RTL in %s under Verilator (%s build; the first build takes about a minute, "
             "then it is cached)", where, build.name)
    try:
        return RtlCore(build, sources=sources)
    except ToolMissing as exc:
        raise BackendError(f"--core rtl: {exc}") from None
    except RtlError as exc:
        raise BackendError(f"--core rtl: the RTL in {where} did not build: {exc}") from None


def sensor_bus(overlay: Overlay, profile: BoardProfile, **pair_options: Any) -> I2CBus:
    """The I2C bus on which ``overlay``'s two image sensors answer, as ``profile`` describes them.

    On the board: its ``/dev/i2c-<n>`` (the caller closes it). Emulated: a new emulated pair
    (``pair_options``: chip ids, read noise) that drives the overlay's cameras every frame
    from now on (:attr:`~.interface.Overlay.sensors`). BackendError on any other overlay.
    """
    if overlay.backend == "pynq":
        from ..drivers.i2c import LinuxI2CBus

        return LinuxI2CBus(profile.i2c_bus, timeout=profile.i2c_timeout)
    from .emulated.overlay import EmulatedOverlay

    if isinstance(overlay, EmulatedOverlay):
        return overlay.attach_sensors(profile, **pair_options).bus
    raise BackendError(f"no camera sensors on the {overlay.backend!r} backend")


def open_replay(folder: Path, *, loop: bool = True) -> Replay:
    """The recorded frames in ``folder`` (a stereocam recording, captures or image pairs), read back.

    Raises :class:`SourceError` saying why they cannot be read. Blocks while the folder is listed.
    """
    from .emulated.replay import ReplayError, ReplaySource

    try:
        return ReplaySource(folder, loop=loop)
    except ReplayError as exc:
        raise SourceError(str(exc)) from None
