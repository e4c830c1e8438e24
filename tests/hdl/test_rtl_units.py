"""The rectify core's and camera_in's building blocks, each in a cocotb bench of its own.

The system benches (tb_rc_datapath, tb_camera_in, tb_rectify_core) reach these modules only through
their callers, at the parameters the callers use and with the traffic the callers make; a module
bench drives each one alone, with random data (and random gaps and backpressure where it has a
handshake), against a Python statement of what its header promises or the model's integer
function. rc_div, rc_coord_mul and rc_fifo have theirs in tb_rc_coord (test_rc_coord.py); rc_fifo's
OUTPUT_REG mode, the rectify core's output FIFO, its own here (tb_rc_fifo_output_reg).

Each case runs under Icarus (it builds in a second); the first case of each module under Verilator
too (a build takes some 10-30 s, cached), and every case with ``STEREOCAM_COSIM_FULL=1``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest

from stereocam.overlays.rtl import toolchain as hdl

from .cocotb_run import run_cocotb
from .sim_cases import sim_cases

RTL = hdl.rtl_dir()
CAMERA = RTL / "camera"


@dataclass(frozen=True)
class Unit:
    """One build of one module: its sources, parameters and the cocotb module that tests it."""

    top: str
    params: dict[str, int]
    sources: tuple[Path, ...] = ()
    bench: str = ""
    verilator: bool = False  # this case also runs under Verilator in the quick suite
    verilator_args: tuple[str, ...] = ()

    @property
    def id(self) -> str:
        return "-".join([self.top, *(f"{k}{v}" for k, v in self.params.items())])


def unit(top: str, params: dict[str, int], *, folder: Path = RTL, extra: tuple[str, ...] = (),
         verilator: bool = False, verilator_args: tuple[str, ...] = (), bench: str = "") -> Unit:
    sources = (*(folder / name for name in extra), folder / f"{top}.v")
    return Unit(top, params, sources, bench or f"tb_{top}", verilator, verilator_args)


WIDE_ADDRESS = ("-Wno-WIDTHTRUNC",)  # an AW above $clog2(DEPTH): the bench uses addresses below DEPTH

UNITS = [
    unit("rc_skid", {"WIDTH": 66}, verilator=True),
    unit("rc_skid", {"WIDTH": 1}),
    # rc_fifo's OUTPUT_REG mode, the rectify core's output FIFO (its other modes: tb_rc_coord)
    unit("rc_fifo", {"WIDTH": 67, "DEPTH": 32, "SHOW_AHEAD": 1, "OUTPUT_REG": 1}, verilator=True,
         bench="tb_rc_fifo_output_reg"),
    unit("rc_fifo", {"WIDTH": 9, "DEPTH": 2, "SHOW_AHEAD": 1, "OUTPUT_REG": 1},
         bench="tb_rc_fifo_output_reg"),
    unit("rc_fifo", {"WIDTH": 5, "DEPTH": 5, "SHOW_AHEAD": 1, "OUTPUT_REG": 1},
         bench="tb_rc_fifo_output_reg"),
    unit("rc_delay", {"WIDTH": 13, "LATENCY": 5, "RESET": 1}, verilator=True),
    unit("rc_delay", {"WIDTH": 7, "LATENCY": 3, "RESET": 0}),
    unit("rc_delay", {"WIDTH": 1, "LATENCY": 1, "RESET": 1}),
    unit("rc_delay", {"WIDTH": 1, "LATENCY": 1, "RESET": 0}),
    unit("rc_delay", {"WIDTH": 9, "LATENCY": 0, "RESET": 1}),
    unit("rc_coord_delay", {"W": 12, "N": 5}, verilator=True),  # packed: N * W <= 64
    unit("rc_coord_delay", {"W": 20, "N": 4}),  # a chain of registers
    unit("rc_coord_delay", {"W": 3, "N": 1}),
    unit("rc_coord_delay", {"W": 8, "N": 0}),
    unit("rc_ram", {"WIDTH": 24, "DEPTH": 10, "AW": 4}, verilator=True),  # DEPTH no power of two
    # AW wider than needed (allowed: 2**AW >= DEPTH); Verilator warns of the address wider than the array
    unit("rc_ram", {"WIDTH": 1, "DEPTH": 2, "AW": 3}, verilator_args=WIDE_ADDRESS),
    unit("rc_ram", {"WIDTH": 66, "DEPTH": 16, "AW": 4}),
    # in slices of 18 bits, the last 12 (the stereo core's RAMs); and a slice wider than the word (one)
    unit("rc_ram", {"WIDTH": 66, "DEPTH": 10, "AW": 4, "SLICE": 18}, verilator=True),
    unit("rc_ram", {"WIDTH": 7, "DEPTH": 6, "AW": 3, "SLICE": 9}),
    unit("rc_linebuf", {"WIDTH": 24, "DEPTH": 12, "AW": 4}, extra=("rc_ram.v",), verilator=True),
    unit("rc_linebuf", {"WIDTH": 8, "DEPTH": 5, "AW": 5}, extra=("rc_ram.v",), verilator_args=WIDE_ADDRESS),
    unit("rc_gray", {}, verilator=True),
    unit("rc_interp", {}, verilator=True),
    # the runner passes INIT as a 32-bit number: Verilator warns that it is cut to WIDTH bits
    unit("ci_sync", {"WIDTH": 5, "INIT": 0b10110}, folder=CAMERA, verilator=True,
         verilator_args=("-Wno-WIDTHTRUNC",)),
    unit("ci_sync", {"WIDTH": 1, "INIT": 1}, folder=CAMERA),
    unit("ci_demosaic", {}, folder=CAMERA, extra=("../rc_gray.v",), verilator=True),
    unit("ci_lfifo", {"WIDTH": 18, "AW": 4}, folder=CAMERA, extra=("ci_sync.v",), verilator=True),
    unit("ci_lfifo", {"WIDTH": 7, "AW": 2}, folder=CAMERA, extra=("ci_sync.v",)),
    unit("ci_rx", {"MAX_WIDTH": 16, "AW": 6}, folder=CAMERA, extra=("ci_sync.v",), verilator=True),
]


@pytest.mark.timeout(600)
@pytest.mark.parametrize(("sim", "case"), sim_cases(UNITS, lambda u: u.id, lambda u: u.verilator))
def test_module(sim: str, case: Unit, cocotb_dir: Path) -> None:
    """Every cocotb test of the module's bench passes at these parameters."""
    env = {"STEREOCAM_UNIT_PARAMS": json.dumps(case.params), "COCOTB_RANDOM_SEED": "1"}
    run = run_cocotb(case.top, case.sources, case.bench, sim=sim, parameters=case.params,
                     build_args=case.verilator_args if sim == "verilator" else (), extra_env=env,
                     test_dir=cocotb_dir)
    print(f"{sim} {case.id}: build {run.build_seconds:.1f} s, run {run.run_seconds:.1f} s, "
          f"{len(run.passed)} tests")
    assert run.passed
