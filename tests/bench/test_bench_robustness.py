"""``stereocam bench robustness`` runs end to end, each figure against its floor (no speed asserts)."""
from __future__ import annotations

import contextlib
import copy
import io
import json

import pytest

from stereocam.bench import robustness as br
from stereocam.bench.alias_bomb import alias_bombs
from stereocam.cli import main

pytestmark = pytest.mark.slow

SHORT = ["--requests", "150", "--fps", "15", "--rounds", "1", "--reads", "3", "--settle", "5"]


@pytest.fixture(scope="module")
def short_run() -> tuple:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["bench", "robustness", "--json", *SHORT])
    text = out.getvalue()
    assert text.count("\n") == 1, "one JSON object on one line"
    return code, json.loads(text)


@pytest.mark.timeout(600)  # starts the daemon: a busy machine makes it slower, never red
def test_the_short_run_reports_every_figure_and_its_floor(short_run) -> None:
    code, result = short_run
    barrage, bomb, reader = result["barrage"], result["alias_bomb"], result["slow_reader"]
    assert barrage["requests"] == 150 and sum(barrage["kinds"].values()) == 150
    assert sum(barrage["statuses"].values()) == 150 and barrage["status_5xx"] == 0
    assert barrage["tracebacks"] == 0 and barrage["unexpected"] == [], barrage
    assert barrage["stream_parts"] > 0 and 0 < barrage["stream_max_gap_s"] <= barrage["seconds"] + 1
    for key in ("rss_ready_mb", "rss_start_mb", "rss_peak_mb", "rss_end_mb"):
        assert barrage[key] > 10, (key, barrage[key])
    assert barrage["rss_peak_mb"] >= barrage["rss_start_mb"]
    assert barrage["rss_delta_mb"] == pytest.approx(barrage["rss_end_mb"] - barrage["rss_start_mb"], abs=0.2)
    assert barrage["websocket_messages"] > 0 and barrage["websocket_unexpected"] == []
    assert bomb["statuses"] == {"400": 3} and 0 < bomb["ms_median"] <= bomb["ms_max"]
    assert sorted(bomb["ms_max_by_file"]) == sorted(alias_bombs("x: 1\n"))
    assert len(reader["frames"]) == 3 and reader["frames"] == sorted(reader["frames"])
    assert reader["client"]["frames"] >= 3 and reader["lag_max_periods"] >= 0 and reader["lag_max_s"] >= 0
    assert result["floor"] == {"stream_max_gap_s": 1.0, "status_5xx": 0, "tracebacks": 0,
                               "rss_delta_mb": 50.0, "alias_bomb_ms": 100.0, "slow_reader_lag_periods": 2.0}
    assert result["meets"]["requests"] is False  # 150 are not the 2,000 of the floor
    assert result["meets"] == br.meets(result) and result["meets_floor"] is False and code == 1


@pytest.mark.timeout(600)
def test_each_floor_decides_the_exit_code_and_has_its_line(short_run) -> None:
    _, result = short_run
    good = copy.deepcopy(result)
    good["barrage"].update(requests=2000, stream_max_gap_s=0.2, status_5xx=0, tracebacks=0, rss_delta_mb=3.0)
    good["alias_bomb"].update(ms_max=5.0, statuses={"400": 15})
    good["slow_reader"].update(lag_max_periods=1)
    assert all(br.meets(good).values())
    for section, key, value in (("barrage", "stream_max_gap_s", 1.5), ("barrage", "status_5xx", 1),
                                ("barrage", "tracebacks", 2), ("barrage", "rss_delta_mb", 51.0),
                                ("alias_bomb", "ms_max", 100.0),
                                ("alias_bomb", "statuses", {"400": 14, "500": 1}),
                                ("slow_reader", "lag_max_periods", 3)):
        bad = copy.deepcopy(good)
        bad[section][key] = value
        assert not all(br.meets(bad).values()), (section, key, value)
    good["meets"] = br.meets(good)
    lines = br.text_lines(good)
    assert len(lines) == 8 and sum("[ok]" in line for line in lines) == 7, lines
    for words in ("5xx answers", "log tracebacks", "stream max gap", "memory", "alias bomb", "slow reader"):
        assert any(line.startswith(words) for line in lines), words
