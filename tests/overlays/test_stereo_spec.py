"""stereocam/overlays/STEREO_CORE.md and stereocam/overlays/spec/stereo.py describe the same core."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from stereocam.overlays.spec import stereo as spec

pytestmark = pytest.mark.armhf

DOC = (Path(spec.__file__).parents[1] / "STEREO_CORE.md").read_text()


def test_the_documents_register_table_is_the_maps() -> None:
    assert spec.STEREO_MAP.table_markdown() in DOC


def test_the_documents_limits_and_defaults_are_the_specs() -> None:
    for name, reg in spec.PARAM_REGISTERS.items():
        row = re.search(rf"^\| {reg} \| ([^|]+) \| (\d+)", DOC, re.M)
        assert row, reg
        assert int(row.group(2)) == getattr(spec.DEFAULT_PARAMS, name) == spec.STEREO_MAP[reg].reset
        lo, hi = spec.LIMITS[name](spec.DEFAULT_BUILD)
        if name != "num_disp":
            assert row.group(1).startswith(f"{lo} .. {hi}"), reg
    for width_name, bits in (("cost C", spec.COST_BITS), ("path cost L_r", spec.PATH_BITS),
                             ("sum S", spec.SUM_BITS), ("disparity code", spec.DISP_BITS),
                             ("confidence", spec.CONF_BITS), ("reason", spec.REASON_BITS),
                             ("census word", spec.CENSUS_BITS)):
        assert f"| {width_name} | {bits} |" in DOC


def test_the_widths_hold_their_largest_values() -> None:
    assert len(spec.CENSUS_OFFSETS) == spec.CENSUS_BITS == 62
    assert spec.COST_OOB < 1 << spec.COST_BITS
    assert spec.COST_OOB + spec.P2_MAX == (1 << spec.PATH_BITS) - 1
    assert len(spec.PATHS) * ((1 << spec.PATH_BITS) - 1) < 1 << spec.SUM_BITS
    assert 16 * (spec.DEFAULT_BUILD.max_disp - 1) + 8 < spec.INVALID
    assert max(spec.REASONS) < 1 << spec.REASON_BITS


def test_the_control_registers_reset_is_the_default_parameters() -> None:
    control = spec.STEREO_MAP["CONTROL"]
    assert spec.register_values(spec.DEFAULT_PARAMS)["CONTROL"] == control.reset
    words = {r.name: r.reset for r in spec.STEREO_MAP}
    assert spec.params_from_registers(words) == spec.DEFAULT_PARAMS


@pytest.mark.parametrize("values", [dict(num_disp=64, lr_check=False),
                                    dict(p1=0, p2_edge=0, p2=0, median=False),
                                    dict(uniqueness=255, lr_tol=15, subpixel=False, edge_thresh=0)])
def test_registers_program_exactly_the_parameters(values: dict) -> None:
    p = spec.DEFAULT_PARAMS.with_values(**values)
    assert not p.problems()
    assert spec.params_from_registers(spec.register_values(p)) == p


@pytest.mark.parametrize("values, words", [
    (dict(num_disp=100), "multiple of 32"),
    (dict(num_disp=160), "32 .. 128"),
    (dict(p2=194), "0 .. 193"),
    (dict(p1=50, p2_edge=40), "p1 <= p2_edge <= p2"),
    (dict(p2_edge=120), "p1 <= p2_edge <= p2"),
    (dict(lr_tol=-1), "0 .. 15"),
    (dict(uniqueness=2.5), "whole number"),
    (dict(median="yes"), "true or false"),
])
def test_values_the_core_refuses_are_named_with_what_it_takes(values: dict, words: str) -> None:
    problems = spec.DEFAULT_PARAMS.with_values(**values).problems()
    assert problems and words in "; ".join(problems)


def test_frame_sizes_outside_the_build_are_refused() -> None:
    assert spec.size_problems(752, 480) == []
    assert "9 .. 752" in spec.size_problems(753, 480)[0]
    assert "7 .. 1024" in spec.size_problems(100, 6)[0]
