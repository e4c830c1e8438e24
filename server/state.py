"""The daemon's application state: typed ``web.AppKey``s and the small holders they point at.

``create_app`` (:mod:`.app`) fills every key before the app starts; route
modules read them (``request.app[PIPELINE]``). Extensions (calibration,
issue 4; sensors, issue 5) add their routes in their ``setup(app)`` and
register providers in ``app[EXTENSIONS]``: what they add to ``/api/status``,
``/metrics`` and capture metadata.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterable, List, Optional, Tuple, TypeVar

from aiohttp import web

if TYPE_CHECKING:  # pragma: no cover
    from .captures import CaptureStore
    from .config import Config
    from .encoders import Encoders, FrameFeed
    from .fabric_health import FabricHealth
    from .metrics import Metrics
    from .pipeline import Pipeline
    from .routes_api import VirtualCamera
    from .streams import StreamClients

log = logging.getLogger(__name__)
T = TypeVar("T")

__all__ = [
    "CONFIG", "OVERLAY", "PIPELINE", "FEED", "ENCODERS", "STREAMS", "METRICS", "CAPTURES", "VIRTUAL",
    "CALIBRATION", "EXTENSIONS", "EXECUTORS", "FABRIC_HEALTH", "Executors", "CalibrationState", "Extensions",
]


@dataclass
class Executors:
    """Worker threads: ``encode`` for views and JPEG/PNG (hot path), ``work`` for disk, uploads, verify."""

    encode: concurrent.futures.ThreadPoolExecutor
    work: concurrent.futures.ThreadPoolExecutor

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

    def shutdown(self) -> None:
        self.encode.shutdown(wait=False, cancel_futures=True)
        self.work.shutdown(wait=False, cancel_futures=True)


@dataclass
class CalibrationState:
    """The calibration the core runs with, as status and captures report it.

    ``id`` names it (captures record it), ``description`` says where it came
    from, ``rows_needed``/``lb_rows`` are the line-buffer fit. Issue 4's
    calibration routes replace these fields when they program a new one.
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
    history: List[Tuple[int, int, Dict[str, Any]]] = field(default_factory=list, repr=False, compare=False)

    def to_json(self) -> Dict[str, Any]:
        return {"id": self.id, "description": self.description, "rows_needed": self.rows_needed,
                "lb_rows": self.lb_rows, "lb_delay": self.lb_delay}

    def changed(self, before: int, effective: int, previous: Dict[str, Any]) -> None:
        """Record a change: frames up to ``before`` ran ``previous``, frames from ``effective`` this one.

        ``before``/``effective`` are FRAME_COUNT values read before programming and two frames
        after the core latched (the frame in flight may still leave with the old set).
        """
        self.history.append((before, effective, previous))
        del self.history[:-HISTORY]

    def for_frame(self, count: int) -> Optional[Dict[str, Any]]:
        """``to_json()`` of the calibration frame ``count`` (its FRAME_COUNT) ran with; None when unknown.

        Unknown: a frame of a change in progress, or between a change's two counts.
        """
        if self.changing:
            return None
        after = self.to_json()
        for before, effective, previous in reversed(self.history):
            if _not_before(count, effective):
                return after
            if not _not_before(count, before + 1):
                after = previous
                continue
            return None
        return after


HISTORY = 8  # calibration changes remembered for labelling frames (a capture is seconds old at most)


def _not_before(count: int, mark: int) -> bool:
    """FRAME_COUNT ``count`` is ``mark`` or later (it wraps at 2**32)."""
    return (count - mark) % (1 << 32) < (1 << 31)


Provider = Callable[[], Dict[str, Any]]
MetricsProvider = Callable[[], Iterable[str]]
# Faults active now, each {"what": a stable name such as "sensor.left", "text": what is wrong,
# "since": wall-clock seconds when it began}: /healthz, /api/status and /metrics report them.
FaultProvider = Callable[[], Iterable[Dict[str, Any]]]


@dataclass
class Extensions:
    """Where other parts of the daemon plug in (loop thread; providers must not block).

    - ``status``: name -> provider; ``/api/status`` gets ``{name: provider()}``
      (e.g. ``"sensors"``).
    - ``metrics``: providers of extra Prometheus text lines.
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

    def metrics_lines(self) -> List[str]:
        return self._chain(self.metrics, "metrics")


CONFIG: "web.AppKey[Config]" = web.AppKey("stereocam.config")
OVERLAY: "web.AppKey[Any]" = web.AppKey("stereocam.overlay")
PIPELINE: "web.AppKey[Pipeline]" = web.AppKey("stereocam.pipeline")
FEED: "web.AppKey[FrameFeed]" = web.AppKey("stereocam.feed")
ENCODERS: "web.AppKey[Encoders]" = web.AppKey("stereocam.encoders")
STREAMS: "web.AppKey[StreamClients]" = web.AppKey("stereocam.streams")
METRICS: "web.AppKey[Metrics]" = web.AppKey("stereocam.metrics")
CAPTURES: "web.AppKey[CaptureStore]" = web.AppKey("stereocam.captures")
VIRTUAL: "web.AppKey[VirtualCamera]" = web.AppKey("stereocam.virtual")
CALIBRATION: "web.AppKey[CalibrationState]" = web.AppKey("stereocam.calibration")
EXTENSIONS: "web.AppKey[Extensions]" = web.AppKey("stereocam.extensions")
EXECUTORS: "web.AppKey[Executors]" = web.AppKey("stereocam.executors")
FABRIC_HEALTH: "web.AppKey[FabricHealth]" = web.AppKey("stereocam.fabric_health")
