"""cocotb testbench for stereocam/overlays/rtl/rc_linebuf.v, one camera's four-bank line buffer.

Run by ``tests/hdl/test_rtl_units.py``. Random writes into the bank {row parity, column parity} and
reads of all four banks at their own addresses, clock by clock, against four ``unit_bench.RamModel``:
a write lands in its bank only, each bank's read data is at [b*WIDTH +: WIDTH] 2 clocks after its
address, held until the next read.
"""
from __future__ import annotations

from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from .unit_bench import RamModel, start_unit


@cocotb.test()
async def four_banks_by_parity(dut: Any) -> None:
    """Fill every word of every bank, then 4,000 clocks of random writes and four-bank reads."""
    p, rng = start_unit(dut)
    width, depth, aw = p["WIDTH"], p["DEPTH"], p["AW"]
    banks = [RamModel() for _ in range(4)]
    dut.we.value = 0
    dut.re.value = 0
    await FallingEdge(dut.clk)
    schedule = [(True, b, a, rng.getrandbits(width), False, [0] * 4) for b in range(4) for a in range(depth)]
    for _ in range(4000):
        schedule.append((rng.random() < 0.6, rng.randrange(4), rng.randrange(depth), rng.getrandbits(width),
                         rng.random() < 0.5, [rng.randrange(depth) for _ in range(4)]))
    problems: list[str] = []
    for c, (we, bank, waddr, wdata, re, raddr) in enumerate(schedule):
        dut.we.value, dut.wrow_par.value, dut.wcol_par.value = int(we), bank >> 1, bank & 1
        dut.waddr.value, dut.wdata.value = waddr, wdata
        dut.re.value = int(re)
        dut.raddr.value = sum(a << (b * aw) for b, a in enumerate(raddr))
        await FallingEdge(dut.clk)
        rdata = int(dut.rdata.value) if c >= 4 * depth + 2 else None
        for b, model in enumerate(banks):
            model.edge(we and b == bank, waddr, wdata, re, raddr[b])
            if rdata is not None and model.rdata is not None:
                have = (rdata >> (b * width)) & ((1 << width) - 1)
                if have != model.rdata:
                    problems.append(f"clock {c} bank {b}: {have:#x}, expected {model.rdata:#x}")
    assert not problems, f"{len(problems)} wrong:\n" + "\n".join(problems[:8])
