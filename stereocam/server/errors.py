"""The one base of errors the daemon's building blocks raise for a user to read.

No aiohttp and no HTTP status here: the frame path raises these with a :class:`Kind`
(what went wrong: a bad request, something not found, no space, ...); the HTTP side
(``stereocam/server/http/errors.py``) chooses the status for each kind and turns every
one into the daemon's JSON answer.
"""
from __future__ import annotations

import enum
import json
from typing import Any, Dict, Mapping, Optional, Union


class Kind(enum.Enum):
    """What kind of refusal or failure an :class:`ApiError` is; the HTTP side maps each to a status."""

    BAD_REQUEST = "bad_request"  # the caller's input is malformed or out of range
    NOT_FOUND = "not_found"  # nothing of that (valid) name
    CONFLICT = "conflict"  # clashes with what exists or runs now
    TOO_LARGE = "too_large"  # more bytes than allowed
    UNSUPPORTED = "unsupported"  # a format or media type that is not taken
    UNUSABLE = "unusable"  # well-formed, but cannot be used (damaged, wrong size, no pattern found)
    TOO_MANY = "too_many"  # a limit on how many at once
    FAILED = "failed"  # the daemon's own failure (I/O, a bug)
    UNAVAILABLE = "unavailable"  # not now: no signal, shutting down, the hardware did not commit
    TIMEOUT = "timeout"  # the hardware did not answer in time
    NO_SPACE = "no_space"  # the disk is (too) full


class ApiError(Exception):
    """``kind`` says what went wrong, ``message`` one line for the user, ``headers`` extra response headers
    (``Retry-After``, ``WWW-Authenticate``, ...).

    ``status`` is None unless the HTTP side chose one itself (its handlers and middlewares raise
    ``ApiError(message, status=...)``); otherwise the HTTP side's table of kinds gives it.
    """

    kind = Kind.FAILED
    status: Optional[int] = None

    def __init__(self, message: str, *, kind: Optional[Kind] = None, status: Optional[int] = None,
                 headers: Optional[Mapping[str, str]] = None) -> None:
        super().__init__(message)
        self.message = message
        if kind is not None:
            self.kind = kind
        if status is not None:
            self.status = int(status)
        self.headers: Dict[str, str] = dict(headers or {})

    def to_json(self) -> Dict[str, str]:
        return {"error": self.message}


def parse_json(data: Union[str, bytes]) -> Any:
    """``json.loads`` whose every failure is a ``ValueError`` (a caller's ``except ValueError``: bad request).

    ``json.loads`` raises ``RecursionError`` on deeply nested arrays, which would end
    as a failure with a traceback; bytes that are not UTF-8 raise ``UnicodeDecodeError``,
    itself a ``ValueError``.
    """
    try:
        return json.loads(data)
    except RecursionError:
        raise ValueError("nested too deeply") from None
