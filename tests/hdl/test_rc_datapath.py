"""rc_datapath (stereocam/overlays/rtl/rc_datapath.v) on its own, in Verilator and Icarus, against a numpy
model.

The testbench (``tb_rc_datapath.py``) plays rc_regs and the coordinate engine. Small builds
(64 columns, 16-row line buffer, gray and colour) keep a run within seconds;
``STEREOCAM_COSIM_FULL=1`` runs more seeds of every case.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from stereocam.overlays.rtl import toolchain as hdl

from .cocotb_run import run_cocotb

FULL = os.environ.get("STEREOCAM_COSIM_FULL") == "1"


def datapath_sources() -> list[Path]:
    rtl = hdl.rtl_dir()
    names = ["rc_datapath", "rc_skid", "rc_ram", "rc_fifo", "rc_delay", "rc_interp", "rc_gray", "rc_linebuf"]
    return [rtl / f"{n}.v" for n in names]


BUILDS = {
    # name: (MAX_WIDTH, MAX_HEIGHT, LB_ROWS, COLOUR)
    "colour-64x16": (64, 1024, 16, 1),
    "gray-64x16": (64, 1024, 16, 0),
    "colour-63x5": (63, 64, 5, 1),  # odd width, odd slot count, a window smaller than the delays
}


# Icarus is about ten times slower than Verilator: in CI it runs one build and a subset of the tests.
ICARUS_CI_TESTS = (r"random_taps/seed=0|bypass_and_debug_line/gray=False|enable_and_apply_pending"
                   r"|rate_and_latency")


# ... and Verilator runs every test on the first build, these on the others.
VERILATOR_CI_OTHER = (r"random_taps/seed=[01]|calibrations/seed=0|bypass_and_debug_line/gray=True"
                      r"|malformed_input/lb_delay=3")


@pytest.mark.timeout(2400)  # the full set under Icarus
@pytest.mark.parametrize("build", list(BUILDS))
def test_rc_datapath(sim: str, build: str, cocotb_dir: Path) -> None:
    """Every cocotb test of tb_rc_datapath (more seeds with STEREOCAM_COSIM_FULL=1); in CI Verilator
    runs all on the first build and VERILATOR_CI_OTHER on the others, Icarus ICARUS_CI_TESTS on
    the first and one seed of random taps on the others."""
    mw, mh, lb, colour = BUILDS[build]
    env = {"STEREOCAM_DP_BUILD": f"{mw},{mh},{lb},{colour}", "COCOTB_RANDOM_SEED": "1"}
    if FULL:
        env["STEREOCAM_COSIM_FULL"] = "1"
    elif sim == "icarus":
        tests = ICARUS_CI_TESTS if build == "colour-64x16" else "random_taps/seed=0"
        env["COCOTB_TEST_FILTER"] = rf"tb_rc_datapath\.({tests})$"
    elif build != "colour-64x16":
        env["COCOTB_TEST_FILTER"] = rf"tb_rc_datapath\.({VERILATOR_CI_OTHER})$"
    run = run_cocotb(
        "rc_datapath", datapath_sources(), "tb_rc_datapath", sim=sim,
        parameters={"MAX_WIDTH": mw, "MAX_HEIGHT": mh, "LB_ROWS": lb, "COLOUR": colour},
        includes=[hdl.rtl_dir()], extra_env=env, test_dir=cocotb_dir,
    )
    print(f"{sim} {build}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s, "
          f"{len(run.passed)} tests")


def test_rc_datapath_lints_clean() -> None:
    """Verilator -Wall on rc_datapath and its helpers, both builds (initial values on registers are
    the style)."""
    import subprocess

    exe = hdl.verilator_bin()
    for colour in (0, 1):
        out = subprocess.run(
            [str(exe), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{hdl.rtl_dir()}",
             "--top-module", "rc_datapath", f"-GCOLOUR={colour}", *map(str, datapath_sources())],
            capture_output=True, text=True, timeout=120, check=False,
        )
        assert out.returncode == 0, out.stderr[-3000:]


def yosys_stat(top: str, files: list[Path], chparams: dict[str, int]) -> dict[str, int]:
    """Cell counts of ``top`` after yosys 0.23 ``synth_xilinx -family xc7``."""
    import re
    import subprocess
    import tempfile

    hdl.check_tools("yosys")
    sets = "".join(f"chparam -set {k} {v} {top}; " for k, v in chparams.items())
    with tempfile.TemporaryDirectory() as tmp:
        stat = Path(tmp) / "stat.txt"
        script = (f"read_verilog -sv -I {hdl.rtl_dir()} {' '.join(map(str, files))}; {sets}"
                  f"synth_xilinx -family xc7 -top {top}; tee -q -o {stat} stat")
        subprocess.run(["yosys", "-q", "-p", script],
                       capture_output=True, text=True, timeout=1500, check=True)
        out = stat.read_text()
    # the whole design's counts follow the hierarchy (a flat design has only its own block)
    block = out[out.rindex("=== design hierarchy ==="):] if "=== design hierarchy ===" in out else out
    return {m[1]: int(m[2]) for m in re.finditer(r"^\s+(\w+)\s+(\d+)\s*$", block, re.M)}


@pytest.mark.timeout(600)
@pytest.mark.parametrize("build", ["gray", "colour"])
def test_rc_datapath_resources(build: str) -> None:
    """Real build sizes: no DSP anywhere (interpolation in LUTs), the line buffers in block RAM.

    Per camera four banks of ceil(81 / 2) * 376 words (RGB 24 bits: 12 BRAM36 each, gray 8 bits:
    4), both cameras: 96 or 32; the BYPASS side buffer (two rows of the other bits) 1 or 3.
    """
    from stereocam.overlays.spec.rectify import BUILDS

    b = BUILDS[build]
    cells = yosys_stat("rc_datapath", datapath_sources(),
                       {"MAX_WIDTH": b.max_width, "MAX_HEIGHT": b.max_height, "LB_ROWS": b.lb_rows,
                        "COLOUR": int(b.colour)})
    luts = sum(cells.get(f"LUT{i}", 0) for i in range(1, 7))
    ffs = sum(n for name, n in cells.items() if name.startswith("FD"))
    print(f"rc_datapath {build}: {cells.get('RAMB36E1', 0)} RAMB36E1, {cells.get('RAMB18E1', 0)} RAMB18E1, "
          f"{cells.get('DSP48E1', 0)} DSP48E1, {luts} LUT (logic), {ffs} FF")
    assert cells.get("DSP48E1", 0) == 0
    assert cells.get("RAMB36E1", 0) + cells.get("RAMB18E1", 0) / 2 <= (97 if b.colour else 35)
    interp = yosys_stat("rc_interp", [hdl.rtl_dir() / "rc_interp.v"], {})
    assert interp.get("DSP48E1", 0) == 0, "the interpolation must not use DSP48E1"
