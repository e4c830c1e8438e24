"""The ``serve`` benchmark runs end to end: structure of its JSON and frames delivered (no speed asserts)."""
from __future__ import annotations

import json
import os
import time

import pytest

from stereocam.bench.serve import measure_serve, tree_cpu_seconds

pytestmark = pytest.mark.slow


def test_serve_bench_short_run() -> None:
    result = measure_serve(seconds=1.0, clients=(1, 3), fps=15.0, warmup=0.5)
    json.dumps(result)  # JSON-able
    assert result["view"] == "rect_left" and result["fps_target"] == 15.0
    runs = result["runs"]
    assert isinstance(runs, dict) and sorted(runs) == ["1", "3"]
    for key, run in runs.items():
        assert run["clients"] == int(key)
        for field in ("delivered_fps_mean", "delivered_fps_min", "cpu_s_per_frame", "daemon_cpu_s",
                      "latency_ms_p50", "latency_ms_p95", "window_s", "bench_client_cpu_s"):
            assert isinstance(run[field], float), (key, field, run[field])
        assert run["delivered_fps_min"] > 0 and run["frames_per_client_mean"] >= 1, run
        assert run["delivered_fps_min"] <= run["delivered_fps_mean"]
        assert run["latency_ms_p50"] <= run["latency_ms_p95"]
        assert run["daemon_cpu_s"] > 0, "the daemon's CPU time was not read"
    ratio = result["cpu_ratio_3_vs_1"]
    assert isinstance(ratio, float) and ratio > 0
    assert isinstance(result["meets_floor"], bool)


def test_tree_cpu_seconds_counts_this_process() -> None:
    # Burn a little CPU and see it in /proc/<pid>/stat.
    before = tree_cpu_seconds(os.getpid())
    deadline = time.monotonic() + 60.0  # a last-resort bound: a busy machine gives this process less CPU
    while tree_cpu_seconds(os.getpid()) - before < 0.05:
        sum(range(10000))
        assert time.monotonic() < deadline, "0.05 s of CPU time never showed up in /proc/<pid>/stat"
