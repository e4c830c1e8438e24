"""The one base of errors the daemon's building blocks raise for a user to read."""
from __future__ import annotations

from typing import Dict, Optional


class ApiError(Exception):
    """``status`` is the HTTP status to answer with, ``message`` one line for the user."""

    status = 500

    def __init__(self, message: str, *, status: Optional[int] = None) -> None:
        super().__init__(message)
        self.message = message
        if status is not None:
            self.status = int(status)

    def to_json(self) -> Dict[str, str]:
        return {"error": self.message}
