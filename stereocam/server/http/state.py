"""The daemon's application state: typed ``web.AppKey``s and the small holders they point at.

``create_app`` (:mod:`.app`) fills every key before the app starts; route
modules read them (``request.app[PIPELINE]``). The keys here are those of the
types whose modules declare none (the frame path's and the overlay's: no
aiohttp there; :class:`.settings.Settings`, which the CLI reads without
aiohttp) and of the holders below; any other type of server/http has its key
beside it (:data:`.streams.STREAMS`, :data:`.metrics.METRICS`,
...), so this module imports none of the modules that read it. Extensions
(calibration, sensors) add their routes in their ``setup(app)`` and register
providers in ``app[EXTENSIONS]``: what they add to ``/api/status``,
``/metrics`` and capture metadata.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterable, List, Optional, Tuple, TypeVar

from aiohttp import web

from ...overlays.interface import Overlay
from ..frames.capturing import CaptureService
from ..frames.cpu_budget import CpuBudget
from ..frames.encoders import Encoders
from ..frames.fabric_health import FabricHealth
from ..frames.feed import FrameFeed
from ..frames.pipeline import Pipeline
from ..frames.virtual_camera import VirtualCamera
from ..stores.captures import CaptureStore
from ..stores.frame_calibration import FrameCalibration
from .settings import Settings

if TYPE_CHECKING:  # pragma: no cover
    from prometheus_client.metrics_core import Metric

log = logging.getLogger(__name__)
T = TypeVar("T")

__all__ = [
    "SETTINGS", "OVERLAY", "PIPELINE", "FEED", "BUDGET", "ENCODERS", "CAPTURES", "VIRTUAL",
    "CALIBRATION", "EXTENSIONS", "EXECUTORS", "FABRIC_HEALTH", "Executors", "CalibrationState",
    "CalibrationInEffect", "Extensions",
]


@dataclass
class Executors:
    """Worker threads: ``encode`` for views and JPEG/PNG (hot path), ``work`` for disk, uploads, verify.

    The process's exit waits for a job running on ``encode`` or ``work`` (Python joins executor
    threads at exit), so a job there is short or is one that must finish (a file being written,
    registers being programmed). Long computation whose only effect is its result (parsing and
    checking an uploaded calibration) goes to :meth:`run_abandonable`: :meth:`abandon` (shutdown)
    stops it at once, and SIGTERM's 2 s hold even while one runs.
    """

    encode: concurrent.futures.ThreadPoolExecutor
    work: concurrent.futures.ThreadPoolExecutor
    abandonable_threads: int = 2  # run_abandonable jobs running at once
    _slots: Optional[asyncio.Semaphore] = field(default=None, init=False, repr=False)
    _running: Dict[int, "asyncio.Future[Any]"] = field(default_factory=dict, init=False, repr=False)
    _guard: Any = field(default=None, init=False, repr=False)  # threading.Lock over _running
    _closed: bool = field(default=False, init=False, repr=False)

    @classmethod
    def create(cls, encode_threads: int) -> "Executors":
        return cls(
            encode=concurrent.futures.ThreadPoolExecutor(encode_threads,
                                                         thread_name_prefix="stereocam-encode"),
            work=concurrent.futures.ThreadPoolExecutor(4, thread_name_prefix="stereocam-work"),
        )

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on a ``work`` thread, awaited from the event loop."""
        return await asyncio.get_running_loop().run_in_executor(self.work, fn, *args)

    async def run_abandonable(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on a daemon thread of its own, awaited from the event loop; shutdown stops it.

        Only for work whose sole effect is its result (parsing, validating, planning) and that
        takes no lock another thread needs: :meth:`abandon` stops ``fn`` at any point (SystemExit
        raised in its thread) and the await is then cancelled. Never for anything that writes
        files, registers or shared state, or logs (that goes to :meth:`run`). A cancelled await
        leaves ``fn`` running to its end, result dropped. At most ``abandonable_threads`` run at
        once; more calls wait here. ``RuntimeError`` after :meth:`abandon` or :meth:`shutdown`.
        """
        import threading

        if self._closed:
            raise RuntimeError("the worker threads are shut down: the daemon is stopping")
        loop = asyncio.get_running_loop()
        if self._slots is None:
            self._slots = asyncio.Semaphore(self.abandonable_threads)
            self._guard = threading.Lock()
        slots, guard, running = self._slots, self._guard, self._running
        await slots.acquire()
        future: "asyncio.Future[T]" = loop.create_future()

        def settle(ok: bool, value: Any) -> None:  # on the loop, once fn has returned or raised
            slots.release()
            if future.done():  # cancelled (the caller's await, or abandon()): drop the result
                return
            if value is None and not ok:  # abandoned, although the await was not cancelled
                future.cancel()
                return
            if ok:
                future.set_result(value)
            else:
                future.set_exception(value)

        def target() -> None:
            outcome: Tuple[bool, Any]
            try:
                try:
                    outcome = (True, fn(*args))
                except SystemExit:  # abandon(): nobody waits; fn's half-built data is freed here, at once
                    outcome = (False, None)
                except BaseException as exc:
                    outcome = (False, exc)
                with guard:  # from here on abandon() no longer interrupts this thread
                    running.pop(threading.get_ident(), None)
                try:
                    loop.call_soon_threadsafe(settle, *outcome)
                except RuntimeError:  # the loop is closed: the daemon stopped and nobody waits
                    pass
            except SystemExit:  # abandon() came as fn returned: nobody waits; the thread just ends
                pass

        thread = threading.Thread(target=target, name="stereocam-abandonable", daemon=True)
        with guard:  # registered before the thread can unregister itself
            try:
                thread.start()
            except BaseException:
                slots.release()
                raise
            assert thread.ident is not None
            running[thread.ident] = future
        return await future

    def abandon(self) -> None:
        """Shutdown (loop thread): stop the :meth:`run_abandonable` jobs and refuse new ones.

        Their awaits are cancelled, then ``SystemExit`` is raised in their threads at their next
        Python instruction (C code runs to its end first), so they stop using the CPU and the
        GIL the shutdown needs. Returns at once.
        """
        import ctypes

        self._closed = True
        if self._guard is None:
            return
        set_async_exc = ctypes.pythonapi.PyThreadState_SetAsyncExc
        with self._guard:
            for ident, future in self._running.items():
                future.cancel()
                set_async_exc(ctypes.c_ulong(ident), ctypes.py_object(SystemExit))
            self._running.clear()

    def shutdown(self) -> None:
        """Abandon, cancel queued jobs and return at once; the exit still waits for running ``work`` jobs."""
        self.abandon()
        self.encode.shutdown(wait=False, cancel_futures=True)
        self.work.shutdown(wait=False, cancel_futures=True)


EXECUTORS: "web.AppKey[Executors]" = web.AppKey("stereocam.executors", Executors)


@dataclass(frozen=True)
class CalibrationState:
    """The calibration the core runs with, whole, as status and captures report it (immutable).

    ``id`` names it (captures record it), ``description`` says where it came
    from, ``rows_needed``/``lb_rows`` are the line-buffer fit. Never changed in
    place: a change makes a new one (:meth:`changing_from_count`,
    :meth:`succeeded_by`) and :class:`CalibrationInEffect` swaps it in with one
    assignment, so a reader on another thread (the pipeline's, labelling a
    recorded frame) holding one reference sees every field of one calibration.
    What a frame ran with is :attr:`frame_calibration` (:meth:`for_frame`), the one
    record captures, recordings and the page's readouts take.
    """

    id: Optional[str] = None
    description: str = "none: the core passes frames through unrectified"
    rows_needed: Optional[int] = None
    lb_rows: Optional[int] = None
    lb_delay: Optional[int] = None
    calibration: Any = field(default=None, repr=False, compare=False)  # the Calibration, when one is known
    # A change in progress (registers being programmed: frames may carry either set), and the
    # calibrations that ran before, each from the FRAME_COUNT it surely took effect.
    changing: bool = field(default=False, compare=False)
    changing_from: Optional[int] = field(default=None, compare=False)  # FRAME_COUNT read before it began
    history: Tuple[Tuple[int, int, "CalibrationState"], ...] = field(default=(), repr=False, compare=False)
    # The record of a frame that ran with this calibration: made once here, with the state.
    frame_calibration: FrameCalibration = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame_calibration", FrameCalibration.of(
            self.calibration, id=self.id, description=self.description, rows_needed=self.rows_needed,
            lb_rows=self.lb_rows, lb_delay=self.lb_delay))

    def to_json(self) -> Dict[str, Any]:
        """The calibration in effect as ``/api/status`` reports it: its record's stored form."""
        return self.frame_calibration.to_json()

    def changing_from_count(self, before: int) -> "CalibrationState":
        """This calibration while a change begun at FRAME_COUNT ``before`` is programmed."""
        return replace(self, changing=True, changing_from=before)

    def unchanged(self) -> "CalibrationState":
        """This calibration after a change that failed (its registers were put back)."""
        return replace(self, changing=False)

    def succeeded_by(self, new: "CalibrationState", before: int, effective: int) -> "CalibrationState":
        """``new``, after this one: frames up to ``before`` ran this one, from ``effective`` on ``new``.

        ``before``/``effective`` are FRAME_COUNT values read before programming and two frames
        after the core latched (the frame in flight may still leave with the old set).
        """
        previous = replace(self, changing=False, changing_from=None, history=())
        history = (self.history + ((before, effective, previous),))[-HISTORY:]
        return replace(new, changing=False, changing_from=None, history=history)

    def for_frame(self, count: int) -> Optional[FrameCalibration]:
        """The calibration frame ``count`` (its FRAME_COUNT) ran with; None when unknown.

        Unknown: a frame of a change in progress, or between a change's two counts.
        """
        start = self.changing_from
        if self.changing and (start is None or _not_before(count, start + 1)):
            return None  # after programming began: either register set
        after: CalibrationState = self  # during a change still the old one: the new one is swapped in whole
        for before, effective, previous in reversed(self.history):
            if _not_before(count, effective):
                return after.frame_calibration
            if not _not_before(count, before + 1):
                after = previous
                continue
            return None
        return after.frame_calibration


class CalibrationInEffect:
    """``app[CALIBRATION]``: the :class:`CalibrationState` in effect, replaced whole by :meth:`swap`.

    Swapped on the event loop only; read from any thread (the pipeline's labels recorded
    frames with :meth:`for_frame`). A reader takes :attr:`now` once and reads every field
    it needs from that one state.
    """

    def __init__(self, state: CalibrationState) -> None:
        self._now = state

    @property
    def now(self) -> CalibrationState:
        return self._now

    def swap(self, state: CalibrationState) -> None:
        """Put ``state`` in effect (loop thread): one assignment, so no reader sees half of it."""
        self._now = state

    def for_frame(self, count: int) -> Optional[FrameCalibration]:
        """:meth:`CalibrationState.for_frame` of the state in effect (safe from any thread)."""
        return self._now.for_frame(count)

    def to_json(self) -> Dict[str, Any]:
        return self._now.to_json()

    @property
    def id(self) -> Optional[str]:
        """The id of the calibration in effect (captures and recordings name it)."""
        return self._now.id


CALIBRATION: "web.AppKey[CalibrationInEffect]" = web.AppKey("stereocam.calibration", CalibrationInEffect)


HISTORY = 8  # calibration changes remembered for labelling frames (a capture is seconds old at most)


def _not_before(count: int, mark: int) -> bool:
    """FRAME_COUNT ``count`` is ``mark`` or later (it wraps at 2**32)."""
    return (count - mark) % (1 << 32) < (1 << 31)


Provider = Callable[[], Dict[str, Any]]
# Metric families for /metrics, made at each scrape: prometheus_client ``Metric``s
# (``GaugeMetricFamily``, ``CounterMetricFamily``...) with names in base units, counters without
# ``_total`` (prometheus_client adds it) and one label set per family.
MetricsProvider = Callable[[], Iterable["Metric"]]
# Faults active now, each {"what": a stable name such as "sensor.left", "text": what is wrong,
# "since": wall-clock seconds when it began}: /healthz, /api/status and /metrics report them.
FaultProvider = Callable[[], Iterable[Dict[str, Any]]]


@dataclass
class Extensions:
    """Where other parts of the daemon plug in (loop thread; providers must not block).

    - ``status``: name -> provider; ``/api/status`` gets ``{name: provider()}``
      (e.g. ``"sensors"``).
    - ``metrics``: providers of extra metric families (:data:`MetricsProvider`); a family
      whose name the daemon or an earlier provider already uses is left out.
    - ``capture_meta``: name -> provider; each capture's meta.json gets
      ``{name: provider()}`` (e.g. ``"sensors"``: exposure and gain).
    - ``faults``: providers of the faults active now (:data:`FaultProvider`).
    """

    status: Dict[str, Provider] = field(default_factory=dict)
    metrics: List[MetricsProvider] = field(default_factory=list)
    capture_meta: Dict[str, Provider] = field(default_factory=dict)
    faults: List[FaultProvider] = field(default_factory=list)

    @staticmethod
    def _collect(providers: Dict[str, Provider], what: str) -> Dict[str, Any]:
        out: Dict[str, Any] = {}
        for name, provider in providers.items():
            try:
                out[name] = provider()
            except Exception as exc:  # one broken extension must not break status or captures
                log.warning("%s provider %r failed: %s", what, name, exc)
                out[name] = {"error": str(exc)}
        return out

    def status_sections(self) -> Dict[str, Any]:
        return self._collect(self.status, "status")

    def capture_sections(self) -> Dict[str, Any]:
        return self._collect(self.capture_meta, "capture meta")

    @staticmethod
    def _chain(providers: Iterable[Callable[[], Iterable[T]]], what: str) -> List[T]:
        out: List[T] = []
        for provider in providers:
            try:
                out.extend(provider())
            except Exception as exc:  # one broken extension must not break the rest
                log.warning("%s provider failed: %s", what, exc)
        return out

    def active_faults(self) -> List[Dict[str, Any]]:
        return self._chain(self.faults, "fault")

    def metric_families(self) -> List["Metric"]:
        return self._chain(self.metrics, "metrics")


EXTENSIONS: "web.AppKey[Extensions]" = web.AppKey("stereocam.extensions", Extensions)


# Keys of types whose modules declare none: the frame path's (it serves no HTTP: no aiohttp
# there), the overlay's, and Settings' (configuration the CLI reads without aiohttp). Every key
# of the daemon is written ``NAME: "web.AppKey[T]" = web.AppKey("stereocam.<name>", T)``.
SETTINGS: "web.AppKey[Settings]" = web.AppKey("stereocam.settings", Settings)
OVERLAY: "web.AppKey[Overlay]" = web.AppKey("stereocam.overlay", Overlay)
PIPELINE: "web.AppKey[Pipeline]" = web.AppKey("stereocam.pipeline", Pipeline)
FEED: "web.AppKey[FrameFeed]" = web.AppKey("stereocam.feed", FrameFeed)
BUDGET: "web.AppKey[CpuBudget]" = web.AppKey("stereocam.cpu_budget", CpuBudget)
ENCODERS: "web.AppKey[Encoders]" = web.AppKey("stereocam.encoders", Encoders)
CAPTURES: "web.AppKey[CaptureStore]" = web.AppKey("stereocam.captures", CaptureStore)
CAPTURING: "web.AppKey[CaptureService]" = web.AppKey("stereocam.capturing", CaptureService)
VIRTUAL: "web.AppKey[VirtualCamera]" = web.AppKey("stereocam.virtual", VirtualCamera)
FABRIC_HEALTH: "web.AppKey[FabricHealth]" = web.AppKey("stereocam.fabric_health", FabricHealth)
