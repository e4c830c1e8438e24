"""Recordings: every raw stereo pair of N seconds (or until stopped), lossless, one folder each.

A recording is a folder ``<root>/<id>/`` holding

    left_000000.png  right_000000.png   the raw pair of each frame, as the demosaic delivered it
    left_000001.png  right_000001.png   (numbered from 0 in recorded order; 6 digits, more past 999999)
    ...
    frames.jsonl                        one JSON object per frame, in order (below)
    recording.json                      what was recorded (below); written last

Pixels are stored as captures store them (:mod:`.captures`): an 8-bit gray PNG
for a gray camera, RGB otherwise; Y goes to ``y_left_000000.png`` only where it
is not :func:`...overlays.spec.pixel.gray_of` of RGB (never for live raw frames),
so every frame comes back bit for bit. Recordings are encoded faster than captures
(:data:`.capture_images.FAST_PNG`: deflate level 1, the Paeth filter, run-length
matches), which for camera frames is also smaller; any PNG reader reads both, so a
recording made before (level 3) lists, replays and downloads the same. The pairs are named so any tool that
pairs ``left*``/``right*`` files reads them; the emulated cameras' replay
(``stereocam serve --source FOLDER``) recognises ``recording.json`` and replays
the frames in order at the recording's rate, and the virtual camera plays them
through the core (``POST /api/virtual-camera {"recording": id}``).

``frames.jsonl``: ``index`` (0, 1, ...), ``frame`` (the daemon's frame number),
``fabric_count`` (the core's FRAME_COUNT of that frame: consecutive unless the
pipeline missed frames), ``time`` (capture time, seconds since the epoch),
``t`` (seconds since the first frame), ``source`` (``live``|``virtual``),
``calibration_id`` (the calibration the frame ran with, None when a change was
being programmed), ``left``, ``right`` (file names), ``left_y``, ``right_y``
(None or the Y file), ``color`` (``gray``|``rgb``), ``bytes``.

A raw pair that comes twice (the raw channel can complete the next frame before
the core finishes this one, so two frame sets in a row may carry the same raw
store) is recorded once and counted in ``duplicates``.

``recording.json``: ``format`` (``stereocam-recording/1``), ``id``, ``created``,
``time_utc`` (of the first frame), ``seconds`` (asked; None: until stopped),
``duration_s``, ``frames``, ``fps`` (the cameras' rate while recording, from
FRAME_COUNT over time), ``frame_size``, ``source`` and ``calibration_id`` (of the
first frame; ``sources``/``calibration_ids`` every one seen), ``calibration`` (the
first frame's :class:`.frame_calibration.FrameCalibration`, as captures store it),
``backend``, ``end`` (``duration``, ``stopped``, ``disk_full``, ``shutdown``,
``error``, ``interrupted``), ``complete`` (false when it ended before the seconds
asked: the disk filled, the daemon stopped, failed or was killed), ``end_text``,
``missed`` (FRAME_COUNT values between the first and the last frame with no frame
recorded: frames the pipeline did not copy, or whose raw pair came with the next),
``duplicates``, ``skipped`` (frames copied that the writer could not keep up with;
both null for a recording recovered after a crash: not known), ``bytes``,
``frames_file``.

On disk (:mod:`.recording_files`): a recording is written into
``.incoming-<id>/`` and renamed to ``<id>`` once every file is synced and
``recording.json`` written. Frames reach the disk whole and are synced in
batches of at most a second; ``recording.json`` is created at the start with
the room finishing needs, so a disk that fills cannot keep a recording from
being finished. Frames are checked against the free space before each is
written (``min_free_bytes`` kept free, as :class:`.captures.CaptureStore`
does); the disk filling ends the recording, and a frame being written then is
removed whole. A recording with no frame is removed. A new store recovers the
recordings a crash or a power cut interrupted: their whole frames are kept
and listed (``end`` ``interrupted``), and the log says so. Nothing recorded is
ever removed but by :meth:`RecordingStore.delete`, or by
:meth:`RecordingStore.trash` (what ``DELETE /api/recordings/{id}`` does, as for
captures: the folder is renamed into the hidden ``.trash/``, from where
:meth:`RecordingStore.restore` renames it back, for :data:`.trash.TRASH_KEEP_S`;
older ones are removed at the next delete and at start-up, and every one when a
recording is short of space).

Threads: :class:`Recorder` is driven from the event loop (``start``, ``stop``)
and fed on the pipeline thread (``offer``, which never blocks); each recording
has encoder threads and a writer thread of its own (:mod:`..frames.recorder`).
:class:`RecordingStore` methods block and are thread-safe.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import (
    Any,
    Callable,
    Dict,
    List,
    Mapping,
    Optional,
    Tuple,
)

from .errors import Conflict, Damaged, DiskFull, InvalidId, NotFound, StoreError
from .files import iso_utc, read_member, remove_tree
from .folder_store import DELETING_PREFIX, INCOMING_PREFIX, FolderStore
from .recording_files import (
    ENDS,
    FORMAT,
    FRAMES_FILE,
    META_FILE,
    frame_names,
    incoming_id,
    read_meta,
    recover,
)

log = logging.getLogger(__name__)

__all__ = [
    "RecordingStore", "RecordingInfo", "RecordingError", "RecordingNotFound",
    "InvalidRecordingId", "RecordingDiskFull", "RecordingBusy", "FORMAT", "META_FILE", "FRAMES_FILE",
    "frame_names", "ENDS",
]



# -- errors: the stores' one tree (:mod:`.store_errors`), by the names callers know ------------------

RecordingError = StoreError
InvalidRecordingId = InvalidId
RecordingNotFound = NotFound
RecordingBusy = Conflict  # another recording runs, or the recording is in use
RecordingDiskFull = DiskFull  # not enough free space to start; nothing was created


# -- what the store reports ---------------------------------------------------------------------------

@dataclass(frozen=True)
class RecordingInfo:
    """One recording as listed: finished (``state`` ``done``) or being recorded (``recording``).

    ``error`` is None unless a finished recording's folder is damaged (recording.json
    unreadable, a frame file missing).
    """

    id: str
    created: str
    state: str
    frames: int
    seconds: Optional[float]
    duration_s: float
    fps: Optional[float]
    frame_size: Optional[List[int]]
    source: Optional[str]
    calibration_id: Optional[str]
    bytes: int
    end: Optional[str]
    complete: Optional[bool]
    end_text: Optional[str]
    error: Optional[str] = None
    meta: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def to_json(self, *, meta: bool = False) -> Dict[str, Any]:
        out: Dict[str, Any] = {
            "id": self.id, "created": self.created, "state": self.state, "frames": self.frames,
            "seconds": self.seconds, "duration_s": self.duration_s, "fps": self.fps,
            "frame_size": self.frame_size, "source": self.source, "calibration_id": self.calibration_id,
            "bytes": self.bytes, "end": self.end, "complete": self.complete, "end_text": self.end_text,
            "error": self.error,
        }
        if meta:
            out["meta"] = dict(self.meta)
        return out


# -- the store ------------------------------------------------------------------------------------------

class RecordingStore(FolderStore[RecordingInfo]):
    """The recordings folder ``root``: reserve, publish, list, zip, delete (a folder store).

    ``min_free_bytes`` is kept free on its filesystem (a recording stops before it
    would take it). Ids are capture-style (``20261122T040512Z-000123-ab12``: UTC
    second, first frame number, 4 random hex digits) and checked before any path is
    built from them; symbolic links are never followed. Made once per daemon: it
    recovers what a crash or a power cut left being recorded (see :meth:`recover_interrupted`).
    """

    noun = "recording"
    folder_name = "the recordings folder"

    def __init__(self, root: "str | Path", *, min_free_bytes: int = 0,
                 clock: Optional[Callable[[], datetime]] = None) -> None:
        super().__init__(root, min_free_bytes=min_free_bytes, clock=clock)
        self.recover_interrupted()
        self.purge_trash()

    def has_room(self, need: int) -> bool:
        """True when ``need`` more bytes leave ``min_free_bytes`` free (blocks; OSError if unknown).

        Short of space, recordings waiting in the trash for an undo give theirs first, as
        captures' do: a recording is worth more than an undo.
        """
        if self.room() >= need:
            return True
        return self.purge_trash(0.0) > 0 and self.room() >= need

    @staticmethod
    def _shown_id(ident: object) -> str:
        text = ident if isinstance(ident, str) else repr(ident)
        return repr(text if len(text) <= 40 else text[:40] + "...")

    def recover_interrupted(self) -> None:
        """Publish the whole frames of every recording a crash interrupted; finish deletes a crash cut short.

        Blocks (each interrupted recording's frames file is read once). Every recovery is
        logged; a folder that cannot be recovered now (the disk, its permissions) is left for
        the next start, never removed.
        """
        with os.scandir(self.root) as entries:
            hidden = [(e.name, e.is_dir(follow_symlinks=False)) for e in entries if e.name.startswith(".")]
        for name, is_dir in hidden:
            path = self.root / name
            rid = incoming_id(name, INCOMING_PREFIX)
            if rid is None or not is_dir:
                if name.startswith((INCOMING_PREFIX, DELETING_PREFIX)):
                    remove_tree(path)  # a delete a crash cut short, or nothing a recorder made
                continue
            if os.path.lexists(self.root / rid):
                log.error("recording %s: both %s and a recording of that id exist; %s is left as it is",
                          rid, name, name)
                continue
            try:
                done = recover(self.root, path, rid)
            except OSError as exc:
                log.error("recording %s was interrupted and cannot be recovered now (%s): its folder %s "
                          "is kept for the next start; make room or check the disk", rid,
                          exc.strerror or exc, path)
                continue
            except Exception:  # a bug must not keep the daemon from starting, nor lose the frames
                log.exception("recording %s was interrupted and its recovery failed: its folder %s is kept",
                              rid, path)
                continue
            if done.finished:
                log.warning("recording %s had been finished but not published when the daemon stopped: "
                            "published (%d frames)", rid, done.frames)
            elif done.frames:
                log.warning("recording %s was interrupted (the daemon was killed or lost power while "
                            "recording): recovered its %d whole frames (%.1f s)%s; listed with end "
                            "'interrupted'", rid, done.frames, done.duration_s,
                            f", {done.dropped} incomplete frame(s) after them were not kept" if done.dropped
                            else "")
            else:
                log.warning("recording %s was interrupted before a whole frame was written: nothing to keep",
                            rid)

    def _info(self, rid: str, folder: Path) -> RecordingInfo:
        sizes: Dict[str, int] = {}
        links = set()
        try:
            with os.scandir(folder) as entries:
                for entry in entries:
                    if entry.is_symlink():
                        links.add(entry.name)
                    elif entry.is_file(follow_symlinks=False):
                        sizes[entry.name] = entry.stat(follow_symlinks=False).st_size
        except (FileNotFoundError, NotADirectoryError):
            raise self.not_found(rid) from None
        doc: Dict[str, Any] = {}
        problems: List[str] = []
        try:
            doc = read_meta(folder)
        except FileNotFoundError:
            problems.append(f"{META_FILE} is missing")
        except (OSError, ValueError) as exc:
            why = "a symbolic link, not a file" if META_FILE in links else "damaged"
            problems.append(f"{META_FILE} is {why} ({' '.join(str(exc).split())[:80]})")
        count = doc.get("frames")
        frames = count if isinstance(count, int) and not isinstance(count, bool) else 0
        for i in range(frames):
            missing = [n for n in frame_names(i) if n not in sizes]
            if missing:
                why = "a symbolic link, not a file" if missing[0] in links else "missing"
                problems.append(f"{missing[0]} is {why}")
                break
        stamp = doc.get("created")
        created = stamp if isinstance(stamp, str) else iso_utc(
            datetime.strptime(rid[:16], "%Y%m%dT%H%M%SZ").replace(tzinfo=timezone.utc))

        def num(key: str) -> Optional[float]:
            v = doc.get(key)
            return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None

        def text(key: str) -> Optional[str]:
            v = doc.get(key)
            return v if isinstance(v, str) else None

        size = doc.get("frame_size")
        complete = doc.get("complete")
        return RecordingInfo(
            id=rid, created=created, state="done", frames=frames, seconds=num("seconds"),
            duration_s=num("duration_s") or 0.0, fps=num("fps"),
            frame_size=list(size) if isinstance(size, list) else None, source=text("source"),
            calibration_id=text("calibration_id"), bytes=sum(sizes.values()), end=text("end"),
            complete=complete if isinstance(complete, bool) else None, end_text=text("end_text"),
            error="; ".join(problems) or None, meta=doc,
        )

    def frame_png(self, ident: object, index: int, side: str) -> Tuple[bytes, int]:
        """Frame ``index``'s ``side`` (``left``|``right``) PNG as stored, and the recording's frame count:
        what the capture viewer steps through. InvalidId/NotFound as :meth:`path`; NotFound for an index
        out of range (the message gives the range); Damaged when that file is missing or unreadable."""
        folder = self.path(ident)
        rid = folder.name
        try:
            count = read_meta(folder).get("frames")
        except (OSError, ValueError) as exc:
            raise Damaged(f"recording {rid} cannot be read: its {META_FILE} is missing or damaged "
                          f"({' '.join(str(exc).split())[:80]})") from None
        frames = count if isinstance(count, int) and not isinstance(count, bool) else 0
        if not 0 <= index < frames:
            raise NotFound(f"recording {rid} has no frame {index}: its frames are 0 to {frames - 1}"
                           if frames else f"recording {rid} has no frames")
        name = frame_names(index)[0 if side == "left" else 1]
        try:
            return read_member(folder, name), frames
        except FileNotFoundError:
            raise Damaged(f"recording {rid} is damaged: {name} is missing") from None
        except OSError as exc:
            raise Damaged(f"recording {rid}: cannot read {name} ({exc.strerror or exc})") from None

    def _zip_names(self, folder: Path, info: RecordingInfo) -> List[str]:
        """recording.json, frames.jsonl, then every other regular file by name."""
        with os.scandir(folder) as entries:
            names = sorted(e.name for e in entries if e.is_file(follow_symlinks=False))
        first = {META_FILE: 0, FRAMES_FILE: 1}
        names.sort(key=lambda n: (first.get(n, 2), n))
        return names
