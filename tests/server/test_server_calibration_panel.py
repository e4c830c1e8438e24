"""The page's calibration panel over HTTP: live corners, pairs, coverage, compute, figures, apply.

Checkerboard views of the synthetic rig (known calibration, tests/sample.py)
go in through the virtual camera, so the raw frames the panel works on are
exactly those images; the calibration computed from them must come back to
the rig's truth, and applying it must program the core and survive a restart.
"""
from __future__ import annotations

import asyncio
import dataclasses
import json
import time
from typing import Callable

import cv2
import numpy as np
import pytest

from stereocam.calibration.calibrate import CalibrationReport, Pattern, detect_corners
from stereocam.calibration.file import Calibration, load_calibration
from stereocam.calibration.stereo import rectify
from stereocam.cli import main as cli_main
from stereocam.server.http import routes_calibration, routes_calibration_panel
from stereocam.server.http.app import default_extensions, program_default_calibration
from stereocam.server.http.routes_calibration_panel import PANEL, Candidate
from stereocam.server.http.settings import Settings
from stereocam.server.stores.calibration_pairs import SETTINGS_FILE

from ..sample import SYNTH_SQUARE, synthetic_views
from .daemon import FULL, WAIT_S, make_overlay, show_pair  # noqa: F401

pytestmark = pytest.mark.slow

EXT = (routes_calibration.setup, routes_calibration_panel.setup)
PATTERN = Pattern(9, 6, SYNTH_SQUARE)


# Full-size frames at 20 fps: on a busy machine the emulated fabric may take over a second for one,
# and with the default no_signal_s (0.5 s) a pair or a corners poll waits only 1 s for a fresh frame
# (max(1 s, 2 * no_signal_s)) and answers 503 "no signal". 5 s: they wait up to 10 s.
NO_SIGNAL_S = 5.0


async def start(start_daemon, **settings):
    settings.setdefault("no_signal_s", NO_SIGNAL_S)
    return await start_daemon(overlay=make_overlay(size=FULL, fps=20.0, calibrate=False), extensions=EXT,
                              **settings)


async def show_nothing(daemon) -> None:
    """Back to the live cameras (stopped by the test): wait until the daemon says no signal."""
    async with daemon.http.put("/api/source", json={"source": "live"}) as r:
        assert r.status == 200
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        async with daemon.http.get("/api/status") as r:
            if not (await r.json())["signal"]:
                return
        await asyncio.sleep(0.05)
    raise AssertionError(f"the daemon did not lose the signal within {WAIT_S} s")


async def corners_when(daemon, condition: Callable[[dict], bool]) -> dict:
    """``GET /api/calibration/corners`` until its answer meets ``condition`` (within WAIT_S): that answer."""
    deadline = time.monotonic() + WAIT_S
    while True:
        async with daemon.http.get("/api/calibration/corners") as r:
            body = await r.json()
        if r.status == 200 and condition(body):
            return body
        assert time.monotonic() < deadline, f"no such answer within {WAIT_S} s: {r.status} {body}"
        await asyncio.sleep(0.05)


async def session(daemon, token: "str | None" = None) -> dict:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    async with daemon.http.get("/api/calibration/session", headers=headers) as r:
        assert r.status == 200
        return await r.json()


async def put_settings(daemon, doc) -> "tuple[int, dict]":
    async with daemon.http.put("/api/calibration/session", data=json.dumps(doc),
                               headers={"Content-Type": "application/json"}) as r:
        return r.status, await r.json()


async def late(body: bytes):
    """A request body that arrives 0.3 s after the headers."""
    await asyncio.sleep(0.3)
    yield body


async def capture_pair(daemon) -> "tuple[int, dict]":
    async with daemon.http.post("/api/calibration/pairs") as r:
        return r.status, await r.json()


def test_the_panel_is_a_default_extension() -> None:
    assert routes_calibration_panel.setup in default_extensions()


async def test_settings_default_validate_and_persist(start_daemon, tmp_path) -> None:
    daemon = await start(start_daemon)
    body = await session(daemon)
    assert body["settings"] == {"pattern": "9x6", "square_mm": 25.0, "alpha": 0.0}
    assert body["count"] == 0 and body["pairs"] == [] and body["image_size"] == list(FULL)
    assert body["coverage"]["left"] == 0 and body["coverage"]["right"] == 0
    assert body["folder"] == str(tmp_path / "calibration-pairs")

    status, body = await put_settings(daemon, {"pattern": "7x5", "square_mm": 30, "alpha": 0.5})
    assert status == 200 and body["settings"] == {"pattern": "7x5", "square_mm": 30.0, "alpha": 0.5}
    for bad, words in (({"pattern": "7by5"}, "COLSxROWS"), ({"pattern": "2x5"}, "3x3"),
                       ({"square_mm": -1}, "square_mm"), ({"square_mm": "25"}, "square_mm"),
                       ({"square_mm": 1e-300}, "square_mm"),
                       ({"alpha": 1.5}, "alpha"), ({"colour": 1}, "unknown field"), ([1, 2], "JSON object")):
        status, err = await put_settings(daemon, bad)
        assert status == 400 and words in err["error"], (bad, err)
    async with daemon.http.put("/api/calibration/session", data=b"{not json",
                               headers={"Content-Type": "application/json"}) as r:
        assert r.status == 400 and "not valid JSON" in (await r.json())["error"]
    assert (await session(daemon))["settings"] == {"pattern": "7x5", "square_mm": 30.0, "alpha": 0.5}
    # Two changes at once, bodies arriving late: both are kept.
    replies = await asyncio.gather(
        daemon.http.put("/api/calibration/session", data=late(b'{"pattern": "8x5"}'),
                        headers={"Content-Type": "application/json"}),
        daemon.http.put("/api/calibration/session", data=late(b'{"alpha": 0.25}'),
                        headers={"Content-Type": "application/json"}))
    assert [r.status for r in replies] == [200, 200]
    for r in replies:
        r.release()
    both = {"pattern": "8x5", "square_mm": 30.0, "alpha": 0.25}
    assert (await session(daemon))["settings"] == both
    assert json.loads((tmp_path / "calibration-pairs" / SETTINGS_FILE).read_text()) == both
    await daemon.stop()

    again = await start(start_daemon)  # the same folders: the settings come back
    assert (await session(again))["settings"] == both
    (tmp_path / "calibration-pairs" / SETTINGS_FILE).write_text("{broken")
    await again.stop()
    third = await start(start_daemon)  # an unreadable settings file: the defaults, and the daemon starts
    assert (await session(third))["settings"]["pattern"] == "9x6"


async def test_live_corners_on_the_scene_and_on_a_board(start_daemon) -> None:
    daemon = await start(start_daemon)
    async with daemon.http.get("/api/calibration/corners") as r:
        assert r.status == 200
        body = await r.json()
    assert body["found"] is False and body["left"] is None and body["right"] is None  # the scene: no board
    assert body["image_size"] == list(FULL) and body["pattern"] == "9x6"

    _, views = synthetic_views()
    left, right = views[0]
    await show_pair(daemon, left, right)
    body = await corners_when(daemon, lambda b: b["source"] == "virtual")  # the scene's answer has expired
    assert body["found"] is True and body["source"] == "virtual"
    got = np.asarray(body["left"])
    want = detect_corners(left, PATTERN, thorough=False)
    assert want is not None and got.shape == (54, 2)
    assert np.abs(got - want).max() <= 0.006  # the same detector, rounded to 1/100 px
    assert np.asarray(body["right"]).shape == (54, 2)

    # Without signal the answer is an immediate 503, not a queue of pollers waiting for frames.
    daemon.overlay.emulation.cameras_running = False
    await show_nothing(daemon)
    capture_wait = max(1.0, 2 * daemon.config.no_signal_s)  # how long a capture waits for a frame
    await asyncio.sleep(capture_wait)
    t0 = asyncio.get_running_loop().time()
    async with daemon.http.get("/api/calibration/corners") as r:
        assert r.status == 503 and "no signal" in (await r.json())["error"]
    assert asyncio.get_running_loop().time() - t0 < capture_wait, "the poll waited for a frame"
    daemon.overlay.emulation.cameras_running = True
    await show_pair(daemon, left, right)

    # Many pollers at once share one detection.
    await corners_when(daemon, lambda b: b.get("found") is True)  # the signal is back
    replies = await asyncio.gather(*(daemon.http.get("/api/calibration/corners") for _ in range(6)))
    frames = set()
    for r in replies:
        frames.add((await r.json())["frame"])
        r.release()
    assert len(frames) == 1


async def test_pairs_are_refused_without_the_board_and_when_the_view_repeats(start_daemon, tmp_path) -> None:
    daemon = await start(start_daemon)
    status, err = await capture_pair(daemon)
    assert status == 422 and "not found in either image" in err["error"]
    assert "nothing was stored" in err["error"]
    assert (await session(daemon))["count"] == 0
    assert not any(p.name[0].isdigit() for p in (tmp_path / "calibration-pairs").iterdir())

    _, views = synthetic_views()
    blank = np.full_like(views[0][1], 128)
    await show_pair(daemon, views[0][0], blank)
    status, err = await capture_pair(daemon)
    assert status == 422 and "the right image" in err["error"]

    await show_pair(daemon, *views[0])
    status, body = await capture_pair(daemon)
    assert status == 201, body
    assert body["count"] == 1 and body["pair"]["pattern"] == "9x6"
    assert np.asarray(body["pair"]["corners"]["left"]).shape == (54, 2)
    assert 0 < body["coverage"]["left"] < 1 and 0 < body["coverage"]["right"] < 1
    pid, first_cover = body["pair"]["id"], body["coverage"]
    folder = tmp_path / "calibration-pairs" / pid
    stored = {p.name for p in folder.iterdir()}
    assert {"raw_left.png", "raw_right.png", "rect_left.png", "meta.json"} <= stored
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["purpose"] == "calibration-pair" and meta["source"] == "virtual"
    assert np.array_equal(cv2.imread(str(folder / "raw_left.png"), cv2.IMREAD_GRAYSCALE), views[0][0])

    status, err = await capture_pair(daemon)  # the board has not moved
    assert status == 409 and pid in err["error"]
    await show_pair(daemon, *views[1])
    status, body = await capture_pair(daemon)
    assert status == 201 and body["count"] == 2
    assert body["coverage"]["left"] > first_cover["left"] and body["coverage"]["right"] > first_cover["right"]

    async with daemon.http.delete(f"/api/calibration/pairs/{pid}") as r:
        assert r.status == 204
    assert [p["id"] for p in (await session(daemon))["pairs"]] == [body["pair"]["id"]]
    for bad, code in (("../captures", 404), ("nope", 400), (pid, 404)):
        async with daemon.http.delete(f"/api/calibration/pairs/{bad}") as r:
            assert r.status == code, bad
    async with daemon.http.delete("/api/calibration/pairs") as r:
        assert r.status == 204
    assert (await session(daemon))["count"] == 0


async def test_compute_review_apply_and_restart(start_daemon, tmp_path) -> None:
    daemon = await start(start_daemon)
    truth, views = synthetic_views()
    status, _ = await put_settings(daemon, {"square_mm": SYNTH_SQUARE * 1000})
    assert status == 200

    for left, right in views[:3]:
        await show_pair(daemon, left, right)
        assert (await capture_pair(daemon))[0] == 201
    async with daemon.http.post("/api/calibration/compute") as r:
        assert r.status == 422
        assert "at least 5" in (await r.json())["error"]
    async with daemon.http.get("/api/calibration/compute") as r:
        assert (await r.json())["state"] == "failed"
    async with daemon.http.get("/api/calibration/candidate") as r:
        assert r.status == 404

    for left, right in views[3:8]:
        await show_pair(daemon, left, right)
        assert (await capture_pair(daemon))[0] == 201
    cover = (await session(daemon))["coverage"]
    # Two computes at once, their bodies arriving late (both handlers wait in the read): one runs,
    # the other is told to wait.
    first, second = await asyncio.gather(daemon.http.post("/api/calibration/compute", data=late(b"{}")),
                                         daemon.http.post("/api/calibration/compute", data=late(b"{}")))
    assert sorted([first.status, second.status]) == [200, 409]
    busy = first if first.status == 409 else second
    assert "already being computed" in (await busy.json())["error"]
    first.release()
    second.release()
    # While a compute runs, its pairs cannot be deleted (and nothing else waits for it).
    pairs = (await session(daemon))["pairs"]
    running = asyncio.ensure_future(daemon.http.post("/api/calibration/compute"))
    while True:
        async with daemon.http.get("/api/calibration/compute") as r:
            p = await r.json()
        if p["state"] == "running" and p["total"]:
            break
        assert not running.done(), "the compute ended before it was seen running"
        await asyncio.sleep(0.01)
    async with daemon.http.delete(f"/api/calibration/pairs/{pairs[0]['id']}") as r:
        assert r.status == 409 and "being computed" in (await r.json())["error"]
    async with daemon.http.delete("/api/calibration/pairs") as r:
        assert r.status == 409
    (await running).release()
    assert (await session(daemon))["count"] == 8
    assert cover["left"] > 0.15 and cover["right"] > 0.15
    async with daemon.http.post("/api/calibration/compute") as r:
        assert r.status == 200, await r.text()
        cand = await r.json()
    report = cand["report"]
    assert report["pairs_used"] == 8 and report["rms"] < 0.3 and report["row_error_mean"] < 0.1
    assert cand["fits"] is True and report["rows_needed"] <= report["lb_rows"] == 80
    assert all("id" in p for p in report["pairs"])
    assert cand["worst_pair"] in [p["id"] for p in report["pairs"]]
    for side, K in (("left", truth.K1), ("right", truth.K2)):
        assert abs(report[side]["fx"] / K[0, 0] - 1) < 0.005 and abs(report[side]["fy"] / K[1, 1] - 1) < 0.005
        assert abs(report[side]["cx"] - K[0, 2]) < 2 and abs(report[side]["cy"] - K[1, 2]) < 2
    assert abs(report["baseline_m"] / truth.baseline - 1) < 0.01
    async with daemon.http.get("/api/calibration/compute") as r:
        assert (await r.json())["state"] == "done"

    async with daemon.http.get("/api/calibration/candidate.yaml") as r:
        assert r.status == 200
        text = await r.text()
    (tmp_path / "cand.yaml").write_text(text)
    assert load_calibration(tmp_path / "cand.yaml").id == cand["id"]
    async with daemon.http.get(f"/api/calibration/candidate/rectified.png?pair={cand['worst_pair']}") as r:
        assert r.status == 200 and r.content_type == "image/png"
        figure = cv2.imdecode(np.frombuffer(await r.read(), np.uint8), cv2.IMREAD_COLOR)
    assert figure.shape == (FULL[1], 2 * FULL[0], 3)
    async with daemon.http.get("/api/calibration/candidate/rectified.png?pair=nope") as r:
        assert r.status == 404

    before = daemon.overlay.fabric.rectify.read_config()
    old_id = (await session(daemon))["candidate"]["id"]
    assert old_id == cand["id"]
    async with daemon.http.post("/api/calibration/apply", json={"id": "something-else"}) as r:
        assert r.status == 409
    async with daemon.http.post("/api/calibration/apply", json={"nope": 1}) as r:
        assert r.status == 400
    async with daemon.http.post("/api/calibration/compute", json=[]) as r:
        assert r.status == 400 and "JSON object" in (await r.json())["error"]
    assert daemon.overlay.fabric.rectify.read_config() == before
    assert not (tmp_path / "calibration.yaml").exists()

    async with daemon.http.post("/api/calibration/apply", json={"id": cand["id"]}) as r:
        assert r.status == 200, await r.text()
        applied = await r.json()
    assert applied["id"] == cand["id"] and applied["file"] == str(tmp_path / "calibration.yaml")
    saved = load_calibration(tmp_path / "calibration.yaml")
    cfg = daemon.overlay.fabric.rectify.read_config()
    programmed = saved.core_config()
    assert saved.id == cand["id"] and (cfg.left, cfg.right) == (programmed.left, programmed.right)
    async with daemon.http.get("/api/status") as r:
        assert (await r.json())["calibration"]["id"] == cand["id"]
    await daemon.stop()

    # The pairs folder is a valid input of the command line calibrator: the same figures.
    code = cli_main(["calibrate", "--pattern", "9x6", "--square", f"{SYNTH_SQUARE * 1000:g}mm", "--quiet",
                     "-o", str(tmp_path / "cli.yaml"), str(tmp_path / "calibration-pairs")])
    assert code == 0
    cli = load_calibration(tmp_path / "cli.yaml")
    used = [{"name": p["id"], "rms_px": round(p["rms"], 6)} for p in report["pairs"]]
    assert cli.quality["pairs_used"] == used
    assert np.allclose(cli.model.K1, saved.model.K1) and np.allclose(cli.model.T, saved.model.T)

    # Without --calibration, the next start programs what the page applied.
    overlay = make_overlay(size=FULL, fps=20.0, calibrate=False)
    try:
        state = program_default_calibration(overlay, Settings(captures=str(tmp_path / "captures")))
        assert state.id == cand["id"] and state.calibration == saved
        cfg = overlay.fabric.rectify.read_config()
        assert (cfg.left, cfg.right) == (programmed.left, programmed.right)
    finally:
        overlay.close()


async def test_a_saved_calibration_that_cannot_run_is_skipped_at_start(tmp_path, caplog) -> None:
    (tmp_path / "calibration.yaml").write_text("schema: broken\n")
    overlay = make_overlay(size=FULL, fps=20.0, calibrate=False)
    try:
        state = program_default_calibration(overlay, Settings(captures=str(tmp_path / "captures")))
    finally:
        overlay.close()
    assert state.id is not None and state.id.startswith("synthetic-rig-")
    assert any("cannot be used" in rec.getMessage() for rec in caplog.records)


async def test_apply_refuses_a_candidate_the_line_buffer_cannot_hold(start_daemon, tmp_path) -> None:
    daemon = await start(start_daemon)
    model = daemon.overlay.emulation.source.model
    wide = dataclasses.replace(
        model, D1=np.array([-0.45, 0.1, 0.0, 0.0]), D2=np.array([-0.45, 0.1, 0.0, 0.0])
    )
    cal = Calibration.derive(wide, rectify(wide, alpha=1.0), alpha=1.0, source="test")
    assert cal.rows_needed > 80
    panel = daemon.app[PANEL]
    panel.candidate = Candidate(CalibrationReport(cal, PATTERN, (), 0.2, 0.05, 0.1, 80), [], 0.0)
    before = daemon.overlay.fabric.rectify.read_config()
    async with daemon.http.post("/api/calibration/apply", json={"id": cal.id}) as r:
        assert r.status == 422
        err = (await r.json())["error"]
    assert "previous calibration stays active" in err and str(cal.rows_needed) in err
    assert daemon.overlay.fabric.rectify.read_config() == before
    assert not (tmp_path / "calibration.yaml").exists()


@pytest.mark.parametrize("method,path", [
    ("POST", "/api/calibration/pairs"), ("DELETE", "/api/calibration/pairs"),
    ("PUT", "/api/calibration/session"), ("POST", "/api/calibration/compute"),
    ("POST", "/api/calibration/apply"),
])
async def test_changes_from_another_origin_or_without_the_token_are_refused(
    start_daemon, method, path
) -> None:
    daemon = await start(start_daemon, access_token="panel-secret")
    async with daemon.http.request(method, path, json={}, headers={"Origin": "http://evil.example"}) as r:
        assert r.status == 403
    async with daemon.http.request(method, path, json={}) as r:
        assert r.status == 401
    async with daemon.http.get("/api/calibration/session") as r:  # protect: all, the default: reads too
        assert r.status == 401
    assert (await session(daemon, token="panel-secret"))["settings"]["pattern"] == "9x6"


@pytest.mark.parametrize("path", ["/api/calibration/candidate", "/api/calibration/candidate.yaml",
                                  "/api/calibration/candidate/rectified.png"])
async def test_no_candidate_yet_is_a_clear_404(start_daemon, path) -> None:
    daemon = await start(start_daemon)
    async with daemon.http.get(path) as r:
        assert r.status == 404 and "no calibration has been computed" in (await r.json())["error"]


async def test_apply_checks_the_body_before_the_candidate(start_daemon) -> None:
    daemon = await start(start_daemon)
    async with daemon.http.post("/api/calibration/apply", json=[1]) as r:
        assert r.status == 400 and '{"id"' in (await r.json())["error"]
    async with daemon.http.post("/api/calibration/apply", json={"id": "x"}) as r:
        assert r.status == 404


async def test_state_dir_holds_the_pairs_and_the_calibration_file(start_daemon, tmp_path) -> None:
    daemon = await start(start_daemon, state_dir=str(tmp_path / "state"))
    assert (await session(daemon))["folder"] == str(tmp_path / "state" / "calibration-pairs")
    async with daemon.http.get("/api/calibration") as r:
        assert (await r.json())["file"] == str(tmp_path / "state" / "calibration.yaml")
    with pytest.raises(ValueError, match="state_dir"):
        Settings(state_dir="  ")
