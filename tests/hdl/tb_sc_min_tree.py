"""cocotb testbench for stereocam/overlays/rtl/stereo/sc_min_tree.v, the stereo core's pipelined minimum.

Run by ``tests/hdl/test_stereo_front.py``. Random words every clock with ``en`` low on random clocks:
after each enabled clock, ``out`` must be the minimum of the words taken STAGES enabled clocks before
(the header's latency, whether the root is a register or logic after the last one), and hold while
``en`` is low.
"""
from __future__ import annotations

from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from .unit_bench import start_unit


@cocotb.test()
async def minimum_after_stages(dut: Any) -> None:
    """3,000 clocks of random words (a third of them with runs of equal words or all ones)."""
    p, rng = start_unit(dut, 2)
    n, w, stages = p["N"], p["W"], p["STAGES"]
    taken: list[int] = []
    problems: list[str] = []
    dut.en.value = 0
    await FallingEdge(dut.clk)
    for c in range(3000):
        if rng.random() < 0.3:
            words = [rng.choice([(1 << w) - 1, rng.getrandbits(w)]) for _ in range(n)]
        else:
            words = [rng.getrandbits(w) for _ in range(n)]
        en = rng.random() < 0.7
        dut.en.value = int(en)
        dut.__getattr__("in").value = sum(v << (w * i) for i, v in enumerate(words))
        if en:
            taken.append(min(words))
        await FallingEdge(dut.clk)
        if len(taken) >= stages and int(dut.out.value) != taken[-stages]:
            problems.append(f"clock {c}: out {int(dut.out.value)}, expected {taken[-stages]}")
    assert len(taken) > 1500
    assert not problems, f"{len(problems)} wrong:\n" + "\n".join(problems[:8])
