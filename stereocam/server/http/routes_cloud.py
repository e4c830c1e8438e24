"""Point clouds over HTTP: a capture's stored ``cloud.ply`` and the newest frame's.

- ``GET /api/captures/{id}/cloud.ply``: the cloud the capture stored (409 saying why when it
  has none: its calibration gave no depth, or it was captured before captures kept depth).
- ``GET /api/cloud.ply``: the newest frame's, from the stereo core's output and the calibration
  the frame ran with (409: no calibration with depth; 422: a frame size the core does not take).

Binary little-endian PLY, points in metres (``stereocam/calibration/cloud.py``); computed on
the daemon's ``work`` threads.
"""
from __future__ import annotations

from aiohttp import web

from ..errors import ApiError
from ..frames.cloud import CLOUD_FILE, frame_cloud
from ..stores.captures import CaptureInfo, CaptureStore
from .routes_viewer import frame_for
from .state import CALIBRATION, CAPTURES, EXECUTORS

__all__ = ["setup_routes", "PLY_TYPE"]

PLY_TYPE = "application/octet-stream"  # PLY has no registered media type; tools go by the name


def _ply(body: bytes, filename: str) -> web.Response:
    return web.Response(body=body, content_type=PLY_TYPE, headers={
        "Content-Disposition": f'attachment; filename="{filename}"', "Cache-Control": "no-store"})


def _why_none(info: CaptureInfo) -> str:
    depth = info.meta.get("depth")
    if not isinstance(depth, dict):
        return "it was captured before captures kept depth"
    why = depth.get("cloud_unavailable") or depth.get("unavailable")
    return str(why) if why else "none was stored"


async def capture_cloud(request: web.Request) -> web.Response:
    store: CaptureStore = request.app[CAPTURES]
    cid = request.match_info["id"]
    run = request.app[EXECUTORS].run
    info = await run(store.get, cid)
    if CLOUD_FILE not in {f.name for f in info.files}:
        raise ApiError(f"capture {info.id} has no point cloud: {_why_none(info)}", status=409)
    body = await run(store.read_file, info.id, CLOUD_FILE)
    return _ply(body, f"{info.id}.ply")


async def live_cloud(request: web.Request) -> web.Response:
    app = request.app
    fs = await frame_for(app, None)
    calibration = app[CALIBRATION].for_frame(fs.fabric_count)
    body = await app[EXECUTORS].run(frame_cloud, fs, calibration, f"frame {fs.frame}")
    return _ply(body, f"frame-{fs.frame}.ply")


def setup_routes(app: web.Application) -> None:
    """Register the routes; call before the generic ``/api/captures/{id}/{file}`` route is added."""
    app.router.add_get("/api/cloud.ply", live_cloud)
    app.router.add_get(r"/api/captures/{id:[^/]+}/cloud.ply", capture_cloud)
