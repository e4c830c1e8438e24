"""Fault injection over HTTP (``/api/faults``): only with ``serve --allow-fault-injection``, emulated fabric.

For tests and demonstrations of the daemon's recovery: inject a fault of a
kind :mod:`..overlays.emulated.faults` knows, watch ``/healthz``,
``/api/status`` ``faults`` and ``/metrics`` report it, end it, watch the
part recover. Without the flag none of these routes exists (404). Faults
still active when the daemon stops are ended first, so the fabric stops cleanly.
"""
from __future__ import annotations

import logging
from typing import Any, AsyncIterator

from aiohttp import web

from ...overlays.emulated.faults import KINDS, FaultError, FaultInjector
from ..frames.errors import parse_json
from .state import OVERLAY
from .streams import json_error

log = logging.getLogger(__name__)

__all__ = ["setup", "INJECTOR", "FaultInjectionUnavailable"]

INJECTOR: "web.AppKey[FaultInjector]" = web.AppKey("stereocam.fault_injector", FaultInjector)


class FaultInjectionUnavailable(Exception):
    """The overlay is not the emulated fabric: a board's faults cannot be made on request."""


async def list_faults(request: web.Request) -> web.Response:
    injector = request.app[INJECTOR]
    return web.json_response({"kinds": {k: list(v) if v else None for k, v in KINDS.items()},
                              "injected": [f.to_json() for f in injector.active()]},
                             headers={"Cache-Control": "no-store"})


async def inject_fault(request: web.Request) -> web.Response:
    if request.content_type != "application/json":
        return json_error(415, 'send JSON such as {"kind": "dma_slave", "target": "vdma_raw.s2mm"}')
    try:
        body: Any = parse_json(await request.read())
    except (ValueError, UnicodeDecodeError):
        return json_error(400, 'the body is not valid JSON: send {"kind": ..., "target": ...}')
    if not isinstance(body, dict) or set(body) - {"kind", "target"} or "kind" not in body:
        return json_error(400, 'send an object with "kind" and, for kinds on a part, "target" '
                               "(GET /api/faults lists them)")
    kind, target = body["kind"], body.get("target")
    if not isinstance(kind, str) or not (target is None or isinstance(target, str)):
        return json_error(400, "kind and target are strings (GET /api/faults lists them)")
    try:
        fault = request.app[INJECTOR].inject(kind, target)
    except FaultError as exc:
        return json_error(409 if "already has" in str(exc) else 400, str(exc))
    log.warning("fault injected on request: %s%s (id %d)", kind, f" on {target}" if target else "", fault.id)
    return web.json_response(fault.to_json(), status=201)


async def end_fault(request: web.Request) -> web.Response:
    text = request.match_info["id"]
    if not text.isdigit() or len(text) > 12:
        return json_error(404, f"no injected fault {text!r}: GET /api/faults lists them")
    try:
        fault = request.app[INJECTOR].end(int(text))
    except KeyError:
        return json_error(404, f"no injected fault {text}: it ended already, or GET /api/faults lists them")
    log.warning("fault ended on request: %s (id %d)", fault.kind, fault.id)
    return web.json_response(fault.to_json())


async def end_all_faults(request: web.Request) -> web.Response:
    ended = request.app[INJECTOR].end_all()
    return web.json_response({"ended": [f.to_json() for f in ended]})


async def _end_at_stop(app: web.Application) -> AsyncIterator[None]:
    yield
    ended = app[INJECTOR].end_all()
    if ended:
        log.info("ended %d injected fault(s) before stopping the fabric", len(ended))


def setup(app: web.Application) -> None:
    """Add the routes; raises :class:`FaultInjectionUnavailable` off the emulated fabric.

    Call it after the fabric's cleanup context is appended: faults end before the fabric stops.
    """
    overlay = app[OVERLAY]
    hw = getattr(overlay, "hw", None)
    if getattr(overlay.fabric, "backend", None) != "emulated" or hw is None:
        raise FaultInjectionUnavailable("--allow-fault-injection works on the emulated fabric only "
                                        "(--backend emulated): a board's faults cannot be made on request")
    app[INJECTOR] = FaultInjector(hw)
    app.cleanup_ctx.append(_end_at_stop)
    app.router.add_get("/api/faults", list_faults)
    app.router.add_post("/api/faults", inject_fault)
    app.router.add_delete("/api/faults", end_all_faults)
    app.router.add_delete("/api/faults/{id}", end_fault)
    log.warning("fault injection is on (/api/faults): for testing only")
