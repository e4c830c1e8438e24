"""The control API: status, source, virtual camera (flows 4 and 6), verify (flow 5) and captures (flow 1).

Handlers stay on the event loop only to parse, check and answer; anything
that blocks (register dumps, image decoding, the model, PNG encoding, disk)
runs on the daemon's ``work`` threads. Every refusal is ``{"error": "..."}``
with a 4xx/5xx status, and a refused request changes nothing.
"""
from __future__ import annotations

import asyncio
import json
import logging
import mimetypes
import os
import stat
import time
from typing import Any, Callable, Dict, Optional, Tuple, TypeVar

import numpy as np
from aiohttp import BodyPartReader, web

from ...overlays.spec import pixel
from ..errors import ApiError
from ..frames.depth import DepthNotTaken, disparity_by, model_of, stereo_of
from ..frames.encoders import png_for
from ..frames.feed import BroadcastClosed
from ..frames.pipeline import FrameSet
from ..frames.verify import compare, compare_stereo, difference_image
from ..frames.views import REGISTRY, arm_status
from ..frames.virtual_camera import VerifyResult, VirtualCamera
from ..stores.captures import CaptureError, CaptureStore
from ..stores.errors import NotFound
from .bodies import json_response, read_json
from .downloads import stream_download
from .errors import shutting_down
from .metrics import METRICS
from .routes_cloud import setup_routes as setup_cloud_routes
from .routes_stereo import setup_routes as setup_stereo_routes
from .routes_tools import setup_routes as setup_tools_routes
from .routes_viewer import setup_routes as setup_viewer_routes
from .state import (
    BUDGET,
    CALIBRATION,
    CAPTURES,
    CAPTURING,
    ENCODERS,
    EXECUTORS,
    EXTENSIONS,
    FEED,
    OVERLAY,
    PIPELINE,
    SETTINGS,
    VIRTUAL,
)
from .streams import STREAMS
from .uploads import (
    PAIR_FIELDS,
    SBS_FIELD,
    Fit,
    UploadError,
    decode_pair_fitted,
    parse_fit,
    parse_json_replay_request,
)

log = logging.getLogger(__name__)
FIT_FIELD = "fit"  # the upload's optional text field naming the fit (or ?fit= in the URL)

__all__ = ["setup_routes"]

T = TypeVar("T")
SOURCES = ("live", "virtual")


async def _run(request: web.Request, fn: Callable[..., T], *args: Any) -> T:
    return await request.app[EXECUTORS].run(fn, *args)


# -- status and source ------------------------------------------------------------------------------

async def status_handler(request: web.Request) -> web.Response:
    app = request.app
    overlay, pipeline, feed, streams = app[OVERLAY], app[PIPELINE], app[FEED], app[STREAMS]
    try:
        hw = await _run(request, overlay.status)
    except Exception as exc:  # registers unreadable: say so, keep the rest
        hw = {"core": None, "vdma": None, "error": str(exc)}
    choice = overlay.choice
    fps: Dict[str, float] = {"camera": round(pipeline.fabric_fps(), 2),
                             "pipeline": round(pipeline.meter.rate(), 2)}
    encoders = app[ENCODERS]
    if encoders.disparity.running:
        fps["disparity"] = round(encoders.disparity.meter.rate(), 2)
    fps.update(encoders.fps_by_view())
    metrics = app[METRICS]
    errors = metrics.recent()
    if pipeline.last_error:
        errors.append(f"pipeline: {pipeline.last_error}")
    age = feed.frame_age()
    calibration = app[CALIBRATION].now
    body: Dict[str, Any] = {
        "backend": overlay.backend,
        "backend_reason": choice.reason if choice is not None else None,
        "backend_warning": choice.warning if choice is not None else None,
        "source": app[VIRTUAL].source,
        "mux": hw.get("source"),
        "frame_size": list(overlay.frame_size),
        "signal": feed.signal,
        "last_frame": {"frame": pipeline.last_frame_number, "age_s": None if age is None else round(age, 3)},
        "fps": fps,
        "frames": pipeline.frames,
        "frames_seen": pipeline.frames_seen,
        "drops": pipeline.drops,
        "core": hw.get("core"),
        "core_impl": overlay.core_kind,
        # Which computes the disparity, and the stereo core's state (null without one).
        "disparity": {"by": disparity_by(pipeline.has_stereo), "stereo": hw.get("stereo"),
                      "arm": None if pipeline.has_stereo else arm_status(
                          pipeline.arm_scale, overlay.frame_size, app[ENCODERS].disparity.fps)},
        "vdma": hw.get("vdma"),
        "calibration": {**calibration.to_json(), "changing": calibration.changing},
        "virtual_camera": app[VIRTUAL].to_json(),
        "clients": len(streams),
        "max_streams": streams.max_streams,
        "streams": [c.to_json() for c in streams.clients.values()],
        "encoders": encoders.status(),
        "cpu": app[BUDGET].status(),
        "uptime_s": round(time.time() - metrics.started, 1),
        "access_token": app[SETTINGS].access_token is not None,
        "errors": errors[-20:],
    }
    now = time.time()
    body["faults"] = [{**f, "for_s": round(now - f["since"], 3) if f.get("since") else None}
                      for f in app[EXTENSIONS].active_faults()]
    body.update(app[EXTENSIONS].status_sections())
    return json_response(body, headers={"Cache-Control": "no-store"})


async def get_views(request: web.Request) -> web.Response:
    """``GET /api/views``: the view registry (stereocam/server/frames/views.py), in the page's order."""
    return json_response({"views": [v.as_json() for v in REGISTRY]})


async def get_source(request: web.Request) -> web.Response:
    return json_response({"source": request.app[VIRTUAL].source})


async def put_source(request: web.Request) -> web.Response:
    doc = await read_json(request, example='{"source": "live"}')
    if not isinstance(doc, dict) or set(doc) != {"source"} or doc["source"] not in SOURCES:
        raise ApiError('send {"source": "live"} or {"source": "virtual"}', status=400)
    await request.app[VIRTUAL].select(request.app[EXECUTORS].work, doc["source"])
    return json_response({"source": request.app[VIRTUAL].source})


# -- virtual camera ---------------------------------------------------------------------------------

async def _read_fields(request: web.Request, limit: int) -> Dict[str, bytes]:
    """The multipart fields of an upload, at most ``limit`` bytes in all (413 beyond)."""
    fields: Dict[str, bytes] = {}
    total = 0
    try:
        reader = await request.multipart()
        while True:
            part = await reader.next()
            if part is None:
                break
            if not isinstance(part, BodyPartReader):
                raise ApiError("nested multipart bodies are not accepted: "
                               "send the fields left and right, or sbs", status=400)
            name = part.name
            if name not in PAIR_FIELDS and name != SBS_FIELD and name != FIT_FIELD:
                raise ApiError(f"unknown field {str(name)[:40]!r}: send the fields left and right "
                               "(a stereo pair) or one field sbs (a side-by-side image), and optionally fit",
                               status=400)
            if name in fields:
                raise ApiError(f"field {name} was sent twice", status=400)
            data = bytearray()
            while True:
                chunk = await part.read_chunk(1 << 16)
                if not chunk:
                    break
                total += len(chunk)
                if total > limit:
                    raise ApiError(f"the upload is larger than {limit} bytes (max_upload_bytes)", status=413)
                data.extend(chunk)
            fields[name] = bytes(data)
    except (ApiError, web.HTTPException):
        raise
    except (ValueError, AssertionError, KeyError, asyncio.IncompleteReadError) as exc:
        raise ApiError(f"malformed multipart body ({type(exc).__name__}): send multipart/form-data "
                       "with fields left and right, or sbs", status=400) from None
    return fields


def _fit_choice(request: web.Request, fields: Dict[str, bytes]) -> str:
    """The fit asked: ``?fit=`` or the form field ``fit`` (removed from ``fields``); 400 if they differ."""
    in_url = request.query.get(FIT_FIELD)
    in_form: Optional[str] = None
    raw = fields.pop(FIT_FIELD, None)
    if raw is not None:
        try:
            in_form = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise UploadError(400, "the fit field must be exact, crop, pad or scale") from None
    if in_url is not None and in_form is not None and parse_fit(in_url) != parse_fit(in_form):
        raise UploadError(400, f"fit is {in_url[:20]!r} in the URL but {in_form[:20]!r} in the form: "
                               "send one")
    return parse_fit(in_url if in_url is not None else in_form)


async def _uploaded_frame(request: web.Request) -> Tuple[np.ndarray, str, Fit]:
    """The stream frame of a multipart upload, fitted as asked: ``(frame, origin, fit)``."""
    app = request.app
    limit = app[SETTINGS].max_upload_bytes
    fields = await _read_fields(request, limit)
    fit = _fit_choice(request, fields)
    frame, done = await _run(request, _decode, fields, app[OVERLAY].frame_size, limit, fit)
    return frame, "upload (" + ", ".join(sorted(fields)) + ")", done


async def post_virtual_camera(request: web.Request) -> web.Response:
    app = request.app
    frame_size = app[OVERLAY].frame_size
    metrics = app[METRICS]
    fit: Optional[Fit] = None
    replay: Any = None  # a recording's ReplaySource, to play after its first frame
    try:
        ctype = request.content_type
        if ctype == "application/json":
            if parse_fit(request.query.get(FIT_FIELD)) != "exact":
                raise ApiError("fit applies to uploaded images: captures and recordings are replayed as "
                               "they were stored", status=400)
            kind, ident = parse_json_replay_request(await read_json(request, example='{"capture": "<id>"}'))
            if kind == "recording":
                from .routes_recordings import open_replay

                replay = await open_replay(app, ident)
                frame = await _run(request, replay.frame, 0)
                origin = f"recording {ident}"
            else:
                store: CaptureStore = app[CAPTURES]
                left, right = await _run(request, store.raw_pair, ident)
                if left.shape[:2] != (frame_size[1], frame_size[0]):
                    fw, fh = frame_size
                    raise ApiError(f"capture {ident} is {left.shape[1]}x{left.shape[0]}, "
                                   f"the fabric takes {fw}x{fh}", status=422)
                frame = pixel.pack(left, right)
                origin = f"capture {ident}"
        elif ctype.startswith("multipart/"):
            frame, origin, fit = await _uploaded_frame(request)
        else:
            raise ApiError("send multipart/form-data with fields left and right (or sbs), "
                           'or JSON {"capture": "<id>"} or {"recording": "<id>"}', status=415)
    except ApiError:  # UploadError, CaptureError, ...: answered by the error middleware
        if replay is not None:
            replay.close()
        metrics.upload("rejected")
        raise
    metrics.upload("ok")
    vc = app[VIRTUAL]
    try:
        result = await vc.send(app[EXECUTORS].work, frame, origin)
    except ApiError as exc:
        if replay is not None:
            replay.close()
        metrics.error(exc.message, "virtual-camera")
        raise
    except BroadcastClosed:
        if replay is not None:
            replay.close()
        raise shutting_down() from None
    w, h = frame_size
    body: Dict[str, Any] = {"frame": result.frame, "source": "virtual", "width": w, "height": h,
                            "input": origin}
    if fit is not None:
        body["fit"] = fit.to_json()
    if replay is not None:
        from ..frames.recorder import RecordingPlayer

        source = replay
        player = RecordingPlayer(
            origin.split(" ", 1)[1], source, read=lambda k: app[EXECUTORS].run(source.frame, k),
            show=lambda f: vc.show_next(app[EXECUTORS].work, f))
        if player.frames > 1 and vc.input is frame:
            vc.player = player
            player.start()
        else:
            source.close()
        body["playing"] = player.to_json() if player.running else None
    return json_response(body)


def _decode(fields: Dict[str, bytes], size: Tuple[int, int], limit: int, fit: str) -> Tuple[np.ndarray, Fit]:
    return decode_pair_fitted(fields, size=size, fit=fit, max_bytes=limit)


def _preview_png(frame: np.ndarray) -> bytes:
    """The fitted pair side by side (left | right), as PNG: gray when both cameras are gray."""
    from ..frames.encoders import encode_image

    left, right = frame[..., pixel.LEFT], frame[..., pixel.RIGHT]
    sbs = np.hstack([left, right])
    rgb = sbs[..., :3]
    if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]):
        return encode_image(np.ascontiguousarray(sbs[..., 0]), ".png")
    return encode_image(np.ascontiguousarray(rgb[..., ::-1]), ".png")


async def preview_virtual_camera(request: web.Request) -> web.Response:
    """What an upload would put on the virtual camera, fitted: a PNG, the fabric untouched."""
    if not request.content_type.startswith("multipart/"):
        raise ApiError("send multipart/form-data with fields left and right (or sbs), as for an upload",
                       status=415)
    frame, _, fit = await _uploaded_frame(request)
    body = await _run(request, _preview_png, frame)
    w, h = fit.size
    return web.Response(body=body, content_type="image/png",
                        headers={"X-Fit": json.dumps(fit.to_json()), "X-Frame-Size": f"{w}x{h}",
                                 "Cache-Control": "no-store"})


async def get_virtual_camera(request: web.Request) -> web.Response:
    return json_response(request.app[VIRTUAL].to_json())


async def virtual_result(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.result is None:
        raise ApiError("no virtual-camera result yet: POST /api/virtual-camera first", status=404)
    side = request.match_info["side"]
    body = await _run(request, png_for, vc.result, f"rect_{side}", False)
    return web.Response(body=body, content_type="image/png",
                        headers={"X-Frame-Number": str(vc.result.frame), "Cache-Control": "no-store"})


# -- verify -----------------------------------------------------------------------------------------

def _verify_blocking(vc: VirtualCamera, frame_in: np.ndarray, actual: FrameSet) -> VerifyResult:
    from ..frames.encoders import encode_image

    expected = vc.models.run(vc.overlay, frame_in)
    report = compare(expected, actual.processed)
    diff = difference_image(expected, actual.processed)
    png = encode_image(np.ascontiguousarray(diff[..., ::-1]), ".png")
    body = report.to_json()
    body.update({"frame": actual.frame, "source": actual.source, "input": vc.origin,
                 "stereo": _verify_stereo(vc, actual)})
    return VerifyResult(body, png)


def _verify_stereo(vc: VirtualCamera, actual: FrameSet) -> Dict[str, Any]:
    """The stereo core's disparity of ``actual`` against its model's on the same rectified pair."""
    control = vc.overlay.stereo
    if control is None:
        return {"compared": False, "by": disparity_by(False),
                "reason": "this bitstream has no stereo core: the disparity is computed on the ARM"}
    try:
        core = stereo_of(actual)
    except DepthNotTaken:
        return {"compared": False, "by": disparity_by(True),
                "reason": "the frame was read without the stereo core's output: verify again"}
    assert core is not None
    params = control.params()
    try:
        model = model_of(actual, params)
    except ValueError as exc:  # a frame the core does not take
        return {"compared": False, "by": disparity_by(True), "reason": str(exc)}
    return {"by": disparity_by(True), "params": params.as_json(), **compare_stereo(model, core)}


async def post_verify(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.input is None or vc.result is None:
        raise ApiError("there is no virtual-camera input yet: POST /api/virtual-camera first", status=409)
    if vc.player is not None and vc.player.running:
        raise ApiError(f"recording {vc.player.id} is playing through the virtual camera: Verify checks a "
                       "still input; upload a pair or replay a capture, then verify", status=409)
    try:
        actual = await vc.actual_frame(with_depth=True)
    except asyncio.TimeoutError:
        raise ApiError("the fabric returned no processed frame of the virtual input in time",
                       status=504) from None
    except BroadcastClosed:
        raise shutting_down() from None
    result = await _run(request, _verify_blocking, vc, vc.input, actual)
    vc.verify = result
    return json_response(result.report)


async def verify_difference(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.verify is None:
        raise ApiError("no verify has run for the current input: POST /api/verify first", status=404)
    return web.Response(body=vc.verify.difference_png, content_type="image/png",
                        headers={"Cache-Control": "no-store"})


# -- captures ---------------------------------------------------------------------------------------

async def post_capture(request: web.Request) -> web.Response:
    app = request.app
    metrics = app[METRICS]
    capturing = app[CAPTURING]
    fs = await capturing.fresh_raw_frame()
    store: CaptureStore = app[CAPTURES]
    try:
        info = await capturing.store(store, fs)
    except CaptureError as exc:
        metrics.error(exc.message, "captures")
        raise
    metrics.captures += 1
    body = info.to_json()
    return json_response(body, status=201, headers={"Location": f"/api/captures/{info.id}"})


async def list_captures(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    infos = await _run(request, store.list)
    return json_response({"captures": [i.to_json() for i in infos]},
                             headers={"Cache-Control": "no-store"})


async def get_capture(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    info = await _run(request, store.get, request.match_info["id"])
    return json_response(info.to_json(meta=True))


async def capture_zip(request: web.Request) -> web.StreamResponse:
    store: CaptureStore = request.app[CAPTURES]
    cid = request.match_info["id"]
    chunks = await _run(request, store.zip_stream, cid)
    return await stream_download(request, chunks, filename=f"{cid}.zip", content_type="application/zip",
                                 run=request.app[EXECUTORS].run)


def _read_capture_file(store: CaptureStore, cid: str, name: str) -> bytes:
    """One file of a capture, by a name its listing shows (never a path built from the request)."""
    info = store.get(cid)
    if name not in {f.name for f in info.files}:
        names = ", ".join(f.name for f in info.files)
        raise NotFound(f"capture {cid} has no file {name[:60]!r}; it has {names}")
    fd = os.open(store.path(cid) / name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise CaptureError(f"{name} is not a file")
        return fh.read()


async def capture_file(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    cid, name = request.match_info["id"], request.match_info["file"]
    try:
        body = await _run(request, _read_capture_file, store, cid, name)
    except OSError as exc:
        status = 404 if isinstance(exc, FileNotFoundError) else 500
        raise ApiError(f"cannot read {name}: {exc.strerror}", status=status) from None
    ctype = mimetypes.guess_type(name)[0] or "application/octet-stream"
    return web.Response(body=body, content_type=ctype)


async def delete_capture(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    # Into the store's trash: POST /api/captures/{id}/restore undoes it (routes_viewer.py).
    await _run(request, store.trash, request.match_info["id"])
    return web.Response(status=204)


def setup_routes(app: web.Application) -> None:
    r = app.router
    r.add_get("/api/status", status_handler)
    r.add_get("/api/views", get_views)
    r.add_get("/api/source", get_source)
    r.add_put("/api/source", put_source)
    r.add_get("/api/virtual-camera", get_virtual_camera)
    r.add_post("/api/virtual-camera", post_virtual_camera)
    r.add_post("/api/virtual-camera/preview", preview_virtual_camera)
    r.add_get(r"/api/virtual-camera/result/{side:left|right}.png", virtual_result)
    r.add_post("/api/verify", post_verify)
    r.add_get("/api/verify/difference.png", verify_difference)
    r.add_get("/api/captures", list_captures)
    r.add_post("/api/captures", post_capture)
    r.add_get(r"/api/captures/{id:[^/]+}.zip", capture_zip)
    setup_tools_routes(app)  # /api/alignment, /api/histogram
    setup_stereo_routes(app)  # /api/stereo
    setup_viewer_routes(app)  # thumb.jpg, restore, /api/point: before the {file} route below
    setup_cloud_routes(app)  # cloud.ply: before the {file} route below
    r.add_get(r"/api/captures/{id:[^/]+}/{file:[^/]+}", capture_file)
    r.add_get(r"/api/captures/{id:[^/]+}", get_capture)
    r.add_delete(r"/api/captures/{id:[^/]+}", delete_capture)
    from . import routes_recordings

    routes_recordings.setup(app)
