"""``GET /metrics`` through prometheus_client: clean under ``promtool check metrics``.

The daemon runs with the cameras extension (sensor gauges) and an injected DMA fault (fault
gauges and counters), so every family the daemon can show is in the scrape that Debian's
``promtool`` (package ``prometheus``, installed by ``./scripts/test``) checks: no error and no
lint warning. Counters print every digit (``{:g}`` printed 1000009 as ``1.00001e+06``), the
process metrics are there, and each family has one label set.
"""
from __future__ import annotations

import asyncio
import contextlib
import re
import shutil
import time
from typing import Any, AsyncIterator, Dict, FrozenSet, List, Set

from prometheus_client.parser import text_string_to_metric_families
from prometheus_client.samples import Sample

from stereocam.server.http import routes_cameras
from stereocam.server.http.metrics import METRICS
from stereocam.server.http.state import EXTENSIONS, PIPELINE

from .daemon import WAIT_S, read_parts  # noqa: F401

FAULTED = "vdma_raw.s2mm"
BIG = 1000009  # {:g} printed this as 1.00001e+06
BIG_FRAMES = 10**9 + 9  # and this as 1e+09: nine frames fewer


async def _scrape(d: Any) -> str:
    async with d.http.get("/metrics") as resp:
        assert resp.status == 200, await resp.text()
        assert resp.headers["Content-Type"] == "text/plain; version=0.0.4; charset=utf-8"
        return await resp.text()


async def _scrape_until(d: Any, what: str, *patterns: str) -> str:
    """Scrape until every regex in ``patterns`` matches a line (bounded by WAIT_S: only a hang gets there)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        text = await _scrape(d)
        if all(re.search(p, text, re.MULTILINE) for p in patterns):
            return text
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not in /metrics within {WAIT_S} s:\n{text}")
        await asyncio.sleep(0.05)


@contextlib.asynccontextmanager
async def _watching(d: Any, view: str) -> AsyncIterator[None]:
    """A stream client of ``view`` that reads all the while (one that stops reading is dropped)."""
    async with d.http.get(f"/stream/{view}") as stream:
        await read_parts(stream, 2)

        async def drain() -> None:
            while await stream.content.readany():
                pass

        reader = asyncio.create_task(drain())
        try:
            yield
        finally:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader


def _samples(text: str) -> Dict[str, List[Sample]]:
    return {f.name: list(f.samples) for f in text_string_to_metric_families(text)}


def _value_text(text: str, sample: str) -> str:
    """The value of one sample exactly as printed (``sample`` is the name with its labels)."""
    for line in text.splitlines():
        if line.startswith(sample + " "):
            return line[len(sample) + 1:]
    raise AssertionError(f"{sample} is not in /metrics")


async def _promtool(text: str) -> None:
    promtool = shutil.which("promtool")
    assert promtool, "promtool is missing: ./scripts/test installs Debian's prometheus package"
    proc = await asyncio.create_subprocess_exec(promtool, "check", "metrics", stdin=asyncio.subprocess.PIPE,
                                                stdout=asyncio.subprocess.PIPE,
                                                stderr=asyncio.subprocess.PIPE)
    out, err = await asyncio.wait_for(proc.communicate(text.encode("utf-8")), WAIT_S)
    assert (proc.returncode, out.decode(), err.decode()) == (0, "", ""), text


async def _daemon_with_everything(start_daemon: Any) -> Any:
    """A daemon with sensors, a stream client, an encoded view, a fault active and big counters."""
    d = await start_daemon(allow_fault_injection=True, extensions=(routes_cameras.setup,))
    async with d.http.post("/api/faults", json={"kind": "dma_slave", "target": FAULTED}) as resp:
        assert resp.status == 201, await resp.text()
    d.app[METRICS].captures = BIG
    d.app[PIPELINE].frames = BIG
    return d


async def test_the_scrape_passes_promtool_with_every_family_there(start_daemon) -> None:
    d = await _daemon_with_everything(start_daemon)
    async with _watching(d, "rect_left"):
        text = await _scrape_until(
            d, "sensors, the fault, a stream client and an encoded view",
            r'^stereocam_sensor_exposure_seconds\{camera="left"\} ',
            rf'^stereocam_fault\{{what="{re.escape(FAULTED)}"\}} 1\.0$',
            rf'^stereocam_fabric_faults_total\{{part="{re.escape(FAULTED)}"\}} [1-9]',
            r'^stereocam_clients\{kind="mjpeg"\} 1\.0$',
            r'^stereocam_encode_seconds_count\{view="rect_left"\} [1-9]',
            r'^stereocam_view_encoded_frames_per_second\{view="rect_left"\} ')
    await _promtool(text)
    samples = _samples(text)
    for family in ("stereocam_stage_frames_per_second", "stereocam_view_encoded_frames_per_second",
                   "stereocam_frames", "stereocam_drops", "stereocam_signal", "stereocam_encode_seconds",
                   "stereocam_clients", "stereocam_stream_clients_dropped",
                   "stereocam_stream_clients_refused", "stereocam_uploads", "stereocam_errors",
                   "stereocam_http_responses", "stereocam_captures",
                   "stereocam_uptime_seconds", "stereocam_faults_active", "stereocam_fault",
                   "stereocam_fabric_faults", "stereocam_fabric_restarts", "stereocam_sensor_ok",
                   "stereocam_sensor_exposure_seconds", "stereocam_sensor_gain",
                   "stereocam_sensor_auto_exposure_enabled", "stereocam_sensor_auto_gain_enabled"):
        assert samples.get(family), f"{family} has no sample"
    stages = {s.labels["stage"] for s in samples["stereocam_stage_frames_per_second"]}
    assert stages == {"camera", "pipeline", "disparity"}
    assert 0 < samples["stereocam_sensor_exposure_seconds"][0].value < 1  # seconds, not microseconds
    assert not any(line.startswith(("stereocam_fps", "stereocam_sensor_exposure_us", "stereocam_sensor_aec"))
                   for line in text.splitlines())


async def test_counters_print_every_digit(start_daemon) -> None:
    d = await _daemon_with_everything(start_daemon)
    pipeline = d.app[PIPELINE]
    pipeline.frames = BIG_FRAMES
    before = pipeline.frames
    text = await _scrape(d)
    after = pipeline.frames  # the pipeline goes on counting
    captures = _value_text(text, "stereocam_captures_total")
    assert float(captures) == BIG, captures  # printed as Go does (1.000009e+06): every digit
    frames = float(_value_text(text, "stereocam_frames_total"))
    assert frames == int(frames) and before <= frames <= after, (before, frames, after)


async def test_process_metrics_and_counters_named_total(start_daemon) -> None:
    d = await _daemon_with_everything(start_daemon)
    text = await _scrape(d)
    samples = _samples(text)
    for name in ("process_cpu_seconds", "process_resident_memory_bytes", "process_virtual_memory_bytes",
                 "process_start_time_seconds", "process_open_fds", "python_info"):
        assert samples.get(name), f"{name} is missing"
    assert samples["process_resident_memory_bytes"][0].value > 1e6
    types = dict(re.findall(r"^# TYPE (\S+) (\S+)$", text, re.MULTILINE))
    counters = [name for name, kind in types.items() if kind == "counter"]
    assert "stereocam_frames_total" in counters and "stereocam_fabric_restarts_total" in counters
    assert all(name.endswith("_total") for name in counters), counters
    assert not [n for n, kind in types.items() if kind != "counter" and n.endswith("_total")]


async def test_every_family_has_one_label_set(start_daemon) -> None:
    d = await _daemon_with_everything(start_daemon)
    async with _watching(d, "rect_left"):
        text = await _scrape_until(d, "the sensors and an encoded view",
                                   r'^stereocam_sensor_gain\{camera="right"\} ',
                                   r'^stereocam_encode_seconds_count\{view="rect_left"\} [1-9]')
    for family in text_string_to_metric_families(text):
        label_sets: Set[FrozenSet[str]] = {frozenset(s.labels) for s in family.samples}
        assert len(label_sets) <= 1, f"{family.name} mixes label sets: {label_sets}"


async def test_each_app_has_its_own_registry(start_daemon) -> None:
    from stereocam.server.http.metrics import REGISTRY

    one = await start_daemon()
    two = await start_daemon()
    assert one.app[REGISTRY] is not two.app[REGISTRY]
    one.app[METRICS].captures = 3
    assert "stereocam_captures_total 3.0" in await _scrape(one)
    assert "stereocam_captures_total 0.0" in await _scrape(two)


async def test_a_broken_or_clashing_extension_does_not_break_the_scrape(start_daemon, caplog) -> None:
    from prometheus_client.core import GaugeMetricFamily

    def broken() -> List[Any]:
        raise RuntimeError("sensor snapshot went away")

    def clashing() -> List[Any]:
        return [GaugeMetricFamily("stereocam_signal", "A second family of an existing name.", value=7)]

    def fine() -> List[Any]:
        return [GaugeMetricFamily("stereocam_test_extension", "An extension's gauge.", value=2)]

    def setup(app: Any) -> None:
        app[EXTENSIONS].metrics.extend([broken, clashing, fine])

    d = await start_daemon(extensions=[setup])
    text = await _scrape(d)
    assert "stereocam_test_extension 2.0" in text.splitlines()
    assert "stereocam_signal 7.0" not in text.splitlines()
    assert len(re.findall(r"^# TYPE stereocam_signal ", text, re.MULTILINE)) == 1
    assert "sensor snapshot went away" in caplog.text and "stereocam_signal" in caplog.text
    await _promtool(text)
