"""Operations: counters of the daemon, ``GET /metrics`` (Prometheus text) and ``GET /healthz``.

:class:`Metrics` is written from any thread (encoders time themselves in
worker threads) and read by the handlers. Names (API.md):
``stereocam_fps{stage}``, ``stereocam_frames_total``, ``stereocam_drops_total``,
``stereocam_encode_seconds{view}`` (a summary: ``_count`` and ``_sum``),
``stereocam_clients{kind}``, ``stereocam_uploads_total{result}``,
``stereocam_errors_total{where}``, plus a few more, and whatever extensions add.
"""
from __future__ import annotations

import collections
import threading
import time
from typing import Any, Deque, Dict, List, Tuple

from aiohttp import web

from .state import CONFIG, ENCODERS, EXTENSIONS, FEED, METRICS, PIPELINE, STREAMS

__all__ = ["Metrics", "render", "setup_routes", "healthy"]


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


def _esc(value: Any) -> str:
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def render(app: web.Application) -> str:
    """The Prometheus text exposition of the daemon's state (cheap; loop thread)."""
    metrics = app[METRICS]
    pipeline, encoders, streams, feed = app[PIPELINE], app[ENCODERS], app[STREAMS], app[FEED]
    lines: List[str] = []

    def family(name: str, kind: str, help_text: str, samples: List[Tuple[Dict[str, Any], float]]) -> None:
        lines.append(f"# HELP {name} {help_text}")
        lines.append(f"# TYPE {name} {kind}")
        for labels, value in samples:
            label_text = ",".join(f'{k}="{_esc(v)}"' for k, v in labels.items())
            lines.append(f"{name}{{{label_text}}} {value:g}" if label_text else f"{name} {value:g}")

    fps: List[Tuple[Dict[str, Any], float]] = [
        ({"stage": "camera"}, pipeline.fabric_fps()),
        ({"stage": "pipeline"}, pipeline.meter.rate()),
        ({"stage": "disparity"}, encoders.disparity.meter.rate() if encoders.disparity.running else 0.0),
    ]
    fps += [({"stage": "encode", "view": view}, rate)
            for view, rate in sorted(encoders.fps_by_view().items())]
    family("stereocam_fps", "gauge", "Frames per second per stage over the last 2 s.", fps)
    family("stereocam_frames_total", "counter", "Frame sets the pipeline published.", [({}, pipeline.frames)])
    family("stereocam_drops_total", "counter",
           "Frames the fabric completed that the pipeline did not publish.",
           [({}, pipeline.drops)])
    family("stereocam_signal", "gauge", "1 while frames arrive, 0 while the no-signal frame shows.",
           [({}, 1.0 if feed.signal else 0.0)])
    with metrics._lock:
        encode = {k: tuple(v) for k, v in metrics.encode.items()}
        uploads = dict(metrics.uploads)
        errors = dict(metrics.errors)
        requests = dict(metrics.requests)
    lines.append("# HELP stereocam_encode_seconds Time to JPEG-encode one frame of a view.")
    lines.append("# TYPE stereocam_encode_seconds summary")
    for view, (count, total) in sorted(encode.items()):
        lines.append(f'stereocam_encode_seconds_count{{view="{_esc(view)}"}} {count:g}')
        lines.append(f'stereocam_encode_seconds_sum{{view="{_esc(view)}"}} {total:.6f}')
    family("stereocam_clients", "gauge", "Stream clients connected.",
           [({"kind": k}, float(v)) for k, v in sorted(streams.by_kind().items())])
    family("stereocam_stream_clients_dropped_total", "counter", "Stream clients dropped for not reading.",
           [({}, streams.dropped)])
    family("stereocam_stream_clients_refused_total", "counter", "Stream requests refused (max_streams).",
           [({}, streams.refused)])
    family("stereocam_uploads_total", "counter", "Virtual-camera uploads by result.",
           [({"result": k}, float(v)) for k, v in sorted(uploads.items())] or [({"result": "ok"}, 0.0)])
    family("stereocam_errors_total", "counter", "Errors by where they happened.",
           [({"where": k}, float(v)) for k, v in sorted(errors.items())]
           + [({"where": "pipeline"}, float(pipeline.errors))])
    family("stereocam_http_responses_total", "counter", "HTTP responses by status class.",
           [({"class": k}, float(v)) for k, v in sorted(requests.items())])
    family("stereocam_captures_total", "counter", "Captures stored since start.", [({}, metrics.captures)])
    family("stereocam_uptime_seconds", "gauge", "Seconds since the daemon started.",
           [({}, round(time.time() - metrics.started, 3))])
    faults = app[EXTENSIONS].active_faults()
    family("stereocam_faults_active", "gauge", "Faults active now (see stereocam_fault).", [({}, len(faults))])
    family("stereocam_fault", "gauge", "1 for each fault active now, by the part it is on.",
           [({"what": f["what"]}, 1) for f in faults])
    lines.extend(app[EXTENSIONS].metrics_lines())
    return "\n".join(lines) + "\n"


def healthy(app: web.Application) -> Tuple[bool, str]:
    """True while frames flow (one within ``no_signal_s``, at least a second) and no fault is active.

    The text names every active fault, one per line, so a monitor's log says what is wrong.
    """
    limit = max(1.0, app[CONFIG].no_signal_s)
    age = app[FEED].frame_age()
    problems = [f"{f['what']}: {f['text']}" for f in app[EXTENSIONS].active_faults()]
    if age is None:
        problems.insert(0, "no frame yet")
    elif age > limit and not any(p.startswith("cameras:") for p in problems):
        problems.insert(0, f"no frame for {age:.1f} s")
    if problems:
        return False, "\n".join(problems)
    return True, "ok"


async def metrics_handler(request: web.Request) -> web.Response:
    return web.Response(body=render(request.app).encode("utf-8"),
                        headers={"Content-Type": "text/plain; version=0.0.4; charset=utf-8",
                                 "Cache-Control": "no-store"})


async def healthz_handler(request: web.Request) -> web.Response:
    ok, text = healthy(request.app)
    return web.Response(text=text + "\n", status=200 if ok else 503, headers={"Cache-Control": "no-store"})


def setup_routes(app: web.Application) -> None:
    app.router.add_get("/metrics", metrics_handler)
    app.router.add_get("/healthz", healthz_handler)

