"""The calibration API: GET and PUT /api/calibration, serve --calibration with a stereocam YAML."""
from __future__ import annotations

import dataclasses
import time

import cv2
import numpy as np
import pytest
import yaml

from stereocam.bench.rectify import bench_calibration
from stereocam.calibration.file import Calibration, load_calibration
from stereocam.calibration.stereo import rectify
from stereocam.server.http import routes_calibration
from stereocam.server.http.app import default_extensions, program_default_calibration
from stereocam.server.http.settings import Settings

from ..interleave import at_every_bytecode
from .daemon import SMALL, make_overlay  # noqa: F401

pytestmark = pytest.mark.slow

EXT = (routes_calibration.setup,)
YAML = {"Content-Type": "application/yaml"}


def rig_calibration(daemon, *, alpha: float = 0.0, **model_changes) -> Calibration:
    model = daemon.overlay.emulation.source.model
    if model_changes:
        model = dataclasses.replace(model, **model_changes)
    return Calibration.derive(model, rectify(model, alpha=alpha), alpha=alpha, source="test rig")


def core_registers(cal: Calibration) -> tuple:
    """The registers a calibration programs (spec 2.0: derived for its frame size)."""
    config = cal.core_config()
    return config.left, config.right


def registers(daemon):
    return daemon.overlay.fabric.rectify.read_config()


async def status_calibration(daemon) -> dict:
    async with daemon.http.get("/api/status") as r:
        assert r.status == 200
        return (await r.json())["calibration"]


def test_default_extensions_include_the_calibration_routes() -> None:
    assert routes_calibration.setup in default_extensions()


async def test_get_shows_the_synthetic_rig_calibration(start_daemon) -> None:
    daemon = await start_daemon(extensions=EXT)
    async with daemon.http.get("/api/calibration") as r:
        assert r.status == 200
        body = await r.json()
    status = await status_calibration(daemon)
    assert body["id"] == status["id"] and body["id"].startswith("synthetic-rig-")
    assert body["image_size"] == list(SMALL) and body["lb_rows"] == 80
    assert body["rows_needed"] == status["rows_needed"] and body["lb_delay"] == status["lb_delay"]
    assert set(body["model"]) == {"K1", "D1", "K2", "D2", "R", "T"}
    assert np.asarray(body["model"]["K1"]).shape == (3, 3)
    assert set(body["rectification"]) >= {"R1", "R2", "P1", "P2"}
    assert np.asarray(body["rectification"]["P2"]).shape == (3, 4)
    expected = rig_calibration(daemon)
    assert body["file_id"] == expected.id and body["source"].startswith("the synthetic rig")
    # The rig's T is in metres (its calibration says so: the depth readout needs the unit).
    assert body["yaml"] == dataclasses.replace(expected, source=body["source"], units="m").to_yaml()
    cfg = registers(daemon)
    assert (cfg.left, cfg.right) == core_registers(expected)  # the yaml is what the core runs


async def test_put_programs_saves_and_reports_a_new_calibration(start_daemon, tmp_path) -> None:
    daemon = await start_daemon(extensions=EXT)
    old_id = (await status_calibration(daemon))["id"]
    before = registers(daemon)
    path = tmp_path / "calibration.yaml"  # <captures>/../calibration.yaml without --calibration
    cal = rig_calibration(daemon, alpha=0.6)
    async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
        assert r.status == 200, await r.text()
        body = await r.json()
    assert body["id"] == cal.id != old_id and body["file"] == str(path)
    status = await status_calibration(daemon)
    assert status["id"] == cal.id and status["rows_needed"] == cal.rows_needed
    assert status["lb_delay"] == cal.lb_delay
    assert load_calibration(path) == cal
    after = registers(daemon)
    assert after != before and (after.left, after.right) == core_registers(cal)
    async with daemon.http.get("/api/calibration") as r:
        got = await r.json()
    assert got["id"] == cal.id and got["yaml"] == cal.to_yaml() and got["alpha"] == 0.6

    # JSON {"yaml": ...} too, and text/plain
    cal2 = rig_calibration(daemon, alpha=0.3)
    async with daemon.http.put("/api/calibration", json={"yaml": cal2.to_yaml()}) as r:
        assert r.status == 200, await r.text()
    cal3 = rig_calibration(daemon, alpha=0.1)
    async with daemon.http.put("/api/calibration", data=cal3.to_yaml(),
                               headers={"Content-Type": "text/plain"}) as r:
        assert r.status == 200, await r.text()
    assert (await status_calibration(daemon))["id"] == cal3.id


async def test_put_replaces_the_given_calibration_file(start_daemon, tmp_path) -> None:
    overlay = make_overlay(calibrate=False)
    path = tmp_path / "mine.yaml"
    model = overlay.emulation.source.model
    first = Calibration.derive(model, rectify(model, alpha=0.0), alpha=0.0)
    first.save(path)
    daemon = await start_daemon(overlay=overlay, extensions=EXT, calibration=str(path))
    status = await status_calibration(daemon)
    assert status["id"] == first.id and str(path) in status["description"]
    async with daemon.http.get("/api/calibration") as r:
        assert (await r.json())["yaml"] == first.to_yaml()
    cal = rig_calibration(daemon, alpha=0.5)
    async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
        assert r.status == 200, await r.text()
        assert (await r.json())["file"] == str(path)
    assert path.read_text() == cal.to_yaml()
    assert not (tmp_path / "calibration.yaml").exists()


def _nan(text: str) -> str:
    lines = text.splitlines(keepends=True)
    for i, line in enumerate(lines):
        if line.strip().startswith("D1:"):
            indent = line[:len(line) - len(line.lstrip())]
            lines[i] = f"{indent}D1: [.nan, 0.0, 0.0, 0.0]\n"
            return "".join(lines)
    raise AssertionError("no D1 line")


@pytest.mark.parametrize("case", ["broken", "nan", "frame_size", "line_buffer", "not_calibration", "empty",
                                  "alias_bomb", "deep", "zero_baseline", "huge_projection"])
async def test_put_refuses_and_keeps_the_previous_calibration(start_daemon, tmp_path, case) -> None:
    daemon = await start_daemon(extensions=EXT)
    path = tmp_path / "calibration.yaml"
    good = rig_calibration(daemon, alpha=0.4)
    async with daemon.http.put("/api/calibration", data=good.to_yaml(), headers=YAML) as r:
        assert r.status == 200, await r.text()
    file_before = path.read_bytes()
    regs_before = registers(daemon)

    if case == "broken":
        text, status_code, words = "schema_version: 1\nmodel: [oops\n", 400, "not valid YAML"
    elif case == "nan":
        text, status_code, words = _nan(good.to_yaml()), 400, "finite"
    elif case == "frame_size":
        model, rect, _, _ = bench_calibration()  # 752x480: the daemon runs 376x240
        text, status_code, words = Calibration.derive(model, rect).to_yaml(), 422, "376x240"
    elif case == "line_buffer":
        barrel = np.array([-0.8, 0.0, 0.0, 0.0])  # strong distortion
        strong = rig_calibration(daemon, D1=barrel, D2=barrel)
        assert strong.rows_needed > 80, strong.rows_needed
        text, status_code, words = strong.to_yaml(), 422, "line-buffer rows"
    elif case == "not_calibration":
        text, status_code, words = "hello: world\n", 400, "schema_version"
    elif case == "alias_bomb":  # a valid calibration whose quality section holds a billion laughs
        bomb = "".join(f"  l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9) if i else 'lol'}]\n"
                       for i in range(10))
        text, status_code, words = good.to_yaml() + "bomb:\n" + bomb, 400, "aliases"
    elif case == "zero_baseline":  # fits every register, describes no stereo rig
        doc = yaml.safe_load(good.to_yaml())
        doc["model"]["T"] = [0.0, 0.0, 0.0]
        del doc["core"], doc["id"]
        text, status_code, words = yaml.safe_dump(doc), 400, "baseline of 0"
    elif case == "huge_projection":  # its singularity check overflowed: a 500, and nothing said why
        doc = yaml.safe_load(good.to_yaml())
        doc["rectification"]["P1"][0][1] = 1e308
        del doc["core"], doc["id"]
        text, status_code, words = yaml.safe_dump(doc), 400, "singular"
    elif case == "deep":
        text, status_code, words = good.to_yaml() + "deep: " + "[" * 5000 + "]" * 5000 + "\n", 400, "nested"
    else:
        text, status_code, words = "  \n", 400, "empty"
    async with daemon.http.put("/api/calibration", data=text, headers=YAML) as r:
        assert r.status == status_code, await r.text()
        error = (await r.json())["error"]
    assert "\n" not in error and words.lower() in error.lower(), error
    assert "previous calibration stays active" in error or case == "empty"
    assert (await status_calibration(daemon))["id"] == good.id
    assert registers(daemon) == regs_before
    assert path.read_bytes() == file_before
    async with daemon.http.get("/api/calibration") as r:
        assert (await r.json())["id"] == good.id


async def test_put_refuses_bad_bodies(start_daemon) -> None:
    daemon = await start_daemon(extensions=EXT)
    old = await status_calibration(daemon)
    async with daemon.http.put("/api/calibration", json={"yml": "x"}) as r:
        assert r.status == 400 and "yaml" in (await r.json())["error"]
    async with daemon.http.put("/api/calibration", data=b"x", headers={"Content-Type": "image/png"}) as r:
        assert r.status == 415
    async with daemon.http.put("/api/calibration", data=b"\xff\xfe", headers=YAML) as r:
        assert r.status == 400
    assert await status_calibration(daemon) == old


async def test_put_from_another_origin_is_forbidden(start_daemon, tmp_path) -> None:
    daemon = await start_daemon(extensions=EXT)
    old = await status_calibration(daemon)
    before = registers(daemon)
    cal = rig_calibration(daemon, alpha=0.7)
    headers = {**YAML, "Origin": "http://evil.example"}
    async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=headers) as r:
        assert r.status == 403
        assert "error" in await r.json()
    assert await status_calibration(daemon) == old and registers(daemon) == before
    assert not (tmp_path / "calibration.yaml").exists()


async def test_capture_records_the_new_calibration_id(start_daemon) -> None:
    daemon = await start_daemon(extensions=EXT)
    cal = rig_calibration(daemon, alpha=0.2)
    async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
        assert r.status == 200
    from .daemon import wait_for_frames

    await wait_for_frames(daemon)
    async with daemon.http.post("/api/captures") as r:
        assert r.status == 201, await r.text()
        entry = await r.json()
    assert entry["calibration_id"] == cal.id


def test_program_default_calibration_reads_a_stereocam_yaml(tmp_path) -> None:
    overlay = make_overlay(calibrate=False)
    try:
        model = overlay.emulation.source.model
        cal = Calibration.derive(model, rectify(model, alpha=0.2), alpha=0.2, source="bench")
        path = cal.save(tmp_path / "cal.yaml")
        state = program_default_calibration(overlay, Settings(calibration=str(path)))
        assert state.id == cal.id and state.rows_needed == cal.rows_needed and "bench" in state.description
        cfg = overlay.fabric.rectify.read_config()
        assert (cfg.left, cfg.right) == core_registers(cal)
        with pytest.raises(ValueError, match="376x240"):
            model2, rect2, _, _ = bench_calibration()
            big = Calibration.derive(model2, rect2).save(tmp_path / "big.yaml")
            program_default_calibration(overlay, Settings(calibration=str(big)))
    finally:
        overlay.close()


async def test_put_keeps_the_file_it_replaces(start_daemon, tmp_path) -> None:
    daemon = await start_daemon(extensions=EXT)
    first, second = rig_calibration(daemon, alpha=0.2), rig_calibration(daemon, alpha=0.7)
    for cal in (first, second):
        async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
            assert r.status == 200, await r.text()
    assert load_calibration(tmp_path / "calibration.yaml") == second
    assert load_calibration(routes_calibration.previous_path(tmp_path / "calibration.yaml")) == first
    assert routes_calibration.previous_path(tmp_path / "calibration.yaml").name == "calibration.previous.yaml"


def test_frames_are_labelled_with_the_calibration_they_ran_with() -> None:
    from stereocam.server.http.state import CalibrationState

    state = CalibrationState(id="A")
    assert state.for_frame(5).id == "A"  # type: ignore[union-attr]
    changing = state.changing_from_count(6)
    assert changing.for_frame(7) is None  # registers being programmed: either set
    assert changing.unchanged().for_frame(7).id == "A"  # type: ignore[union-attr]  # a change that failed
    state = changing.succeeded_by(CalibrationState(id="B"), 10, 14)
    labels = [getattr(state.for_frame(c), "id", None) for c in (9, 10, 11, 13, 14, 20)]
    assert labels == ["A", "A", None, None, "B", "B"]
    assert not state.changing and changing.id == "A"  # each state is a value: nothing changed in place
    wrap = CalibrationState(id="A").succeeded_by(CalibrationState(id="B"), (1 << 32) - 10, (1 << 32) - 6)
    wrap = wrap.succeeded_by(CalibrationState(id="C"), (1 << 32) - 2, 1)  # FRAME_COUNT wraps at 2**32
    counts = [(1 << 32) - 11, (1 << 32) - 6, (1 << 32) - 2, (1 << 32) - 1, 0, 1, 2]
    assert [getattr(wrap.for_frame(c), "id", None) for c in counts] == ["A", "B", "B", None, None, "C", "C"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        wrap.id = "D"  # type: ignore[misc]


async def test_the_calibration_in_effect_is_read_whole_while_it_changes(start_daemon) -> None:
    """The pipeline thread labels each recorded frame (``for_frame``) while PUTs change the calibration
    on the loop: every label another thread can read is one calibration whole, never one's id with
    another's line-buffer figures. A thread reads as fast as it can; and, so that no interleaving is
    left to the scheduler's luck, the labels are also read between every two bytecodes the change runs
    (where the GIL may pass to the pipeline thread)."""
    import sys
    import threading

    from stereocam.server.http.state import CALIBRATION

    daemon = await start_daemon(extensions=EXT)
    cals = [rig_calibration(daemon, alpha=0.0), rig_calibration(daemon, alpha=0.6)]
    wholes = {}
    for cal in cals:
        async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
            assert r.status == 200, await r.text()
            body = await r.json()
        wholes[cal.id] = {k: body[k] for k in ("id", "description", "rows_needed", "lb_rows", "lb_delay")}
    a, b = wholes.values()
    assert (a["rows_needed"], a["lb_delay"]) != (b["rows_needed"], b["lb_delay"])  # a torn read would show
    in_effect = daemon.app[CALIBRATION]
    later = int(daemon.overlay.frame_count()) + 1_000_000  # a frame after every change: the one in effect
    seen: dict = {}
    torn: list = []

    def label() -> None:  # what the pipeline thread does for each frame of a recording
        record = in_effect.for_frame(later)
        got = None if record is None else record.to_json()
        if got is not None:
            seen[got["id"]] = seen.get(got["id"], 0) + 1
            if got != wholes.get(got["id"]):
                torn.append(got)

    stop = threading.Event()

    def label_frames() -> None:
        while not stop.is_set():
            label()

    switch, tracer = sys.getswitchinterval(), sys.gettrace()
    sys.setswitchinterval(1e-6)  # let the thread run between any two bytecodes of the loop's
    thread = threading.Thread(target=label_frames, name="test-labeller")
    thread.start()
    sys.settrace(at_every_bytecode(routes_calibration.activate.__code__, label))
    try:
        for cal in cals * 2:
            async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
                assert r.status == 200, await r.text()
    finally:
        sys.settrace(tracer)
        stop.set()
        thread.join()
        sys.setswitchinterval(switch)
    assert not torn, f"{len(torn)} labels mixed two calibrations, e.g. {torn[0]} (wholes: {wholes})"
    assert set(seen) == set(wholes), seen


async def test_a_capture_during_a_calibration_change_names_the_calibration_its_frames_ran_with(
        start_daemon, tmp_path, monkeypatch) -> None:
    """The core runs the new registers while the file is still being written (slow storage): a capture
    taken then must not be labelled with the old calibration."""
    import asyncio

    from stereocam.overlays.model.fast import RectifyModel
    from stereocam.server.http.state import CALIBRATION, CAPTURES

    daemon = await start_daemon(extensions=EXT)
    cals = [rig_calibration(daemon, alpha=0.0), rig_calibration(daemon, alpha=0.6)]
    assert cals[0].id != cals[1].id
    real_apply = routes_calibration._apply

    def slow_apply(rectify, cal, path):  # the registers are live at once; the file write takes a while
        config = real_apply(rectify, cal, path)
        time.sleep(0.3)
        return config

    monkeypatch.setattr(routes_calibration, "_apply", slow_apply)
    expected = {}
    for cal in cals:  # the rectified frame each calibration gives for the rig's still frame
        async with daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML) as r:
            assert r.status == 200, await r.text()
        config, options = daemon.overlay.core_setup()
        raw = daemon.overlay.emulation.source.frame
        expected[cal.id] = RectifyModel(config.left, config.right, config.width, config.height,
                                        options).process(raw).frame
    for cal in cals * 2:
        put = asyncio.ensure_future(daemon.http.put("/api/calibration", data=cal.to_yaml(), headers=YAML))
        state = daemon.app[CALIBRATION]
        while not (state.now.changing or put.done()):  # until the PUT is in its slow write: new registers run
            await asyncio.sleep(0.005)
        assert state.now.changing, "the PUT ended before the capture could be taken during it"
        async with daemon.http.post("/api/captures") as r:
            assert r.status == 201, await r.text()
            info = await r.json()
        async with await put as r:
            assert r.status == 200
        label = info["meta"]["calibration_id"] if "meta" in info else None
        if label is None:
            label = daemon.app[CAPTURES].get(info["id"]).to_json(meta=True)["meta"]["calibration_id"]
        rect_left = cv2.imread(str(daemon.app[CAPTURES].path(info["id"]) / "rect_left.png"), cv2.IMREAD_COLOR)
        ran_with = [cid for cid, frame in expected.items()
                    if np.array_equal(rect_left, frame[..., [2, 1, 0]])]
        assert ran_with == [label], (label, ran_with)
