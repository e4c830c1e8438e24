"""The hidden ``.trash/`` folder of a store, where deleted folders (captures) wait for an undo.

A trashed folder is ``<id>.<nanoseconds>`` (when it was deleted),
moved there by one rename; what stays longer than :data:`TRASH_KEEP_S` is
removed.
"""
from __future__ import annotations

import os
import re
import stat
from datetime import datetime
from pathlib import Path
from typing import Callable, List, Optional, Tuple

from .errors import StoreError
from .files import remove_tree
from .ids import ID_PATTERN

__all__ = ["TRASH_DIR", "TRASH_KEEP_S"]

TRASH_DIR = ".trash"
TRASH_KEEP_S = 600.0  # a trashed folder can be restored for 10 minutes
_TRASH_RE = re.compile(r"(" + ID_PATTERN + r")\.([0-9]{1,20})")


def trash_dir(root: Path, create: bool, noun: str = "capture") -> Optional[Path]:
    """``root/.trash`` (a real folder, never a symbolic link), made if ``create``; else None if absent."""
    folder = root / TRASH_DIR
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        if not create:
            return None
        try:
            os.mkdir(folder, 0o755)
        except FileExistsError:
            pass
        st = os.lstat(folder)
    if not stat.S_ISDIR(st.st_mode):
        raise StoreError(f"{folder} is not a folder: remove it so that deleted {noun}s can be kept "
                           f"for an undo")
    return folder


def trashed(folder: Path) -> List[Tuple[str, int, Path]]:
    """``(id, deleted at (ns since the epoch), path)`` of every folder in the trash folder."""
    out = []
    with os.scandir(folder) as entries:
        for e in entries:
            m = _TRASH_RE.fullmatch(e.name)
            if m and e.is_dir(follow_symlinks=False):
                out.append((m.group(1), int(m.group(2)), Path(e.path)))
    return out


def purge_trash(root: Path, clock: Callable[[], datetime], keep_s: float) -> int:
    """Remove what has been in ``root``'s trash for ``keep_s`` seconds or more; how many. Never raises."""
    try:
        trash = trash_dir(root, create=False)
        if trash is None:
            return 0
        now_ns = clock().timestamp() * 1e9
        keep_ns = keep_s * 1e9  # a clock set back (a board without RTC) ages entries too
        old = [path for _, deleted, path in trashed(trash) if abs(now_ns - deleted) >= keep_ns]
    except (OSError, StoreError):
        return 0
    for path in old:
        remove_tree(path)
    return len(old)
