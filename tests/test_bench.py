"""``stereocam bench --json`` prints one JSON object with every figure the issue asks for."""
from __future__ import annotations

import json

from stereocam.cli import main


def test_bench_json(capsys) -> None:
    assert main(["bench", "--json", "--seconds", "0.1"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    result = json.loads(out)
    for key in ("model_fps", "reference_fps", "fabric_fps", "opencv_remap_fps"):
        assert isinstance(result[key], float) and result[key] > 0, key
    assert abs(result["ratio"] - result["model_fps"] / result["opencv_remap_fps"]) < 0.01
    assert result["frame"] == [752, 480] and result["channels"] == 8
    # The model and OpenCV's remap did the same work: identical output on the rig's frames.
    assert result["model_equals_opencv_share"] == 1.0
    assert result["line_buffer_rows_needed"] <= 80
    assert result["reference_fps"] < result["model_fps"]
