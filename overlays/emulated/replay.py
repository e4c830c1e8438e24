"""Replay: recorded stereo frames from a folder, played as a live camera source.

Its recordings are frames the IP already demosaiced (captures of the
stream): they are played as they are, not mosaicked again. A stereocam
recording (``POST /api/recordings``: a folder with ``recording.json``) is
played frame by frame in order at the rate it was recorded.
"""
from __future__ import annotations

import bisect
import json
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Union

import cv2
import numpy as np

from ...calibration.image_files import (
    CAPTURE_FILES,
    ImageTooLarge,
    decode_image_file,
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


# A stereocam recording (server/frames/recordings.py writes it): named here, so no server import.
_RECORDING_FILE = "recording.json"
_RECORDING_FORMAT = "stereocam-recording/"
_COUNT_MOD = 1 << 32


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
        self._slots: Optional[List[int]] = None  # a recording's frames, in frame periods from the first
        self._recorded_size: Optional[Tuple[int, int]] = None
        if (self.folder / _RECORDING_FILE).is_file():
            self._entries = self._discover_recording()
        else:
            self._entries = self._discover()
        self._size = self._check_sizes()

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
            if path.is_dir():
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

    def _discover_recording(self) -> List[_Entry]:
        """A stereocam recording's frames from its ``recording.json`` and frames file."""
        folder = self.folder

        def bad(what: str) -> ReplayError:
            return ReplayError(f"recording {folder}: {what}; record it again or remove it")

        try:
            doc = json.loads((folder / _RECORDING_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
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
        frames_file = folder / frames_name
        entries: List[_Entry] = []
        counts: List[int] = []
        try:
            lines = frames_file.read_text(encoding="utf-8").splitlines()
        except (OSError, ValueError) as exc:
            raise bad(f"{frames_file.name} cannot be read ({exc})") from None

        def member(line: Dict[str, object], key: str) -> Optional[Path]:
            name = line.get(key)
            if name is None:
                return None
            if not isinstance(name, str) or "/" in name or name.startswith("."):
                raise bad(f"{frames_file.name} names a file {name!r} outside the recording")
            return folder / name

        for number, text in enumerate(lines, 1):
            if not text.strip():
                continue
            try:
                line = json.loads(text)
                fabric_count = int(line["fabric_count"])
                left, right = member(line, "left"), member(line, "right")
            except ReplayError:
                raise
            except (ValueError, KeyError, TypeError, OverflowError) as exc:  # OverflowError: Infinity
                raise bad(f"line {number} of {frames_file.name} is damaged ({exc})") from None
            if left is None or right is None:
                raise bad(f"line {number} of {frames_file.name} names no left or right file")
            entries.append(_Entry(left.name, left, right, member(line, "left_y"), member(line, "right_y")))
            counts.append(fabric_count)
        if not entries:
            raise bad("it holds no frames")
        if isinstance(count, int) and count != len(entries):
            raise bad(f"{_RECORDING_FILE} says {count} frames but {frames_file.name} lists {len(entries)}")
        slots = [(c - counts[0]) % _COUNT_MOD for c in counts]
        if any(b <= a for a, b in zip(slots, slots[1:], strict=False)):
            raise bad(f"the FRAME_COUNTs in {frames_file.name} do not increase")
        self.fps = float(fps)
        self._slots = slots
        self._recorded_size = (int(size[0]), int(size[1]))
        return entries

    def _check_sizes(self) -> Tuple[int, int]:
        def size_of(path: Path) -> Tuple[int, int]:
            try:
                size = image_size(path, str(path)) if path.is_file() else None
            except ImageTooLarge as exc:
                raise ReplayError(f"{exc}: replace or remove it") from None
            if size is None:
                raise ReplayError(f"cannot read image {path}: not an image, or its header is truncated or "
                                  "corrupt; replace or remove that file")
            return size

        first: Optional[Tuple[int, int]] = None
        # A recording: its first frame (recording.json gives the size; every frame is checked on decode).
        entries = self._entries[:1] if self._slots is not None else self._entries
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
                    f"({self._entries[0].left.name}) is {first[0]}x{first[1]}: every frame of a replay must "
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
        return len(self._entries)

    @property
    def names(self) -> List[str]:
        """The recordings in play order (file names, or capture folder names)."""
        return [e.name for e in self._entries]

    @property
    def is_recording(self) -> bool:
        """Whether the folder is a stereocam recording (played at its :attr:`fps`)."""
        return self._slots is not None

    @property
    def slots(self) -> List[int]:
        """When each frame is played, in frame periods (``1 / fps``) from the first: ``[0, 1, 2, ...]``
        for a recording that missed no frame; ``range(len(self))`` for other folders."""
        return list(self._slots) if self._slots is not None else list(range(len(self._entries)))

    @property
    def duration_s(self) -> Optional[float]:
        """A recording's length (the last frame's slot plus one period) in seconds; None for others."""
        if self._slots is None or self.fps is None:
            return None
        return (self._slots[-1] + 1) / self.fps

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
        if self._slots is not None and self.fps is not None:
            period = self._slots[-1] + 1
            slot = math.floor(max(0.0, float(t)) * self.fps + 1e-6)
            if slot >= period and not self.loop:
                raise ReplayEnded(f"the recording {self.folder} lasts {period / self.fps:g} s; "
                                  f"t = {t:g} s is past the end")
            return self.frame(bisect.bisect_right(self._slots, slot % period) - 1)
        n = len(self._entries)
        if index >= n and not self.loop:
            raise ReplayEnded(f"the replay of {self.folder} has {n} frames; frame {index} is past the end")
        return self.frame(index % n)

    def frame(self, k: int) -> np.ndarray:
        """Recorded frame ``k`` (0 .. len - 1), read-only ``(H, W, 8)``, whatever the time."""
        if self._closed:
            raise SourceClosedError(f"the ReplaySource of {self.folder} is closed: make a new one")
        n = len(self._entries)
        if not 0 <= int(k) < n:
            raise IndexError(f"frame {k} of a replay of {n} frames")
        slot = int(k)
        with self._lock:
            frame = self._cache.get(slot)
            if frame is not None:
                self._cache.move_to_end(slot)
                return frame
        frame = self._decode(self._entries[slot])
        frame.setflags(write=False)
        with self._lock:
            self._cache[slot] = frame
            self._cache.move_to_end(slot)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return frame

    def close(self) -> None:
        """Drop the cache. Idempotent."""
        self._closed = True
        with self._lock:
            self._cache.clear()

    def __enter__(self) -> "ReplaySource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- decoding ----------------------------------------------------------

    def _load(self, path: Path) -> np.ndarray:
        """An (H, W) gray or (H, W, 3) RGB uint8 image."""
        try:
            image = decode_image_file(path, cv2.IMREAD_UNCHANGED)
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
