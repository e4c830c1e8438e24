"""The frames held for the page's readouts (``server/frames/held.py``) keep what the readouts read and let
their rendered views go: on a 512 MiB board eight whole recent frames with the page's eight views held
about 100 MiB (the Zynq VM's memory check found it)."""
from __future__ import annotations

import numpy as np
import pytest

from stereocam.server.frames.held import KEEP_WHOLE, RECENT, HeldFrames
from stereocam.server.frames.pipeline import FrameSet, OnceCache
from stereocam.server.frames.views import render

pytestmark = pytest.mark.armhf


def frame_set(n: int) -> FrameSet:
    rng = np.random.default_rng(n)
    processed = rng.integers(0, 256, (48, 64, 8), dtype=np.uint8)
    return FrameSet(seq=n, frame=n, fabric_count=n, timestamp=0.0, monotonic=0.0, source="live",
                    processed=processed, raw=processed.copy())


def fill(fs: FrameSet) -> None:
    """What the page's views and readouts leave in a frame's cache."""
    fs.cache.get(("disparity16",), lambda: np.full((48, 64), 16 * fs.frame, np.int16))
    fs.cache.get(("stereo",), lambda: "the core's output")
    for view in ("rect_left", "raw_right", "sbs"):
        render(fs, view, False, 0.5)
    fs.cache.get(("jpeg", "sbs"), lambda: b"\xff\xd8 a JPEG")


def test_release_drops_what_keep_refuses_and_computes_it_again() -> None:
    cache = OnceCache()
    cache.get(("a",), lambda: 1)
    cache.get(("b",), lambda: 2)
    assert cache.release(lambda key: key == ("a",)) == 1
    assert cache.peek(("a",)) == 1 and cache.peek(("b",)) is None
    assert cache.get(("b",), lambda: 3) == 3


def test_older_recent_frames_keep_their_disparity_and_drop_their_views() -> None:
    held = HeldFrames()
    frames = [frame_set(n) for n in range(1, RECENT + 2)]
    for fs in frames:
        fill(fs)
        held.saw(fs)
    # The newest KEEP_WHOLE may still be encoding: whole.
    for fs in frames[-KEEP_WHOLE:]:
        assert fs.cache.peek(("view", "sbs", False, 0.5)) is not None
        assert fs.cache.peek(("jpeg", "sbs")) is not None
    for fs in frames[:-KEEP_WHOLE]:
        assert fs.cache.peek(("view", "sbs", False, 0.5)) is None
        assert fs.cache.peek(("view", "rect_left", False)) is None
        assert fs.cache.peek(("jpeg", "sbs")) is None
        assert fs.cache.peek(("stereo",)) == "the core's output"
        np.testing.assert_array_equal(fs.cache.peek(("disparity16",)), 16 * fs.frame)
    # A view of a trimmed frame is rendered again, the same image.
    old = frames[-KEEP_WHOLE - 1]
    again = render(old, "sbs", False, 0.5)
    fresh = frame_set(old.frame)
    np.testing.assert_array_equal(again, render(fresh, "sbs", False, 0.5))
    # The oldest fell out of the recent ones, the rest are found by number.
    assert held.get(frames[0].frame) is None
    assert held.get(frames[1].frame) is frames[1]


def test_a_pinned_frame_keeps_its_whole_cache() -> None:
    held = HeldFrames()
    first = frame_set(1)
    fill(first)
    held.saw(first)
    held.pin(first)
    for n in range(2, KEEP_WHOLE + 3):
        fs = frame_set(n)
        fill(fs)
        held.saw(fs)
    assert first.cache.peek(("view", "sbs", False, 0.5)) is not None
    assert held.get(1) is first
