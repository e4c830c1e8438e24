"""The stereo core's registers from the API (issue 23): ``GET /api/stereo`` and ``PUT /api/stereo``.

GET gives whether the overlay has a stereo core (and so what computes the disparity), the
parameters it holds, their defaults and limits (its build's, read back), and its status. PUT takes
a JSON object of the parameters to change (the others stay); a value the core would refuse is
refused here with every problem's text (422; an unknown name or a body that is not an object, 400)
and nothing is written, so the previous parameters stay active. Programming waits for the core to
latch the set at the next frame start (on the ``work`` threads); one PUT at a time.
"""
from __future__ import annotations

import asyncio
from dataclasses import fields
from typing import Any, Dict

from aiohttp import web

from ...overlays.interface import RegisterTimeout, StereoConfigRefused, StereoControl
from ...overlays.spec.stereo import DEFAULT_PARAMS, LIMITS, StereoParams
from ..errors import ApiError
from ..frames.depth import disparity_by
from .bodies import json_response, read_json
from .state import EXECUTORS, OVERLAY

__all__ = ["setup_routes", "stereo_state"]

EXAMPLE = '{"p2": 120, "uniqueness": 20}'
NAMES = tuple(f.name for f in fields(StereoParams))
PUT_LOCK: "web.AppKey[asyncio.Lock]" = web.AppKey("stereocam.stereo_put", asyncio.Lock)


def limits_of(control: StereoControl) -> Dict[str, Any]:
    """What the core takes for each parameter (its build's ranges; the switches are true or false)."""
    build = control.build
    out: Dict[str, Any] = {}
    for name in NAMES:
        if name in LIMITS:
            lo, hi = LIMITS[name](build)
            out[name] = {"min": lo, "max": hi}
        else:
            out[name] = {"type": "boolean"}
    out["num_disp"]["multiple_of"] = build.parallel
    out["rules"] = ["p1 <= p2_edge <= p2"]
    return out


def stereo_state(control: StereoControl) -> Dict[str, Any]:
    """The body of ``GET /api/stereo`` for an overlay with a stereo core (register reads: blocks)."""
    build = control.build
    return {"present": True, "by": disparity_by(True), "params": control.params().as_json(),
            "defaults": DEFAULT_PARAMS.as_json(), "limits": limits_of(control),
            "build": {"max_width": build.max_width, "max_height": build.max_height,
                      "max_disp": build.max_disp, "parallel": build.parallel},
            "status": control.status().as_json()}


def _no_core() -> Dict[str, Any]:
    return {"present": False, "by": disparity_by(False)}


def _control(app: web.Application) -> StereoControl:
    control = app[OVERLAY].stereo
    if control is None:
        raise ApiError("this bitstream has no stereo core, so it has no matcher registers: the disparity is "
                       f"computed on the {disparity_by(False)}; load a depth build to set them", status=409)
    return control


async def get_stereo(request: web.Request) -> web.Response:
    control = request.app[OVERLAY].stereo
    body = _no_core() if control is None else await request.app[EXECUTORS].run(stereo_state, control)
    return json_response(body, headers={"Cache-Control": "no-store"})


def parse_changes(body: Any, current: StereoParams, control: StereoControl) -> StereoParams:
    """``current`` with the body's changes; ApiError 400 (not an object, unknown name) or 422 (refused)."""
    if not isinstance(body, dict) or not body:
        raise ApiError(f"send a JSON object of the parameters to change, such as {EXAMPLE}", status=400)
    unknown = sorted(set(body) - set(NAMES))
    if unknown:
        raise ApiError(f"unknown parameter {unknown[0][:30]!r}: the stereo core takes {', '.join(NAMES)}",
                       status=400)
    wanted = current.with_values(**body)
    problems = wanted.problems(control.build)
    if problems:
        raise ApiError("; ".join(problems) + "; the previous parameters stay active", status=422)
    return wanted


def _program(control: StereoControl, body: Any) -> Dict[str, Any]:
    """Check and program the changes (blocks until the core latched them, at most the driver's wait)."""
    wanted = parse_changes(body, control.params(), control)
    try:
        control.program(wanted)
    except StereoConfigRefused as exc:
        raise ApiError(f"{exc}", status=422) from None
    except RegisterTimeout:
        return {**stereo_state(control), "applied": False,
                "note": "written; the core latches them at the next frame start, and none came yet"}
    return {**stereo_state(control), "applied": True}


async def put_stereo(request: web.Request) -> web.Response:
    app = request.app
    control = _control(app)
    body = await read_json(request, example=EXAMPLE)
    async with app[PUT_LOCK]:
        out = await app[EXECUTORS].run(_program, control, body)
    return json_response(out, status=200 if out["applied"] else 202)


def setup_routes(app: web.Application) -> None:
    app[PUT_LOCK] = asyncio.Lock()
    app.router.add_get("/api/stereo", get_stereo)
    app.router.add_put("/api/stereo", put_stereo)
