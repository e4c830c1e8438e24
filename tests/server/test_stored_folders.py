"""Readers of stored folders (recordings, captures, calibration pairs) refuse symbolic links and read
bounded (issue 20, items 7 and 8).

Replay followed a symbolic link inside a recording's folder: an image outside it was shown through
the virtual camera while the listing called the file missing. A 1,000,000-line ``frames.jsonl`` was
read whole (55 s, RSS up by 600 MB); ``recording.json`` was read unbounded.
"""
from __future__ import annotations

import json
import logging
import os
import tracemalloc
from pathlib import Path
from typing import Tuple

import cv2
import numpy as np
import pytest

from stereocam.overlays.emulated.replay import MAX_LINE_BYTES, ReplayError, ReplaySource
from stereocam.server.frames.recorder import Recorder
from stereocam.server.stores.calibration_pairs import (
    SETTINGS_FILE,
    PanelError,
    PanelSettings,
    compute,
    load_settings,
)
from stereocam.server.stores.captures import CaptureStore
from stereocam.server.stores.recordings import RecordingStore

from .daemon import SMALL, WAIT_S
from .test_recordings_durable import HandFeed, write_frames


def recording(tmp_path: Path, counts: Tuple[int, ...] = (1, 2, 3)) -> Tuple[RecordingStore, str]:
    """A finished recording of the frames ``counts`` (the in-process writer, fed by hand)."""
    store = RecordingStore(tmp_path / "recordings")
    feed = HandFeed()
    rec = Recorder(store, feed).start(seconds=None, frame_size=SMALL, fps=10.0, frame_no=counts[0])
    write_frames(rec, feed, list(counts))
    rec.stop()
    assert rec.join(WAIT_S) is not None, rec.error
    return store, rec.id


def outside_image(tmp_path: Path) -> Path:
    """An image of the recording's size outside its folder: what a link would show."""
    path = tmp_path / "outside.png"
    cv2.imwrite(str(path), np.full((SMALL[1], SMALL[0], 3), 200, np.uint8))
    return path


# -- symbolic links ---------------------------------------------------------------------------------

def test_replay_refuses_a_frame_that_is_a_symbolic_link_and_the_listing_names_it(tmp_path: Path) -> None:
    store, rid = recording(tmp_path)
    folder = store.root / rid
    (folder / "left_000001.png").unlink()
    (folder / "left_000001.png").symlink_to(outside_image(tmp_path))
    with ReplaySource(folder) as replay:
        replay.frame(0)
        with pytest.raises(ReplayError, match=r"left_000001\.png is a symbolic link: a replay reads only the "
                                              r"files in its folder"):
            replay.frame(1)
    assert store.get(rid).error == "left_000001.png is a symbolic link, not a file"


@pytest.mark.parametrize("name", ["recording.json", "frames.jsonl", "left_000000.png"])
def test_replay_refuses_a_recording_whose_own_files_are_symbolic_links(tmp_path: Path, name: str) -> None:
    store, rid = recording(tmp_path)
    folder = store.root / rid
    moved = tmp_path / f"moved-{name}"
    (folder / name).rename(moved)
    (folder / name).symlink_to(moved)
    with pytest.raises(ReplayError, match=rf"{name.replace('.', '[.]')} is a symbolic link"):
        ReplaySource(folder)


def test_replay_of_a_folder_refuses_linked_images_and_captures(tmp_path: Path) -> None:
    image = outside_image(tmp_path)
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    for name in ("left1.png", "right1.png"):
        os.link(image, pairs / name)  # a hard link is a file of the folder
    (pairs / "left2.png").symlink_to(image)
    os.link(image, pairs / "right2.png")
    with pytest.raises(ReplayError, match=r"left2\.png is a symbolic link"):
        ReplaySource(pairs)
    (pairs / "left2.png").unlink()
    os.link(image, pairs / "left2.png")
    (pairs / "notes.txt").symlink_to(image)  # not an image: ignored, as any other file
    assert len(ReplaySource(pairs)) == 2

    captures = tmp_path / "captures"
    (captures / "a").mkdir(parents=True)
    os.link(image, captures / "a" / "raw_left.png")
    (captures / "a" / "raw_right.png").symlink_to(image)
    with pytest.raises(ReplayError, match=r"raw_right\.png is a symbolic link"):
        ReplaySource(captures)
    (captures / "a" / "raw_right.png").unlink()
    os.link(image, captures / "a" / "raw_right.png")
    (captures / "b").symlink_to(captures / "a", target_is_directory=True)
    with pytest.raises(ReplayError, match=r"captures/b is a symbolic link"):
        ReplaySource(captures)


def test_calibration_pairs_refuse_symbolic_links(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    folder = tmp_path / "calibration-pairs"
    store = CaptureStore(folder, min_free_bytes=0)
    secret = tmp_path / "secret.json"
    secret.write_text(json.dumps({"pattern": "7x5", "square_mm": 40}))
    (folder / SETTINGS_FILE).symlink_to(secret)
    with caplog.at_level(logging.WARNING):
        assert load_settings(folder) == PanelSettings.default()
    assert "it is a symbolic link, not a file" in caplog.text

    pair = "20261122T040512Z-000123-ab12"
    (folder / pair).mkdir()
    (folder / pair / "raw_left.png").symlink_to(outside_image(tmp_path))
    with pytest.raises(PanelError, match=rf"pair {pair}: raw_left\.png is a symbolic link, not a file; "
                                         r"delete that pair"):
        compute(store, [pair], PanelSettings.default(), rectify=None, progress=lambda *a: None)


# -- bounded reads -----------------------------------------------------------------------------------

def test_a_recording_json_over_the_bound_is_refused_with_one_line(tmp_path: Path) -> None:
    store, rid = recording(tmp_path)
    folder = store.root / rid
    doc = json.loads((folder / "recording.json").read_text())
    doc["padding"] = "x" * (5 << 20)
    (folder / "recording.json").write_text(json.dumps(doc))
    with pytest.raises(ReplayError, match=r"recording\.json cannot be read \(.*recording\.json is larger "
                                          r"than 4 MiB"):
        ReplaySource(folder)
    error = store.get(rid).error
    assert error is not None and "recording.json is damaged (recording.json is larger than" in error
    assert "\n" not in error


def test_a_frames_line_over_the_bound_is_damage(tmp_path: Path) -> None:
    store, rid = recording(tmp_path)
    folder = store.root / rid
    with open(folder / "frames.jsonl", "a") as fh:
        fh.write('{"fabric_count": 9, "left": "' + "x" * MAX_LINE_BYTES + '"}\n')
    with pytest.raises(ReplayError, match=r"line 4 of frames\.jsonl is longer than 64 KiB: it is damaged"):
        ReplaySource(folder)


@pytest.mark.slow
def test_a_huge_frames_file_is_indexed_not_held(tmp_path: Path) -> None:
    """100,000 lines (27 MB): opening it allocates a few bytes a frame, not the file and its lines."""
    store, rid = recording(tmp_path, (0,))
    folder = store.root / rid
    line = json.loads((folder / "frames.jsonl").read_text())
    n = 100_000
    with open(folder / "frames.jsonl", "w") as fh:
        for k in range(n):
            fh.write(json.dumps({**line, "fabric_count": k, "frame": k}) + "\n")
    doc = json.loads((folder / "recording.json").read_text())
    (folder / "recording.json").write_text(json.dumps({**doc, "frames": n}))
    assert (folder / "frames.jsonl").stat().st_size > 20e6
    tracemalloc.start()
    try:
        replay = ReplaySource(folder)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    with replay:
        assert len(replay) == n and replay.slots[-1] == n - 1 and replay.duration_s == pytest.approx(n / 10.0)
        np.testing.assert_array_equal(replay.frame(n - 1), replay.frame(0))  # the same files, read by offset
    assert peak < 10e6, f"opening took {peak / 1e6:.1f} MB"  # read whole: the text alone is 27 MB
