"""Replay: recorded stereo frames from a folder, played as a live camera source.

Its recordings are frames the IP already demosaiced (captures of the
stream): they are played as they are, not mosaicked again. A stereocam
recording (``POST /api/recordings``: a folder with ``recording.json``) is
played frame by frame in order at the rate it was recorded.

Files are read without following a symbolic link (one in their place is
refused, named), and what is read is bounded: ``recording.json`` at
:data:`MAX_META_BYTES`, each ``frames.jsonl`` line at :data:`MAX_LINE_BYTES`
(the file is indexed, never held whole), an image at :data:`MAX_IMAGE_BYTES`.
"""
from __future__ import annotations

import bisect
import errno
import json
import math
import os
import stat
import threading
import weakref
from array import array
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Callable, Dict, List, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from ...calibration.image_files import (
    CAPTURE_FILES,
    IMAGE_EXTS,
    MAX_IMAGE_PIXELS,
    ImageTooLarge,
    decode_image_bytes,
    image_size,
    is_image_file,
    natural_key,
)
from ..spec.pixel import pack, rgby
from .cameras import SourceClosedError

__all__ = ["ReplayEnded", "ReplayError", "ReplaySource"]


class ReplayError(ValueError):
    """A replay folder that cannot be played: the message names the file and says what to do."""


class ReplayEnded(IndexError):
    """``read`` past the last recorded frame of a ``ReplaySource(loop=False)``."""


# A stereocam recording (server/stores/recordings.py and server/frames/recorder.py write it):
# named here, so no server import.
_RECORDING_FILE = "recording.json"
_RECORDING_FORMAT = "stereocam-recording/"
_COUNT_MOD = 1 << 32
MAX_META_BYTES = 4 << 20  # a recording.json larger than this is not a recording's
MAX_LINE_BYTES = 64 * 1024  # a frames.jsonl line is a few hundred bytes; longer is damage
MAX_IMAGE_BYTES = 4 * MAX_IMAGE_PIXELS + (1 << 20)  # the largest image decoded, uncompressed, and its header
_LINE_FILES = ("left", "right", "left_y", "right_y")  # the keys of a frames.jsonl line naming files
_SLOT_TYPE = "I" if array("I").itemsize == 4 else "L"  # 4 bytes: a FRAME_COUNT difference


def _open_regular(path: Path) -> IO[bytes]:
    """``path`` opened for reading if it is a regular file, never through a symbolic link.

    FileNotFoundError when it is missing; :class:`ReplayError` naming it when it is a link
    or not a file.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ReplayError(f"{path} is a symbolic link: a replay reads only the files in its folder; "
                              f"copy the file there instead of linking it") from None
        raise
    fh = os.fdopen(fd, "rb")
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        fh.close()
        raise ReplayError(f"{path} is not a file: replace or remove it")
    return fh


def _read_regular(path: Path, limit: int) -> bytes:
    """The bytes of the regular file ``path`` (:func:`_open_regular`); ReplayError past ``limit`` bytes."""
    with _open_regular(path) as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise ReplayError(f"{path} is larger than {limit / 2**20:g} MiB: not a recording's; replace or "
                          f"remove it")
    return data


@dataclass(frozen=True)
class _Entry:
    """One recorded stereo frame: two files, or one side-by-side file (right is None)."""

    name: str
    left: Path
    right: Optional[Path]
    left_y: Optional[Path] = None  # a recording's Y planes, where Y is not gray_of(RGB)
    right_y: Optional[Path] = None


class ReplaySource:
    """Recorded stereo frames from ``folder``, as a live :class:`.cameras.CameraSource`.

    The folder holds one kind of recording:

    - pairs ``left<suffix>.<ext>`` / ``right<suffix>.<ext>`` (png, jpg,
      bmp, tif, pgm, ppm; case-insensitive), matched by suffix, played in natural
      order of the suffix (``left2`` before ``left10``);
    - stereocam captures: subfolders each holding ``raw_left.png`` and
      ``raw_right.png``, played in natural order of the subfolder name;
    - side-by-side images ``sbs<suffix>.<ext>``, left camera in the left half;
    - a stereocam recording: ``recording.json`` and the frames ``frames.jsonl``
      lists (``left_000000.png`` / ``right_000000.png`` ...), played in order.

    Other files are ignored. Gray or colour 8-bit images (colour is RGB
    after decoding; gray fills R, G, B and Y). Frame ``index`` is recording
    ``index % len(self)`` (``loop=True``) or raises :class:`ReplayEnded`
    past the end; ``t`` is ignored, except for a stereocam recording, which
    is played at its own rate whatever the frame clock's: ``read(index, t)``
    gives the frame recorded ``t`` seconds after the first (``t * fps``
    frame periods, by the FRAME_COUNT each frame was recorded with, so a
    frame the recording missed keeps the one before on the stream), looping
    after :attr:`duration_s`; a clock at the recording's :attr:`fps` gets
    every recorded frame once per loop, in order. :meth:`frame` gives
    recorded frame ``k`` whatever the time. The folder is listed and every
    image's header checked when the source is made (a recording's first
    frame only: ``recording.json`` gives its size), so a bad folder fails at
    once with :class:`ReplayError`; pixels are decoded on first use and the
    last ``cache_size`` frames are kept. ``read`` returns a read-only array
    shared with the cache: copy it to modify it. Safe to read from several
    threads.
    """

    def __init__(self, folder: Union[str, Path], *, loop: bool = True, cache_size: int = 8) -> None:
        self.folder = Path(folder)
        self.loop = bool(loop)
        if cache_size < 1:
            raise ValueError(f"cache_size must be >= 1, got {cache_size}")
        self._cache_size = int(cache_size)
        self._cache: "OrderedDict[int, np.ndarray]" = OrderedDict()
        self._lock = threading.Lock()
        self._closed = False
        self.fps: Optional[float] = None  # a recording's frame rate; None for other folders
        self._frames: Optional[_FramesIndex] = None  # a recording's frames file, indexed
        self._entries: List[_Entry] = []  # the frames of other folders
        self._recorded_size: Optional[Tuple[int, int]] = None
        if os.path.lexists(self.folder / _RECORDING_FILE):
            self._frames = self._discover_recording()
        else:
            self._entries = self._discover()
        try:
            self._size = self._check_sizes()
        except BaseException:
            self.close()
            raise

    def _entry(self, k: int) -> _Entry:
        return self._frames.entry(k) if self._frames is not None else self._entries[k]

    # -- listing -----------------------------------------------------------

    def _discover(self) -> List[_Entry]:
        folder = self.folder
        if not folder.is_dir():
            raise ReplayError(
                f"replay folder {folder} does not exist or is not a folder: give a folder of recordings"
            )
        lefts: Dict[str, Path] = {}
        rights: Dict[str, Path] = {}
        sbs: Dict[str, Path] = {}
        captures: List[_Entry] = []
        for path in sorted(folder.iterdir()):
            if path.name.startswith("."):
                continue  # hidden: e.g. a capture still being written (.incoming-*) or deleted
            if path.is_symlink():
                if path.suffix.lower() in IMAGE_EXTS or path.is_dir():
                    raise ReplayError(f"{path} is a symbolic link: a replay reads only the files in its "
                                      f"folder; copy it there instead of linking it")
                continue
            if path.is_dir():
                for f in CAPTURE_FILES:
                    if (path / f).is_symlink():
                        raise ReplayError(f"{path / f} is a symbolic link: a replay reads only the files in "
                                          f"its folder; copy it there instead of linking it")
                present = [(path / f).is_file() for f in CAPTURE_FILES]
                if all(present):
                    captures.append(_Entry(path.name, path / CAPTURE_FILES[0], path / CAPTURE_FILES[1]))
                elif any(present):
                    have, missing = (CAPTURE_FILES if present[0] else CAPTURE_FILES[::-1])
                    raise ReplayError(
                        f"capture {path} has {have} but no {missing}: restore it or remove that folder"
                    )
                continue
            if not is_image_file(path):
                continue
            name = path.name.lower()
            stem = name[: -len(path.suffix)]
            for prefix, table in (("left", lefts), ("right", rights), ("sbs", sbs)):
                if stem.startswith(prefix):
                    key = stem[len(prefix):]
                    if key in table:
                        raise ReplayError(
                            f"{table[key].name} and {path.name} in {folder} are the same frame in two files: "
                            f"keep one"
                        )
                    table[key] = path
                    break
        found = (("left/right pairs", lefts or rights), ("side-by-side sbs* images", sbs),
                 ("capture folders", captures))
        kinds = [kind for kind, present in found if present]
        if not kinds:
            raise ReplayError(
                f"replay folder {folder} holds no recordings: put left*/right* image pairs, sbs* "
                f"side-by-side images or capture folders (raw_left.png + raw_right.png) in it"
            )
        if len(kinds) > 1:
            raise ReplayError(f"replay folder {folder} mixes {' and '.join(kinds)}: keep one kind per folder")
        if captures:
            return sorted(captures, key=lambda e: natural_key(e.name))
        if sbs:
            return [_Entry(sbs[k].name, sbs[k], None) for k in sorted(sbs, key=natural_key)]
        unmatched = sorted([p.name for k, p in lefts.items() if k not in rights]
                           + [p.name for k, p in rights.items() if k not in lefts], key=natural_key)
        if unmatched:
            more = f" and {len(unmatched) - 5} more" if len(unmatched) > 5 else ""
            shown = ", ".join(unmatched[:5]) + more
            raise ReplayError(
                f"{len(unmatched)} image(s) in {folder} have no partner: {shown}; every left<suffix> needs a "
                f"right<suffix> with the same suffix (e.g. left07.png and right07.png): rename or remove them"
            )
        return [_Entry(f"{lefts[k].name}+{rights[k].name}", lefts[k], rights[k])
                for k in sorted(lefts, key=natural_key)]

    def _discover_recording(self) -> "_FramesIndex":
        """A stereocam recording's frames from its ``recording.json`` and frames file (indexed, not held)."""
        folder = self.folder

        def bad(what: str) -> ReplayError:
            return ReplayError(f"recording {folder}: {what}; record it again or remove it")

        try:
            doc = json.loads(_read_regular(folder / _RECORDING_FILE, MAX_META_BYTES).decode("utf-8"))
        except (OSError, ValueError, RecursionError) as exc:  # ValueError: a ReplayError too
            raise bad(f"{_RECORDING_FILE} cannot be read ({exc})") from None
        if not isinstance(doc, dict) or not str(doc.get("format", "")).startswith(_RECORDING_FORMAT):
            raise bad(f"{_RECORDING_FILE} is not a stereocam recording's")
        fps, size, count = doc.get("fps"), doc.get("frame_size"), doc.get("frames")
        if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not 0 < fps < 10000:
            raise bad(f"{_RECORDING_FILE} has no valid fps ({fps!r})")
        if not (isinstance(size, list) and len(size) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
            raise bad(f"{_RECORDING_FILE} has no valid frame_size ({size!r})")
        frames_name = doc.get("frames_file") or "frames.jsonl"
        if not isinstance(frames_name, str) or "/" in frames_name or "\\" in frames_name \
                or frames_name.startswith("."):
            raise bad(f"{_RECORDING_FILE} names a frames file {frames_name!r} outside the recording")
        frames = _FramesIndex(folder, frames_name, count if isinstance(count, int) else None, bad)
        if not len(frames) or (isinstance(count, int) and count != len(frames)):
            frames.close()
            raise bad("it holds no frames" if not len(frames) else
                      f"{_RECORDING_FILE} says {count} frames but {frames_name} lists {len(frames)}")
        self.fps = float(fps)
        self._recorded_size = (int(size[0]), int(size[1]))
        return frames

    def _check_sizes(self) -> Tuple[int, int]:
        def size_of(path: Path) -> Tuple[int, int]:
            try:
                with _open_regular(path) as fh:
                    size = image_size(fh, str(path))
            except FileNotFoundError:
                size = None
            except ImageTooLarge as exc:
                raise ReplayError(f"{exc}: replace or remove it") from None
            if size is None:
                raise ReplayError(f"cannot read image {path}: not an image, or its header is truncated or "
                                  "corrupt; replace or remove that file")
            return size

        first: Optional[Tuple[int, int]] = None
        # A recording: its first frame (recording.json gives the size; every frame is checked on decode).
        entries = [self._entry(0)] if self._frames is not None else self._entries
        for entry in entries:
            lw, lh = size_of(entry.left)
            if entry.right is None:
                if lw % 2:
                    raise ReplayError(
                        f"side-by-side image {entry.left} is {lw} pixels wide, an odd number: it must be two "
                        f"equal halves (left camera | right camera)"
                    )
                size = (lw // 2, lh)
            else:
                rs = size_of(entry.right)
                if rs != (lw, lh):
                    raise ReplayError(
                        f"{entry.left.name} is {lw}x{lh} but {entry.right.name} is {rs[0]}x{rs[1]} in "
                        f"{entry.left.parent}: both cameras' images of a frame must have the same size"
                    )
                size = (lw, lh)
            if first is None:
                first = size
            elif size != first:
                raise ReplayError(
                    f"{entry.left} is {size[0]}x{size[1]} per camera but the first frame "
                    f"({entries[0].left.name}) is {first[0]}x{first[1]}: every frame of a replay must "
                    f"have the same size; move the odd ones to another folder"
                )
        assert first is not None
        if self._recorded_size is not None and first != self._recorded_size:
            raise ReplayError(
                f"recording {self.folder}: {entries[0].left.name} is {first[0]}x{first[1]} but "
                f"{_RECORDING_FILE} says {self._recorded_size[0]}x{self._recorded_size[1]}; record it again"
            )
        return first

    # -- the CameraSource protocol ---------------------------------------

    @property
    def frame_size(self) -> Tuple[int, int]:
        """``(width, height)`` of one camera's image, from the first recording."""
        return self._size

    def __len__(self) -> int:
        return len(self._frames) if self._frames is not None else len(self._entries)

    @property
    def names(self) -> List[str]:
        """The recordings in play order (file names, or capture folder names; a recording's frames file is
        read for them)."""
        return [self._entry(k).name for k in range(len(self))]

    @property
    def is_recording(self) -> bool:
        """Whether the folder is a stereocam recording (played at its :attr:`fps`)."""
        return self._frames is not None

    @property
    def slots(self) -> Sequence[int]:
        """When each frame is played, in frame periods (``1 / fps``) from the first: ``[0, 1, 2, ...]``
        for a recording that missed no frame; ``range(len(self))`` for other folders. Read-only, and
        4 bytes a frame however long the recording."""
        if self._frames is not None:
            return memoryview(self._frames.slots).toreadonly()
        return range(len(self._entries))

    @property
    def duration_s(self) -> Optional[float]:
        """A recording's length (the last frame's slot plus one period) in seconds; None for others."""
        if self._frames is None or self.fps is None:
            return None
        return (self._frames.slots[-1] + 1) / self.fps

    def read(self, index: int, t: float = 0.0) -> np.ndarray:
        """Recorded stereo frame number ``index`` (a recording: the one at ``t`` s), read-only ``(H, W, 8)``.

        See the class doc. Raises :class:`ReplayEnded` past the end without ``loop``, and
        :class:`ReplayError` naming the file if an image cannot be decoded.
        """
        if self._closed:
            raise SourceClosedError(f"the ReplaySource of {self.folder} is closed: make a new one")
        index = int(index)
        if index < 0:
            raise ValueError(f"frame index must be >= 0, got {index}")
        if self._frames is not None and self.fps is not None:
            slots = self._frames.slots
            period = slots[-1] + 1
            slot = math.floor(max(0.0, float(t)) * self.fps + 1e-6)
            if slot >= period and not self.loop:
                raise ReplayEnded(f"the recording {self.folder} lasts {period / self.fps:g} s; "
                                  f"t = {t:g} s is past the end")
            return self.frame(bisect.bisect_right(slots, slot % period) - 1)
        n = len(self._entries)
        if index >= n and not self.loop:
            raise ReplayEnded(f"the replay of {self.folder} has {n} frames; frame {index} is past the end")
        return self.frame(index % n)

    def frame(self, k: int) -> np.ndarray:
        """Recorded frame ``k`` (0 .. len - 1), read-only ``(H, W, 8)``, whatever the time."""
        if self._closed:
            raise SourceClosedError(f"the ReplaySource of {self.folder} is closed: make a new one")
        n = len(self)
        if not 0 <= int(k) < n:
            raise IndexError(f"frame {k} of a replay of {n} frames")
        slot = int(k)
        with self._lock:
            frame = self._cache.get(slot)
            if frame is not None:
                self._cache.move_to_end(slot)
                return frame
        frame = self._decode(self._entry(slot))
        frame.setflags(write=False)
        with self._lock:
            self._cache[slot] = frame
            self._cache.move_to_end(slot)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return frame

    def close(self) -> None:
        """Drop the cache and close a recording's frames file. Idempotent."""
        self._closed = True
        with self._lock:
            self._cache.clear()
        if self._frames is not None:
            self._frames.close()

    def __enter__(self) -> "ReplaySource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- decoding ----------------------------------------------------------

    def _load(self, path: Path) -> np.ndarray:
        """An (H, W) gray or (H, W, 3) RGB uint8 image."""
        try:
            image = decode_image_bytes(_read_regular(path, MAX_IMAGE_BYTES), cv2.IMREAD_UNCHANGED, str(path))
        except FileNotFoundError:
            image = None
        except ImageTooLarge as exc:
            raise ReplayError(f"{exc}: replace or remove it") from None
        if image is None:
            raise ReplayError(
                f"cannot decode image {path} (missing, truncated or corrupt): replace or remove it"
            )
        if image.dtype != np.uint8:
            raise ReplayError(
                f"image {path} has {image.dtype} pixels; cameras are 8-bit: convert it to 8 bits"
            )
        if image.ndim == 3:
            if image.shape[2] == 1:
                image = image[..., 0]
            elif image.shape[2] == 2:  # gray + alpha
                image = image[..., 0]
            elif image.shape[2] == 3:
                image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
            elif image.shape[2] == 4:
                image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
            else:
                raise ReplayError(f"image {path} has {image.shape[2]} channels: use gray or RGB images")
        return np.ascontiguousarray(image)

    def _decode(self, entry: _Entry) -> np.ndarray:
        w, h = self._size
        left = self._load(entry.left)
        if entry.right is None:
            if left.shape[:2] != (h, 2 * w):
                raise ReplayError(f"{entry.left} changed size since the replay was opened: reopen the folder")
            left, right = left[:, :w], left[:, w:]
        else:
            right = self._load(entry.right)
            for path, img in ((entry.left, left), (entry.right, right)):
                if img.shape[:2] != (h, w):
                    raise ReplayError(f"{path} changed size since the replay was opened: reopen the folder")
        if left.ndim != right.ndim:  # one gray, one colour: both as RGB
            left, right = (np.repeat(x[..., None], 3, axis=2) if x.ndim == 2 else x for x in (left, right))
        sides = [rgby(np.ascontiguousarray(left)), rgby(np.ascontiguousarray(right))]
        for side, y_path in zip(sides, (entry.left_y, entry.right_y), strict=True):
            if y_path is not None:
                y = self._load(y_path)
                if y.ndim != 2 or y.shape != side.shape[:2]:
                    raise ReplayError(f"{y_path} is not a gray image of its frame's size: replace or "
                                      f"remove it")
                side[..., 3] = y
        return pack(sides[0], sides[1])


class _FramesIndex:
    """A recording's frames file, indexed: where each frame's line starts and its slot, 12 bytes a frame.

    The file is read once, a line at a time (each at most :data:`MAX_LINE_BYTES`), and every
    line checked then; a frame's line is read again, by its offset, when the frame is wanted.
    It stays open (read with ``pread``: safe from several threads) until :meth:`close`.
    """

    def __init__(self, folder: Path, name: str, count: Optional[int],
                 bad: Callable[[str], ReplayError]) -> None:
        self.folder, self.name, self._bad = folder, name, bad
        self.offsets = array("Q")
        self.slots = array(_SLOT_TYPE)
        try:
            fh = _open_regular(folder / name)
        except (OSError, ReplayError) as exc:
            raise bad(f"{name} cannot be read ({exc})") from None
        self._fd = os.dup(fh.fileno())
        self._closer = weakref.finalize(self, os.close, self._fd)
        try:
            with fh:
                self._scan(fh, count)
        except BaseException:
            self.close()
            raise

    def __len__(self) -> int:
        return len(self.offsets)

    def _scan(self, fh: IO[bytes], count: Optional[int]) -> None:
        slots = self.slots
        offset, number = 0, 0
        first: Optional[int] = None
        while True:
            raw = fh.readline(MAX_LINE_BYTES + 1)
            if not raw:
                break
            number += 1
            start, offset = offset, offset + len(raw)
            if len(raw) > MAX_LINE_BYTES:
                raise self._bad(f"line {number} of {self.name} is longer than {MAX_LINE_BYTES // 1024} KiB: "
                                f"it is damaged")
            if not raw.strip():
                continue
            if count is not None and len(self.offsets) == count:
                raise self._bad(f"{_RECORDING_FILE} says {count} frames but {self.name} lists more")
            _, fabric_count = self._parse(raw, f"line {number}")
            if first is None:
                first = fabric_count
            slot = (fabric_count - first) % _COUNT_MOD
            if slots and slot <= slots[-1]:
                raise self._bad(f"the FRAME_COUNTs in {self.name} do not increase")
            self.offsets.append(start)
            slots.append(slot)

    def _parse(self, raw: bytes, where: str) -> Tuple[List[Optional[str]], int]:
        """The file names a line gives (left, right, left_y, right_y), checked, and its FRAME_COUNT."""
        name = self.name
        try:
            line = json.loads(raw)
            fabric_count = int(line["fabric_count"])
            names = [line.get(key) for key in _LINE_FILES]
        except (ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError) as exc:
            raise self._bad(f"{where} of {name} is damaged ({exc})") from None  # OverflowError: Infinity
        for value in names:
            if value is not None and (not isinstance(value, str) or not value or value.startswith(".")
                                      or "/" in value or "\\" in value or "\0" in value):
                raise self._bad(f"{name} names a file {value!r} outside the recording")
        if names[0] is None or names[1] is None:
            raise self._bad(f"{where} of {name} names no left or right file")
        return names, fabric_count

    def entry(self, k: int) -> _Entry:
        """Frame ``k``'s files, from its line (read again now)."""
        if not self._closer.alive:
            raise SourceClosedError(f"the frames file of {self.folder} is closed: make a new ReplaySource")
        data = os.pread(self._fd, MAX_LINE_BYTES + 1, self.offsets[k])
        left, right, left_y, right_y = (None if n is None else self.folder / n for n in
                                        self._parse(data.split(b"\n", 1)[0], f"the line of frame {k}")[0])
        assert left is not None and right is not None
        return _Entry(left.name, left, right, left_y, right_y)

    def close(self) -> None:
        self._closer()
