"""JSON in and out: the one reader of JSON bodies, so every endpoint refuses a bad one alike, and
the one writer of JSON responses, which never sends NaN or Infinity.

The body's size is bounded before it is read (``client_max_size``, set from
``max_upload_bytes``; the guard middleware refuses a declared larger one first).
Every refusal is an :class:`~..errors.ApiError` the error middleware answers.
"""
from __future__ import annotations

import json
import math
from typing import Any, Mapping, Optional

from aiohttp import web

from ..errors import ApiError, parse_json
from .errors import too_large

__all__ = ["read_json", "json_response", "JSON"]

JSON = "application/json"


async def read_json(request: web.Request, *, example: Optional[str] = None, optional: bool = False,
                    typed: bool = True) -> Any:
    """The JSON value of ``request``'s body; raises ApiError 400 (not JSON), 413 (too large) or 415.

    ``typed``: the body must come as ``application/json`` (415 otherwise); the calibration
    panel's endpoints take any type. ``optional``: an empty body is ``None``, whatever its type
    (else a 400).
    ``example`` (a JSON text) is shown in the refusals.
    """
    wrong_type = typed and request.content_type != JSON
    if wrong_type and not optional:
        raise _unsupported(request, example)
    try:
        raw = await request.read()
    except web.HTTPRequestEntityTooLarge:
        raise ApiError(too_large(request.client_max_size), status=413) from None
    if not raw.strip():
        if optional:
            return None
        such = f" such as {example}" if example else ""
        raise ApiError(f"the body is empty: send JSON{such}", status=400)
    if wrong_type:
        raise _unsupported(request, example)
    try:
        return parse_json(raw)
    except ValueError as exc:  # UnicodeDecodeError too
        reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise ApiError(f"the body is not valid JSON ({reason})" + (f": send {example}" if example else ""),
                       status=400) from None


def _unsupported(request: web.Request, example: Optional[str]) -> ApiError:
    given = request.content_type or "nothing"
    such = f" such as {example}" if example else ""
    return ApiError(f"send JSON (Content-Type: {JSON}){such}, not {given}", status=415)


def _finite(value: Any) -> Any:
    """``value`` with every float that is not finite replaced by None (JSON has no NaN or Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def dumps(value: Any) -> str:
    """Standard JSON: a NaN or an infinity (a damaged ``recording.json`` or ``meta.json`` may hold
    them, Python's ``json`` reads them) becomes null, where ``json.dumps`` would write ``NaN`` and
    every browser's ``JSON.parse`` would refuse the whole response."""
    try:
        return json.dumps(value, allow_nan=False)
    except ValueError:  # rare: only then is the value walked
        return json.dumps(_finite(value), allow_nan=False)


def json_response(data: Any, *, status: int = 200,
                  headers: Optional[Mapping[str, str]] = None) -> web.Response:
    """``web.json_response`` writing standard JSON (:func:`dumps`)."""
    return web.json_response(data, status=status, headers=headers, dumps=dumps)
