"""Recording that keeps up, and recordings deleted with undo (issue 24, item 7).

Performance itself is a benchmark's (``stereocam bench recording``: stop-to-done seconds and
bytes per frame); these tests hold the mechanism that gives it, with no clock involved:

- frames are encoded and written while the recording runs, so at a stop only what is still
  queued or being encoded is left, and the recording is done only once that is written;
- frames are encoded on several threads at once and written in the order they came;
- the recordings' PNG is smaller than the captures' RGB PNG on camera frames, gray frames
  are stored as gray PNGs, and every frame reads back bit for bit; recordings made with
  the captures' PNG (every recording made before) list, replay and download as they did;
- the trash of recordings: purged by age at start-up, emptied before a recording would
  run short of space, restorable across a restart.
"""
from __future__ import annotations

import io
import threading
import zipfile
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Callable, List, Tuple

import cv2
import numpy as np
import pytest

from stereocam.overlays.emulated.replay import ReplaySource
from stereocam.overlays.spec import pixel
from stereocam.server.frames.recorder import Encoded, Recorder, Recording, encode_pair
from stereocam.server.stores.capture_images import CAPTURE_PNG, FAST_PNG, encode_pixels
from stereocam.server.stores.recordings import RecordingNotFound, RecordingStore
from stereocam.server.stores.trash import TRASH_DIR, TRASH_KEEP_S

from .daemon import FULL, SMALL, WAIT_S, rig_frame
from .test_recordings_durable import HandFeed, assert_whole, wait_for, write_frames

pytestmark = pytest.mark.slow

REC_FPS = 10.0


class Clock:
    def __init__(self) -> None:
        self.now = datetime(2026, 11, 28, 0, 0, 0, tzinfo=timezone.utc)

    def __call__(self) -> datetime:
        return self.now


class GatedEncoder:
    """:func:`encode_pair`, held at a gate while ``gate`` is clear; counts the encodes under way."""

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.gate.set()
        self.lock = threading.Lock()
        self.running = 0
        self.most = 0  # the most encodes under way at once

    def __call__(self, raw: np.ndarray) -> Tuple[Encoded, Encoded]:
        with self.lock:
            self.running += 1
            self.most = max(self.most, self.running)
        try:
            assert self.gate.wait(WAIT_S), "the test never opened the gate"
            return encode_pair(raw)
        finally:
            with self.lock:
                self.running -= 1


def start(store: RecordingStore, feed: HandFeed, encode: Callable[[np.ndarray], Tuple[Encoded, Encoded]],
          encoders: int = 2) -> Recording:
    recorder = Recorder(store, feed, encoders=encoders, encode=encode)
    return recorder.start(seconds=None, frame_size=SMALL, fps=REC_FPS, frame_no=1)


def test_frames_are_written_while_recording_and_done_follows_the_queue_draining(tmp_path: Path) -> None:
    store, feed, encoder = RecordingStore(tmp_path / "recordings"), HandFeed(), GatedEncoder()
    rec = start(store, feed, encoder)
    # While it runs, each frame is encoded and written as it comes: nothing waits for the stop.
    write_frames(rec, feed, [0, 1, 2, 3])
    assert rec.running and rec.frames == 4 and rec.queued == 0
    assert [line["fabric_count"] for line in _lines(rec.folder)] == [0, 1, 2, 3]
    # Frames the encoders have not done are what a stop leaves: "queued", then written.
    encoder.gate.clear()
    assert feed.sink is not None
    for count in (4, 5, 6, 7):
        feed.sink(feed.frame(count))
    wait_for("two encodes held at the gate", lambda: encoder.running == 2)
    assert rec.queued == 4 and rec.frames == 4
    rec.stop()
    entry = rec.to_json()
    assert entry["state"] == "finishing" and entry["queued"] == 4
    assert rec.join(0) is None and rec.running  # not done while frames wait
    assert store.list() == []  # nor listed
    encoder.gate.set()
    info = rec.join(WAIT_S)
    assert info is not None and info.state == "done" and info.frames == 8 and rec.queued == 0
    assert info.meta["end"] == "stopped" and info.meta["skipped"] == 0
    assert_whole(store, rec.id, list(range(8)))


def test_frames_are_encoded_at_once_and_written_in_the_order_they_came(tmp_path: Path) -> None:
    store, feed = RecordingStore(tmp_path / "recordings"), HandFeed()
    first_done = threading.Event()
    together = threading.Barrier(2, timeout=WAIT_S)  # passes only when two encodes run at once
    order: List[int] = []

    def encode(raw: np.ndarray) -> Tuple[Encoded, Encoded]:
        stamp = int.from_bytes(np.ascontiguousarray(raw[0, :4, 0]).tobytes(), "little")
        if stamp < 2:
            together.wait()
        if stamp == 0:  # the first frame finishes last
            assert first_done.wait(WAIT_S)
        pair = encode_pair(raw)
        order.append(stamp)
        if stamp == 1:
            first_done.set()
        return pair

    rec = start(store, feed, encode)
    assert feed.sink is not None
    for count in range(5):
        feed.sink(feed.frame(count))
    wait_for("five frames written", lambda: rec.frames == 5 or not rec.running)
    rec.stop()
    info = rec.join(WAIT_S)
    assert info is not None and info.frames == 5, rec.error
    assert order.index(1) < order.index(0)  # encoded at once, the second done first ...
    assert_whole(store, rec.id, [0, 1, 2, 3, 4])  # ... written in order


def test_an_encoder_failing_ends_the_recording_keeping_the_frames_before(tmp_path: Path) -> None:
    store, feed = RecordingStore(tmp_path / "recordings"), HandFeed()

    def encode(raw: np.ndarray) -> Tuple[Encoded, Encoded]:
        if int(raw[0, 0, 0]) == 3:
            raise ValueError("no PNG for this one")
        return encode_pair(raw)

    rec = start(store, feed, encode)
    write_frames(rec, feed, [0, 1, 2, 3, 4])
    info = rec.join(WAIT_S)
    assert info is not None and info.meta["end"] == "error" and info.meta["complete"] is False
    assert "no PNG for this one" in info.meta["end_text"]
    assert_whole(store, rec.id, [0, 1, 2])


# -- what is stored ---------------------------------------------------------------------------------

def test_the_recordings_png_is_smaller_than_the_rgb_png_on_camera_frames_and_bit_exact() -> None:
    frame, _ = rig_frame(FULL)  # the synthetic rig through Bayer sensors: noise, as a camera's
    new = old = 0
    for side in (pixel.LEFT, pixel.RIGHT):
        camera = frame[..., side]
        color, png, y_png = encode_pixels("frame", camera, FAST_PNG)
        assert color == "rgb" and y_png is None  # Y is gray_of(RGB): not stored
        _, old_png, _ = encode_pixels("frame", camera, CAPTURE_PNG)
        new, old = new + len(png), old + len(old_png)
        back = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(pixel.rgby(cv2.cvtColor(back, cv2.COLOR_BGR2RGB)), camera)
    assert new < old, (new, old)


def test_a_gray_recording_stores_gray_pngs_and_reads_back_bit_for_bit(tmp_path: Path) -> None:
    store, feed = RecordingStore(tmp_path / "recordings"), HandFeed()
    gray = np.ascontiguousarray(feed.source.left[..., 1])
    color = feed.source.read(0, 0.0)

    def gray_frame(count: int) -> np.ndarray:
        g = gray.copy()
        g[0, :4] = np.frombuffer(int(count).to_bytes(4, "little"), np.uint8)
        return pixel.pack(pixel.rgby(g), pixel.rgby(g))

    feed.source.read = lambda index, t: gray_frame(index)  # type: ignore[method-assign]
    rec = start(store, feed, encode_pair)
    write_frames(rec, feed, [0, 1, 2])
    rec.stop()
    info = rec.join(WAIT_S)
    assert info is not None and info.meta["color"] == "gray"
    assert {line["color"] for line in _lines(store.root / rec.id)} == {"gray"}
    png = (store.root / rec.id / "left_000001.png").read_bytes()
    assert cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED).ndim == 2  # one channel
    rgb_png = encode_pixels("frame", color[..., pixel.LEFT], FAST_PNG)[1]
    assert len(png) < len(rgb_png) / 2  # a third of the samples
    with ReplaySource(store.root / rec.id, loop=False) as replay:
        for k in range(3):
            np.testing.assert_array_equal(replay.frame(k), gray_frame(k))


def test_a_recording_made_with_the_captures_png_lists_replays_and_downloads(tmp_path: Path) -> None:
    """Every recording made before this change holds level-3 RGB PNGs: they read as before."""
    store, feed = RecordingStore(tmp_path / "recordings"), HandFeed()

    def old_encode(raw: np.ndarray) -> Tuple[Encoded, Encoded]:
        return (encode_pixels("left", raw[..., pixel.LEFT], CAPTURE_PNG),
                encode_pixels("right", raw[..., pixel.RIGHT], CAPTURE_PNG))

    rec = start(store, feed, old_encode, encoders=1)
    write_frames(rec, feed, [0, 1, 2])
    rec.stop()
    assert rec.join(WAIT_S) is not None
    old = (store.root / rec.id / "left_000000.png").read_bytes()
    raw = feed.frame(0).raw
    assert raw is not None and old == encode_pixels("left", raw[..., pixel.LEFT], CAPTURE_PNG)[1]
    meta = assert_whole(store, rec.id, [0, 1, 2])  # listed, replayed bit for bit, zipped
    with zipfile.ZipFile(io.BytesIO(b"".join(store.zip_stream(rec.id)))) as zf:
        assert zf.read(f"{rec.id}/left_000000.png") == old
    assert meta["frames"] == 3


# -- the trash -------------------------------------------------------------------------------------

def _record(store: RecordingStore, feed: HandFeed, counts: List[int]) -> str:
    rec = start(store, feed, encode_pair)
    write_frames(rec, feed, counts)
    rec.stop()
    assert rec.join(WAIT_S) is not None
    return rec.id


def test_the_trash_of_recordings_expires_as_captures_and_gives_its_space_first(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    clock, feed = Clock(), HandFeed()
    store = RecordingStore(tmp_path / "recordings", clock=clock)
    old = _record(store, feed, [0, 1])
    store.trash(old)
    assert store.list() == []
    with pytest.raises(RecordingNotFound):
        store.get(old)
    # A restart keeps what is younger than TRASH_KEEP_S ...
    store = RecordingStore(store.root, clock=clock)
    assert store.restore(old).frames == 2
    assert_whole(store, old, [0, 1])
    store.trash(old)
    # ... and removes what is older.
    clock.now += timedelta(seconds=TRASH_KEEP_S + 1)
    store = RecordingStore(store.root, clock=clock)
    assert list((store.root / TRASH_DIR).iterdir()) == []
    with pytest.raises(RecordingNotFound, match="not in the trash"):
        store.restore(old)
    # Short of space: the trash gives its space first, rather than a recording end early ...
    trash = store.root / TRASH_DIR

    def free() -> int:  # a trashed recording holds the space a frame needs
        return 1000 if any(trash.iterdir()) else 1 << 40

    monkeypatch.setattr(store, "free_bytes", free)
    young = _record(store, feed, [2, 3])
    rec = start(store, feed, encode_pair)
    write_frames(rec, feed, [4])
    store.trash(young)
    write_frames(rec, feed, [5, 6])
    assert rec.running and list(trash.iterdir()) == []
    rec.stop()
    info = rec.join(WAIT_S)
    assert info is not None and info.frames == 3 and info.end == "stopped" and info.complete is True
    # ... or refuse to start.
    store.trash(rec.id)
    assert _record(store, feed, [7, 8]) and list(trash.iterdir()) == []


def _lines(folder: Path) -> List[Any]:
    import json

    return [json.loads(line) for line in (folder / "frames.jsonl").read_text().splitlines()]
