"""Recording: every raw stereo pair the pipeline copies, queued, encoded in parallel and written in order.

The frame-path half of recordings: :class:`Recorder` holds the pipeline's raw pairs and
every frame while a :class:`Recording` runs, and :class:`RecordingPlayer` plays one back
through the virtual camera. What is stored, and how it is listed, read, zipped and
deleted, is :mod:`..stores.recordings`.

Keeping up. Encoding PNGs is nearly all a recording's work (writing and syncing the files
is a few per cent of it), so a recording encodes on :data:`ENCODERS` threads of its own
(OpenCV's encoder runs without the GIL) at :data:`..stores.capture_images.FAST_PNG`, while
its writer thread writes the encoded frames in order as they come. The frames are written
while recording: what a stop leaves to do is the frames queued and being encoded then
(``queued`` in the listing), then one sync.
"""
from __future__ import annotations

import asyncio
import builtins
import contextlib
import json
import logging
import math
import os
import queue
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import (
    Any,
    Awaitable,
    Callable,
    ContextManager,
    Dict,
    List,
    Mapping,
    Optional,
    Protocol,
    Tuple,
)

import numpy as np

from ...overlays.spec import pixel
from ..stores.capture_images import FAST_PNG, encode_pixels
from ..stores.files import FULL_ERRNOS, fsync_dir, iso_utc, mb, meta_dumps, remove_tree, utcnow
from ..stores.frame_calibration import FrameCalibration
from ..stores.recording_files import (
    FORMAT,
    FRAMES_FILE,
    META_FILE,
    META_RESERVE,
    STOP_REASONS,
    SYNC_FRAMES,
    SYNC_S,
    FramesFile,
    FrameStats,
    create_file,
    frame_names,
    reserve_meta,
    rewrite_meta,
    sync_file,
    sync_folder,
)
from ..stores.recordings import (
    RecordingBusy,
    RecordingDiskFull,
    RecordingError,
    RecordingInfo,
    RecordingStore,
)
from .pipeline import COUNT_MOD, FrameSet

log = logging.getLogger(__name__)

__all__ = ["Recorder", "Recording", "RecordingPlayer", "FrameSource", "MAX_SECONDS", "ENCODERS",
           "encode_pair"]

MAX_SECONDS = 24 * 3600.0
SLACK_BYTES = 64 * 1024  # per frame: folder entries, inodes, its line of frames.jsonl
PNG_SHARE = 0.75  # a PNG of camera frames, of the uncompressed RGB: what a start reckons with
QUEUE_BYTES = 64 << 20  # frames waiting for the writer, at most (then they are skipped, counted)
ENCODERS = max(1, min(2, os.cpu_count() or 1))  # threads encoding a recording's frames (the board: 2 cores)

# One camera's encoded frame: its color ("gray"|"rgb"), its PNG, its Y plane's PNG (None: not needed).
Encoded = Tuple[str, bytes, Optional[bytes]]
# A frame handed to the encoders: the frame, its calibration, its two cameras to come.
Taken = Tuple[FrameSet, Optional[FrameCalibration], "Future[Tuple[Encoded, Encoded]]"]


def encode_pair(raw: np.ndarray) -> Tuple[Encoded, Encoded]:
    """Both cameras of a raw ``(H, W, 8)`` stream frame as a recording stores them (an encoder thread)."""
    return (encode_pixels("the left frame", raw[..., pixel.LEFT], FAST_PNG),
            encode_pixels("the right frame", raw[..., pixel.RIGHT], FAST_PNG))


# -- recording ------------------------------------------------------------------------------------------

class FrameSource(Protocol):
    """What a recording needs from the pipeline (:class:`.pipeline.Pipeline` is one)."""

    def raw_wanted(self) -> ContextManager[None]: ...

    def every_frame(self, sink: Callable[[FrameSet], None]) -> ContextManager[None]: ...


class Recording:
    """One recording in progress: fed by :meth:`offer` (pipeline thread), encoded and written by its threads.

    Made by :meth:`Recorder.start`. ``seconds`` None records until :meth:`stop`.
    Frames grabbed before ``started`` (monotonic) are not taken; with ``seconds``,
    neither are frames grabbed ``seconds`` or more after it (the recording then ends
    by itself, with or without frames coming). :meth:`join` waits for the end and
    returns the :class:`RecordingInfo` (None when nothing was kept: ``error`` says why).
    """

    def __init__(self, store: RecordingStore, rid: str, folder: Path, *, seconds: Optional[float],
                 frame_size: Tuple[int, int], meta: Mapping[str, Any],
                 calibration_for: Callable[[int], Optional[FrameCalibration]],
                 on_end: Callable[["Recording"], None], started: float, fps_hint: Optional[float],
                 raw_stores: int = 3, encoders: int = ENCODERS,
                 encode: Callable[[np.ndarray], Tuple[Encoded, Encoded]] = encode_pair) -> None:
        self.store = store
        self.id = rid
        self.folder = folder
        self.seconds = seconds
        self.frame_size = frame_size
        self.meta = dict(meta)
        self.started = started
        self.deadline = None if seconds is None else started + seconds
        self.fps_hint = fps_hint
        self.raw_stores = raw_stores
        self._calibration_for = calibration_for
        self._on_end = on_end
        w, h = frame_size
        # Frames taken, oldest first, each handed to the encoders as it came: written in this order.
        self._queue: "queue.Queue[Taken]" = queue.Queue(max(2, QUEUE_BYTES // max(1, w * h * 8)))
        self.encoders = max(1, int(encoders))
        self._encode = encode
        # Threads are started by the first frames (lazily), and ended with the writer thread.
        self._pool = ThreadPoolExecutor(self.encoders, thread_name_prefix=f"stereocam-encode-{rid}")
        self._taking = threading.Lock()  # offer's taking a frame, and the writer's last look at the queue
        self._held = 0  # 1 while the writer waits for a frame's encoding or writes it
        self._stop = threading.Event()
        self._accepting = True
        self._done = threading.Event()
        self.created = iso_utc(utcnow())
        self.end: Optional[str] = None
        self.end_text: Optional[str] = None
        self.error: Optional[str] = None  # why nothing was kept, or why it is not listed yet
        self.info: Optional[RecordingInfo] = None
        # Counters (written by the writer thread, read anywhere).
        self.skipped = 0
        self.duplicates = 0
        self._stats = FrameStats()
        self._last: Optional[FrameSet] = None  # the last frame taken for encoding
        self._t0: Optional[float] = None  # the first frame's monotonic time
        self._first_calibration: Optional[FrameCalibration] = None  # None: the first frame's was not known
        self._lines: Optional[FramesFile] = None
        self._unsynced = 0
        self._synced = 0  # frames known to be on the disk (recording.json says so, for a recovery)
        self._synced_at = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"stereocam-recording-{rid}", daemon=True)

    @property
    def frames(self) -> int:
        """Frames written so far (each whole: its images and its line)."""
        return self._stats.frames

    @property
    def bytes(self) -> int:
        return self._stats.bytes

    @property
    def missed(self) -> int:
        """FRAME_COUNT values from the first frame to the last with no frame recorded."""
        return self._stats.missed

    @property
    def queued(self) -> int:
        """Frames taken but not written yet: waiting for an encoder, being encoded, or being written."""
        return self._queue.qsize() + self._held

    # -- any thread --------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return not self._done.is_set()

    def stop(self, reason: str = "stopped") -> None:
        """Ask the recording to end (idempotent); frames already queued are still written."""
        if reason not in STOP_REASONS:
            raise ValueError(f"reason must be one of {', '.join(STOP_REASONS)}, got {reason!r}")
        self._end(reason, None)

    def join(self, timeout: Optional[float] = None) -> Optional[RecordingInfo]:
        """Wait (at most ``timeout`` s) until the recording is published or removed; its info (blocks)."""
        self._done.wait(timeout)
        return self.info

    def to_json(self) -> Dict[str, Any]:
        """The listing entry while it runs: ``state`` ``recording``, then ``finishing`` (no more frames
        taken, the ``queued`` ones being written) until it is done."""
        stats = self._stats
        first = stats.first
        fps = stats.fps(self.fps_hint)
        entry = RecordingInfo(
            id=self.id, created=self.created, state="recording" if self._accepting else "finishing",
            frames=stats.frames, seconds=self.seconds, duration_s=round(stats.duration(fps), 3),
            fps=None if fps is None else round(fps, 3), frame_size=list(self.frame_size),
            source=first["source"] if first is not None else None,
            calibration_id=stats.calibration_ids[0] if stats.calibration_ids else None, bytes=stats.bytes,
            end=self.end, complete=None, end_text=self.end_text,
        ).to_json()
        entry["queued"] = self.queued
        return entry

    # -- files (Recorder.start, then the writer thread) ----------------------------------------------------
    def _doc(self, **finished: Any) -> "builtins.bytes":  # (``bytes`` here is the property above)
        """recording.json: at the start what is known then (``state`` ``recording``); finished, all of it."""
        first = self._first_calibration
        if finished:
            return meta_dumps(self._stats.doc(
                rid=self.id, created=self.created, seconds=self.seconds, frame_size=list(self.frame_size),
                calibration=first, fps_hint=self.fps_hint, meta=self.meta, **finished))
        return meta_dumps({
            "format": FORMAT, "state": "recording", "id": self.id, "created": self.created,
            "seconds": self.seconds, "frame_size": list(self.frame_size), "fps_hint": self.fps_hint,
            "calibration": None if first is None else first.to_json(), "frames_file": FRAMES_FILE,
            "meta": self.meta, "synced_frames": self._synced})

    def begin(self) -> None:
        """Create ``recording.json`` (with the room finishing needs) and ``frames.jsonl`` (blocks).

        OSError when they cannot be written (ENOSPC: the disk is full); the caller removes the folder.
        """
        reserve_meta(self.folder / META_FILE, self._doc())
        self._lines = FramesFile(self.folder / FRAMES_FILE)
        fsync_dir(self.folder)

    def close_files(self) -> None:
        if self._lines is not None:
            self._lines.close()
        self._pool.shutdown(wait=False, cancel_futures=True)  # a start that failed: nothing to encode

    # -- pipeline thread -------------------------------------------------------------------------------
    def offer(self, fs: FrameSet) -> None:
        """Take ``fs`` if it belongs to the recording: to the encoders at once, queued for the writer.

        Never blocks (pipeline thread): with :data:`QUEUE_BYTES` of frames taken and not written
        yet, a frame is skipped (counted) instead.
        """
        with self._taking:
            if not self._accepting or fs.monotonic < self.started:
                return
            if self.deadline is not None and fs.monotonic >= self.deadline:
                self._end("duration", None)
                return
            if fs.raw is None:
                return  # the raw channel had no frame (a fault): nothing to record for this one
            if self._duplicate(fs):
                return
            if self._queue.full():
                self.skipped += 1
                return
            calibration = self._calibration_for(fs.fabric_count)
            self._queue.put_nowait((fs, calibration, self._pool.submit(self._encode, fs.raw)))
            self._last = fs

    # -- the writer thread -----------------------------------------------------------------------------
    def _end(self, reason: str, text: Optional[str]) -> None:
        if self.end is None:
            self.end, self.end_text = reason, text
        self._accepting = False
        self._stop.set()

    def _full(self, exc: Optional[OSError] = None) -> None:
        why = f" ({exc.strerror or 'no space left'})" if exc is not None else ""
        kept = f", and {mb(self.store.min_free_bytes)} kept free" if exc is None else ""
        self._end("disk_full", f"the disk filled after {self.frames} frames{why}: they were kept{kept}; "
                               f"delete old recordings or captures to make room")

    def start_writing(self) -> None:
        """Start the writer thread (once, after :meth:`begin`)."""
        self._thread.start()

    def _run(self) -> None:
        """Write each frame taken, in order, as soon as it is encoded.

        Ends when the recording is asked to and every frame taken is written: the queue
        drains first (what a stop leaves is in :attr:`queued`).
        """
        try:
            while True:
                try:
                    fs, calibration, encoded = self._queue.get(timeout=0.05)
                    self._held = 1
                except queue.Empty:
                    if self._stop.is_set():
                        with self._taking:  # no frame is being taken now, and none will be after this
                            if self._queue.empty():
                                self._accepting = False
                                break
                        continue
                    if self.deadline is not None and time.monotonic() >= self.deadline + 1.0:
                        self._end("duration", None)  # no frame came after the end: end anyway
                    self._sync(idle=True)
                    continue
                pair = encoded.result()  # the oldest: frames are written in the order they came
                written = self._write(fs, calibration, pair)
                self._held = 0
                if not written or not self._sync(idle=False):
                    break
        except Exception as exc:
            log.exception("recording %s failed", self.id)
            self._end("error", f"the recording failed: {exc}")
        finally:
            self._held = 0
            with self._taking:
                self._accepting = False
            with contextlib.suppress(queue.Empty):
                while True:  # frames taken before an early end (the disk full, an error): not kept
                    self._queue.get_nowait()[2].cancel()
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._finish()

    def _duplicate(self, fs: FrameSet) -> bool:
        """True (counted) when ``fs`` carries the raw pair of the frame taken before it."""
        last = self._last
        if (last is not None and fs.raw_store is not None and fs.raw_store == last.raw_store
                and (fs.fabric_count - last.fabric_count) % COUNT_MOD < self.raw_stores):
            self.duplicates += 1  # the raw frame recorded with the frame before
            return True
        return False

    def _sync(self, *, idle: bool) -> bool:
        """Sync the frames written since the last sync, when a batch is due; False when the disk failed."""
        due = time.monotonic() - self._synced_at >= SYNC_S
        if not self._unsynced or not (due or (not idle and self._unsynced >= SYNC_FRAMES)):
            return True
        try:
            sync_folder(self.folder)
        except OSError as exc:
            if exc.errno in FULL_ERRNOS:
                self._full(exc)
            else:
                self._end("error", f"syncing the recording failed after {self.frames} frames "
                                   f"({exc.strerror or exc}): they were kept")
            return False
        self._unsynced, self._synced_at, self._synced = 0, time.monotonic(), self.frames
        try:  # noted in place (no new space), on the disk with the next sync: a recovery trusts these frames
            rewrite_meta(self.folder / META_FILE, self._doc(), final=False, sync=False)
        except OSError as exc:
            log.warning("recording %s: cannot note the frames synced in %s (%s)", self.id, META_FILE,
                        exc.strerror or exc)
        return True

    def _write(self, fs: FrameSet, calibration: Optional[FrameCalibration],
               pair: Tuple[Encoded, Encoded]) -> bool:
        """Write one encoded frame, whole or not at all; False when the recording must end (disk full)."""
        index = self.frames
        names = frame_names(index)
        files: List[Tuple[str, bytes]] = []
        entry: Dict[str, Any] = {}
        for side, name, (_, png, y_png) in (("left", names[0], pair[0]), ("right", names[1], pair[1])):
            files.append((name, png))
            entry[side], entry[f"{side}_y"] = name, None
            if y_png is not None:
                entry[f"{side}_y"] = f"y_{name}"
                files.append((f"y_{name}", y_png))
        color = "gray" if pair[0][0] == pair[1][0] == "gray" else "rgb"
        need = sum(len(d) for _, d in files) + SLACK_BYTES
        if not self.store.has_room(need):
            self._full()
            return False
        t0 = fs.monotonic if self._t0 is None else self._t0
        line = {"index": index, "frame": fs.frame, "fabric_count": fs.fabric_count, "time": fs.timestamp,
                "t": round(fs.monotonic - t0, 6), "source": fs.source,
                "calibration_id": calibration.id if calibration else None,
                **entry, "color": color, "bytes": sum(len(d) for _, d in files)}
        written: List[Path] = []
        try:
            for name, data in files:
                written.append(self.folder / name)
                create_file(self.folder / name, data)
            assert self._lines is not None
            self._lines.append((json.dumps(line) + "\n").encode("utf-8"))
        except OSError as exc:
            for path in written:
                with contextlib.suppress(OSError):
                    path.unlink()
            if exc.errno in FULL_ERRNOS:
                self._full(exc)
                return False
            raise
        if self._t0 is None:
            self._t0 = fs.monotonic
            self._first_calibration = calibration
            try:  # the start as a recovery after a crash needs it; the end writes it anyway
                rewrite_meta(self.folder / META_FILE, self._doc(), final=False)
            except OSError as exc:
                log.warning("recording %s: cannot note its calibration in %s (%s)", self.id, META_FILE,
                            exc.strerror or exc)
        self._stats.add(line)
        self._unsynced += 1
        return True

    def _finish(self) -> None:
        """Sync and publish the folder (keeping every frame written), or remove it when no frame was."""
        try:
            self.close_files()
            if self.frames == 0:
                why = {"disk_full": "the disk is full", "error": self.end_text or "it failed"}.get(
                    self.end or "", "no frame came")
                self.error = f"nothing was recorded: {why}"
                remove_tree(self.folder)
                return
            end = self.end or "stopped"
            doc = self._doc(end=end, end_text=self.end_text, duplicates=self.duplicates, skipped=self.skipped)
            rewrite_meta(self.folder / META_FILE, doc, final=True, sync=False)  # in the room reserved
            try:
                sync_folder(self.folder)
                sync_file(self.folder, META_FILE)
                fsync_dir(self.folder)
            except OSError as exc:  # written whole (in the page cache): keep the frames, publish, say so
                log.warning("recording %s: syncing its files failed (%s); they are kept and listed, but a "
                            "power cut before the system writes them could still lose them", self.id,
                            exc.strerror or exc)
            self.store.publish(self.folder, self.id)
            self.info = self.store.get(self.id)
            log.info("recording %s: %d frames, %.1f s (%s)", self.id, self.frames,
                     self._stats.duration(self._stats.fps(self.fps_hint)), end)
        except Exception as exc:
            full = isinstance(exc, OSError) and exc.errno in FULL_ERRNOS
            why = "the disk is full" if full else f"{exc}"
            self.error = (f"recording {self.id} could not be finished ({why}): its {self.frames} frames are "
                          f"kept and will be listed when the daemon starts again")
            log.error("%s", self.error)
        finally:
            self._on_end(self)
            self._done.set()


class Recorder:
    """At most one :class:`Recording` at a time, fed by ``pipeline`` (loop thread for start/stop).

    While a recording runs it holds ``pipeline.raw_wanted()`` and
    ``pipeline.every_frame(recording.offer)``: every frame is copied with its raw pair
    and handed to it; both are released when it ends. Each recording encodes on ``encoders``
    threads with ``encode`` (:func:`encode_pair`; tests pass their own).
    """

    def __init__(self, store: RecordingStore, pipeline: FrameSource, *,
                 calibration_for: Callable[[int], Optional[FrameCalibration]] = lambda count: None,
                 raw_stores: int = 3, encoders: int = ENCODERS,
                 encode: Callable[[np.ndarray], Tuple[Encoded, Encoded]] = encode_pair) -> None:
        self.store = store
        self.raw_stores = raw_stores  # frame stores of the raw channel (duplicates: see Recording)
        self.encoders, self.encode = encoders, encode
        self.pipeline = pipeline
        self.calibration_for = calibration_for
        self._lock = threading.Lock()
        self.current: Optional[Recording] = None
        self._holds: Optional[contextlib.ExitStack] = None
        self.last: Optional[Recording] = None

    def start(self, *, seconds: Optional[float], frame_size: Tuple[int, int], fps: Optional[float],
              frame_no: int, meta: Optional[Mapping[str, Any]] = None) -> Recording:
        """Begin recording from now (blocks briefly: a folder is made).

        ``seconds`` None records until :meth:`stop`. ``fps`` (the cameras' rate now) and
        ``frame_size`` size the disk check: :class:`RecordingDiskFull` when the
        recording asked for (or, without ``seconds``, one second of it) would not leave
        ``min_free_bytes``; :class:`RecordingBusy` while another runs. Nothing is
        created when it is refused.
        """
        if seconds is not None and not (0 < seconds <= MAX_SECONDS and math.isfinite(seconds)):
            raise ValueError(f"seconds must be in (0, {MAX_SECONDS:g}], got {seconds!r}")
        w, h = frame_size
        rate = fps if fps and fps > 0 else 60.0
        per_frame = int(w * h * 6 * PNG_SHARE) + SLACK_BYTES
        need = int(math.ceil((seconds if seconds is not None else 1.0) * rate)) * per_frame + META_RESERVE
        with self._lock:
            running = self.current
            if running is not None and running.running:
                raise RecordingBusy(f"recording {running.id} is running: stop it first "
                                    f"(POST /api/recordings/{running.id}/stop) or wait for it to end")
            try:
                fits = self.store.has_room(need)
                room = self.store.room()
            except OSError as exc:
                raise RecordingError(f"cannot check the free space in {self.store.root} "
                                     f"({exc.strerror or exc}); nothing was recorded") from exc
            if not fits:
                what = f"{seconds:g} s" if seconds is not None else "a recording (1 s at least)"
                raise RecordingDiskFull(
                    f"not enough free space for {what} at {rate:.0f} fps in {self.store.root}: it needs "
                    f"about {mb(need)}, {mb(max(0, room + self.store.min_free_bytes))} are free and "
                    f"{mb(self.store.min_free_bytes)} are kept free; record fewer seconds or delete old "
                    f"recordings or captures")
            rid, folder = self.store.reserve(frame_no)
            rec = Recording(self.store, rid, folder, seconds=seconds, frame_size=(int(w), int(h)),
                            meta=meta or {}, calibration_for=self.calibration_for, on_end=self._ended,
                            started=time.monotonic(), fps_hint=fps, raw_stores=self.raw_stores,
                            encoders=self.encoders, encode=self.encode)
            try:
                rec.begin()
            except OSError as exc:
                rec.close_files()
                remove_tree(folder)
                why = exc.strerror or exc
                if exc.errno in FULL_ERRNOS:
                    raise RecordingDiskFull(f"the disk of {self.store.root} is full ({why}): nothing was "
                                            f"recorded; delete old recordings or captures") from exc
                raise RecordingError(f"cannot start a recording in {self.store.root} ({why}): nothing was "
                                     f"recorded") from exc
            holds = contextlib.ExitStack()
            try:
                holds.enter_context(self.pipeline.raw_wanted())
                holds.enter_context(self.pipeline.every_frame(rec.offer))
                rec.start_writing()
            except BaseException:
                holds.close()
                rec.close_files()
                remove_tree(folder)
                raise
            self.current, self._holds = rec, holds
        log.info("recording %s started (%s)", rid,
                 f"{seconds:g} s" if seconds is not None else "until stopped")
        return rec

    def _ended(self, rec: Recording) -> None:
        """The writer thread finished ``rec``: let the pipeline copy only what others need again."""
        with self._lock:
            holds = self._holds if self.current is rec else None
            if self.current is rec:
                self._holds = None
                self.current, self.last = None, rec
        if holds is not None:
            holds.close()

    def get(self, rid: str) -> Optional[Recording]:
        """The recording ``rid`` if it is the one running (or finishing)."""
        rec = self.current
        return rec if rec is not None and rec.id == rid else None

    def stop_all(self, reason: str = "shutdown", timeout: float = 30.0) -> None:
        """End the running recording, if any, and wait for it to be written (blocks)."""
        rec = self.current
        if rec is not None:
            rec.stop(reason)
            rec.join(timeout)


# -- playing a recording through the virtual camera ---------------------------------------------------

class RecordingPlayer:
    """Plays a recording's frames one after the other at its rate, looping, until :meth:`stop` (loop thread).

    ``source`` is the recording read back, a :class:`stereocam.overlays.interface.Replay` (its
    ``frame(k)``, ``slots``, ``fps``, ``duration_s``); ``read(k)`` decodes frame ``k`` off the
    loop; ``show(frame)`` puts one frame on the virtual camera and returns once the fabric
    took it. Frame 0 is already shown when :meth:`start` is called. Frame ``k`` is due
    ``slots[k] / fps`` s after frame 0 (so missed frames keep their gap), each loop
    ``duration_s`` after the one before; the next frame is decoded while one is shown.
    Late by more than a frame period (a slow fabric or decoder), the schedule moves on
    from now: every frame is shown once per loop, none is skipped. An error reading or
    showing a frame ends the playing (``error`` says why); the last frame stays on.
    """

    def __init__(self, rid: str, source: Any, *, read: Callable[[int], Awaitable[np.ndarray]],
                 show: Callable[[np.ndarray], Awaitable[None]]) -> None:
        self.id = rid
        self.source = source
        self._read = read
        self._show = show
        self.frames = len(source)
        self.fps = float(source.fps)
        self.position = 0  # the frame shown now
        self.loops = 0
        self.shown = 1
        self.error: Optional[str] = None
        self._stop: Optional[asyncio.Event] = None
        self._task: "Optional[asyncio.Task[None]]" = None

    def to_json(self) -> Dict[str, Any]:
        return {"recording": self.id, "frame": self.position, "frames": self.frames,
                "fps": round(self.fps, 3), "loops": self.loops, "shown": self.shown, "running": self.running,
                "error": self.error}

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def start(self) -> None:
        if self._task is None and self.frames > 1:
            self._stop = asyncio.Event()
            self._task = asyncio.get_running_loop().create_task(self._run(), name=f"stereocam-play-{self.id}")

    async def stop(self) -> None:
        """End the playing and wait for the frame being shown (idempotent)."""
        if self._stop is not None:
            self._stop.set()
        task = self._task
        if task is not None and task is not asyncio.current_task():
            await asyncio.gather(task, return_exceptions=True)
        self.source.close()

    async def _run(self) -> None:
        assert self._stop is not None
        loop = asyncio.get_running_loop()
        slots, period_s = self.source.slots, 1.0 / self.fps
        length = (slots[-1] + 1) * period_s
        start = loop.time()
        k = 1
        pending: "asyncio.Future[np.ndarray]" = asyncio.ensure_future(self._read(k))
        try:
            while not self._stop.is_set():
                due = start + self.loops * length + slots[k] * period_s
                delay = due - loop.time()
                if delay > 0:
                    with contextlib.suppress(asyncio.TimeoutError):
                        await asyncio.wait_for(self._stop.wait(), delay)
                    if self._stop.is_set():
                        break
                elif delay < -period_s:
                    start -= delay  # late: go on from now rather than rush through frames
                frame = await pending
                await self._show(frame)
                self.position, self.shown = k, self.shown + 1
                k += 1
                if k == self.frames:
                    k, self.loops = 0, self.loops + 1
                pending = asyncio.ensure_future(self._read(k))
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            self.error = f"playing recording {self.id} stopped at frame {k}: {exc}"
            log.warning("%s", self.error)
        finally:
            if not pending.done():
                pending.cancel()
            await asyncio.gather(pending, return_exceptions=True)
