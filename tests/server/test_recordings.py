"""Recordings: every raw pair of N seconds, lossless, replayable by --source and the
virtual camera; listed, downloaded, deleted, refused when the disk would fill or one already runs."""
from __future__ import annotations

import asyncio
import errno
import io
import json
import logging
import os
import re
import time
import zipfile
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np
import pytest

from stereocam.overlays.backend import camera_source
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.replay import ReplayError, ReplaySource
from stereocam.overlays.spec.pixel import pack, rgby
from stereocam.server.frames import recorder as recorder_module
from stereocam.server.frames.pipeline import Pipeline
from stereocam.server.http.app import program_default_calibration
from stereocam.server.http.routes_recordings import RECORDER, RECORDINGS
from stereocam.server.http.settings import Settings
from stereocam.server.http.state import CALIBRATION, PIPELINE, VIRTUAL
from stereocam.server.stores import recording_files
from stereocam.server.stores import recordings as recordings_module

from .daemon import SMALL, WAIT_S, rig_frame, wait_for_frames  # noqa: F401

pytestmark = pytest.mark.slow

REC_FPS = 10.0  # the cameras' rate in these tests: 10 s is 100 frames


class CountingSource:
    """The rig's still frame with the frame index written into the first row of both cameras.

    Every frame differs from the one before and says which it is (:func:`stamp_of`); Y is
    made as the demosaic makes it, so a recording stores RGB only and gives it back bit for bit.
    """

    def __init__(self, size: Tuple[int, int] = SMALL) -> None:
        base, self.model = rig_frame(size)
        self.left = np.ascontiguousarray(base[..., 0:3])
        self.right = np.ascontiguousarray(base[..., 4:7])

    @property
    def frame_size(self) -> Tuple[int, int]:
        h, w = self.left.shape[:2]
        return w, h

    def read(self, index: int, t: float) -> np.ndarray:
        stamp = np.frombuffer(int(index).to_bytes(4, "little"), np.uint8)
        left, right = self.left.copy(), self.right.copy()
        left[0, :4, 0] = stamp
        right[0, :4, 0] = stamp
        return pack(rgby(left), rgby(right))

    def close(self) -> None:
        pass


def stamp_of(frame: np.ndarray) -> int:
    return int.from_bytes(np.ascontiguousarray(frame[0, :4, 0]).tobytes(), "little")


def counting_overlay(**kw: Any) -> EmulatedOverlay:
    return EmulatedOverlay(source=CountingSource(), fps=kw.pop("fps", REC_FPS), **kw)


async def wait_until(what: str, check: Callable[[], Any], timeout: float = WAIT_S) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s")
        await asyncio.sleep(0.05)


async def record(d: Any, body: Any = None) -> Dict[str, Any]:
    kwargs = {} if body is None else {"json": body}
    async with d.http.post("/api/recordings", **kwargs) as resp:
        assert resp.status == 201, await resp.text()
        entry = await resp.json()
        assert resp.headers["Location"] == f"/api/recordings/{entry['id']}"
    return entry


async def finished(d: Any, rid: str, timeout: float = WAIT_S) -> Dict[str, Any]:
    """The listing entry of ``rid`` once it is done (polled: it ends by itself)."""
    async def entry() -> Dict[str, Any]:
        async with d.http.get(f"/api/recordings/{rid}") as resp:
            assert resp.status == 200, await resp.text()
            return await resp.json()

    deadline = time.monotonic() + timeout
    while True:
        doc = await entry()
        if doc["state"] == "done":
            return doc
        if time.monotonic() > deadline:
            raise AssertionError(f"recording {rid} not done within {timeout} s: {doc}")
        await asyncio.sleep(0.1)


def frame_lines(folder: Path) -> List[Dict[str, Any]]:
    return [json.loads(line) for line in (folder / "frames.jsonl").read_text().splitlines()]


# -- the check ----------------------------------------------------------------------------

async def test_a_10_s_recording_replays_through_source_with_the_same_frame_count(start_daemon) -> None:
    source = CountingSource()
    d = await start_daemon(overlay=EmulatedOverlay(source=source, fps=REC_FPS))
    await wait_for_frames(d, 3)
    entry = await record(d, {"seconds": 10})
    assert entry["state"] == "recording" and entry["seconds"] == 10 and entry["frame_size"] == list(SMALL)
    rid = entry["id"]
    done = await finished(d, rid, timeout=10 + WAIT_S)
    assert done["end"] == "duration" and done["complete"] is True and done["error"] is None
    n = done["frames"]
    assert 0.5 * 10 * REC_FPS <= n <= 10 * REC_FPS + 1, n  # a busy machine's frame clock skips late frames

    # The folder: every frame's pair and metadata, in order.
    folder = d.app[RECORDINGS].root / rid
    meta = json.loads((folder / "recording.json").read_text())
    lines = frame_lines(folder)
    assert meta["format"] == "stereocam-recording/1" and meta["id"] == rid
    assert meta["frames"] == len(lines) == n
    assert [line["index"] for line in lines] == list(range(n))
    counts = [line["fabric_count"] for line in lines]
    assert all(b > a for a, b in zip(counts, counts[1:], strict=False))
    assert meta["missed"] == counts[-1] - counts[0] + 1 - n  # FRAME_COUNT gaps: frames the pipeline missed
    calibration_id = d.app[CALIBRATION].id
    assert calibration_id and meta["calibration_id"] == calibration_id
    assert meta["calibration"]["id"] == calibration_id
    assert {(line["source"], line["calibration_id"]) for line in lines} == {("live", calibration_id)}
    times = [line["time"] for line in lines]
    assert all(b > a for a, b in zip(times, times[1:], strict=False)) and 0 <= lines[-1]["t"] < 10
    assert abs(time.time() - times[-1]) < WAIT_S
    assert [line["left"] for line in lines[:2]] == ["left_000000.png", "left_000001.png"]
    assert all(line["left_y"] is None and line["right_y"] is None for line in lines)  # Y = gray_of(RGB)
    assert 0.5 * REC_FPS <= meta["fps"] <= 1.05 * REC_FPS
    assert meta["duration_s"] == pytest.approx((counts[-1] - counts[0] + 1) / meta["fps"], abs=2e-3)
    assert meta["frame_size"] == list(SMALL) and meta["source"] == "live" and meta["seconds"] == 10

    # Lossless: each recorded pair is the cameras' frame bit for bit (the stamp says which).
    replay = ReplaySource(folder, loop=False)
    assert replay.is_recording and len(replay) == n and replay.fps == meta["fps"]
    stamps = []
    for k in range(n):
        frame = replay.frame(k)
        stamps.append(stamp_of(frame))
        np.testing.assert_array_equal(frame, source.read(stamps[-1], 0.0))
    assert all(b > a for a, b in zip(stamps, stamps[1:], strict=False)), stamps  # each camera frame once

    # Through --source: what `stereocam serve --source FOLDER` plays, on a fabric at the recording's rate.
    played = camera_source(str(folder))
    assert isinstance(played, ReplaySource) and played.is_recording
    overlay = EmulatedOverlay(source=played, fps=meta["fps"], clock="stepped").start()
    seen: List[int] = []
    try:
        overlay.step()  # a store counts as complete once the channel moves on to the next
        for _ in range(replay.slots[-1] + 1):  # one pass: the recording's length in frame periods
            overlay.step()
            _, raw = overlay.fabric.latest_raw()
            seen.append(stamp_of(raw))
    finally:
        overlay.close()
    in_order = [s for i, s in enumerate(seen) if i == 0 or s != seen[i - 1]]
    assert len(set(seen)) == n and in_order == stamps  # the same frames, in order, once each
    if meta["missed"] == 0:
        assert seen == stamps  # one fabric frame per recorded frame


# -- start, stop, list, download, delete ----------------------------------------------------------

async def test_recording_until_stopped_then_listed_downloaded_and_deleted(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    entry = await record(d)  # no body: until stopped
    rid = entry["id"]
    assert entry["seconds"] is None and entry["state"] == "recording"
    rec = d.app[RECORDER].current
    assert rec is not None and rec.id == rid
    await wait_until("5 frames recorded", lambda: rec.frames >= 5)
    async with d.http.get("/api/recordings") as resp:
        listing = await resp.json()
    assert listing["recording"] == rid and listing["recordings"][0]["id"] == rid
    assert listing["recordings"][0]["state"] == "recording"
    for method, url, status in (("POST", "/api/recordings", 409), (
            "DELETE", f"/api/recordings/{rid}", 409), ("GET", f"/api/recordings/{rid}.zip", 409)):
        async with d.http.request(method, url, json={"seconds": 1} if method == "POST" else None) as resp:
            assert resp.status == status, (method, url, await resp.text())
            error = (await resp.json())["error"]
        assert rid in error and "\n" not in error
    async with d.http.post(f"/api/recordings/{rid}/stop") as resp:
        assert resp.status == 200, await resp.text()
        stopped = await resp.json()
    assert stopped["state"] == "done" and stopped["end"] == "stopped" and stopped["complete"] is True
    assert stopped["frames"] >= 5 and stopped["bytes"] > 0
    assert d.app[RECORDER].current is None
    async with d.http.post(f"/api/recordings/{rid}/stop") as resp:  # idempotent
        assert resp.status == 200 and (await resp.json())["frames"] == stopped["frames"]
    async with d.http.get("/api/recordings") as resp:
        listing = await resp.json()
    assert listing["recording"] is None and [r["id"] for r in listing["recordings"]] == [rid]
    async with d.http.get(f"/api/recordings/{rid}") as resp:
        detail = await resp.json()
    assert detail["meta"]["frames"] == stopped["frames"] and detail["meta"]["end"] == "stopped"
    async with d.http.get(f"/api/recordings/{rid}.zip") as resp:
        assert resp.status == 200 and resp.headers["Content-Type"] == "application/zip"
        data = await resp.read()
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        names = zf.namelist()
        assert names[:2] == [f"{rid}/recording.json", f"{rid}/frames.jsonl"]
        assert len([n for n in names if n.endswith(".png")]) == 2 * stopped["frames"]
        assert json.loads(zf.read(f"{rid}/recording.json"))["id"] == rid
        folder = d.app[RECORDINGS].root / rid
        assert zf.read(f"{rid}/left_000000.png") == (folder / "left_000000.png").read_bytes()
    # Delete with undo, as captures: into the trash, back as it was, once.
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    async with d.http.delete(f"/api/recordings/{rid}") as resp:
        assert resp.status == 204
    assert not folder.exists() and [p.name for p in d.app[RECORDINGS].root.iterdir()] == [".trash"]
    for method, url, status in (("GET", f"/api/recordings/{rid}", 404),
                                ("DELETE", f"/api/recordings/{rid}", 404),
                                ("GET", f"/api/recordings/{rid}.zip", 404),
                                ("POST", f"/api/recordings/{rid}/stop", 404),
                                ("GET", "/api/recordings/..%2F..%2Fetc", 400),
                                ("POST", "/api/recordings/nonsense/stop", 400),
                                ("POST", "/api/recordings/nonsense/restore", 400),
                                ("POST", "/api/recordings/.trash/restore", 400),
                                ("POST", "/api/recordings/20261122T040512Z-000123-ab12/restore", 404)):
        async with d.http.request(method, url) as resp:
            assert resp.status == status, (method, url, await resp.text())
    async with d.http.get("/api/recordings") as resp:
        assert (await resp.json())["recordings"] == []
    evil = {"Origin": "http://evil.example"}
    async with d.http.post(f"/api/recordings/{rid}/restore", headers=evil) as resp:
        assert resp.status == 403  # a change: another origin may not
    async with d.http.post(f"/api/recordings/{rid}/restore") as resp:
        assert resp.status == 200, await resp.text()
        restored = await resp.json()
        assert resp.headers["Location"] == f"/api/recordings/{rid}"
    assert restored["id"] == rid and restored["frames"] == stopped["frames"] and restored["state"] == "done"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    async with d.http.get("/api/recordings") as resp:
        assert [r["id"] for r in (await resp.json())["recordings"]] == [rid]
    async with d.http.post(f"/api/recordings/{rid}/restore") as resp:
        assert resp.status == 404, await resp.text()  # restored already
        assert "not in the trash" in (await resp.json())["error"]
    async with d.http.delete(f"/api/recordings/{rid}") as resp:
        assert resp.status == 204
    async with d.http.get("/api/recordings") as resp:
        assert (await resp.json())["recordings"] == []


async def test_a_recording_makes_the_pipeline_copy_every_frame_then_only_what_is_needed(start_daemon) -> None:
    """Nobody watches: the pipeline only sees frames; recording, it copies each one with its raw pair."""
    d = await start_daemon(overlay=counting_overlay())
    pipeline = d.app[PIPELINE]
    await wait_for_frames(d, 5)
    assert pipeline.frames < pipeline.frames_seen and not pipeline.wants_raw
    entry = await record(d, {"seconds": 1.5})
    assert pipeline.wants_raw
    done = await finished(d, entry["id"])
    assert done["frames"] >= 0.5 * 1.5 * REC_FPS
    assert not pipeline.wants_raw  # released when it ended
    copied = pipeline.frames
    await wait_for_frames(d, pipeline.frames_seen + 5)
    assert pipeline.frames == copied  # nobody needs them again


def test_every_frame_hands_each_copied_frame_to_the_consumer_whatever_the_copy_rate() -> None:
    overlay = counting_overlay(clock="stepped")
    program_default_calibration(overlay, Settings())  # the core runs (it passes nothing through before)
    overlay.start()
    published: List[Any] = []
    got: List[Any] = []
    pipeline = Pipeline(overlay, publish=published.append, copy_rate=lambda: 0.0)  # copies nothing
    pipeline.start()

    def step(n: int) -> None:
        for _ in range(n):
            seen = pipeline.frames_seen
            overlay.step()
            deadline = time.monotonic() + WAIT_S
            while pipeline.frames_seen == seen:
                assert time.monotonic() < deadline, "the pipeline did not see the frame"
                time.sleep(0.005)

    try:
        overlay.step()  # a store counts as complete once the channel moves on to the next
        step(3)
        assert pipeline.frames == 0 and not published
        with pipeline.raw_wanted(), pipeline.every_frame(got.append):
            step(5)
        step(3)
    finally:
        pipeline.stop()
        overlay.close()
    assert len(got) == 5 and got == published  # each handed over, then published, in order
    assert [fs.fabric_count for fs in got] == list(range(got[0].fabric_count, got[0].fabric_count + 5))
    assert all(fs.raw is not None and fs.raw_store is not None for fs in got)
    first = stamp_of(got[0].raw)
    assert [stamp_of(fs.raw) for fs in got] == list(range(first, first + 5))


def test_a_raw_pair_that_comes_twice_is_recorded_once(tmp_path) -> None:
    """The raw channel can complete frame n + 1 before the core finishes frame n: the pipeline then
    hands over frame n with raw n + 1, and frame n + 1 with the same raw store again."""
    overlay = counting_overlay(clock="stepped")
    source = CountingSource()
    pipeline = Pipeline(overlay, publish=lambda fs: None)
    store = recordings_module.RecordingStore(tmp_path / "recordings")
    recorder = recorder_module.Recorder(store, pipeline, raw_stores=3)
    rec = recorder.start(seconds=None, frame_size=SMALL, fps=REC_FPS, frame_no=100)
    assert pipeline.wants_raw
    processed = np.zeros((SMALL[1], SMALL[0], 8), np.uint8)

    def frame_set(count: int, raw_frame: int) -> Any:
        from stereocam.server.frames.pipeline import FrameSet

        return FrameSet(seq=count, frame=count, fabric_count=count, timestamp=time.time(),
                        monotonic=time.monotonic(), source="live", processed=processed,
                        raw=source.read(raw_frame, 0.0), raw_store=raw_frame % 3)

    #          counts 100..105, raw frames: 101 came early with 100, then again with 101
    for count, raw_frame in ((100, 100), (101, 101), (102, 103), (103, 103), (104, 104), (107, 107)):
        rec.offer(frame_set(count, raw_frame))
    rec.stop()
    info = rec.join(WAIT_S)
    overlay.close()
    assert info is not None and info.frames == 5 and not pipeline.wants_raw
    assert info.meta["duplicates"] == 1 and info.meta["missed"] == 3  # 103 (came early) and 105, 106
    replay = ReplaySource(store.root / info.id)
    assert [stamp_of(replay.frame(k)) for k in range(5)] == [100, 101, 103, 104, 107]
    assert list(replay.slots) == [0, 1, 2, 4, 7]  # 107 after a gap of two frame periods


# -- refusals ------------------------------------------------------------------------------------

async def test_a_recording_the_disk_cannot_hold_is_refused_with_nothing_written(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay(), min_free_mb=1e7)  # keep 10 TB free: no disk has that
    await wait_for_frames(d, 3)
    for body in ({"seconds": 10}, None):
        async with d.http.post("/api/recordings", json=body) as resp:
            assert resp.status == 507, await resp.text()
            error = (await resp.json())["error"]
        assert "not enough free space" in error and "delete old recordings" in error and "\n" not in error
    assert list(d.app[RECORDINGS].root.iterdir()) == []  # not even a hidden folder
    async with d.http.get("/api/recordings") as resp:
        assert (await resp.json())["recordings"] == []
    assert not d.app[PIPELINE].wants_raw


async def test_the_disk_filling_while_recording_ends_it_keeping_whole_frames(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    entry = await record(d, {"seconds": 60})
    rec = d.app[RECORDER].current
    await wait_until("4 frames recorded", lambda: rec.frames >= 4)
    d.app[RECORDINGS].min_free_bytes = 10**16  # the free space is now below what must stay free
    done = await finished(d, entry["id"])
    assert done["end"] == "disk_full" and done["complete"] is False and done["frames"] >= 4
    assert "the disk filled after" in done["end_text"] and "they were kept" in done["end_text"]
    folder = d.app[RECORDINGS].root / entry["id"]
    lines = frame_lines(folder)
    assert len(lines) == done["frames"]
    names = {p.name for p in folder.iterdir()}
    images = {line[side] for line in lines for side in ("left", "right")}
    assert names == {"recording.json", "frames.jsonl"} | images
    assert len(ReplaySource(folder)) == done["frames"]  # what was kept plays


async def test_a_disk_full_error_while_writing_leaves_no_half_frame_and_no_empty_recording(
        start_daemon, monkeypatch) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    full: Dict[str, Optional[int]] = {"frame": 3}  # the disk is full from this frame's images on (None: all)
    real_write = recording_files._os_write

    def fills_up(fd: int, data: Any) -> int:
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        image = re.fullmatch(r"(?:left|right)_([0-9]+)\.png", name)
        if full["frame"] is None or (image is not None and int(image.group(1)) >= full["frame"]):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(recording_files, "_os_write", fills_up)
    entry = await record(d, {"seconds": 60})
    done = await finished(d, entry["id"])
    assert done["end"] == "disk_full" and done["frames"] == 3 and done["complete"] is False
    folder = d.app[RECORDINGS].root / entry["id"]
    assert sorted(p.name for p in folder.glob("*.png")) == [
        "left_000000.png", "left_000001.png", "left_000002.png",
        "right_000000.png", "right_000001.png", "right_000002.png"]  # the 4th frame's left is gone too
    assert len(frame_lines(folder)) == 3

    full["frame"] = 0  # from now on no frame fits at all: nothing is kept
    entry = await record(d)
    rec = d.app[RECORDER].current
    await wait_until("the recording gave up", lambda: not rec.running)
    async with d.http.post(f"/api/recordings/{entry['id']}/stop") as resp:
        assert resp.status == 404  # it never became a recording
    async with d.http.get("/api/recordings") as resp:
        listing = await resp.json()
    assert [r["id"] for r in listing["recordings"]] == [done["id"]]
    assert "nothing was recorded: the disk is full" in listing["last_error"]
    assert sorted(p.name for p in d.app[RECORDINGS].root.iterdir()) == [done["id"]]

    full["frame"] = None  # not even recording.json fits: refused at the start, nothing created
    async with d.http.post("/api/recordings") as resp:
        assert resp.status == 507, await resp.text()
        assert "is full (No space left on device): nothing was recorded" in (await resp.json())["error"]
    assert sorted(p.name for p in d.app[RECORDINGS].root.iterdir()) == [done["id"]]


async def test_bad_requests_and_no_signal_are_refused(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    for body, status in (({"seconds": 0}, 400), ({"seconds": -1}, 400), ({"seconds": "10"}, 400),
                         ({"seconds": True}, 400), ({"seconds": 1e9}, 400), ({"secs": 1}, 400), ([1], 400)):
        async with d.http.post("/api/recordings", json=body) as resp:
            assert resp.status == status, (body, await resp.text())
    async with d.http.post("/api/recordings", data=b"seconds=1",
                           headers={"Content-Type": "application/x-www-form-urlencoded"}) as resp:
        assert resp.status == 415
    bad_json = {"Content-Type": "application/json"}
    async with d.http.post("/api/recordings", data=b"{nope", headers=bad_json) as resp:
        assert resp.status == 400
    d.overlay.emulation.cameras_running = False
    await wait_until("no signal", lambda: not d.app[PIPELINE].last_frame_age() or
                     d.app[PIPELINE].last_frame_age() > 2 * d.config.no_signal_s)
    async with d.http.post("/api/recordings", json={"seconds": 1}) as resp:
        assert resp.status == 503 and "no signal" in (await resp.json())["error"]
    assert list(d.app[RECORDINGS].root.iterdir()) == []


# -- the virtual camera plays a recording ----------------------------------------------------------

async def test_the_virtual_camera_plays_a_recording_through_the_core_at_its_rate(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    rid = (await record(d, {"seconds": 2}))["id"]
    done = await finished(d, rid)
    n = done["frames"]
    assert n >= 5
    folder = d.app[RECORDINGS].root / rid
    recorded = [stamp_of(ReplaySource(folder).frame(k)) for k in range(n)]

    async with d.http.post("/api/virtual-camera", json={"recording": rid}) as resp:
        assert resp.status == 200, await resp.text()
        body = await resp.json()
    assert body["input"] == f"recording {rid}" and body["source"] == "virtual"
    assert body["playing"]["recording"] == rid and body["playing"]["frames"] == n
    vc = d.app[VIRTUAL]
    player = vc.player
    started = time.monotonic()
    shown: List[int] = []
    while player.loops < 1:  # one whole loop, watching the virtual camera's input
        stamp = stamp_of(vc.input)
        if not shown or shown[-1] != stamp:
            shown.append(stamp)
        assert time.monotonic() - started < WAIT_S + done["duration_s"], "no loop within the bound"
        await asyncio.sleep(0.01)
    took = time.monotonic() - started
    assert took >= 0.8 * done["duration_s"] - 0.2  # at the recording's rate, not as fast as possible
    assert set(shown) <= set(recorded)
    positions = [recorded.index(s) for s in shown]
    assert positions == sorted(positions) or positions.index(0) > 0  # in order (the loop may wrap once)
    assert len(set(shown)) >= 0.5 * n  # a poll every 10 ms sees most of them
    async with d.http.get("/api/virtual-camera") as resp:
        state = await resp.json()
    assert state["playing"]["recording"] == rid and state["playing"]["loops"] >= 1
    async with d.http.get("/snapshot/raw_left.png") as resp:  # the raw views show the recording
        assert resp.status == 200

    async with d.http.post("/api/verify") as resp:  # Verify checks still inputs only
        assert resp.status == 409 and "playing" in (await resp.json())["error"]
    async with d.http.delete(f"/api/recordings/{rid}") as resp:
        assert resp.status == 409 and "playing" in (await resp.json())["error"]
    async with d.http.put("/api/source", json={"source": "live"}) as resp:  # another source ends it
        assert resp.status == 200
    assert vc.player is None and not player.running and player.error is None
    async with d.http.get("/api/virtual-camera") as resp:
        assert (await resp.json())["playing"] is None
    async with d.http.delete(f"/api/recordings/{rid}") as resp:
        assert resp.status == 204

    for body, status in (({"recording": rid}, 404), ({"recording": "../x"}, 400), ({"recording": 5}, 400),
                         ({"recording": rid, "capture": rid}, 400)):
        async with d.http.post("/api/virtual-camera", json=body) as resp:
            assert resp.status == status, (body, await resp.text())


async def test_a_new_upload_stops_the_recording_playing(start_daemon) -> None:
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    rid = (await record(d, {"seconds": 1.5}))["id"]
    await finished(d, rid)
    async with d.http.post("/api/virtual-camera", json={"recording": rid}) as resp:
        assert resp.status == 200, await resp.text()
    player = d.app[VIRTUAL].player
    await wait_until("a few frames played", lambda: player.shown >= 3)
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    async with d.http.post("/api/virtual-camera", json={"capture": cid}) as resp:
        assert resp.status == 200
    assert d.app[VIRTUAL].player is None and not player.running
    async with d.http.post("/api/verify") as resp:
        assert (await resp.json())["identical"] is True


def test_a_damaged_recording_folder_is_named_when_replayed(tmp_path) -> None:
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "recording.json").write_text(json.dumps({"format": "stereocam-recording/1", "fps": 10,
                                                       "frame_size": [8, 8], "frames": 1}))
    line = {"fabric_count": 1, "left": "../x.png", "right": "r.png"}
    (folder / "frames.jsonl").write_text(json.dumps(line))
    with pytest.raises(ReplayError, match="outside the recording"):
        ReplaySource(folder)
    (folder / "frames.jsonl").write_text("")
    with pytest.raises(ReplayError, match="holds no frames"):
        ReplaySource(folder)
    # A frame count of Infinity (Python's json reads it): damaged, not an OverflowError.
    (folder / "frames.jsonl").write_text('{"fabric_count": Infinity, "left": "l.png", "right": "r.png"}\n')
    with pytest.raises(ReplayError, match=r"line 1 of frames.jsonl is damaged \(cannot convert float inf"):
        ReplaySource(folder)
    # The frames file is the recording's own too: no path out of it.
    for name in ("../frames.jsonl", "/etc/passwd", ".hidden"):
        (folder / "recording.json").write_text(json.dumps({
            "format": "stereocam-recording/1", "fps": 10, "frame_size": [8, 8], "frames_file": name}))
        with pytest.raises(ReplayError, match=r"names a frames file .* outside the recording"):
            ReplaySource(folder)


def _standard_json(text: str) -> Any:
    """``text`` as JSON a browser's ``JSON.parse`` takes: no NaN, Infinity or -Infinity."""
    def refuse(constant: str) -> None:
        raise AssertionError(f"{constant} in a response: not JSON, JSON.parse refuses the whole body")

    return json.loads(text, parse_constant=refuse)


async def test_a_damaged_recording_json_with_nan_is_listed_as_standard_json(start_daemon) -> None:
    """Python's json reads NaN and Infinity; a recording.json holding them (damaged, or written by
    hand) made GET /api/recordings send them back, and the page could not read its list."""
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    rid = (await record(d, {"seconds": 0.2}))["id"]
    await wait_until("the recording done", lambda: d.app[RECORDER].current is None)
    meta_file = d.app[RECORDINGS].root / rid / "recording.json"
    doc = json.loads(meta_file.read_text())
    doc.update(fps=float("inf"), duration_s=float("nan"), seconds=-float("inf"))
    meta_file.write_text(json.dumps(doc))  # json.dumps writes Infinity and NaN
    for url in ("/api/recordings", f"/api/recordings/{rid}"):
        async with d.http.get(url) as resp:
            assert resp.status == 200
            body = _standard_json(await resp.text())
        entry = body["recordings"][0] if "recordings" in body else body
        assert entry["id"] == rid and entry["fps"] is None and entry["seconds"] is None
        assert entry["frames"] >= 1


# -- a playing that fails, and downloads cut short -------------------------------------------------------

async def test_a_playing_that_fails_is_reported_until_the_next_input(start_daemon) -> None:
    """A damaged frame stops the playing; before, GET /api/virtual-camera then said ``playing: null``."""
    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    rid = (await record(d, {"seconds": 1.5}))["id"]
    assert (await finished(d, rid))["frames"] >= 4
    folder = d.app[RECORDINGS].root / rid
    whole = (folder / "left_000002.png").read_bytes()
    (folder / "left_000002.png").write_bytes(whole[:100])  # its header is whole, its pixels are not
    async with d.http.post("/api/virtual-camera", json={"recording": rid}) as resp:
        assert resp.status == 200, await resp.text()
    player = d.app[VIRTUAL].player
    await wait_until("the playing stopped at the damaged frame", lambda: player.error)
    for url in ("/api/virtual-camera", "/api/status"):
        async with d.http.get(url) as resp:
            body = await resp.json()
        playing = body["playing"] if "playing" in body else body["virtual_camera"]["playing"]
        assert playing is not None and playing["recording"] == rid and playing["running"] is False
        assert f"playing recording {rid} stopped at frame 2" in playing["error"]
        assert "left_000002.png" in playing["error"] and "\n" not in playing["error"]
    async with d.http.get("/api/virtual-camera") as resp:  # still there: until the next input
        assert (await resp.json())["playing"]["error"] == playing["error"]
    async with d.http.put("/api/source", json={"source": "live"}) as resp:
        assert resp.status == 200
    async with d.http.get("/api/virtual-camera") as resp:
        assert (await resp.json())["playing"] is None

    (folder / "left_000000.png").write_bytes((folder / "left_000001.png").read_bytes()[:100])
    async with d.http.post("/api/virtual-camera", json={"recording": rid}) as resp:  # before: a 500
        assert resp.status == 422, await resp.text()
        error = (await resp.json())["error"]
    assert error.startswith(f"recording {rid} cannot be replayed: ") and "left_000000.png" in error


async def test_a_download_the_client_gives_up_ends_quietly(start_daemon, monkeypatch, caplog) -> None:
    """A cancelled zip download: ``drain()`` raises a ConnectionError, which logged an ERROR traceback."""
    from aiohttp import ClientError, web

    d = await start_daemon(overlay=counting_overlay())
    await wait_for_frames(d, 3)
    rid = (await record(d, {"seconds": 0.5}))["id"]
    await finished(d, rid)
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    real_write = web.StreamResponse.write
    gone: List[str] = []

    async def client_gone(self: web.StreamResponse, data: bytes) -> None:
        if self.content_type == "application/zip":  # what drain() raises once the client is gone
            gone.append(self.headers["Content-Disposition"])
            raise ConnectionError("Connection lost") if len(gone) % 2 else BrokenPipeError(32, "Broken pipe")
        await real_write(self, data)

    monkeypatch.setattr(web.StreamResponse, "write", client_gone)
    with caplog.at_level(logging.DEBUG):
        for url in (f"/api/recordings/{rid}.zip", f"/api/captures/{cid}.zip") * 2:
            with pytest.raises(ClientError):  # the connection closes: never a whole, shorter zip
                async with d.http.get(url) as resp:
                    await resp.read()
    assert len(gone) == 4
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []
    monkeypatch.setattr(web.StreamResponse, "write", real_write)
    async with d.http.get(f"/api/recordings/{rid}.zip") as resp:  # the next download is whole
        assert resp.status == 200 and zipfile.ZipFile(io.BytesIO(await resp.read())).testzip() is None
