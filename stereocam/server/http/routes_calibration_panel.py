"""The page's calibration panel over HTTP: live corners, pairs, coverage, compute, apply.

- ``GET/PUT /api/calibration/session``: the board (``pattern`` "9x6",
  ``square_mm``), ``alpha``, the stored pairs with their corners, coverage
  per camera, the compute's progress and the candidate's figures.
- ``GET /api/calibration/corners``: corners on a frame newer than the
  request (fast detector). Detection runs at most every
  :data:`LIVE_MIN_INTERVAL_S` whatever the number of clients: polling
  clients share the latest result. ``GET /api/calibration/corners/{frame}/{side}.jpg``:
  the raw image of a recent detection's frame, so the page draws the corners on the
  very frame they were found in.
- ``POST /api/calibration/pairs``: capture the next frame as a pair, only
  when the pattern is in both images (else 422) and the view differs from
  every stored pair (else 409). ``DELETE /api/calibration/pairs[/{id}]``.
- ``POST /api/calibration/compute``: calibrate from the stored pairs in a
  worker (one at a time: 409 while one runs; ``GET`` gives its progress).
  The result is the candidate: ``GET /api/calibration/candidate`` (report
  and file text), ``.../candidate.yaml``, ``.../candidate/rectified.png``.
- ``POST /api/calibration/apply`` with ``{"id": candidate id}``: program
  the core and write the calibration file, exactly as ``PUT
  /api/calibration`` does (refused: the previous calibration stays).
"""
from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Set

from aiohttp import web

from ...calibration.calibrate import CalibrationReport
from ..errors import ApiError
from ..frames.encoders import encode_image
from ..frames.pipeline import FrameSet
from ..frames.views import render
from ..stores.calibration_pairs import (
    PAIRS_FOLDER,
    PURPOSE,
    PanelError,
    PanelSettings,
    compute,
    coverage,
    detect_frame,
    load_settings,
    missing_in,
    pair_entries,
    pair_ids,
    rectified_figure,
    same_view,
    save_settings,
)
from ..stores.captures import CaptureError, CaptureStore
from .bodies import json_response, read_json
from .metrics import METRICS
from .routes_calibration import activate, check_runnable
from .state import CAPTURING, EXECUTORS, FEED, OVERLAY, SETTINGS

log = logging.getLogger(__name__)

__all__ = ["setup", "PANEL", "Panel", "LIVE_MIN_INTERVAL_S", "pairs_folder"]

LIVE_MIN_INTERVAL_S = 0.2
LIVE_FRAMES_KEPT = 3  # detection frames whose images GET /api/calibration/corners/{frame}/{side}.jpg serves


@dataclass
class Candidate:
    """A computed calibration awaiting review: the report and the pairs it came from."""

    report: CalibrationReport
    pair_ids: List[str]
    computed_at: float

    @property
    def id(self) -> str:
        return self.report.calibration.id

    def to_json(self) -> Dict[str, Any]:
        body = self.report.to_dict()
        for entry, pid in zip(body["pairs"], self.pair_ids, strict=True):
            entry["id"] = pid
        worst = max((p for p in body["pairs"] if p["used"]), key=lambda p: p["row_error_max"] or 0.0,
                    default=None)
        return {"id": self.id, "computed_at": self.computed_at, "report": body, "lines": self.report.lines(),
                "worst_pair": worst["id"] if worst else None, "fits": self.report.fits,
                "yaml": self.report.calibration.to_yaml()}


@dataclass
class Panel:
    """The panel's state: settings, the pair store, the latest live corners, the compute and its result."""

    folder: Path
    store: CaptureStore
    settings: PanelSettings
    live: Optional[Dict[str, Any]] = None
    live_at: float = 0.0
    live_frames: List[FrameSet] = field(default_factory=list)  # the last detections' frames, newest last
    live_lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    pairs_lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    settings_lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    computing: Optional[Set[str]] = None  # the pair ids of the compute that runs
    progress: Dict[str, Any] = field(default_factory=lambda: {"state": "idle"})
    candidate: Optional[Candidate] = None


PANEL: "web.AppKey[Panel]" = web.AppKey("stereocam.calibration.panel", Panel)


def pairs_folder(config: Any) -> Path:
    """Where the panel keeps its pairs: ``<state_dir>/calibration-pairs``, beside ``calibration.yaml``."""
    return config.state_path / PAIRS_FOLDER


def _frame_size(app: web.Application) -> Any:
    w, h = app[OVERLAY].frame_size
    return int(w), int(h)


async def _session_body(app: web.Application) -> Dict[str, Any]:
    panel = app[PANEL]
    entries = await app[EXECUTORS].run(pair_entries, panel.store)
    size = _frame_size(app)
    cover = await app[EXECUTORS].run(coverage, entries, size)
    cand = panel.candidate
    return {"settings": panel.settings.to_json(), "folder": str(panel.folder), "image_size": list(size),
            "pairs": entries, "count": len(entries), "coverage": cover, "progress": dict(panel.progress),
            "candidate": None if cand is None else {"id": cand.id, "fits": cand.report.fits,
                                                    "rms": cand.report.rms}}


# -- routes -----------------------------------------------------------------------------------------

async def get_session(request: web.Request) -> web.Response:
    return json_response(await _session_body(request.app), headers={"Cache-Control": "no-store"})


async def put_session(request: web.Request) -> web.Response:
    app = request.app
    panel = app[PANEL]
    doc = await read_json(request, example='{"pattern": "9x6", "square_mm": 25}', typed=False)
    try:
        async with panel.settings_lock:  # read, change, save, set: concurrent PUTs lose nothing
            settings = panel.settings.updated(doc)
            await app[EXECUTORS].run(save_settings, panel.folder, settings)
            panel.settings = settings
    except OSError as exc:
        raise ApiError(f"cannot write the panel's settings in {panel.folder}: {exc.strerror or exc}; "
                       "the previous settings stay", status=500) from None
    panel.live, panel.live_at = None, 0.0
    return json_response(await _session_body(app))


async def get_corners(request: web.Request) -> web.Response:
    """Corners on a recent frame: shared by every poller, recomputed at most every LIVE_MIN_INTERVAL_S."""
    app = request.app
    panel = app[PANEL]
    asked = time.monotonic()
    feed = app[FEED]
    since = feed.last_frame_at if feed.last_frame_at is not None else feed.started_at
    if asked - since > app[SETTINGS].frame_wait_s:
        # No frame for longer than a capture would wait: answer now, pollers must not queue up.
        raise ApiError(f"no signal: no frame has come for {asked - since:.1f} s", status=503)
    async with panel.live_lock:
        if panel.live is None or panel.live_at < asked - LIVE_MIN_INTERVAL_S:
            fs = await app[CAPTURING].fresh_raw_frame()
            settings = panel.settings
            raw = fs.raw
            assert raw is not None
            found = await app[EXECUTORS].run(lambda: detect_frame(raw, settings.pattern, thorough=False))
            panel.live = {"frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source,
                          "image_size": list(fs.size), "pattern": str(settings.pattern), **found,
                          "found": missing_in(found) is None}
            panel.live_at = time.monotonic()
            panel.live_frames = [*panel.live_frames, fs][-LIVE_FRAMES_KEPT:]
        body = panel.live
    return json_response(body, headers={"Cache-Control": "no-store"})


async def get_corners_frame(request: web.Request) -> web.Response:
    """JPEG of one camera's raw image of a recent detection's frame (``?scale=0.5|0.25|1``)."""
    app = request.app
    side = request.match_info["side"]
    try:
        frame = int(request.match_info["frame"])
        scale = float(request.query.get("scale", "1"))
    except ValueError:
        raise ApiError("give the frame as a number and scale as 1, 0.5 or 0.25", status=400) from None
    if side not in ("left", "right") or scale not in (1.0, 0.5, 0.25):
        raise ApiError("side is left or right, scale 1, 0.5 or 0.25", status=400)
    fs = next((f for f in app[PANEL].live_frames if f.frame == frame), None)
    if fs is None:
        raise ApiError(f"frame {frame} is not one of the last corner detections: "
                       "ask GET /api/calibration/corners again", status=404)
    jpeg = await app[EXECUTORS].run(lambda: encode_image(render(fs, "raw_" + side, False, scale), ".jpg", 85))
    return web.Response(body=jpeg, content_type="image/jpeg",
                        headers={"X-Frame-Number": str(fs.frame), "Cache-Control": "private, max-age=60"})


async def post_pair(request: web.Request) -> web.Response:
    app = request.app
    panel = app[PANEL]
    async with panel.pairs_lock:
        settings = panel.settings
        fs = await app[CAPTURING].fresh_raw_frame()
        raw = fs.raw
        assert raw is not None
        found = await app[EXECUTORS].run(lambda: detect_frame(raw, settings.pattern, thorough=True))
        where = missing_in(found)
        if where is not None:
            raise ApiError(f"the {settings.pattern} pattern was not found in {where} (frame {fs.frame}): "
                           "hold the whole board in view of both cameras, still and well lit; "
                           "nothing was stored", status=422)
        entries = await app[EXECUTORS].run(pair_entries, panel.store)
        twin = same_view(found, entries)
        if twin is not None:
            raise ApiError(f"the board is where it was in pair {twin}: move or tilt it before the next pair "
                           "(the same view adds nothing); nothing was stored", status=409)
        extra = {"purpose": PURPOSE, "pattern": str(settings.pattern),
                 "square_mm": settings.pattern.square * 1000.0,
                 "corners": {"left": found["left"], "right": found["right"]}}
        try:
            info = await app[CAPTURING].store(panel.store, fs, extra, depth=False)  # pairs: corners only
        except CaptureError as exc:
            app[METRICS].error(exc.message, "calibration")
            raise
    body = await _session_body(app)
    pair = next((p for p in body["pairs"] if p["id"] == info.id), None)
    log.info("calibration pair %s stored (frame %d, %d pairs)", info.id, fs.frame, body["count"])
    return json_response({"pair": pair, **body}, status=201)


async def delete_pair(request: web.Request) -> web.Response:
    app = request.app
    panel = app[PANEL]
    pid = request.match_info["id"]
    if panel.computing is not None and pid in panel.computing:
        raise ApiError(f"pair {pid} is in the calibration being computed: delete it when that is done",
                       status=409)
    async with panel.pairs_lock:
        await app[EXECUTORS].run(panel.store.delete, pid)
    return web.Response(status=204)


async def delete_pairs(request: web.Request) -> web.Response:
    app = request.app
    panel = app[PANEL]
    if panel.computing is not None:
        raise ApiError("a calibration is being computed from the pairs: delete them when that is done",
                       status=409)
    async with panel.pairs_lock:
        for info in await app[EXECUTORS].run(panel.store.list):
            await app[EXECUTORS].run(panel.store.delete, info.id)
    return web.Response(status=204)


async def get_compute(request: web.Request) -> web.Response:
    return json_response(dict(request.app[PANEL].progress), headers={"Cache-Control": "no-store"})


async def post_compute(request: web.Request) -> web.Response:
    app = request.app
    panel = app[PANEL]
    doc = await read_json(request, example='{"alpha": 0.5}', optional=True, typed=False)
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise PanelError('send no body, or a JSON object of settings to use, e.g. {"alpha": 0.5}', status=400)
    settings = panel.settings.updated(doc)
    if panel.computing is not None:  # checked and set with no await between: one at a time
        raise ApiError("a calibration is already being computed: wait for it "
                       "(GET /api/calibration/compute shows its progress)", status=409)
    panel.computing = set()
    started = time.time()
    panel.progress = {"state": "running", "stage": "detect", "done": 0, "total": 0, "started": started}

    def progress(stage: str, done: int, total: int) -> None:  # worker thread: replace, never mutate
        panel.progress = {"state": "running", "stage": stage, "done": done, "total": total,
                          "started": started}

    rectify = app[OVERLAY].rectify
    try:
        async with panel.pairs_lock:  # a snapshot: pairs captured meanwhile wait for the next compute
            ids = await app[EXECUTORS].run(pair_ids, panel.store)
        panel.computing = set(ids)
        # It reads the pairs and writes nothing, so shutdown may stop it anywhere rather than wait.
        report = await app[EXECUTORS].run_abandonable(
            lambda: compute(panel.store, ids, settings, rectify, progress=progress))
    except PanelError as exc:
        panel.progress = {"state": "failed", "error": exc.message, "started": started}
        raise
    except Exception as exc:  # logged, with its traceback, by the error middleware
        panel.progress = {"state": "failed", "error": f"{type(exc).__name__}: {exc}", "started": started}
        raise
    finally:
        panel.computing = None
        if panel.progress.get("state") == "running":  # cancelled (client gone, shutdown)
            panel.progress = {"state": "failed", "error": "the compute was interrupted", "started": started}
    panel.candidate = Candidate(report, ids, time.time())
    panel.progress = {"state": "done", "started": started, "seconds": round(time.time() - started, 2),
                      "id": panel.candidate.id}
    log.info("calibration computed from %d pairs: RMS %.3f px, row error %.3f px, %s", report.pairs_used,
             report.rms, report.row_error_mean, report.calibration.id)
    return json_response(panel.candidate.to_json())


def _candidate(app: web.Application) -> Candidate:
    cand = app[PANEL].candidate
    if cand is None:
        raise PanelError("no calibration has been computed yet: capture pairs, then "
                         "POST /api/calibration/compute", status=404)
    return cand


async def get_candidate(request: web.Request) -> web.Response:
    return json_response(_candidate(request.app).to_json(), headers={"Cache-Control": "no-store"})


async def candidate_yaml(request: web.Request) -> web.Response:
    cand = _candidate(request.app)
    return web.Response(text=cand.report.calibration.to_yaml(), content_type="application/yaml",
                        headers={"Content-Disposition": 'attachment; filename="calibration.yaml"'})


async def candidate_rectified(request: web.Request) -> web.Response:
    app = request.app
    cand = _candidate(app)
    pair = request.query.get("pair") or next(
        (pid for p, pid in zip(cand.report.pairs, cand.pair_ids, strict=True) if p.used), None)
    if pair not in cand.pair_ids:
        raise PanelError(f"pair {str(pair)[:40]!r} is not one the candidate was computed from", status=404)
    png = await app[EXECUTORS].run(rectified_figure, app[PANEL].store, pair, cand.report,
                                   app[OVERLAY].rectify.lb_rows)
    return web.Response(body=png, content_type="image/png", headers={"Cache-Control": "no-store"})


async def post_apply(request: web.Request) -> web.Response:
    app = request.app
    doc = await read_json(request, example='{"id": "<the candidate\'s id>"}', typed=False)
    if not isinstance(doc, dict) or set(doc) != {"id"} or not isinstance(doc["id"], str):
        raise PanelError('send {"id": "<the candidate\'s id>"} (GET /api/calibration/candidate gives it)',
                         status=400)
    cand = _candidate(app)
    if doc["id"] != cand.id:
        raise PanelError(f"the candidate is now {cand.id}, not {doc['id'][:40]}: review it, then apply it",
                         status=409)
    cal, rectify, size = cand.report.calibration, app[OVERLAY].rectify, _frame_size(app)
    body = await activate(app, lambda: check_runnable(cal, rectify, size), "calibration panel")
    return json_response(body)


def setup(app: web.Application) -> None:
    folder = pairs_folder(app[SETTINGS])
    store = CaptureStore(folder, min_free_bytes=int(app[SETTINGS].min_free_mb * 1e6))
    app[PANEL] = Panel(folder=folder, store=store, settings=load_settings(folder))
    r = app.router
    r.add_get("/api/calibration/session", get_session)
    r.add_put("/api/calibration/session", put_session)
    r.add_get("/api/calibration/corners", get_corners)
    r.add_get("/api/calibration/corners/{frame}/{side}.jpg", get_corners_frame)
    r.add_post("/api/calibration/pairs", post_pair)
    r.add_delete("/api/calibration/pairs", delete_pairs)
    r.add_delete(r"/api/calibration/pairs/{id:[^/]+}", delete_pair)
    r.add_get("/api/calibration/compute", get_compute)
    r.add_post("/api/calibration/compute", post_compute)
    r.add_get("/api/calibration/candidate", get_candidate)
    r.add_get("/api/calibration/candidate.yaml", candidate_yaml)
    r.add_get("/api/calibration/candidate/rectified.png", candidate_rectified)
    r.add_post("/api/calibration/apply", post_apply)
