"""Injected faults are reported while they last and every part recovers after.

The faults are made in the emulated fabric the way the hardware shows them
(:mod:`stereocam.overlays.emulated.faults`); the daemon finds them through
its registers and buses only. The rounds test injects every kind of fault,
one after the other, 100 times in a row over HTTP (``--allow-fault-injection``)
and waits for conditions: each fault shows in ``/api/status``, ``/healthz`` and
``/metrics``, the streams the faulted part does not feed keep getting frames,
and after the fault ends the part works again and nothing is reported.
"""
from __future__ import annotations

import asyncio
import time
from typing import Any, Dict, Iterator, List, Tuple

import numpy as np
import pytest

from stereocam.bench.faults import KINDS, ON_THE_PROCESSED_PATH
from stereocam.overlays.emulated.faults import FaultError, FaultInjector
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.fabric import SOURCES
from stereocam.server.http import routes_cameras
from stereocam.server.http.app import ServeError, create_app
from stereocam.server.http.settings import Settings, SettingsError
from stereocam.server.http.state import FABRIC_HEALTH, PIPELINE

from .daemon import make_overlay, wait_for_frames  # noqa: F401

pytestmark = pytest.mark.slow

DEADLINE_S = 60.0  # a bound for a broken daemon only: a busy machine makes the waits longer, not red


async def until(what: str, check: Any, *, timeout: float = DEADLINE_S, pause: float = 0.02) -> float:
    """Wait for ``await check()`` (or ``check()``) to be true; the seconds it took."""
    t0 = time.monotonic()
    while True:
        result = check()
        if asyncio.iscoroutine(result):
            result = await result
        if result:
            return time.monotonic() - t0
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"{what}: not within {timeout} s")
        await asyncio.sleep(pause)


# -- the injector on the emulated fabric, without the daemon ------------------------------------

Stepped = Tuple[EmulatedOverlay, FaultInjector]


@pytest.fixture
def stepped() -> Iterator[Stepped]:
    """An emulated overlay that moves only on ``overlay.step()`` (not started), and its fault injector;
    closed after the test."""
    overlay = make_overlay(clock="stepped")
    try:
        yield overlay, FaultInjector(overlay.emulation)
    finally:
        overlay.close()


def test_a_dma_fault_halts_the_channel_on_every_restart_until_it_ends(stepped: Stepped) -> None:
    overlay, faults = stepped
    overlay.start()
    s2mm = overlay.fabric.raw_vdma.s2mm
    overlay.step(2)
    assert s2mm.errors() == () and s2mm.running
    fault = faults.inject("dma_slave", "vdma_raw.s2mm")
    overlay.step(1)
    assert s2mm.errors() == ("VDMASlvErr",) and not s2mm.running
    s2mm.recover()
    overlay.step(1)
    assert s2mm.errors() == ("VDMASlvErr",), "a persisting fault halts the restarted channel again"
    faults.end(fault.id)
    s2mm.recover()
    overlay.step(2)
    assert s2mm.errors() == () and s2mm.running
    assert overlay.emulation.vdma_proc.s2mm.frames > 0  # the other channels never noticed


def test_a_hung_reset_finishes_when_the_fault_ends(stepped: Stepped) -> None:
    from stereocam.drivers.mmio import RegisterTimeout

    overlay, faults = stepped
    overlay.start()
    mm2s = overlay.fabric.proc_vdma.mm2s
    fault = faults.inject("reset_hang", "vdma_proc.mm2s")
    overlay.step(1)
    assert "VDMAIntErr" in mm2s.errors()
    with pytest.raises(RegisterTimeout, match="soft reset never completed"):
        mm2s.recover(timeout=0.05)
    faults.end(fault.id)
    mm2s.recover(timeout=5.0)
    overlay.step(2)
    assert mm2s.errors() == () and mm2s.running


def test_the_mux_refuses_commits_while_the_fault_lasts(stepped: Stepped) -> None:
    from stereocam.drivers.mmio import RegisterTimeout

    overlay, faults = stepped
    overlay.start()
    fault = faults.inject("mux_refuse")
    with pytest.raises(RegisterTimeout, match="commit never finished"):
        overlay.fabric.select("virtual", timeout=0.05)
    assert overlay.emulation.mux.selected == SOURCES["live"]
    faults.end(fault.id)
    overlay.fabric.select("live", timeout=5.0)
    assert overlay.emulation.mux.selected == SOURCES["live"]


def test_bad_injections_are_refused_with_what_to_give(stepped: Stepped) -> None:
    _, faults = stepped
    with pytest.raises(FaultError, match="unknown fault kind 'meltdown'; known: camera_stall"):
        faults.inject("meltdown")
    with pytest.raises(FaultError, match="needs a target, one of: vdma_raw.s2mm"):
        faults.inject("dma_decode", "vdma_raw.mm2s")
    with pytest.raises(FaultError, match="takes no target"):
        faults.inject("camera_stall", "left")
    with pytest.raises(FaultError, match="no camera sensors"):
        faults.inject("sensor_silent", "left")
    first = faults.inject("dma_decode", "vdma_proc.s2mm")
    with pytest.raises(FaultError, match="already has fault"):
        faults.inject("reset_hang", "vdma_proc.s2mm")
    assert [f.id for f in faults.active()] == [first.id]
    with pytest.raises(KeyError):
        faults.end(first.id + 1)


# -- the switch: only the flag, only on the emulated fabric -------------------------------------

async def test_without_the_flag_there_is_no_fault_route(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.post("/api/faults", json={"kind": "camera_stall"}) as resp:
        assert resp.status == 404
    assert d.overlay.emulation.cameras_running


def test_a_settings_file_cannot_allow_fault_injection(tmp_path) -> None:
    path = tmp_path / "stereocam.yaml"
    path.write_text("allow_fault_injection: true\n")
    with pytest.raises(SettingsError, match="only the --allow-fault-injection flag sets it"):
        Settings.from_file(path)


def test_fault_injection_is_refused_off_the_emulated_fabric() -> None:
    overlay = make_overlay(clock="stepped")
    try:
        overlay.fault_injection = None  # as the board's overlay has
        with pytest.raises(ServeError, match="emulated fabric only"):
            create_app(Settings(allow_fault_injection=True), overlay)
    finally:
        overlay.close()


def test_the_fabric_health_is_handed_its_parts_and_holds_no_app() -> None:
    """Hooks are constructor arguments; FabricHealth reads the pipeline and virtual camera, not the app."""
    from aiohttp import web

    from stereocam.server.http.state import VIRTUAL

    overlay = make_overlay(clock="stepped")
    try:
        app = create_app(Settings(), overlay)
        health, pipeline, virtual = app[FABRIC_HEALTH], app[PIPELINE], app[VIRTUAL]
        assert pipeline.channel_ok == health.channel_ok
        assert (virtual.mux_refused, virtual.mux_committed) == (health.mux_refused, health.mux_committed)
        held = [cell.cell_contents for getter in (health._source, health._period)
                for cell in getter.__closure__ or ()]
        assert held and not any(isinstance(value, web.Application) for value in held)
        assert health._source() == "live"
        virtual.source = "virtual"
        assert health._source() == "virtual"
    finally:
        overlay.close()


async def test_bad_fault_requests_get_a_clear_4xx(start_daemon) -> None:
    d = await start_daemon(allow_fault_injection=True)
    cases: List[Tuple[Any, int, str]] = [
        ({"kind": "meltdown"}, 400, "unknown fault kind"),
        ({"kind": "dma_slave"}, 400, "needs a target"),
        ({"kind": "camera_stall", "extra": 1}, 400, "kind"),
        ([1, 2], 400, "kind"),
        ({"kind": 5}, 400, "strings"),
    ]
    for body, status, text in cases:
        async with d.http.post("/api/faults", json=body) as resp:
            assert resp.status == status, body
            assert text in (await resp.json())["error"], body
    async with d.http.post("/api/faults", data=b"{", headers={"Content-Type": "application/json"}) as resp:
        assert resp.status == 400
    async with d.http.delete("/api/faults/77") as resp:
        assert resp.status == 404
    async with d.http.get("/api/faults") as resp:
        body = await resp.json()
        assert body["injected"] == [] and "vdma_raw.s2mm" in body["kinds"]["dma_internal"]


# -- the rounds -------------------------------------------------------------------------------

ROUNDS = 100


class Observer:
    """What a monitoring client sees: faults in status, healthz, metrics."""

    def __init__(self, daemon: Any) -> None:
        self.d = daemon

    async def faults(self) -> List[Dict[str, Any]]:
        async with self.d.http.get("/api/status") as resp:
            assert resp.status == 200
            return list((await resp.json())["faults"])

    async def reported(self, what: str) -> bool:
        return any(f["what"] == what for f in await self.faults())

    async def clear(self) -> bool:
        if await self.faults():
            return False
        async with self.d.http.get("/healthz") as resp:
            return resp.status == 200

    async def everywhere(self, what: str) -> None:
        """While it lasts, the fault is in healthz (503, named) and in the metrics too."""
        async with self.d.http.get("/healthz") as resp:
            text = await resp.text()
            assert resp.status == 503 and what in text, text
        async with self.d.http.get("/metrics") as resp:
            assert f'stereocam_fault{{what="{what}"}} 1.0' in await resp.text()


async def _works_again(d: Any, what: str) -> None:
    """The part does its job again, seen from outside."""
    pipeline = d.app[PIPELINE]
    if what == "vdma_raw.s2mm":
        async with d.http.get("/snapshot/raw_left.png") as resp:
            assert resp.status == 200, await resp.text()
    elif what == "vdma_proc.mm2s":
        mm2s = d.overlay.fabric.proc_vdma.mm2s
        assert mm2s.errors() == () and mm2s.running
    elif what == "mux":
        async with d.http.put("/api/source", json={"source": "live"}) as resp:
            assert resp.status == 200, await resp.text()
        assert d.overlay.emulation.mux.selected == SOURCES["live"]
    elif what.startswith("sensor."):
        async with d.http.get("/api/cameras") as resp:
            body = await resp.json()
            assert body["health"][what.split(".")[1]]["ok"], body
    frames = pipeline.frames_seen
    await until("rectified frames after the fault", lambda: pipeline.frames_seen >= frames + 2)


async def test_every_fault_is_reported_while_it_lasts_and_recovered_after_100_rounds(start_daemon) -> None:
    d = await start_daemon(allow_fault_injection=True, extensions=(routes_cameras.setup,))
    pipeline = d.app[PIPELINE]
    await wait_for_frames(d, 3)
    watch = Observer(d)
    await until("no fault at start", watch.clear)
    detect: Dict[str, List[float]] = {}
    recover: Dict[str, List[float]] = {}
    for n in range(ROUNDS):
        kind, target, what = KINDS[n % len(KINDS)]
        async with d.http.post("/api/faults", json={"kind": kind, "target": target}) as resp:
            assert resp.status == 201, await resp.text()
            fault = await resp.json()
        if what == "mux":  # the daemon meets a refusing mux when it switches
            async with d.http.put("/api/source", json={"source": "live"}) as resp:
                assert resp.status == 503 and "retries" in (await resp.json())["error"]
        took = await until(f"round {n}: {what} reported", lambda: watch.reported(what))  # noqa: B023
        detect.setdefault(what, []).append(took)
        await watch.everywhere(what)
        if what not in ON_THE_PROCESSED_PATH:  # the other streams go on during the fault
            frames = pipeline.frames_seen
            await until(f"round {n}: rectified frames during the {what} fault",
                        lambda: pipeline.frames_seen >= frames + 3)  # noqa: B023
            assert await watch.reported(what), f"round {n}: {what} stopped being reported while it lasted"
        async with d.http.delete(f"/api/faults/{fault['id']}") as resp:
            assert resp.status == 200
        t1 = time.monotonic()
        await until(f"round {n}: {what} recovered", watch.clear)
        recover.setdefault(what, []).append(time.monotonic() - t1)
        await _works_again(d, what)
    summary = {w: (round(max(detect[w]), 2), round(max(recover[w]), 2)) for w in detect}
    print("worst (report s, recover s) by part:", summary)
    assert set(detect) == {w for _, _, w in KINDS}
    assert pipeline.frames_seen > ROUNDS  # frames flowed between the rounds


async def test_rectified_frames_go_on_through_a_hung_raw_reset(start_daemon) -> None:
    """A raw channel whose reset hangs is left alone by the frame thread: rectified frames go on."""
    d = await start_daemon(allow_fault_injection=True)
    pipeline = d.app[PIPELINE]
    await wait_for_frames(d, 3)
    with pipeline.raw_wanted():
        async with d.http.post("/api/faults", json={"kind": "reset_hang", "target": "vdma_raw.s2mm"}) as resp:
            fault = await resp.json()
        health_part = d.app[FABRIC_HEALTH].channels["vdma_raw.s2mm"]
        await until("the hung reset reported", lambda: "restarting it failed" in health_part.text)
        frames = pipeline.frames_seen
        await until("rectified frames during the hung reset", lambda: pipeline.frames_seen >= frames + 5)
        async with d.http.delete(f"/api/faults/{fault['id']}"):
            pass
        await until("raw frames again",
                    lambda: pipeline.frames_seen > frames + 5 and health_part.since is None)
    async with d.http.get("/snapshot/raw_left.png") as resp:  # a raw frame copied again
        assert resp.status == 200, await resp.text()
        assert (await resp.read()).startswith(b"\x89PNG")


def test_the_faults_benchmark_measures_every_kind_against_the_floor() -> None:
    from stereocam.bench.faults import FLOORS, measure_faults, text_lines

    result = measure_faults(rounds=1)
    parts = result["parts"]
    assert {(row["kind"], row["part"]) for row in parts.values()} == {(k, w) for k, _, w in KINDS}
    for row in parts.values():
        assert row["rounds"] == 1 and row["report_s"] > 0 and row["recover_s"] > 0
        assert (row["gap_s"] is None) == (row["part"] in ON_THE_PROCESSED_PATH)
    met = all(row[k] is None or row[k] <= FLOORS[k] for row in parts.values() for k in FLOORS)
    assert result["ok"] == met
    text = "\n".join(text_lines(result))
    assert ("all floors met" in text) == met and "vdma_proc.mm2s" in text


async def test_the_virtual_camera_shows_its_input_again_after_an_mm2s_fault(start_daemon) -> None:
    """The restart parks the channel on the store it showed, not store 0 (an older upload)."""
    from stereocam.overlays.spec import pixel
    from stereocam.server.http.state import VIRTUAL

    from .test_server_api import encode, model_output, pair_form, pattern_pair

    d = await start_daemon(allow_fault_injection=True)
    await wait_for_frames(d, 3)
    for seed in (3, 4):  # the second upload goes to another store than the first
        left, right = pattern_pair(seed)
        async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
            assert resp.status == 200, await resp.text()
    expected = model_output(d, pixel.pack(pixel.rgby(left), pixel.rgby(right)))
    async with d.http.post("/api/faults", json={"kind": "dma_decode", "target": "vdma_proc.mm2s"}) as resp:
        fault = await resp.json()
    watch = Observer(d)
    await until("the MM2S fault reported", lambda: watch.reported("vdma_proc.mm2s"))
    async with d.http.delete(f"/api/faults/{fault['id']}"):
        pass
    await until("recovered", watch.clear)
    shown = await d.app[VIRTUAL].actual_frame()  # a frame the fabric made after the restart
    np.testing.assert_array_equal(shown.processed, expected)
