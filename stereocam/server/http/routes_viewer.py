"""What the page's capture viewer and live-view readouts need.

- ``GET /api/captures/{id}/thumb.jpg``: a small JPEG of a capture (its rectified left frame),
  made on first use and kept in memory (:class:`ThumbnailCache`).
- ``POST /api/captures/{id}/restore``: undo of ``DELETE /api/captures/{id}`` (the capture
  comes back from the store's trash).
- ``GET /api/point?x=&y=``: the rectified pixels, the disparity and the depth (metres, from the
  calibration's Q matrix) at one pixel of the newest frame the disparity view showed.
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
from ..frames.feed import BroadcastClosed
from ..frames.pipeline import FrameSet
from ..frames.views import STEREO_BM, disparity_raw
from ..stores.captures import THUMB_FRAMES, CaptureStore, capture_file
from ..stores.frame_calibration import DepthScale, FrameCalibration
from .bodies import json_response
from .errors import shutting_down
from .security import TOKEN_PARAM
from .state import CALIBRATION, CAPTURES, ENCODERS, EXECUTORS, FEED, SETTINGS

__all__ = ["setup_routes", "ThumbnailCache", "point_at", "depth_readout"]

THUMB_CACHE_ENTRIES = 256  # about 5 KB each
FRESH_S = 1.0  # a frame set older than this is not "the newest": /api/point waits for the next one
POINT_QUERY = ("x", "y", "frame")


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


def _int_param(request: web.Request, name: str, hi: int) -> int:
    text = request.query.get(name)
    if text is None:
        raise ApiError(f"give {name}: a pixel of the rectified left image, 0 to {hi - 1}", status=400)
    try:
        value = int(text)
    except ValueError:
        raise ApiError(f"{name} must be a whole number of pixels, not {text[:20]!r}", status=400) from None
    if not 0 <= value < hi:
        raise ApiError(f"{name} = {value} is outside the image: 0 to {hi - 1}", status=400)
    return value


def _newest(app: web.Application, frame: Optional[int]) -> Optional[FrameSet]:
    """The frame set the disparity view showed last (or ``frame`` if that is one at hand), if fresh."""
    now = time.time()
    candidates = []
    _, shown = app[ENCODERS].disparity_output.current()
    if isinstance(shown, FrameSet):
        candidates.append(shown)
    last = app[FEED].last_frame
    if last is not None:
        candidates.append(last)
    for fs in candidates:
        if frame is not None and fs.frame == frame:
            return fs
    for fs in candidates:
        if now - fs.timestamp <= FRESH_S:
            return fs
    return None


async def get_point(request: web.Request) -> web.Response:
    app = request.app
    unknown = sorted(set(request.query) - set(POINT_QUERY) - {TOKEN_PARAM})
    if unknown:
        raise ApiError(f"unknown query parameter {unknown[0][:20]!r}: give x, y and optionally frame",
                       status=400)
    w, h = app[FEED].frame_size
    x, y = _int_param(request, "x", w), _int_param(request, "y", h)
    frame = _int_param(request, "frame", 1 << 62) if "frame" in request.query else None
    fs = _newest(app, frame)
    if fs is None:
        timeout = app[SETTINGS].frame_wait_s
        try:
            fs = await app[FEED].next_frame(timeout=timeout)
        except asyncio.TimeoutError:
            raise ApiError(f"no signal: no frame came within {timeout:g} s", status=503) from None
        except BroadcastClosed:
            raise shutting_down() from None
    state = app[CALIBRATION].now  # one calibration, whole: the label, the id and the Q matrix agree
    ran = state.for_frame(fs.fabric_count)
    readout = depth_readout(ran, state.frame_calibration)
    depth = ran.depth if ran is not None and "depth_unavailable" not in readout else None
    body = await app[EXECUTORS].run(point_at, fs, x, y, depth)
    body.update(readout)
    return json_response(body, headers={"Cache-Control": "no-store"})


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
