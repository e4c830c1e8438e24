"""The frame gate (stereocam/overlays/rtl/camera/frame_gate.v) in Verilator and Icarus, clock by clock
against its
model.

The testbench (``tb_frame_gate.py``) drives schedules of beats and TREADY patterns and compares every
beat that leaves, and the clock it leaves in, with ``stereocam/overlays/model/frame_gate.py``. A DEPTH-64
build
runs the policy cases (overflow after three 20-beat lines); the default build (DEPTH 1024) runs the
camera-rate case: 752-beat lines at camera_in's rate into the rectify core's and a VDMA's.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from stereocam.overlays.rtl import synth as hw_synth
from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.spec import frame_gate as spec

from .cocotb_run import run_cocotb

SMALL_DEPTH = 64
SMALL_TESTS = ("always_ready", "back_to_back_frames", "never_ready", "random_tready", "overflow_mid_frame",
               "ready_again_mid_frame", "capacity_boundary", "malformed_input", "reset_mid_frame")


def camera_dir() -> Path:
    return hdl.rtl_dir() / "camera"


def sources() -> list[Path]:
    """The IP's Verilog files (spec.SOURCES without the prelude they include)."""
    return [camera_dir() / name for name in spec.SOURCES if name.endswith(".v")]


def test_sources_hold_every_module_the_gate_uses() -> None:
    """spec.SOURCES (what package_ip.tcl packages) defines the top and every module it instantiates."""
    text = "\n".join(p.read_text() for p in sources())
    defined = set(re.findall(r"^module\s+(\w+)", text, re.M))
    assert spec.TOP in defined
    used = set(re.findall(r"^\s*(\w+)\s+#\s*\(", text, re.M)) - {"module"}
    assert used and used <= defined, used - defined


def test_top_module_has_the_spec_ports_and_parameters() -> None:
    text = (camera_dir() / f"{spec.TOP}.v").read_text()
    start = text.index(f"module {spec.TOP}")
    header = text[start:text.index(");", start)]
    ports = {m.group(3): (m.group(1), m.group(2))
             for m in re.finditer(r"(input|output)\s+wire\s+(\[[^\]]+\])?\s*(\w+)", header)}
    assert set(ports) == set(spec.PORTS)
    for name, (direction, width) in spec.PORTS.items():
        assert ports[name][0] == direction, name
        assert ports[name][1] == (None if width == 1 else f"[{width - 1}:0]"), name
    params = dict(re.findall(r"parameter\s+(\w+)\s*=\s*(\w+)", header))
    assert {k: int(v) for k, v in params.items()} == spec.PARAMETERS
    # the gate never holds its input: TREADY is a constant, not logic that could fall
    assert re.search(r"^assign s_axis_tready = 1'b1;$", text, re.M)


def test_frame_gate_lints_clean() -> None:
    """Verilator -Wall at the default DEPTH, the extremes of its range and one that is no power of two."""
    exe = hdl.verilator_bin()
    for depth in (spec.PARAMETERS["DEPTH"], *spec.DEPTH_RANGE, 100):
        out = subprocess.run(
            [str(exe), "--lint-only", "-Wall", "-Wno-PROCASSINIT", f"-I{hdl.rtl_dir()}",
             "--top-module", spec.TOP,
             f"-GDEPTH={depth}", *map(str, sources())],
            capture_output=True, text=True, timeout=120, check=False,
        )
        assert out.returncode == 0, f"DEPTH {depth}:\n{out.stderr[-3000:]}"


@pytest.mark.timeout(600)
def test_frame_gate_rtl(sim: str, cocotb_dir: Path) -> None:
    """Every policy case at DEPTH 64."""
    env = {"STEREOCAM_FG_DEPTH": str(SMALL_DEPTH), "COCOTB_RANDOM_SEED": "1",
           "COCOTB_TEST_FILTER": rf"tb_frame_gate\.({'|'.join(SMALL_TESTS)})$"}
    run = run_cocotb(spec.TOP, sources(), "tb_frame_gate", sim=sim, parameters={"DEPTH": SMALL_DEPTH},
                     extra_env=env, test_dir=cocotb_dir)
    print(f"{sim}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s, {len(run.passed)} tests")
    assert len(run.passed) == len(SMALL_TESTS)


@pytest.mark.timeout(600)
def test_frame_gate_rtl_default_depth(sim: str, cocotb_dir: Path) -> None:
    """The default build (the block design's DEPTH) at the fabric's rates."""
    depth = spec.PARAMETERS["DEPTH"]
    env = {"STEREOCAM_FG_DEPTH": str(depth), "COCOTB_RANDOM_SEED": "1",
           "COCOTB_TEST_FILTER": r"tb_frame_gate\.camera_rate$"}
    run = run_cocotb(spec.TOP, sources(), "tb_frame_gate", sim=sim, extra_env=env, test_dir=cocotb_dir)
    print(f"{sim} DEPTH {depth}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s")
    assert run.passed


@pytest.mark.timeout(600)
def test_frame_gate_resources() -> None:
    """yosys synth_xilinx (stereocam.overlays.rtl.synth) of the default build: the FIFO in block RAM,
    the output FIFO in distributed RAM, no DSP, little logic."""
    shared = [p for p in sources() if p.parent != camera_dir()]  # ../rc_ram.v, ../rc_fifo.v
    result = hw_synth.synthesize(camera_dir(), top=spec.TOP, parameters=spec.PARAMETERS, extra_sources=shared)
    counts = result.counts
    ram_bits = spec.ram_words(spec.PARAMETERS["DEPTH"]) * (spec.STREAM_BITS + 2)
    print(f"frame_gate: {result.cells.get('RAMB36E1', 0)} RAMB36E1, {result.cells.get('RAMB18E1', 0)} "
          f"RAMB18E1, {counts.lut} LUT ({counts.lutram} as RAM), {counts.ff} FF, {counts.dsp} DSP")
    assert counts.dsp == 0
    assert ram_bits / (36 * 1024) <= counts.bram36 <= 2 * ram_bits / (36 * 1024)
    assert counts.lut < 400 and counts.ff < 300
