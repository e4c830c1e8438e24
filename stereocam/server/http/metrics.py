"""Operations: counters of the daemon, ``GET /metrics`` (Prometheus text) and ``GET /healthz``.

:class:`Metrics` is written from any thread (encoders time themselves in
worker threads) and read by the handlers. ``/metrics`` is prometheus_client's
text exposition (format 0.0.4) of a :class:`~prometheus_client.CollectorRegistry`
of the app's own (``app[REGISTRY]``; never the library's global one, so that
apps in one process do not clash): a :class:`DaemonCollector` that reads the
daemon's counters and snapshots at each scrape, and prometheus_client's
process and platform collectors (``process_*``, ``python_info``). Names, in
base units, counters ending ``_total``, one label set per family (API.md,
"Operations"): ``stereocam_stage_frames_per_second{stage}``,
``stereocam_view_encoded_frames_per_second{view}``, ``stereocam_frames_total``,
``stereocam_encode_seconds{view}`` (a summary: ``_count`` and ``_sum``),
``stereocam_clients{kind}``, the CPU budget (``stereocam_cpu_budget_cores``,
``stereocam_cpu_used_cores``) and each watched view under it
(``stereocam_view_{target,planned}_frames_per_second{view}``, ``stereocam_view_cost_seconds{view}``,
``stereocam_view_limited{view,reason}``), ``stereocam_errors_total{where}``, the faults
active now, and the families extensions add (``Extensions.metrics``).

A scrape runs on the event loop: every value is a counter or a snapshot the
daemon already keeps (no register or I2C access), and the process collector
reads a few files under ``/proc``.
"""
from __future__ import annotations

import collections
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Deque, Dict, Iterable, Iterator, List, Set, Tuple

from aiohttp import web
from prometheus_client import CollectorRegistry, PlatformCollector, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric, SummaryMetricFamily
from prometheus_client.registry import Collector

from ..frames.cpu_budget import CpuBudget
from ..frames.encoders import Encoders
from ..frames.feed import FrameFeed
from ..frames.pipeline import Pipeline
from .state import BUDGET, ENCODERS, EXTENSIONS, FEED, PIPELINE, SETTINGS, Extensions
from .streams import STREAMS, StreamClients

__all__ = ["Metrics", "DaemonCollector", "METRICS", "REGISTRY", "CONTENT_TYPE", "make_registry", "render",
           "setup_routes", "healthy"]

log = logging.getLogger(__name__)

# What generate_latest writes: the text format 0.0.4 (prometheus_client 0.14's CONTENT_TYPE_LATEST;
# later releases call it CONTENT_TYPE_PLAIN_0_0_4 and mean format 1.0.0 by CONTENT_TYPE_LATEST).
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


class Metrics:
    """Thread-safe counters; ``recent_errors`` keeps the last 20 error lines with their time."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.encode: Dict[str, List[float]] = {}  # view -> [count, seconds]
        self.uploads: Dict[str, int] = collections.Counter()
        self.errors: Dict[str, int] = collections.Counter()
        self.requests: Dict[str, int] = collections.Counter()  # by status class: 2xx, 4xx, 5xx
        self.captures = 0
        self.recent_errors: Deque[Tuple[float, str]] = collections.deque(maxlen=20)
        self.started = time.time()

    def observe_encode(self, view: str, seconds: float) -> None:
        with self._lock:
            entry = self.encode.setdefault(view, [0, 0.0])
            entry[0] += 1
            entry[1] += seconds

    def upload(self, result: str) -> None:
        with self._lock:
            self.uploads[result] += 1

    def error(self, text: str, where: str = "daemon") -> None:
        with self._lock:
            self.errors[where] += 1
            self.recent_errors.append((time.time(), " ".join(str(text).split())[:300]))

    def request(self, status: int) -> None:
        with self._lock:
            self.requests[f"{status // 100}xx"] += 1

    def recent(self) -> List[str]:
        with self._lock:
            return [f"{time.strftime('%Y-%m-%dT%H:%M:%S', time.localtime(t))} {text}"
                    for t, text in self.recent_errors]


METRICS: "web.AppKey[Metrics]" = web.AppKey("stereocam.metrics", Metrics)
REGISTRY: "web.AppKey[CollectorRegistry]" = web.AppKey("stereocam.metrics_registry", CollectorRegistry)


@dataclass(frozen=True)
class DaemonParts:
    """What :class:`DaemonCollector` reads at each scrape: the daemon's counters and stages."""

    metrics: Metrics
    pipeline: Pipeline
    encoders: Encoders
    streams: StreamClients
    feed: FrameFeed
    budget: CpuBudget
    extensions: Extensions


class DaemonCollector(Collector):
    """The daemon's families, read from the parts it is handed at each scrape (loop thread; never blocks).

    Extension families (``Extensions.metrics``) follow the daemon's own; a family whose name is
    already taken is left out with a warning (two families of one name fail the whole scrape in
    Prometheus), and so is anything that is not a prometheus_client ``Metric``.
    """

    def __init__(self, parts: "DaemonParts") -> None:
        self._parts = parts

    def collect(self) -> Iterator[Metric]:
        seen: Set[str] = set()
        for family in (*self._daemon(), *self._parts.extensions.metric_families()):
            if not isinstance(family, Metric):
                log.warning("metrics: an extension gave %r, not a prometheus_client metric family: left out",
                            family)
                continue
            if family.name in seen:
                log.warning("metrics: a second family named %s: left out", family.name)
                continue
            seen.add(family.name)
            yield family

    def _daemon(self) -> Iterable[Metric]:
        parts = self._parts
        metrics, pipeline, encoders, streams, feed = (parts.metrics, parts.pipeline, parts.encoders,
                                                      parts.streams, parts.feed)
        out: List[Metric] = []

        stages = GaugeMetricFamily("stereocam_stage_frames_per_second",
                                   "Frames per second through a stage over the last 2 s: the rectify core "
                                   "(camera), the frames the pipeline published (pipeline), disparity.",
                                   labels=["stage"])
        stages.add_metric(["camera"], pipeline.fabric_fps())
        stages.add_metric(["pipeline"], pipeline.meter.rate())
        disparity = encoders.disparity
        stages.add_metric(["disparity"], disparity.meter.rate() if disparity.running else 0.0)
        out.append(stages)
        views = GaugeMetricFamily("stereocam_view_encoded_frames_per_second",
                                  "Frames per second a view is JPEG-encoded at over the last 2 s "
                                  "(views being encoded now).", labels=["view"])
        for view, rate in sorted(encoders.fps_by_view().items()):
            views.add_metric([view], rate)
        out.append(views)
        out.extend(_budget_families(parts.budget, encoders.status()))
        out.append(CounterMetricFamily("stereocam_frames", "Frame sets the pipeline published.",
                                       value=pipeline.frames))
        out.append(CounterMetricFamily("stereocam_frames_seen",
                                       "Frames the pipeline saw complete, copied or not.",
                                       value=pipeline.frames_seen))
        out.append(CounterMetricFamily("stereocam_drops",
                                       "Frames the fabric completed that the pipeline did not publish.",
                                       value=pipeline.drops))
        out.append(GaugeMetricFamily("stereocam_signal",
                                     "1 while frames arrive, 0 while the no-signal frame shows.",
                                     value=1.0 if feed.signal else 0.0))
        with metrics._lock:
            encode = {k: (int(v[0]), float(v[1])) for k, v in metrics.encode.items()}
            uploads = dict(metrics.uploads)
            errors = dict(metrics.errors)
            requests = dict(metrics.requests)
            captures = metrics.captures
        encode_seconds = SummaryMetricFamily("stereocam_encode_seconds",
                                             "Time to JPEG-encode one frame of a view.", labels=["view"])
        for view, (count, total) in sorted(encode.items()):
            encode_seconds.add_metric([view], count_value=count, sum_value=total)
        out.append(encode_seconds)
        clients = GaugeMetricFamily("stereocam_clients", "Stream clients connected.", labels=["kind"])
        for kind, count in sorted(streams.by_kind().items()):
            clients.add_metric([kind], count)
        out.append(clients)
        out.append(CounterMetricFamily("stereocam_stream_clients_dropped",
                                       "Stream clients dropped for not reading.", value=streams.dropped))
        out.append(CounterMetricFamily("stereocam_stream_clients_refused",
                                       "Stream requests refused (max_streams).", value=streams.refused))
        out.append(_counter_by("stereocam_uploads", "Virtual-camera uploads by result.", "result",
                               {"ok": 0, **uploads}))
        errors["pipeline"] = errors.get("pipeline", 0) + pipeline.errors
        out.append(_counter_by("stereocam_errors", "Errors by where they happened.", "where", errors))
        out.append(_counter_by("stereocam_http_responses", "HTTP responses by status class.", "class",
                               requests))
        out.append(CounterMetricFamily("stereocam_captures", "Captures stored since start.", value=captures))
        out.append(GaugeMetricFamily("stereocam_uptime_seconds", "Seconds since the daemon started.",
                                     value=time.time() - metrics.started))
        faults = parts.extensions.active_faults()
        out.append(GaugeMetricFamily("stereocam_faults_active", "Faults active now (see stereocam_fault).",
                                     value=len(faults)))
        fault = GaugeMetricFamily("stereocam_fault", "1 for each fault active now, by the part it is on.",
                                  labels=["what"])
        for what in sorted({str(f["what"]) for f in faults}):
            fault.add_metric([what], 1)
        out.append(fault)
        return out


def _budget_families(budget: "CpuBudget", encoders: List[Dict[str, Any]]) -> List[Metric]:
    """The CPU budget and each watched view's rates under it (the fastest encoder of each view)."""
    out: List[Metric] = [
        GaugeMetricFamily("stereocam_cpu_budget_cores",
                          "Cores the daemon may spend on the views (cpu_budget).", value=budget.cores),
        GaugeMetricFamily("stereocam_cpu_used_cores",
                          "Cores the daemon used over the last 2 s, emulated hardware excluded.",
                          value=budget.used or 0.0),
    ]
    by_view: Dict[str, Dict[str, Any]] = {}
    for e in encoders:
        best = by_view.get(e["view"])
        if best is None or e["planned_fps"] > best["planned_fps"]:
            by_view[e["view"]] = e
    families = (("stereocam_view_target_frames_per_second",
                 "Frames per second a view's clients asked for, at most the fabric's rate.", "target_fps"),
                ("stereocam_view_planned_frames_per_second",
                 "Frames per second the CPU budget plans for a view.", "planned_fps"))
    for name, documentation, field in families:
        family = GaugeMetricFamily(name, documentation, labels=["view"])
        for view, e in sorted(by_view.items()):
            family.add_metric([view], float(e[field]))
        out.append(family)
    cost = GaugeMetricFamily("stereocam_view_cost_seconds",
                             "CPU seconds one frame of a view costs (render, encode, matching).",
                             labels=["view"])
    limited = GaugeMetricFamily("stereocam_view_limited",
                                "1 for a view planned below its target, with the reason.",
                                labels=["view", "reason"])
    for view, e in sorted(by_view.items()):
        if e["cost_ms"] is not None:
            cost.add_metric([view], e["cost_ms"] / 1e3)
        if e["limited_by"] and e["planned_fps"] < e["target_fps"]:
            limited.add_metric([view, e["limited_by"]], 1.0)
    return out + [cost, limited]


def _counter_by(name: str, documentation: str, label: str, counts: Dict[str, int]) -> CounterMetricFamily:
    family = CounterMetricFamily(name, documentation, labels=[label])
    for key, count in sorted(counts.items()):
        family.add_metric([key], count)
    return family


def make_registry(app: web.Application) -> CollectorRegistry:
    """A registry of ``app``'s own: the daemon's families, the process's and the platform's."""
    registry = CollectorRegistry()
    registry.register(DaemonCollector(DaemonParts(
        metrics=app[METRICS], pipeline=app[PIPELINE], encoders=app[ENCODERS], streams=app[STREAMS],
        feed=app[FEED], budget=app[BUDGET], extensions=app[EXTENSIONS])))
    ProcessCollector(registry=registry)
    PlatformCollector(registry=registry)
    return registry


def render(app: web.Application) -> bytes:
    """The text exposition of ``app[REGISTRY]`` (cheap; loop thread)."""
    return generate_latest(app[REGISTRY])


def healthy(feed: FrameFeed, extensions: Extensions, no_signal_s: float) -> Tuple[bool, str]:
    """True while frames flow (one within ``no_signal_s``, at least a second) and no fault is active.

    The text names every active fault, one per line, so a monitor's log says what is wrong.
    """
    limit = max(1.0, no_signal_s)
    age = feed.frame_age()
    problems = [f"{f['what']}: {f['text']}" for f in extensions.active_faults()]
    if age is None:
        problems.insert(0, "no frame yet")
    elif age > limit and not any(p.startswith("cameras:") for p in problems):
        problems.insert(0, f"no frame for {age:.1f} s")
    if problems:
        return False, "\n".join(problems)
    return True, "ok"


async def metrics_handler(request: web.Request) -> web.Response:
    return web.Response(body=render(request.app),
                        headers={"Content-Type": CONTENT_TYPE, "Cache-Control": "no-store"})


async def healthz_handler(request: web.Request) -> web.Response:
    app = request.app
    ok, text = healthy(app[FEED], app[EXTENSIONS], app[SETTINGS].no_signal_s)
    return web.Response(text=text + "\n", status=200 if ok else 503, headers={"Cache-Control": "no-store"})


def setup_routes(app: web.Application) -> None:
    """``GET /metrics``, ``GET /healthz`` and ``app[REGISTRY]`` (``app[METRICS]``, ``app[EXTENSIONS]`` first).

    The registry is made here, not at the first scrape: collectors never see a half-built app.
    """
    app[REGISTRY] = make_registry(app)
    app.router.add_get("/metrics", metrics_handler)
    app.router.add_get("/healthz", healthz_handler)

