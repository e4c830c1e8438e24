"""The errors the folder stores (captures, recordings, calibration pairs) raise on purpose.

One tree for every store: :class:`StoreError` and its kinds. Each carries the
HTTP ``status`` to answer with and a one-line ``message`` for the user; the
stores name themselves in the message ("no capture ...", "no recording ...").
"""
from __future__ import annotations

from .errors import ApiError

__all__ = ["StoreError", "InvalidId", "NotFound", "DiskFull", "Conflict", "Damaged", "gone"]


class StoreError(ApiError):
    """Base of every error a store raises on purpose: ``status`` is the HTTP status to answer with."""


class InvalidId(StoreError):
    """The id is not of the form ``20261122T040512Z-000123-ab12`` (400)."""

    status = 400


class NotFound(StoreError):
    """Nothing stored under that (valid) id, or no such file in it (404)."""

    status = 404


class DiskFull(StoreError):
    """Not enough space to store it; nothing was written (507)."""

    status = 507


class Conflict(StoreError):
    """The request clashes with what is stored or running: a restore of a folder that exists, a second
    recording (409)."""

    status = 409


class Damaged(StoreError):
    """A stored folder whose files cannot be used (missing, corrupt) for this request (422)."""

    status = 422


def gone(noun: str, ident: str) -> NotFound:
    """The one 404 message for a stored folder that is gone, wherever its store finds it gone."""
    return NotFound(f"no {noun} {ident}: it was deleted or never existed; list the {noun}s")
