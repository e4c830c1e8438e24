"""``stereocam hw timing``'s estimator on hand-made netlists whose worst path is known.

No yosys here: the netlists are written as yosys's ``write_json`` writes them, so the walk, the
delay model and the naming are tested by themselves (tests/overlays/test_hw_timing.py runs the
command on the real core).
"""
from __future__ import annotations

import math
from typing import Any, Dict, List

import pytest

from stereocam.overlays.rtl import timing
from stereocam.overlays.rtl.timing import MODEL, TimingError, analyse


def ff(d: int, q: int, ce: Any = "1", src: str = "") -> Dict[str, Any]:
    return {"type": "FDRE", "parameters": {}, "attributes": {"src": src},
            "port_directions": {"C": "input", "CE": "input", "D": "input", "R": "input", "Q": "output"},
            "connections": {"C": [1], "CE": [ce], "D": [d], "R": ["0"], "Q": [q]}}


def lut2(i0: int, i1: int, o: int) -> Dict[str, Any]:
    return {"type": "LUT2", "parameters": {"INIT": "0110"}, "attributes": {},
            "port_directions": {"I0": "input", "I1": "input", "O": "output"},
            "connections": {"I0": [i0], "I1": [i1], "O": [o]}}


def carry4(s0: int, co3: int) -> Dict[str, Any]:
    return {"type": "CARRY4", "parameters": {}, "attributes": {},
            "port_directions": {"CI": "input", "CYINIT": "input", "DI": "input", "S": "input",
                                "O": "output", "CO": "output"},
            "connections": {"CI": ["0"], "CYINIT": ["0"], "DI": ["0", "0", "0", "0"],
                            "S": [s0, "1", "1", "1"],
                            "O": [20, 21, 22, 23], "CO": [24, 25, 26, co3]}}


def netlist(cells: Dict[str, Any], nets: Dict[str, List[int]]) -> Dict[str, Any]:
    netnames = {name: {"hide_name": 1 if name.startswith("$") else 0, "bits": bits, "attributes": {}}
                for name, bits in nets.items()}
    return {"modules": {"t": {"attributes": {"top": "00000000000000000000000000000001"},
                              "ports": {}, "cells": cells, "netnames": netnames}}}


# a_q, b_q -> LUT2 -> CARRY4 S[0] -> CO[3] -> c's D; b_q also feeds d's CE (so b_q has two loads).
KNOWN = netlist(
    {"$a": ff(10, 2), "$b": ff(11, 3), "$lut": lut2(2, 3, 4), "$carry": carry4(4, 5),
     "$c": ff(5, 6, src="t.v:9.3"), "$d": ff(12, 7, ce=3)},
    {"clk": [1], "a_q": [2], "b_q": [3], "$auto$lut_out": [4], "done": [5], "c_q": [6], "d_q": [7],
     "a_d": [10], "b_d": [11], "d_d": [12]})


def test_the_worst_path_of_a_known_netlist_is_the_model_summed_along_it() -> None:
    (worst, *rest) = analyse(KNOWN, n=10)
    # b_q has two loads; the LUT feeds only the carry of its own slice (no routing); the carry's CO
    # is routed to c's D.
    expected = (MODEL.ff_clk_to_q + MODEL.net(2) + MODEL.lut + 0.0 + MODEL.carry_s_to_co + MODEL.net(1)
                + MODEL.ff_d_setup)
    assert worst.delay_ns == pytest.approx(expected)
    assert worst.delay_ns == pytest.approx(0.52 + 0.50 + 0.124 + 0.59 + 0.40 + 0.07)  # the figures as stated
    assert (worst.start, worst.end, worst.end_pin) == ("b_q", "c_q", "D")
    assert [s.type for s in worst.steps] == ["FDRE", "LUT2", "CARRY4", "FDRE"]
    assert worst.levels == {"LUT": 1, "CARRY4": 1}
    assert [s.net for s in worst.steps[:-1]] == ["b_q", "$auto$lut_out", "done"]
    # each endpoint by its worst path only (a_q -> c_q, one load less on a_q, is not listed): then d's enable
    assert [(p.start, p.end, p.end_pin) for p in rest] == [("b_q", "d_q", "CE")]
    assert rest[0].delay_ns == pytest.approx(MODEL.ff_clk_to_q + MODEL.net(2) + MODEL.ff_ce_setup)


def test_fanout_costs_routing_per_doubling() -> None:
    assert MODEL.net(1) == pytest.approx(MODEL.net_base)
    assert MODEL.net(4096) - MODEL.net(1) == pytest.approx(12 * MODEL.net_per_log2_fanout)
    assert math.isclose(MODEL.net(0), MODEL.net(1))


def test_a_register_without_a_name_is_named_by_its_source_line() -> None:
    data = netlist({"$a": ff(10, 2), "$c": ff(2, 6, src="t.v:9.3")},
                   {"a_q": [2], "$c_q": [6], "a_d": [10]})
    (path,) = analyse(data)
    assert path.start == "a_q"
    assert path.end == "FDRE $c (t.v:9.3)"


def test_a_combinational_loop_is_refused_naming_a_net_on_it() -> None:
    data = netlist({"$a": ff(10, 2), "$l1": lut2(2, 5, 4), "$l2": lut2(4, 2, 5), "$c": ff(5, 6)},
                   {"a_q": [2], "x": [4], "y": [5], "c_q": [6], "a_d": [10]})
    with pytest.raises(TimingError, match="combinational loop through"):
        analyse(data)


def test_dsp_registers_decide_launch_and_setup() -> None:
    def dsp(preg: int, mreg: int) -> timing.Cell:
        params = {"AREG": "1", "BREG": "1", "CREG": "0", "DREG": "1", "MREG": str(mreg), "PREG": str(preg)}
        return timing.Cell("$dsp", "DSP48E1", params, {"A[0]": 1, "C[0]": 2, "PCIN[0]": 3}, {"P[0]": 4}, "")

    full = timing.cell_timing(dsp(1, 1))
    assert full.launch == {"P[0]": MODEL.dsp_p_from_preg}
    assert full.setup == {"A[0]": MODEL.dsp_in_reg_setup, "C[0]": MODEL.dsp_c_to_preg,
                          "PCIN[0]": MODEL.dsp_pcin_to_preg}
    no_p = timing.cell_timing(dsp(0, 1))
    assert no_p.launch == {"P[0]": MODEL.dsp_p_from_mreg}
    assert ("C[0]", "P[0]", MODEL.dsp_comb_c_to_p) in no_p.arcs
