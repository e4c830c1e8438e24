"""The core's products in the yosys netlist are mapped to DSP48E1 as rc_coord_mul.v's comment states.

The statement is the comment's DSP1..DSP4 table (stereocam/overlays/rtl/dsp_map.py parses it);
the netlist is yosys 0.23's ``write_json`` of the whole core. A form of the RTL that yosys maps
otherwise (each P through fabric into the next C) is shown to fail the same check.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import List

import pytest

from stereocam.overlays.rtl import dsp_map
from stereocam.overlays.rtl import synth as hw_synth
from stereocam.overlays.rtl.dsp_map import NetDsp

pytestmark = pytest.mark.slow

RTL = hw_synth.rtl_dir()


def products_in_core() -> int:
    """rc_coord_mul instances in rc_coord.v: the core's only multiplies."""
    return len(re.findall(r"^\s*rc_coord_mul\s+#\(", (RTL / "rc_coord.v").read_text(), re.M))


def test_the_stated_table_is_read_from_the_comment() -> None:
    rows = dsp_map.stated_chain()
    assert [r.pcin_shift for r in rows] == [None, 17, 0, 17]
    assert [r.registers["PREG"] for r in rows] == [(0, 0), (1, 1), (0, 0), (1, 1)]
    assert [r.registers["AREG"] for r in rows] == [(1, 2), (1, 2), (2, 2), (2, 2)]
    assert all(r.registers["MREG"] == (1, 1) for r in rows)
    text = "//   DSP1  m = a b   AREG BREG=2 MREG\n//   DSP2  h = a b + m  (PCIN)  PREG\n"
    one, two = dsp_map.stated_chain(text)
    assert one.registers == {"AREG": (1, 1), "BREG": (2, 2), "MREG": (1, 1), "PREG": (0, 0)}
    assert one.pcin_shift is None and two.pcin_shift == 0 and two.registers["AREG"] == (0, 0)
    with pytest.raises(ValueError, match="no DSP1..DSPn table"):
        dsp_map.stated_chain("// no table here\n")


def _chain(c_from_p: bool = False, preg2: int = 1) -> List[NetDsp]:
    regs = [(1, 1, 1, 0), (1, 1, 1, preg2), (2, 2, 1, 0), (2, 2, 1, 1)]
    shifts = [None, 17, 0, 17]
    out = []
    for i, (a, b, m, p) in enumerate(regs):
        prev = f"d{i}" if i else None
        out.append(NetDsp(f"d{i + 1}", {"AREG": a, "BREG": b, "MREG": m, "PREG": p},
                          prev, shifts[i], prev if c_from_p and i else None))
    return out


def test_the_check_names_each_difference() -> None:
    stated = dsp_map.stated_chain()
    assert dsp_map.mismatches(dsp_map.chains(_chain()), stated, 1) == []
    no_preg = dsp_map.mismatches(dsp_map.chains(_chain(preg2=0)), stated, 1)
    assert no_preg == ["DSP2 (d2): PREG=0, stated 1..1"]
    fabric = dsp_map.mismatches(dsp_map.chains(_chain(c_from_p=True)), stated, 1)
    assert fabric == [f"DSP{i} (d{i}): C driven by d{i - 1}'s P through fabric" for i in (2, 3, 4)]
    # no cascade at all: four chains of one instead of one of four
    broken = [NetDsp(d.name, d.registers, None, None, d.pcin_from) for d in _chain()]
    assert dsp_map.mismatches(dsp_map.chains(broken), stated, 1) == [
        "4 DSP chains (lengths [1, 1, 1, 1]), not 1 of 4"]
    assert dsp_map.summary(broken) == {"DSP48E1": 4, "PCIN": 0, "C_from_P": 3, "PREG": 2}


@pytest.mark.timeout(1800)  # a full yosys run of the core (a minute or two); cached after that
def test_every_product_of_the_core_maps_as_stated() -> None:
    build = hw_synth.builds()[0]["gray"]
    result = hw_synth.synthesize(RTL, parameters=build.parameters(), netlist=True)
    assert result.netlist is not None and result.netlist.is_file()
    dsps = dsp_map.read_dsps(result.netlist)
    products = products_in_core()
    assert products == 13
    problems = dsp_map.mismatches(dsp_map.chains(dsps), dsp_map.stated_chain(), products)
    summary = dsp_map.summary(dsps)
    print(f"core DSP48E1: {summary}")
    assert problems == []
    assert summary == {"DSP48E1": 4 * products, "PCIN": 3 * products, "C_from_P": 0, "PREG": 2 * products}
    assert summary["DSP48E1"] <= 220


# The three post-adders as they were written before (explicit sign-extension slices, DSP4's sum one
# bit wider than h2): yosys 0.23 then finds none of a product's PCIN cascades in the core.
OLD_ADDERS = """    wire signed [WD3-1:0]   d3 = {{WD3-W3{m3[W3-1]}}, m3} + {{WD3-WH1{h1[WH1-1]}}, h1};
    wire signed [WH1-1:0]   h1_next = {{WH1-W2{m2[W2-1]}}, m2} + {{WH1-W1+17{m1[W1-1]}}, m1[W1-1:17]};
    localparam WS2 = ((W4 > WD3 - 17) ? W4 : WD3 - 17) + 1;
    wire signed [WS2-1:0]   h2_next = {{WS2-W4{m4[W4-1]}}, m4} + {{WS2-WD3+17{d3[WD3-1]}}, d3[WD3-1:17]};
"""
# A product whose inputs come from a register (as in the core), so that synthesis absorbs it.
WRAPPER = """
module mul_in_context(input clk, input signed [34:0] a, input signed [32:0] b, output signed [39:0] p);
    reg signed [34:0] a_q;
    always @(posedge clk) a_q <= a;
    rc_coord_mul #(.AW(35), .BW(33), .LO(31), .CW(2), .SH(1), .OW(40)) mul (.clk(clk), .a(a_q), .b(b),
                                                                           .c(2'sd1), .p(p));
endmodule
"""


def _in_context(folder: Path, mul_text: str) -> List[str]:
    folder.mkdir()
    (folder / "rc_coord_mul.v").write_text(mul_text)
    (folder / "prelude.vh").write_text((RTL / "prelude.vh").read_text())  # which every RTL file includes
    (folder / "mul_in_context.v").write_text(WRAPPER)
    result = hw_synth.synthesize(folder, top="mul_in_context", netlist=True, cache_dir=folder / "cache")
    assert result.netlist is not None
    return dsp_map.mismatches(dsp_map.chains(dsp_map.read_dsps(result.netlist)), dsp_map.stated_chain(), 1)


def test_the_check_fails_on_the_form_yosys_maps_otherwise(tmp_path: Path) -> None:
    text = (RTL / "rc_coord_mul.v").read_text()
    assert _in_context(tmp_path / "now", text) == []
    old = text.replace("    wire signed [WD3-1:0]   d3 = m3 + h1;", OLD_ADDERS + "//", 1)
    old = old.replace("h1 <= m2 + (m1 >>> 17);", "h1 <= h1_next;", 1)
    old = old.replace("h2 <= m4 + (d3 >>> 17);", "h2 <= h2_next[WH2-1:0];", 1)
    assert old.count("_next") == 4
    problems = _in_context(tmp_path / "old", old)
    assert any("DSP chains" in p for p in problems), problems
