"""The one base of errors the daemon's building blocks raise for a user to read.

No aiohttp here: the frame path raises these too; the HTTP side's middleware
(``stereocam/server/http/errors.py``) turns every one into the daemon's JSON answer.
"""
from __future__ import annotations

import json
from typing import Any, Dict, Mapping, Optional, Union


class ApiError(Exception):
    """``status`` is the HTTP status to answer with, ``message`` one line for the user, ``headers``
    extra response headers (``Retry-After``, ``WWW-Authenticate``, ...)."""

    status = 500

    def __init__(self, message: str, *, status: Optional[int] = None,
                 headers: Optional[Mapping[str, str]] = None) -> None:
        super().__init__(message)
        self.message = message
        if status is not None:
            self.status = int(status)
        self.headers: Dict[str, str] = dict(headers or {})

    def to_json(self) -> Dict[str, str]:
        return {"error": self.message}


def parse_json(data: Union[str, bytes]) -> Any:
    """``json.loads`` whose every failure is a ``ValueError`` (so a caller's ``except ValueError`` is a 400).

    ``json.loads`` raises ``RecursionError`` on deeply nested arrays, which would end
    as a 500 with a traceback; bytes that are not UTF-8 raise ``UnicodeDecodeError``,
    itself a ``ValueError``.
    """
    try:
        return json.loads(data)
    except RecursionError:
        raise ValueError("nested too deeply") from None
