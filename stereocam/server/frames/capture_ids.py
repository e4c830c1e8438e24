"""Capture ids: ``20261122T040512Z-000123-ab12``, the UTC second, the frame number, 4 random hex digits.

They sort by time, are URL-safe, and are checked against :data:`ID_PATTERN`
before any path is built from them.
"""
from __future__ import annotations

import re
from datetime import datetime, timezone

from .store_files import iso_utc

__all__ = ["ID_PATTERN", "ID_EXAMPLE", "MAX_FRAME_NUMBER"]

ID_PATTERN = r"[0-9]{8}T[0-9]{6}Z-[0-9]{6,10}-[0-9a-f]{4}"
ID_EXAMPLE = "20261122T040512Z-000123-ab12"
MAX_FRAME_NUMBER = 10**10 - 1  # what the id's 6 to 10 digits hold

_ID_RE = re.compile(ID_PATTERN)
_MAX_ID_LENGTH = 32


def created_from_id(capture_id: str) -> str:
    """The creation time an id names, for a capture whose meta.json does not say."""
    t = datetime.strptime(capture_id[:16], "%Y%m%dT%H%M%SZ").replace(tzinfo=timezone.utc)
    return iso_utc(t)
