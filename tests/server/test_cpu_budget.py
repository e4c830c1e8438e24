"""The CPU budget: views share a number of cores instead of all falling behind.

The end-to-end check runs ``stereocam bench budget``: ``stereocam serve --cpu-budget 0.3`` as a
subprocess, its CPU read from ``/proc`` without the emulated fabric's thread, all seven views
watched, then one; the test checks what the budget decides, the benchmark the figures. The rest
checks the parts: the plan, the pipeline copying only what is wanted, thumbnails, and what
status and ``/metrics`` say.
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import re
import struct
import threading
import time
from typing import Any, Callable, Dict, List

import cv2
import numpy as np
import pytest

from stereocam.bench.budget import daemon_cpu_seconds
from stereocam.server.frames.cpu_budget import (
    BOARD_CORES,
    MIN_FPS,
    CpuBudget,
    Demand,
    default_cores,
    plan_cost,
    plan_rates,
)
from stereocam.server.frames.pipeline import Pipeline
from stereocam.server.http.state import BUDGET, PIPELINE

from .daemon import WAIT_S, H, W, make_overlay
from .test_metrics import _promtool

pytestmark = pytest.mark.slow


async def until(what: str, condition: Callable[[], Any], timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {timeout} s"
        await asyncio.sleep(0.02)


# -- the plan ----------------------------------------------------------------------------------

def _demands() -> List[Demand]:
    return [Demand("cheap", asked=60, target=30, cost=0.002),
            Demand("slow", asked=60, target=10, cost=0.030, match=0.0),
            Demand("raw", asked=60, target=30, cost=0.003, raw=True)]


def test_every_target_that_fits_is_planned_as_asked() -> None:
    rate, limited = plan_rates(_demands(), cores=2.0, copy=0.001, raw_copy=0.001)
    assert math.isinf(rate) and not limited


def test_over_budget_every_view_gets_one_common_rate_that_fits() -> None:
    demands, cores = _demands(), 0.2
    rate, limited = plan_rates(demands, cores=cores, copy=0.001, raw_copy=0.001)
    assert limited and MIN_FPS < rate < 30
    assert plan_cost(demands, rate, 0.001, 0.001) <= cores + 1e-6
    assert plan_cost(demands, rate * 1.01, 0.001, 0.001) > cores  # the most that fits, not less
    # The slow view's lower target is kept: only the others share what it leaves.
    assert min(10, rate) == 10 if rate >= 10 else rate < 10


def test_a_budget_too_small_for_anything_still_gives_min_fps() -> None:
    rate, limited = plan_rates(_demands(), cores=0.001, copy=0.001, raw_copy=0.001)
    assert limited and rate == MIN_FPS


class FakeCpu:
    def __init__(self) -> None:
        self.used = 0.0

    def sample(self) -> float:
        return self.used


def test_the_gain_shrinks_while_the_daemon_is_over_and_the_reason_is_given() -> None:
    budget = CpuBudget(0.3)
    cpu = FakeCpu()
    budget.cpu = cpu  # type: ignore[assignment]
    demands = [Demand(f"v{i}", asked=60, target=60, cost=0.004) for i in range(7)]
    cpu.used = 0.25
    first = budget.plan(demands, frame_bytes=W * H * 8)
    reason = "CPU budget: 0.3 cores shared by 7 views"
    assert all(p.limited and p.reason.startswith(reason) for p in first.values())
    rate = budget.rate_cap
    cpu.used = 0.6  # the model missed half of what the daemon spends: the next plan gives less
    budget.plan(demands, frame_bytes=W * H * 8)
    assert budget.gain < 1 and budget.rate_cap < rate
    assert budget.copy_rate == pytest.approx(budget.rate_cap)
    status = budget.status()
    assert status["limited"] is True and status["used_cores"] == 0.6


# -- the pipeline copies only what is wanted ---------------------------------------------------

async def test_the_pipeline_sees_every_frame_and_copies_only_what_is_wanted() -> None:
    overlay = make_overlay()
    published: List[Any] = []
    alive = threading.Event()
    first: List[int] = []  # the number of the first frame the pipeline saw

    def seen_one() -> None:
        if not first and pipeline.last_frame_number is not None:
            first.append(pipeline.last_frame_number)
        alive.set()

    wanted: Dict[str, Any] = {"rate": 0.0}
    pipeline = Pipeline(overlay, publish=published.append, alive=seen_one,
                        copy_rate=lambda: wanted["rate"])
    overlay.start()
    pipeline.start()
    try:
        await until("frames seen", lambda: pipeline.seen >= 10)
        assert published == [] and pipeline.frames == 0 and alive.is_set()
        assert pipeline.last_frame_number is not None
        # 5 frames a second of a 25 fps fabric: about one in five is copied, never more than the rate.
        wanted["rate"] = 5.0
        t0, copies0 = time.monotonic(), pipeline.frames
        await until("copies at the wanted rate", lambda: pipeline.frames >= copies0 + 5)
        seconds = time.monotonic() - t0
        assert pipeline.frames - copies0 <= 5.0 * seconds + 2
        # Every frame while somebody waits for one (None).
        wanted["rate"] = None
        seen = pipeline.frames_seen
        await until("every frame copied", lambda: pipeline.frames_seen >= seen + 10)
        copied, seen = pipeline.frames, pipeline.frames_seen
        await until("ten more", lambda: pipeline.frames_seen >= seen + 10)
        assert pipeline.frames - copied >= 9  # (one may straddle the switch)
        numbers = [fs.frame for fs in published]
        assert numbers == sorted(set(numbers))  # numbered by the fabric's count, never repeated
    finally:
        pipeline.stop()
        overlay.close()
    # Every frame the fabric completed is accounted for: copied, only seen, or counted as a drop
    # (a busy machine may make the thread late for one; the books must still balance).
    assert pipeline.last_frame_number is not None and first
    assert pipeline.frames_seen + pipeline.drops == pipeline.last_frame_number - first[0] + 1


# -- thumbnails, status and metrics ------------------------------------------------------------

async def test_thumbnails_are_scaled_views_and_a_bad_scale_is_refused(start_daemon) -> None:
    d = await start_daemon()
    sizes = (("rect_left", (W // 2, H // 2)), ("sbs", (W, H // 2)), ("disparity", (W // 4, H // 4)))
    for view, size in sizes:
        scale = 0.25 if view == "disparity" else 0.5
        async with d.http.get(f"/snapshot/{view}.png?scale={scale}") as resp:
            assert resp.status == 200, await resp.text()
            image = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
        assert (image.shape[1], image.shape[0]) == size, view
    async with d.http.get("/snapshot/rect_left.png") as resp:
        full = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    assert (full.shape[1], full.shape[0]) == (W, H)
    async with d.http.get("/stream/rect_left?scale=0.3") as resp:
        assert resp.status == 400 and "scale must be one of 0.25, 0.5, 1" in (await resp.json())["error"]


async def _watch(d: Any, doc: Dict[str, Any], frames: int) -> Dict[str, List[Dict[str, Any]]]:
    """Watch over the page's WebSocket until every view asked for has sent ``frames`` frames."""
    got: Dict[str, List[Dict[str, Any]]] = {v: [] for v in doc["views"]}
    async with d.http.ws_connect("/ws") as ws:
        await ws.send_json(doc)
        deadline = time.monotonic() + WAIT_S
        while min(len(v) for v in got.values()) < frames:
            assert time.monotonic() < deadline, {v: len(x) for v, x in got.items()}
            msg = await ws.receive(timeout=WAIT_S)
            n = struct.unpack(">I", msg.data[:4])[0]
            header = json.loads(msg.data[4:4 + n])
            jpeg = cv2.imdecode(np.frombuffer(msg.data[4 + n:], np.uint8), cv2.IMREAD_UNCHANGED)
            header["size"] = (jpeg.shape[1], jpeg.shape[0])
            got[header["view"]].append(header)
    return got


async def test_the_page_socket_sends_thumbnails_and_full_views(start_daemon) -> None:
    d = await start_daemon()
    got = await _watch(d, {"views": ["rect_left", "raw_right"], "fps": 25, "scale": 0.5,
                           "full": ["raw_right"]}, frames=2)
    assert {h["size"] for h in got["rect_left"]} == {(W // 2, H // 2)}
    assert {h["size"] for h in got["raw_right"]} == {(W, H)}


async def test_a_tight_budget_lowers_every_watched_view_and_says_why(start_daemon) -> None:
    # Today's bitstream (no stereo core): the ARM's StereoBM makes the disparity view the costly one.
    # With the core the view is an encoding like the others (the planner's figures for it: issue 23).
    d = await start_daemon(cpu_budget=0.05,  # less than this machine needs for three views at 25 fps
                           overlay=make_overlay(stereo=False))
    views = ["rect_left", "rect_right", "disparity"]
    watching = asyncio.ensure_future(_watch(d, {"views": views, "fps": 25}, frames=10 ** 6))
    try:
        budget = d.app[BUDGET]
        await until("a limited plan", lambda: budget.rate_cap < math.inf and len(budget.plans) == 3)
        async with d.http.get("/api/status") as resp:
            status = await resp.json()
        assert status["cpu"]["cores"] == 0.05 and status["cpu"]["limited"] is True
        for e in status["encoders"]:
            assert e["planned_fps"] < e["target_fps"], e
            assert e["limited_by"].startswith("CPU budget: 0.05 cores"), e
            assert e["cost_ms"] > 0
        # Frames beyond what the planned views need are seen, not copied.
        pipeline = d.app[PIPELINE]
        await until("frames seen and not copied", lambda: pipeline.seen > 0)
        assert budget.copy_rate is not None and budget.copy_rate < 25
        async with d.http.get("/metrics") as resp:
            text = await resp.text()
        assert re.search(r'^stereocam_cpu_budget_cores 0\.05$', text, re.M)
        assert re.search(r'^stereocam_view_limited\{reason="CPU budget: 0\.05 cores shared by 3 views",'
                         r'view="disparity"\} 1\.0$', text, re.M), text
        assert re.search(r'^stereocam_view_planned_frames_per_second\{view="rect_left"\} ', text, re.M)
        await _promtool(text)
    finally:
        watching.cancel()
        await asyncio.gather(watching, return_exceptions=True)


# -- the floor ---------------------------------------------------------------------------------

def test_the_daemon_cpu_reading_leaves_out_the_emulated_fabric_thread() -> None:
    """A thread named as the emulated fabric's burns a known CPU time and then waits: a reading that
    leaves it out, taken first, and one that counts it, taken after, differ by at least that time
    (the other threads' time only grows between the two, so a busy machine cannot reverse it)."""
    import os

    from stereocam.bench.budget import FABRIC_THREAD
    from stereocam.overlays.emulated.clock import _name_os_thread

    burnt: List[float] = []
    done, release = threading.Event(), threading.Event()

    def fabric() -> None:
        _name_os_thread(FABRIC_THREAD)
        start = time.thread_time()
        while time.thread_time() - start < 0.3:
            pass
        burnt.append(time.thread_time())
        done.set()
        release.wait(WAIT_S)

    thread = threading.Thread(target=fabric)
    thread.start()
    try:
        assert done.wait(WAIT_S)
        without = daemon_cpu_seconds(os.getpid())
        with_it = daemon_cpu_seconds(os.getpid(), excluded="no-such-thread")
    finally:
        release.set()
        thread.join(WAIT_S)
    tick = 1 / os.sysconf("SC_CLK_TCK")  # /proc counts CPU time in clock ticks
    assert with_it - without >= burnt[0] - 2 * tick


def test_the_budget_bench_shares_0_3_cores_among_seven_views_and_leaves_one_view_be(capsys) -> None:
    """``stereocam bench budget`` end to end, briefly: the daemon under ``--cpu-budget 0.3`` plans
    seven watched views below what they ask, for the budget's reason, and every one of them delivers;
    one view alone is planned at the fabric's rate, limited by nothing else. The rates and cores it
    measures are the floor's figures (0.3 cores, 2 fps each, one view at the fabric's rate): those
    are performance goals, judged by the benchmark (exit 1 below them), not by this test, as a
    machine busy with other work takes frames and CPU from any window."""
    from stereocam.bench.budget import VIEWS
    from stereocam.cli import main
    from stereocam.server.frames.views import uses_disparity_worker

    code = main(["bench", "budget", "--json", "--cores", "0.3", "--seconds", "20", "--one-seconds", "5"])
    result = json.loads(capsys.readouterr().out)
    every, one = result["all"], result["one"]
    assert code == (0 if result["meets_floor"] else 1), result
    assert result["meets_floor"] == all(result["checks"].values())
    assert set(every["delivered_fps"]) == set(VIEWS) == set(every["planned_fps"]), every
    assert all(rate > 0 for rate in every["delivered_fps"].values()), every  # nobody starves
    # One rate for every view but those of the disparity worker (disparity and depth: their own, lower
    # target): the budget's common
    # rate when seven views at the fabric's rate are over it, as at the fabric's 30 fps they are; the
    # fabric's rate itself when a machine busy with other work slowed the emulated fabric so far
    # that they fit.
    rates = {rate for view, rate in every["planned_fps"].items() if not uses_disparity_worker(view)}
    assert len(rates) == 1 and min(rates) >= MIN_FPS, every
    if f"CPU budget: 0.3 cores shared by {len(VIEWS)} views" in every["limited_by"]:
        assert min(rates) < every["camera_fps"], every
    else:
        assert "the fabric's rate" in every["limited_by"], every
    assert one["camera_fps"] and one["delivered_fps"]["rect_left"] > 0, one
    assert one["planned_fps"]["rect_left"] >= 0.99 * one["camera_fps"], one  # the budget leaves it be
    assert one["limited_by"] == ["the fabric's rate"], one


def test_the_default_budget_is_the_boards_on_a_board_even_emulated() -> None:
    """Issue 25 item 5: `auto` on a board without its bitstream emulates within the board's budget."""
    whole = float(os.cpu_count() or 1)
    assert default_cores("pynq") == BOARD_CORES == default_cores("emulated", board=True) == 1.0
    assert default_cores("emulated") == whole
