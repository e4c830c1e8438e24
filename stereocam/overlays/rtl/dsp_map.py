"""How the core's products map to DSP48E1, read from a yosys netlist and held against the RTL's word.

The statement is written once, in the header comment of ``rc_coord_mul.v`` (its ``DSP1`` ...
``DSP4`` table: each DSP's input, output and pipeline registers and whether it takes the previous
DSP's P through the PCIN cascade, shifted by 17 or not). :func:`stated_chain` parses that
table; :func:`read_dsps` and :func:`chains` read what synthesis made of it (``write_json``);
:func:`mismatches` names every DSP that differs. A product that yosys maps otherwise than its
comment says (P through fabric into C instead of PCIN, a register missing) is a mismatch.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from . import toolchain as hdl

MUL_FILE = "rc_coord_mul.v"
MUL_MODULE = "rc_coord_mul"
REGISTERS = ("AREG", "BREG", "MREG", "PREG")
_ROW = re.compile(r"^//\s+DSP(\d)\s+(.*)$", re.M)
_REG = re.compile(r"\b([ABMP]REG)(?:(>=|=)(\d))?")


@dataclass(frozen=True)
class StatedDsp:
    """One row of the comment's table: the cascade it takes and its registers (minimum, maximum)."""

    index: int  # 1-based, DSP1 first
    pcin_shift: Optional[int]  # None: no PCIN; 0: PCIN; 17: PCIN >> 17
    registers: Dict[str, Tuple[int, int]]  # AREG -> (at least, at most); absent from the row: (0, 0)


def stated_chain(text: Optional[str] = None) -> List[StatedDsp]:
    """The DSP table of ``rc_coord_mul.v``'s header comment.

    ``AREG`` alone means 1, ``AREG=2`` exactly 2, ``AREG>=1`` 1 or 2 (a register in front of the
    product may be absorbed as A1REG); a register not named is 0. ``(PCIN)`` and ``(PCIN >> 17)``
    name the cascade from the previous DSP.
    """
    if text is None:
        text = (hdl.rtl_dir() / MUL_FILE).read_text(encoding="utf-8")
    rows: List[StatedDsp] = []
    for number, rest in _ROW.findall(text):
        shift: Optional[int] = None
        m = re.search(r"\(PCIN(?:\s*>>\s*(\d+))?\)", rest)
        if m:
            shift = int(m.group(1) or 0)
        regs: Dict[str, Tuple[int, int]] = {r: (0, 0) for r in REGISTERS}
        for name, op, value in _REG.findall(rest):
            if not op:
                regs[name] = (1, 1)
            elif op == "=":
                regs[name] = (int(value), int(value))
            else:
                regs[name] = (int(value), 2)
        rows.append(StatedDsp(int(number), shift, regs))
    if [r.index for r in rows] != list(range(1, len(rows) + 1)) or not rows:
        raise ValueError(f"no DSP1..DSPn table in the header comment of {MUL_FILE}")
    return rows


@dataclass(frozen=True)
class NetDsp:
    """A DSP48E1 cell of a netlist: its registers and where its PCIN and C come from."""

    name: str
    registers: Dict[str, int]
    pcin_from: Optional[str]  # the DSP whose PCOUT drives PCIN
    pcin_shift: Optional[int]  # 17 when OPMODE[6] selects PCIN >> 17, 0 when PCIN, None without
    c_from_p: Optional[str]  # a DSP whose P drives C directly (through fabric, not the cascade)


def _int(v: Any) -> int:
    return int(v, 2) if isinstance(v, str) else int(v)


def read_dsps(netlist: Path, module: Optional[str] = None) -> List[NetDsp]:
    """Every DSP48E1 of ``module`` (the only module when None) in a yosys ``write_json`` netlist."""
    data = json.loads(netlist.read_text(encoding="utf-8"))
    modules: Mapping[str, Any] = data["modules"]
    with_dsp = [n for n, m in modules.items()
                if any(c["type"] == "DSP48E1" for c in m.get("cells", {}).values())]
    name = module or (with_dsp[0] if with_dsp else None)
    if name is None:
        return []
    cells: Mapping[str, Any] = modules[name]["cells"]
    drivers: Dict[int, Tuple[str, str]] = {}
    for cname, cell in cells.items():
        for port, bits in cell["connections"].items():
            if cell.get("port_directions", {}).get(port) == "output":
                for b in bits:
                    if isinstance(b, int):
                        drivers[b] = (cname, port)
    out: List[NetDsp] = []
    for cname, cell in cells.items():
        if cell["type"] != "DSP48E1":
            continue
        con = cell["connections"]
        params = cell["parameters"]
        regs = {r: _int(params.get(r, 0)) for r in REGISTERS}
        pcin = {drivers[b][0] for b in con.get("PCIN", []) if isinstance(b, int) and b in drivers
                and drivers[b][1] == "PCOUT"}
        opmode = con.get("OPMODE", [])
        shift: Optional[int] = None
        if pcin:
            shift = 17 if len(opmode) == 7 and opmode[6] == "1" else 0
        c_p = {drivers[b][0] for b in con.get("C", []) if isinstance(b, int) and b in drivers
               and drivers[b][1] == "P" and cells[drivers[b][0]]["type"] == "DSP48E1"}
        out.append(NetDsp(cname, regs, next(iter(pcin)) if pcin else None, shift,
                          next(iter(c_p)) if c_p else None))
    return out


def chains(dsps: Sequence[NetDsp]) -> List[List[NetDsp]]:
    """The PCOUT -> PCIN chains, each from its first DSP (one without PCIN) on; a DSP alone is a chain."""
    by_name = {d.name: d for d in dsps}
    after = {d.pcin_from: d for d in dsps if d.pcin_from is not None}
    out = []
    for d in dsps:
        if d.pcin_from is not None and d.pcin_from in by_name:
            continue
        chain = [d]
        while chain[-1].name in after:
            chain.append(after[chain[-1].name])
        out.append(chain)
    return out


def mismatches(netlist_chains: Sequence[Sequence[NetDsp]], stated: Sequence[StatedDsp],
               products: int) -> List[str]:
    """Every way the netlist differs from ``products`` products mapped as ``stated``: empty when it agrees."""
    problems: List[str] = []
    if len(netlist_chains) != products:
        lengths = sorted(len(c) for c in netlist_chains)
        problems.append(f"{len(netlist_chains)} DSP chains (lengths {lengths}), "
                        f"not {products} of {len(stated)}")
    for chain in netlist_chains:
        if len(chain) != len(stated):
            continue
        for want, got in zip(stated, chain, strict=True):
            where = f"DSP{want.index} ({got.name})"
            if got.pcin_shift != want.pcin_shift:
                problems.append(f"{where}: PCIN shift {got.pcin_shift}, stated {want.pcin_shift}")
            if got.c_from_p is not None:
                problems.append(f"{where}: C driven by {got.c_from_p}'s P through fabric")
            for reg, (lo, hi) in want.registers.items():
                if not lo <= got.registers[reg] <= hi:
                    problems.append(f"{where}: {reg}={got.registers[reg]}, stated {lo}..{hi}")
    return problems


def summary(dsps: Sequence[NetDsp]) -> Dict[str, int]:
    """Counts for a report: DSPs, those on PCIN, those whose C takes another DSP's P, those with PREG."""
    return {"DSP48E1": len(dsps), "PCIN": sum(d.pcin_from is not None for d in dsps),
            "C_from_P": sum(d.c_from_p is not None for d in dsps),
            "PREG": sum(d.registers["PREG"] > 0 for d in dsps)}
