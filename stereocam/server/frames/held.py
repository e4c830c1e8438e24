"""Frames a client may still ask about by number: what the page's freeze and ruler read (issue 24, item 4).

A page shows frames a little after the daemon made them, and a frozen page shows one frame for as long
as the user likes; its depth readout and ruler must read *that* frame's disparity, not the newest. So:

- the last :data:`RECENT` frame sets the disparity view was given (:class:`ShownLatest` notes them as
  the disparity worker publishes them): the frame a live page shows is among them;
- up to :data:`PINNED_MAX` frozen ones (:meth:`HeldFrames.pin`, ``POST /api/freeze``), kept until
  released or until newer pins push the oldest out. A frame held neither way is gone: the API says
  so (410) and the page tells the user to freeze again.

A held frame set is the pipeline's own, read-only (about 1.4 MB at 752x480, twice that with its raw
pair). Its cache also holds every view rendered of it and their JPEGs, about 12 MB with the page's eight
views: on a 512 MB board eight such frames were 100 MB. So a recent frame keeps in its cache only what
the readouts read and what is costly to compute again (:data:`KEPT`: the disparity, the stereo core's
output) once :data:`KEEP_WHOLE` newer ones have come; a view of it asked for later is rendered again.
Pinned frames keep theirs. Event-loop thread only.
"""
from __future__ import annotations

from collections import OrderedDict, deque
from typing import Deque, Hashable, Iterable, List, Optional

from .feed import FeedItem, Latest
from .pipeline import FrameSet

__all__ = ["HeldFrames", "ShownLatest", "RECENT", "PINNED_MAX", "KEEP_WHOLE", "KEPT"]

RECENT = 8      # the disparity view's last frames: a live page's readout asks for one of these
PINNED_MAX = 4  # frozen frames held at once (several tabs may freeze); the oldest goes first
KEEP_WHOLE = 2  # the newest recent frames keep their whole cache: views may still be encoding them
# What an older recent frame's cache keeps (by the key's first element): the 16-bit disparity (2 s of the
# board's A9 to compute again), the stereo core's output and the model's, the tools' small results.
KEPT = frozenset({"disparity16", "stereo", "stereo model", "tool"})


def _kept(key: Hashable) -> bool:
    return isinstance(key, tuple) and bool(key) and key[0] in KEPT


class HeldFrames:
    """The recent and the pinned frame sets, by frame number."""

    def __init__(self, recent: int = RECENT, pinned: int = PINNED_MAX) -> None:
        self.recent: Deque[FrameSet] = deque(maxlen=recent)
        self.pinned: "OrderedDict[int, FrameSet]" = OrderedDict()
        self.pinned_max = pinned

    def saw(self, fs: FrameSet) -> None:
        """Note a frame set a view was given; the one :data:`KEEP_WHOLE` back keeps only :data:`KEPT`."""
        self.recent.append(fs)
        if len(self.recent) > KEEP_WHOLE:
            older = self.recent[-1 - KEEP_WHOLE]
            if older.frame not in self.pinned:
                older.cache.release(_kept)

    def get(self, frame: int, also: Iterable[Optional[FrameSet]] = ()) -> Optional[FrameSet]:
        """Frame ``frame`` if it is pinned, recent or one of ``also`` (e.g. the feed's newest)."""
        if frame in self.pinned:
            return self.pinned[frame]
        for fs in list(self.recent) + list(also):
            if fs is not None and fs.frame == frame:
                return fs
        return None

    def pin(self, fs: FrameSet) -> List[int]:
        """Hold ``fs`` until :meth:`unpin` (or until PINNED_MAX newer pins); the frames pushed out."""
        self.pinned.pop(fs.frame, None)
        self.pinned[fs.frame] = fs
        gone = []
        while len(self.pinned) > self.pinned_max:
            gone.append(self.pinned.popitem(last=False)[0])
        return gone

    def unpin(self, frame: int) -> bool:
        """Release a pinned frame; False when it was not pinned."""
        return self.pinned.pop(frame, None) is not None

    def frames(self) -> List[int]:
        """The pinned frames' numbers, oldest pin first."""
        return list(self.pinned)


class ShownLatest(Latest[FeedItem]):
    """A :class:`Latest` that notes every frame set published through it in ``held`` (the disparity
    worker's output: the frames the disparity view and the depth readouts show)."""

    def __init__(self, held: HeldFrames) -> None:
        super().__init__()
        self.held = held

    def publish(self, value: FeedItem) -> None:
        if isinstance(value, FrameSet):
            self.held.saw(value)
        super().publish(value)
