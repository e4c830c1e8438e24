"""The errors the folder stores (captures, recordings, calibration pairs) raise on purpose.

One tree for every store: :class:`StoreError` and its kinds. Each carries its
:class:`.errors.Kind` (the HTTP side chooses the status) and a one-line
``message`` for the user; the stores name themselves in the message ("no
capture ...", "no recording ...").
"""
from __future__ import annotations

from ..errors import ApiError, Kind

__all__ = ["StoreError", "InvalidId", "NotFound", "DiskFull", "Conflict", "Damaged", "gone"]


class StoreError(ApiError):
    """Base of every error a store raises on purpose; of itself a failure of the store (I/O)."""


class InvalidId(StoreError):
    """The id is not of the form ``20261122T040512Z-000123-ab12`` (bad request)."""

    kind = Kind.BAD_REQUEST


class NotFound(StoreError):
    """Nothing stored under that (valid) id, or no such file in it (not found)."""

    kind = Kind.NOT_FOUND


class DiskFull(StoreError):
    """Not enough space to store it; nothing was written (no space)."""

    kind = Kind.NO_SPACE


class Conflict(StoreError):
    """The request clashes with what is stored or running: a restore of a folder that exists, a second
    recording (conflict)."""

    kind = Kind.CONFLICT


class Damaged(StoreError):
    """A stored folder whose files cannot be used (missing, corrupt) for this request (unusable)."""

    kind = Kind.UNUSABLE


def gone(noun: str, ident: str) -> NotFound:
    """The one not-found message for a stored folder that is gone, wherever its store finds it gone."""
    return NotFound(f"no {noun} {ident}: it was deleted or never existed; list the {noun}s")
