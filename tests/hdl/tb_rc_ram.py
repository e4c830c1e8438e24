"""cocotb testbench for stereocam/overlays/rtl/rc_ram.v, the block-RAM of the line buffers and FIFOs.

Run by ``tests/hdl/test_rtl_units.py``. Random writes and reads at once, clock by clock, against
``unit_bench.RamModel`` (the header's statement: read data 2 clocks after the address, the old word on
a read of the address written in the same clock, rdata held until the next read), at a depth that is
no power of two and an AW wider than needed.
"""
from __future__ import annotations

from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from .unit_bench import RamModel, start_unit


@cocotb.test()
async def reads_what_was_written(dut: Any) -> None:
    """Fill every word, then 4,000 clocks of random writes and reads, some of one address in one clock."""
    p, rng = start_unit(dut)
    width, depth = p["WIDTH"], p["DEPTH"]
    model = RamModel()
    dut.we.value = 0
    dut.re.value = 0
    await FallingEdge(dut.clk)
    schedule = [(True, a, rng.getrandbits(width), False, 0) for a in range(depth)]
    for _ in range(4000):
        we, re = rng.random() < 0.5, rng.random() < 0.5
        waddr = rng.randrange(depth)
        raddr = waddr if rng.random() < 0.1 else rng.randrange(depth)
        schedule.append((we, waddr, rng.getrandbits(width), re, raddr))
    problems: list[str] = []
    reads = same_address = 0
    for c, (we, waddr, wdata, re, raddr) in enumerate(schedule):
        dut.we.value, dut.waddr.value, dut.wdata.value = int(we), waddr, wdata
        dut.re.value, dut.raddr.value = int(re), raddr
        await FallingEdge(dut.clk)
        model.edge(we, waddr, wdata, re, raddr)
        reads += re
        same_address += re and we and raddr == waddr
        if model.rdata is not None and int(dut.rdata.value) != model.rdata:
            problems.append(f"clock {c}: rdata {int(dut.rdata.value):#x}, expected {model.rdata:#x}")
    assert not problems, f"{len(problems)} wrong:\n" + "\n".join(problems[:8])
    assert reads > 1000 and same_address > 50, (reads, same_address)
