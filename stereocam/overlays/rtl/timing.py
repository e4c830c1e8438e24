"""``stereocam hw timing``: the worst register-to-register paths of the rectify core, estimated.

No open tool can place and route a Zynq design, so this is a static estimate on yosys 0.23's
``synth_xilinx`` netlist (the same synthesis as ``stereocam hw synth``, written out as JSON): every
cell gets the delay of its primitive from :data:`MODEL` (the xc7z020 at speed grade -1), every net a
routing delay that grows with its fanout, and the longest path from a clocked output (flip-flop,
block RAM, DSP48E1, LUT RAM, SRL) to a clocked input (data, enable, reset, setup of the same) is
found by a longest-path walk over the combinational cells. It cannot see placement, so it is
a guide with margin, not sign-off: ``build.tcl`` stops on a negative routed WNS or WHS, which is.

The clock is the block design's one fabric clock, :data:`stereocam.overlays.spec.overlay.FABRIC_CLOCK_HZ`
(``settings.tcl``'s ``STEREOCAM_FCLK0_MHZ``; a test checks they agree).
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Set, Tuple

from ..spec.overlay import FABRIC_CLOCK_HZ
from . import synth as hw_synth

#: The issue's floor: every build's worst estimated path at most this share of the period.
MARGIN_SHARE = 0.75
DEFAULT_PATHS = 10


# --------------------------------------------------------------------------- the delay model


@dataclass(frozen=True)
class DelayModel:
    """Delays in ns for the xc7z020 at speed grade -1 (VCCINT 1.0 V).

    Cell figures are the data sheet's switching characteristics (DS187, "Zynq-7000 SoC (Z-7010,
    Z-7015, Z-7020): DC and AC Switching Characteristics", tables "CLB Switching
    Characteristics", "Block RAM and FIFO Switching Characteristics", "DSP48E1 Switching
    Characteristics", -1 column), parameter names as UG474 (CLB), UG473 (block RAM) and UG479
    (DSP48E1) define them; where one symbol varies by pin, the largest is taken. Routing is not in
    any data sheet: :attr:`net_base` and :attr:`net_per_log2_fanout` are this estimate's own
    assumption (a short -1 fabric route is 0.3-0.6 ns in Vivado's reports; a net of n loads spreads
    over about log2(n) more switch boxes), stated so it can be argued with.
    """

    # CLB (DS187 CLB switching characteristics)
    lut: float = 0.124  # TILO: A-D inputs through a LUT to its output
    ff_clk_to_q: float = 0.52  # TCKO
    ff_d_setup: float = 0.07  # TDICK (AX-DX to CLK, the D of a routed input)
    ff_ce_setup: float = 0.30  # TCECK
    ff_sr_setup: float = 0.52  # TSRCK (synchronous set/reset; also taken as recovery of CLR/PRE)
    carry_s_to_co: float = 0.59  # TOPCYA-D / TAXCY: S or DI into the chain to CO (worst position)
    carry_s_to_o: float = 0.50  # TOPCYx to O (sum out of the same CARRY4)
    carry_ci_to_co: float = 0.11  # TBYP: CIN to COUT, one CARRY4
    carry_ci_to_o: float = 0.37  # TCINCK-like: CIN to a sum output
    muxf7: float = 0.29  # TIF7: LUT output through MUXF7
    muxf7_sel: float = 0.34  # select (AX/CX) through MUXF7
    muxf8: float = 0.31  # TIF8: MUXF7 output through MUXF8
    lutram_read: float = 0.26  # distributed RAM / SRL read address to output (TILO plus the RAM's mux)
    lutram_clk_to_out: float = 1.20  # TSHCKO: write clock to output of a LUT RAM
    lutram_setup: float = 0.60  # TWS/TDS/TAS of the write port (worst)
    srl_clk_to_out: float = 1.30  # TREG: SRL clock to Q
    # Block RAM (DS187 block RAM switching characteristics)
    bram_clk_to_do: float = 2.45  # TRCKO_DO: clock to DO without the output register
    bram_clk_to_do_reg: float = 0.88  # TRCKO_DO_REG: clock to DO with DO_REG = 1
    bram_addr_setup: float = 0.57  # TRCCK_ADDR
    bram_di_setup: float = 0.74  # TRDCK_DI
    bram_we_setup: float = 0.59  # TRCCK_WE
    bram_en_setup: float = 0.44  # TRCCK_EN
    bram_other_setup: float = 0.60  # RST, REGCE and the rest
    # DSP48E1 (DS187 DSP48E1 switching characteristics)
    dsp_in_reg_setup: float = 0.35  # TDSPDCK_{A,B,C,D}_{A,B,C,D}REG: into an input register
    dsp_ab_to_mreg: float = 3.60  # TDSPDCK_{A,B}_MREG: unregistered A/B through the multiplier
    dsp_ab_to_preg: float = 4.20  # TDSPDCK_{A,B}_PREG with MREG = 0
    dsp_c_to_preg: float = 1.90  # TDSPDCK_C_PREG with CREG = 0
    dsp_pcin_to_preg: float = 1.40  # TDSPDCK_PCIN_PREG
    dsp_ctrl_setup: float = 0.50  # OPMODE, ALUMODE, CE, RST, ... (worst of their setups)
    dsp_p_from_preg: float = 0.55  # TDSPCKO_P_PREG
    dsp_p_from_mreg: float = 2.00  # TDSPCKO_P_MREG (PREG = 0)
    dsp_p_from_inreg: float = 4.00  # TDSPCKO_P_AREG (MREG = PREG = 0)
    dsp_comb_ab_to_p: float = 4.80  # TDSPDO_{A,B}_P, no register at all
    dsp_comb_c_to_p: float = 2.50  # TDSPDO_C_P
    # Routing: this estimate's own assumption (see the class docstring)
    net_base: float = 0.40
    net_per_log2_fanout: float = 0.10
    unknown_cell: float = 0.50  # a cell type the model does not know: each input to each output

    def net(self, fanout: int) -> float:
        """One routed hop from a driver to one of ``fanout`` loads."""
        return self.net_base + self.net_per_log2_fanout * math.log2(max(1, fanout))

    def to_dict(self) -> Dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


MODEL = DelayModel()
MODEL_SOURCE = ("cells: DS187 (Zynq-7000 Z-7010/7015/7020 DC and AC switching characteristics), "
                "speed grade -1, "
                "symbols as UG474/UG473/UG479 define them; routing: "
                f"{MODEL.net_base} ns + {MODEL.net_per_log2_fanout} ns x log2(fanout) per hop, "
                "this estimate's assumption; dedicated connections (carry chain, F7/F8 muxes, DSP cascade, "
                "a LUT feeding its own slice's carry) cost no routing")

CLOCK_PINS = frozenset({"C", "CLK", "CLKARDCLK", "CLKBWRCLK", "WCLK", "RDCLK", "WRCLK"})
_FF = re.compile(r"^FD[RSCP]E(_1)?$")


class TimingError(hw_synth.HwSynthError):
    """A tool or netlist problem: one line, exit code 2."""


# --------------------------------------------------------------------------- the netlist graph


Bit = int


@dataclass
class Cell:
    name: str
    type: str
    params: Dict[str, Any]
    inputs: Dict[str, Bit]  # "PIN" or "PIN[i]" -> bit
    outputs: Dict[str, Bit]
    src: str


@dataclass
class Arc:
    """A combinational arc of one cell: input pin to output pin, its delay."""

    cell: int
    pin_in: str
    pin_out: str
    delay: float


@dataclass
class Graph:
    cells: List[Cell]
    driver: Dict[Bit, Tuple[int, str]]  # bit -> (cell index, output pin)
    loads: Dict[Bit, List[Tuple[int, str]]]  # bit -> [(cell index, input pin)] (no clock pins)
    names: Dict[Bit, str]  # bit -> best RTL name, "sig[3]"
    max_fanout: Dict[Bit, int] = field(default_factory=dict)  # from a (* max_fanout = N *) on the signal
    hidden: Set[Bit] = field(default_factory=set)  # bits whose best name is one yosys made up


def _param(params: Mapping[str, Any], name: str, default: int = 0) -> int:
    v = params.get(name)
    if v is None:
        return default
    if isinstance(v, int):
        return v
    s = str(v).strip()
    if s and set(s) <= {"0", "1", "x", "z"}:
        return int(s.replace("x", "0").replace("z", "0"), 2)
    try:
        return int(s)
    except ValueError:
        return default


def _param_str(params: Mapping[str, Any], name: str) -> str:
    v = params.get(name)
    if isinstance(v, str) and v and not set(v) <= {"0", "1"}:
        return v.strip()
    if isinstance(v, str) and len(v) % 8 == 0 and v:  # yosys may write a string as bits
        try:
            return bytes(int(v[i:i + 8], 2) for i in range(0, len(v), 8)).decode("ascii").strip("\0 ")
        except (ValueError, UnicodeDecodeError):
            return v
    return "" if v is None else str(v)


def parse_netlist(data: Mapping[str, Any], top: Optional[str] = None) -> Graph:
    """The timing graph of one flattened module of a yosys ``write_json`` netlist."""
    modules = data.get("modules", {})
    if top is None:
        tops = [n for n, m in modules.items() if _param(m.get("attributes", {}), "top")]
        top = tops[0] if tops else next(iter(modules), None)
    if top is None or top not in modules:
        raise TimingError(f"the netlist has no module {top}")
    mod = modules[top]
    names: Dict[Bit, Tuple[int, str]] = {}  # bit -> (rank, name); lower rank is better
    max_fanout: Dict[Bit, int] = {}
    for net, info in mod.get("netnames", {}).items():
        is_hidden = bool(info.get("hide_name"))
        bits = info.get("bits", [])
        clean = net.lstrip("\\")
        cap = _param(info.get("attributes", {}), "max_fanout")
        if cap > 0:
            for b in bits:
                if isinstance(b, int):
                    max_fanout[b] = cap
        for i, b in enumerate(bits):
            if not isinstance(b, int):
                continue
            label = clean if len(bits) == 1 else f"{clean}[{i + int(info.get('offset', 0))}]"
            rank = (2 if is_hidden else 0, len(clean))
            key = rank[0] * 100000 + rank[1]
            if b not in names or key < names[b][0]:
                names[b] = (key, label)
    cells: List[Cell] = []
    driver: Dict[Bit, Tuple[int, str]] = {}
    loads: Dict[Bit, List[Tuple[int, str]]] = {}
    for cname, c in mod.get("cells", {}).items():
        dirs = c.get("port_directions", {})
        ins: Dict[str, Bit] = {}
        outs: Dict[str, Bit] = {}
        for port, bits in c.get("connections", {}).items():
            d = dirs.get(port, "input")
            for i, b in enumerate(bits):
                if not isinstance(b, int):
                    continue  # a constant
                pin = port if len(bits) == 1 else f"{port}[{i}]"
                (outs if d == "output" else ins)[pin] = b
        src = rtl_src(str(c.get("attributes", {}).get("src", "")))
        idx = len(cells)
        params = dict(c.get("parameters", {}))
        cells.append(Cell(cname.lstrip("\\"), str(c.get("type", "")), params, ins, outs, src))
        for pin, b in outs.items():
            driver[b] = (idx, pin)
        for pin, b in ins.items():
            if pin.split("[")[0] in CLOCK_PINS:
                continue
            loads.setdefault(b, []).append((idx, pin))
    made_up = {b for b, (key, _) in names.items() if key >= 200000}
    return Graph(cells, driver, loads, {b: n for b, (_, n) in names.items()}, max_fanout, made_up)


def rtl_src(src: str) -> str:
    """The RTL lines of a ``src`` attribute (file name and line), without yosys's own techmap files."""
    parts = [p for p in src.split("|") if p and "share/yosys" not in p]
    return "|".join(Path(p).name for p in parts)


def _port(pin: str) -> Tuple[str, int]:
    if "[" in pin:
        base, rest = pin.split("[", 1)
        return base, int(rest.rstrip("]"))
    return pin, 0


# --------------------------------------------------------------------------- per-cell timing


@dataclass
class CellTiming:
    """What a cell contributes: launch delays of its clocked outputs, setups of its clocked inputs,
    and combinational arcs."""

    launch: Dict[str, float] = field(default_factory=dict)  # output pin -> clock-to-out
    setup: Dict[str, float] = field(default_factory=dict)  # input pin -> setup
    arcs: List[Tuple[str, str, float]] = field(default_factory=list)  # (in, out, delay)


def cell_timing(cell: Cell, m: DelayModel = MODEL) -> CellTiming:
    """The model applied to one cell."""
    t = CellTiming()
    typ = cell.type
    ins, outs = cell.inputs, cell.outputs
    if typ.startswith("LUT") or typ == "INV":  # an INV is a LUT1 Vivado folds into its load (no hop after it)
        for i in ins:
            for o in outs:
                t.arcs.append((i, o, m.lut))
    elif _FF.match(typ):
        for o in outs:
            t.launch[o] = m.ff_clk_to_q
        for i in ins:
            base = _port(i)[0]
            t.setup[i] = {"D": m.ff_d_setup, "CE": m.ff_ce_setup}.get(base, m.ff_sr_setup)
    elif typ == "CARRY4":
        for i in ins:
            base, j = _port(i)
            for o in outs:
                ob, k = _port(o)
                if base in ("CI", "CYINIT"):
                    d = m.carry_ci_to_co if ob == "CO" else m.carry_ci_to_o
                    if base == "CYINIT":
                        d = m.carry_s_to_co if ob == "CO" else m.carry_s_to_o
                elif j <= k:
                    d = m.carry_s_to_co if ob == "CO" else m.carry_s_to_o
                else:
                    continue
                t.arcs.append((i, o, d))
    elif typ in ("MUXF7", "MUXF8"):
        for i in ins:
            d = m.muxf7_sel if i == "S" else (m.muxf7 if typ == "MUXF7" else m.muxf8)
            for o in outs:
                t.arcs.append((i, o, d))
    elif typ.startswith("SRL"):
        for o in outs:
            t.launch[o] = m.srl_clk_to_out
        for i in ins:
            if _port(i)[0] == "A":
                for o in outs:
                    if o == "Q":
                        t.arcs.append((i, o, m.lutram_read))
            else:
                t.setup[i] = m.lutram_setup
    elif typ.startswith("RAM") and not typ.startswith("RAMB"):
        write_addr = {"ADDRD", "A"}
        for o in outs:
            t.launch[o] = m.lutram_clk_to_out
        for i in ins:
            base = _port(i)[0]
            if base.startswith("ADDR") or base in ("A", "DPRA"):
                for o in outs:
                    t.arcs.append((i, o, m.lutram_read))
                if base in write_addr:
                    t.setup[i] = m.lutram_setup
            else:
                t.setup[i] = m.lutram_setup
    elif typ.startswith("RAMB") or typ.startswith("FIFO"):
        reg_a = _param(cell.params, "DOA_REG")
        reg_b = _param(cell.params, "DOB_REG")
        for o in outs:
            b = _port(o)[0]
            reg = reg_b if b in ("DOBDO", "DOPBDOP", "DOB", "DOPB") else reg_a
            t.launch[o] = m.bram_clk_to_do_reg if reg else m.bram_clk_to_do
        for i in ins:
            b = _port(i)[0]
            if b.startswith("ADDR"):
                s = m.bram_addr_setup
            elif b.startswith("DI"):
                s = m.bram_di_setup
            elif b.startswith("WE"):
                s = m.bram_we_setup
            elif b.startswith("EN"):
                s = m.bram_en_setup
            else:
                s = m.bram_other_setup
            t.setup[i] = s
    elif typ == "DSP48E1":
        _dsp_timing(cell, t, m)
    elif typ in ("GND", "VCC", "BUFG"):
        pass
    else:
        for i in ins:
            for o in outs:
                t.arcs.append((i, o, m.unknown_cell))
    return t


def _dsp_timing(cell: Cell, t: CellTiming, m: DelayModel) -> None:
    p = cell.params
    areg = _param(p, "AREG", 1) or _param(p, "ACASCREG", 0)
    breg = _param(p, "BREG", 1) or _param(p, "BCASCREG", 0)
    creg, dreg = _param(p, "CREG", 1), _param(p, "DREG", 1)
    mreg, preg = _param(p, "MREG", 1), _param(p, "PREG", 1)
    use_mult = _param_str(p, "USE_MULT") or "MULTIPLY"
    mult = use_mult != "NONE"
    if preg:
        launch: Optional[float] = m.dsp_p_from_preg
    elif mreg and mult:
        launch = m.dsp_p_from_mreg
    elif areg or breg or creg:
        launch = m.dsp_p_from_inreg
    else:
        launch = None
    outputs = list(cell.outputs)
    if launch is not None:
        for o in outputs:
            t.launch[o] = launch
    for i in cell.inputs:
        b = _port(i)[0]
        # (setup of the first register the input meets, or None) and the arc when it meets none
        if b in ("A", "ACIN", "B", "BCIN", "D"):
            reg = areg if b in ("A", "ACIN") else breg if b in ("B", "BCIN") else dreg
            setup = (m.dsp_in_reg_setup if reg else m.dsp_ab_to_mreg if mreg and mult
                     else m.dsp_ab_to_preg if preg else None)
            comb = m.dsp_comb_ab_to_p
        elif b == "C":
            setup = m.dsp_in_reg_setup if creg else m.dsp_c_to_preg if preg else None
            comb = m.dsp_comb_c_to_p
        elif b == "PCIN":
            setup, comb = (m.dsp_pcin_to_preg if preg else None), m.dsp_comb_c_to_p
        else:  # the control inputs (clock enables, resets, OPMODE, ALUMODE): always registered
            setup, comb = m.dsp_ctrl_setup, 0.0
        if setup is not None:
            t.setup[i] = setup
        else:
            t.arcs += [(i, o, comb) for o in outputs]


# --------------------------------------------------------------------------- the longest paths


@dataclass
class PathStep:
    cell: str
    type: str
    pin_in: str
    pin_out: str
    net: str  # the net leaving this step
    arrival_ns: float
    src: str

    def to_dict(self) -> Dict[str, Any]:
        return {"cell": self.cell, "type": self.type, "in": self.pin_in, "out": self.pin_out, "net": self.net,
                "arrival_ns": round(self.arrival_ns, 3), "src": self.src}


@dataclass
class TimingPath:
    start: str  # the RTL signal the launching register drives
    end: str  # the RTL signal of the capturing register (its output), or the capturing cell's name
    end_pin: str
    delay_ns: float
    steps: List[PathStep]
    levels: Dict[str, int]

    def to_dict(self) -> Dict[str, Any]:
        return {"start": self.start, "end": self.end, "end_pin": self.end_pin,
                "delay_ns": round(self.delay_ns, 3),
                "levels": self.levels, "cells": [s.to_dict() for s in self.steps]}


_DEDICATED = {
    ("CARRY4", "CI"): ("CARRY4",),
    ("MUXF7", "I0"): ("LUT",), ("MUXF7", "I1"): ("LUT",),
    ("MUXF8", "I0"): ("MUXF7",), ("MUXF8", "I1"): ("MUXF7",),
}
_DSP_CASCADE = frozenset({"PCIN", "ACIN", "BCIN", "CARRYCASCIN", "MULTSIGNIN"})


class Analysis:
    """Arrival times over a :class:`Graph` under a :class:`DelayModel`."""

    def __init__(self, graph: Graph, model: DelayModel = MODEL) -> None:
        self.g = graph
        self.m = model
        self.timing = [cell_timing(c, model) for c in graph.cells]
        self.arcs_to: Dict[Tuple[int, str], List[Tuple[str, float]]] = {}
        for idx, t in enumerate(self.timing):
            for i, o, d in t.arcs:
                self.arcs_to.setdefault((idx, o), []).append((i, d))
        self.arrival: Dict[Bit, float] = {}
        # bit -> (cell, in pin, out pin, in bit)
        self.pred: Dict[Bit, Optional[Tuple[int, str, str, Bit]]] = {}
        self._compute()

    def net_delay(self, bit: Bit, load: Tuple[int, str]) -> float:
        """Routing from ``bit``'s driver to one load pin."""
        cell = self.g.cells[load[0]]
        base = _port(load[1])[0]
        drv = self.g.driver.get(bit)
        if drv is not None:
            dtype = self.g.cells[drv[0]].type
            if dtype == "INV":
                return 0.0  # folded into the LUT (or carry input) it feeds: the hop into it was counted
            ded = _DEDICATED.get((cell.type, base))
            if ded and any(dtype.startswith(p) for p in ded):
                return 0.0
            if cell.type == "DSP48E1" and base in _DSP_CASCADE:
                return 0.0
            if (cell.type == "CARRY4" and base in ("S", "DI") and dtype.startswith("LUT")
                    and len(self.g.loads.get(bit, ())) == 1):
                return 0.0  # the LUT of the carry's own slice
        return self.m.net(self.fanout(bit))

    def fanout(self, bit: Bit) -> int:
        """Loads of ``bit`` as routed: a register marked ``max_fanout`` is replicated by Vivado's synthesis
        so that no copy drives more than that many."""
        n = len(self.g.loads.get(bit, ()))
        cap = self.g.max_fanout.get(bit)
        return min(n, cap) if cap else n

    def _compute(self) -> None:
        """Arrival at every driven bit (at the driver's output), in dependency order."""
        g = self.g
        state: Dict[Bit, int] = {}
        for start in list(g.driver):
            if start in self.arrival:
                continue
            stack: List[Tuple[Bit, bool]] = [(start, False)]
            while stack:
                bit, done = stack.pop()
                if bit in self.arrival:
                    continue
                cidx, opin = g.driver[bit]
                launch = self.timing[cidx].launch.get(opin)
                arcs = self.arcs_to.get((cidx, opin), [])
                if not done:
                    if state.get(bit) == 1:
                        raise TimingError(f"a combinational loop through {g.names.get(bit, bit)} "
                                          f"({g.cells[cidx].name}): fix the RTL")
                    state[bit] = 1
                    stack.append((bit, True))
                    for ipin, _ in arcs:
                        ib = g.cells[cidx].inputs[ipin]
                        if ib not in self.arrival and ib in g.driver:
                            stack.append((ib, False))
                    continue
                best = launch if launch is not None else -math.inf
                pred: Optional[Tuple[int, str, str, Bit]] = None
                for ipin, d in arcs:
                    ib = g.cells[cidx].inputs[ipin]
                    a = self.arrival.get(ib, -math.inf)
                    if a == -math.inf:
                        continue
                    a += self.net_delay(ib, (cidx, ipin)) + d
                    if a > best:
                        best, pred = a, (cidx, ipin, opin, ib)
                self.arrival[bit] = best
                self.pred[bit] = pred
                state[bit] = 2

    def endpoints(self) -> Iterable[Tuple[float, int, str, Bit]]:
        """(arrival plus setup, cell, pin, bit) of every clocked input fed by a clocked output."""
        for idx, t in enumerate(self.timing):
            for pin, setup in t.setup.items():
                bit = self.g.cells[idx].inputs.get(pin)
                if bit is None:
                    continue
                a = self.arrival.get(bit, -math.inf)
                if a == -math.inf:
                    continue
                yield a + self.net_delay(bit, (idx, pin)) + setup, idx, pin, bit

    def name_of(self, bit: Bit, cell: Optional[int] = None) -> str:
        """The RTL signal of ``bit``; without one (a name yosys made up), its driving cell and source line."""
        name = self.g.names.get(bit)
        if name and bit not in self.g.hidden:
            return name
        if cell is not None:
            c = self.g.cells[cell]
            return f"{c.name} ({c.src})" if c.src else c.name
        return f"net {bit}"

    def net_name(self, bit: Bit) -> str:
        """Any name of ``bit``, yosys's own included (for the steps of a path)."""
        return self.g.names.get(bit, f"net {bit}")

    def endpoint_name(self, cidx: int) -> str:
        """The capturing register, by the RTL signal it drives (a flip-flop's Q), else the cell's name."""
        c = self.g.cells[cidx]
        if "Q" in c.outputs and c.outputs["Q"] in self.g.names and c.outputs["Q"] not in self.g.hidden:
            return self.name_of(c.outputs["Q"], cidx)
        return f"{c.type} {c.name}" + (f" ({c.src})" if c.src else "")

    def trace(self, total: float, cidx: int, pin: str, bit: Bit) -> TimingPath:
        steps: List[PathStep] = []
        b: Optional[Bit] = bit
        start_bit = bit
        while b is not None:
            p = self.pred.get(b)
            dcell, dpin = self.g.driver[b]
            c = self.g.cells[dcell]
            if p is None:
                steps.append(PathStep(c.name, c.type, "(clock)", dpin, self.net_name(b), self.arrival[b],
                                      c.src))
                start_bit = b
                b = None
            else:
                steps.append(PathStep(c.name, c.type, p[1], p[2], self.net_name(b), self.arrival[b], c.src))
                b = p[3]
        steps.reverse()
        end = self.g.cells[cidx]
        steps.append(PathStep(end.name, end.type, pin, "(setup)", "", total, end.src))
        levels: Dict[str, int] = {}
        for s in steps[1:-1]:
            kind = "LUT" if s.type.startswith("LUT") else s.type
            levels[kind] = levels.get(kind, 0) + 1
        return TimingPath(self.name_of(start_bit, self.g.driver[start_bit][0]), self.endpoint_name(cidx), pin,
                          total, steps, levels)

    def worst_paths(self, n: int = DEFAULT_PATHS) -> List[TimingPath]:
        """The ``n`` worst paths, at most one per (start signal, end signal) pair without bit indices."""
        eps = sorted(self.endpoints(), key=lambda e: -e[0])
        out: List[TimingPath] = []
        seen: Set[Tuple[str, str]] = set()
        for total, cidx, pin, bit in eps:
            path = self.trace(total, cidx, pin, bit)
            key = (_strip_index(path.start), _strip_index(path.end))
            if key in seen:
                continue
            seen.add(key)
            out.append(path)
            if len(out) >= n:
                break
        return out


def _strip_index(name: str) -> str:
    return re.sub(r"\[\d+\]", "", name)


def analyse(data: Mapping[str, Any], top: Optional[str] = None, n: int = DEFAULT_PATHS,
            model: DelayModel = MODEL) -> List[TimingPath]:
    """The worst paths of a yosys JSON netlist."""
    return Analysis(parse_netlist(data, top), model).worst_paths(n)


def high_fanout(data: Mapping[str, Any], top: Optional[str] = None, n: int = 10) -> List[Tuple[str, int]]:
    """The ``n`` nets with the most loads (clock pins excluded), by RTL name."""
    g = parse_netlist(data, top)
    ranked = sorted(((len(v), b) for b, v in g.loads.items() if b in g.driver), reverse=True)[:n]
    return [(g.names.get(b, f"net {b}"), k) for k, b in ranked]


# --------------------------------------------------------------------------- running yosys


def clock_mhz() -> float:
    return FABRIC_CLOCK_HZ / 1e6


@dataclass
class Netlist:
    data: Dict[str, Any]
    cached: bool
    seconds: float
    path: Path


def synth_netlist(sources_dir: Path, *, top: str = hw_synth.TOP,
                  parameters: Optional[Mapping[str, int]] = None, cache_dir: Optional[Path] = None,
                  timeout: float = hw_synth.DEFAULT_TIMEOUT_S,
                  use_cache: bool = True) -> Netlist:
    """yosys's mapped netlist of ``sources_dir``: the very run (and cache) of ``stereocam hw synth``."""
    result = hw_synth.synthesize(sources_dir, top=top, parameters=parameters, cache_dir=cache_dir,
                                 timeout=timeout, use_cache=use_cache, netlist=True)
    assert result.netlist is not None
    data = json.loads(result.netlist.read_text(encoding="utf-8"))
    return Netlist(data, result.cached, result.seconds, result.netlist)


def stereo_netlist(build: hw_synth.BuildParams, *, timeout: float = hw_synth.DEFAULT_TIMEOUT_S,
                   use_cache: bool = True) -> Netlist:
    """yosys's mapped netlist of the build's stereo core (the run and cache of ``stereocam hw synth``)."""
    result = hw_synth.synthesize_stereo(build, timeout=timeout, use_cache=use_cache, netlist=True)
    assert result.netlist is not None
    return Netlist(json.loads(result.netlist.read_text(encoding="utf-8")), result.cached, result.seconds,
                   result.netlist)


# --------------------------------------------------------------------------- report


def report_dict(paths: Sequence[TimingPath], build: hw_synth.BuildParams, netlist: Netlist,
                fanout: Sequence[Tuple[str, int]], mhz: Optional[float] = None) -> Dict[str, Any]:
    """The ``--json`` object."""
    mhz = clock_mhz() if mhz is None else mhz
    period = 1000.0 / mhz
    worst = paths[0].delay_ns if paths else 0.0
    return {
        "top": hw_synth.TOP if build.stereo is None else f"{hw_synth.TOP} and {hw_synth.STEREO_TOP}",
        "device": hw_synth.DEVICE, "speed_grade": -1, "build": build.to_dict(),
        "clock_mhz": mhz, "clock_from": "stereocam/overlays/spec/overlay.py FABRIC_CLOCK_HZ "
                                         "(= settings.tcl STEREOCAM_FCLK0_MHZ)",
        "period_ns": round(period, 3), "worst_ns": round(worst, 3),
        "limit_ns": round(MARGIN_SHARE * period, 3), "share_of_period": round(worst / period, 3),
        "within_margin": worst <= MARGIN_SHARE * period,
        "estimated_fmax_mhz": round(1000.0 / worst, 1) if worst > 0 else None,
        "paths": [p.to_dict() for p in paths],
        "high_fanout_nets": [{"net": n, "loads": k} for n, k in fanout],
        "model": MODEL.to_dict(), "model_source": MODEL_SOURCE,
        "yosys": {"command": hw_synth.SYNTH_COMMAND.format(top=hw_synth.TOP), "cached": netlist.cached,
                  "seconds": round(netlist.seconds, 2), "netlist": str(netlist.path)},
        "note": "an estimate on yosys's netlist without placement; Vivado's routed timing is the sign-off",
    }


def format_report(report: Mapping[str, Any]) -> str:
    b = report["build"]
    lines = [f"{report['top']}, build {b['name']}: clock {report['clock_mhz']:g} MHz "
             f"({report['clock_from']}), "
             f"period {report['period_ns']:g} ns, limit {report['limit_ns']:g} ns (75 %)",
             f"worst estimated path {report['worst_ns']:.2f} ns "
             f"({100 * report['share_of_period']:.0f} % of the "
             f"period, ~{report['estimated_fmax_mhz']} MHz)", ""]
    for p in report["paths"]:
        lv = ", ".join(f"{k} {v}" for k, v in sorted(p["levels"].items()))
        lines.append(f"{p['delay_ns']:6.2f} ns  {p['start']} -> {p['end']} ({p['end_pin']})  [{lv}]")
    if report["high_fanout_nets"]:
        nets = ", ".join(f"{f['net']} {f['loads']:,}" for f in report["high_fanout_nets"])
        lines += ["", "highest fanout: " + nets]
    lines += ["", "model: " + report["model_source"], report["note"]]
    return "\n".join(lines)


# --------------------------------------------------------------------------- command line


def add_timing_parser(hw_sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam hw timing``, added to the ``hw`` group by ``cli.build_parser``."""
    table, _ = hw_synth.builds()
    s = hw_sub.add_parser(
        "timing", help="estimate the rectify core's worst register-to-register paths (-1 speed grade)",
        description=f"Synthesise the rectify core with yosys (as `stereocam hw synth`) and estimate its "
                    f"worst "
                    f"register-to-register paths with a stated xc7z020 -1 delay model, against the block "
                    f"design's clock ({clock_mhz():g} MHz). Exit 0 when the worst path is within "
                    f"{int(MARGIN_SHARE * 100)} % of the period, 1 when not, 2 on a tool or input error.")
    hw_synth.add_yosys_args(s, table)
    s.add_argument("--paths", type=int, default=DEFAULT_PATHS, metavar="N",
                   help="how many paths (default 10)")
    s.set_defaults(func=cmd_hw_timing)


def cmd_hw_timing(args: argparse.Namespace) -> int:
    """Exit 0 within 75 % of the period, 1 over it, 2 on a tool or input error."""
    if args.paths < 1:
        print("stereocam hw timing: error: --paths must be at least 1", file=sys.stderr)
        return 2
    try:
        table, _ = hw_synth.builds()
        build = table[args.build]
        rtl = Path(args.rtl) if args.rtl else hw_synth.rtl_dir()
        net = synth_netlist(rtl, parameters=build.parameters(), timeout=args.timeout,
                            use_cache=not args.no_cache)
        paths = analyse(net.data, hw_synth.TOP, args.paths)
        fanout = high_fanout(net.data, hw_synth.TOP)
        if build.stereo is not None:  # the depth build: the stereo core's paths beside the rectify core's
            stereo = stereo_netlist(build, timeout=args.timeout, use_cache=not args.no_cache)
            paths = sorted([*paths, *analyse(stereo.data, hw_synth.STEREO_TOP, args.paths)],
                           key=lambda p: -p.delay_ns)[:args.paths]
            fanout = sorted([*fanout, *high_fanout(stereo.data, hw_synth.STEREO_TOP)],
                            key=lambda f: -f[1])[:len(fanout)]
    except hw_synth.HwSynthError as exc:
        print(f"stereocam hw timing: error: {exc}", file=sys.stderr)
        return 2
    report = report_dict(paths, build, net, fanout)
    print(json.dumps(report) if args.json else format_report(report))
    if not report["within_margin"]:
        print(f"stereocam hw timing: build {build.name}: worst path {report['worst_ns']:.2f} ns is over "
              f"{report['limit_ns']:g} ns (75 % of {report['period_ns']:g} ns)", file=sys.stderr)
        return 1
    return 0
