"""Who owns the fabric: an exclusive ``flock`` that says who holds it. No pynq import.

The daemon's overlay (:mod:`.overlay`) takes it before pynq reads or programs
anything; :mod:`.guard`, imported by pynq into every process that makes an
``Overlay``, asks it before any bitstream download, so a notebook cannot reprogram the
fabric under a running daemon.
"""
from __future__ import annotations

import datetime
import errno
import fcntl
import json
import os
import sys
from pathlib import Path
from typing import IO, Any, Dict, Optional

from ..interface import BackendError

__all__ = ["FabricBusy", "FabricLock", "LOCK_ENV", "DEFAULT_LOCK", "held_by_another_process"]

LOCK_ENV = "STEREOCAM_FABRIC_LOCK"
DEFAULT_LOCK = Path("/run/stereocam/fabric.lock")


class FabricBusy(BackendError):
    """Another process (or overlay) owns the fabric; the message names it and says how to stop it."""


class FabricLock:
    """An exclusive, non-blocking ``flock`` that says who holds it.

    ``path``: the lock file (default ``$STEREOCAM_FABRIC_LOCK``, else
    ``/run/stereocam/fabric.lock``). The holder writes its pid, command line,
    start time and bitstream into the file; the kernel drops the lock when
    the holder's file is closed or the process dies, so a crashed daemon
    leaves no stale lock. Two locks on the same path conflict even within
    one process.
    """

    def __init__(self, path: Optional[Path] = None) -> None:
        self.path = Path(path or os.environ.get(LOCK_ENV) or DEFAULT_LOCK)
        self._file: Optional[IO[str]] = None

    @property
    def held(self) -> bool:
        return self._file is not None

    def acquire(self, bitstream: str) -> None:
        """Take the lock or raise :class:`FabricBusy` at once (never waits)."""
        if self._file is not None:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fh = open(self.path, "a+", encoding="utf-8")  # not "w": the holder's record must survive
        except OSError as exc:
            raise BackendError(f"cannot open the fabric lock {self.path}: {exc.strerror}; run as root "
                               f"(pynq needs it) or set {LOCK_ENV} to a writable path") from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            fh.close()
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            raise FabricBusy(self._busy_message()) from None
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps({"pid": os.getpid(), "cmdline": _cmdline(), "bitstream": bitstream,
                             "since": datetime.datetime.now().strftime("%Y-%m-%d %H:%M:%S"),
                             "service": "INVOCATION_ID" in os.environ}) + "\n")
        fh.flush()
        self._file = fh

    def release(self) -> None:
        """Drop the lock; idempotent. The file stays (removing a locked file races with its next user)."""
        fh, self._file = self._file, None
        if fh is not None:
            fh.close()

    def holder(self) -> Dict[str, Any]:
        """The record the holder wrote (empty if unreadable, e.g. while it is being written)."""
        try:
            record = json.loads(self.path.read_text(encoding="utf-8") or "{}")
        except (OSError, ValueError):
            return {}
        return record if isinstance(record, dict) else {}

    def _busy_message(self) -> str:
        who = self.holder()
        pid = who.get("pid", "?")
        cmd = " ".join(str(who.get("cmdline") or "an unknown process").split())
        cmd = cmd if len(cmd) <= 100 else cmd[:97] + "..."
        since = who.get("since", "an unknown time")
        if who.get("service"):
            holder = f"the stereocam service (pid {pid}: `{cmd}`)"
            hint = "stop it with `systemctl stop stereocam`"
        else:
            holder, hint = f"`{cmd}` (pid {pid})", f"close its overlay or end process {pid}"
        return f"the fabric is in use by {holder} since {since}: {hint} first (lock: {self.path})"


def _cmdline() -> str:
    try:
        raw = Path("/proc/self/cmdline").read_bytes()
        return " ".join(part.decode(errors="replace") for part in raw.split(b"\0") if part)
    except OSError:
        return " ".join([sys.executable, *sys.argv])


def held_by_another_process(path: Optional[Path] = None) -> Optional[FabricLock]:
    """The lock if a process other than this one holds it (to read its holder), else None.

    Probes with a second ``flock`` that is released at once; in the holder's own process
    the probe fails too, so the holder's recorded pid decides.
    """
    probe = FabricLock(path)
    try:
        probe.acquire("(probe)")
    except FabricBusy:
        return None if probe.holder().get("pid") == os.getpid() else probe
    except BackendError:  # the lock file cannot even be opened: nobody can hold it
        return None
    probe.release()
    return None
