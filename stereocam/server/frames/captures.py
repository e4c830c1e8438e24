"""Captures: synchronised stereo sets stored on disk, one folder each.

A capture is a folder ``<root>/<id>/`` holding

    raw_left.png   raw_right.png    the cameras' frames as the demosaic delivered them
    rect_left.png  rect_right.png   the rectify core's output for the same frame
    meta.json                       what the caller passed, plus id, created, images, files

and, only where needed, ``<frame>_y.png`` (see "Pixels" below). The names of
the raw pair are the ones the emulated cameras' replay and the calibration
read (:mod:`stereocam.calibration.image_files` names them), so a capture folder (or
the whole store) replays as a live source.

Pixels: every frame is stored losslessly as PNG and comes back bit for bit;
:mod:`.capture_images` says how.

Atomicity. :meth:`CaptureStore.save` writes into ``.incoming-<id>/`` on the
same filesystem, fsyncs every file and the folder, then renames it to
``<id>``: a capture is listed complete or not at all. Any failure removes
the temporary folder; so does the next :class:`CaptureStore` on start-up
after a crash. :meth:`CaptureStore.delete` renames ``<id>`` to a hidden
``.deleting-*`` folder first, then removes it. :meth:`CaptureStore.trash` (what
``DELETE /api/captures/{id}`` does, so that the page can undo it) renames it
into the hidden ``.trash/`` folder instead, as ``<id>.<nanoseconds>``, from
where :meth:`CaptureStore.restore` renames it back; what stays there longer
than :data:`TRASH_KEEP_S` is removed (at the next trash, and at start-up),
and so is the whole trash when a save is short of space. Names starting with ``.``
and anything that is not a capture id are never listed. One daemon per
capture folder: a new store clears the hidden folders of a previous one.

Ids. ``20261122T040512Z-000123-ab12``: UTC second, frame number (6 to 10
digits), 4 random hex digits (:mod:`.capture_ids`); symbolic links in the
store are never followed.

Thread safety: a :class:`CaptureStore` holds no mutable state; every method
is synchronous, blocking (disk I/O, PNG encoding) and safe to call from
several threads at once. Run them in a worker thread, not on an event loop.

Errors: every :class:`CaptureError` carries the HTTP ``status`` to answer
with and a one-line ``message`` for the user. Wrong arguments from the
calling code (frames of the wrong shape, meta that is not JSON) raise
``ValueError``/``TypeError``: those are bugs, answer 500.
"""
from __future__ import annotations

import hashlib
import json
import numbers
import os
import secrets
import shutil
import stat
import weakref
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any, Callable, Dict, Iterator, List, Mapping, Optional, Tuple, Union

import numpy as np

from ...calibration.image_files import CAPTURE_FILES, capture_file
from .capture_errors import (
    CaptureConflict,
    CaptureDamaged,
    CaptureDiskFull,
    CaptureError,
    CaptureNotFound,
    InvalidCaptureId,
    not_found,
)
from .capture_ids import _ID_RE, _MAX_ID_LENGTH, ID_EXAMPLE, ID_PATTERN, MAX_FRAME_NUMBER
from .capture_images import FRAME_NAMES, encode_frames, read_raw_pair
from .capture_info import META_FILE, CaptureFile, CaptureInfo, read_info
from .capture_thumbnails import THUMB_FRAMES, THUMB_WIDTH, thumbnail_jpeg
from .capture_trash import TRASH_DIR, TRASH_KEEP_S, purge_trash, trash_dir, trashed
from .store_files import (
    CHUNK,
    FULL_ERRNOS,
    fsync_dir,
    iso_utc,
    mb,
    meta_dumps,
    open_member,
    read_member,
    remove_tree,
    utcnow,
    write_new_file,
)
from .zip_stream import close_all, zip_chunks

__all__ = [
    "CaptureStore",
    "CaptureInfo",
    "CaptureFile",
    "CaptureError",
    "CaptureNotFound",
    "InvalidCaptureId",
    "CaptureDiskFull",
    "CaptureDamaged",
    "CaptureConflict",
    "CAPTURE_FILES",
    "FRAME_NAMES",
    "THUMB_FRAMES",
    "capture_file",
    "META_FILE",
    "ID_PATTERN",
    "DEFAULT_MIN_FREE_BYTES",
    "TRASH_DIR",
    "TRASH_KEEP_S",
    "THUMB_WIDTH",
]

FORMAT = "stereocam-capture/1"
DEFAULT_MIN_FREE_BYTES = 64 * 1024 * 1024
RESERVED_META_KEYS = ("format", "id", "created", "images", "files")
INCOMING_PREFIX = ".incoming-"
DELETING_PREFIX = ".deleting-"


def _random_suffix() -> str:
    return secrets.token_hex(2)


def _shown(value: object) -> str:
    """An untrusted value, quoted and cut short, for an error message."""
    text = value if isinstance(value, str) else repr(value)
    if len(text) > 40:
        text = text[:40] + "..."
    return json.dumps(text)


class CaptureStore:
    """The capture folder ``root``: save, list, download as zip, delete, replay.

    ``min_free_bytes``: :meth:`save` refuses (507) unless the filesystem keeps
    at least this much free after the capture is written. ``clock`` returns
    the current time as an aware ``datetime`` (tests pass a fixed one).

    The constructor creates ``root`` if needed and removes what a crashed
    save or delete left behind (hidden ``.incoming-*`` / ``.deleting-*``).
    """

    def __init__(
        self,
        root: Union[str, Path],
        *,
        min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
        clock: Optional[Callable[[], datetime]] = None,
    ) -> None:
        if min_free_bytes < 0:
            raise ValueError(f"min_free_bytes must be >= 0, got {min_free_bytes}")
        self.min_free_bytes = int(min_free_bytes)
        self._clock = clock or utcnow
        try:
            Path(root).mkdir(parents=True, exist_ok=True)
            self.root = Path(root).resolve(strict=True)
        except OSError as exc:
            raise CaptureError(
                f"cannot use {root} as the capture folder: {exc.strerror or exc}; "
                f"give a writable folder"
            ) from exc
        if not self.root.is_dir():
            raise CaptureError(f"the capture folder {root} is not a folder: give a writable folder")
        with os.scandir(self.root) as entries:
            stale = [Path(e.path) for e in entries if e.name.startswith((INCOMING_PREFIX, DELETING_PREFIX))]
        for path in stale:
            remove_tree(path)
        self.purge_trash()

    # -- ids ---------------------------------------------------------------

    @staticmethod
    def valid_id(capture_id: object) -> bool:
        """True if ``capture_id`` is a well-formed capture id (says nothing about whether it exists)."""
        return (
            isinstance(capture_id, str)
            and len(capture_id) <= _MAX_ID_LENGTH
            and _ID_RE.fullmatch(capture_id) is not None
        )

    @classmethod
    def check_id(cls, capture_id: object) -> str:
        """``capture_id`` if well-formed, else :class:`InvalidCaptureId` (400)."""
        if not cls.valid_id(capture_id):
            raise InvalidCaptureId(
                f"invalid capture id {_shown(capture_id)}: capture ids look like {ID_EXAMPLE}"
            )
        assert isinstance(capture_id, str)
        return capture_id

    def path(self, capture_id: object) -> Path:
        """The folder of an existing capture: 400 for a malformed id, 404 if absent.

        Only a real folder directly in ``root`` counts: a symbolic link
        named like a capture is treated as absent.
        """
        cid = self.check_id(capture_id)
        folder = self.root / cid
        try:
            st = os.lstat(folder)
        except FileNotFoundError:
            st = None
        if st is None or not stat.S_ISDIR(st.st_mode):
            raise not_found(cid)
        return folder

    # -- save --------------------------------------------------------------

    def save(self, frames: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> CaptureInfo:
        """Store one stereo set atomically and return what :meth:`list` will show for it.

        ``frames`` has exactly the keys :data:`FRAME_NAMES`; each is an
        ``(H, W, 4)`` RGBY, ``(H, W, 3)`` RGB or ``(H, W)`` gray uint8 array
        (read only; the caller keeps ownership). The left and right frames of
        each pair must have the same size. ``meta`` must be JSON-serialisable
        (numpy scalars and arrays are converted) and hold ``"frame"``, the
        frame number (int, 0 .. 9_999_999_999); ``"source"`` and
        ``"calibration_id"`` (str or None) are shown in listings; the keys
        :data:`RESERVED_META_KEYS` are the store's. Suggested further keys:
        ``"time"``, ``"registers"``, ``"camera"``.

        Raises :class:`CaptureDiskFull` (507) if the space is short, before
        writing or on ENOSPC/EDQUOT while writing, and :class:`CaptureError`
        (500) on any other I/O error; in both cases no file of this capture
        remains and :meth:`list` is unchanged.
        """
        user_meta, frame_no = self._check_meta(meta)
        images, files = encode_frames(frames)
        now = self._clock()
        if now.tzinfo is None:
            raise ValueError("the store's clock must return an aware datetime (e.g. in timezone.utc)")
        doc: Dict[str, Any] = {"format": FORMAT, "id": "", "created": iso_utc(now)}
        doc.update(user_meta)
        doc["images"] = images
        doc["files"] = [
            {"name": n, "bytes": len(d), "sha256": hashlib.sha256(d).hexdigest()} for n, d in files
        ]
        try:
            meta_size = len(meta_dumps(doc)) + _MAX_ID_LENGTH
        except (TypeError, ValueError) as exc:
            raise ValueError(f"meta is not JSON-serialisable: {exc}") from exc
        self._check_space(sum(len(d) for _, d in files) + meta_size + 64 * 1024)  # + folder and inode slack
        cid, meta_bytes = self._write(now, frame_no, doc, files)

        stored = [CaptureFile(f["name"], f["bytes"], f["sha256"]) for f in doc["files"]]
        stored.append(CaptureFile(META_FILE, len(meta_bytes)))
        return CaptureInfo(
            id=cid,
            created=doc["created"],
            frame=frame_no,
            source=doc.get("source"),
            calibration_id=doc.get("calibration_id"),
            files=tuple(sorted(stored, key=lambda f: f.name)),
            bytes=sum(f.bytes for f in stored),
            meta=json.loads(meta_bytes),  # as get() will read it: plain JSON types
        )

    def _check_space(self, need: int) -> None:
        """Raise :class:`CaptureDiskFull` unless ``need`` bytes fit and :attr:`min_free_bytes` stay free.

        Captures waiting in the trash for an undo give their space first.
        """
        try:
            free = self._free_bytes()
        except OSError as exc:
            raise CaptureError(
                f"cannot check the free space in {self.root} ({exc.strerror or exc}); nothing was stored"
            ) from exc
        if free - need < self.min_free_bytes and self.purge_trash(0.0):
            try:
                free = self._free_bytes()
            except OSError:
                pass
        if free - need < self.min_free_bytes:
            raise CaptureDiskFull(
                f"not enough free space for a capture in {self.root}: {mb(free)} free, the capture needs "
                f"{mb(need)} and {mb(self.min_free_bytes)} are kept free; delete old captures to make room"
            )

    def _write(self, now: datetime, frame_no: int, doc: Dict[str, Any],
               files: List[Tuple[str, bytes]]) -> Tuple[str, bytes]:
        """Write ``files`` and meta.json into a fresh ``.incoming-<id>``, then publish it as ``<id>``.

        Sets ``doc["id"]``; returns the id and the meta.json written. On any
        failure the temporary folder is removed: :class:`CaptureDiskFull` on
        ENOSPC/EDQUOT, :class:`CaptureError` on any other ``OSError``.
        """
        tmp: Optional[Path] = None
        step = "creating the capture folder"
        try:
            cid, tmp = self._reserve(now, frame_no)
            doc["id"] = cid
            for name, data in files:
                step = f"writing {name}"
                write_new_file(tmp / name, data)
            step = f"writing {META_FILE}"
            meta_bytes = meta_dumps(doc)
            write_new_file(tmp / META_FILE, meta_bytes)
            step = "syncing the capture folder"
            fsync_dir(tmp)
            step = "publishing the capture"
            os.rename(tmp, self.root / cid)
            tmp = None
        except OSError as exc:
            if tmp is not None:
                remove_tree(tmp)
            if exc.errno in FULL_ERRNOS:
                raise CaptureDiskFull(
                    f"the capture disk is full ({exc.strerror or 'no space left'}) while {step}: "
                    f"nothing was stored; delete old captures to make room"
                ) from exc
            raise CaptureError(
                f"cannot store the capture: {step} in {self.root} failed ({exc.strerror or exc}); "
                f"nothing was stored"
            ) from exc
        except BaseException:
            if tmp is not None:
                remove_tree(tmp)
            raise
        try:
            fsync_dir(self.root)  # durability of the rename; the capture is complete and listed either way
        except OSError:
            pass
        return cid, meta_bytes

    def _check_meta(self, meta: Mapping[str, Any]) -> Tuple[Dict[str, Any], int]:
        if not isinstance(meta, Mapping):
            raise TypeError(f"meta must be a mapping, got {type(meta).__name__}")
        user = dict(meta)
        bad_keys = [k for k in user if not isinstance(k, str)]
        if bad_keys:
            raise TypeError(f"meta keys must be strings, got {bad_keys!r}")
        reserved = [k for k in RESERVED_META_KEYS if k in user]
        if reserved:
            raise ValueError(f"meta keys {', '.join(reserved)} are set by the store: leave them out")
        frame = user.get("frame")
        if (isinstance(frame, (bool, np.bool_)) or not isinstance(frame, numbers.Integral)
                or not 0 <= int(frame) <= MAX_FRAME_NUMBER):
            raise ValueError(f"meta['frame'] must be the frame number, an int in 0..{MAX_FRAME_NUMBER}; "
                             f"got {frame!r}")
        user["frame"] = int(frame)
        for key in ("source", "calibration_id"):
            if user.get(key) is not None and not isinstance(user[key], str):
                raise TypeError(f"meta[{key!r}] must be a str or None, got {type(user[key]).__name__}")
        return user, int(frame)

    def _free_bytes(self) -> int:
        return shutil.disk_usage(self.root).free

    def _reserve(self, now: datetime, frame_no: int) -> Tuple[str, Path]:
        """A fresh id and its empty ``.incoming-<id>`` folder.

        Every writer creates ``.incoming-<id>`` exclusively and checks that
        ``<id>`` does not exist after that, and ``<id>`` only appears by the
        atomic rename of an ``.incoming-<id>``: two savers (threads or
        processes) can never publish the same id.
        """
        stamp = now.astimezone(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        for _ in range(64):
            cid = f"{stamp}-{frame_no:06d}-{_random_suffix()}"
            final = self.root / cid
            tmp = self.root / f"{INCOMING_PREFIX}{cid}"
            if os.path.lexists(final):
                continue
            try:
                os.mkdir(tmp, 0o755)
            except FileExistsError:
                continue
            if os.path.lexists(final):
                os.rmdir(tmp)
                continue
            return cid, tmp
        raise CaptureError(f"cannot find a free capture id for frame {frame_no} in {self.root}: try again")

    # -- read --------------------------------------------------------------

    def list(self) -> List[CaptureInfo]:
        """Every capture, newest first. Damaged ones are included, with ``error`` set."""
        with os.scandir(self.root) as entries:
            found = [e.name for e in entries if self.valid_id(e.name) and e.is_dir(follow_symlinks=False)]
        infos = []
        for cid in found:
            try:
                infos.append(self._info(cid, self.root / cid))
            except CaptureNotFound:  # deleted while we listed
                continue
        infos.sort(key=lambda i: (i.created, i.id), reverse=True)
        return infos

    def get(self, capture_id: object) -> CaptureInfo:
        """One capture (400 malformed id, 404 absent); ``meta`` holds its meta.json."""
        folder = self.path(capture_id)
        return self._info(folder.name, folder)

    def _info(self, cid: str, folder: Path) -> CaptureInfo:
        return read_info(cid, folder)

    def raw_pair(self, capture_id: object) -> Tuple[np.ndarray, np.ndarray]:
        """The raw left and right frames as ``(H, W, 4)`` RGBY uint8 arrays, bit for bit as captured.

        Fresh arrays the caller owns; ``pixel.pack(*store.raw_pair(id))`` is
        the stream frame for the virtual camera. 400/404 as :meth:`path`;
        :class:`CaptureDamaged` (422) if a raw image is missing or corrupt.
        """
        folder = self.path(capture_id)
        return read_raw_pair(folder.name, folder)

    # -- download ----------------------------------------------------------

    def read_file(self, capture_id: object, name: object) -> bytes:
        """The bytes of one file of a capture (``raw_left.png``, ``meta.json``, ...).

        ``name`` must be the name of a regular file directly in the capture
        folder, as :attr:`CaptureInfo.files` lists them: it is looked up in
        that listing, never joined to a path as given, so ``../x`` or a
        symbolic link cannot be read. 400 malformed id; 404 absent capture
        or no such file (the message lists the files there are).
        """
        folder = self.path(capture_id)
        cid = folder.name
        names = [f.name for f in self._info(cid, folder).files]
        if not isinstance(name, str) or name not in names:
            raise CaptureNotFound(
                f"capture {cid} has no file {_shown(name)}; it has {', '.join(names) or 'no files'}"
            )
        try:
            return read_member(folder, name)
        except FileNotFoundError:
            raise CaptureNotFound(f"capture {cid} was deleted while it was being read") from None
        except OSError as exc:
            raise CaptureError(f"cannot read {name} of capture {cid}: {exc.strerror or exc}") from exc

    def zip_stream(self, capture_id: object, *, chunk_size: int = CHUNK) -> Iterator[bytes]:
        """The capture as a zip archive, as an iterator of byte chunks (each at most ~``chunk_size``).

        The archive holds the folder ``<id>/`` with meta.json and every
        image (PNGs stored, not recompressed). 400/404 are raised here, at
        the call, before any byte is produced; the files are opened now too,
        so a delete while the archive streams does not cut it short. Iterate
        it to the end or ``close()`` it (garbage collection closes it too).
        """
        folder = self.path(capture_id)
        cid = folder.name
        info = self._info(cid, folder)
        order = {META_FILE: 0, **{capture_file(n): i + 1 for i, n in enumerate(FRAME_NAMES)}}
        names = sorted((f.name for f in info.files), key=lambda n: (order.get(n, len(order)), n))
        handles: List[Tuple[str, IO[bytes], int]] = []
        try:
            for name in names:
                member: IO[bytes] = os.fdopen(open_member(folder, name), "rb")
                handles.append((name, member, os.fstat(member.fileno()).st_size))
        except OSError as exc:
            close_all([fh for _, fh, _ in handles])
            if isinstance(exc, FileNotFoundError):
                raise CaptureNotFound(f"capture {cid} was deleted while it was being read") from None
            raise CaptureError(f"cannot read capture {cid}: {exc.strerror or exc}") from exc
        try:
            stamp = datetime.strptime(info.created[:19], "%Y-%m-%dT%H:%M:%S")
        except ValueError:
            stamp = datetime.strptime(cid[:16], "%Y%m%dT%H%M%SZ")
        date_time = (max(stamp.year, 1980), stamp.month, stamp.day, stamp.hour, stamp.minute, stamp.second)
        gen = zip_chunks(cid, date_time, handles, max(1, int(chunk_size)))
        weakref.finalize(gen, close_all, [fh for _, fh, _ in handles])
        return gen

    def write_zip(self, capture_id: object, out: IO[bytes]) -> int:
        """Write :meth:`zip_stream` to the binary file-like ``out``; returns the number of bytes."""
        total = 0
        for chunk in self.zip_stream(capture_id):
            out.write(chunk)
            total += len(chunk)
        return total

    # -- delete ------------------------------------------------------------

    def delete(self, capture_id: object) -> None:
        """Remove a capture: 400 malformed id, 404 absent.

        The folder is first renamed to a hidden ``.deleting-*`` name (from
        then on it is not listed), then removed; what a crash leaves behind
        is removed by the next store on start-up.
        """
        folder = self.path(capture_id)
        cid = folder.name
        trash = self.root / f"{DELETING_PREFIX}{cid}-{secrets.token_hex(4)}"
        try:
            os.rename(folder, trash)
        except FileNotFoundError:
            raise not_found(cid) from None
        except OSError as exc:
            raise CaptureError(f"cannot delete capture {cid}: {exc.strerror or exc}") from exc
        try:
            fsync_dir(self.root)
        except OSError:
            pass
        remove_tree(trash)

    # -- trash (delete with undo) ---------------------------------------------

    def trash(self, capture_id: object) -> None:
        """Delete a capture so that :meth:`restore` can bring it back (for :data:`TRASH_KEEP_S`).

        400 malformed id, 404 absent. From the rename on, the capture is no longer listed and
        every other call says 404; nothing is copied (one rename on the same filesystem), so a
        page closed before its undo loses nothing: the delete stands and the files stay
        restorable until the trash is purged.
        """
        folder = self.path(capture_id)
        cid = folder.name
        try:
            trash = trash_dir(self.root, create=True)
            assert trash is not None
            stamp = int(self._clock().timestamp() * 1e9)
            while os.path.lexists(trash / f"{cid}.{stamp}"):  # deleted, restored, deleted in one clock tick
                stamp += 1
            os.rename(folder, trash / f"{cid}.{stamp}")
        except FileNotFoundError:
            raise not_found(cid) from None
        except OSError as exc:
            raise CaptureError(f"cannot delete capture {cid}: {exc.strerror or exc}") from exc
        for path in (self.root, trash):
            try:
                fsync_dir(path)
            except OSError:
                pass
        self.purge_trash()

    def restore(self, capture_id: object) -> CaptureInfo:
        """Bring back a capture :meth:`trash` deleted (the latest delete of that id) and return it.

        400 malformed id; 404 when it is not in the trash (never deleted, purged, or restored
        already); 409 when a capture of that id exists.
        """
        cid = self.check_id(capture_id)
        trash = trash_dir(self.root, create=False)
        found = sorted(t for t in (trashed(trash) if trash is not None else []) if t[0] == cid)
        if not found:
            raise CaptureNotFound(f"capture {cid} is not in the trash: it was never deleted, was restored "
                                  f"already, or was deleted more than {TRASH_KEEP_S / 60:g} minutes ago")
        final = self.root / cid
        if os.path.lexists(final):
            raise CaptureConflict(f"capture {cid} exists already: it was restored before")
        try:
            os.rename(found[-1][2], final)
        except FileNotFoundError:
            raise CaptureNotFound(f"capture {cid} was purged from the trash meanwhile") from None
        except OSError as exc:
            raise CaptureError(f"cannot restore capture {cid}: {exc.strerror or exc}") from exc
        try:
            fsync_dir(self.root)
        except OSError:
            pass
        return self.get(cid)

    def purge_trash(self, keep_s: float = TRASH_KEEP_S) -> int:
        """Remove what has been in the trash for ``keep_s`` seconds or more (0: everything).

        Returns how many captures were removed. Never raises.
        """
        return purge_trash(self.root, self._clock, keep_s)

    # -- thumbnails ----------------------------------------------------------

    def thumbnail(self, capture_id: object, width: int = THUMB_WIDTH) -> bytes:
        """A small JPEG of the capture: its rectified left frame (its raw left one when that cannot
        be read), ``width`` pixels wide (never wider than the frame), aspect kept.

        400/404 as :meth:`path`; :class:`CaptureDamaged` (422) when neither image can be read.
        Files are read by fixed names, never following a symbolic link.
        """
        folder = self.path(capture_id)
        return thumbnail_jpeg(folder.name, folder, width)
