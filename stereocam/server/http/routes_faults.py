"""Fault injection over HTTP (``/api/faults``): only with ``serve --allow-fault-injection``, emulated fabric.

For tests and demonstrations of the daemon's recovery: inject a fault of a
kind the overlay's ``fault_injection`` knows (:class:`~stereocam.overlays.interface.FaultInjection`),
watch ``/healthz``, ``/api/status`` ``faults`` and ``/metrics`` report it,
end it, watch the part recover. Without the flag none of these routes exists (404). Faults
still active when the daemon stops are ended first, so the fabric stops cleanly.
"""
from __future__ import annotations

import logging
from typing import Any, AsyncIterator

from aiohttp import web

from ...overlays.interface import FaultError, FaultInjection
from ..errors import ApiError
from .bodies import json_response, read_json
from .state import OVERLAY

log = logging.getLogger(__name__)

__all__ = ["setup", "INJECTOR", "FaultInjectionUnavailable"]

INJECTOR: "web.AppKey[FaultInjection]" = web.AppKey("stereocam.fault_injector", FaultInjection)


class FaultInjectionUnavailable(Exception):
    """The overlay makes no faults on request (a board's cannot be made)."""


async def list_faults(request: web.Request) -> web.Response:
    injector = request.app[INJECTOR]
    return json_response({"kinds": {k: list(v) if v else None for k, v in injector.kinds.items()},
                              "injected": [f.to_json() for f in injector.active()]},
                             headers={"Cache-Control": "no-store"})


async def inject_fault(request: web.Request) -> web.Response:
    body: Any = await read_json(request, example='{"kind": "dma_slave", "target": "vdma_raw.s2mm"}')
    if not isinstance(body, dict) or set(body) - {"kind", "target"} or "kind" not in body:
        raise ApiError('send an object with "kind" and, for kinds on a part, "target" '
                       "(GET /api/faults lists them)", status=400)
    kind, target = body["kind"], body.get("target")
    if not isinstance(kind, str) or not (target is None or isinstance(target, str)):
        raise ApiError("kind and target are strings (GET /api/faults lists them)", status=400)
    try:
        fault = request.app[INJECTOR].inject(kind, target)
    except FaultError as exc:
        raise ApiError(str(exc), status=409 if "already has" in str(exc) else 400) from None
    log.warning("fault injected on request: %s%s (id %d)", kind, f" on {target}" if target else "", fault.id)
    return json_response(fault.to_json(), status=201)


async def end_fault(request: web.Request) -> web.Response:
    text = request.match_info["id"]
    if not text.isdigit() or len(text) > 12:
        raise ApiError(f"no injected fault {text!r}: GET /api/faults lists them", status=404)
    try:
        fault = request.app[INJECTOR].end(int(text))
    except KeyError:
        raise ApiError(f"no injected fault {text}: it ended already, or GET /api/faults lists them",
                       status=404) from None
    log.warning("fault ended on request: %s (id %d)", fault.kind, fault.id)
    return json_response(fault.to_json())


async def end_all_faults(request: web.Request) -> web.Response:
    ended = request.app[INJECTOR].end_all()
    return json_response({"ended": [f.to_json() for f in ended]})


async def _end_at_stop(app: web.Application) -> AsyncIterator[None]:
    yield
    ended = app[INJECTOR].end_all()
    if ended:
        log.info("ended %d injected fault(s) before stopping the fabric", len(ended))


def setup(app: web.Application) -> None:
    """Add the routes; raises :class:`FaultInjectionUnavailable` for an overlay without fault injection.

    Call it after the fabric's cleanup context is appended: faults end before the fabric stops.
    """
    injector = app[OVERLAY].fault_injection
    if injector is None:
        raise FaultInjectionUnavailable("--allow-fault-injection works on the emulated fabric only "
                                        "(--backend emulated): a board's faults cannot be made on request")
    app[INJECTOR] = injector
    app.cleanup_ctx.append(_end_at_stop)
    app.router.add_get("/api/faults", list_faults)
    app.router.add_post("/api/faults", inject_fault)
    app.router.add_delete("/api/faults", end_all_faults)
    app.router.add_delete("/api/faults/{id}", end_fault)
    log.warning("fault injection is on (/api/faults): for testing only")
