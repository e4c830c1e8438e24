"""The rectify core's register block, stereocam/overlays/rtl/rc_regs.v: co-simulation, lint and synthesis.

The cocotb testbench is ``tb_rc_regs.py``; it reads the build parameters of the run from
``RC_REGS_BUILD`` and derives every expectation from ``RECTIFY_MAP`` and ``PARAM_RANGE``.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest

from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec.rectify import BUILDS, DEFAULT_BUILD, PARAM_FORMAT, PARAM_NAMES, Build

from .cocotb_run import run_cocotb

SOURCE = hdl.rtl_dir() / "rc_regs.v"

# "default" runs the module's own parameter defaults (they must be DEFAULT_BUILD's); the
# named builds pass theirs; "small" has other numbers everywhere, so that no constant typed
# in the RTL instead of a parameter can pass.
BUILD_CASES: dict[str, Build | None] = {
    "default": None,
    **BUILDS,
    "small": Build("small", max_width=64, max_height=48, lb_rows=8, colour=False),
}
# Icarus builds in a second and runs every case; a Verilator build takes half a minute, so
# Verilator runs the defaults (the colour build's numbers), and the gray build too with
# STEREOCAM_COSIM_FULL=1 (./scripts/cosim).
FULL = os.environ.get("STEREOCAM_COSIM_FULL", "") not in ("", "0")
SIM_BUILDS = [
    pytest.param(sim, build, id=f"{sim}-{build}")
    for sim in hdl.SIMULATORS
    for build in BUILD_CASES
    if sim == "icarus" or build == "default" or (FULL and build == "gray")
]

TB_TESTS = {
    "reset_values",
    "unmapped_and_read_only_ignore_writes",
    "read_write_registers_read_back",
    "byte_strobes",
    "channel_order_and_backpressure",
    "flags_are_sticky_and_write_one_to_clear",
    "flag_raise_wins_over_a_clear",
    "status_follows_busy_and_apply",
    "frame_count_counts_and_wraps",
    "apply_when_idle_latches_on_the_next_clock",
    "apply_waits_for_idle",
    "validation_of_each_parameter",
    "validation_of_frame_size",
    "apply_while_the_shadow_is_being_written",
}


def _parameters(build: Build) -> dict[str, int]:
    return {
        "MAX_WIDTH": build.max_width,
        "MAX_HEIGHT": build.max_height,
        "LB_ROWS": build.lb_rows,
        "COLOUR": int(build.colour),
    }


@pytest.mark.parametrize(("sim", "build"), SIM_BUILDS)
def test_rc_regs_cosim(sim: str, build: str, cocotb_dir: Path) -> None:
    chosen = BUILD_CASES[build]
    parameters = _parameters(chosen) if chosen is not None else {}
    run = run_cocotb(
        "rc_regs",
        [SOURCE],
        "tb_rc_regs",
        sim=sim,
        parameters=parameters,
        includes=[hdl.rtl_dir()],
        extra_env={"RC_REGS_BUILD": json.dumps(_parameters(chosen or DEFAULT_BUILD))},
        test_dir=cocotb_dir,
    )
    print(
        f"{sim} {build}: build {run.build_seconds:.1f} s ({'built' if run.built else 'cached'}), "
        f"run {run.run_seconds:.1f} s, {len(run.passed)} cocotb tests"
    )
    assert {name.rsplit(".", 1)[-1] for name in run.passed} == TB_TESTS


@pytest.mark.parametrize("build", BUILD_CASES)
def test_rc_regs_lints_clean_with_verilator(build: str) -> None:
    # -Wall minus PROCASSINIT: initial values on registers are FPGA power-up values here.
    chosen = BUILD_CASES[build]
    overrides = [f"-G{name}={value}" for name, value in (_parameters(chosen) if chosen else {}).items()]
    result = subprocess.run(
        [str(hdl.verilator_bin()), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{hdl.rtl_dir()}",
         *overrides, str(SOURCE)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr


def _cells(stat: str) -> dict[str, int]:
    return {m[1]: int(m[2]) for m in re.finditer(r"^\s+(\w+)\s+(\d+)$", stat, re.M)}


def test_rc_regs_synthesizes_small_with_yosys(tmp_path: Path) -> None:
    """synth_xilinx for the xc7: no latches, the storage the spec implies, and a LUT budget.

    Storage: the shadow set (2 x RC_NPARAMS x 64 bits) and the active set (each
    parameter in its own width) in flip-flops; the read-back copy of the parameter
    words in distributed RAM (RAM64M, four LUTs each). The budget is for logic LUTs:
    the range check takes a few hundred, the byte-enable decode of the shadow words
    about 2 x 34 x 4, the read multiplexer and the rest about a hundred.
    """
    yosys = hdl.check_tools("yosys")
    stat_file = tmp_path / "stat.txt"
    script = (
        f"read_verilog -sv -I {hdl.rtl_dir()} {SOURCE}; synth_xilinx -family xc7 -top rc_regs; "
        f"check -assert; tee -q -o {stat_file} stat"
    )
    result = subprocess.run(
        [str(yosys), "-q", "-p", script],
        capture_output=True, text=True, timeout=1500, check=False, cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    stat = stat_file.read_text()
    cells = _cells(stat)
    luts = sum(n for name, n in cells.items() if re.fullmatch(r"LUT\d", name))
    ffs = sum(n for name, n in cells.items() if name.startswith("FD"))
    lutram = 4 * cells.get("RAM64M", 0) + 2 * cells.get("RAM64X1D", 0) + 4 * cells.get("RAM128X1D", 0)
    print(f"rc_regs on xc7: {luts} LUT logic + {lutram} LUT as distributed RAM, {ffs} FF; cells {cells}")
    assert not any("LATCH" in name.upper() or name.startswith("LD") for name in cells), stat
    assert not any(name.startswith("RAMB") for name in cells), "the read-back copy must not take a block RAM"
    shadow = 2 * len(PARAM_NAMES) * 64
    active = 2 * sum(PARAM_FORMAT[name].bits for name in PARAM_NAMES)
    assert ffs >= shadow + active, (
        f"{ffs} flip-flops cannot hold the shadow ({shadow}) and active ({active}) sets")
    assert ffs <= shadow + active + 600, f"{ffs} flip-flops: more than the sets and some control"
    assert luts <= 900, f"{luts} logic LUTs"
    assert lutram <= 128, f"{lutram} LUTs of distributed RAM for 2 x 34 words"
