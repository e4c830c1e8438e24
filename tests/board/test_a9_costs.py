"""The Cortex-A9 cost table `stereocam bench a9` counts, and the CPU budget planning with it on the board.

The counting itself runs the daemon's code as armhf under QEMU with a plugin of ours; here, what
needs no emulator: the table is current for the code it measured, it holds every per-frame
operation with sane numbers, the host side turns the plugin's marks into it, and the daemon's
budget takes its priors from it on the board (and this machine's elsewhere)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereocam.bench.a9 import run
from stereocam.board import a9_costs
from stereocam.server.frames import views
from stereocam.server.frames.cpu_budget import (
    HEADROOM,
    HOST_PRIORS,
    CpuBudget,
    board_priors,
    default_cores,
    plan_cost,
    plan_rates,
)
from stereocam.server.frames.encoders import EncoderKey, demand_for
from stereocam.server.http.app import BOARD_DISPARITY_FPS, arm_disparity, budget_priors
from stereocam.server.http.settings import Settings


def test_the_table_was_measured_on_the_code_as_it_is() -> None:
    table = a9_costs.load_table()
    assert a9_costs.is_current(table), (
        "a file the A9 table measures changed (stereocam/board/a9_costs.py: MEASURED): run "
        "`stereocam bench a9` and commit stereocam/board/a9_costs.json")
    changed = dict(table, fingerprint="0" * 16)
    assert not a9_costs.is_current(changed)


def test_the_table_holds_every_per_frame_operation_with_a_time_range() -> None:
    table = a9_costs.load_table()
    ops = table["ops"]
    for view in views.VIEWS:
        if not views.uses_disparity_worker(view):
            assert f"render.{view}.colour.x1" in ops and f"render.{view}.colour.x0.5" in ops, view
    assert {"copy.frame", "jpeg.colour.q80", "jpeg.gray.q80", "png.colour", "png.gray", "stereobm.full",
            "stereobm.colour_map", "import.cli", "import.serve"} <= set(ops)
    cpi = table["cpu"]["cpi"]
    for name, op in ops.items():
        low, high = op["ms"]
        assert op["instructions"] > 0 and 0 < low < high, name
        assert high == pytest.approx(low * cpi[1] / cpi[0], rel=1e-3), name
    # what the work is, in order: a JPEG grows with its quality, a thumbnail costs less to encode,
    # a wide view more, gray less than colour, and StereoBM dwarfs every encode
    assert ops["jpeg.colour.q50"]["instructions"] < ops["jpeg.colour.q80"]["instructions"] \
        < ops["jpeg.colour.q95"]["instructions"]
    assert ops["jpeg.colour_half.q80"]["instructions"] < ops["jpeg.colour.q80"]["instructions"] \
        < ops["jpeg.colour_wide.q80"]["instructions"]
    assert ops["jpeg.gray.q80"]["instructions"] < ops["jpeg.colour.q80"]["instructions"]
    assert ops["stereobm.full"]["instructions"] > 20 * ops["jpeg.colour.q80"]["instructions"]


def test_the_plugins_marks_become_instructions_per_run() -> None:
    marks = run.read_marks("0 100\n1 1100\n2 1100\n3 7100\nexit 9000\n")
    assert marks == {0: 100, 1: 1100, 2: 1100, 3: 7100}
    ops = [{"name": "a", "mark": 0, "reps": 2}, {"name": "b", "mark": 2, "reps": 3}]
    assert run.per_op(marks, ops) == {"a": 500, "b": 2000}
    with pytest.raises(run.A9Error, match="no marks 4 and 5 around c"):
        run.per_op(marks, [{"name": "c", "mark": 4, "reps": 1}])
    table = run.table_of({"a": 650_000}, {"python": "3.11.2", "frame": [752, 480]}, "7.2.0")
    assert table["ops"]["a"] == {"instructions": 650_000, "ms": [1.0, 1.5]}
    assert table["fingerprint"] == a9_costs.fingerprint() and table["cpu"]["clock_hz"] == 650_000_000


def test_on_the_board_the_budget_plans_with_the_a9s_costs(tmp_path: Path) -> None:
    seconds = a9_costs.board_seconds()
    priors = board_priors()
    frame = 752 * 480
    colour_view = priors.encode_s_per_byte * 3 * frame
    assert colour_view == pytest.approx(seconds["render.rect_left.colour.x1"] + seconds["jpeg.colour.q80"])
    assert priors.match_s_per_pixel * frame == pytest.approx(seconds["stereobm.full"]
                                                             + seconds["stereobm.colour_map"])
    # the A9 pays many times what this machine does, for everything
    assert priors.encode_s_per_byte > 5 * HOST_PRIORS.encode_s_per_byte
    assert priors.match_s_per_pixel > 5 * HOST_PRIORS.match_s_per_pixel
    assert budget_priors("pynq", False) == priors == budget_priors("emulated", True)
    assert budget_priors("emulated", False) == HOST_PRIORS
    budget = CpuBudget(1.0, priors=priors)
    assert "a9_costs.json" in str(budget.status()["priors"])
    # a table that cannot be read: this machine's priors, not a daemon that will not start
    broken = tmp_path / "a9_costs.json"
    broken.write_text("{", encoding="utf-8")
    with pytest.raises(a9_costs.A9TableError, match="stereocam bench a9"):
        a9_costs.load_table(broken)
    assert json.loads(a9_costs.TABLE.read_text())["cpu"]["name"] == "Cortex-A9"


def test_the_pages_default_fits_the_boards_budget_with_every_view_at_2_fps_or_more() -> None:
    """Issue 25 item 3, by the table: the page's default (every view as a half-size thumbnail at the
    default quality, 15 fps asked, cameras at 60 fps) planned by the daemon's planner on the board's
    budget, today's bitstream (StereoBM on the ARM): every view at 2 fps or more but the disparity
    views, which run at a slower rate of their own, granted in full, as the status panel says."""
    settings = Settings()
    scale, disparity_fps = arm_disparity(settings, board=True, has_stereo=False)
    assert (scale, disparity_fps) == (0.5, BOARD_DISPARITY_FPS)
    assert arm_disparity(settings, board=False, has_stereo=False) == (1.0, 10.0)
    assert arm_disparity(settings, board=True, has_stereo=True) == (0.5, 10.0), "a stereo core: no ARM work"
    budget = CpuBudget(default_cores("pynq"), priors=budget_priors("pynq", False, scale))
    frame, thumb, page_fps, camera_fps = (752, 480), 0.5, 15.0, 60.0
    demands = [demand_for(EncoderKey(view, settings.default_quality, False, thumb), page_fps, camera_fps,
                          frame, budget, disparity_fps) for view in views.VIEWS]
    seconds = a9_costs.board_seconds()
    # the planner's costs are the table's: a thumbnail is the view rendered, scaled and encoded
    rect = next(d for d in demands if d.key.view == "rect_left")
    assert rect.cost == pytest.approx(seconds["render.rect_left.colour.x0.5"]
                                      + seconds["jpeg.colour.q80"] / 4, rel=1e-3)
    disparity = next(d for d in demands if d.key.view == "disparity")
    assert disparity.match * 1.0 == pytest.approx(seconds["stereobm.half"] + seconds["stereobm.colour_map"])
    frame_bytes = frame[0] * frame[1] * 8
    copy = budget.priors.copy_s_per_byte * frame_bytes
    cores = HEADROOM * budget.cores
    rate, _ = plan_rates(demands, cores, copy, copy)
    planned = {d.key.view: min(d.target, rate) for d in demands}
    for view, fps in planned.items():
        if views.uses_disparity_worker(view):
            assert fps == disparity_fps, (view, planned)
        else:
            assert fps >= 2.0, (view, planned)
    assert plan_cost(demands, rate, copy, copy) <= cores + 1e-9
    # at full size StereoBM alone would take more than the board's core at that rate: why half
    full = budget_priors("pynq", False, 1.0).match_s_per_pixel * frame[0] * frame[1]
    assert full * disparity_fps > budget.cores
