"""``stereocam hw synth``'s whole-overlay table: every block-design cell counted, totals, citations,
the device.

The RTL rows are real yosys runs of the camera input and the frame gate (seconds; cached);
the core is stood in for by a fixed cell count except in the per-build test, which runs it.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Dict, List

import pytest

from stereocam.cli import build_parser
from stereocam.overlays.rtl import ip_estimates
from stereocam.overlays.rtl import synth as hw_synth
from stereocam.overlays.rtl.synth import BdCell, Part, SynthResult

pytestmark = pytest.mark.slow

# A stand-in for the core's yosys result: known numbers, so the core's row is checkable by hand.
CORE_CELLS: Dict[str, int] = {"LUT6": 1000, "RAM32M": 10, "FDRE": 2000, "RAMB36E1": 30, "RAMB18E1": 2,
                              "DSP48E1": 52}


def fake_core() -> SynthResult:
    return SynthResult("rectify_core", {"COLOUR": 0}, dict(CORE_CELLS), "Yosys 0.23", "", 0.0, True, None)


def gray() -> hw_synth.BuildParams:
    return hw_synth.builds()[0]["gray"]


def parts_of(cells: List[BdCell]) -> List[Part]:
    return hw_synth.overlay_parts(gray(), fake_core(), cells=cells)


@pytest.fixture(scope="module")
def cells() -> List[BdCell]:
    return hw_synth.block_design_cells()


@pytest.fixture(scope="module")
def parts(cells: List[BdCell]) -> List[Part]:
    return parts_of(cells)


def run(argv: List[str]) -> int:
    args: argparse.Namespace = build_parser().parse_args(argv)
    return int(args.func(args))


def test_the_block_design_is_read_with_its_configuration(cells: List[BdCell]) -> None:
    by_name = {c.name: c for c in cells}
    assert by_name["vdma_raw"].vlnv == "xilinx.com:ip:axi_vdma:6.3"
    assert by_name["vdma_raw"].config["c_include_mm2s"] == "0"
    assert by_name["vdma_raw"].config["c_s2mm_linebuffer_depth"] == "512"
    assert by_name["gate_raw"].config == {"DEPTH": "1024"}
    assert by_name["camera_in"].config == {"MAX_WIDTH": "752", "BAYER_PHASE": "3"}
    assert [c.name for c in cells if c.ip == "frame_gate"] == ["gate_raw", "gate_live"]


def test_every_cell_is_counted_once(cells: List[BdCell], parts: List[Part]) -> None:
    counted = [name for p in parts for name in p.cells]
    assert sorted(counted) == sorted(c.name for c in cells)
    kinds = {name: p.kind for p in parts for name in p.cells}
    assert {n for n, k in kinds.items() if k == "yosys"} == {"rectify", "camera_in", "gate_raw", "gate_live"}


def test_core_row_is_the_core_and_gates_count_twice(parts: List[Part]) -> None:
    core = parts[0]
    assert core.cells == ("rectify",) and core.kind == "yosys"
    # 1000 LUT6 + 10 RAM32M (4 LUT each); 30 RAMB36 + 2 RAMB18 (half each)
    assert (core.lut, core.ff, core.bram36, core.dsp) == (1040, 2000, 31.0, 52)
    gates = next(p for p in parts if p.cells == ("gate_raw", "gate_live"))
    rtl = hw_synth.rtl_dir()
    one = hw_synth.synthesize(rtl / "camera", top="frame_gate", parameters={"DEPTH": 1024},
                              extra_sources=[rtl / "rc_ram.v", rtl / "rc_fifo.v"])
    assert gates.lut == 2 * one.counts.lut and gates.bram36 == 2 * one.counts.bram36 > 0
    camera = next(p for p in parts if p.cells == ("camera_in",))
    assert camera.bram36 >= 3 and camera.lut > 500 and "BAYER_PHASE 3" in camera.source


def test_totals_are_the_sum_of_the_parts(parts: List[Part]) -> None:
    total = hw_synth.overlay_totals(parts)
    for key in ("LUT", "FF", "BRAM36", "DSP48E1"):
        assert total[key] == sum(p.values()[key] for p in parts)
    assert total["DSP48E1"] == 52


def test_without_the_camera_path_and_gates_the_total_drops(cells: List[BdCell], parts: List[Part]) -> None:
    full = hw_synth.overlay_totals(parts)
    cut = hw_synth.overlay_totals(parts_of([c for c in cells if c.ip not in ("camera_in", "frame_gate")]))
    camera_and_gates = [p for p in parts if set(p.cells) & {"camera_in", "gate_raw", "gate_live"}]
    for key in ("LUT", "FF", "BRAM36"):
        assert cut[key] < full[key]
        assert full[key] - cut[key] == sum(p.values()[key] for p in camera_and_gates)
    assert full["BRAM36"] - cut["BRAM36"] >= 3.5 + 2 * 2


def test_every_ip_row_cites_its_product_guide(parts: List[Part], cells: List[BdCell]) -> None:
    guides = {"axi_vdma": "PG020", "axis_switch": "PG085", "axis_broadcaster": "PG085",
              "axi_interconnect": "PG059", "proc_sys_reset": "PG164", "processing_system7": "PG082"}
    by_name = {c.name: c for c in cells}
    estimates = [p for p in parts if p.kind == "estimate"]
    assert len(estimates) == 11
    for p in estimates:
        ip = p.name.split()[0]
        (cell,) = (by_name[name] for name in p.cells)
        est = ip_estimates.rule(cell.vlnv, cell.config)
        assert est.ip == ip
        assert "(estimate)" in p.name and p.to_dict()["estimate"] is True
        assert p.source.startswith(est.citation) and est.table and est.basis
        if ip in guides:
            assert est.document.startswith(guides[ip]), (ip, est.document)


def test_vdma_block_ram_follows_its_line_buffers(parts: List[Part], cells: List[BdCell]) -> None:
    by_cell = {p.cells[0]: p for p in parts}
    assert by_cell["vdma_raw"].bram36 == 1  # S2MM only: 512 x 66 bits in one RAMB36
    assert by_cell["vdma_proc"].bram36 == 2  # MM2S and S2MM, 512 deep each
    raw = next(c for c in cells if c.name == "vdma_raw")
    deeper = dataclasses.replace(raw, config={**raw.config, "c_s2mm_linebuffer_depth": "2048"})
    _, fig = ip_estimates.estimate(deeper.vlnv, deeper.config)
    assert fig.bram36 == 4  # 2048 x 66 bits = 3.7 RAMB36
    assert fig.lut == by_cell["vdma_raw"].lut


def test_an_ip_without_an_estimate_is_refused_by_name(cells: List[BdCell]) -> None:
    odd = BdCell("fifo0", "xilinx.com:ip:axis_data_fifo:2.0", {})
    with pytest.raises(hw_synth.HwSynthError, match=r"cell fifo0 \(xilinx.com:ip:axis_data_fifo:2.0\) has no "
                                                    r"resource estimate"):
        parts_of([*cells, odd])


@pytest.mark.parametrize("build", ["gray", "colour", "depth"])
def test_each_interconnect_is_estimated_by_its_own_use(build: str) -> None:
    """GP0's register interconnect by its crossbar and AXI4-Lite converter, per MI; each HP port's 1:1
    interconnect as one AXI4 -> AXI3 protocol converter and nothing else."""
    design = hw_synth.block_design_cells(build=build)
    hubs = [c for c in design if c.ip == "axi_interconnect"]
    memory = [c for c in hubs if (c.config["NUM_SI"], c.config["NUM_MI"]) == ("1", "1")]
    (registers,) = [c for c in hubs if c not in memory]
    channels = sum(c.config.get(f"c_include_{ch}") == "1" for c in design if c.ip == "axi_vdma"
                   for ch in ("mm2s", "s2mm"))
    assert len(memory) == channels == (4 if build == "depth" else 3), "one per VDMA channel"
    for cell in memory:
        est, fig = ip_estimates.estimate(cell.vlnv, cell.config)
        assert fig == ip_estimates.AXI3_CONVERTER
        assert est.table == "AXI Protocol Converter Resource Utilization" and not est.read_from_table
        assert "conversion only" in est.basis and "high side" in est.basis
    est, fig = ip_estimates.estimate(registers.vlnv, registers.config)
    mi = int(registers.config["NUM_MI"])
    assert mi > 1 and "AXI Crossbar" in est.table
    assert (fig.lut, fig.ff) == (300 + 100 * mi, 400 + 100 * mi)


def test_an_interconnect_configuration_without_a_rule_is_refused(cells: List[BdCell]) -> None:
    """A crossbar of several masters is neither use the table covers: refused, not estimated as one."""
    shared = BdCell("axi_mem", "xilinx.com:ip:axi_interconnect:2.1", {"NUM_SI": "3", "NUM_MI": "1"})
    with pytest.raises(KeyError):
        ip_estimates.estimate(shared.vlnv, shared.config)
    with pytest.raises(hw_synth.HwSynthError, match=r"cell axi_mem \(xilinx.com:ip:axi_interconnect:2.1\) "
                                                    r"has no resource estimate .* for its configuration "
                                                    r"\(NUM_SI 3, NUM_MI 1\)"):
        parts_of([*cells, shared])


def test_text_table_has_a_row_per_part_and_the_total(parts: List[Part]) -> None:
    overlay = hw_synth.overlay_dict(parts, gray())
    text = hw_synth.format_overlay(overlay)
    lines = text.splitlines()
    for p in parts:
        assert any(ln.startswith(p.name) for ln in lines), p.name
    total = next(ln for ln in lines if ln.startswith("total"))
    assert f"{overlay['total']['LUT']:,.0f}" in total
    share = next(ln for ln in lines if ln.startswith("% of xc7z020"))
    assert f"{overlay['share_pct']['BRAM36']:.1f} %" in share
    assert "estimates" in text and text.endswith("within the xc7z020")
    over = hw_synth.overlay_dict([*parts, Part("x", ("x",), "estimate", 60_000, 0, 0, 0, "t")], gray())
    assert over["over_device"] == [f"LUT {overlay['total']['LUT'] + 60_000:,.0f} > 53,200"]
    assert not over["within_device"]


def test_the_depth_build_is_held_to_its_floor(parts: List[Part]) -> None:
    """The depth build's whole overlay has a floor below the device (LUT 75 %, BRAM36 85 %, DSP48E1 220):
    the table says which it is over, and the command exits 1."""
    depth = hw_synth.builds()[0][hw_synth.STEREO_BUILD]
    assert hw_synth.OVERLAY_FLOORS[depth.name] == {"LUT": 39_900, "BRAM36": 119, "DSP48E1": 220}
    assert hw_synth.overlay_dict(parts, gray())["floor"] == {}  # the gray build's floor is its core's
    fits = hw_synth.overlay_dict(parts, depth)
    assert fits["within_floor"] and fits["within_device"], fits["over_floor"]
    assert "within the floor of build depth (LUT <= 39,900, BRAM36 <= 119, DSP48E1 <= 220)" in (
        hw_synth.format_overlay(fits))
    room = 39_900 - fits["total"]["LUT"]
    big = hw_synth.overlay_dict([*parts, Part("x", ("x",), "estimate", room + 1, 0, 0, 0, "t")], depth)
    assert big["over_floor"] == ["LUT 39,901 > 39,900"] and big["within_device"] and not big["within_floor"]
    assert "OVER the floor of build depth" in hw_synth.format_overlay(big)
    bram = hw_synth.overlay_dict([*parts, Part("x", ("x",), "yosys", 0, 0, 119.5 - fits["total"]["BRAM36"], 0,
                                                "t")], depth)
    assert bram["over_floor"] == ["BRAM36 119.5 > 119"]


@pytest.mark.timeout(1800)  # a full yosys run of the core per build (about a minute); cached after that
@pytest.mark.parametrize("build", ["gray", "colour"])
def test_each_build_fits_the_device(build: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = run(["hw", "synth", "--build", build, "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads(captured.out)
    overlay = report["overlay"]
    assert overlay["build"] == build and overlay["within_device"] and overlay["over_device"] == []
    core = overlay["parts"][0]
    assert core["cells"] == ["rectify"] and core["LUT"] == report["resources"]["LUT"]["yosys"]
    assert core["BRAM36"] == report["resources"]["BRAM36"]["yosys"]
    for key, device in {"LUT": 53_200, "FF": 106_400, "BRAM36": 140, "DSP48E1": 220}.items():
        assert overlay["total"][key] == sum(p[key] for p in overlay["parts"])
        assert overlay["total"][key] <= device
        assert overlay["device_totals"][key] == device
    # every product's four DSP48E1 in one PCOUT -> PCIN chain (tests/overlays/test_dsp_map.py has the detail)
    assert report["dsp_cascade"] == {"DSP48E1": 52, "PCIN": 39, "C_from_P": 0, "PREG": 26}
    print(build, {k: overlay["total"][k] for k in ("LUT", "FF", "BRAM36", "DSP48E1")}, overlay["share_pct"],
          report["dsp_cascade"])


@pytest.mark.timeout(1800)  # a yosys run of a small stereo core: a minute or two idle, more when busy
def test_the_depth_build_adds_the_stereo_core_and_its_vdma(cells: List[BdCell]) -> None:
    """The depth build: the gray rectify core's parameters, and the block design's depth cells: the stereo
    core synthesised (here a small build of it, for time: the full one takes yosys half an hour), the
    VDMA writing its output and the split feeding it estimated from their own configuration."""
    table, source = hw_synth.builds()
    depth = table[hw_synth.STEREO_BUILD]
    assert depth.parameters() == gray().parameters() and "depth" in source
    assert depth.stereo_parameters() == {"MAX_WIDTH": 752, "MAX_HEIGHT": 1024, "MAX_DISP": 128,
                                         "PARALLEL": 32}
    depth_cells = hw_synth.block_design_cells(build="depth")
    by_cell = {c.name: c for c in depth_cells}
    assert set(by_cell) - {c.name for c in cells} == {"stereo", "vdma_depth", "rectified_split",
                                                     "axi_mem_depth"}
    assert by_cell["rectify"].config["COLOUR"] == "0", "the depth build's block design has the gray core"
    assert by_cell["axi_ctrl"].config["NUM_MI"] == "6" and by_cell["irq_concat"].config["NUM_PORTS"] == "4"
    small = dataclasses.replace(depth, stereo=hw_synth.StereoBuild("small", 64, 64, 32, 8))
    parts = hw_synth.overlay_parts(small, fake_core(), cells=depth_cells)
    assert sorted(name for p in parts for name in p.cells) == sorted(by_cell), "every cell counted once"
    by_name = {p.name: p for p in parts}
    stereo = by_name["stereo core (depth)"]
    assert stereo.kind == "yosys" and stereo.cells == ("stereo",) and stereo.lut > 1000 and stereo.bram36 > 0
    assert "MAX_DISP 32" in stereo.source and "PARALLEL 8" in stereo.source
    (vdma,) = [p for p in parts if p.cells == ("vdma_depth",)]
    assert vdma.kind == "estimate" and "PG020" in vdma.source
    (split,) = [p for p in parts if p.cells == ("rectified_split",)]
    assert split.kind == "estimate" and "PG085" in split.source
    (memory,) = [p for p in parts if p.cells == ("axi_mem_depth",)]
    assert memory.kind == "estimate" and "AXI Protocol Converter" in memory.source
    assert (memory.lut, memory.ff) == (ip_estimates.AXI3_CONVERTER.lut, ip_estimates.AXI3_CONVERTER.ff)
    with pytest.raises(hw_synth.HwSynthError, match="no stereo core"):
        hw_synth.overlay_parts(small, fake_core(), cells=cells)
    totals = hw_synth.overlay_totals(parts)
    assert totals["LUT"] == sum(p.lut for p in parts) > sum(p.lut for p in parts_of(cells))
