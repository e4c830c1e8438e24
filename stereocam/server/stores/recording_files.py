"""A recording's folder on disk: its names, how the writer writes it, and its recovery after a crash.

The writer (:class:`.recordings.Recording`) writes each frame's PNGs, then its
line of ``frames.jsonl``, and syncs the folder in batches (:data:`SYNC_FRAMES`
frames or :data:`SYNC_S` seconds, whichever comes first). ``recording.json``
is created when the recording starts, holding what is known then and padded
with spaces to the size the finished one needs (:data:`META_RESERVE` more):
finishing overwrites those bytes in place, so a disk that filled meanwhile
cannot keep a recording from being finished.

A daemon killed (or a board losing power) while recording leaves the hidden
``.incoming-<id>/`` folder. :func:`recover` keeps its whole frames: frames in
order from the first, each kept when its line is whole JSON naming its files
and each file is a regular file that ends as a PNG ends, the sizes adding up
to the line's ``bytes``. The first frame that is not whole ends what is
kept; its files and those after it are removed, ``frames.jsonl`` is cut
after the last whole line, and ``recording.json`` is written (``end``
``interrupted``, ``complete`` false) before the folder is published. After
each sync the writer notes in ``recording.json`` how many frames are on the
disk (``synced_frames``, itself on the disk with the next sync): those frames'
files are not read again, so a long recording is recovered in the time its
lines take to read, not its files.

Every file is opened without following a symbolic link; ``_os_write``,
``_os_pwrite``, ``_os_fsync`` and ``_syncfs`` are module-level so that tests
can make the disk fill exactly there.
"""
from __future__ import annotations

import contextlib
import errno
import functools
import json
import logging
import os
import re
import struct
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

from .files import fsync_dir, meta_dumps, open_member, read_member, remove_tree
from .frame_calibration import FrameCalibration
from .ids import ID_PATTERN, created_from_id

log = logging.getLogger(__name__)

__all__ = [
    "FORMAT", "META_FILE", "FRAMES_FILE", "ENDS", "STOP_REASONS", "META_RESERVE", "MAX_META_BYTES",
    "MAX_LINE_BYTES", "SYNC_FRAMES", "SYNC_S", "COUNT_MOD", "frame_names", "FrameStats", "FramesFile",
    "create_file", "reserve_meta", "rewrite_meta", "read_meta", "sync_file", "sync_folder", "recover",
    "Recovered",
]

FORMAT = "stereocam-recording/1"
META_FILE = "recording.json"
FRAMES_FILE = "frames.jsonl"
STOP_REASONS = ("duration", "stopped", "disk_full", "shutdown", "error")
ENDS = STOP_REASONS + ("interrupted",)  # interrupted: recovered after a crash or a power cut
META_RESERVE = 256 * 1024  # what recording.json may grow by from its start to its end
MAX_META_BYTES = 4 << 20  # a recording.json larger than this is not one of ours: refused
MAX_LINE_BYTES = 64 * 1024  # a frames.jsonl line is a few hundred bytes; longer is damage
MAX_IDS = 256  # calibration ids recorded in recording.json, at most (so it fits its reserve)
SYNC_FRAMES = 60  # frames written between two syncs of the folder, at most
SYNC_S = 1.0  # seconds between two syncs while frames are written, at most
COUNT_MOD = 1 << 32  # FRAME_COUNT wraps here

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk every whole PNG ends with
_LINE_KEYS = frozenset(("index", "frame", "fabric_count", "time", "t", "source", "calibration_id", "left",
                        "right", "left_y", "right_y", "color", "bytes"))  # a frames.jsonl line's, all there
_FRAME_FILE_RE = re.compile(r"(?:y_)?(?:left|right)_([0-9]{6,})\.png")
_INCOMING_ID_RE = re.compile(ID_PATTERN)

# Low-level I/O, module-level so tests can make the disk fail exactly here.
_os_write = os.write
_os_pwrite = os.pwrite
_os_fsync = os.fsync


def frame_names(index: int) -> Tuple[str, str]:
    """The file names of frame ``index``'s left and right images."""
    return f"left_{index:06d}.png", f"right_{index:06d}.png"


# -- writing ---------------------------------------------------------------------------------------

def _write_all(fd: int, data: bytes, offset: Optional[int] = None) -> None:
    view = memoryview(data)
    while view:
        n = _os_write(fd, view) if offset is None else _os_pwrite(fd, view, offset)
        view = view[n:]
        if offset is not None:
            offset += n


def create_file(path: Path, data: bytes) -> None:
    """Create ``path`` (must not exist) holding ``data``; not synced (the writer syncs in batches)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        _write_all(fd, data)
    finally:
        os.close(fd)


def reserve_meta(path: Path, data: bytes) -> int:
    """Create ``recording.json`` holding ``data`` and :data:`META_RESERVE` spaces after it, synced.

    The spaces are the room finishing needs (JSON allows trailing whitespace); returns the size.
    """
    size = len(data) + META_RESERVE
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        _write_all(fd, data + b" " * META_RESERVE)
        _os_fsync(fd)
    finally:
        os.close(fd)
    return size


def rewrite_meta(path: Path, data: bytes, *, final: bool, sync: bool = True) -> None:
    """Overwrite ``recording.json`` in place with ``data``, and sync it unless told not to.

    Within the reserved size this needs no new space. Not ``final``, the rest of the
    reserve stays as spaces; ``final``, the file is cut to ``data``.
    """
    fd = os.open(path, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        size = os.fstat(fd).st_size
        if not final and len(data) < size:
            data += b" " * (size - len(data))
        _write_all(fd, data, 0)
        if final:
            os.ftruncate(fd, len(data))
        if sync:
            _os_fsync(fd)
    finally:
        os.close(fd)


def sync_file(folder: Path, name: str) -> None:
    """fsync ``folder/name`` (a regular file, never through a symbolic link)."""
    fd = open_member(folder, name)
    try:
        _os_fsync(fd)
    finally:
        os.close(fd)


class FramesFile:
    """``frames.jsonl`` being written: whole lines only (an append that fails is cut off again).

    Unbuffered (``O_APPEND``), so nothing waits in memory for a flush that could fail at the end.
    """

    def __init__(self, path: Path) -> None:
        self.fd: Optional[int] = os.open(
            path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        self.size = 0

    def append(self, line: bytes) -> None:
        assert self.fd is not None
        try:
            _write_all(self.fd, line)
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, self.size)  # shrinking needs no space
            raise
        self.size += len(line)

    def close(self) -> None:
        fd, self.fd = self.fd, None
        if fd is not None:
            os.close(fd)


@functools.lru_cache(maxsize=1)
def _libc_syncfs() -> Optional[Callable[[int], int]]:
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).syncfs
    except (OSError, AttributeError):
        return None


def _syncfs(fd: int) -> bool:
    """``syncfs(2)`` of the file system holding ``fd``: False where there is none; OSError when it fails."""
    fn = _libc_syncfs()
    if fn is None:
        return False
    if fn(fd) == 0:
        return True
    import ctypes

    err = ctypes.get_errno()
    if err == errno.ENOSYS:
        return False
    raise OSError(err, os.strerror(err))


def sync_folder(folder: Path) -> None:
    """Every file of ``folder`` on disk (blocks): one ``syncfs`` where there is one (Linux).

    A recording holds thousands of files; an fsync each takes seconds on an SD card, which
    would hold up a stop or SIGTERM. One syncfs writes them in one sweep.
    """
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        if _syncfs(fd):
            return
    finally:
        os.close(fd)
    for name in sorted(os.listdir(folder)):
        sync_file(folder, name)


# -- what recording.json says of the frames ------------------------------------------------------------

def _number(value: Any) -> Optional[float]:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


class FrameStats:
    """What ``recording.json`` says of the frames, gathered from their lines as they are written or read."""

    def __init__(self) -> None:
        self.frames = 0
        self.bytes = 0
        self.first: Optional[Dict[str, Any]] = None
        self.last: Optional[Dict[str, Any]] = None
        self.sources: List[str] = []
        self.calibration_ids: List[Optional[str]] = []
        self.color: Optional[str] = None

    def add(self, line: Mapping[str, Any]) -> None:
        """One more frame, its ``frames.jsonl`` line."""
        if self.first is None:
            self.first = dict(line)
        self.last = dict(line)
        if line["source"] not in self.sources:
            self.sources.append(line["source"])
        cal_id = line["calibration_id"]
        if cal_id not in self.calibration_ids and len(self.calibration_ids) < MAX_IDS:
            self.calibration_ids.append(cal_id)
        self.color = line["color"]
        self.frames += 1
        self.bytes += int(line["bytes"])

    @property
    def counts(self) -> int:
        """FRAME_COUNT periods from the first frame to the last."""
        if self.first is None or self.last is None:
            return 0
        return (int(self.last["fabric_count"]) - int(self.first["fabric_count"])) % COUNT_MOD

    @property
    def missed(self) -> int:
        """FRAME_COUNT values from the first frame to the last with no frame recorded."""
        return self.counts + 1 - self.frames if self.frames else 0

    def fps(self, hint: Optional[float]) -> Optional[float]:
        """The cameras' rate, FRAME_COUNT over time (``hint`` before two frames tell)."""
        span = _number(self.last.get("t")) if self.last is not None else None
        if span and span > 0 and self.counts > 0:
            return self.counts / span
        return hint

    def duration(self, fps: Optional[float]) -> float:
        return (self.counts + 1) / fps if self.frames and fps else 0.0

    def doc(self, *, rid: str, created: str, seconds: Optional[float], frame_size: List[int],
            calibration: Optional[FrameCalibration], fps_hint: Optional[float], end: str,
            end_text: Optional[str], duplicates: Optional[int], skipped: Optional[int],
            meta: Mapping[str, Any]) -> Dict[str, Any]:
        """The finished ``recording.json`` (see :mod:`.recordings`); ``calibration``: the first frame's."""
        first = self.first
        assert first is not None, "a recording without a frame has no recording.json"
        fps = self.fps(fps_hint)
        doc: Dict[str, Any] = {
            "format": FORMAT, "id": rid, "created": created,
            "time_utc": datetime.fromtimestamp(float(first["time"]), timezone.utc).isoformat(
                timespec="milliseconds"),
            "seconds": seconds, "duration_s": round(self.duration(fps), 3), "frames": self.frames,
            "fps": None if fps is None else round(fps, 3), "frame_size": list(frame_size),
            "color": self.color, "source": first["source"], "sources": self.sources,
            "calibration_id": self.calibration_ids[0] if self.calibration_ids else None,
            "calibration_ids": self.calibration_ids,
            "calibration": None if calibration is None else calibration.to_json(),
            "end": end, "complete": end in ("duration", "stopped"), "end_text": end_text,
            "missed": self.missed, "duplicates": duplicates, "skipped": skipped, "bytes": self.bytes,
            "frames_file": FRAMES_FILE,
            "first": {"frame": first["frame"], "fabric_count": first["fabric_count"], "time": first["time"]},
        }
        for key, value in meta.items():
            doc.setdefault(key, value)
        return doc


def read_meta(folder: Path) -> Dict[str, Any]:
    """``recording.json`` of ``folder``: at most :data:`MAX_META_BYTES`, never through a symbolic link.

    FileNotFoundError when there is none, OSError when it cannot be read, ValueError
    (one line) when it is too large or not a JSON object.
    """
    loaded = json.loads(read_member(folder, META_FILE, MAX_META_BYTES).decode("utf-8"))
    if not isinstance(loaded, dict):
        raise ValueError("not a JSON object")
    return loaded


# -- recovery after a crash ------------------------------------------------------------------------

@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` did with an interrupted recording's folder."""

    id: str
    frames: int  # whole frames kept (0: nothing to keep, the folder was removed)
    dropped: int  # lines of frames.jsonl not kept (the frame being written, and any after it)
    duration_s: float
    finished: bool  # it had been finished already (recording.json written): only published


def _whole_png(folder: Path, name: str) -> Optional[int]:
    """The size of ``folder/name`` when it is a regular file beginning and ending as a PNG does."""
    try:
        fd = open_member(folder, name)
    except OSError:
        return None
    try:
        size = os.fstat(fd).st_size
        if size < len(_PNG_SIGNATURE) + len(_PNG_END):
            return None
        if os.pread(fd, 8, 0) != _PNG_SIGNATURE or os.pread(fd, 12, size - 12) != _PNG_END:
            return None
        return size
    finally:
        os.close(fd)


def _png_size(folder: Path, name: str) -> Optional[List[int]]:
    """``[width, height]`` from a PNG's IHDR chunk."""
    try:
        fd = open_member(folder, name)
    except OSError:
        return None
    try:
        head = os.pread(fd, 24, 0)
    finally:
        os.close(fd)
    if len(head) < 24 or head[12:16] != b"IHDR":
        return None
    return list(struct.unpack(">II", head[16:24]))


def _plausible(seconds: Any) -> bool:
    """A time of a line (since the epoch, or since the first frame) a date can be made of."""
    value = _number(seconds)
    return value is not None and 0 <= value < 1e11


def _whole_frame(folder: Path, raw: bytes, index: int, slot_after: int, first_count: Optional[int],
                 synced: bool) -> Optional[Tuple[Dict[str, Any], int]]:
    """The line ``raw`` of frame ``index`` and its slot, when the frame is whole; else None.

    ``synced``: the writer said the frame was on the disk; its files are not read.
    """
    if not raw.endswith(b"\n"):
        return None  # torn: the write of the line did not finish
    try:
        line = json.loads(raw)
        if not isinstance(line, dict) or not _LINE_KEYS <= line.keys():
            return None
        left, right = frame_names(index)
        count = line["fabric_count"]
        if (line["index"] != index or line["left"] != left or line["right"] != right
                or line["left_y"] not in (None, f"y_{left}") or line["right_y"] not in (None, f"y_{right}")
                or not isinstance(count, int) or isinstance(count, bool) or not _plausible(line["time"])
                or not _plausible(line["t"]) or not isinstance(line["bytes"], int)
                or not isinstance(line["source"], str)):
            return None
    except (ValueError, KeyError, TypeError, RecursionError):
        return None
    slot = 0 if first_count is None else (count - first_count) % COUNT_MOD
    if index and slot <= slot_after:
        return None  # FRAME_COUNTs must increase
    if synced:
        return line, slot
    total = 0
    for name in (left, right, line["left_y"], line["right_y"]):
        if name is not None:
            size = _whole_png(folder, name)
            if size is None:
                return None
            total += size
    return (line, slot) if total == line["bytes"] else None


def _frame_file_index(name: str) -> Optional[int]:
    m = _FRAME_FILE_RE.fullmatch(name)
    return int(m.group(1)) if m else None


def _keep_whole_frames(folder: Path, synced: int) -> Tuple[FrameStats, int]:
    """Cut ``frames.jsonl`` after its last whole frame and remove the files of frames not kept.

    Streams the file (a line at a time, each at most :data:`MAX_LINE_BYTES`); the files of the
    first ``synced`` frames are not read. Returns the kept frames' stats and how many lines
    were dropped.
    """
    stats = FrameStats()
    dropped = 0
    try:
        fd = open_member(folder, FRAMES_FILE)
    except FileNotFoundError:
        fd = None
    if fd is not None:
        kept_bytes, slot, first_count = 0, -1, None
        with os.fdopen(fd, "rb") as fh:
            while True:
                raw = fh.readline(MAX_LINE_BYTES + 1)
                if not raw:
                    break
                whole = None if dropped else _whole_frame(folder, raw, stats.frames, slot, first_count,
                                                          stats.frames < synced)
                if whole is None:
                    dropped += 1
                    continue
                line, slot = whole
                if first_count is None:
                    first_count = int(line["fabric_count"])
                stats.add(line)
                kept_bytes += len(raw)
        if dropped:
            cut = os.open(folder / FRAMES_FILE, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
            try:
                os.ftruncate(cut, kept_bytes)
                _os_fsync(cut)
            finally:
                os.close(cut)
    with os.scandir(folder) as entries:
        indexed = [(e.name, _frame_file_index(e.name)) for e in entries]
    for name in [name for name, index in indexed if index is not None and index >= stats.frames]:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(folder / name)
    return stats, dropped


def _start_doc(folder: Path) -> Tuple[Dict[str, Any], bool]:
    """``recording.json`` as the crash left it (``{}`` when unreadable) and whether it was finished."""
    try:
        doc = read_meta(folder)
    except (OSError, ValueError):
        return {}, False
    finished = (doc.get("format") == FORMAT and doc.get("end") in ENDS
                and isinstance(doc.get("frames"), int) and isinstance(doc.get("complete"), bool))
    return doc, finished


def _first_calibration(stored: Any, rid: str) -> Optional[FrameCalibration]:
    """The first frame's calibration as the start's ``recording.json`` had it; None when absent or not one."""
    if stored is None:
        return None
    try:
        return FrameCalibration.from_json(stored)
    except ValueError as exc:
        log.warning("recording %s: its calibration in %s is not one (%s): recovered without it",
                    rid, META_FILE, exc)
        return None


def _interrupted_text(kept: int, dropped: int) -> str:
    text = (f"the daemon stopped without finishing the recording (killed, or the power was cut); the {kept} "
            f"whole frames written before were recovered when it started again")
    if dropped:
        text += f"; {dropped} frame(s) being written then were incomplete and not kept"
    return text


def recover(root: Path, folder: Path, rid: str) -> Recovered:
    """Keep the whole frames of the interrupted recording in ``folder`` (``.incoming-<rid>``) and publish it.

    Blocks (reads every line and stats every frame file once). Raises OSError when the
    folder cannot be read or written; it is then left as it is, for a later start.
    """
    start, finished = _start_doc(folder)
    if finished:
        os.rename(folder, root / rid)
        fsync_dir(root)
        return Recovered(rid, int(start["frames"]), 0, _number(start.get("duration_s")) or 0.0, True)
    synced = start.get("synced_frames")
    stats, dropped = _keep_whole_frames(folder, synced if isinstance(synced, int) else 0)
    if not stats.frames:
        remove_tree(folder)
        return Recovered(rid, 0, dropped, 0.0, False)

    def given(key: str, ok: Callable[[Any], bool]) -> Any:
        value = start.get(key)
        return value if ok(value) else None

    size = given("frame_size", lambda v: isinstance(v, list) and len(v) == 2
                 and all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in v))
    created = given("created", lambda v: isinstance(v, str))
    fps_hint = _number(start.get("fps_hint"))
    doc = stats.doc(
        rid=rid, created=created or created_from_id(rid), seconds=_number(start.get("seconds")),
        frame_size=size or _png_size(folder, frame_names(0)[0]) or [0, 0],
        calibration=_first_calibration(start.get("calibration"), rid), fps_hint=fps_hint,
        end="interrupted", end_text=_interrupted_text(stats.frames, dropped), duplicates=None, skipped=None,
        meta=given("meta", lambda v: isinstance(v, dict)) or {})
    data = meta_dumps(doc)
    try:
        rewrite_meta(folder / META_FILE, data, final=True)
    except OSError as exc:
        if exc.errno not in (errno.ENOENT, errno.ELOOP):
            raise
        with contextlib.suppress(FileNotFoundError):
            os.unlink(folder / META_FILE)  # a symbolic link in its place: not ours
        create_file(folder / META_FILE, data)
        sync_file(folder, META_FILE)
    fsync_dir(folder)
    os.rename(folder, root / rid)
    with contextlib.suppress(OSError):
        fsync_dir(root)
    return Recovered(rid, stats.frames, dropped, doc["duration_s"], False)


def incoming_id(name: str, prefix: str) -> Optional[str]:
    """The recording id of a hidden ``<prefix><id>`` folder, None for anything else."""
    if not name.startswith(prefix):
        return None
    rid = name[len(prefix):]
    return rid if _INCOMING_ID_RE.fullmatch(rid) else None
