"""Recordings over HTTP: start, stop, list, download, delete with undo; opening one for the virtual camera.

The recording itself (when it starts and ends) is :mod:`..frames.recorder`, what is stored
:mod:`..stores.recordings`;
these handlers check requests, answer, and run the blocking parts on the daemon's
``work`` threads. Recordings live in ``<state_dir>/recordings/`` and keep
``min_free_mb`` free on that disk, as captures do. See stereocam/server/API.md, "Recordings".
"""
from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any, AsyncIterator, Dict, Optional

from aiohttp import web

from ...overlays import backend
from ...overlays.interface import Replay
from ..errors import ApiError
from ..frames.recorder import MAX_SECONDS, Recorder
from ..stores.recordings import RecordingStore
from .bodies import json_response, read_json
from .downloads import stream_download
from .security import refuse_if_gone
from .state import CALIBRATION, EXECUTORS, FEED, OVERLAY, PIPELINE, SETTINGS, VIRTUAL

__all__ = ["RECORDINGS", "RECORDER", "setup", "open_replay"]

RECORDINGS: "web.AppKey[RecordingStore]" = web.AppKey("stereocam.recordings", RecordingStore)
RECORDER: "web.AppKey[Recorder]" = web.AppKey("stereocam.recorder", Recorder)
STOP_WAIT_S = 120.0  # a stop waits for the queued frames to be written and the folder synced


def setup(app: web.Application) -> None:
    """The recordings store, the recorder and their routes (``create_app`` calls it via routes_api)."""
    config = app[SETTINGS]
    store = RecordingStore(Path(config.state_path) / "recordings",
                           min_free_bytes=int(config.min_free_mb * 1e6))
    app[RECORDINGS] = store
    app[RECORDER] = Recorder(store, app[PIPELINE],
                             calibration_for=lambda count: app[CALIBRATION].for_frame(count),
                             raw_stores=app[OVERLAY].raw_stores)
    r = app.router
    r.add_get("/api/recordings", list_recordings)
    r.add_post("/api/recordings", start_recording)
    r.add_get(r"/api/recordings/{id:[^/]+}.zip", recording_zip)
    r.add_post(r"/api/recordings/{id:[^/]+}/stop", stop_recording)
    r.add_post(r"/api/recordings/{id:[^/]+}/restore", restore_recording)
    r.add_get(r"/api/recordings/{id:[^/]+}/frames/{index}/{side}.png", recording_frame)
    r.add_get(r"/api/recordings/{id:[^/]+}", get_recording)
    r.add_delete(r"/api/recordings/{id:[^/]+}", delete_recording)
    app.on_shutdown.append(_end_recording)
    app.cleanup_ctx.append(_recorder_ctx)


async def _end_recording(app: web.Application) -> None:
    """Shutdown, while frames still flow: stop a playing recording; end and keep a running one."""
    await app[VIRTUAL].stop_player()
    await asyncio.get_running_loop().run_in_executor(None, app[RECORDER].stop_all, "shutdown", STOP_WAIT_S)


async def _recorder_ctx(app: web.Application) -> AsyncIterator[None]:
    yield
    await _end_recording(app)  # an app that never served (tests) has no on_shutdown run


# -- handlers ------------------------------------------------------------------------------------------

def _seconds(doc: Any) -> Optional[float]:
    if doc is None:
        return None
    if not isinstance(doc, dict) or set(doc) - {"seconds"}:
        raise ApiError('send no body (record until stopped) or {"seconds": N}', status=400)
    value = doc.get("seconds")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not 0 < value <= MAX_SECONDS:
        raise ApiError(f"seconds must be a number above 0 and at most {MAX_SECONDS:g} (or null: until "
                       f"stopped); got {str(value)[:40]}", status=400)
    return float(value)


async def start_recording(request: web.Request) -> web.Response:
    app = request.app
    seconds = _seconds(await read_json(request, example='{"seconds": 10}', optional=True))
    if not app[FEED].signal:
        raise ApiError("no signal: no frame is coming from the fabric, so there is nothing to record; "
                       "check the cameras (GET /api/status)", status=503)
    pipeline, overlay = app[PIPELINE], app[OVERLAY]
    fps = pipeline.fabric_fps() or (1.0 / pipeline.period if pipeline.period else None)
    meta: Dict[str, Any] = {"backend": overlay.backend, "core_impl": overlay.core_kind}
    refuse_if_gone(request)  # an until-stopped recording nobody would know the id of
    rec = await app[EXECUTORS].run(lambda: app[RECORDER].start(
        seconds=seconds, frame_size=overlay.frame_size, fps=fps,
        frame_no=pipeline.last_frame_number or 0, meta=meta))
    return json_response(rec.to_json(), status=201, headers={"Location": f"/api/recordings/{rec.id}"})


async def list_recordings(request: web.Request) -> web.Response:
    app = request.app
    recorder = app[RECORDER]
    infos = await app[EXECUTORS].run(app[RECORDINGS].list)
    running = recorder.current
    entries = [running.to_json()] if running is not None else []
    last = recorder.last
    return json_response({
        "recordings": entries + [i.to_json() for i in infos if running is None or i.id != running.id],
        "recording": running.id if running is not None else None,
        "last_error": last.error if last is not None and last.error else None,
    }, headers={"Cache-Control": "no-store"})


async def get_recording(request: web.Request) -> web.Response:
    app, rid = request.app, request.match_info["id"]
    running = app[RECORDER].get(rid)
    if running is not None:
        return json_response(running.to_json(), headers={"Cache-Control": "no-store"})
    info = await app[EXECUTORS].run(app[RECORDINGS].get, rid)
    return json_response(info.to_json(meta=True))


async def stop_recording(request: web.Request) -> web.Response:
    app, rid = request.app, request.match_info["id"]
    rec = app[RECORDER].get(rid)
    if rec is None:  # finished already (or never was): answer what there is
        info = await app[EXECUTORS].run(app[RECORDINGS].get, rid)
        return json_response(info.to_json())
    rec.stop("stopped")
    kept = await asyncio.get_running_loop().run_in_executor(None, rec.join, STOP_WAIT_S)
    if kept is None:
        if rec.running:
            raise ApiError(f"recording {rid} is still being written; list the recordings in a moment",
                           status=504)
        status = 507 if rec.end == "disk_full" else 503 if rec.frames == 0 else 500
        raise ApiError(rec.error or "nothing was recorded", status=status)
    return json_response(kept.to_json())


async def recording_zip(request: web.Request) -> web.StreamResponse:
    app, rid = request.app, request.match_info["id"]
    if app[RECORDER].get(rid) is not None:
        raise ApiError(f"recording {rid} is still running: stop it or wait for it to end, then download it",
                       status=409)
    chunks = await app[EXECUTORS].run(app[RECORDINGS].zip_stream, rid)
    return await stream_download(request, chunks, filename=f"{rid}.zip", content_type="application/zip",
                                 run=app[EXECUTORS].run)


async def delete_recording(request: web.Request) -> web.Response:
    app, rid = request.app, request.match_info["id"]
    if app[RECORDER].get(rid) is not None:
        raise ApiError(f"recording {rid} is running: stop it first (POST /api/recordings/{rid}/stop)",
                       status=409)
    player = app[VIRTUAL].player
    if player is not None and player.running and player.id == rid:
        raise ApiError(f"recording {rid} is playing through the virtual camera: choose another input or the "
                       "live source first", status=409)
    # Into the store's trash, as captures go: POST /api/recordings/{id}/restore undoes it.
    await app[EXECUTORS].run(app[RECORDINGS].trash, rid)
    return web.Response(status=204)


async def recording_frame(request: web.Request) -> web.Response:
    """One stored frame of a finished recording (the capture viewer's stepping): the PNG as recorded,
    with the frame count in ``X-Frames``."""
    app, rid = request.app, request.match_info["id"]
    text, side = request.match_info["index"], request.match_info["side"]
    if side not in ("left", "right"):
        raise ApiError(f"no side {side[:20]!r}: ask for left.png or right.png", status=404)
    if not (text.isascii() and text.isdigit()) or len(text) > 9:
        raise ApiError(f"frame index must be a whole number 0 or above, got {text[:20]!r}", status=400)
    if app[RECORDER].get(rid) is not None:
        raise ApiError(f"recording {rid} is still running: its frames can be stepped through once it ends",
                       status=409)
    body, frames = await app[EXECUTORS].run(app[RECORDINGS].frame_png, rid, int(text), side)
    # an IHDR colour type of 0 is gray (every recording's PNG starts with a 25-byte header and IHDR)
    color = "gray" if len(body) > 25 and body[25] == 0 else "rgb"
    return web.Response(body=body, content_type="image/png", headers={
        "X-Frames": str(frames), "X-Color": color, "Cache-Control": "private, max-age=3600",
        "Content-Disposition": f'inline; filename="{rid}-{side}_{int(text):06d}.png"'})


async def restore_recording(request: web.Request) -> web.Response:
    """The undo of ``DELETE /api/recordings/{id}``: the recording back from the trash, as it was."""
    app = request.app
    info = await app[EXECUTORS].run(app[RECORDINGS].restore, request.match_info["id"])
    return json_response(info.to_json(), headers={"Location": f"/api/recordings/{info.id}"})


# -- the virtual camera's side -----------------------------------------------------------------------

async def open_replay(app: web.Application, rid: str) -> Replay:
    """The finished recording ``rid`` read back, looping, for the virtual camera.

    ApiError 400 malformed id, 404 unknown (or still recording), 422 damaged or of
    another frame size than the fabric's.
    """
    store = app[RECORDINGS]

    def open_it() -> Replay:
        folder = store.path(rid)
        try:
            source = backend.open_replay(folder, loop=True)
        except backend.SourceError as exc:
            raise ApiError(f"recording {rid} cannot be replayed: {exc}", status=422) from None
        if not source.is_recording:
            source.close()
            raise ApiError(f"recording {rid} cannot be replayed: it has no recording.json", status=422)
        w, h = app[OVERLAY].frame_size
        if source.frame_size != (w, h):
            rw, rh = source.frame_size
            source.close()
            raise ApiError(f"recording {rid} is {rw}x{rh}, the fabric takes {w}x{h}", status=422)
        try:
            source.frame(0)  # decoded (and kept) now: a damaged first frame is a 422, not a failed request
        except ValueError as exc:
            source.close()
            raise ApiError(f"recording {rid} cannot be replayed: {exc}", status=422) from None
        return source

    return await app[EXECUTORS].run(open_it)
