"""``stereocam bench recording``: a short run reports every figure; the floor decides the exit code."""
from __future__ import annotations

import argparse
from typing import Any, Dict

import pytest

from stereocam.bench import recording
from stereocam.cli import build_parser

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def short_run() -> Dict[str, Any]:
    return recording.measure_recording(fps=30.0, seconds=2.0, warmup=1.0)


def test_the_short_run_reports_every_figure(short_run: Dict[str, Any]) -> None:
    r = short_run
    assert r["frames"] > 0 and r["fps"] > 0 and r["frame_size"] == [752, 480]
    assert r["stop_to_done_s"] > 0 and isinstance(r["queued_at_stop"], int)
    assert 0 < r["bytes_per_frame"] < r["rgb_png_bytes_per_frame"]  # camera frames: smaller than level 3
    assert r["skipped"] >= 0 and r["missed"] >= 0
    assert r["meets_floor"] == (r["stop_to_done_s"] < recording.FLOOR_STOP_S)
    lines = recording.text_lines(r)
    assert any(line.startswith("stop to done") for line in lines)
    assert any(line.startswith("per frame") for line in lines)


def test_the_floor_decides_the_exit_code(short_run: Dict[str, Any], monkeypatch, capsys) -> None:
    args = build_parser().parse_args(["bench", "recording", "--seconds", "2", "--json"])
    assert args.func is recording.run_recording
    for stop_s, code in ((0.5, 0), (recording.FLOOR_STOP_S, 1)):
        result = dict(short_run, stop_to_done_s=stop_s, meets_floor=stop_s < recording.FLOOR_STOP_S)
        monkeypatch.setattr(recording, "measure_recording", lambda r=result, **kw: r)
        assert recording.run_recording(argparse.Namespace(**vars(args))) == code
    assert '"stop_to_done_s"' in capsys.readouterr().out
