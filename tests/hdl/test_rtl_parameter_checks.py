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
]


def _elaborate(top: str, params: dict[str, int], out: Path) -> subprocess.CompletedProcess[str]:
    iverilog = hdl.check_tools("icarus")
    overrides = [arg for name, value in params.items() for arg in ("-P", f"{top}.{name}={value}")]
    return subprocess.run(
        [str(iverilog), "-g2005", "-I", str(RTL), "-s", top, *overrides, "-o", str(out),
         str(RTL / f"{top}.v")],
        capture_output=True, text=True, timeout=120, check=False,
    )


@pytest.mark.parametrize(("top", "params", "rule"), CASES, ids=[rule for _, _, rule in CASES])
def test_a_broken_parameter_stops_elaboration_by_name(top: str, params: dict[str, int], rule: str,
                                                      tmp_path: Path) -> None:
    result = _elaborate(top, params, tmp_path / "sim")
    assert result.returncode != 0
    assert rule in result.stdout + result.stderr


@pytest.mark.parametrize("top", ["rc_fifo", "rc_ram"])
def test_the_defaults_elaborate(top: str, tmp_path: Path) -> None:
    result = _elaborate(top, {}, tmp_path / "sim")
    assert result.returncode == 0, result.stdout + result.stderr
