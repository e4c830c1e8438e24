"""The daemon: :func:`create_app` wires the stages into an aiohttp application, :func:`run` serves it.

``create_app(config, overlay)`` takes an opened overlay (an
:class:`~...overlays.interface.Overlay`) and returns a ``web.Application`` whose state is
in ``web.AppKey``s: :mod:`.state`'s, and those declared beside their types (:data:`.streams.STREAMS`,
:data:`.metrics.METRICS`). Starting the app starts the
overlay's streams and the pipeline thread and the background tasks
(no-signal watch, slow-client sweeper, systemd watchdog); cleaning it up
stops them in reverse order, with the mux back on live. The overlay itself
(opening, closing) is the caller's.

``run(config)`` is ``stereocam serve``: open the overlay, program the
default calibration, serve until SIGTERM/SIGINT, then stop the streams, the
VDMA channels and the mux (live) and exit, all within 2 s.

Extensions (calibration, sensors) are callables
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
from typing import Any, AsyncIterator, Callable, List, Optional, Sequence, Tuple

from aiohttp import web

from ...overlays.backend import RTL_TIMEOUT_S, BackendError, open_overlay
from ...overlays.interface import Overlay
from ...overlays.model.stereo import compiled_path_installed
from ..frames.capturing import CaptureService
from ..frames.cpu_budget import (
    HOST_PRIORS,
    PLAN_PERIOD_S,
    CpuBudget,
    Priors,
    board_priors,
    default_cores,
    single_threaded_opencv,
)
from ..frames.encoders import Encoders
from ..frames.fabric_health import FabricHealth
from ..frames.feed import FrameFeed
from ..frames.pipeline import Pipeline
from ..frames.virtual_camera import VirtualCamera
from ..stores.captures import CaptureStore
from . import routes_faults, signin
from .connections import BoundedSite, ConnectionLimits
from .errors import BAD_REQUEST_LINES, json_errors
from .heap import give_back_memory, limit_arenas
from .metrics import METRICS, Metrics
from .metrics import setup_routes as setup_ops_routes
from .routes_api import setup_routes as setup_api_routes
from .security import allowed_host_names, guard
from .settings import Settings
from .state import (
    BUDGET,
    CALIBRATION,
    CAPTURES,
    CAPTURING,
    ENCODERS,
    EXECUTORS,
    EXTENSIONS,
    FABRIC_HEALTH,
    FEED,
    OVERLAY,
    PIPELINE,
    SETTINGS,
    VIRTUAL,
    CalibrationInEffect,
    CalibrationState,
    Executors,
    Extensions,
)
from .streams import STREAMS, StreamClients
from .streams import setup_routes as setup_stream_routes
from .systemd import loaded, loading, notify, watchdog_interval

log = logging.getLogger(__name__)

__all__ = ["create_app", "run", "serve", "program_default_calibration", "default_extensions", "ServeError",
           "STATIC_DIR"]

STATIC_DIR = Path(__file__).resolve().parent / "static"
RTL_NO_SIGNAL_S = 5.0  # no_signal_s at least this with the RTL core (it runs a few frames per second)
Setup = Callable[[web.Application], None]


class ServeError(Exception):
    """The daemon cannot start as configured (port taken, ...): one line for the user."""


def default_extensions() -> List[Setup]:
    """The extensions ``run`` installs: calibration and the camera sensors."""
    from . import routes_calibration, routes_calibration_panel, routes_cameras

    return [routes_calibration.setup, routes_calibration_panel.setup, routes_cameras.setup]


# -- the page ---------------------------------------------------------------------------------

async def _index(request: web.Request) -> web.StreamResponse:
    page = STATIC_DIR / "index.html"
    if not page.is_file():
        raise web.HTTPNotFound(text="the web page is not installed (stereocam/server/http/static/index.html "
                                    "is missing); the API works: see /api/status")
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

#: The disparity views' rate where the ARM computes them within the board's budget: StereoBM at half
#: size costs a Cortex-A9 0.2-0.3 s a frame (stereocam/board/a9_costs.json), so the other views keep
#: 2 fps or more in one core beside it (tests/board/test_a9_costs.py plans the page's default).
BOARD_DISPARITY_FPS = 1.0
DISPARITY_FPS = 10.0  # elsewhere, unless disparity_fps says otherwise


def arm_disparity(config: Settings, board: bool, has_stereo: bool) -> Tuple[float, float]:
    """The scale the ARM's StereoBM runs at (``arm_disparity``: half within the board's budget) and the
    disparity views' rate (``disparity_fps``; unset: :data:`BOARD_DISPARITY_FPS` where the ARM computes
    them on the board, :data:`DISPARITY_FPS` elsewhere). A stereo core takes the work off the ARM."""
    scale = 0.5 if config.arm_disparity == "half" or (config.arm_disparity == "auto" and board) else 1.0
    if config.disparity_fps is not None:
        return scale, config.disparity_fps
    return scale, BOARD_DISPARITY_FPS if board and not has_stereo else DISPARITY_FPS


def budget_priors(backend: str, on_board: bool, arm_scale: float = 1.0) -> Priors:
    """The CPU budget's priors: the Cortex-A9's table where the daemon runs on the board (the pynq
    backend, or the emulated fabric on a board without its bitstream), this machine's elsewhere."""
    if backend != "pynq" and not on_board:
        return HOST_PRIORS
    try:
        return board_priors(arm_scale=arm_scale)
    except Exception as exc:  # a package without its table plans as off the board, and says so
        log.warning("the CPU budget plans with this machine's costs until it has measured them: %s", exc)
        return HOST_PRIORS


def create_app(
    config: Settings,
    overlay: Overlay,
    *,
    calibration: Optional[CalibrationState] = None,
    captures: Optional[CaptureStore] = None,
    extensions: Sequence[Setup] = (),
) -> web.Application:
    """The daemon's application for ``overlay`` (see the module doc); nothing runs until it starts."""
    if overlay.core_kind == "rtl" and config.no_signal_s < RTL_NO_SIGNAL_S:
        # A simulated core delivers a few frames per second: a frame 0.5 s old is not a lost signal.
        config = config.replace(no_signal_s=RTL_NO_SIGNAL_S)
    metrics = Metrics()
    app = web.Application(
        middlewares=[json_errors(metrics),
                     guard(access_token=config.access_token, max_body=config.max_upload_bytes,
                           allowed_hosts=allowed_host_names(config.host, config.allowed_hosts),
                           protect=config.protect)],
        client_max_size=config.max_upload_bytes,
    )
    on_board = overlay.choice is not None and overlay.choice.board
    cores = config.cpu_budget if config.cpu_budget is not None else default_cores(overlay.backend,
                                                                                 board=on_board)
    emulation = tuple(overlay.emulation_threads)
    arm_scale, disparity_fps = arm_disparity(config, overlay.backend == "pynq" or on_board,
                                             overlay.stereo is not None)
    budget = CpuBudget(cores, excluded_threads=lambda: emulation,
                       priors=budget_priors(overlay.backend, on_board, arm_scale))
    feed = FrameFeed(frame_size=overlay.frame_size, no_signal_s=config.no_signal_s)
    # FabricHealth reads the pipeline's frame period and the virtual camera's source, which are
    # told of its faults (constructor arguments): it is made first and reads the two once the
    # app runs (its thread starts with the fabric; nothing calls it before create_app returns).
    health = FabricHealth(overlay, source=lambda: virtual.source, frame_age=feed.frame_age,
                          period=lambda: pipeline.period, no_signal_s=config.no_signal_s)
    pipeline = Pipeline(overlay, publish=feed.push, alive=feed.alive, charge=budget.charge,
                        channel_ok=health.channel_ok, arm_scale=arm_scale)
    executors = Executors.create(config.encode_threads)
    app[SETTINGS] = config
    app[OVERLAY] = overlay
    app[METRICS] = metrics
    app[FEED] = feed
    app[PIPELINE] = pipeline
    app[EXECUTORS] = executors
    app[BUDGET] = budget
    app[ENCODERS] = encoders = Encoders(feed, pipeline, executors.encode, disparity_fps=disparity_fps,
                                        observe=metrics.observe_encode,
                                        on_error=lambda text: metrics.error(text, "encode"), budget=budget)
    pipeline.set_copy_rate(encoders.copy_rate)  # Encoders reads the pipeline: set once both exist
    app[STREAMS] = StreamClients(max_streams=config.max_streams, timeout=config.stream_timeout_s)
    app[CAPTURES] = captures if captures is not None else CaptureStore(
        config.captures_path, min_free_bytes=int(config.min_free_mb * 1e6))
    rtl = overlay.core_kind == "rtl"
    app[VIRTUAL] = virtual = VirtualCamera(overlay, pipeline, feed,
                                           round_trip_timeout=RTL_TIMEOUT_S if rtl else 2.0,
                                           mux_refused=health.mux_refused, mux_committed=health.mux_committed)
    app[CALIBRATION] = CalibrationInEffect(calibration or CalibrationState(lb_rows=overlay.rectify.lb_rows))
    pipeline.set_calibration(app[CALIBRATION].for_frame)  # the depth view's Q, per frame
    app[EXTENSIONS] = extended = Extensions(faults=[health.faults], metrics=[health.metrics])
    app[FABRIC_HEALTH] = health
    # What POST /api/captures and the calibration panel's pairs capture with: made once, its
    # collaborators fixed; the frame wait is read from the settings at each grab.
    app[CAPTURING] = CaptureService(
        feed=feed, pipeline=pipeline, overlay=overlay, virtual=virtual, calibration=app[CALIBRATION],
        run=executors.run, frame_wait_s=lambda: config.frame_wait_s, sections=extended.capture_sections)

    app.router.add_get("/", _index)
    app.router.add_get("/static/{path:.+}", _static)
    signin.setup(app)
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
             loop.create_task(give_back_memory(), name="stereocam-malloc-trim")]
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
        started = time.monotonic()
        await loop.run_in_executor(None, pipeline.stop)
        pipeline_s, started = time.monotonic() - started, time.monotonic()
        await loop.run_in_executor(None, overlay.stop)  # clock, then streams: mux back to live, VDMA stopped
        # With the times: on a slow CPU the emulated fabric finishes the frame it is emulating first,
        # which a board's fabric does not (the Zynq VM's stop check reads this line).
        log.info("fabric stopped: mux on live, VDMA channels stopped (the frame pipeline in %.2f s, the %s "
                 "fabric in %.2f s)", pipeline_s, overlay.backend, time.monotonic() - started)


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


async def _plan_budget(app: web.Application) -> None:
    """Re-plan the views' frame rates within the CPU budget every :data:`PLAN_PERIOD_S` (cpu_budget.py)."""
    budget, encoders, pipeline = app[BUDGET], app[ENCODERS], app[PIPELINE]
    size = app[OVERLAY].frame_size
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


async def _feed_while_stopping(interval: float) -> None:
    """Ping systemd's watchdog while the app cleans up: systemd keeps the watchdog armed while a unit
    stops, and the pipeline's heartbeat ends first, so a stop longer than ``WatchdogSec`` would end in
    SIGABRT and a core dump instead of the exit it is making. The stop's own limit is TimeoutStopSec."""
    while True:
        notify("WATCHDOG=1")
        await asyncio.sleep(interval / 3)


# -- calibration at start -------------------------------------------------------------------

def _calibration_id(prefix: str, left: Any, right: Any) -> str:
    digest = hashlib.sha256(repr((left.values(), right.values())).encode("utf-8")).hexdigest()[:12]
    return f"{prefix}-{digest}"


def program_default_calibration(overlay: Overlay, config: Settings) -> CalibrationState:
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
    ``CoreParamsError``).
    """
    from .routes_calibration import calibration_path, load_configured

    w, h = overlay.frame_size
    rectify = overlay.rectify
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
        cal = overlay.rig_calibration()
        if cal is None:
            log.warning("no calibration given: the rectify core passes frames through (give --calibration)")
            return CalibrationState(lb_rows=rectify.lb_rows)
        state_id = _calibration_id("synthetic-rig", cal.left, cal.right)
        description = cal.source
    core_config, fit = rectify.program(cal.left, cal.right, w, h)
    state = CalibrationState(id=state_id, description=description, rows_needed=fit.rows,
                             lb_rows=rectify.lb_rows, lb_delay=core_config.lb_delay, calibration=cal)
    log.info("calibration %s: %s (line buffer %d of %d rows)", state.id, description, fit.rows,
             rectify.lb_rows)
    return state


# -- serving --------------------------------------------------------------------------------

def open_configured_overlay(config: Settings) -> Overlay:
    """The overlay ``config`` asks for (:func:`stereocam.overlays.backend.open_overlay`), or ServeError."""
    bitstream = Path(config.bitstream).expanduser() if config.bitstream else None
    stereo = config.stereo_core
    if stereo is None:  # unset: an emulated stereo core only where its model keeps up
        stereo = compiled_path_installed()
    try:
        overlay = open_overlay(config.backend, bitstream=bitstream, source=config.source, fps=config.fps,
                               clock="realtime", build=config.core_build, core=config.core,
                               rtl_dir=config.rtl_dir, stereo=stereo)
    except BackendError as exc:
        raise ServeError(str(exc)) from None
    if config.stereo_core is None and not stereo and overlay.backend == "emulated":
        # Said once the overlay is open: a refused --source is the only line a typo gets.
        log.info("the emulated fabric has no stereo core: its model needs numba to keep up "
                 "(pip install 'stereocam[fast]', or stereo_core: true to have it anyway); the "
                 "disparity view uses OpenCV's StereoBM")
    return overlay


async def serve(app: web.Application, config: Settings, *, stop: Optional[asyncio.Event] = None,
                on_ready: Optional[Callable[[str], None]] = None, handle_signals: bool = True) -> None:
    """Serve ``app`` until ``stop`` is set (or SIGTERM/SIGINT, with ``handle_signals``), then clean up.

    ``on_ready(url)`` is called once the socket listens (``config.port`` 0
    picks a free port; the URL has the real one). Connections are bounded by
    :class:`.connections.BoundedSite` (header and keep-alive timeouts, a cap below the fd
    limit). Cleaning up stops the
    long checks first (:meth:`.state.Executors.abandon`: a calibration PUT's
    ends in 503), then aiohttp's shutdown (handlers get ``shutdown_timeout``)
    and the app's cleanup (streams, pipeline, fabric).
    """
    loop = asyncio.get_running_loop()
    stop = stop or asyncio.Event()
    logging.getLogger("aiohttp.server").addFilter(BAD_REQUEST_LINES)  # a set: adding twice keeps one
    runner = web.AppRunner(app, handle_signals=False, shutdown_timeout=0.5)
    try:
        await runner.setup()  # the app's start: sensors, fabric streams, pipeline (cleanup_ctx)
    except BaseException:
        # A start that failed (a device refused: systemd.LateDriver) stops what had started, in reverse,
        # and the worker threads, whose context may not have been entered.
        await runner.cleanup()
        app[EXECUTORS].shutdown()
        raise
    try:
        limits = ConnectionLimits(header_timeout_s=config.header_timeout_s,
                                  keepalive_timeout_s=config.keepalive_timeout_s,
                                  max_connections=config.max_connections, max_body=config.max_upload_bytes)
        site = BoundedSite(runner, config.host, config.port, limits=limits)
        try:
            await site.start()
        except OSError as exc:
            raise ServeError(f"cannot listen on {config.host}:{config.port}: {exc.strerror or exc}; "
                             "is another stereocam running? choose another --port") from None
        port = site.port
        host = f"[{config.host}]" if ":" in config.host else config.host
        url = f"http://{host}:{port}/"
        log.info("serving on %s (%s fabric)", url, app[OVERLAY].backend)
        installed = []
        for sig in (signal.SIGTERM, signal.SIGINT) if handle_signals else ():
            try:
                loop.add_signal_handler(sig, stop.set)
                installed.append(sig)
            except (NotImplementedError, RuntimeError):  # not the main thread
                pass
        loaded()  # no more start-timeout extensions (stereocam serve's, from its first line)
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
        interval = watchdog_interval()
        feeding = None if interval is None else loop.create_task(_feed_while_stopping(interval),
                                                                 name="stereocam-watchdog-stopping")
        try:
            await runner.cleanup()
        finally:
            if feeding is not None:
                feeding.cancel()
                await asyncio.gather(feeding, return_exceptions=True)


def run(config: Settings, *, extensions: Optional[Sequence[Setup]] = None) -> int:
    """``stereocam serve``: blocks until SIGTERM/SIGINT; returns the exit code."""
    limit_arenas()  # before the overlay's and the pipeline's threads exist
    loading("the fabric (the overlay and its bitstream)")  # under systemd, `systemctl status` shows these
    overlay = open_configured_overlay(config)
    try:
        reason = overlay.choice.reason if overlay.choice is not None else ""
        log.info("fabric: %s (%s)", overlay.backend, reason)
        log.info("captures in %s; the page's calibration file and pairs in %s", config.captures_path,
                 config.state_path)
        loading("the calibration")
        calibration = program_default_calibration(overlay, config)
        app = create_app(config, overlay, calibration=calibration,
                         extensions=default_extensions() if extensions is None else extensions)
        loading("the camera sensors and the fabric's streams")
        asyncio.run(serve(app, config))
    finally:
        overlay.close()
    # Everything is stopped and closed. A check the shutdown stopped (Executors.abandon) leaves its
    # half-built YAML document in reference cycles (PyYAML's loader and its generators): the
    # interpreter's exit-time collections would take seconds over it (SIGTERM's 2 s). The OS frees it.
    gc.freeze()
    return 0
