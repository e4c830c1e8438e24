"""The daemon: :func:`create_app` wires the stages into an aiohttp application, :func:`run` serves it.

``create_app(config, overlay)`` takes an opened overlay (``.fabric``,
``start()``, ``stop()``) and returns a ``web.Application`` whose state is
in the ``web.AppKey``s of :mod:`.state`. Starting the app starts the
overlay's streams and the pipeline thread and the background tasks
(no-signal watch, slow-client sweeper, systemd watchdog); cleaning it up
stops them in reverse order, with the mux back on live. The overlay itself
(opening, closing) is the caller's.

``run(config)`` is ``stereocam serve``: open the overlay, program the
default calibration, serve until SIGTERM/SIGINT, then stop the streams, the
VDMA channels and the mux (live) and exit, all within 2 s.

Extensions (issue 4: calibration, issue 5: sensors) are callables
``setup(app)`` passed in ``extensions``: they add routes and register
providers in ``app[EXTENSIONS]`` (status sections, metrics lines, capture
metadata); :func:`default_extensions` lists the ones ``run`` installs.
"""
from __future__ import annotations

import asyncio
import gc
import hashlib
import logging
import signal
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, AsyncIterator, Awaitable, Callable, List, Optional, Sequence

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestPayloadError

from ..frames.captures import CaptureStore
from ..frames.cpu_budget import PLAN_PERIOD_S, CpuBudget, default_cores, single_threaded_opencv
from ..frames.encoders import Encoders, FrameFeed
from ..frames.fabric_health import FabricHealth
from ..frames.pipeline import Pipeline
from . import routes_faults
from .config import Config
from .metrics import Metrics
from .metrics import setup_routes as setup_ops_routes
from .routes_api import VirtualCamera
from .routes_api import setup_routes as setup_api_routes
from .security import allowed_host_names, guard
from .state import (
    BUDGET,
    CALIBRATION,
    CAPTURES,
    CONFIG,
    ENCODERS,
    EXECUTORS,
    EXTENSIONS,
    FABRIC_HEALTH,
    FEED,
    METRICS,
    OVERLAY,
    PIPELINE,
    STREAMS,
    VIRTUAL,
    CalibrationState,
    Executors,
    Extensions,
)
from .streams import StreamClients, json_error
from .streams import setup_routes as setup_stream_routes
from .systemd import notify, watchdog_interval

if TYPE_CHECKING:  # pragma: no cover
    from aiohttp.typedefs import Middleware

log = logging.getLogger(__name__)

__all__ = ["create_app", "run", "serve", "program_default_calibration", "default_extensions", "ServeError",
           "STATIC_DIR"]

STATIC_DIR = Path(__file__).resolve().parent / "static"
SOURCES = ("synthetic", "checkerboard")  # the emulated cameras' built-in scenes; anything else is a folder
RTL_NO_SIGNAL_S = 5.0  # no_signal_s at least this with the RTL core (it runs a few frames per second)
RTL_TIMEOUT_S = 30.0  # driver waits with the RTL core: a frame of simulation takes a large part of a second
Setup = Callable[[web.Application], None]
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class ServeError(Exception):
    """The daemon cannot start as configured (port taken, ...): one line for the user."""


def default_extensions() -> List[Setup]:
    """The extensions ``run`` installs (issues 4 and 5 add theirs here)."""
    from . import routes_calibration, routes_calibration_panel, routes_cameras

    return [routes_calibration.setup, routes_calibration_panel.setup, routes_cameras.setup]


# -- errors as JSON ---------------------------------------------------------------------------

def _message(exc: web.HTTPException, request: web.Request) -> str:
    text = exc.text or ""
    default = f"{exc.status}: {exc.reason}"
    if text and text != default:
        return text
    if exc.status == 404:
        return f"no such resource: {request.path}"
    if exc.status == 405:
        allowed = exc.headers.get("Allow", "")
        return f"{request.method} is not allowed on {request.path}" + (f"; use {allowed}" if allowed else "")
    if exc.status == 413:
        return (f"the request body is too large: the limit is {request.app[CONFIG].max_upload_bytes} bytes "
                "(max_upload_bytes)")
    return exc.reason


class _BadRequestLines(logging.Filter):
    """aiohttp logs a malformed request line or header with a traceback: make it one warning line."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, RequestPayloadError) and isinstance(exc.__cause__, HttpProcessingError):
            exc = exc.__cause__  # a body that does not decode, read again by aiohttp after our 400
        if isinstance(exc, HttpProcessingError):
            record.msg = "refused a malformed request (%s %s): %s"
            record.args = (exc.code, type(exc).__name__, str(exc.message).splitlines()[0][:200])
            record.exc_info = None
            record.exc_text = None
            record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


BAD_REQUEST_LINES = _BadRequestLines()


def _json_errors(metrics: Metrics) -> "Middleware":
    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            response = await handler(request)
        except web.HTTPException as exc:
            if exc.status < 400:
                raise
            metrics.request(exc.status)
            keep = {k: v for k, v in exc.headers.items() if k in ("WWW-Authenticate", "Allow", "Retry-After")}
            return json_error(exc.status, _message(exc, request), **keep)
        except (asyncio.CancelledError, ConnectionError):
            raise
        except HttpProcessingError as exc:  # a malformed body found while reading it (e.g. a part header)
            status = exc.code if 400 <= exc.code < 500 else 400
            metrics.request(status)
            return json_error(status, f"malformed request: {str(exc.message).splitlines()[0][:200]}")
        except Exception as exc:
            log.exception("%s %s failed", request.method, request.path)
            metrics.error(f"{request.method} {request.path}: {type(exc).__name__}: {exc}", "http")
            metrics.request(500)
            return json_error(500, f"internal error ({type(exc).__name__}: {exc}); see the daemon's log")
        metrics.request(response.status)
        return response

    return middleware


# -- the page ---------------------------------------------------------------------------------

async def _index(request: web.Request) -> web.StreamResponse:
    page = STATIC_DIR / "index.html"
    if not page.is_file():
        raise web.HTTPNotFound(text="the web page is not installed (server/http/static/index.html is missing); "
                                    "the API works: see /api/status")
    return web.FileResponse(page, headers={"Cache-Control": "no-cache"})


async def _static(request: web.Request) -> web.StreamResponse:
    root = STATIC_DIR.resolve()
    try:
        target = (root / request.match_info["path"]).resolve()
    except (OSError, ValueError):
        raise web.HTTPNotFound() from None
    if root not in target.parents or not target.is_file():
        raise web.HTTPNotFound()
    return web.FileResponse(target, headers={"Cache-Control": "no-cache"})


# -- the app ----------------------------------------------------------------------------------

def create_app(
    config: Config,
    overlay: Any,
    *,
    calibration: Optional[CalibrationState] = None,
    captures: Optional[CaptureStore] = None,
    extensions: Sequence[Setup] = (),
) -> web.Application:
    """The daemon's application for ``overlay`` (see the module doc); nothing runs until it starts."""
    if getattr(overlay, "core_kind", None) == "rtl" and config.no_signal_s < RTL_NO_SIGNAL_S:
        # A simulated core delivers a few frames per second: a frame 0.5 s old is not a lost signal.
        config = config.replace(no_signal_s=RTL_NO_SIGNAL_S)
    metrics = Metrics()
    app = web.Application(
        middlewares=[_json_errors(metrics),
                     guard(access_token=config.access_token, max_body=config.max_upload_bytes,
                           allowed_hosts=allowed_host_names(config.host, config.allowed_hosts),
                           protect=config.protect)],
        client_max_size=config.max_upload_bytes,
    )
    fabric = overlay.fabric
    cores = config.cpu_budget if config.cpu_budget is not None else default_cores(fabric.backend)
    emulation = tuple(getattr(overlay, "emulation_threads", ()))
    budget = CpuBudget(cores, excluded_threads=lambda: emulation)
    feed = FrameFeed(frame_size=tuple(fabric.frame_size), no_signal_s=config.no_signal_s)
    pipeline = Pipeline(fabric, publish=feed.push, alive=feed.alive, charge=budget.charge)
    executors = Executors.create(config.encode_threads)
    app[CONFIG] = config
    app[OVERLAY] = overlay
    app[METRICS] = metrics
    app[FEED] = feed
    app[PIPELINE] = pipeline
    app[EXECUTORS] = executors
    app[BUDGET] = budget
    app[ENCODERS] = encoders = Encoders(feed, pipeline, executors.encode, disparity_fps=config.disparity_fps,
                                        observe=metrics.observe_encode,
                                        on_error=lambda text: metrics.error(text, "encode"), budget=budget)
    pipeline.set_copy_rate(encoders.copy_rate)
    app[STREAMS] = StreamClients(max_streams=config.max_streams, timeout=config.stream_timeout_s)
    app[CAPTURES] = captures if captures is not None else CaptureStore(
        config.captures_path, min_free_bytes=int(config.min_free_mb * 1e6))
    rtl = getattr(overlay, "core_kind", None) == "rtl"
    app[VIRTUAL] = VirtualCamera(overlay, pipeline, feed, round_trip_timeout=RTL_TIMEOUT_S if rtl else 2.0)
    app[CALIBRATION] = calibration or CalibrationState(lb_rows=fabric.rectify.lb_rows)
    app[EXTENSIONS] = Extensions()
    health = FabricHealth(fabric, source=lambda: app[VIRTUAL].source, frame_age=feed.frame_age,
                          period=lambda: pipeline.period, no_signal_s=config.no_signal_s)
    app[FABRIC_HEALTH] = health
    pipeline.channel_ok = health.channel_ok
    app[VIRTUAL].mux_refused, app[VIRTUAL].mux_committed = health.mux_refused, health.mux_committed
    app[EXTENSIONS].faults.append(health.faults)
    app[EXTENSIONS].metrics.append(health.metrics)

    app.router.add_get("/", _index)
    app.router.add_get("/static/{path:.+}", _static)
    setup_stream_routes(app)
    setup_api_routes(app)
    setup_ops_routes(app)
    for setup in extensions:
        setup(app)

    app.cleanup_ctx.append(_executors_ctx)
    app.cleanup_ctx.append(_fabric_ctx)
    app.cleanup_ctx.append(_health_ctx)  # starts after the fabric streams, stops before it stops
    if config.allow_fault_injection:
        try:
            routes_faults.setup(app)
        except routes_faults.FaultInjectionUnavailable as exc:
            raise ServeError(str(exc)) from None
    app.on_shutdown.append(_close_streams)
    return app


async def _executors_ctx(app: web.Application) -> AsyncIterator[None]:
    yield
    app[EXECUTORS].shutdown()


async def _fabric_ctx(app: web.Application) -> AsyncIterator[None]:
    """Start: overlay streams, pipeline thread, background tasks. Cleanup: the reverse, mux to live."""
    loop = asyncio.get_running_loop()
    overlay, pipeline, feed, streams = app[OVERLAY], app[PIPELINE], app[FEED], app[STREAMS]
    feed.attach(loop)
    await loop.run_in_executor(app[EXECUTORS].work, overlay.start)
    pipeline.start()
    tasks = [loop.create_task(feed.watch(), name="stereocam-no-signal"),
             loop.create_task(_plan_budget(app), name="stereocam-cpu-budget"),
             loop.create_task(streams.sweep(), name="stereocam-sweeper"),
             loop.create_task(_give_back_memory(), name="stereocam-malloc-trim")]
    interval = watchdog_interval()
    if interval is not None:
        tasks.append(loop.create_task(_watchdog(pipeline, interval), name="stereocam-watchdog"))
    try:
        yield
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await app[ENCODERS].close()
        feed.close()
        await loop.run_in_executor(None, pipeline.stop)
        await loop.run_in_executor(None, overlay.stop)  # clock, then streams: mux back to live, VDMA stopped
        log.info("fabric stopped: mux on live, VDMA channels stopped")


async def _health_ctx(app: web.Application) -> AsyncIterator[None]:
    """FabricHealth's thread and its mux task, while the fabric streams."""
    health, loop = app[FABRIC_HEALTH], asyncio.get_running_loop()
    health.start()
    task = loop.create_task(health.watch_mux(app[VIRTUAL].lock, app[EXECUTORS].work), name="stereocam-mux")
    try:
        yield
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await loop.run_in_executor(None, health.stop)


async def _close_streams(app: web.Application) -> None:
    """Shutdown, before aiohttp waits for handlers: wake every stream so it ends, abort the stuck ones."""
    app[FEED].close()
    await app[ENCODERS].close()
    await app[STREAMS].close_all()


TRIM_S = 2.0


async def _give_back_memory() -> None:
    """Return freed heap to the system every :data:`TRIM_S` (glibc keeps it after large requests).

    Without it the daemon's resident memory stays tens of MB above its working set after a burst
    of big uploads: memory a 512 MB board needs back. A fixed mmap threshold would do it too, but
    doubles the CPU per frame. Nothing happens where the C library has no ``malloc_trim``.
    """
    import ctypes
    import ctypes.util

    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return
    loop = asyncio.get_running_loop()
    while True:
        await asyncio.sleep(TRIM_S)
        await loop.run_in_executor(None, trim, 0)  # a heap walk: off the loop (ctypes drops the GIL)


async def _plan_budget(app: web.Application) -> None:
    """Re-plan the views' frame rates within the CPU budget every :data:`PLAN_PERIOD_S` (cpu_budget.py)."""
    budget, encoders, pipeline = app[BUDGET], app[ENCODERS], app[PIPELINE]
    size = tuple(app[OVERLAY].fabric.frame_size)
    frame_bytes = size[0] * size[1] * 8
    with single_threaded_opencv():
        while True:
            demands = encoders.demands(pipeline.fabric_fps(), size)
            encoders.apply(budget.plan(demands, frame_bytes=frame_bytes))
            await asyncio.sleep(PLAN_PERIOD_S)


async def _watchdog(pipeline: Pipeline, interval: float) -> None:
    """Ping systemd's watchdog while the pipeline thread iterates (its heartbeat is recent)."""
    while True:
        await asyncio.sleep(interval / 3)
        if time.monotonic() - pipeline.heartbeat_at < interval / 2:
            notify("WATCHDOG=1")
        else:
            log.error("pipeline heartbeat is %.1f s old: not feeding the watchdog",
                      time.monotonic() - pipeline.heartbeat_at)


# -- calibration at start -------------------------------------------------------------------

def _calibration_id(prefix: str, left: Any, right: Any) -> str:
    digest = hashlib.sha256(repr((left.values(), right.values())).encode("utf-8")).hexdigest()[:12]
    return f"{prefix}-{digest}"


def program_default_calibration(overlay: Any, config: Config) -> CalibrationState:
    """Program the core before the streams start and say what it runs with (blocks).

    In order: ``config.calibration`` (a stereocam calibration.yaml or
    anything :func:`stereocam.calibration.file.load_calibration` reads; an
    error stops the start); else the file the page and ``PUT
    /api/calibration`` write (:func:`.routes_calibration.calibration_path`),
    if there is one (an unusable one is logged and skipped: the daemon still
    starts); else, on the emulated fabric with the synthetic rig, the rig's
    known calibration (the same as :func:`stereocam.bench.rectify.bench_calibration`
    at 752x480); else nothing: the core passes frames through. Raises the
    calibration loader's and the core's errors (``CalibrationFileError``,
    ``ConfigError``).
    """
    from ...calibration.file import Calibration
    from ...calibration.stereo import rectify as stereo_rectify
    from .routes_calibration import calibration_path, load_configured

    fabric = overlay.fabric
    w, h = fabric.frame_size
    rectify = fabric.rectify
    cal: Any = None
    if config.calibration:
        cal, state_id, description = load_configured(config.calibration, rectify, (w, h))
    else:
        saved = calibration_path(config)
        if saved.is_file():
            try:
                cal, state_id, description = load_configured(str(saved), rectify, (w, h))
                rectify.plan(cal.left, cal.right, w, h)  # what program() would refuse, refused here
            except (ValueError, OSError) as exc:
                log.error("the saved calibration %s cannot be used (%s): starting without it; fix or remove "
                          "the file, or apply a new calibration from the page", saved, exc)
                cal = None
    if cal is None:
        source = getattr(getattr(overlay, "hw", None), "source", None)
        rig_model = getattr(source, "model", None)
        if rig_model is None:
            log.warning("no calibration given: the rectify core passes frames through (give --calibration)")
            return CalibrationState(lb_rows=rectify.lb_rows)
        cal = Calibration.derive(rig_model, stereo_rectify(rig_model, alpha=0.0), alpha=0.0, units="m",
                                 source="the synthetic rig's known calibration (emulated fabric)")
        state_id = _calibration_id("synthetic-rig", cal.left, cal.right)
        description = "the synthetic rig's known calibration (emulated fabric)"
    core_config, fit = rectify.program(cal.left, cal.right, w, h)
    state = CalibrationState(id=state_id, description=description, rows_needed=fit.rows,
                             lb_rows=rectify.lb_rows, lb_delay=core_config.lb_delay, calibration=cal)
    log.info("calibration %s: %s (line buffer %d of %d rows)", state.id, description, fit.rows,
             rectify.lb_rows)
    return state


# -- serving --------------------------------------------------------------------------------

def _camera_source(config: Config) -> Any:
    if config.source == "synthetic":
        return None  # the emulated fabric's default SyntheticRig
    if config.source == "checkerboard":
        from ...overlays.emulated.targets import CheckerboardTarget

        return CheckerboardTarget()  # the rig with a 9x6 board (25 mm squares) held in a new pose every 1.5 s
    from ...overlays.emulated.cameras import ReplayError, ReplaySource

    try:
        return ReplaySource(Path(config.source).expanduser())
    except ReplayError as exc:
        import difflib

        close = difflib.get_close_matches(config.source, SOURCES, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ServeError(f"--source {config.source!r}: {hint}give {' or '.join(SOURCES)}, or a folder of "
                         f"recorded pairs ({exc})") from None


def open_rtl_core(build: Any, rtl_dir: Optional[str] = None) -> Any:
    """The rectify core's RTL (or the copy in ``rtl_dir``) compiled for ``build``; ServeError if it cannot be."""
    from ...overlays.rtl.core import RtlCore, RtlError, rtl_sources
    from ...overlays.rtl.toolchain import ToolMissing

    sources = None
    if rtl_dir is not None:
        folder = Path(rtl_dir).expanduser()
        sources = sorted([*folder.glob("*.v"), *folder.glob("*.vh")])
        if not (folder / "rectify_core.v").is_file():
            raise ServeError(f"--rtl-dir {folder}: no rectify_core.v there; give a copy of overlays/rtl")
    where = rtl_dir or str(rtl_sources()[0].parent)
    log.info("rectify core: the RTL in %s under Verilator (%s build; the first build takes about a minute, "
             "then it is cached)", where, build.name)
    try:
        return RtlCore(build, sources=sources)
    except ToolMissing as exc:
        raise ServeError(f"--core rtl: {exc}") from None
    except RtlError as exc:
        raise ServeError(f"--core rtl: the RTL in {where} did not build: {exc}") from None


def open_configured_overlay(config: Config) -> Any:
    from ...overlays.backend import open_overlay
    from ...overlays.spec.rectify import BUILDS

    bitstream = Path(config.bitstream).expanduser() if config.bitstream else None
    build = BUILDS[config.core_build]
    if config.core == "model":
        return open_overlay(config.backend, bitstream=bitstream, source=_camera_source(config), fps=config.fps,
                            clock="realtime", build=build)
    if config.backend == "pynq":
        raise ServeError("--core rtl simulates the core's RTL on the emulated fabric; the pynq backend runs "
                         "the board's own core: use --backend emulated (or auto) with --core rtl")
    from ...overlays.backend import Choice

    core = open_rtl_core(build, config.rtl_dir)
    try:
        overlay = open_overlay("emulated", source=_camera_source(config), fps=config.fps, clock="realtime",
                               build=build, core=core, core_kind="rtl", timeout=RTL_TIMEOUT_S)
    except BaseException:
        core.close()
        raise
    overlay.choice = Choice("emulated", "--core rtl: the rectify core is its RTL under Verilator")
    return overlay


async def serve(app: web.Application, config: Config, *, stop: Optional[asyncio.Event] = None,
                on_ready: Optional[Callable[[str], None]] = None, handle_signals: bool = True) -> None:
    """Serve ``app`` until ``stop`` is set (or SIGTERM/SIGINT, with ``handle_signals``), then clean up.

    ``on_ready(url)`` is called once the socket listens (``config.port`` 0
    picks a free port; the URL has the real one). Cleaning up stops the
    long checks first (:meth:`.state.Executors.abandon`: a calibration PUT's
    ends in 503), then aiohttp's shutdown (handlers get ``shutdown_timeout``)
    and the app's cleanup (streams, pipeline, fabric).
    """
    loop = asyncio.get_running_loop()
    stop = stop or asyncio.Event()
    logging.getLogger("aiohttp.server").addFilter(BAD_REQUEST_LINES)  # a set: adding twice keeps one
    runner = web.AppRunner(app, handle_signals=False, shutdown_timeout=0.5)
    await runner.setup()
    try:
        site = web.TCPSite(runner, config.host, config.port, reuse_address=True)
        try:
            await site.start()
        except OSError as exc:
            raise ServeError(f"cannot listen on {config.host}:{config.port}: {exc.strerror}; "
                             "is another stereocam running? choose another --port") from None
        port = runner.addresses[0][1] if runner.addresses else config.port
        host = f"[{config.host}]" if ":" in config.host else config.host
        url = f"http://{host}:{port}/"
        log.info("serving on %s (%s fabric)", url, app[OVERLAY].fabric.backend)
        installed = []
        for sig in (signal.SIGTERM, signal.SIGINT) if handle_signals else ():
            try:
                loop.add_signal_handler(sig, stop.set)
                installed.append(sig)
            except (NotImplementedError, RuntimeError):  # not the main thread
                pass
        notify("READY=1")
        notify(f"STATUS=serving on {url}")
        if on_ready is not None:
            on_ready(url)
        try:
            await stop.wait()
        finally:
            for sig in installed:
                loop.remove_signal_handler(sig)
        log.info("stopping")
        notify("STOPPING=1")
    finally:
        app[EXECUTORS].abandon()  # a long check (a calibration PUT's) stops now: it would hold the GIL
        await runner.cleanup()


def run(config: Config, *, extensions: Optional[Sequence[Setup]] = None) -> int:
    """``stereocam serve``: blocks until SIGTERM/SIGINT; returns the exit code."""
    overlay = open_configured_overlay(config)
    try:
        reason = getattr(getattr(overlay, "choice", None), "reason", "")
        log.info("fabric: %s (%s)", overlay.fabric.backend, reason)
        log.info("captures in %s; the page's calibration file and pairs in %s", config.captures_path,
                 config.state_path)
        calibration = program_default_calibration(overlay, config)
        app = create_app(config, overlay, calibration=calibration,
                         extensions=default_extensions() if extensions is None else extensions)
        asyncio.run(serve(app, config))
    finally:
        overlay.close()
    # Everything is stopped and closed. A check the shutdown stopped (Executors.abandon) leaves its
    # half-built YAML document in reference cycles (PyYAML's loader and its generators): the
    # interpreter's exit-time collections would take seconds over it (SIGTERM's 2 s). The OS frees it.
    gc.freeze()
    return 0
