"""The page's stereo tools (issue 24, item 4), over the newest frame.

- ``GET /api/alignment``: how well the rectified pair's rows agree (matched features' vertical
  offsets: :func:`..frames.tools.alignment`); 422 when too few features match to say.
- ``GET /api/histogram[?view=RAW_VIEW][&mask=0]``: each raw camera's histograms, clipped shares and
  clipping mask (:func:`..frames.tools.histogram`).

Both compute on the ``work`` threads, once per frame (cached in the frame set), so the page's 1 Hz
polls from several tabs cost one computation a frame.
"""
from __future__ import annotations

import asyncio
import base64
import contextlib
import time
from typing import Any, Dict, List

from aiohttp import web

from ..errors import ApiError
from ..frames.feed import BroadcastClosed
from ..frames.pipeline import FrameSet
from ..frames.tools import MIN_MATCHES, alignment_of, histogram_of
from ..frames.views import RAW_VIEWS, VIEWS
from .bodies import json_response
from .errors import shutting_down
from .security import TOKEN_PARAM
from .state import EXECUTORS, FEED, PIPELINE, SETTINGS

__all__ = ["setup_routes"]

FRESH_S = 1.0  # an older frame is not "the newest": wait for the next one


def _check_query(request: web.Request, allowed: List[str]) -> None:
    unknown = sorted(set(request.query) - set(allowed) - {TOKEN_PARAM})
    if unknown:
        hint = ", ".join(allowed) if allowed else "nothing"
        raise ApiError(f"unknown query parameter {unknown[0][:20]!r}: give {hint}", status=400)


async def _frame(app: web.Application, need_raw: bool) -> FrameSet:
    """The newest frame (with its raw pair when ``need_raw``), or the next one when that is stale."""
    last = app[FEED].last_frame
    fresh = last is not None and time.time() - last.timestamp <= FRESH_S
    if last is not None and fresh and (not need_raw or last.raw is not None):
        return last

    def wanted(fs: FrameSet) -> bool:
        return not need_raw or fs.raw is not None

    timeout = app[SETTINGS].frame_wait_s
    try:
        with app[PIPELINE].raw_wanted() if need_raw else contextlib.nullcontext():
            return await app[FEED].next_frame(timeout=timeout, accept=wanted)
    except asyncio.TimeoutError:
        raise ApiError(f"no signal: no frame came within {timeout:g} s; check the cameras "
                       "(GET /api/status)", status=503) from None
    except BroadcastClosed:
        raise shutting_down() from None


async def get_alignment(request: web.Request) -> web.Response:
    _check_query(request, [])
    app = request.app
    fs = await _frame(app, need_raw=False)
    found = await app[EXECUTORS].run(alignment_of, fs)
    body: Dict[str, Any] = {"frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source,
                            **found.to_json()}
    status = 200
    if not found.enough:
        status = 422
        body["error"] = (f"too few features: {found.count} matched pairs, {MIN_MATCHES} needed to measure "
                         "the rows; point the cameras at a textured, well-lit scene")
    return json_response(body, status=status, headers={"Cache-Control": "no-store"})


async def get_histogram(request: web.Request) -> web.Response:
    _check_query(request, ["view", "mask"])
    app = request.app
    raw = [v for v in VIEWS if v in RAW_VIEWS]
    view = request.query.get("view")
    if view is not None and view not in RAW_VIEWS:
        raise ApiError(f"view {view[:30]!r} is not a raw camera view: give one of {', '.join(raw)}, "
                       "or no view for all", status=400)
    mask_text = request.query.get("mask", "1")
    if mask_text not in ("0", "1"):
        raise ApiError(f"mask must be 0 or 1, not {mask_text[:20]!r}", status=400)
    views = [view] if view is not None else raw
    fs = await _frame(app, need_raw=True)

    def compute() -> Dict[str, Dict[str, Any]]:
        return {v: histogram_of(fs, v) for v in views}

    found = await app[EXECUTORS].run(compute)
    out: Dict[str, Any] = {}
    for v, h in found.items():
        item = {k: val for k, val in h.items() if k != "mask_png"}
        if mask_text == "1":
            item["mask_png"] = "data:image/png;base64," + base64.b64encode(h["mask_png"]).decode("ascii")
        out[v] = item
    return json_response({"frame": fs.frame, "timestamp": fs.timestamp, "source": fs.source, "views": out},
                         headers={"Cache-Control": "no-store"})


def setup_routes(app: web.Application) -> None:
    r = app.router
    r.add_get("/api/alignment", get_alignment)
    r.add_get("/api/histogram", get_histogram)


