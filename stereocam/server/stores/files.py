"""The files of the capture and recording stores on disk, and the meta.json they write.

Files are created exclusively and fsynced, read without following a symbolic
link, and removed without raising, so that a store's folder is complete or
absent after a crash. ``_os_write`` and ``_os_fsync`` are module-level so that
tests can make the disk fail exactly here.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import stat
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np

CHUNK = 1 << 20
MAX_IMAGE_FILE_BYTES = 64 << 20  # a stored frame's PNG is far smaller; larger is not one of ours
FULL_ERRNOS = frozenset(e for e in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if e is not None)

# Low-level I/O, module-level so tests can make the disk fail exactly here.
_os_write = os.write
_os_fsync = os.fsync


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


def iso_utc(t: datetime) -> str:
    t = t.astimezone(timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def mb(n: int) -> str:
    """``n`` bytes as the messages show sizes: "12.3 MB"."""
    return f"{n / 1e6:.1f} MB"


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def meta_dumps(doc: Mapping[str, Any]) -> bytes:
    return (json.dumps(doc, indent=2, allow_nan=False, default=_json_default) + "\n").encode("utf-8")


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        _os_fsync(fd)
    finally:
        os.close(fd)


def write_new_file(path: Path, data: bytes) -> None:
    """Create ``path`` (must not exist), write ``data`` in chunks, fsync it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        view = memoryview(data)
        while view:
            written = _os_write(fd, view[:CHUNK])
            view = view[written:]
        _os_fsync(fd)
    finally:
        os.close(fd)


def open_member(folder: Path, name: str) -> int:
    """A read-only fd of the regular file ``folder/name``; never follows a symbolic link."""
    fd = os.open(folder / name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise IsADirectoryError(errno.EISDIR, "not a regular file", str(folder / name))
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_member(folder: Path, name: str, limit: Optional[int] = None) -> bytes:
    fd = open_member(folder, name)
    with os.fdopen(fd, "rb") as fh:
        data = fh.read() if limit is None else fh.read(limit + 1)
    if limit is not None and len(data) > limit:
        raise ValueError(f"{name} is larger than {mb(limit)}")
    return data


def remove_tree(path: Path) -> None:
    """Remove a folder (or a symbolic link in its place) as far as possible; never raises."""
    try:
        if path.is_symlink() or not path.is_dir():
            path.unlink()
        else:
            shutil.rmtree(path, ignore_errors=True)
    except OSError:
        pass
