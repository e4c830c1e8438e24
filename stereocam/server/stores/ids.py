"""Store ids: ``20261122T040512Z-000123-ab12``, the UTC second, the frame number, 4 random hex digits.

Captures, recordings and calibration pairs are all named so. They sort by
time, are URL-safe, and are checked with :func:`valid_id` before any path is
built from them.
"""
from __future__ import annotations

import re
from datetime import datetime, timezone

from .files import iso_utc

__all__ = ["ID_PATTERN", "ID_EXAMPLE", "MAX_FRAME_NUMBER", "MAX_ID_LENGTH", "valid_id", "created_from_id"]

ID_PATTERN = r"[0-9]{8}T[0-9]{6}Z-[0-9]{6,10}-[0-9a-f]{4}"
ID_EXAMPLE = "20261122T040512Z-000123-ab12"
MAX_FRAME_NUMBER = 10**10 - 1  # what the id's 6 to 10 digits hold
MAX_ID_LENGTH = 32

_ID_RE = re.compile(ID_PATTERN)


def valid_id(value: object) -> bool:
    """True if ``value`` is a well-formed store id (says nothing about whether it exists)."""
    return isinstance(value, str) and len(value) <= MAX_ID_LENGTH and _ID_RE.fullmatch(value) is not None


def created_from_id(ident: str) -> str:
    """The creation time an id names, for a stored folder whose own file does not say."""
    t = datetime.strptime(ident[:16], "%Y%m%dT%H%M%SZ").replace(tzinfo=timezone.utc)
    return iso_utc(t)
