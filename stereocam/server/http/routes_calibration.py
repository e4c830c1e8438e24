"""The calibration API: ``GET /api/calibration`` and ``PUT /api/calibration``.

``setup(app)`` adds the routes (an extension, see :func:`.app.default_extensions`).

- ``GET`` answers what the core runs with: the id status and captures record,
  where it came from, the line-buffer figures, the model and rectification
  matrices and the stereocam calibration file's text.
- ``PUT`` takes the text of a stereocam calibration file and checks it
  completely on a worker thread (schema, finite values, register ranges,
  frame size = the fabric's, line-buffer fit against the core's ``LB_ROWS``)
  and prepares its registers and file text, before touching anything; a
  refused one leaves the core, the file and ``app[CALIBRATION]`` as they
  were. An accepted one is programmed into the core, then written atomically
  to the calibration file (:func:`calibration_path`), then becomes
  ``app[CALIBRATION]``: a new immutable :class:`.state.CalibrationState` swapped
  in with one assignment (the pipeline thread reads it for recorded frames).

Shutdown (SIGTERM) must end the daemon within 2 s, and checking a large file
takes seconds: the check changes nothing, so shutdown stops it
(:meth:`.state.Executors.run_abandonable`) and a PUT still checking then gets
503, with nothing changed. Programming the registers and writing the file is
short and is never cut: shutdown waits for a change in progress, so the files
hold one calibration, the previous or the new one.

:func:`load_configured` is how ``serve --calibration`` reads its argument
(:func:`.app.program_default_calibration`).
"""
from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Tuple

from aiohttp import web

from ...calibration.file import MAX_FILE_CHARS, Calibration, _sniff, load_calibration, parse_yaml
from ...calibration.formats import CalibrationFileError, atomic_write_text
from ...overlays.interface import DriverError
from ...overlays.model.core_params import CoreParamsError
from ...overlays.spec.rectify import DEFAULT_MAX_HEIGHT, DEFAULT_MAX_WIDTH, CoreConfig
from ..errors import ApiError
from .bodies import JSON, json_response, read_json
from .state import CALIBRATION, EXECUTORS, OVERLAY, SETTINGS, CalibrationState

log = logging.getLogger(__name__)

__all__ = ["setup", "load_configured", "calibration_path", "activate", "check_runnable", "CalibrationRefused",
           "ACTIVE", "ActiveCalibration", "Prepared", "CALIBRATION_FILE"]

CALIBRATION_FILE = "calibration.yaml"
STOP_WAIT_S = 1.0  # shutdown waits this long at most for a calibration change being programmed and written
STOPPING = "the daemon is stopping: the calibration was not applied; the previous calibration stays active"
YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml", "text/x-yaml", "text/plain",
              "application/octet-stream")
KINDS = {"stereocam": "calibration file", "matlab": "MATLAB stereoParameters",
         "opencv": "OpenCV stereo_calib files", "ros": "ROS camera_info files"}


class CalibrationRefused(ValueError):
    """A calibration that parses but that this core cannot run (HTTP 422)."""


@dataclass
class ActiveCalibration:
    """The :class:`Calibration` behind ``app[CALIBRATION]`` (None: none, or not a file's); where PUT writes.

    ``lock`` is held by a change from its check to its end; ``stopping`` is set when the daemon
    starts shutting down (no change starts after it).
    """

    path: Path
    calibration: Optional[Calibration] = None
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    stopping: asyncio.Event = field(default_factory=asyncio.Event)


@dataclass(frozen=True)
class Prepared:
    """A checked calibration ready to go live: its register set and the text of its file."""

    calibration: Calibration
    config: CoreConfig
    text: str


ACTIVE: "web.AppKey[ActiveCalibration]" = web.AppKey("stereocam.calibration.active", ActiveCalibration)


# -- loading ------------------------------------------------------------------------------------

def _limits(rectify: Any) -> Dict[str, int]:
    out = {}
    for name in ("max_width", "max_height"):
        value = getattr(rectify, name, None)
        if isinstance(value, int) and value > 0:
            out[name] = value
    return out


def load_configured(arg: str, rectify: Any, frame_size: Tuple[int, int]) -> Tuple[Calibration, str, str]:
    """Read ``--calibration`` (any format :func:`load_calibration` reads): ``(calibration, id, description)``.

    The id is the file's id for a stereocam calibration file, ``<kind>-<id>``
    for an imported one (``opencv-``, ``ros-``, ``matlab-``). Checks the frame
    size and the line-buffer fit against ``rectify``; raises the loader's
    errors (``ValueError`` subclasses with a message for the user).
    """
    paths = [Path(p).expanduser() for p in arg.split(",") if p]
    for p in paths:
        if not p.is_file():
            raise CalibrationFileError(f"{p}: no such file")
    limits = _limits(rectify)
    cal = load_calibration(paths, image_size=(int(frame_size[0]), int(frame_size[1])),
                           lb_rows=rectify.lb_rows,
                           max_width=limits.get("max_width", DEFAULT_MAX_WIDTH),
                           max_height=limits.get("max_height", DEFAULT_MAX_HEIGHT))
    kind = _sniff(paths[0]) if paths else "unknown"
    where = " and ".join(str(p) for p in paths)
    description = f"{KINDS.get(kind, kind)} {where}" + (f" ({cal.source})" if cal.source else "")
    return cal, (cal.id if kind == "stereocam" else f"{kind}-{cal.id}"), description


def calibration_path(config: Any) -> Path:
    """Where PUT writes: the ``--calibration`` file if it is a stereocam calibration file,
    else ``calibration.yaml`` in the state folder (``state_dir``, default ``<captures>/..``)."""
    arg = config.calibration
    if arg and "," not in arg:
        p = Path(arg).expanduser()
        try:
            if not p.is_file() or _sniff(p) == "stereocam":
                return p
        except OSError:
            pass
    return config.state_path / CALIBRATION_FILE


# -- the routes ---------------------------------------------------------------------------------

def _lists(obj: Any, names: Tuple[str, ...]) -> Dict[str, Any]:
    import numpy as np

    return {n: np.asarray(getattr(obj, n), dtype=np.float64).tolist() for n in names}


async def get_calibration(request: web.Request) -> web.Response:
    app = request.app
    active = app[ACTIVE]
    state, cal = app[CALIBRATION], active.calibration
    body: Dict[str, Any] = {
        **state.to_json(),
        "source": cal.source if cal is not None else None,
        "file_id": cal.id if cal is not None else None,
        "file": str(active.path),
        "image_size": list(cal.image_size) if cal is not None else None,
        "alpha": cal.alpha if cal is not None else None,
        "units": cal.units if cal is not None else None,
        "model": _lists(cal.model, ("K1", "D1", "K2", "D2", "R", "T")) if cal is not None else None,
        "rectification": _lists(cal.rect, ("R1", "R2", "P1", "P2", "Q")) if cal is not None else None,
        "yaml": cal.to_yaml() if cal is not None else None,
    }
    return json_response(body)


async def _body_text(request: web.Request) -> str:
    ctype = request.content_type.lower()
    if ctype == JSON:
        doc = await read_json(request, example='{"yaml": "<the calibration file text>"}')
        if not isinstance(doc, dict) or not isinstance(doc.get("yaml"), str) or set(doc) != {"yaml"}:
            raise ApiError('a JSON body must be {"yaml": "<the calibration file text>"}', status=400)
        text = doc["yaml"]
    elif ctype in YAML_TYPES:
        try:
            text = (await request.read()).decode("utf-8")
        except UnicodeDecodeError:
            raise ApiError("the calibration file is not UTF-8 text", status=400) from None
    else:
        raise ApiError("PUT /api/calibration takes the calibration file as application/yaml or text/plain, "
                       f'or JSON {{"yaml": "..."}}; got {ctype}', status=415)
    if not text.strip():
        raise ApiError("the body is empty: send the text of a stereocam calibration.yaml", status=400)
    return text


def check_runnable(cal: Calibration, rectify: Any, frame_size: Tuple[int, int]) -> Calibration:
    """``cal`` if this core can run it at ``frame_size`` (blocking), else :class:`CalibrationRefused`."""
    w, h = frame_size
    cw, ch = cal.image_size
    try:
        if (cw, ch) != (w, h):
            raise CalibrationRefused(f"the calibration is for {cw}x{ch} images but the fabric's frames are "
                                     f"{w}x{h}: calibrate these cameras at this size")
        cal.check_fits(rectify.lb_rows)
        rectify.plan(cal.left, cal.right, w, h)
    except CoreParamsError as exc:
        raise CalibrationRefused(str(exc)) from None
    return cal


def _check(text: str, rectify: Any, frame_size: Tuple[int, int]) -> Calibration:
    """Parse and validate completely (blocking): CalibrationFileError (400) or CalibrationRefused (422)."""
    cal = parse_yaml(text, where="the calibration", derive_missing=True, **_limits(rectify))
    return check_runnable(cal, rectify, frame_size)


def previous_path(path: Path) -> Path:
    """Where the calibration file replaced by the last PUT/apply is kept: ``calibration.previous.yaml``."""
    return path.with_name(f"{path.stem}.previous{path.suffix or '.yaml'}")


def _prepare(check: Callable[[], Calibration], rectify: Any) -> Prepared:
    """Check (``check``), plan the registers, make the file's text (blocking, seconds for a large file).

    Changes nothing and takes no lock, so shutdown may stop it anywhere
    (:meth:`.state.Executors.run_abandonable`). Raises the check's errors, and
    :class:`CalibrationRefused` for a file this daemon could not read back at its next start.
    """
    cal = check()
    w, h = cal.image_size
    try:
        config, _ = rectify.plan(cal.left, cal.right, w, h)
    except CoreParamsError as exc:
        raise CalibrationRefused(str(exc)) from None
    text = cal.to_yaml()
    if len(text) > MAX_FILE_CHARS:
        limit = MAX_FILE_CHARS
        raise CalibrationRefused(f"its file would be {len(text):,} characters, more than the {limit:,} a "
                                 "calibration file may have: shorten its quality section")
    return Prepared(cal, config, text)


def _apply(rectify: Any, prepared: Prepared, path: Path) -> CoreConfig:
    """Program the core, then write the file (blocking; short: a ``work`` job shutdown waits for).

    Any failure (the core refusing the set or not latching it, a write failing) puts the
    previous registers back and leaves the files as they were. The file being replaced is
    kept as :func:`previous_path` (one level of undo: a calibration someone trusted is never
    lost to a click). Both writes are atomic (temporary file, then rename).
    """
    previous = rectify.read_config()
    try:
        rectify.load(prepared.config)
        if path.is_file():
            atomic_write_text(previous_path(path), path.read_text(encoding="utf-8"))
        atomic_write_text(path, prepared.text)
    except Exception as exc:
        try:
            rectify.load(previous)
        except Exception as undo:  # the error that started this is what the caller needs
            log.error("could not put the previous calibration's registers back: %s", undo)
        if isinstance(exc, CalibrationFileError):  # atomic_write_text: "cannot write PATH: why"
            raise OSError(f"{exc}; the previous calibration stays active") from None
        if isinstance(exc, OSError):
            raise OSError(f"cannot write {path} ({exc.strerror or exc}); the previous calibration stays "
                          "active") from None
        raise
    return prepared.config


def _refuse_if_stopping(active: ActiveCalibration) -> None:
    if active.stopping.is_set():
        raise ApiError(STOPPING, status=503)


async def _unless_stopping(active: ActiveCalibration, job: "asyncio.Future[Prepared]") -> Prepared:
    """``job``'s result, or 503 as soon as the daemon starts stopping (``job`` abandoned or cancelled)."""
    stopping: "asyncio.Future[Any]" = asyncio.ensure_future(active.stopping.wait())
    try:
        done, _ = await asyncio.wait([job, stopping], return_when=asyncio.FIRST_COMPLETED)
    except BaseException:  # the request itself is cancelled
        job.cancel()
        raise
    finally:
        stopping.cancel()
    if job not in done or job.cancelled():  # cancelled: Executors.abandon(), the daemon is stopping
        job.cancel()
        raise ApiError(STOPPING, status=503)
    return job.result()


async def activate(app: web.Application, check: Callable[[], Calibration], how: str) -> Dict[str, Any]:
    """Validate with ``check``, then program the core and write the file.

    ``check`` blocks and runs on a thread shutdown may abandon: it must change
    nothing (parse, validate, plan). ``how`` says where the calibration came
    from (the log and ``/api/status`` show it). Raises :class:`ApiError`: 400
    for a file that does not parse, 422 for one this core cannot run, 500 when
    the core or the file cannot take it, 503 when the daemon starts stopping
    before the change begins; in every case the previous calibration,
    registers and file stay. Returns the reply's body.
    """
    overlay = app[OVERLAY]
    rectify = overlay.rectify
    active = app[ACTIVE]
    executors = app[EXECUTORS]
    async with active.lock:
        _refuse_if_stopping(active)
        log.info("calibration check started (%s)", how)
        try:
            job = asyncio.ensure_future(executors.run_abandonable(_prepare, check, rectify))
            prepared = await _unless_stopping(active, job)
        except CalibrationRefused as exc:
            raise ApiError(f"refused, the previous calibration stays active: {exc}", status=422) from None
        except ValueError as exc:
            raise ApiError(f"refused, the previous calibration stays active: {exc}", status=400) from None
        _refuse_if_stopping(active)
        cal = prepared.calibration
        in_effect = app[CALIBRATION]
        before = int(await executors.run(overlay.frame_count))
        changing = in_effect.now.changing_from_count(before)
        in_effect.swap(changing)  # later frames may carry either set
        try:
            core_config = await executors.run(_apply, rectify, prepared, active.path)
            latched = await executors.run(overlay.frame_count)
        except BaseException as exc:
            in_effect.swap(changing.unchanged())  # _apply put the previous registers back
            if isinstance(exc, (OSError, CoreParamsError, DriverError)):
                raise ApiError(str(exc), status=500) from None
            raise
        description = f"calibration file {active.path} ({how}" + (f"; {cal.source})" if cal.source else ")")
        new = CalibrationState(id=cal.id, description=description, rows_needed=cal.rows_needed,
                               lb_rows=rectify.lb_rows, lb_delay=core_config.lb_delay, calibration=cal)
        in_effect.swap(changing.succeeded_by(new, before, (int(latched) + 2) % (1 << 32)))
        active.calibration = cal
    log.info("calibration %s programmed (%s) and written to %s (line buffer %d of %d rows)",
             cal.id, how, active.path, cal.rows_needed, rectify.lb_rows)
    return {**new.to_json(), "file": str(active.path), "summary": cal.summary()}


async def put_calibration(request: web.Request) -> web.Response:
    app = request.app
    text = await _body_text(request)
    overlay = app[OVERLAY]
    rectify, frame_size = overlay.rectify, overlay.frame_size
    body = await activate(app, lambda: _check(text, rectify, frame_size), "PUT /api/calibration")
    return json_response(body)


async def _stop_changes(app: web.Application) -> None:
    """Shutdown, before aiohttp waits for handlers: checks end in 503, a change in progress ends first."""
    active = app[ACTIVE]
    active.stopping.set()
    try:
        await asyncio.wait_for(active.lock.acquire(), STOP_WAIT_S)
    except asyncio.TimeoutError:
        log.warning("stopping while a calibration change has run for more than %.1f s: the previous or the "
                    "new calibration file stays, whichever its atomic write left", STOP_WAIT_S)
    else:
        active.lock.release()


def setup(app: web.Application) -> None:
    app[ACTIVE] = ActiveCalibration(path=calibration_path(app[SETTINGS]),
                                    calibration=app[CALIBRATION].now.calibration)
    app.on_shutdown.append(_stop_changes)
    app.router.add_get("/api/calibration", get_calibration)
    app.router.add_put("/api/calibration", put_calibration)
