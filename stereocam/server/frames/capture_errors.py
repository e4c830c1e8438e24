"""The errors a capture store raises on purpose, each with the HTTP status to answer with."""
from __future__ import annotations

from .errors import ApiError

__all__ = [
    "CaptureError",
    "InvalidCaptureId",
    "CaptureNotFound",
    "CaptureDiskFull",
    "CaptureConflict",
    "CaptureDamaged",
]


class CaptureError(ApiError):
    """Base of every error the store raises on purpose: ``status`` is the HTTP status to answer with."""


class InvalidCaptureId(CaptureError):
    """The id is not of the form ``20261122T040512Z-000123-ab12`` (400)."""

    status = 400


class CaptureNotFound(CaptureError):
    """No capture with that (valid) id (404)."""

    status = 404


class CaptureDiskFull(CaptureError):
    """Not enough space to store the capture; nothing was written (507)."""

    status = 507


class CaptureConflict(CaptureError):
    """The request clashes with what is stored (a restore of a capture that exists) (409)."""

    status = 409


class CaptureDamaged(CaptureError):
    """A stored capture whose files cannot be used (missing, corrupt) for this request (422)."""

    status = 422


def not_found(cid: str) -> CaptureNotFound:
    """The one 404 message for a capture that is gone, wherever the store finds it gone."""
    return CaptureNotFound(f"no capture {cid}: it was deleted or never existed; list the captures")
