"""The shared RTL modules refuse parameters they cannot honour at elaboration, naming the rule.

A check is a generate block instantiating a module whose name states the rule
(``rc_fifo_parameter_DEPTH_must_be_at_least_2``); no such module exists, so every
tool stops there with that name in its message. Icarus elaborates in well under a
second, so each case is cheap.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from stereocam.overlays.rtl import toolchain as hdl

RTL = hdl.rtl_dir()

CASES = [
    ("rc_fifo", {"DEPTH": 1}, "rc_fifo_parameter_DEPTH_must_be_at_least_2"),
    ("rc_fifo", {"SHOW_AHEAD": 2}, "rc_fifo_parameter_SHOW_AHEAD_must_be_0_or_1"),
    ("rc_ram", {"WIDTH": 0}, "rc_ram_parameter_WIDTH_must_be_at_least_1"),
    ("rc_ram", {"DEPTH": 1}, "rc_ram_parameter_DEPTH_must_be_at_least_2"),
    ("rc_ram", {"DEPTH": 9, "AW": 3}, "rc_ram_parameter_AW_too_small_for_DEPTH"),
    ("rc_skid", {"WIDTH": 0}, "rc_skid_parameter_WIDTH_must_be_at_least_1"),
    ("rc_fifo", {"OUTPUT_REG": 2}, "rc_fifo_parameter_OUTPUT_REG_must_be_0_or_1"),
    ("rc_fifo", {"OUTPUT_REG": 1, "SHOW_AHEAD": 0}, "rc_fifo_parameter_OUTPUT_REG_needs_SHOW_AHEAD_1"),
    ("rc_delay", {"WIDTH": 0}, "rc_delay_parameter_WIDTH_must_be_at_least_1"),
    ("rc_delay", {"LATENCY": -1}, "rc_delay_parameter_LATENCY_must_be_at_least_0"),
    ("rc_delay", {"RESET": 2}, "rc_delay_parameter_RESET_must_be_0_or_1"),
    ("rc_coord_delay", {"W": 0}, "rc_coord_delay_parameter_W_must_be_at_least_1"),
    ("rc_coord_delay", {"N": -1}, "rc_coord_delay_parameter_N_must_be_at_least_0"),
    ("rc_linebuf", {"WIDTH": 0}, "rc_linebuf_parameter_WIDTH_must_be_at_least_1"),
    ("rc_linebuf", {"DEPTH": 1}, "rc_linebuf_parameter_DEPTH_must_be_at_least_2"),
    ("rc_linebuf", {"DEPTH": 17, "AW": 4}, "rc_linebuf_parameter_AW_too_small_for_DEPTH"),
    ("rc_div", {"LANES": 0}, "rc_div_parameter_LANES_must_be_at_least_1"),
    ("rc_div", {"QB": 0, "SH": 0}, "rc_div_parameter_QB_must_be_at_least_1"),
    ("rc_div", {"SH": 34}, "rc_div_parameter_SH_must_be_0_to_QB"),
    ("rc_div", {"SH": -1}, "rc_div_parameter_SH_must_be_0_to_QB"),
    ("rc_div", {"NW": 2}, "rc_div_parameter_NW_must_exceed_QB_minus_SH"),
    ("rc_div", {"DW": 0}, "rc_div_parameter_DW_must_be_at_least_1"),
    ("rc_coord_mul", {"AW": 17}, "rc_coord_mul_parameters_out_of_range"),
    ("rc_coord_mul", {"AW": 43}, "rc_coord_mul_parameters_out_of_range"),
    ("rc_coord_mul", {"BW": 36}, "rc_coord_mul_parameters_out_of_range"),
    ("rc_coord_mul", {"LO": 16}, "rc_coord_mul_parameters_out_of_range"),
    ("ci_sync", {"WIDTH": 0}, "ci_sync_parameter_WIDTH_must_be_at_least_1"),
    ("ci_rx", {"MAX_WIDTH": 0}, "ci_rx_parameter_MAX_WIDTH_must_fit_the_length_field"),
    ("ci_rx", {"MAX_WIDTH": 2048, "AW": 12}, "ci_rx_parameter_MAX_WIDTH_must_fit_the_length_field"),
    ("ci_rx", {"MAX_WIDTH": 31, "AW": 5}, "ci_rx_parameter_AW_too_small_for_MAX_WIDTH"),
    ("stereo_core", {"MAX_DISP": 128, "PARALLEL": 16}, "stereo_core_parameter_MAX_DISP_must_be_4_x_PARALLEL"),
]
# What each top needs besides its own file (relative to the RTL folder).
SOURCES = {
    "rc_linebuf": ["rc_ram.v"],
    "ci_rx": ["camera/ci_sync.v"],
    "stereo_core": ["rc_ram.v", "rc_fifo.v",
                    *sorted(f"stereo/{p.name}" for p in (RTL / "stereo").glob("sc_*.v"))],
}
# The largest parameters each rule still allows, and the builds the callers make: they elaborate.
ALLOWED = [
    ("rc_fifo", {"DEPTH": 2, "OUTPUT_REG": 1}),
    ("rc_delay", {"LATENCY": 0, "RESET": 1}),
    ("rc_coord_delay", {"N": 0}),
    ("rc_linebuf", {"DEPTH": 16, "AW": 4}),
    ("rc_div", {"SH": 33}),
    ("rc_div", {"LANES": 3, "NW": 9, "DW": 7, "QB": 5, "SH": 3}),
    ("rc_coord_mul", {"AW": 42, "BW": 35, "LO": 17}),
    ("ci_rx", {"MAX_WIDTH": 2047, "AW": 12}),
    ("ci_rx", {"MAX_WIDTH": 30, "AW": 5}),
    ("stereo_core", {"MAX_DISP": 32, "PARALLEL": 8}),
]


def _path(top: str) -> Path:
    found = [path for path in (RTL / f"{top}.v", RTL / "camera" / f"{top}.v", RTL / "stereo" / f"{top}.v")
             if path.is_file()]
    return found[0]


def _elaborate(top: str, params: dict[str, int], out: Path) -> subprocess.CompletedProcess[str]:
    iverilog = hdl.check_tools("icarus")
    overrides = [arg for name, value in params.items() for arg in ("-P", f"{top}.{name}={value}")]
    sources = [str(RTL / s) for s in SOURCES.get(top, [])] + [str(_path(top))]
    return subprocess.run(
        [str(iverilog), "-g2005", "-I", str(RTL), "-I", str(RTL / "camera"), "-I", str(RTL / "stereo"),
         "-s", top, *overrides, "-o", str(out), *sources],
        capture_output=True, text=True, timeout=120, check=False,
    )


@pytest.mark.parametrize(("top", "params", "rule"), CASES, ids=[rule for _, _, rule in CASES])
def test_a_broken_parameter_stops_elaboration_by_name(top: str, params: dict[str, int], rule: str,
                                                      tmp_path: Path) -> None:
    result = _elaborate(top, params, tmp_path / "sim")
    assert result.returncode != 0
    assert rule in result.stdout + result.stderr


@pytest.mark.parametrize("top", sorted({top for top, _, _ in CASES}))
def test_the_defaults_elaborate(top: str, tmp_path: Path) -> None:
    result = _elaborate(top, {}, tmp_path / "sim")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(("top", "params"), ALLOWED,
                         ids=[f"{t}-" + "-".join(f"{k}{v}" for k, v in p.items()) for t, p in ALLOWED])
def test_parameters_at_a_rule_s_limit_elaborate(top: str, params: dict[str, int], tmp_path: Path) -> None:
    """A check is no stricter than its rule: the limit itself is allowed."""
    result = _elaborate(top, params, tmp_path / "sim")
    assert result.returncode == 0, result.stdout + result.stderr
