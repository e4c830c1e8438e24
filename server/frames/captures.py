"""Captures: synchronised stereo sets stored on disk, one folder each.

A capture is a folder ``<root>/<id>/`` holding

    raw_left.png   raw_right.png    the cameras' frames as the demosaic delivered them
    rect_left.png  rect_right.png   the rectify core's output for the same frame
    meta.json                       what the caller passed, plus id, created, images, files

and, only where needed, ``<frame>_y.png`` (see "Pixels" below). The names of
the raw pair are the ones the emulated cameras' replay and the calibration
read (:mod:`stereocam.calibration.image_files` names them), so a capture folder (or
the whole store) replays as a live source.

Pixels. A frame is an ``(H, W, 4)`` RGBY view of the stream (or ``(H, W, 3)``
RGB, or ``(H, W)`` gray) and is stored losslessly as PNG:

- ``"color": "gray"``: R == G == B == Y at every pixel (a gray camera): an
  8-bit gray PNG.
- ``"color": "rgb"``: an RGB PNG. Y is not stored when it equals
  :func:`...overlays.spec.pixel.gray_of` of the RGB pixels, which is what the
  demosaic stage computes for raw frames. Otherwise (rectified frames: the
  core interpolates Y on its own) Y goes to a gray PNG ``<frame>_y.png``,
  named by ``"y_file"``, so every stored frame comes back bit for bit.

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
digits), 4 random hex digits. They sort by time, are URL-safe, and are
checked against :data:`ID_PATTERN` before any path is built from them;
symbolic links in the store are never followed.

Thread safety: a :class:`CaptureStore` holds no mutable state; every method
is synchronous, blocking (disk I/O, PNG encoding) and safe to call from
several threads at once. Run them in a worker thread, not on an event loop.

Errors: every :class:`CaptureError` carries the HTTP ``status`` to answer
with and a one-line ``message`` for the user. Wrong arguments from the
calling code (frames of the wrong shape, meta that is not JSON) raise
``ValueError``/``TypeError``: those are bugs, answer 500.
"""
from __future__ import annotations

import errno
import hashlib
import json
import numbers
import os
import re
import secrets
import shutil
import stat
import weakref
import zipfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any, Callable, Dict, Iterator, List, Mapping, Optional, Tuple, Union

import cv2
import numpy as np

from ...calibration.image_files import CAPTURE_FILES, RAW_FRAMES, capture_file
from ...overlays.spec import pixel
from .errors import ApiError

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

FRAME_NAMES = RAW_FRAMES + ("rect_left", "rect_right")
THUMB_FRAMES = ("rect_left", "raw_left")  # what a thumbnail shows: the first of these that can be read
META_FILE = "meta.json"
FORMAT = "stereocam-capture/1"
ID_PATTERN = r"[0-9]{8}T[0-9]{6}Z-[0-9]{6,10}-[0-9a-f]{4}"
ID_EXAMPLE = "20261122T040512Z-000123-ab12"
MAX_FRAME_NUMBER = 10**10 - 1
DEFAULT_MIN_FREE_BYTES = 64 * 1024 * 1024
RESERVED_META_KEYS = ("format", "id", "created", "images", "files")
INCOMING_PREFIX = ".incoming-"
DELETING_PREFIX = ".deleting-"
TRASH_DIR = ".trash"
TRASH_KEEP_S = 600.0  # a trashed capture can be restored for 10 minutes
THUMB_WIDTH = 160  # pixels: the capture list's thumbnails (shown at 80 CSS px, sharp on a 2x screen)
_THUMB_QUALITY = 80
_TRASH_RE = re.compile(r"(" + ID_PATTERN + r")\.([0-9]{1,20})")

_ID_RE = re.compile(ID_PATTERN)
_MAX_ID_LENGTH = 32
_CHUNK = 1 << 20
_MAX_META_BYTES = 4 << 20
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]
_FULL_ERRNOS = frozenset(e for e in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if e is not None)

# Low-level I/O, module-level so tests can make the disk fail exactly here.
_os_write = os.write
_os_fsync = os.fsync


def _random_suffix() -> str:
    return secrets.token_hex(2)


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------

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


# --------------------------------------------------------------------------
# What the store reports
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class CaptureFile:
    name: str
    bytes: int
    sha256: Optional[str] = None  # from meta.json; None if not recorded there (meta.json itself, damage)

    def to_json(self) -> Dict[str, Any]:
        return {"name": self.name, "bytes": self.bytes, "sha256": self.sha256}


@dataclass(frozen=True)
class CaptureInfo:
    """One stored capture, as listed.

    ``files`` are the regular files in the capture's folder (``meta.json``
    included), ``bytes`` their total size. ``error`` is None for a sound
    capture, else a one-line description of what is wrong with it (meta.json
    missing or not JSON, a file missing or of the wrong size): damaged
    captures are listed, never hidden. ``meta`` is the parsed meta.json
    (empty when it cannot be read).
    """

    id: str
    created: str
    frame: Optional[int]
    source: Optional[str]
    calibration_id: Optional[str]
    files: Tuple[CaptureFile, ...]
    bytes: int
    error: Optional[str] = None
    meta: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def to_json(self, *, meta: bool = False) -> Dict[str, Any]:
        """A JSON-ready dict; ``meta=True`` adds the whole meta.json under ``"meta"``."""
        out: Dict[str, Any] = {
            "id": self.id,
            "created": self.created,
            "frame": self.frame,
            "source": self.source,
            "calibration_id": self.calibration_id,
            "files": [f.to_json() for f in self.files],
            "bytes": self.bytes,
            "error": self.error,
        }
        if meta:
            out["meta"] = dict(self.meta)
        return out


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

def _shown(value: object) -> str:
    """An untrusted value, quoted and cut short, for an error message."""
    text = value if isinstance(value, str) else repr(value)
    if len(text) > 40:
        text = text[:40] + "..."
    return json.dumps(text)


def _iso(t: datetime) -> str:
    t = t.astimezone(timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _created_from_id(capture_id: str) -> str:
    t = datetime.strptime(capture_id[:16], "%Y%m%dT%H%M%SZ").replace(tzinfo=timezone.utc)
    return _iso(t)


def _not_found(cid: str) -> CaptureNotFound:
    return CaptureNotFound(f"no capture {cid}: it was deleted or never existed; list the captures")


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _dumps(doc: Mapping[str, Any]) -> bytes:
    return (json.dumps(doc, indent=2, allow_nan=False, default=_json_default) + "\n").encode("utf-8")


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        _os_fsync(fd)
    finally:
        os.close(fd)


def _write_new_file(path: Path, data: bytes) -> None:
    """Create ``path`` (must not exist), write ``data`` in chunks, fsync it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        view = memoryview(data)
        while view:
            written = _os_write(fd, view[:_CHUNK])
            view = view[written:]
        _os_fsync(fd)
    finally:
        os.close(fd)


def _open_member(folder: Path, name: str) -> int:
    """A read-only fd of the regular file ``folder/name``; never follows a symbolic link."""
    fd = os.open(folder / name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise IsADirectoryError(errno.EISDIR, "not a regular file", str(folder / name))
    except BaseException:
        os.close(fd)
        raise
    return fd


def _read_member(folder: Path, name: str, limit: Optional[int] = None) -> bytes:
    fd = _open_member(folder, name)
    with os.fdopen(fd, "rb") as fh:
        data = fh.read() if limit is None else fh.read(limit + 1)
    if limit is not None and len(data) > limit:
        raise ValueError(f"{name} is larger than {_mb(limit)}")
    return data


def _remove_tree(path: Path) -> None:
    """Remove a folder (or a symbolic link in its place) as far as possible; never raises."""
    try:
        if path.is_symlink() or not path.is_dir():
            path.unlink()
        else:
            shutil.rmtree(path, ignore_errors=True)
    except OSError:
        pass


def _png(name: str, image: np.ndarray) -> bytes:
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), _PNG_PARAMS)
    if not ok:
        raise CaptureError(f"cannot encode {name} as PNG (OpenCV refused it): nothing was stored")
    return buf.tobytes()


def _encode_frame(name: str, frame: Any) -> Tuple[Dict[str, Any], List[Tuple[str, bytes]]]:
    """The image entry of meta.json and the PNG files of one frame (see the module doc)."""
    a = np.asarray(frame)
    if a.dtype != np.uint8:
        raise TypeError(f"frame {name} must be uint8, got {a.dtype}")
    if a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3):
        a = pixel.rgby(a)
    elif not (a.ndim == 3 and a.shape[2] == 4):
        raise ValueError(f"frame {name} must be (H, W, 4) RGBY, (H, W, 3) RGB or (H, W) gray; got {a.shape}")
    h, w = a.shape[:2]
    if h == 0 or w == 0:
        raise ValueError(f"frame {name} is empty: {a.shape}")
    r, g, b, y = (a[..., i] for i in range(4))
    file, y_file = capture_file(name), capture_file(name, y_plane=True)
    entry: Dict[str, Any] = {"file": file, "width": int(w), "height": int(h)}
    if np.array_equal(r, g) and np.array_equal(r, b) and np.array_equal(r, y):
        entry.update(color="gray", y_file=None)
        return entry, [(file, _png(name, r))]
    rgb = a[..., :3]
    files = [(file, _png(name, rgb))]
    if np.array_equal(y, pixel.gray_of(rgb)):
        entry.update(color="rgb", y_file=None)
    else:
        entry.update(color="rgb", y_file=y_file)
        files.append((y_file, _png(f"{name}_y", np.ascontiguousarray(y))))
    return entry, files


def _encode_frames(frames: Mapping[str, np.ndarray]) -> Tuple[Dict[str, Any], List[Tuple[str, bytes]]]:
    """meta.json's ``images`` and the PNG files of a capture's :data:`FRAME_NAMES` frames.

    ``ValueError`` unless ``frames`` has exactly those keys and each pair's
    left and right frames have the same size.
    """
    missing = [n for n in FRAME_NAMES if n not in frames]
    extra = sorted(str(n) for n in frames if n not in FRAME_NAMES)
    if missing or extra:
        raise ValueError(
            f"frames must have exactly the keys {', '.join(FRAME_NAMES)}"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(extra)}" if extra else "")
        )
    images: Dict[str, Any] = {}
    files: List[Tuple[str, bytes]] = []
    for name in FRAME_NAMES:
        entry, pngs = _encode_frame(name, frames[name])
        images[name] = entry
        files.extend(pngs)
    for a, b in (("raw_left", "raw_right"), ("rect_left", "rect_right")):
        sa = (images[a]["width"], images[a]["height"])
        sb = (images[b]["width"], images[b]["height"])
        if sa != sb:
            raise ValueError(
                f"frames {a} ({sa[0]}x{sa[1]}) and {b} ({sb[0]}x{sb[1]}) must have the same size"
            )
    return images, files


def _decode_png(data: bytes) -> Optional[np.ndarray]:
    if not data:
        return None
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint8:
        return None
    if img.ndim == 3:
        if img.shape[2] == 3:
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        return None
    return img


# --------------------------------------------------------------------------
# The store
# --------------------------------------------------------------------------

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
        self._clock = clock or _utcnow
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
            _remove_tree(path)
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
            raise _not_found(cid)
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
        images, files = _encode_frames(frames)
        now = self._clock()
        if now.tzinfo is None:
            raise ValueError("the store's clock must return an aware datetime (e.g. in timezone.utc)")
        doc: Dict[str, Any] = {"format": FORMAT, "id": "", "created": _iso(now)}
        doc.update(user_meta)
        doc["images"] = images
        doc["files"] = [
            {"name": n, "bytes": len(d), "sha256": hashlib.sha256(d).hexdigest()} for n, d in files
        ]
        try:
            meta_size = len(_dumps(doc)) + _MAX_ID_LENGTH
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
                f"not enough free space for a capture in {self.root}: {_mb(free)} free, the capture needs "
                f"{_mb(need)} and {_mb(self.min_free_bytes)} are kept free; delete old captures to make room"
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
                _write_new_file(tmp / name, data)
            step = f"writing {META_FILE}"
            meta_bytes = _dumps(doc)
            _write_new_file(tmp / META_FILE, meta_bytes)
            step = "syncing the capture folder"
            _fsync_dir(tmp)
            step = "publishing the capture"
            os.rename(tmp, self.root / cid)
            tmp = None
        except OSError as exc:
            if tmp is not None:
                _remove_tree(tmp)
            if exc.errno in _FULL_ERRNOS:
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
                _remove_tree(tmp)
            raise
        try:
            _fsync_dir(self.root)  # durability of the rename; the capture is complete and listed either way
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
        problems: List[str] = []
        sizes: Dict[str, int] = {}
        try:
            with os.scandir(folder) as entries:
                for entry in entries:
                    if entry.is_symlink():
                        problems.append(f"{entry.name} is a symbolic link, not a file")
                    elif entry.is_file(follow_symlinks=False):
                        sizes[entry.name] = entry.stat(follow_symlinks=False).st_size
        except (FileNotFoundError, NotADirectoryError):  # deleted meanwhile
            raise _not_found(cid) from None
        problems.sort()

        doc: Dict[str, Any] = {}
        doc_ok = False
        try:
            loaded = json.loads(_read_member(folder, META_FILE, _MAX_META_BYTES).decode("utf-8"))
            if not isinstance(loaded, dict):
                raise ValueError("not a JSON object")
            doc, doc_ok = loaded, True
        except FileNotFoundError:
            problems.insert(0, f"{META_FILE} is missing")
        except OSError as exc:
            problems.insert(0, f"{META_FILE} cannot be read ({exc.strerror or exc})")
        except ValueError as exc:  # includes JSONDecodeError and UnicodeDecodeError
            problems.insert(0, f"{META_FILE} is damaged ({' '.join(str(exc).split())[:80] or 'bad JSON'})")

        hashes: Dict[str, str] = {}
        if doc_ok:
            listed = doc.get("files")
            if not isinstance(listed, list) or not all(
                isinstance(f, dict) and isinstance(f.get("name"), str) and isinstance(f.get("bytes"), int)
                for f in listed
            ):
                problems.append(f"{META_FILE} has no valid file list")
                listed = []
            for f in listed:
                name, size = f["name"], f["bytes"]
                if isinstance(f.get("sha256"), str):
                    hashes[name] = f["sha256"]
                if name not in sizes:
                    problems.append(f"{name} is missing")
                elif sizes[name] != size:
                    problems.append(f"{name} is {sizes[name]} bytes, {META_FILE} says {size}")
        else:
            for name in CAPTURE_FILES:
                if name not in sizes:
                    problems.append(f"{name} is missing")

        if problems and not os.path.isdir(folder):  # deleted while we looked: not damage
            raise _not_found(cid)
        created = doc.get("created")
        if not isinstance(created, str) or not created:
            created = _created_from_id(cid)
        frame = doc.get("frame")
        if isinstance(frame, bool) or not isinstance(frame, int):
            frame = int(cid.split("-")[1])
        source = doc.get("source") if isinstance(doc.get("source"), str) else None
        calib = doc.get("calibration_id") if isinstance(doc.get("calibration_id"), str) else None
        files = tuple(CaptureFile(n, sizes[n], hashes.get(n)) for n in sorted(sizes))
        return CaptureInfo(
            id=cid,
            created=created,
            frame=frame,
            source=source,
            calibration_id=calib,
            files=files,
            bytes=sum(sizes.values()),
            error="; ".join(problems) or None,
            meta=doc,
        )

    def raw_pair(self, capture_id: object) -> Tuple[np.ndarray, np.ndarray]:
        """The raw left and right frames as ``(H, W, 4)`` RGBY uint8 arrays, bit for bit as captured.

        Fresh arrays the caller owns; ``pixel.pack(*store.raw_pair(id))`` is
        the stream frame for the virtual camera. 400/404 as :meth:`path`;
        :class:`CaptureDamaged` (422) if a raw image is missing or corrupt.
        """
        folder = self.path(capture_id)
        cid = folder.name
        out = []
        for name in RAW_FRAMES:
            file, y_file = capture_file(name), capture_file(name, y_plane=True)
            try:
                data = _read_member(folder, file)
            except FileNotFoundError:
                raise CaptureDamaged(f"capture {cid} cannot be replayed: {file} is missing") from None
            except OSError as exc:
                raise CaptureDamaged(
                    f"capture {cid} cannot be replayed: {file} cannot be read ({exc.strerror or exc})"
                ) from exc
            image = _decode_png(data)
            if image is None:
                raise CaptureDamaged(
                    f"capture {cid} cannot be replayed: {file} is not a valid 8-bit image"
                )
            frame = pixel.rgby(image)
            try:
                y_data: Optional[bytes] = _read_member(folder, y_file)
            except FileNotFoundError:
                y_data = None
            except OSError as exc:
                raise CaptureDamaged(
                    f"capture {cid} cannot be replayed: {y_file} cannot be read ({exc.strerror or exc})"
                ) from exc
            if y_data is not None:
                y = _decode_png(y_data)
                if y is None or y.shape != frame.shape[:2]:
                    raise CaptureDamaged(
                        f"capture {cid} cannot be replayed: {y_file} is not a gray image of the "
                        f"frame's size"
                    )
                frame[..., pixel.Y] = y
            out.append(frame)
        left, right = out
        if left.shape != right.shape:
            raise CaptureDamaged(
                f"capture {cid} cannot be replayed: {CAPTURE_FILES[0]} is {left.shape[1]}x{left.shape[0]} "
                f"but {CAPTURE_FILES[1]} is {right.shape[1]}x{right.shape[0]}"
            )
        return left, right

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
            return _read_member(folder, name)
        except FileNotFoundError:
            raise CaptureNotFound(f"capture {cid} was deleted while it was being read") from None
        except OSError as exc:
            raise CaptureError(f"cannot read {name} of capture {cid}: {exc.strerror or exc}") from exc

    def zip_stream(self, capture_id: object, *, chunk_size: int = _CHUNK) -> Iterator[bytes]:
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
                member: IO[bytes] = os.fdopen(_open_member(folder, name), "rb")
                handles.append((name, member, os.fstat(member.fileno()).st_size))
        except OSError as exc:
            _close_all([fh for _, fh, _ in handles])
            if isinstance(exc, FileNotFoundError):
                raise CaptureNotFound(f"capture {cid} was deleted while it was being read") from None
            raise CaptureError(f"cannot read capture {cid}: {exc.strerror or exc}") from exc
        try:
            stamp = datetime.strptime(info.created[:19], "%Y-%m-%dT%H:%M:%S")
        except ValueError:
            stamp = datetime.strptime(cid[:16], "%Y%m%dT%H%M%SZ")
        date_time = (max(stamp.year, 1980), stamp.month, stamp.day, stamp.hour, stamp.minute, stamp.second)
        gen = _zip_chunks(cid, date_time, handles, max(1, int(chunk_size)))
        weakref.finalize(gen, _close_all, [fh for _, fh, _ in handles])
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
            raise _not_found(cid) from None
        except OSError as exc:
            raise CaptureError(f"cannot delete capture {cid}: {exc.strerror or exc}") from exc
        try:
            _fsync_dir(self.root)
        except OSError:
            pass
        _remove_tree(trash)

    # -- trash (delete with undo) ---------------------------------------------

    def _trash_dir(self, create: bool) -> Optional[Path]:
        """``root/.trash`` (a real folder, never a symbolic link), made if ``create``; else None if absent."""
        folder = self.root / TRASH_DIR
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
            raise CaptureError(f"{folder} is not a folder: remove it so that deleted captures can be kept "
                               f"for an undo")
        return folder

    def _trashed(self, folder: Path) -> List[Tuple[str, int, Path]]:
        """``(id, deleted at (ns since the epoch), path)`` of every capture in the trash folder."""
        out = []
        with os.scandir(folder) as entries:
            for e in entries:
                m = _TRASH_RE.fullmatch(e.name)
                if m and e.is_dir(follow_symlinks=False):
                    out.append((m.group(1), int(m.group(2)), Path(e.path)))
        return out

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
            trash = self._trash_dir(create=True)
            assert trash is not None
            stamp = int(self._clock().timestamp() * 1e9)
            while os.path.lexists(trash / f"{cid}.{stamp}"):  # deleted, restored, deleted in one clock tick
                stamp += 1
            os.rename(folder, trash / f"{cid}.{stamp}")
        except FileNotFoundError:
            raise _not_found(cid) from None
        except OSError as exc:
            raise CaptureError(f"cannot delete capture {cid}: {exc.strerror or exc}") from exc
        for path in (self.root, trash):
            try:
                _fsync_dir(path)
            except OSError:
                pass
        self.purge_trash()

    def restore(self, capture_id: object) -> CaptureInfo:
        """Bring back a capture :meth:`trash` deleted (the latest delete of that id) and return it.

        400 malformed id; 404 when it is not in the trash (never deleted, purged, or restored
        already); 409 when a capture of that id exists.
        """
        cid = self.check_id(capture_id)
        trash = self._trash_dir(create=False)
        found = sorted(t for t in (self._trashed(trash) if trash is not None else []) if t[0] == cid)
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
            _fsync_dir(self.root)
        except OSError:
            pass
        return self.get(cid)

    def purge_trash(self, keep_s: float = TRASH_KEEP_S) -> int:
        """Remove what has been in the trash for ``keep_s`` seconds or more (0: everything).

        Returns how many captures were removed. Never raises.
        """
        try:
            trash = self._trash_dir(create=False)
            if trash is None:
                return 0
            now_ns = self._clock().timestamp() * 1e9
            keep_ns = keep_s * 1e9  # a clock set back (a board without RTC) ages entries too
            old = [path for _, deleted, path in self._trashed(trash) if abs(now_ns - deleted) >= keep_ns]
        except (OSError, CaptureError):
            return 0
        for path in old:
            _remove_tree(path)
        return len(old)

    # -- thumbnails ----------------------------------------------------------

    def thumbnail(self, capture_id: object, width: int = THUMB_WIDTH) -> bytes:
        """A small JPEG of the capture: its rectified left frame (its raw left one when that cannot
        be read), ``width`` pixels wide (never wider than the frame), aspect kept.

        400/404 as :meth:`path`; :class:`CaptureDamaged` (422) when neither image can be read.
        Files are read by fixed names, never following a symbolic link.
        """
        folder = self.path(capture_id)
        cid = folder.name
        image = None
        for name in map(capture_file, THUMB_FRAMES):
            try:
                data = _read_member(folder, name, 64 << 20)
            except FileNotFoundError:
                continue
            except (OSError, ValueError):
                continue
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
            if image is not None:
                break
        if image is None:
            if not os.path.isdir(folder):
                raise _not_found(cid)
            raise CaptureDamaged(f"capture {cid} has no readable "
                                 f"{' or '.join(map(capture_file, THUMB_FRAMES))} for a thumbnail")
        h, w = image.shape[:2]
        tw = max(1, min(int(width), w))
        th = max(1, round(h * tw / w))
        small = cv2.resize(image, (tw, th), interpolation=cv2.INTER_AREA) if tw != w else image
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, _THUMB_QUALITY])
        if not ok:
            raise CaptureError(f"cannot encode the thumbnail of capture {cid}")
        return buf.tobytes()


class _Sink:
    """A write-only, unseekable file for ``zipfile``: collects what it is given until taken."""

    def __init__(self) -> None:
        self._parts: List[bytes] = []
        self._pos = 0
        self.pending = 0

    def write(self, data: Any) -> int:
        b = bytes(data)
        self._parts.append(b)
        self._pos += len(b)
        self.pending += len(b)
        return len(b)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    def take(self) -> bytes:
        out = b"".join(self._parts)
        self._parts.clear()
        self.pending = 0
        return out


def _close_all(handles: List[IO[bytes]]) -> None:
    for fh in handles:
        fh.close()


def _zip_chunks(
    cid: str, date_time: Tuple[int, int, int, int, int, int],
    handles: List[Tuple[str, IO[bytes], int]], chunk_size: int,
) -> Iterator[bytes]:
    sink = _Sink()
    try:
        with zipfile.ZipFile(sink, "w", allowZip64=True) as zf:
            for name, fh, size in handles:
                zi = zipfile.ZipInfo(f"{cid}/{name}", date_time=date_time)
                zi.compress_type = zipfile.ZIP_STORED if name.endswith(".png") else zipfile.ZIP_DEFLATED
                zi.file_size = size
                zi.external_attr = 0o644 << 16
                with zf.open(zi, "w") as dst:
                    while True:
                        block = fh.read(chunk_size)
                        if not block:
                            break
                        dst.write(block)
                        if sink.pending >= chunk_size:
                            yield sink.take()
                if sink.pending:
                    yield sink.take()
        if sink.pending:
            yield sink.take()
    finally:
        _close_all([fh for _, fh, _ in handles])
