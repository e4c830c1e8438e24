"""The folder store that captures, recordings and calibration pairs share: one folder per id.

A store owns the folder ``root``; each entry is a folder ``<root>/<id>/`` with
a store id (:mod:`.store_ids`). What is in an entry, and what its listing
says, is the subclass's (:meth:`FolderStore._info`, :meth:`FolderStore._zip_names`);
the base does the rest the same way for every store:

- ids: checked (:meth:`FolderStore.check_id`) before any path is built;
  only a real folder directly in ``root`` counts (a symbolic link named
  like an entry is absent);
- writing: :meth:`FolderStore.reserve` makes a fresh id and its hidden
  ``.incoming-<id>/`` folder exclusively; :meth:`FolderStore.publish` renames
  it to ``<id>`` once its files are written and synced, so an entry is listed
  complete or not at all;
- reading: :meth:`FolderStore.list` (newest first, damaged entries
  included), :meth:`FolderStore.get`, :meth:`FolderStore.zip_stream`;
- removing: :meth:`FolderStore.delete` (a hidden ``.deleting-*`` rename,
  then the removal), :meth:`FolderStore.trash` and :meth:`FolderStore.restore`
  (delete with undo, :mod:`.store_trash`);
- space: :meth:`FolderStore.free_bytes` and :meth:`FolderStore.room`, with
  ``min_free_bytes`` kept free.

Errors are :class:`.store_errors.StoreError` and its kinds, their messages
naming the store's :attr:`FolderStore.noun` ("capture", "recording").
Methods block (disk I/O) and are safe to call from several threads at once:
run them in a worker thread, not on an event loop.
"""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import stat
import weakref
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Callable, Generic, Iterator, List, Optional, Protocol, Tuple, TypeVar, Union

from .errors import Conflict, InvalidId, NotFound, StoreError, gone
from .files import CHUNK, fsync_dir, open_member, remove_tree, utcnow
from .ids import ID_EXAMPLE, valid_id
from .trash import TRASH_KEEP_S, purge_trash, trash_dir, trashed
from .zip_stream import close_all, zip_chunks

__all__ = ["FolderStore", "Listed", "INCOMING_PREFIX", "DELETING_PREFIX", "shown"]

INCOMING_PREFIX = ".incoming-"
DELETING_PREFIX = ".deleting-"


class Listed(Protocol):
    """What a store's listing entry has at least: its id and when it was created (ISO 8601, UTC)."""

    @property
    def id(self) -> str: ...

    @property
    def created(self) -> str: ...


InfoT = TypeVar("InfoT", bound=Listed)


def _random_suffix() -> str:
    return secrets.token_hex(2)


def shown(value: object) -> str:
    """An untrusted value, quoted and cut short, for an error message."""
    text = value if isinstance(value, str) else repr(value)
    if len(text) > 40:
        text = text[:40] + "..."
    return json.dumps(text)


class FolderStore(Generic[InfoT]):
    """The folder ``root`` of one kind of entry (see the module's docstring).

    ``noun`` names an entry in messages ("capture"); ``folder_name`` names ``root``
    ("the capture folder"). ``clock`` returns the current time as an aware
    ``datetime`` (tests pass a fixed one). The constructor creates ``root`` if needed.
    """

    noun = "entry"
    folder_name = "the folder"

    def __init__(self, root: Union[str, Path], *, min_free_bytes: int,
                 clock: Optional[Callable[[], datetime]] = None) -> None:
        if min_free_bytes < 0:
            raise ValueError(f"min_free_bytes must be >= 0, got {min_free_bytes}")
        self.min_free_bytes = int(min_free_bytes)
        self._clock = clock or utcnow
        try:
            Path(root).mkdir(parents=True, exist_ok=True)
            self.root = Path(root).resolve(strict=True)
        except OSError as exc:
            raise StoreError(f"cannot use {root} as {self.folder_name}: {exc.strerror or exc}; "
                             f"give a writable folder") from exc
        if not self.root.is_dir():
            raise StoreError(f"{self.folder_name} {root} is not a folder: give a writable folder")

    # -- ids ---------------------------------------------------------------------------------------------

    @staticmethod
    def valid_id(ident: object) -> bool:
        """True if ``ident`` is a well-formed id (says nothing about whether it exists)."""
        return valid_id(ident)

    @classmethod
    def check_id(cls, ident: object) -> str:
        """``ident`` if well-formed, else :class:`.store_errors.InvalidId`."""
        if not valid_id(ident):
            raise InvalidId(f"invalid {cls.noun} id {cls._shown_id(ident)}: {cls.noun} ids look like "
                            f"{ID_EXAMPLE}")
        assert isinstance(ident, str)
        return ident

    @staticmethod
    def _shown_id(ident: object) -> str:
        return shown(ident)

    def not_found(self, ident: str) -> NotFound:
        return gone(self.noun, ident)

    def path(self, ident: object) -> Path:
        """The folder of an existing entry: InvalidId if malformed, NotFound if absent (or a link)."""
        checked = self.check_id(ident)
        folder = self.root / checked
        try:
            st = os.lstat(folder)
        except FileNotFoundError:
            st = None
        if st is None or not stat.S_ISDIR(st.st_mode):
            raise self.not_found(checked)
        return folder

    # -- space -------------------------------------------------------------------------------------------

    def free_bytes(self) -> int:
        """Free bytes on the store's filesystem (a test makes the disk fill here)."""
        return shutil.disk_usage(self.root).free

    def room(self) -> int:
        """Bytes the store may still write: free space less ``min_free_bytes``."""
        return self.free_bytes() - self.min_free_bytes

    # -- writing: reserve, then publish --------------------------------------------------------------------

    def reserve(self, frame_no: int, now: Optional[datetime] = None) -> Tuple[str, Path]:
        """A fresh id (of ``now``, default the clock's, and ``frame_no``) and its empty ``.incoming-<id>``.

        Every writer creates ``.incoming-<id>`` exclusively and checks that
        ``<id>`` does not exist after that, and ``<id>`` only appears by the
        atomic rename of an ``.incoming-<id>`` (:meth:`publish`): two writers
        (threads or processes) can never publish the same id. OSError when the
        folder cannot be made.
        """
        stamp = (now or self._clock()).astimezone(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        for _ in range(64):
            ident = f"{stamp}-{int(frame_no) % 10**10:06d}-{_random_suffix()}"
            final = self.root / ident
            tmp = self.root / f"{INCOMING_PREFIX}{ident}"
            if os.path.lexists(final):
                continue
            try:
                os.mkdir(tmp, 0o755)
            except FileExistsError:
                continue
            if os.path.lexists(final):
                os.rmdir(tmp)
                continue
            return ident, tmp
        raise StoreError(f"cannot find a free {self.noun} id for frame {frame_no} in {self.root}: try again")

    def publish(self, tmp: Path, ident: str) -> None:
        """Rename the written and synced ``tmp`` (from :meth:`reserve`) to ``<id>``: it is listed from now.

        OSError when the rename fails; the rename's own sync is best effort.
        """
        os.rename(tmp, self.root / ident)
        with contextlib.suppress(OSError):
            fsync_dir(self.root)

    def clear_hidden(self) -> None:
        """Remove what a crashed write or delete left (``.incoming-*``, ``.deleting-*``)."""
        with os.scandir(self.root) as entries:
            stale = [Path(e.path) for e in entries if e.name.startswith((INCOMING_PREFIX, DELETING_PREFIX))]
        for path in stale:
            remove_tree(path)

    # -- reading -----------------------------------------------------------------------------------------

    def _info(self, ident: str, folder: Path) -> InfoT:
        """The listing entry of ``folder``: damage described, never raised; NotFound if gone meanwhile."""
        raise NotImplementedError

    def list(self) -> List[InfoT]:
        """Every entry, newest first. Damaged ones are included, with ``error`` set."""
        with os.scandir(self.root) as entries:
            found = [e.name for e in entries if valid_id(e.name) and e.is_dir(follow_symlinks=False)]
        infos = []
        for ident in found:
            try:
                infos.append(self._info(ident, self.root / ident))
            except NotFound:  # deleted while we listed
                continue
        infos.sort(key=lambda i: (i.created, i.id), reverse=True)
        return infos

    def get(self, ident: object) -> InfoT:
        """One entry (InvalidId malformed id, NotFound absent); its ``meta`` holds its own JSON file."""
        folder = self.path(ident)
        return self._info(folder.name, folder)

    def _zip_names(self, folder: Path, info: InfoT) -> List[str]:
        """The files of an entry that its zip holds, in the archive's order."""
        raise NotImplementedError

    def zip_stream(self, ident: object, *, chunk_size: int = CHUNK) -> Iterator[bytes]:
        """The entry as a zip archive (folder ``<id>/``), as an iterator of byte chunks (~``chunk_size``).

        PNGs are stored, not recompressed. InvalidId/NotFound are raised here, at the call,
        before any byte is produced; the files are opened now too, so a delete while
        the archive streams does not cut it short. Iterate it to the end or
        ``close()`` it (garbage collection closes it too).
        """
        folder = self.path(ident)
        checked = folder.name
        info = self._info(checked, folder)
        handles: List[Tuple[str, IO[bytes], int]] = []
        try:
            for name in self._zip_names(folder, info):
                member: IO[bytes] = os.fdopen(open_member(folder, name), "rb")
                handles.append((name, member, os.fstat(member.fileno()).st_size))
        except OSError as exc:
            close_all([fh for _, fh, _ in handles])
            if isinstance(exc, FileNotFoundError):
                raise NotFound(f"{self.noun} {checked} was deleted while it was being read") from None
            raise StoreError(f"cannot read {self.noun} {checked}: {exc.strerror or exc}") from exc
        try:
            stamp = datetime.strptime(info.created[:19], "%Y-%m-%dT%H:%M:%S")
        except ValueError:
            stamp = datetime.strptime(checked[:16], "%Y%m%dT%H%M%SZ")
        date_time = (max(stamp.year, 1980), stamp.month, stamp.day, stamp.hour, stamp.minute, stamp.second)
        gen = zip_chunks(checked, date_time, handles, max(1, int(chunk_size)))
        weakref.finalize(gen, close_all, [fh for _, fh, _ in handles])
        return gen

    def write_zip(self, ident: object, out: IO[bytes]) -> int:
        """Write :meth:`zip_stream` to the binary file-like ``out``; returns the number of bytes."""
        total = 0
        for chunk in self.zip_stream(ident):
            out.write(chunk)
            total += len(chunk)
        return total

    # -- removing ----------------------------------------------------------------------------------------

    def delete(self, ident: object) -> None:
        """Remove an entry: InvalidId malformed id, NotFound absent.

        The folder is first renamed to a hidden ``.deleting-*`` name (from
        then on it is not listed), then removed; what a crash leaves behind
        is removed by the next store on start-up.
        """
        folder = self.path(ident)
        checked = folder.name
        doomed = self.root / f"{DELETING_PREFIX}{checked}-{secrets.token_hex(4)}"
        try:
            os.rename(folder, doomed)
        except FileNotFoundError:
            raise self.not_found(checked) from None
        except OSError as exc:
            raise StoreError(f"cannot delete {self.noun} {checked}: {exc.strerror or exc}") from exc
        with contextlib.suppress(OSError):
            fsync_dir(self.root)
        remove_tree(doomed)

    def trash(self, ident: object) -> None:
        """Delete an entry so that :meth:`restore` can bring it back (for :data:`.store_trash.TRASH_KEEP_S`).

        InvalidId malformed id, NotFound absent. From the rename on, the entry is no longer listed and
        every other call says NotFound; nothing is copied (one rename on the same filesystem), so a
        page closed before its undo loses nothing: the delete stands and the files stay
        restorable until the trash is purged.
        """
        folder = self.path(ident)
        checked = folder.name
        try:
            trash = trash_dir(self.root, create=True, noun=self.noun)
            assert trash is not None
            stamp = int(self._clock().timestamp() * 1e9)
            while os.path.lexists(trash / f"{checked}.{stamp}"):  # deleted, restored, deleted in one tick
                stamp += 1
            os.rename(folder, trash / f"{checked}.{stamp}")
        except FileNotFoundError:
            raise self.not_found(checked) from None
        except OSError as exc:
            raise StoreError(f"cannot delete {self.noun} {checked}: {exc.strerror or exc}") from exc
        for path in (self.root, trash):
            with contextlib.suppress(OSError):
                fsync_dir(path)
        self.purge_trash()

    def restore(self, ident: object) -> InfoT:
        """Bring back an entry :meth:`trash` deleted (the latest delete of that id) and return it.

        InvalidId malformed id; NotFound when it is not in the trash (never deleted, purged, or restored
        already); Conflict when an entry of that id exists.
        """
        checked = self.check_id(ident)
        trash = trash_dir(self.root, create=False, noun=self.noun)
        found = sorted(t for t in (trashed(trash) if trash is not None else []) if t[0] == checked)
        if not found:
            raise NotFound(f"{self.noun} {checked} is not in the trash: it was never deleted, was restored "
                           f"already, or was deleted more than {TRASH_KEEP_S / 60:g} minutes ago")
        final = self.root / checked
        if os.path.lexists(final):
            raise Conflict(f"{self.noun} {checked} exists already: it was restored before")
        try:
            os.rename(found[-1][2], final)
        except FileNotFoundError:
            raise NotFound(f"{self.noun} {checked} was purged from the trash meanwhile") from None
        except OSError as exc:
            raise StoreError(f"cannot restore {self.noun} {checked}: {exc.strerror or exc}") from exc
        with contextlib.suppress(OSError):
            fsync_dir(self.root)
        return self.get(checked)

    def purge_trash(self, keep_s: float = TRASH_KEEP_S) -> int:
        """Remove what has been in the trash for ``keep_s`` seconds or more (0: everything).

        Returns how many entries were removed. Never raises.
        """
        return purge_trash(self.root, self._clock, keep_s)
