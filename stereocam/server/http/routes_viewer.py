"""What the page's capture viewer and live-view readouts need.

- ``GET /api/captures/{id}/thumb.jpg``: a small JPEG of a capture (its rectified left frame),
  made on first use and kept in memory (:class:`ThumbnailCache`).
- ``POST /api/captures/{id}/restore``: undo of ``DELETE /api/captures/{id}`` (the capture
  comes back from the store's trash).
- ``GET /api/point?x=&y=``: the rectified pixels, the disparity (the stereo core's, or StereoBM's on
  the ARM where the bitstream has no core) and the depth (metres, from the calibration's Q matrix) at
  one pixel of the newest frame the disparity view showed.
- ``GET /api/ruler?x0=&y0=&x1=&y1=[&frame=]``: the 3-D points at two rectified left pixels and the
  distance between them, in metres (the readout's maths at each point).
- ``POST /api/freeze``, ``GET /api/freeze``, ``DELETE /api/freeze/{frame}``: hold a frame a page froze
  at, so its readouts and ruler keep reading that frame (:mod:`..frames.held`); ``frame=N`` of the
  readouts is answered for frame N only (410 once it is no longer held), never for another.
- ``GET /api/disparity``: what the disparity view's colours mean (its range and colour map) and
  the depth of each disparity (``focal_px`` x ``baseline_m`` / d) under the active calibration.

Both read the calibration as the :class:`..stores.frame_calibration.FrameCalibration` record
captures and recordings store: the point's is the one its frame ran with.

Handlers parse and answer on the event loop; decoding, block matching and disk run on the
daemon's ``work`` threads.
"""
from __future__ import annotations

import asyncio
import functools
import math
import os
import threading
import time
from collections import OrderedDict
from typing import Any, Dict, List, Optional, Tuple

import cv2
import numpy as np
from aiohttp import web

from ...overlays.spec import pixel
from ..errors import ApiError
from ..frames.depth import needs_depth
from ..frames.feed import BroadcastClosed
from ..frames.held import PINNED_MAX, RECENT
from ..frames.pipeline import FrameSet
from ..frames.views import STEREO_BM, disparity_raw
from ..stores.captures import THUMB_FRAMES, CaptureStore, capture_file
from ..stores.frame_calibration import NO_DEPTH_NONE, DepthScale, FrameCalibration
from .bodies import json_response, read_json
from .errors import shutting_down
from .security import TOKEN_PARAM
from .state import CALIBRATION, CAPTURES, ENCODERS, EXECUTORS, FEED, PIPELINE, SETTINGS

__all__ = ["setup_routes", "ThumbnailCache", "point_at", "depth_readout", "ruler_between", "frame_for"]

THUMB_CACHE_ENTRIES = 256  # about 5 KB each
FRESH_S = 1.0  # a frame set older than this is not "the newest": /api/point waits for the next one
POINT_QUERY = ("x", "y", "frame", "fallback")
RULER_QUERY = ("x0", "y0", "x1", "y1", "frame", "fallback")


class ThumbnailCache:
    """Thumbnails by (capture id, size and change time of the folder's files): thread-safe LRU."""

    def __init__(self, entries: int = THUMB_CACHE_ENTRIES) -> None:
        self.entries = entries
        self._lock = threading.Lock()
        self._items: "OrderedDict[Tuple[Any, ...], bytes]" = OrderedDict()

    def get(self, store: CaptureStore, capture_id: str) -> bytes:
        """The JPEG (blocking: may decode a PNG). Errors as :meth:`CaptureStore.thumbnail`."""
        folder = store.path(capture_id)
        key: Tuple[Any, ...] = (str(store.root), folder.name)
        for name in map(capture_file, THUMB_FRAMES):
            try:
                st = os.lstat(folder / name)
                key += (name, st.st_size, st.st_mtime_ns, st.st_ino)
            except OSError:
                key += (name, None)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        data = store.thumbnail(capture_id)
        with self._lock:
            self._items[key] = data
            while len(self._items) > self.entries:
                self._items.popitem(last=False)
        return data


THUMBS: "web.AppKey[ThumbnailCache]" = web.AppKey("stereocam.thumbnails", ThumbnailCache)


async def capture_thumb(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    body = await request.app[EXECUTORS].run(request.app[THUMBS].get, store, request.match_info["id"])
    # A capture never changes (a restored one is the same files): the browser may keep it.
    return web.Response(body=body, content_type="image/jpeg",
                        headers={"Cache-Control": "private, max-age=86400"})


async def restore_capture(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    info = await request.app[EXECUTORS].run(store.restore, request.match_info["id"])
    return json_response(info.to_json(), headers={"Location": f"/api/captures/{info.id}"})


# -- depth -------------------------------------------------------------------------------------

def depth_readout(ran: Optional[FrameCalibration], now: FrameCalibration) -> Dict[str, Any]:
    """A point readout's calibration fields for a frame that ran with ``ran`` (None: unknown).

    Depth only under the calibration in effect (``now``): a frame of another is told to hover
    again, whose next frame runs with it.
    """
    record = ran if ran is not None and ran.id == now.id else FrameCalibration.unknown()
    depth = record.depth
    out: Dict[str, Any] = {"calibration_id": ran.id if ran is not None else None,
                           "focal_px": depth.focal_px if depth else None,
                           "baseline_m": depth.baseline_m if depth else None}
    if record.depth_unavailable is not None:
        out["depth_unavailable"] = record.depth_unavailable
    return out


def point_at(fs: FrameSet, x: int, y: int, depth: Optional[DepthScale]) -> Dict[str, Any]:
    """The readout of rectified pixel (x, y) of ``fs``, its depth by ``depth`` (blocks: the disparity map
    may be computed)."""
    p = fs.processed
    out: Dict[str, Any] = {
        "x": x, "y": y, "frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source,
        "width": int(p.shape[1]), "height": int(p.shape[0]),
        "rect_left": dict(zip("rgby", (int(v) for v in p[y, x, pixel.LEFT]), strict=True)),
        "rect_right": dict(zip("rgby", (int(v) for v in p[y, x, pixel.RIGHT]), strict=True)),
    }
    d16 = int(disparity_raw(fs)[y, x])
    valid = d16 >= 16 * STEREO_BM["min_disparity"]
    d = d16 / 16.0 if valid else None
    out["disparity_px"] = d
    out["depth_m"] = None
    out["point_m"] = None
    unit = depth.unit_m if depth is not None else None
    if d is not None and depth is not None and unit is not None:
        Q = np.asarray(depth.Q, dtype=np.float64)
        X, Y, Z, W = Q @ np.array([x, y, d, 1.0])
        if W != 0 and math.isfinite(W) and Z / W > 0:
            out["depth_m"] = float(Z / W * unit)
            out["point_m"] = [float(X / W * unit), float(Y / W * unit), float(Z / W * unit)]
    return out


def _int_param(request: web.Request, name: str, hi: int, point: str = "") -> int:
    """Query parameter ``name``, a whole number in 0..hi-1 (``point``: which of the ruler's points it
    places, for the message)."""
    text = request.query.get(name)
    what = f"{point}: " if point else ""
    if text is None:
        raise ApiError(f"{what}give {name}: a pixel of the rectified left image, 0 to {hi - 1}", status=400)
    try:
        value = int(text)
    except ValueError:
        raise ApiError(f"{what}{name} must be a whole number of pixels, not {text[:20]!r}",
                       status=400) from None
    if not 0 <= value < hi:
        raise ApiError(f"{what}{name} = {value} is outside the image: 0 to {hi - 1}"
                       + ("; pick a point on the picture" if point else ""), status=400)
    return value


def _newest(app: web.Application) -> Optional[FrameSet]:
    """The frame set the disparity view showed last (else the feed's newest), if fresh."""
    now = time.time()
    for fs in _candidates(app):
        if fs is not None and now - fs.timestamp <= FRESH_S and not needs_depth(fs):
            return fs
    return None


def _candidates(app: web.Application) -> List[Optional[FrameSet]]:
    _, shown = app[ENCODERS].disparity_output.current()
    return [shown if isinstance(shown, FrameSet) else None, app[FEED].last_frame]


def not_held(frame: int) -> ApiError:
    return ApiError(f"frame {frame} is no longer held (the daemon keeps the disparity view's last {RECENT} "
                    f"frames and {PINNED_MAX} frozen ones): freeze again, or ask without frame for the "
                    "newest", status=410)


async def frame_for(app: web.Application, frame: Optional[int], or_newest: bool = False) -> FrameSet:
    """Frame ``frame`` (410 when it is no longer held, unless ``or_newest``), or without one the newest
    (waiting for the next when the newest is stale; 503 when none comes)."""
    if frame is not None:
        held = app[ENCODERS].held.get(frame, _candidates(app))
        if held is not None:
            return held
        if not or_newest:
            raise not_held(frame)
    fs = _newest(app)
    if fs is None:
        timeout = app[SETTINGS].frame_wait_s
        try:
            with app[PIPELINE].depth_wanted():  # the stereo core's output with it, where there is a core
                fs = await app[FEED].next_frame(timeout=timeout, accept=lambda f: not needs_depth(f))
        except asyncio.TimeoutError:
            raise ApiError(f"no signal: no frame came within {timeout:g} s", status=503) from None
        except BroadcastClosed:
            raise shutting_down() from None
    return fs


def _frame_param(request: web.Request) -> Tuple[Optional[int], bool]:
    """``frame=N`` (None: the newest) and whether ``fallback=newest`` lets a frame no longer held be
    answered by the newest (a live page's readout: the frame it shows may just have gone; the answer
    names the frame it is of)."""
    fallback = request.query.get("fallback")
    if fallback not in (None, "newest"):
        raise ApiError(f"fallback={str(fallback)[:20]!r}: the only fallback is newest", status=400)
    frame = _int_param(request, "frame", 1 << 62) if "frame" in request.query else None
    return frame, fallback == "newest"


def _depth_of(app: web.Application, fs: FrameSet) -> Tuple[Dict[str, Any], Optional[DepthScale]]:
    """The readout's calibration fields of ``fs`` and the scale to compute its depth with (None: none)."""
    state = app[CALIBRATION].now  # one calibration, whole: the label, the id and the Q matrix agree
    ran = state.for_frame(fs.fabric_count)
    readout = depth_readout(ran, state.frame_calibration)
    depth = ran.depth if ran is not None and "depth_unavailable" not in readout else None
    return readout, depth


async def get_point(request: web.Request) -> web.Response:
    app = request.app
    unknown = sorted(set(request.query) - set(POINT_QUERY) - {TOKEN_PARAM})
    if unknown:
        raise ApiError(f"unknown query parameter {unknown[0][:20]!r}: give x, y and optionally frame",
                       status=400)
    w, h = app[FEED].frame_size
    x, y = _int_param(request, "x", w), _int_param(request, "y", h)
    fs = await frame_for(app, *_frame_param(request))
    readout, depth = _depth_of(app, fs)
    body = await app[EXECUTORS].run(point_at, fs, x, y, depth)
    body.update(readout)
    return json_response(body, headers={"Cache-Control": "no-store"})


# -- the ruler ---------------------------------------------------------------------------------

def ruler_between(fs: FrameSet, points: List[Tuple[int, int]], depth: DepthScale) -> Dict[str, Any]:
    """The 3-D points (metres, by ``depth``'s Q) at rectified left pixels ``points`` of ``fs`` and the
    distance between the first two; ApiError 422 naming a point without a usable disparity (blocks)."""
    found = []
    for i, (x, y) in enumerate(points, start=1):
        p = point_at(fs, x, y, depth)
        if p["disparity_px"] is None:
            raise ApiError(f"point {i} (x {x}, y {y}) has no disparity in frame {fs.frame}: the "
                           "matcher found no match there (too little texture, or seen by one camera "
                           "only); pick a point on a textured surface", status=422)
        if p["point_m"] is None:
            raise ApiError(f"point {i} (x {x}, y {y}) has disparity {p['disparity_px']:g} px in frame "
                           f"{fs.frame}: too far to measure; pick a nearer point", status=422)
        found.append({k: p[k] for k in ("x", "y", "disparity_px", "depth_m", "point_m")})
    a, b = (np.asarray(f["point_m"], dtype=np.float64) for f in found[:2])
    return {"frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source, "points": found,
            "distance_m": float(np.linalg.norm(b - a))}


async def get_ruler(request: web.Request) -> web.Response:
    app = request.app
    unknown = sorted(set(request.query) - set(RULER_QUERY) - {TOKEN_PARAM})
    if unknown:
        raise ApiError(f"unknown query parameter {unknown[0][:20]!r}: give x0, y0, x1, y1 and optionally "
                       "frame", status=400)
    w, h = app[FEED].frame_size
    points = [(_int_param(request, f"x{i}", w, f"point {i + 1}"),
               _int_param(request, f"y{i}", h, f"point {i + 1}")) for i in range(2)]
    fs = await frame_for(app, *_frame_param(request))
    readout, depth = _depth_of(app, fs)
    if depth is None:
        why = readout.get("depth_unavailable") or NO_DEPTH_NONE
        raise ApiError(f"no distances without depth: {why}", status=409)
    body = await app[EXECUTORS].run(ruler_between, fs, points, depth)
    body.update(readout)
    return json_response(body, headers={"Cache-Control": "no-store"})


# -- freeze ------------------------------------------------------------------------------------

def _freeze_state(app: web.Application) -> Dict[str, Any]:
    return {"frozen": app[ENCODERS].held.frames(), "max_frozen": PINNED_MAX, "recent": RECENT}


async def post_freeze(request: web.Request) -> web.Response:
    """Hold one frame (the body's ``frame``, else the newest) for the readouts and the ruler."""
    app = request.app
    body = await read_json(request, example='{"frame": 1234}', optional=True)
    if body is None:
        body = {}
    if not isinstance(body, dict) or set(body) - {"frame"}:
        raise ApiError('send {"frame": N} (a frame a view showed) or nothing for the newest', status=400)
    frame = body.get("frame")
    if frame is not None and (isinstance(frame, bool) or not isinstance(frame, int) or frame < 0):
        raise ApiError(f"frame must be a frame number (a whole number, 0 or more), not {frame!r:.30}",
                       status=400)
    fs = await frame_for(app, frame)
    await app[EXECUTORS].run(disparity_raw, fs)  # the readouts of a frozen frame answer at once
    released = app[ENCODERS].held.pin(fs)
    return json_response({"frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source,
                          "released": released, **_freeze_state(app)},
                         headers={"Location": f"/api/freeze/{fs.frame}"})


async def get_freeze(request: web.Request) -> web.Response:
    return json_response(_freeze_state(request.app), headers={"Cache-Control": "no-store"})


async def delete_freeze(request: web.Request) -> web.Response:
    """Release a frozen frame (the page's unfreeze)."""
    text = request.match_info["frame"]
    try:
        frame = int(text)
    except ValueError:
        raise ApiError(f"a frame number is a whole number, not {text[:20]!r}", status=400) from None
    if not request.app[ENCODERS].held.unpin(frame):
        raise ApiError(f"frame {frame} is not frozen (it may have been released, or pushed out by "
                       f"{PINNED_MAX} newer freezes): nothing to release", status=404)
    return json_response({"released": frame, **_freeze_state(request.app)})


async def get_disparity(request: web.Request) -> web.Response:
    record = request.app[CALIBRATION].now.frame_calibration
    depth = record.depth
    body: Dict[str, Any] = {
        "min_disparity": STEREO_BM["min_disparity"], "num_disparities": STEREO_BM["num_disparities"],
        "block_size": STEREO_BM["block_size"], "colormap": "jet",
        "calibration_id": record.id,
        "focal_px": depth.focal_px if depth else None,
        "baseline_m": depth.baseline_m if depth else None,
        "doffs_px": depth.doffs_px if depth else None,
        "frame_size": list(request.app[FEED].frame_size),
        "colors": _jet_colours(),
    }
    return json_response(body, headers={"Cache-Control": "no-store"})


@functools.lru_cache(maxsize=1)
def _jet_colours() -> List[str]:
    """The disparity view's 256 colours, level 0 to 255 (``#rrggbb``), exactly as it draws them."""
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(1, -1), cv2.COLORMAP_JET)[0]
    return [f"#{int(r):02x}{int(g):02x}{int(b):02x}" for b, g, r in lut]


def setup_routes(app: web.Application) -> None:
    """Register the routes; call before the generic ``/api/captures/{id}/{file}`` route is added."""
    app[THUMBS] = ThumbnailCache()
    r = app.router
    r.add_get(r"/api/captures/{id:[^/]+}/thumb.jpg", capture_thumb)
    r.add_post(r"/api/captures/{id:[^/]+}/restore", restore_capture)
    r.add_get("/api/point", get_point)
    r.add_get("/api/disparity", get_disparity)
    r.add_get("/api/ruler", get_ruler)
    r.add_get("/api/freeze", get_freeze)
    r.add_post("/api/freeze", post_freeze)
    r.add_delete(r"/api/freeze/{frame:[^/]+}", delete_freeze)
