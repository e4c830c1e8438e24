"""What every test of the daemon (stereocam/server) may use: the ``start_daemon`` fixture.

The fixture and the helpers around it (the emulated overlay on a still frame, the waits, the
multipart reader) live in :mod:`.daemon`; modules import the helpers they use from there.
"""
from __future__ import annotations

from .daemon import start_daemon_fixture

__all__ = ["start_daemon_fixture"]
