"""The camera input IP (stereocam/overlays/rtl/camera/) in Verilator and Icarus, bit-exact against its numpy
model.

The testbench (``tb_camera_in.py``) plays two MT9V034 buses on their own pixel clocks and compares
every output beat with ``stereocam/overlays/model/camera_in.py``. A 64-wide build keeps a run within seconds
(its line FIFOs hold 256 words, so backpressure overflows them quickly); the 752-wide build plays a 752 x 6
frame pair, a full 752 x 480 one with ``STEREOCAM_COSIM_FULL=1``, which also runs more seeds.
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec import camera_in as spec

from .cocotb_run import run_cocotb

FULL = os.environ.get("STEREOCAM_COSIM_FULL") == "1"

# every cocotb test of tb_camera_in but the full-size one, which needs the 752-wide build
SMALL_TESTS = (r"random_frames|unrelated_clocks|slow_aclk|backpressure_within_the_fifos"
               r"|backpressure_overflow_cuts_frames|cameras_that_disagree|reset_in_mid_frame")
# Icarus is about ten times slower: it runs these
ICARUS_TESTS = r"random_frames|cameras_that_disagree"


def camera_dir() -> Path:
    return hdl.rtl_dir() / "camera"


def camera_sources() -> list[Path]:
    names = ["camera_in", "ci_rx", "ci_lfifo", "ci_sync", "ci_demosaic",
             "../rc_ram", "../rc_fifo", "../rc_gray"]
    return [camera_dir() / f"{n}.v" for n in names]


def test_sources_are_the_whole_folder() -> None:
    """The folder holds camera_in's sources and the frame gate's, nothing else (both IPs are packaged
    from it)."""
    from stereocam.overlays.spec import frame_gate

    here = camera_dir().resolve()
    listed = {p.resolve() for p in camera_sources()} | {(here / n).resolve() for n in frame_gate.SOURCES}
    assert sorted(here.glob("*.v")) == sorted(p for p in listed if p.parent == here)
    assert all(p.is_file() for p in listed)


def test_top_module_has_the_spec_ports_and_parameters() -> None:
    """The ports and parameters another engineer packages from spec/camera_in.py are the RTL's."""
    import re

    text = (camera_dir() / "camera_in.v").read_text()
    header = text[text.index(f"module {spec.TOP}"):text.index(");", text.index(f"module {spec.TOP}"))]
    ports = {}
    for m in re.finditer(r"(input|output)\s+wire\s+(\[[^\]]+\])?\s*(\w+)", header):
        width = m.group(2)
        ports[m.group(3)] = (m.group(1), width)
    assert set(ports) == set(spec.PORTS)
    for name, (direction, width) in spec.PORTS.items():
        assert ports[name][0] == direction, name
        want = None if width == 1 else {10: "[`CI_RAW_W-1:0]", 64: "[63:0]"}[width]
        assert ports[name][1] == want, name
    params = dict(re.findall(r"parameter\s+(\w+)\s*=\s*([^,\n)]+)", header))
    assert set(params) == set(spec.PARAMETERS)
    assert params["MAX_WIDTH"].strip() == str(spec.PARAMETERS["MAX_WIDTH"])


def test_camera_in_lints_clean() -> None:
    """Verilator -Wall on the IP, at the default width and at a small odd one."""
    exe = hdl.verilator_bin()
    for width in (spec.PARAMETERS["MAX_WIDTH"], 17):
        out = subprocess.run(
            [str(exe), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{camera_dir()}", f"-I{hdl.rtl_dir()}",
             "--top-module", spec.TOP,
             f"-GMAX_WIDTH={width}", *map(str, camera_sources())],
            capture_output=True, text=True, timeout=120, check=False,
        )
        assert out.returncode == 0, out.stderr[-3000:]


@pytest.mark.timeout(1800)
def test_camera_in_rtl(sim: str, cocotb_dir: Path) -> None:
    """Every small-build cocotb test under Verilator (more seeds with STEREOCAM_COSIM_FULL=1), ICARUS_TESTS
    under Icarus (all with STEREOCAM_COSIM_FULL=1)."""
    tests = SMALL_TESTS if (sim == "verilator" or FULL) else ICARUS_TESTS
    env = {"STEREOCAM_CI_MAX_WIDTH": "64", "COCOTB_RANDOM_SEED": "1",
           "COCOTB_TEST_FILTER": rf"tb_camera_in\.({tests})$"}
    if FULL:
        env["STEREOCAM_COSIM_FULL"] = "1"
    run = run_cocotb(spec.TOP, camera_sources(), "tb_camera_in", sim=sim, parameters={"MAX_WIDTH": 64},
                     includes=[camera_dir()], extra_env=env, test_dir=cocotb_dir)
    print(f"{sim}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s, {len(run.passed)} tests")
    assert len(run.passed) == len(tests.split("|"))


@pytest.mark.timeout(1800)
def test_camera_in_rtl_full_width(cocotb_dir: Path) -> None:
    """The default 752-wide build under Verilator: a 752 x 6 frame pair (752 x 480 with
    STEREOCAM_COSIM_FULL=1)."""
    env = {"STEREOCAM_CI_MAX_WIDTH": str(spec.PARAMETERS["MAX_WIDTH"]), "COCOTB_RANDOM_SEED": "1",
           "COCOTB_TEST_FILTER": r"tb_camera_in\.full_size$"}
    if FULL:
        env["STEREOCAM_COSIM_FULL"] = "1"
    run = run_cocotb(spec.TOP, camera_sources(), "tb_camera_in", sim="verilator",
                     parameters={"MAX_WIDTH": spec.PARAMETERS["MAX_WIDTH"]},
                     includes=[camera_dir()], extra_env=env, test_dir=cocotb_dir)
    print(f"752 wide: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s")


@pytest.mark.timeout(600)
def test_camera_in_resources() -> None:
    """yosys synth_xilinx of the default build (the recipe of test_rc_datapath.yosys_stat, with this IP's
    include folder): line FIFOs and line buffers in block RAM, no DSP, small logic.

    Measured (yosys 0.23): 2 RAMB36E1 (the line FIFOs, 2048 x 18) + 3 RAMB18E1 (line buffers, 752 x 40),
    no DSP48E1, ~1,220 LUTs, ~1,270 FFs, 11 RAM32M (the output FIFO).
    """
    import re
    import tempfile

    hdl.check_tools("yosys")
    with tempfile.TemporaryDirectory() as tmp:
        stat = Path(tmp) / "stat.txt"
        reads = " ".join(map(str, camera_sources()))
        script = (f"read_verilog -sv -I {camera_dir()} -I {hdl.rtl_dir()} {reads}; "
                  f"synth_xilinx -family xc7 -top {spec.TOP}; tee -q -o {stat} stat")
        subprocess.run(["yosys", "-q", "-p", script], capture_output=True, text=True, timeout=1500,
                       check=True)
        out = stat.read_text()
    block = out[out.rindex("=== design hierarchy ==="):] if "=== design hierarchy ===" in out else out
    cells = {m[1]: int(m[2]) for m in re.finditer(r"^\s+(\w+)\s+(\d+)\s*$", block, re.M)}
    luts = sum(cells.get(f"LUT{i}", 0) for i in range(1, 7))
    ffs = sum(n for name, n in cells.items() if name.startswith("FD"))
    bram36 = cells.get("RAMB36E1", 0) + cells.get("RAMB18E1", 0) / 2
    print(f"camera_in: {cells.get('RAMB36E1', 0)} RAMB36E1, {cells.get('RAMB18E1', 0)} RAMB18E1, "
          f"{cells.get('DSP48E1', 0)} DSP48E1, {luts} LUT, {ffs} FF")
    assert cells.get("DSP48E1", 0) == 0
    assert 2 <= bram36 <= 4
    assert luts < 2500 and ffs < 2500
