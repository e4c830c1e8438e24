"""Shared pieces of the cocotb benches: the one-module ones (``tb_rc_*.py``, ``tb_ci_*.py``;
test_rtl_units.py) and what the larger ones (tb_frame_gate, tb_rc_coord, tb_rc_datapath,
tb_rectify_core) do alike: reset, the AXI4-Stream hold check, ready patterns, the JSON report.

Every bench drives inputs and reads outputs at the falling edge of the clock, half a clock from the
rising edge that samples them, so neither simulator's scheduling order can change what is seen. A
module's parameters reach its bench in ``STEREOCAM_UNIT_PARAMS`` (JSON), the same dictionary the
wrapper builds it with, so the bench never assumes a value the build did not use.
"""
from __future__ import annotations

import json
import os
import random
from collections.abc import Callable, Sequence
from typing import Any

from cocotb.clock import Clock
from cocotb.simtime import get_sim_time
from cocotb.triggers import ClockCycles, FallingEdge, Timer

CLOCK_NS = 10


def params() -> dict[str, int]:
    """The build's parameters (``STEREOCAM_UNIT_PARAMS``), as the wrapper passed them."""
    return {k: int(v) for k, v in json.loads(os.environ.get("STEREOCAM_UNIT_PARAMS", "{}")).items()}


def start_clock(signal: Any, period_ns: float = CLOCK_NS) -> None:
    Clock(signal, period_ns, unit="ns").start()


def start_unit(dut: Any, seed: int = 1) -> tuple[dict[str, int], random.Random]:
    """Start ``dut.clk``; the build's parameters (:func:`params`) and a random generator seeded ``seed``."""
    start_clock(dut.clk)
    return params(), random.Random(seed)


def drive(dut: Any, **values: int) -> None:
    """Set each named input of ``dut`` to its value, in the order given."""
    for name, value in values.items():
        getattr(dut, name).value = value


async def pulse_reset(dut: Any, clocks: int) -> None:
    """Hold ``dut.rst`` high for ``clocks`` rising edges, then let the module run 2 clocks out of reset."""
    dut.rst.value = 1
    await ClockCycles(dut.clk, clocks)
    dut.rst.value = 0
    await ClockCycles(dut.clk, 2)


async def reset_stream(dut: Any, in_reset: Callable[[], None] = lambda: None) -> None:
    """Reset a valid/ready module (``s_valid``, ``m_ready``) for three clocks with both inputs low,
    calling ``in_reset()`` at each of them; returns one clock after the reset, at a falling edge."""
    await FallingEdge(dut.clk)
    dut.rst.value = 1
    dut.s_valid.value = 0
    dut.m_ready.value = 0
    for _ in range(3):
        await FallingEdge(dut.clk)
        in_reset()
    dut.rst.value = 0
    await FallingEdge(dut.clk)


StreamBeat = tuple[int, int, int]  # TDATA, TLAST, TUSER


def check_held_beat(dut: Any, held: StreamBeat | None, violations: list[str]) -> StreamBeat | None:
    """The AXI4-Stream rule on ``dut.m_axis_*`` at one rising edge: once TVALID is up, the beat must not
    change until TREADY takes it. ``held`` is the beat left waiting at the edge before; returns the
    one left waiting now (None if none); a broken rule is added to ``violations``."""
    if not dut.m_axis_tvalid.value:  # TDATA may be X while TVALID is low
        if held is not None:
            violations.append(f"at {get_sim_time('ns')} ns: TVALID dropped, held {held}")
        return None
    beat = (int(dut.m_axis_tdata.value), int(dut.m_axis_tlast.value), int(dut.m_axis_tuser.value))
    if held is not None and beat != held:
        violations.append(f"at {get_sim_time('ns')} ns: held {held}, now {beat}")
    return None if dut.m_axis_tready.value else beat


def add_to_report(env: str, key: str, value: Any) -> None:
    """Set ``key`` in the JSON report named by the environment variable ``env`` (nothing when unset),
    keeping what earlier tests of the same run wrote there."""
    path = os.environ.get(env)
    if not path:
        return
    data = {}
    if os.path.exists(path):
        with open(path) as f:
            data = json.load(f)
    data[key] = value
    with open(path, "w") as f:
        json.dump(data, f, indent=1)


def ready_pattern(rng: random.Random, clocks: int, p_low: float, burst: int) -> list[bool]:
    """A ready (or valid) pattern: low with probability ``p_low``, in runs of 1..``burst`` clocks."""
    out: list[bool] = []
    while len(out) < clocks:
        if rng.random() < p_low:
            out.extend([False] * rng.randint(1, burst))
        else:
            out.append(True)
    return out[:clocks]


async def pipeline(clk: Any, dut: Any, vectors: Sequence[dict[str, int]],
                   read: Callable[[], Any], latency: int) -> list[Any]:
    """Drive one input vector per clock and return ``read()`` of each, ``latency`` clocks later.

    Vector k is driven at falling edge k and sampled by the rising edge after it; a module with
    ``latency`` register stages shows its result at falling edge k + ``latency``. Outputs are read
    1 ns after the inputs are driven, so a zero-latency (wire) path shows the vector just driven.
    """
    out: list[Any] = []
    for k in range(len(vectors) + latency):
        await FallingEdge(clk)
        if k < len(vectors):
            drive(dut, **vectors[k])
        await Timer(1, unit="ns")
        if k >= latency:
            out.append(read())
    return out


def mismatches(got: Sequence[Any], want: Sequence[Any], describe: Callable[[int], str]) -> list[str]:
    """The first few differences between ``got`` and ``want``, each described by its index."""
    assert len(got) == len(want), f"{len(got)} results for {len(want)} inputs"
    bad = [f"{describe(i)}: rtl {g}, expected {w}" for i, (g, w) in enumerate(zip(got, want, strict=True))
           if g != w]
    return [f"{len(bad)} of {len(want)} wrong", *bad[:6]] if bad else []


def first_difference(got: Sequence[int], want: Sequence[int]) -> str:
    """Where two word sequences first differ, for a failure message."""
    for i, (g, w) in enumerate(zip(got, want)):  # noqa: B905 - the lengths may differ
        if g != w:
            return f"word {i} is {g:#x}, expected {w:#x}"
    return f"equal for the first {min(len(got), len(want))} words"


class RamModel:
    """rc_ram as its header states it, one rising edge at a time: a registered read (``re``), then an
    output register loaded one clock later; a read of the address written in the same clock gives
    the old word; ``rdata`` holds between reads (None until the first read has reached it)."""

    def __init__(self) -> None:
        self.mem: dict[int, int] = {}
        self.read_reg: int | None = None
        self.re_reg = False
        self.rdata: int | None = None

    def edge(self, we: bool, waddr: int, wdata: int, re: bool, raddr: int) -> None:
        if self.re_reg:
            self.rdata = self.read_reg
        self.re_reg = re
        if re:
            self.read_reg = self.mem.get(raddr)
        if we:
            self.mem[waddr] = wdata
