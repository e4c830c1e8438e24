"""The frame gate as a clock-by-clock Python loop: beats in, a TREADY pattern, the beats that leave.

Written from :mod:`..spec.frame_gate` ("Behaviour, clock by clock") alone; the RTL
(``stereocam/overlays/rtl/camera/frame_gate.v``) matches it beat for beat and clock for clock
(``tests/hdl/test_frame_gate_rtl.py``). Frames in tests are small, so a plain loop is enough.

Clock ``c`` is one period of ``aclk``: ``inputs[c]`` is the beat offered on ``s_axis`` in it (None:
TVALID low), ``tready[c]`` is ``m_axis_tready`` in it, and a beat offered on ``m_axis`` in clock
``c`` leaves when ``tready[c]`` is high.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Deque, List, NamedTuple, Optional, Sequence, Tuple

from ..spec import frame_gate as spec

__all__ = ["Beat", "GateOutput", "FrameGate", "run", "frame_beats", "split_frames"]


class Beat(NamedTuple):
    """One AXI4-Stream beat: TDATA, TUSER (start of frame), TLAST (end of line)."""

    data: int
    user: bool
    last: bool


@dataclass
class GateOutput:
    """What left ``m_axis``, and the gate's frame counters (the RTL's ``frames_*_reg``)."""

    beats: List[Tuple[int, Beat]] = field(default_factory=list)  # (clock, beat) taken downstream
    admitted: int = 0  # frames that started while the gate was empty
    dropped: int = 0  # frames that started while it was not: none of their beats was stored
    cut: int = 0  # admitted frames that lost their end (overflow, or a partial line before a TUSER)


class FrameGate:
    """The gate's state between clocks; :meth:`clock` runs one clock.

    Only the policy is modelled (what is stored, what is committed, when a beat may leave): no RAM,
    no pointers. ``depth`` is the DEPTH parameter, ``latency`` the spec's LATENCY.
    """

    def __init__(self, depth: int = spec.PARAMETERS["DEPTH"], latency: int = spec.LATENCY) -> None:
        spec.ram_words(depth)  # refuses a DEPTH outside the spec's range
        self.depth = depth
        self.latency = latency
        self.committed: Deque[Tuple[int, Beat]] = deque()  # (first clock it may leave, beat), oldest first
        self.partial: List[Beat] = []  # the uncommitted beats of the line being stored
        self.passing = False  # the current frame was admitted and not cut
        self.out = GateOutput()
        self.now = 0

    def offered(self) -> Optional[Beat]:
        """The beat on ``m_axis`` in the current clock (TVALID high), if any."""
        if self.committed and self.committed[0][0] <= self.now:
            return self.committed[0][1]
        return None

    def clock(self, beat: Optional[Beat], tready: bool) -> Optional[Beat]:
        """One clock: ``beat`` offered on ``s_axis`` (always taken), ``tready`` on ``m_axis``.

        Returns the beat that left on ``m_axis`` in this clock, if one did.
        """
        offered = self.offered()
        empty = not self.committed  # both at the start of the clock
        occupancy = len(self.committed) + len(self.partial)
        if beat is not None:
            if beat.user:
                if self.partial:  # the frame before ended inside a line: that line never leaves
                    self.out.cut += 1
                    self.partial = []
                self.passing = empty
                if empty:
                    self.out.admitted += 1
                    self._store(beat)
                else:
                    self.out.dropped += 1
            elif self.passing:
                if occupancy >= self.depth:
                    self.out.cut += 1
                    self.partial = []
                    self.passing = False
                else:
                    self._store(beat)
        left = None
        if offered is not None and tready:
            self.committed.popleft()
            self.out.beats.append((self.now, offered))
            left = offered
        self.now += 1
        return left

    def _store(self, beat: Beat) -> None:
        self.partial.append(beat)
        if beat.last:
            ready = self.now + self.latency
            self.committed.extend((ready, b) for b in self.partial)
            self.partial = []

    @property
    def holding(self) -> int:
        """Beats held (committed or not)."""
        return len(self.committed) + len(self.partial)


def run(inputs: Sequence[Optional[Beat]], tready: Sequence[bool], *,
        depth: int = spec.PARAMETERS["DEPTH"], clocks: Optional[int] = None) -> GateOutput:
    """Run the gate over ``clocks`` clocks (default ``len(tready)``), from reset.

    ``inputs`` may be shorter than ``clocks`` (TVALID low after it); ``tready`` must cover every clock.
    """
    n = len(tready) if clocks is None else clocks
    if len(tready) < n:
        raise ValueError(f"tready covers {len(tready)} clocks, {n} are run")
    gate = FrameGate(depth)
    for c in range(n):
        gate.clock(inputs[c] if c < len(inputs) else None, bool(tready[c]))
    return gate.out


def frame_beats(frame: Sequence[Sequence[int]]) -> List[Beat]:
    """The beats of a frame given as rows of TDATA words: TUSER on the first, TLAST ending each row."""
    beats = []
    for y, row in enumerate(frame):
        for x, data in enumerate(row):
            beats.append(Beat(int(data), y == 0 and x == 0, x == len(row) - 1))
    return beats


def split_frames(beats: Sequence[Beat]) -> Tuple[List[List[List[int]]], List[str]]:
    """Beats as frames of rows of TDATA words, and what is wrong with their framing (a beat before
    the first TUSER, a TUSER or the end inside a line)."""
    frames: List[List[List[int]]] = []
    problems: List[str] = []
    line: List[int] = []
    for i, b in enumerate(beats):
        if b.user:
            if line:
                problems.append(f"beat {i}: TUSER inside a line of {len(line)} beats")
                line = []
            frames.append([])
        elif not frames:
            problems.append(f"beat {i}: before the first TUSER")
            continue
        line.append(b.data)
        if b.last:
            frames[-1].append(line)
            line = []
    if line:
        problems.append(f"{len(line)} beats after the last TLAST")
    return frames, problems
