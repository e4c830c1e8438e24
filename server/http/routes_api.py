"""The control API: status, source, virtual camera (flows 4 and 6), verify (flow 5) and captures (flow 1).

Handlers stay on the event loop only to parse, check and answer; anything
that blocks (register dumps, image decoding, the model, PNG encoding, disk)
runs on the daemon's ``work`` threads. Every refusal is ``{"error": "..."}``
with a 4xx/5xx status, and a refused request changes nothing.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import mimetypes
import os
import stat
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Callable, Dict, Optional, Tuple, TypeVar

import numpy as np
from aiohttp import BodyPartReader, web

from ...drivers.mmio import DriverError
from ...drivers.vdma import FATAL_ERRORS, ChannelFault
from ...overlays.model.fast import RectifyModel
from ...overlays.model.result import CoreOptions
from ...overlays.spec import pixel
from ...overlays.spec.rectify import RECTIFY_MAP
from ..frames.captures import CaptureError, CaptureStore
from ..frames.encoders import BroadcastClosed, png_for
from ..frames.errors import ApiError, parse_json
from ..frames.pipeline import COUNT_MOD, FrameSet, SourceState
from ..frames.verify import VerifyError, compare, difference_image
from .routes_viewer import setup_routes as setup_viewer_routes
from .state import (
    BUDGET,
    CALIBRATION,
    CAPTURES,
    CONFIG,
    ENCODERS,
    EXECUTORS,
    EXTENSIONS,
    FEED,
    METRICS,
    OVERLAY,
    PIPELINE,
    STREAMS,
    VIRTUAL,
)
from .streams import error_response, json_error
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

__all__ = ["VirtualCamera", "setup_routes", "core_model_setup", "fresh_raw_frame", "store_capture"]

T = TypeVar("T")
SOURCES = ("live", "virtual")
ROUND_TRIP_FRAMES = 2  # frames after MM2S picks the store up until the core's output surely comes from it


async def _run(request: web.Request, fn: Callable[..., T], *args: Any) -> T:
    return await request.app[EXECUTORS].run(fn, *args)


# -- the model, as the core's registers describe it -----------------------------------------------

def core_model_setup(rectify: Any) -> Tuple[Any, CoreOptions]:
    """``(CoreConfig, CoreOptions)`` the core runs with, read back from its registers (blocks)."""
    config = rectify.read_config()
    control = RECTIFY_MAP["CONTROL"].decode(rectify.regs.read("CONTROL"))
    debug_row = rectify.regs.field("DEBUG_ROW", "VALUE") if control["DEBUG_LINE"] else None
    options = CoreOptions(lb_rows=rectify.lb_rows, lb_delay=config.lb_delay, gray=bool(control["GRAY"]),
                          bypass=bool(control["BYPASS"]), debug_row=debug_row, colour=rectify.colour)
    return config, options


class _ModelCache:
    """The last :class:`RectifyModel` built, reused while the registers say the same thing."""

    def __init__(self) -> None:
        self._key: Any = None
        self._model: Optional[RectifyModel] = None

    def run(self, rectify: Any, frame: np.ndarray) -> np.ndarray:
        config, options = core_model_setup(rectify)
        key = (config, options)
        if self._model is None or self._key != key:
            self._model = RectifyModel(config.left, config.right, config.width, config.height, options)
            self._key = key
        return self._model.process(frame).frame


# -- the virtual camera -----------------------------------------------------------------------------

@dataclass
class VerifyResult:
    report: Dict[str, Any]
    difference_png: bytes


PARK_WAIT_S = 5.0


class MuxRefused(ApiError):
    """The mux did not commit a change of source: 503, the daemon's source stays what it was."""

    def __init__(self, source: str, exc: BaseException) -> None:
        super().__init__(f"the mux did not switch to {source} ({exc}): the daemon retries until it commits "
                         "(see /api/status faults); try again in a moment", status=503)


class VirtualCamera:
    """The mux and the virtual camera as the daemon drives them (loop thread; one change at a time).

    ``input`` is the last frame sent down MM2S (read-only ``(H, W, 8)``),
    ``result`` the processed frame set that came back for it.
    """

    def __init__(self, overlay: Any, pipeline: Any, feed: Any, *, round_trip_timeout: float = 2.0) -> None:
        self.overlay = overlay
        self.fabric = overlay.fabric
        self.pipeline = pipeline
        self.feed = feed
        self.lock = asyncio.Lock()
        self.source = "live"
        self.input: Optional[np.ndarray] = None
        self.origin: Optional[str] = None
        self.result: Optional[FrameSet] = None
        self.effective_count = 0
        self.verify: Optional[VerifyResult] = None
        self.models = _ModelCache()
        self.round_trip_timeout = round_trip_timeout
        self.player: Any = None  # a RecordingPlayer while a recording plays (recordings.py)
        # FabricHealth's, once set: a commit the mux refused is a fault until one lands.
        self.mux_refused: Callable[[str, BaseException], None] = lambda source, exc: None
        self.mux_committed: Callable[[], None] = lambda: None

    def to_json(self) -> Dict[str, Any]:
        w, h = self.fabric.frame_size
        player = self.player
        return {"source": self.source, "input": self.origin,
                "frame": self.result.frame if self.result is not None else None,
                "width": w, "height": h,
                "playing": player.to_json() if player is not None and player.running else None}

    def _frames(self, n: float) -> float:
        """Seconds for ``n`` frame periods at the rate the fabric runs (1/60 s before one is known)."""
        return n * (self.pipeline.period or 1 / 60)

    def _send_blocking(self, frame: np.ndarray) -> int:
        """Mux to virtual, frame down MM2S, wait until the channel reads it; the FRAME_COUNT then.

        A channel that halted on a fatal error (a fault since the last upload) is restarted
        once and the frame sent again, so one fault does not fail every later upload.
        """
        self._select_blocking("virtual")
        mm2s = self.fabric.proc_vdma.mm2s
        fatal = [e for e in mm2s.errors() if e in FATAL_ERRORS]
        if fatal:
            log.warning("virtual camera: MM2S channel halted on %s: restarting it", ", ".join(fatal))
            mm2s.recover()
        try:
            self.fabric.send_virtual(frame)
        except ChannelFault as exc:
            log.warning("virtual camera: MM2S channel fault (%s): restarting it", exc)
            mm2s.recover()
            self.fabric.send_virtual(frame)
        # Healthy, the channel takes it at the next frame; the bound only ends a wait for a broken one
        # (a loaded machine's frame clock can run late by a second or more).
        mm2s.wait_parked(timeout=max(PARK_WAIT_S, self._frames(3), self.round_trip_timeout / 2))
        return int(self.pipeline.frame_count())

    def _select_blocking(self, source: str) -> None:
        try:
            self.fabric.select(source)
        except DriverError as exc:
            self.mux_refused(source, exc)
            raise MuxRefused(source, exc) from exc
        self.mux_committed()

    def _live_blocking(self) -> None:
        self._select_blocking("live")

    async def send(self, loop_executor: Any, frame: np.ndarray, origin: str) -> FrameSet:
        """Flow 4: ``frame`` through the fabric; returns the processed set (ApiError 504 if none came).

        A recording playing through the virtual camera stops first.
        """
        frame.flags.writeable = False
        loop = asyncio.get_running_loop()
        await self.stop_player()
        async with self.lock:
            try:
                count = await loop.run_in_executor(loop_executor, self._send_blocking, frame)
            except MuxRefused:
                with contextlib.suppress(MuxRefused):
                    await self._back_to_live(loop_executor)
                raise
            except Exception as exc:
                with contextlib.suppress(MuxRefused):
                    await self._back_to_live(loop_executor)
                raise ApiError(f"the fabric did not take the virtual-camera frame: {exc}", status=504) from exc
            effective = (count + ROUND_TRIP_FRAMES) % COUNT_MOD
            self.pipeline.set_source(SourceState("virtual", frame, effective))
            self.source, self.input, self.origin, self.effective_count = "virtual", frame, origin, effective
            self.result = self.verify = None
            try:
                result = await self._virtual_frame()
            except asyncio.TimeoutError:
                await self._back_to_live(loop_executor)
                raise ApiError(f"the fabric returned no processed frame within "
                               f"{self._round_trip_s():g} s; is the rectify core enabled? "
                               "(GET /api/status); the source is live again", status=504) from None
            self.result = result
            return result

    async def _virtual_frame(self) -> FrameSet:
        effective = self.effective_count

        def from_input(fs: FrameSet) -> bool:
            return fs.source == "virtual" and (fs.fabric_count - effective) % COUNT_MOD < COUNT_MOD // 2

        return await self.feed.next_frame(timeout=self._round_trip_s(), accept=from_input)

    def _round_trip_s(self) -> float:
        return max(self.round_trip_timeout, self._frames(ROUND_TRIP_FRAMES + 4))

    async def _back_to_live(self, executor: Any) -> None:
        try:
            await asyncio.get_running_loop().run_in_executor(executor, self._live_blocking)
        finally:
            self.pipeline.set_source(SourceState())
            self.source = "live"

    async def select(self, executor: Any, source: str) -> None:
        """Flow 6 (live) or back to the last virtual input (virtual).

        Virtual before any input is refused (ApiError 409), the source staying live: the mux
        would feed the core nothing, and the views would show live raw frames beside black
        rectified ones under a header saying virtual.

        A mux that does not take the change (its commit times out) is an ApiError 503 naming
        the source the status then shows; nothing else changes.
        """
        await self._select(executor, source)

    async def _select(self, executor: Any, source: str) -> None:
        await self.stop_player()
        async with self.lock:
            if source == "live":
                await self._back_to_live(executor)
                return
            if self.input is None:
                raise ApiError("the virtual camera has no input yet: upload a pair (POST /api/virtual-camera) "
                               "or send a capture to it first; the source stays live", status=409)
            frame = self.input
        await self.send(executor, frame, self.origin or "upload")

    # -- a recording played through the core (issue 13) ----------------------------------------------
    async def stop_player(self) -> None:
        """Stop the recording playing, if one is (its last frame stays the input)."""
        player, self.player = self.player, None
        if player is not None:
            await player.stop()

    def _next_blocking(self, frame: np.ndarray) -> int:
        """The next frame of a sequence down MM2S (the mux is already on virtual); FRAME_COUNT then."""
        self.fabric.send_virtual(frame)
        self.fabric.proc_vdma.mm2s.wait_parked(timeout=max(PARK_WAIT_S, self._frames(3)))
        return int(self.pipeline.frame_count())

    async def show_next(self, executor: Any, frame: np.ndarray) -> None:
        """Put the next frame of a playing sequence on the virtual camera (no round trip waited for).

        The pipeline labels the processed frames from ``ROUND_TRIP_FRAMES`` later with it as
        their raw pair, as for an upload.
        """
        frame.flags.writeable = False
        async with self.lock:
            if self.source != "virtual":
                raise ApiError("the source is no longer virtual", status=409)
            count = await asyncio.get_running_loop().run_in_executor(executor, self._next_blocking, frame)
            effective = (count + ROUND_TRIP_FRAMES) % COUNT_MOD
            self.pipeline.set_source(SourceState("virtual", frame, effective))
            self.input, self.effective_count = frame, effective

    async def actual_frame(self) -> FrameSet:
        """The fabric's output for the current input: a fresh frame while virtual, else the stored result."""
        if self.source == "virtual" and self.input is not None:
            return await self._virtual_frame()
        assert self.result is not None
        return self.result


# -- status and source ------------------------------------------------------------------------------

async def status_handler(request: web.Request) -> web.Response:
    app = request.app
    overlay, pipeline, feed, streams = app[OVERLAY], app[PIPELINE], app[FEED], app[STREAMS]
    fabric = overlay.fabric
    try:
        hw = await _run(request, fabric.status)
    except Exception as exc:  # registers unreadable: say so, keep the rest
        hw = {"core": None, "vdma": None, "error": str(exc)}
    choice = getattr(overlay, "choice", None)
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
    body: Dict[str, Any] = {
        "backend": getattr(overlay, "backend", fabric.backend),
        "backend_reason": getattr(choice, "reason", None),
        "source": app[VIRTUAL].source,
        "mux": hw.get("source"),
        "frame_size": list(fabric.frame_size),
        "signal": feed.signal,
        "last_frame": {"frame": pipeline.last_frame_number, "age_s": None if age is None else round(age, 3)},
        "fps": fps,
        "frames": pipeline.frames,
        "frames_seen": pipeline.frames_seen,
        "drops": pipeline.drops,
        "core": hw.get("core"),
        "core_impl": getattr(overlay, "core_kind", "hardware"),
        "vdma": hw.get("vdma"),
        "calibration": {**app[CALIBRATION].to_json(), "changing": app[CALIBRATION].changing},
        "virtual_camera": app[VIRTUAL].to_json(),
        "clients": len(streams),
        "max_streams": streams.max_streams,
        "streams": [c.to_json() for c in streams.clients.values()],
        "encoders": encoders.status(),
        "cpu": app[BUDGET].status(),
        "uptime_s": round(time.time() - metrics.started, 1),
        "access_token": app[CONFIG].access_token is not None,
        "errors": errors[-20:],
    }
    now = time.time()
    body["faults"] = [{**f, "for_s": round(now - f["since"], 3) if f.get("since") else None}
                      for f in app[EXTENSIONS].active_faults()]
    body.update(app[EXTENSIONS].status_sections())
    return web.json_response(body, headers={"Cache-Control": "no-store"})


async def _json_body(request: web.Request) -> Any:
    if request.content_type != "application/json":
        given = request.content_type or "nothing"
        raise ApiError(f"send JSON (Content-Type: application/json), not {given}", status=415)
    try:
        return parse_json(await request.read())
    except web.HTTPRequestEntityTooLarge:
        raise
    except (ValueError, UnicodeDecodeError):
        raise ApiError("the body is not valid JSON", status=400) from None


async def get_source(request: web.Request) -> web.Response:
    return web.json_response({"source": request.app[VIRTUAL].source})


async def put_source(request: web.Request) -> web.Response:
    try:
        doc = await _json_body(request)
        if not isinstance(doc, dict) or set(doc) != {"source"} or doc["source"] not in SOURCES:
            raise ApiError('send {"source": "live"} or {"source": "virtual"}', status=400)
        await request.app[VIRTUAL].select(request.app[EXECUTORS].work, doc["source"])
    except ApiError as exc:
        return error_response(exc)
    return web.json_response({"source": request.app[VIRTUAL].source})


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
    limit = app[CONFIG].max_upload_bytes
    fields = await _read_fields(request, limit)
    fit = _fit_choice(request, fields)
    frame, done = await _run(request, _decode, fields, app[OVERLAY].fabric.frame_size, limit, fit)
    return frame, "upload (" + ", ".join(sorted(fields)) + ")", done


async def post_virtual_camera(request: web.Request) -> web.Response:
    app = request.app
    fabric = app[OVERLAY].fabric
    metrics = app[METRICS]
    fit: Optional[Fit] = None
    replay: Any = None  # a recording's ReplaySource, to play after its first frame
    try:
        ctype = request.content_type
        if ctype == "application/json":
            if parse_fit(request.query.get(FIT_FIELD)) != "exact":
                raise ApiError("fit applies to uploaded images: captures and recordings are replayed as "
                               "they were stored", status=400)
            kind, ident = parse_json_replay_request(await _json_body(request))
            if kind == "recording":
                from .routes_recordings import open_replay

                replay = await open_replay(app, ident)
                frame = await _run(request, replay.frame, 0)
                origin = f"recording {ident}"
            else:
                store: CaptureStore = app[CAPTURES]
                left, right = await _run(request, store.raw_pair, ident)
                if left.shape[:2] != (fabric.frame_size[1], fabric.frame_size[0]):
                    fw, fh = fabric.frame_size
                    raise ApiError(f"capture {ident} is {left.shape[1]}x{left.shape[0]}, "
                                   f"the fabric takes {fw}x{fh}", status=422)
                frame = pixel.pack(left, right)
                origin = f"capture {ident}"
        elif ctype.startswith("multipart/"):
            frame, origin, fit = await _uploaded_frame(request)
        else:
            raise ApiError("send multipart/form-data with fields left and right (or sbs), "
                           'or JSON {"capture": "<id>"} or {"recording": "<id>"}', status=415)
    except (ApiError, UploadError, CaptureError) as exc:
        if replay is not None:
            replay.close()
        metrics.upload("rejected")
        return error_response(exc)
    metrics.upload("ok")
    vc = app[VIRTUAL]
    try:
        result = await vc.send(app[EXECUTORS].work, frame, origin)
    except ApiError as exc:
        if replay is not None:
            replay.close()
        metrics.error(exc.message, "virtual-camera")
        return error_response(exc)
    except BroadcastClosed:
        if replay is not None:
            replay.close()
        return json_error(503, "the daemon is shutting down")
    w, h = fabric.frame_size
    body: Dict[str, Any] = {"frame": result.frame, "source": "virtual", "width": w, "height": h,
                            "input": origin}
    if fit is not None:
        body["fit"] = fit.to_json()
    if replay is not None:
        from ..frames.recordings import RecordingPlayer

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
    return web.json_response(body)


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
        return json_error(415, "send multipart/form-data with fields left and right (or sbs), "
                               "as for an upload")
    try:
        frame, _, fit = await _uploaded_frame(request)
    except (ApiError, UploadError) as exc:
        return error_response(exc)
    body = await _run(request, _preview_png, frame)
    w, h = fit.size
    return web.Response(body=body, content_type="image/png",
                        headers={"X-Fit": json.dumps(fit.to_json()), "X-Frame-Size": f"{w}x{h}",
                                 "Cache-Control": "no-store"})


async def get_virtual_camera(request: web.Request) -> web.Response:
    return web.json_response(request.app[VIRTUAL].to_json())


async def virtual_result(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.result is None:
        return json_error(404, "no virtual-camera result yet: POST /api/virtual-camera first")
    side = request.match_info["side"]
    body = await _run(request, png_for, vc.result, f"rect_{side}", False)
    return web.Response(body=body, content_type="image/png",
                        headers={"X-Frame-Number": str(vc.result.frame), "Cache-Control": "no-store"})


# -- verify -----------------------------------------------------------------------------------------

def _verify_blocking(vc: VirtualCamera, frame_in: np.ndarray, actual: FrameSet) -> VerifyResult:
    from ..frames.encoders import encode_image

    expected = vc.models.run(vc.fabric.rectify, frame_in)
    report = compare(expected, actual.processed)
    diff = difference_image(expected, actual.processed)
    png = encode_image(np.ascontiguousarray(diff[..., ::-1]), ".png")
    body = _with_max_diff(report.to_json())
    body.update({"frame": actual.frame, "source": actual.source, "input": vc.origin})
    return VerifyResult(body, png)


def _with_max_diff(stats: Dict[str, Any]) -> Dict[str, Any]:
    """API.md names the largest difference ``max_diff``; verify.py says ``max_difference``: give both."""
    if "max_difference" in stats:
        stats["max_diff"] = stats["max_difference"]
    for group in ("channels", "cameras"):
        for entry in (stats.get(group) or {}).values():
            _with_max_diff(entry)
    return stats


async def post_verify(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.input is None or vc.result is None:
        return json_error(409, "there is no virtual-camera input yet: POST /api/virtual-camera first")
    if vc.player is not None and vc.player.running:
        return json_error(409, f"recording {vc.player.id} is playing through the virtual camera: Verify "
                               "checks a still input; upload a pair or replay a capture, then verify")
    try:
        actual = await vc.actual_frame()
    except asyncio.TimeoutError:
        return json_error(504, "the fabric returned no processed frame of the virtual input in time")
    except BroadcastClosed:
        return json_error(503, "the daemon is shutting down")
    try:
        result = await _run(request, _verify_blocking, vc, vc.input, actual)
    except VerifyError as exc:
        return error_response(exc)
    vc.verify = result
    return web.json_response(result.report)


async def verify_difference(request: web.Request) -> web.Response:
    vc = request.app[VIRTUAL]
    if vc.verify is None:
        return json_error(404, "no verify has run for the current input: POST /api/verify first")
    return web.Response(body=vc.verify.difference_png, content_type="image/png",
                        headers={"Cache-Control": "no-store"})


# -- captures ---------------------------------------------------------------------------------------

CHANGE_WAIT_S = 30.0  # how long a capture waits out a calibration change (programming and file write)

async def fresh_raw_frame(app: web.Application) -> FrameSet:
    """The first frame set grabbed after now that carries its raw pair.

    Raises :class:`ApiError` 503 when no frame comes in time (no signal) or the daemon is stopping.
    """
    feed, pipeline, calibration = app[FEED], app[PIPELINE], app[CALIBRATION]
    timeout = max(1.0, 2 * app[CONFIG].no_signal_s)
    asked = time.time()

    def wanted(f: FrameSet) -> bool:  # grabbed after the request, with its raw pair, of a known calibration
        known = calibration.for_frame(f.fabric_count) is not None
        return f.timestamp >= asked and f.raw is not None and known

    change_ends = time.monotonic() + CHANGE_WAIT_S
    try:
        with pipeline.raw_wanted(), pipeline.pairs_wanted():
            while True:
                try:
                    return await feed.next_frame(timeout=timeout, accept=wanted)
                except asyncio.TimeoutError:
                    # Frames of a calibration change in progress are refused, not missing: wait it out.
                    if not (calibration.changing and time.monotonic() < change_ends):
                        raise
    except asyncio.TimeoutError:
        raise ApiError(f"no signal: no frame came within {timeout:g} s, nothing was captured",
                       status=503) from None
    except BroadcastClosed:
        raise ApiError("the daemon is shutting down", status=503) from None


def paired_raw(app: web.Application, fs: FrameSet) -> Tuple[np.ndarray, str]:
    """The raw pair whose rectified frame ``fs.processed`` is, and how that is known (blocking).

    The pipeline copies the latest raw and processed stores together, but the raw channel
    can complete the next frame before the core has finished this one, so the latest raw
    store may be a frame ahead; for captures it also copies the store before
    (``fs.raw_previous``). The closed loop decides: the raw frame that the model turns into
    exactly the processed one. "checked" when one does; "unverified" when neither does (a
    core that differs from the model, which Verify shows), and the latest raw pair is kept.
    """
    assert fs.raw is not None
    if fs.source == "virtual":
        return fs.raw, "virtual input"
    rectify, models = app[OVERLAY].fabric.rectify, app[VIRTUAL].models
    for candidate in (fs.raw, fs.raw_previous):
        if candidate is not None and np.array_equal(models.run(rectify, candidate), fs.processed):
            return candidate, "checked"
    return fs.raw, "unverified"


async def store_capture(app: web.Application, store: CaptureStore, fs: FrameSet,
                        extra: Optional[Dict[str, Any]] = None) -> Any:
    """Save ``fs`` (raw and rectified pairs, metadata: registers, calibration, extensions) in ``store``.

    Returns the :class:`CaptureInfo`; raises :class:`CaptureError` (disk full, I/O) with nothing stored.
    """
    overlay = app[OVERLAY]
    try:
        registers = await app[EXECUTORS].run(overlay.fabric.rectify.dump)
    except Exception as exc:
        registers = {"error": str(exc)}
    # The calibration this frame ran with (a change since it was grabbed does not relabel it).
    calibration = app[CALIBRATION].for_frame(fs.fabric_count) or {
        "id": None, "description": "unknown: the calibration changed while this frame was processed"}
    assert fs.raw is not None
    try:
        raw, pairing = await app[EXECUTORS].run(paired_raw, app, fs)
    except Exception as exc:  # a model that cannot run (no registers?): store what was copied, say so
        raw, pairing = fs.raw, f"unverified ({type(exc).__name__}: {exc})"
    meta: Dict[str, Any] = {
        "frame": fs.frame,
        "pairing": pairing,
        "fabric_count": fs.fabric_count,
        "time": fs.timestamp,
        "time_utc": datetime.fromtimestamp(fs.timestamp, timezone.utc).isoformat(timespec="milliseconds"),
        "source": fs.source,
        "calibration_id": calibration["id"],
        "calibration": calibration,
        "backend": getattr(overlay, "backend", overlay.fabric.backend),
        "frame_size": list(fs.size),
        "registers": registers,
    }
    if fs.source == "virtual":
        meta["virtual_input"] = app[VIRTUAL].origin
    meta.update(app[EXTENSIONS].capture_sections())
    meta.update(extra or {})
    frames = {"raw_left": raw[..., pixel.LEFT], "raw_right": raw[..., pixel.RIGHT],
              "rect_left": fs.processed[..., pixel.LEFT], "rect_right": fs.processed[..., pixel.RIGHT]}
    return await app[EXECUTORS].run(store.save, frames, meta)


async def post_capture(request: web.Request) -> web.Response:
    app = request.app
    metrics = app[METRICS]
    try:
        fs = await fresh_raw_frame(app)
    except ApiError as exc:
        return error_response(exc)
    store: CaptureStore = app[CAPTURES]
    try:
        info = await store_capture(app, store, fs)
    except CaptureError as exc:
        metrics.error(exc.message, "captures")
        return error_response(exc)
    metrics.captures += 1
    body = info.to_json()
    return web.json_response(body, status=201, headers={"Location": f"/api/captures/{info.id}"})


async def list_captures(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    infos = await _run(request, store.list)
    return web.json_response({"captures": [i.to_json() for i in infos]},
                             headers={"Cache-Control": "no-store"})


async def get_capture(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    try:
        info = await _run(request, store.get, request.match_info["id"])
    except CaptureError as exc:
        return error_response(exc)
    return web.json_response(info.to_json(meta=True))


async def capture_zip(request: web.Request) -> web.StreamResponse:
    store: CaptureStore = request.app[CAPTURES]
    cid = request.match_info["id"]
    try:
        chunks = await _run(request, store.zip_stream, cid)
    except CaptureError as exc:
        return error_response(exc)
    resp = web.StreamResponse(headers={"Content-Type": "application/zip",
                                       "Content-Disposition": f'attachment; filename="{cid}.zip"'})
    try:
        await resp.prepare(request)
        while True:
            chunk = await _run(request, next, chunks, b"")
            if not chunk:
                break
            await resp.write(chunk)
        await resp.write_eof()
    finally:
        close = getattr(chunks, "close", None)  # a generator: closing it closes the files
        if close is not None:
            close()
    return resp


class _NoSuchFile(CaptureError):
    status = 404


def _read_capture_file(store: CaptureStore, cid: str, name: str) -> bytes:
    """One file of a capture, by a name its listing shows (never a path built from the request)."""
    info = store.get(cid)
    if name not in {f.name for f in info.files}:
        names = ", ".join(f.name for f in info.files)
        raise _NoSuchFile(f"capture {cid} has no file {name[:60]!r}; it has {names}")
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
    except CaptureError as exc:
        return error_response(exc)
    except OSError as exc:
        status = 404 if isinstance(exc, FileNotFoundError) else 500
        return json_error(status, f"cannot read {name}: {exc.strerror}")
    ctype = mimetypes.guess_type(name)[0] or "application/octet-stream"
    return web.Response(body=body, content_type=ctype)


async def delete_capture(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    try:
        # Into the store's trash: POST /api/captures/{id}/restore undoes it (routes_viewer.py).
        await _run(request, store.trash, request.match_info["id"])
    except CaptureError as exc:
        return error_response(exc)
    return web.Response(status=204)


def setup_routes(app: web.Application) -> None:
    r = app.router
    r.add_get("/api/status", status_handler)
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
    setup_viewer_routes(app)  # thumb.jpg, restore, /api/point: before the {file} route below
    r.add_get(r"/api/captures/{id:[^/]+}/{file:[^/]+}", capture_file)
    r.add_get(r"/api/captures/{id:[^/]+}", get_capture)
    r.add_delete(r"/api/captures/{id:[^/]+}", delete_capture)
    from . import routes_recordings

    routes_recordings.setup(app)
