"""``stereocam hw synth``: yosys's cells sorted into the paper's Table 1 resources, the report, the errors.

The counting is checked on real yosys 0.23 output of small modules written here, against
counts reasoned from how ``synth_xilinx -family xc7`` maps them (not copied from a run).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Callable, List, Tuple

import pytest

from stereocam.cli import build_parser
from stereocam.overlays.rtl import synth as hw_synth
from stereocam.overlays.rtl.synth import BuildParams, Counts, count_resources, over_floor, synthesize

pytestmark = pytest.mark.slow

# One module with a known amount of each resource. MUL_W and ADDR_W default small and are
# raised by chparam, and the FDPE block needs a define, so the counts also prove that the
# parameters, the define and the include directory reach yosys.
COUNTED_V = r"""
`include "t_width.vh"
module t_top #(parameter MUL_W = 18, parameter ADDR_W = 10) (
    input clk, input rst, input arst, input en,
    input signed [MUL_W-1:0] a, input signed [MUL_W-1:0] b, output reg signed [2*MUL_W-1:0] p,
    input we, input [ADDR_W-1:0] wa, input [ADDR_W-1:0] ra,
    input [`T_DATA_W-1:0] wd, output reg [`T_DATA_W-1:0] rd,
    input [4:0] lwa, input [4:0] lra, input [5:0] lwd, output [5:0] lrd,
    input s_in, output s_out,
    input [7:0] d, output reg [7:0] q_r, output reg [7:0] q_s, output reg [7:0] q_c, output reg [7:0] q_p
);
    // registered signed multiply
    reg signed [MUL_W-1:0] ar, br;
    always @(posedge clk) begin ar <= a; br <= b; p <= ar * br; end
    // block RAM: 2**ADDR_W words of T_DATA_W bits, synchronous read
    reg [`T_DATA_W-1:0] mem [0:(1<<ADDR_W)-1];
    always @(posedge clk) begin if (we) mem[wa] <= wd; rd <= mem[ra]; end
    // LUT RAM: 32 x 6, one write port, one asynchronous read port
    reg [5:0] lmem [0:31];
    always @(posedge clk) if (we) lmem[lwa] <= lwd;
    assign lrd = lmem[lra];
    // a 16-clock delay line with no reset
    reg [15:0] sh;
    always @(posedge clk) sh <= {sh[14:0], s_in};
    assign s_out = sh[15];
    // one 8-bit register of each flip-flop kind
    always @(posedge clk) if (rst) q_r <= 8'h00; else if (en) q_r <= d;
    always @(posedge clk) if (rst) q_s <= 8'hff; else if (en) q_s <= d;
    always @(posedge clk or posedge arst) if (arst) q_c <= 8'h00; else q_c <= d;
`ifdef WITH_PRESET
    always @(posedge clk or posedge arst) if (arst) q_p <= 8'hff; else q_p <= d;
`else
    always @* q_p = d;
`endif
endmodule
"""

# A stand-in rectify_core for the command: the build's parameters, and one 18x18 product per
# colour plane (gray 1, colour 3) so the build visibly reaches the RTL.
FAKE_CORE_V = r"""
module rectify_core #(parameter MAX_WIDTH = 16, parameter MAX_HEIGHT = 16, parameter LB_ROWS = 2,
                      parameter COLOUR = 0) (
    input clk, input signed [17:0] a, input signed [17:0] b, output [3*36-1:0] p,
    output [31:0] sizes
);
    localparam N = COLOUR ? 3 : 1;
    genvar i;
    generate for (i = 0; i < 3; i = i + 1) begin : plane
        if (i < N) begin : used
            reg signed [17:0] ar, br;
            reg signed [35:0] pr;
            always @(posedge clk) begin ar <= a + i; br <= b; pr <= ar * br; end
            assign p[36*i +: 36] = pr;
        end else begin : unused
            assign p[36*i +: 36] = 36'd0;
        end
    end endgenerate
    assign sizes = MAX_WIDTH + MAX_HEIGHT + LB_ROWS;
endmodule
"""


@pytest.fixture(scope="module")
def counted_dirs(tmp_path_factory: pytest.TempPathFactory) -> Tuple[Path, Path]:
    """(sources, cache) of the counted module."""
    src = tmp_path_factory.mktemp("counted")
    (src / "t_top.v").write_text(COUNTED_V)
    (src / "t_width.vh").write_text("`define T_DATA_W 24\n")
    return src, tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def counted(counted_dirs: Tuple[Path, Path]) -> hw_synth.SynthResult:
    return synthesize_counted(*counted_dirs)


def synthesize_counted(src: Path, cache: Path) -> hw_synth.SynthResult:
    return synthesize(src, top="t_top", parameters={"MUL_W": 35, "ADDR_W": 12}, defines={"WITH_PRESET": ""},
                      cache_dir=cache)


@pytest.fixture
def fake_core(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder holding the stand-in rectify_core; the command's cache goes to tmp_path."""
    src = tmp_path / "rtl"
    src.mkdir()
    (src / "rectify_core.v").write_text(FAKE_CORE_V)
    monkeypatch.setattr(hw_synth, "default_cache_dir", lambda: tmp_path / "cache")
    return src


def run(argv: List[str]) -> int:
    """``stereocam ARGV`` as main() runs it: parse, then the command's function."""
    args: argparse.Namespace = build_parser().parse_args(argv)
    return int(args.func(args))


def test_dsp_bram_lutram_and_flip_flops_are_counted(counted: hw_synth.SynthResult) -> None:
    cells = counted.cells
    c = counted.counts
    # 35x35 signed: DSP48E1 multiplies 25x18 signed, so each operand is split into a 17-bit
    # unsigned low part and an 18-bit signed high part; 2 x 2 partial products. (MUL_W stayed
    # 18 without chparam: one DSP.)
    assert cells["DSP48E1"] == 4 and c.dsp == 4
    # 4096 x 24: a RAMB36 is 4096 x 9 (8 data + 1 parity) deep enough, so ceil(24 / 9) = 3; had
    # yosys used RAMB18s (2048 x 9) it would take 2 x 3 halves, the same 3 BRAM36.
    assert c.bram36 == 3.0
    assert cells.get("RAMB36E1", 0) + cells.get("RAMB18E1", 0) / 2 == 3
    # 32 x 6 with one write and one asynchronous read port is exactly one RAM32M (4 LUTs, simple
    # dual port, 3 x 2 bits); the 16-clock delay line is one SRL16E (1 LUT).
    assert cells["RAM32M"] == 1 and cells["SRL16E"] == 1
    assert c.lutram == 4 + 1
    # One 8-bit register per kind: set -> FDSE, async clear -> FDCE, async preset -> FDPE
    # (needs the define). Synchronous reset -> FDRE, plus the multiply's registers that the
    # DSPs do not absorb (at most 35 + 35 + 70 bits).
    assert cells["FDSE"] == 8 and cells["FDCE"] == 8 and cells["FDPE"] == 8
    assert 8 <= cells["FDRE"] <= 8 + 35 + 35 + 70
    assert c.ff == sum(n for name, n in cells.items() if name.startswith("FD"))
    # LUT = logic LUTs + LUTRAM sites; CARRY4 is not a LUT.
    assert c.lut_logic == sum(cells.get(f"LUT{i}", 0) for i in range(1, 7)) > 0
    assert c.lut == c.lut_logic + c.lutram
    assert "CARRY4" not in c.by_key() and all(not k.startswith(("LUT", "FD", "RAM", "DSP")) for k in c.other)
    assert counted.yosys_version.startswith("Yosys ")
    assert "chparam -set MUL_W 35 -set ADDR_W 12 t_top" in counted.script


def test_second_call_is_served_from_the_cache(counted: hw_synth.SynthResult,
                                               counted_dirs: Tuple[Path, Path]) -> None:
    assert not counted.cached and counted.log is not None and counted.log.is_file()
    start = time.monotonic()
    again = synthesize_counted(*counted_dirs)
    assert again.cached and again.cells == counted.cells
    assert time.monotonic() - start < 1.0


def test_cache_key_covers_sources_parameters_and_version(tmp_path: Path) -> None:
    (tmp_path / "a.v").write_text("module a; endmodule\n")
    (tmp_path / "a.vh").write_text("`define X 1\n")
    key = hw_synth.cache_key(tmp_path, "a", {"W": 1}, {}, "Yosys 0.23")
    assert key == hw_synth.cache_key(tmp_path, "a", {"W": 1}, {}, "Yosys 0.23")
    assert key != hw_synth.cache_key(tmp_path, "a", {"W": 2}, {}, "Yosys 0.23")
    assert key != hw_synth.cache_key(tmp_path, "a", {"W": 1}, {}, "Yosys 0.24")
    assert key != hw_synth.cache_key(tmp_path, "a", {"W": 1}, {"D": ""}, "Yosys 0.23")
    (tmp_path / "a.vh").write_text("`define X 2\n")  # a header counts too
    assert key != hw_synth.cache_key(tmp_path, "a", {"W": 1}, {}, "Yosys 0.23")


def test_parse_stat_json_multiplies_out_kept_hierarchy() -> None:
    text = json.dumps({"modules": {"\\leaf": {"num_cells_by_type": {"FDRE": 5}},
                                   "\\top": {"num_cells_by_type": {"\\leaf": 3}}},
                       "design": {"num_cells_by_type": {"FDRE": 15}}})
    assert hw_synth.parse_stat_json(text) == {"FDRE": 15}
    no_top = json.dumps({"modules": {"\\a": {"num_cells_by_type": {"LUT2": 2}},
                                     "\\b": {"num_cells_by_type": {"LUT2": 1, "FDRE": 1}}}})
    assert hw_synth.parse_stat_json(no_top) == {"LUT2": 3, "FDRE": 1}


def test_counting_of_other_primitive_names() -> None:
    c = count_resources({"RAMB18E1": 3, "RAMB36E1": 2, "RAM64M": 2, "RAM64X1D": 1, "SRLC32E": 3,
                         "LDCE": 1, "FDRE": 4, "MUXF7": 5, "LUT6": 7})
    assert c == Counts(lut_logic=7, lutram=2 * 4 + 2 + 3, ff=5, bram36=3.5, dsp=0, other={"MUXF7": 5})


def test_floors_and_table_1_are_the_agreed_numbers() -> None:
    r = {x.key: x for x in hw_synth.RESOURCES}
    assert {k: (r[k].device, r[k].paper_share_pct) for k in ("LUT", "LUTRAM", "FF", "BRAM36", "DSP48E1")} == {
        "LUT": (53_200, 26), "LUTRAM": (17_400, 10), "FF": (106_400, 19), "BRAM36": (140, 46),
        "DSP48E1": (220, 78)}
    assert r["BRAM36"].paper_count == 64 and r["DSP48E1"].paper_count == 172
    assert {k: r[k].floor["gray"] for k in ("DSP48E1", "BRAM36", "LUT", "FF")} == {
        "DSP48E1": 172, "BRAM36": 64, "LUT": 13_800, "FF": 20_200}
    assert {k: r[k].floor["colour"] for k in ("DSP48E1", "BRAM36", "LUT", "FF")} == {
        "DSP48E1": 172, "BRAM36": 100, "LUT": 13_800, "FF": 20_200}
    assert {k: r[k].goal["gray"] for k in ("DSP48E1", "BRAM36", "LUT", "FF")} == {
        "DSP48E1": 86, "BRAM36": 32, "LUT": 6_900, "FF": 10_100}
    over = Counts(lut_logic=13_000, lutram=801, ff=1, bram36=64.5, dsp=172, other={})
    assert over_floor(over, "gray") == ["LUT 13,801 > 13,800", "BRAM36 64.5 > 64"]
    assert over_floor(over, "colour") == ["LUT 13,801 > 13,800"]


def test_builds_come_from_the_spec_when_it_has_them() -> None:
    table, source = hw_synth.builds()
    assert {"gray", "colour"} <= set(table)
    assert not table["gray"].colour and table["colour"].colour
    assert table["gray"].parameters() == {"MAX_WIDTH": table["gray"].max_width,
                                          "MAX_HEIGHT": table["gray"].max_height,
                                          "LB_ROWS": table["gray"].lb_rows, "COLOUR": 0}
    assert source in ("stereocam/overlays/spec/rectify.py BUILDS; depth: gray + spec/stereo.py BUILDS",
                      "stereocam/overlays/rtl/synth.py FALLBACK_BUILDS")
    if "depth" in table:  # the gray rectify core beside the stereo core
        assert table["depth"].parameters() == table["gray"].parameters() and table["depth"].stereo
    assert hw_synth.FALLBACK_BUILDS["gray"] == BuildParams("gray", 752, 1024, 80, False)
    assert hw_synth.FALLBACK_BUILDS["colour"] == BuildParams("colour", 752, 1024, 80, True)


def test_json_report_has_every_resource_beside_table_1(fake_core: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["hw", "synth", "--rtl", str(fake_core), "--build", "colour", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["top"] == "rectify_core" and report["device"] == "xc7z020"
    assert report["build"]["name"] == "colour" and report["parameters"]["COLOUR"] == 1
    assert report["cells"]["DSP48E1"] == 3  # one product per plane: the build's COLOUR reached the RTL
    assert set(report["resources"]) == {"LUT", "LUT_LOGIC", "LUTRAM", "FF", "BRAM36", "DSP48E1"}
    dsp = report["resources"]["DSP48E1"]
    assert dsp == {"yosys": 3, "share_pct": 1.4, "paper_share_pct": 78, "paper_count": 172, "floor": 172,
                   "goal": None, "device": 220, "over": False}
    assert report["resources"]["LUTRAM"]["floor"] is None
    assert report["over"] == [] and report["within_floor"] is True
    assert report["yosys"]["version"].startswith("Yosys ") and report["yosys"]["cached"] is False
    assert "synth_xilinx -family xc7" in report["yosys"]["command"] and "Vivado" in report["note"]


def test_text_report_and_exit_1_over_the_floor(fake_core: Path, capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    assert run(["hw", "synth", "--rtl", str(fake_core)]) == 0  # gray: one DSP
    out = capsys.readouterr().out
    lines = out.splitlines()
    header = next(ln for ln in lines if ln.startswith("resource"))
    columns = ("this core (yosys)", "paper Table 1 (xc7z020 share)", "floor for this build", "device total")
    assert all(column in header for column in columns), header
    dsp_row = next(ln for ln in lines if ln.startswith("DSP48E1"))
    assert dsp_row.split()[:3] == ["DSP48E1", "1", "(0.5"] and "78 % (~172)" in dsp_row
    assert "<= 172 (goal 86)" in dsp_row and dsp_row.rstrip().endswith("220")
    assert "yosys figures run above Vivado's" in out and "within the floor of build gray" in out

    tight = tuple(hw_synth.Resource(r.key, r.label, r.device, r.paper_share_pct, {"gray": 0}, {})
                  if r.key == "DSP48E1" else r for r in hw_synth.RESOURCES)
    monkeypatch.setattr(hw_synth, "RESOURCES", tight)
    assert run(["hw", "synth", "--rtl", str(fake_core)]) == 1
    captured = capsys.readouterr()
    assert "(cached)" in captured.out and "OVER" in captured.out
    assert captured.err == "stereocam hw synth: over the floor of build gray: DSP48E1 1 > 0\n"


def _other_module(folder: Path) -> Path:
    (folder / "other.v").write_text("module other; endmodule\n")
    return folder


@pytest.mark.parametrize("make, message", [
    (lambda p: p / "missing", "is not a folder"),
    (lambda p: p, "has no *.v files"),
    (_other_module, "no module rectify_core in"),
])
def test_missing_rtl_is_one_clear_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             make: Callable[[Path], Path], message: str) -> None:
    folder = make(tmp_path)
    assert run(["hw", "synth", "--rtl", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereocam hw synth: error: ") and err.count("\n") == 1 and message in err
    if "no module" not in message:
        assert "stereocam/overlays/rtl/" in err


def test_missing_yosys_says_how_to_install_it(fake_core: Path, capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(fake_core))  # a folder without yosys in it
    assert run(["hw", "synth", "--rtl", str(fake_core)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereocam hw synth: error: yosys not found") and "apt-get install yosys" in err


def test_a_parameter_the_top_lacks_is_named(fake_core: Path, capsys: pytest.CaptureFixture[str]) -> None:
    no_colour = FAKE_CORE_V.replace(",\n                      parameter COLOUR = 0", "")
    (fake_core / "rectify_core.v").write_text(no_colour.replace("COLOUR ? 3 : 1", "1"))
    assert run(["hw", "synth", "--rtl", str(fake_core)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereocam hw synth: error: yosys failed (exit 1): "
                          "rectify_core has no parameter COLOUR")
    assert err.count("\n") == 1


# The issue's floor for the whole core (both cameras, line buffers, register block): a build over it fails.
@pytest.mark.timeout(1800)  # a full yosys run of the core (about a minute); cached after that
@pytest.mark.parametrize("build", ["gray", "colour"])
def test_rectify_core_fits_its_floor(build: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = run(["hw", "synth", "--build", build, "--json"])
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert code == 0, captured.err
    assert report["top"] == "rectify_core" and report["build"]["name"] == build
    assert report["within_floor"] and report["over"] == []
    floors = {"gray": {"DSP48E1": 172, "BRAM36": 64, "LUT": 13_800, "FF": 20_200},
              "colour": {"DSP48E1": 172, "BRAM36": 100, "LUT": 13_800, "FF": 20_200}}[build]
    for key, floor in floors.items():
        assert report["resources"][key]["yosys"] <= floor, (key, report["resources"][key])
