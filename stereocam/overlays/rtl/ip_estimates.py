"""Resources of the block design's Xilinx IP, for ``stereocam hw synth``'s whole-overlay table.

yosys cannot synthesise Xilinx's encrypted IP, so these rows are estimates: each names the
product guide (and the section holding its resource table) it is taken from, and says how the
figure follows from the block design's configuration. They are marked as estimates in every
output. Where the figure was not read digit for digit from the guide's table here (the guides
now keep their tables on AMD's "Performance and Resource Utilization" pages, which could not be
opened from this machine; for PG059's "AXI Protocol Converter Resource Utilization" the search
index reached holds the page's title but not its figures), ``read_from_table`` is False and the
figure is an engineering estimate sized on the high side for the configuration; Vivado's
``report_utilization`` of a real build replaces them all.

An IP used in more than one way has one rule per use, each with its own guide section, basis and
figures, and the rule is chosen from the cell's configuration (:func:`estimate`): the AXI
Interconnect is the GP0 register crossbar (one SI, several AXI4-Lite MI) and, on each HP port, a
1:1 conversion-only interconnect. A configuration no rule covers is refused rather than guessed.

Block RAM follows from the configuration by arithmetic and is exact up to Vivado's choice of
primitive: a VDMA channel's line buffer is a FIFO of ``depth`` words of the stream width
(plus TLAST and TUSER), in RAMB36 (512 x 72 each).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, Mapping, Sequence, Tuple

#: A RAMB36E1 as a 512 x 72 FIFO (7 series): bits per block.
RAMB36_BITS = 36 * 1024


@dataclass(frozen=True)
class Figures:
    """LUT, FF, BRAM36 and DSP48E1 of one IP instance."""

    lut: int
    ff: int
    bram36: float
    dsp: int


@dataclass(frozen=True)
class IpEstimate:
    """How one IP's resources are estimated: the guide, its table, the rule for the configuration."""

    ip: str  # the VLNV's name part, e.g. ``axi_vdma``
    document: str  # product guide, e.g. "PG020 (AXI VDMA v6.3)"
    table: str  # the section/table of the guide holding the resource figures
    basis: str  # how the figure follows from the configuration
    read_from_table: bool  # were the figures read from the table itself (else: an estimate)
    figures: Callable[[Mapping[str, str]], Figures]
    #: the configurations this rule covers (an IP with several uses has a rule for each)
    applies: Callable[[Mapping[str, str]], bool] = lambda _c: True

    @property
    def citation(self) -> str:
        return f"{self.document}, {self.table}"


def _vdma(config: Mapping[str, str]) -> Figures:
    """Register direct mode (no SG), no DRE: a shared AXI4-Lite register block plus one engine
    per channel; each channel's line buffer in block RAM."""
    lut, ff, bram = 700, 1_100, 0.0  # AXI4-Lite registers, interrupt and reset logic
    for ch, (ch_lut, ch_ff) in (("mm2s", (700, 1_100)), ("s2mm", (800, 1_300))):
        if config.get(f"c_include_{ch}", "0") != "1":
            continue
        width = int(config.get(f"c_m_axis_{ch}_tdata_width" if ch == "mm2s" else f"c_s_axis_{ch}_tdata_width",
                               "32"))
        depth = int(config.get(f"c_{ch}_linebuffer_depth", "0"))
        lut += ch_lut
        ff += ch_ff
        if depth:
            bram += math.ceil(depth * (width + 2) / RAMB36_BITS)
    return Figures(lut, ff, bram, 0)


def _switch(config: Mapping[str, str]) -> Figures:
    si, mi = int(config.get("NUM_SI", "2")), int(config.get("NUM_MI", "1"))
    control = config.get("ROUTING_MODE", "0") == "1"
    return Figures(60 * si * mi + (140 if control else 0), 40 * si * mi + (170 if control else 0), 0, 0)


def _broadcaster(config: Mapping[str, str]) -> Figures:
    return Figures(5 * int(config.get("NUM_MI", "2")), 0, 0, 0)


def _slots(config: Mapping[str, str]) -> Tuple[int, int]:
    """NUM_SI, NUM_MI of an AXI Interconnect (PG059's defaults 1 and 2 when not set)."""
    return int(config.get("NUM_SI", "1")), int(config.get("NUM_MI", "2"))


def _register_interconnect(config: Mapping[str, str]) -> bool:
    """GP0's register crossbar: the PS7 alone to several AXI4-Lite slaves."""
    si, mi = _slots(config)
    return si == 1 and mi > 1


def _conversion_only(config: Mapping[str, str]) -> bool:
    """One master to one slave: PG059 builds no crossbar, only the converters the two ends need."""
    return _slots(config) == (1, 1)


def _interconnect(config: Mapping[str, str]) -> Figures:
    _, mi = _slots(config)
    # crossbar (SASD, AXI4-Lite slaves) plus the AXI3 (GP0) to AXI4-Lite protocol converter
    return Figures(300 + 100 * mi, 400 + 100 * mi, 0, 0)


#: One AXI4 -> AXI3 protocol converter, 64-bit (PG059 "AXI4-to-AXI3 Converter": WID from AWID, bursts
#: over 16 beats split, their responses merged), read and write sides, whichever the master uses:
#: sized on the high side; the guide's figures for it were not read.
AXI3_CONVERTER = Figures(300, 450, 0, 0)


def _by_ip(rules: Sequence[IpEstimate]) -> Dict[str, Tuple[IpEstimate, ...]]:
    out: Dict[str, Tuple[IpEstimate, ...]] = {}
    for e in rules:
        out[e.ip] = (*out.get(e.ip, ()), e)
    return out


#: IP name -> its rules, in the order they are tried (:func:`rule`).
ESTIMATES: Dict[str, Tuple[IpEstimate, ...]] = _by_ip((
    IpEstimate("processing_system7", "PG082 (Zynq-7000 Processing System v5.5)", "Resource Utilization",
               "hard block in the PS: no PL LUT, FF, block RAM or DSP", False,
               lambda _c: Figures(0, 0, 0, 0)),
    IpEstimate("proc_sys_reset", "PG164 (Processor System Reset Module v5.0)", "Resource Utilization table",
               "one instance, synchronous reset outputs", False, lambda _c: Figures(20, 40, 0, 0)),
    IpEstimate("axi_interconnect", "PG059 (AXI Interconnect v2.1)",
               "AXI Crossbar Resource Utilization: SASD, AXI4-Lite Protocol; AXI Protocol Converter Resource "
               "Utilization", "1 SI (GP0, AXI3 32-bit) to NUM_MI AXI4-Lite slaves", False, _interconnect,
               _register_interconnect),
    IpEstimate("axi_interconnect", "PG059 (AXI Interconnect v2.1)",
               "AXI Protocol Converter Resource Utilization",
               "NUM_SI 1, NUM_MI 1: conversion only, no crossbar; one AXI4 (VDMA) to AXI3 (HP port) protocol "
               "converter, 64-bit both sides, one clock; 300 LUT, 450 FF sized on the high side (the table's "
               "figures could not be read here)", False, lambda _c: AXI3_CONVERTER, _conversion_only),
    IpEstimate("axi_vdma", "PG020 (AXI VDMA v6.3)",
               "Resource Utilization (Performance and Resource Utilization page)",
               "register direct mode, per included channel; line buffer depth x (stream width + 2) "
               "bits in RAMB36 (512 x 72)", False, _vdma),
    IpEstimate("axis_switch", "PG085 (AXI4-Stream Infrastructure IP Suite v3.0)",
               "Performance and Resource Utilization: AXI4-Stream Switch",
               "NUM_SI x NUM_MI, 8-byte TDATA, control-register routing (AXI4-Lite) when ROUTING_MODE 1",
               False, _switch),
    IpEstimate("axis_broadcaster", "PG085 (AXI4-Stream Infrastructure IP Suite v3.0)",
               "Performance and Resource Utilization: AXI4-Stream Broadcaster",
               "no register slice: TREADY/TVALID gating only", False, _broadcaster),
    IpEstimate("xlconcat", "xlconcat (Concat v2.1, IP catalog description)", "no resource table: wiring only",
               "concatenates nets into a bus: no logic", False, lambda _c: Figures(0, 0, 0, 0)),
))


def vlnv_name(vlnv: str) -> str:
    """``xilinx.com:ip:axi_vdma:6.3`` -> ``axi_vdma``."""
    parts = vlnv.split(":")
    return parts[2] if len(parts) == 4 else vlnv


def rule(vlnv: str, config: Mapping[str, str]) -> IpEstimate:
    """The rule for one IP cell: the first of its IP's that covers ``config``; KeyError names an IP, or
    a configuration of it, this table does not know."""
    name = vlnv_name(vlnv)
    for e in ESTIMATES.get(name, ()):
        if e.applies(config):
            return e
    raise KeyError(name)


def estimate(vlnv: str, config: Mapping[str, str]) -> Tuple[IpEstimate, Figures]:
    """The estimate for one IP cell (:func:`rule`) and its figures for ``config``."""
    e = rule(vlnv, config)
    return e, e.figures(config)
