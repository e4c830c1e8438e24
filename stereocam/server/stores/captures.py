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
digits), 4 random hex digits (:mod:`.store_ids`); symbolic links in the
store are never followed.

Thread safety: a :class:`CaptureStore` holds no mutable state; every method
is synchronous, blocking (disk I/O, PNG encoding) and safe to call from
several threads at once. Run them in a worker thread, not on an event loop.

Errors: every :class:`CaptureError` carries its ``kind`` (the HTTP side
chooses the status) and a one-line ``message`` for the user. Wrong arguments from the
calling code (frames of the wrong shape, meta that is not JSON) raise
``ValueError``/``TypeError``: those are bugs, answered as failures.
"""
from __future__ import annotations

import hashlib
import json
import numbers
import re
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from ...calibration.image_files import CAPTURE_FILES, capture_file
from .capture_images import FRAME_NAMES, encode_frames, read_raw_pair
from .capture_info import META_FILE, CaptureFile, CaptureInfo, read_info
from .capture_thumbnails import THUMB_FRAMES, THUMB_WIDTH, thumbnail_jpeg
from .errors import Conflict, Damaged, DiskFull, InvalidId, NotFound, StoreError
from .files import (
    FULL_ERRNOS,
    fsync_dir,
    iso_utc,
    mb,
    meta_dumps,
    read_member,
    remove_tree,
    write_new_file,
)
from .folder_store import DELETING_PREFIX, INCOMING_PREFIX, FolderStore, shown
from .ids import ID_PATTERN, MAX_FRAME_NUMBER, MAX_ID_LENGTH
from .trash import TRASH_DIR, TRASH_KEEP_S

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
    "INCOMING_PREFIX",
    "DELETING_PREFIX",
]

# The capture store's errors are the stores' one tree (:mod:`.store_errors`), by the names callers know.
CaptureError = StoreError
InvalidCaptureId = InvalidId
CaptureNotFound = NotFound
CaptureDiskFull = DiskFull
CaptureConflict = Conflict
CaptureDamaged = Damaged

FORMAT = "stereocam-capture/1"
DEFAULT_MIN_FREE_BYTES = 64 * 1024 * 1024
RESERVED_META_KEYS = ("format", "id", "created", "images", "files")
EXTRA_NAME = re.compile(r"[a-z0-9][a-z0-9_]*\.[a-z0-9]+")


def _checked_extra(extra: Sequence[Tuple[str, bytes]], taken: Sequence[str]) -> List[Tuple[str, bytes]]:
    """``extra`` files as (name, bytes), each name a plain file name not ``taken`` nor meta.json."""
    out: List[Tuple[str, bytes]] = []
    for name, data in extra:
        if not (isinstance(name, str) and EXTRA_NAME.fullmatch(name)) or name == META_FILE:
            raise ValueError(f"an extra capture file needs a plain file name, not {name!r}")
        if name in taken or name in (n for n, _ in out):
            raise ValueError(f"the capture already has a file {name}")
        out.append((name, bytes(data)))
    return out


class CaptureStore(FolderStore[CaptureInfo]):
    """The capture folder ``root``: save, list, download as zip, delete, replay.

    ``min_free_bytes``: :meth:`save` refuses (DiskFull) unless the filesystem keeps
    at least this much free after the capture is written. ``clock`` returns
    the current time as an aware ``datetime`` (tests pass a fixed one).

    The constructor creates ``root`` if needed and removes what a crashed
    save or delete left behind (hidden ``.incoming-*`` / ``.deleting-*``).
    Ids, list, get, zip, delete, trash and restore are the
    :class:`.folder_store.FolderStore`'s.
    """

    noun = "capture"
    folder_name = "the capture folder"

    def __init__(
        self,
        root: Union[str, Path],
        *,
        min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
        clock: Optional[Callable[[], datetime]] = None,
    ) -> None:
        super().__init__(root, min_free_bytes=min_free_bytes, clock=clock)
        self.clear_hidden()
        self.purge_trash()

    # -- save --------------------------------------------------------------

    def save(self, frames: Mapping[str, np.ndarray], meta: Mapping[str, Any],
             extra_files: Sequence[Tuple[str, bytes]] = ()) -> CaptureInfo:
        """Store one stereo set atomically and return what :meth:`list` will show for it.

        ``frames`` has exactly the keys :data:`FRAME_NAMES`; each is an
        ``(H, W, 4)`` RGBY, ``(H, W, 3)`` RGB or ``(H, W)`` gray uint8 array
        (read only; the caller keeps ownership). The left and right frames of
        each pair must have the same size. ``meta`` must be JSON-serialisable
        (numpy scalars and arrays are converted) and hold ``"frame"``, the
        frame number (int, 0 .. 9_999_999_999); ``"source"`` and
        ``"calibration_id"`` (str or None) are shown in listings; the keys
        :data:`RESERVED_META_KEYS` are the store's. Suggested further keys:
        ``"time"``, ``"registers"``, ``"camera"``. ``extra_files`` are further files stored as
        they are (name, bytes: the stereo core's disparity, a point cloud), listed in meta.json's
        ``files`` with the frames'; a name must be a plain file name none of the frames use.

        Raises :class:`CaptureDiskFull` if the space is short, before
        writing or on ENOSPC/EDQUOT while writing, and :class:`CaptureError`
        on any other I/O error; in both cases no file of this capture
        remains and :meth:`list` is unchanged.
        """
        user_meta, frame_no = self._check_meta(meta)
        images, files = encode_frames(frames)
        files.extend(_checked_extra(extra_files, [n for n, _ in files]))
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
            meta_size = len(meta_dumps(doc)) + MAX_ID_LENGTH
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
            free = self.free_bytes()
        except OSError as exc:
            raise CaptureError(
                f"cannot check the free space in {self.root} ({exc.strerror or exc}); nothing was stored"
            ) from exc
        if free - need < self.min_free_bytes and self.purge_trash(0.0):
            try:
                free = self.free_bytes()
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
            cid, tmp = self.reserve(frame_no, now)
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
            self.publish(tmp, cid)
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

    # -- read --------------------------------------------------------------

    def _info(self, cid: str, folder: Path) -> CaptureInfo:
        return read_info(cid, folder)

    def raw_pair(self, capture_id: object) -> Tuple[np.ndarray, np.ndarray]:
        """The raw left and right frames as ``(H, W, 4)`` RGBY uint8 arrays, bit for bit as captured.

        Fresh arrays the caller owns; ``pixel.pack(*store.raw_pair(id))`` is
        the stream frame for the virtual camera. InvalidId/NotFound as :meth:`path`;
        :class:`CaptureDamaged` if a raw image is missing or corrupt.
        """
        folder = self.path(capture_id)
        return read_raw_pair(folder.name, folder)

    # -- download ----------------------------------------------------------

    def read_file(self, capture_id: object, name: object) -> bytes:
        """The bytes of one file of a capture (``raw_left.png``, ``meta.json``, ...).

        ``name`` must be the name of a regular file directly in the capture
        folder, as :attr:`CaptureInfo.files` lists them: it is looked up in
        that listing, never joined to a path as given, so ``../x`` or a
        symbolic link cannot be read. InvalidId malformed id; NotFound absent capture
        or no such file (the message lists the files there are).
        """
        folder = self.path(capture_id)
        cid = folder.name
        names = [f.name for f in self._info(cid, folder).files]
        if not isinstance(name, str) or name not in names:
            raise CaptureNotFound(
                f"capture {cid} has no file {shown(name)}; it has {', '.join(names) or 'no files'}"
            )
        try:
            return read_member(folder, name)
        except FileNotFoundError:
            raise CaptureNotFound(f"capture {cid} was deleted while it was being read") from None
        except OSError as exc:
            raise CaptureError(f"cannot read {name} of capture {cid}: {exc.strerror or exc}") from exc

    def _zip_names(self, folder: Path, info: CaptureInfo) -> List[str]:
        """meta.json, then the images in :data:`FRAME_NAMES` order, then anything else listed."""
        order = {META_FILE: 0, **{capture_file(n): i + 1 for i, n in enumerate(FRAME_NAMES)}}
        return sorted((f.name for f in info.files), key=lambda n: (order.get(n, len(order)), n))

    # -- thumbnails ----------------------------------------------------------

    def thumbnail(self, capture_id: object, width: int = THUMB_WIDTH) -> bytes:
        """A small JPEG of the capture: its rectified left frame (its raw left one when that cannot
        be read), ``width`` pixels wide (never wider than the frame), aspect kept.

        InvalidId/NotFound as :meth:`path`; :class:`CaptureDamaged` when neither image can be read.
        Files are read by fixed names, never following a symbolic link.
        """
        folder = self.path(capture_id)
        return thumbnail_jpeg(folder.name, folder, width)
