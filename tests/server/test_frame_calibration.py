"""The calibration a frame ran with is one immutable record (issue 21, item 3): a capture's meta.json,
a recording's frames.jsonl line and recording.json, and the page's depth readout carry the same
:class:`~stereocam.server.stores.frame_calibration.FrameCalibration` for the same frame; it
round-trips through its one stored form, files written before read back as they were, and a
broken calibration field in an old file is refused with one line or read as absent, as before.
"""
from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import pytest

from stereocam.calibration.file import Calibration
from stereocam.calibration.stereo import rectify
from stereocam.server.frames.capturing import CaptureService
from stereocam.server.frames.pipeline import FrameSet
from stereocam.server.frames.recorder import Recorder, Recording
from stereocam.server.http.routes_viewer import depth_readout
from stereocam.server.http.state import CALIBRATION, CalibrationState
from stereocam.server.stores.captures import CaptureStore
from stereocam.server.stores.frame_calibration import FrameCalibration
from stereocam.server.stores.recordings import RecordingStore

from .daemon import SMALL, WAIT_S, HandFeed, rig_frame, wait_for_frames

# The two shapes stereocam has written as a capture's (and recording.json's) "calibration", as in
# the files: a known calibration, and a frame that ran while one was being programmed.
OLD_KNOWN = {"id": "synthetic-rig-0123456789ab", "description": "the synthetic rig's known calibration",
             "rows_needed": 41, "lb_rows": 80, "lb_delay": 22}
OLD_NONE = {"id": None, "description": "none: the core passes frames through unrectified",
            "rows_needed": None, "lb_rows": 80, "lb_delay": None}
OLD_UNKNOWN = {"id": None, "description": "unknown: the calibration changed while this frame was processed"}


def rig_calibration(units: str = "m") -> Calibration:
    model = rig_frame(SMALL)[1]
    return Calibration.derive(model, rectify(model, alpha=0.0), alpha=0.0, units=units, source="test rig")


def state_of(cal_id: str, units: str = "m") -> CalibrationState:
    return CalibrationState(id=cal_id, description=f"test {cal_id}", rows_needed=41, lb_rows=80, lb_delay=22,
                            calibration=rig_calibration(units))


# -- the record ------------------------------------------------------------------------------------

@pytest.mark.parametrize("doc", [OLD_KNOWN, OLD_NONE, OLD_UNKNOWN], ids=["known", "none", "unknown"])
def test_a_stored_calibration_reads_back_to_the_record_that_writes_it_again_byte_for_byte(doc) -> None:
    record = FrameCalibration.from_json(json.loads(json.dumps(doc)))
    assert json.dumps(record.to_json()) == json.dumps(doc)  # the same keys, in the same order
    assert FrameCalibration.from_json(record.to_json()) == record
    assert record.known is (doc is not OLD_UNKNOWN)


def test_the_record_of_a_calibration_in_effect_round_trips_and_cannot_change() -> None:
    state = state_of("A")
    record = state.frame_calibration
    assert record.to_json() == {"id": "A", "description": "test A", "rows_needed": 41, "lb_rows": 80,
                                "lb_delay": 22} == state.to_json()
    back = FrameCalibration.from_json(json.loads(json.dumps(record.to_json())))
    assert back == record  # what a file keeps; the depth scale is not in it
    assert back.depth is None and record.depth is not None
    # Its depth scale, from Q: Z = f B / d.
    Q = np.asarray(rig_calibration().rect.Q, dtype=np.float64)
    assert record.depth.Q == tuple(tuple(row) for row in Q.tolist()) and isinstance(record.depth.Q[0], tuple)
    assert record.depth.focal_px == Q[2, 3] and record.depth.baseline_m == pytest.approx(1 / abs(Q[3, 2]))
    assert record.depth_unavailable is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        record.id = "B"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        record.depth.units = "mm"  # type: ignore[misc,union-attr]
    # Without a unit there is a focal length but no baseline, and the record says why.
    vague = state_of("A", units="unknown").frame_calibration
    assert vague.depth is not None and vague.depth.baseline_m is None and "units: unknown" in str(
        vague.depth_unavailable)
    assert "no calibration is known" in str(CalibrationState().frame_calibration.depth_unavailable)


@pytest.mark.parametrize("change, says", [
    ({"id": 7}, "id is a string or null"),
    ({"description": ["x"]}, "description is a string"),
    ({"rows_needed": True}, "rows_needed is a whole"),
    ({"lb_rows": "80"}, "lb_rows is a whole"),
    ({"lb_delay": 1.5}, "lb_delay is a whole"),
    ({"description": None}, "description is a string"),
], ids=["id", "description", "bool", "text", "float", "null-description"])
def test_a_broken_calibration_field_is_refused_with_one_line_naming_it(change, says) -> None:
    with pytest.raises(ValueError) as err:
        FrameCalibration.from_json({**OLD_KNOWN, **change})
    assert says in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("doc, says", [
    (["A"], "a JSON object, not list"),
    ("A", "a JSON object, not str"),
    (None, "a JSON object, not NoneType"),
    ({"id": "A"}, "without a description"),
], ids=["list", "str", "null", "no-description"])
def test_what_is_not_a_calibration_is_refused_with_one_line(doc, says) -> None:
    with pytest.raises(ValueError) as err:
        FrameCalibration.from_json(doc)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_broken_calibration_in_an_old_capture_reads_as_absent_and_the_listing_is_as_before(
        tmp_path: Path) -> None:
    store = CaptureStore(tmp_path / "captures")
    frames = {name: np.zeros((4, 6), np.uint8) for name in ("raw_left", "raw_right", "rect_left",
                                                            "rect_right")}
    good = store.save(frames, {"frame": 1, "source": "live", "calibration_id": "A", "calibration": OLD_KNOWN})
    broken = store.save(frames, {"frame": 2, "source": "live", "calibration_id": "A",
                                 "calibration": {"id": {"$gt": ""}, "description": 5}})
    old = store.save(frames, {"frame": 3, "source": "live", "calibration_id": None})
    meta_file = store.path(old.id) / "meta.json"  # edited by hand: an id no daemon wrote, no calibration
    doc = json.loads(meta_file.read_text())
    doc["calibration_id"] = 9
    meta_file.write_text(json.dumps(doc))
    listed = {info.id: info for info in store.list()}
    assert listed[good.id].calibration == FrameCalibration.from_json(OLD_KNOWN)
    assert listed[broken.id].calibration is None and listed[broken.id].error is None
    assert listed[broken.id].calibration_id == "A"  # read as before: the listing's field is its own
    assert listed[old.id].calibration is None and listed[old.id].calibration_id is None
    stored = store.get(broken.id).to_json(meta=True)["meta"]["calibration"]
    assert stored == {"id": {"$gt": ""}, "description": 5}  # kept and served as it is


# -- one frame, three consumers ---------------------------------------------------------------------

def frame_set(count: int) -> FrameSet:
    """Frame ``count`` (its FRAME_COUNT), grabbed now, from the virtual camera (raw: its input)."""
    frame = rig_frame(SMALL)[0]
    return FrameSet(seq=count, frame=count, fabric_count=count, timestamp=time.time(),
                    monotonic=time.monotonic(), source="virtual", processed=frame, raw=frame)


class InEffect:
    """The capture service's calibration source over one fixed state."""

    def __init__(self, state: CalibrationState) -> None:
        self.now = state

    def for_frame(self, count: int) -> Optional[FrameCalibration]:
        return self.now.for_frame(count)


def capture(tmp_path: Path, state: CalibrationState, fs: FrameSet) -> Dict[str, Any]:
    async def run(fn: Callable[..., Any], *args: Any) -> Any:
        return fn(*args)

    overlay = SimpleNamespace(rectify=SimpleNamespace(dump=dict), backend="test", stereo=None)
    service = CaptureService(feed=None, pipeline=None, overlay=overlay,  # type: ignore[arg-type]
                             virtual=SimpleNamespace(origin={"kind": "test"}),  # type: ignore[arg-type]
                             calibration=InEffect(state), run=run, frame_wait_s=lambda: 1.0)
    store = CaptureStore(tmp_path / "captures")
    info = asyncio.run(service.store(store, fs))
    return dict(store.get(info.id).meta)


def record(tmp_path: Path, state: CalibrationState, frames: List[FrameSet]) -> List[Dict[str, Any]]:
    """Record ``frames`` (grabbed again now: a recording takes frames grabbed after its start); the
    recording.json and frames.jsonl lines written for them."""
    feed = HandFeed()
    store = RecordingStore(tmp_path / "recordings")
    rec: Recording = Recorder(store, feed, calibration_for=state.for_frame).start(
        seconds=None, frame_size=SMALL, fps=10.0, frame_no=frames[0].frame)
    for fs in frames:
        before = rec.frames
        assert feed.sink is not None
        feed.sink(frame_set(fs.fabric_count))
        deadline = time.monotonic() + WAIT_S
        while rec.frames == before:
            assert time.monotonic() < deadline, "the frame was not written"
            time.sleep(0.01)
    rec.stop()
    assert rec.join(WAIT_S) is not None
    folder = store.root / rec.id
    lines = [json.loads(line) for line in (folder / "frames.jsonl").read_text().splitlines()]
    return [json.loads((folder / "recording.json").read_text())] + lines


def test_a_capture_a_recording_and_the_point_readout_of_a_frame_carry_its_one_record(tmp_path: Path) -> None:
    """Frames 9 (of calibration A, before the change) and 20 (of B, in effect), each through all three."""
    state = state_of("A").changing_from_count(10).succeeded_by(state_of("B"), 10, 14)
    first, second = frame_set(9), frame_set(20)
    recorded = record(tmp_path, state, [first, second])
    doc, lines = recorded[0], recorded[1:]
    for fs, line, cal_id in ((first, lines[0], "A"), (second, lines[1], "B")):
        ran = state.for_frame(fs.fabric_count)
        assert ran is not None and ran.id == cal_id
        meta = capture(tmp_path / str(fs.frame), state, fs)
        assert FrameCalibration.from_json(meta["calibration"]) == ran and meta["calibration_id"] == cal_id
        assert line["fabric_count"] == fs.fabric_count and line["calibration_id"] == cal_id
        readout = depth_readout(ran, state.frame_calibration)
        assert readout["calibration_id"] == cal_id
    # recording.json keeps the first frame's record, whole; both ids seen.
    assert FrameCalibration.from_json(doc["calibration"]) == state.for_frame(first.fabric_count)
    assert doc["calibration_ids"] == ["A", "B"]
    # The readout: depth only under the calibration in effect, by its record's scale.
    b = state.frame_calibration
    assert b.depth is not None
    assert depth_readout(state.for_frame(20), b) == {"calibration_id": "B", "focal_px": b.depth.focal_px,
                                                     "baseline_m": b.depth.baseline_m}
    assert "hover again" in depth_readout(state.for_frame(9), b)["depth_unavailable"]


def test_a_frame_of_a_change_in_progress_is_unknown_everywhere(tmp_path: Path) -> None:
    state = state_of("A").changing_from_count(10)
    fs = frame_set(12)
    assert state.for_frame(12) is None
    meta = capture(tmp_path, state, fs)
    assert meta["calibration"] == OLD_UNKNOWN and meta["calibration_id"] is None  # as captures always wrote
    assert FrameCalibration.from_json(meta["calibration"]) == FrameCalibration.unknown()
    doc, line = record(tmp_path, state, [fs])
    assert line["calibration_id"] is None and doc["calibration"] is None and doc["calibration_ids"] == [None]
    readout = depth_readout(None, state.frame_calibration)
    assert readout["calibration_id"] is None and readout["focal_px"] is None
    assert "hover again" in readout["depth_unavailable"]


def test_a_recovered_recording_keeps_its_calibration_or_reads_a_broken_one_as_absent(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """A crash leaves recording.json as the start wrote it; the recovery reads its calibration back."""
    def dies(rec: Recording) -> None:  # finishing never happens: the process is gone
        rec.close_files()
        rec._on_end(rec)
        rec._done.set()

    state = state_of("A")
    kept = {}
    for name, broken in (("sound", False), ("broken", True)):
        root = tmp_path / name
        store = RecordingStore(root)
        feed = HandFeed()
        with monkeypatch.context() as m:
            m.setattr(Recording, "_finish", dies)
            rec = Recorder(store, feed, calibration_for=state.for_frame).start(
                seconds=None, frame_size=SMALL, fps=10.0, frame_no=5)
            assert feed.sink is not None
            feed.sink(frame_set(5))
            deadline = time.monotonic() + WAIT_S
            while rec.frames == 0:
                assert time.monotonic() < deadline
                time.sleep(0.01)
            rec.stop()
            rec.join(WAIT_S)
        meta_file = root / f".incoming-{rec.id}" / "recording.json"
        start = json.loads(meta_file.read_text())
        assert start["calibration"] == state.to_json()
        if broken:
            start["calibration"] = {"id": ["A"], "description": "x"}
            meta_file.write_text(json.dumps(start))
        with caplog.at_level(logging.WARNING):
            RecordingStore(root)  # the next start recovers it
        kept[name] = json.loads((root / rec.id / "recording.json").read_text())
    assert kept["sound"]["end"] == "interrupted" and kept["sound"]["calibration"] == state.to_json()
    assert kept["broken"]["end"] == "interrupted" and kept["broken"]["calibration"] is None
    assert kept["broken"]["calibration_id"] == "A"  # from its frames' lines, as before
    assert "its calibration in recording.json is not one (a calibration id is a string or null" in caplog.text


# -- the daemon --------------------------------------------------------------------------------------

async def test_the_daemon_s_capture_status_and_depth_scale_carry_the_record_in_effect(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 2)
    record_now = d.app[CALIBRATION].now.frame_calibration
    assert record_now.id and record_now.depth is not None
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201, await resp.text()
        cid = (await resp.json())["id"]
    async with d.http.get(f"/api/captures/{cid}") as resp:
        meta = (await resp.json())["meta"]
    assert FrameCalibration.from_json(meta["calibration"]) == record_now == d.app[CALIBRATION].now.for_frame(
        meta["fabric_count"])
    async with d.http.get("/api/status") as resp:
        status = (await resp.json())["calibration"]
    assert FrameCalibration.from_json(status) == record_now
    async with d.http.get("/api/disparity") as resp:
        scale = await resp.json()
    assert (scale["calibration_id"], scale["focal_px"], scale["baseline_m"], scale["doffs_px"]) == (
        record_now.id, record_now.depth.focal_px, record_now.depth.baseline_m, record_now.depth.doffs_px)
