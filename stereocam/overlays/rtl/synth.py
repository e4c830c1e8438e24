"""``stereocam hw synth``: the rectify core's resources from yosys, beside the paper's Table 1.

No open tool here can place and route a Zynq design (Vivado alone can), so
the only resource figure we can get for the RTL in ``stereocam/overlays/rtl/`` is yosys 0.23
``synth_xilinx -family xc7``. Its counts run above Vivado's (no place and route: no
LUT packing, no cross-boundary optimisation, no retiming), so a build within the
floors here is within them after Vivado too; the reverse is not guaranteed.

The reference figures (the paper's Table 1, the Zynq-7020's totals and the floor
each build must stay under) live in one table, :data:`RESOURCES`.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from ..spec import camera_in as ci
from ..spec import frame_gate as fg
from ..spec.stereo import BUILDS as STEREO_BUILDS
from ..spec.stereo import Build as StereoBuild
from . import dsp_map, ip_estimates
from . import toolchain as hdl

TOP = "rectify_core"
DEVICE = "xc7z020"
# -flatten: one module, as Vivado's default flatten_hierarchy=rebuilt counts it.
# -noiopad/-noclkbuf: the core is an IP inside the block design; it owns no pins and no BUFG.
SYNTH_COMMAND = "synth_xilinx -family xc7 -top {top} -flatten -noiopad -noclkbuf"
# Bump when the script or the counting changes, so cached results are not reused.
FLOW_VERSION = 1
DEFAULT_TIMEOUT_S = 1800.0
SOURCE_SUFFIXES = (".v",)  # read as sources (all of them: the core's files)
HASHED_SUFFIXES = (".v", ".vh", ".sv", ".svh")  # sources and headers such as rectify_spec.vh

NOTE = ("yosys figures run above Vivado's: synth_xilinx does no place and route, so no LUT "
        "packing or cross-boundary optimisation; Table 1 is Vivado after implementation.")


# --------------------------------------------------------------------------- builds


@dataclass(frozen=True)
class BuildParams:
    """One bitstream build: the Verilog parameters of ``rectify_core`` it sets, and of the stereo
    core where the build has one (the ``depth`` build: the gray rectify core and the stereo core)."""

    name: str
    max_width: int
    max_height: int
    lb_rows: int
    colour: bool
    stereo: Optional[StereoBuild] = None

    def stereo_parameters(self) -> Dict[str, int]:
        """``stereo_core``'s parameters (empty without a stereo core)."""
        b = self.stereo
        if b is None:
            return {}
        return {"MAX_WIDTH": b.max_width, "MAX_HEIGHT": b.max_height, "MAX_DISP": b.max_disp,
                "PARALLEL": b.parallel}

    def parameters(self) -> Dict[str, int]:
        """The ``chparam`` values, by Verilog parameter name."""
        return {"MAX_WIDTH": self.max_width, "MAX_HEIGHT": self.max_height,
                "LB_ROWS": self.lb_rows, "COLOUR": int(self.colour)}

    def to_dict(self) -> Dict[str, Any]:
        return {"name": self.name, "max_width": self.max_width, "max_height": self.max_height,
                "lb_rows": self.lb_rows, "colour": self.colour, "stereo": self.stereo_parameters() or None}


# TODO: remove once stereocam/overlays/spec/rectify.py defines BUILDS; builds() switches to it by itself.
FALLBACK_BUILDS: Dict[str, BuildParams] = {
    "gray": BuildParams("gray", 752, 1024, 80, False),
    "colour": BuildParams("colour", 752, 1024, 80, True),
}


def builds() -> Tuple[Dict[str, BuildParams], str]:
    """The builds, from the spec's ``BUILDS`` when it has one, and where they came from.

    Read with ``getattr`` so this module needs no edit when the spec grows ``BUILDS``.
    """
    spec = importlib.import_module("stereocam.overlays.spec.rectify")
    table = getattr(spec, "BUILDS", None)
    if not table:
        return dict(FALLBACK_BUILDS), "stereocam/overlays/rtl/synth.py FALLBACK_BUILDS"
    out = {str(name): BuildParams(str(b.name), int(b.max_width), int(b.max_height), int(b.lb_rows),
                                  bool(int(b.colour)))
           for name, b in table.items()}
    gray = out["gray"]
    out[STEREO_BUILD] = BuildParams(STEREO_BUILD, gray.max_width, gray.max_height, gray.lb_rows, gray.colour,
                                    STEREO_BUILDS[STEREO_BUILD])
    return out, "stereocam/overlays/spec/rectify.py BUILDS; depth: gray + spec/stereo.py BUILDS"


#: The build with a stereo core: the gray rectify core beside it (the colour build leaves too
#: little block RAM, STEREO_CORE.md).
STEREO_BUILD = "depth"
STEREO_TOP = "stereo_core"


# --------------------------------------------------------------------------- reference table


@dataclass(frozen=True)
class Resource:
    """One row of the report: device total, paper Table 1 share, floor (and goal) per build."""

    key: str
    label: str
    device: int
    paper_share_pct: Optional[int]  # Table 1: gray, both cameras, Vivado on the Zynq-7020
    floor: Mapping[str, int] = field(default_factory=dict)  # per build name: must not exceed
    goal: Mapping[str, int] = field(default_factory=dict)  # per build name: what we aim for

    @property
    def paper_count(self) -> Optional[int]:
        return None if self.paper_share_pct is None else round(self.device * self.paper_share_pct / 100)


# LUT is every slice LUT (logic + LUTRAM, as Vivado's Slice LUTs), so its floor binds both.
RESOURCES: Tuple[Resource, ...] = (
    Resource("LUT", "LUT (logic + LUTRAM)", 53_200, 26, {"gray": 13_800, "colour": 13_800}, {"gray": 6_900}),
    Resource("LUT_LOGIC", "  LUT as logic", 53_200, None),
    Resource("LUTRAM", "LUTRAM (LUTs)", 17_400, 10),
    Resource("FF", "FF", 106_400, 19, {"gray": 20_200, "colour": 20_200}, {"gray": 10_100}),
    Resource("BRAM36", "BRAM36", 140, 46, {"gray": 64, "colour": 100}, {"gray": 32}),
    Resource("DSP48E1", "DSP48E1", 220, 78, {"gray": 172, "colour": 172}, {"gray": 86}),
)


# --------------------------------------------------------------------------- cell counting

LUT_CELLS = ("LUT1", "LUT2", "LUT3", "LUT4", "LUT5", "LUT6")
# LUT-as-memory primitives and how many LUT sites each takes (7 series; a few
# UltraScale names too, so that an odd mapping is still counted).
LUTRAM_LUTS: Dict[str, int] = {
    "RAM32X1S": 1, "RAM32X1D": 2, "RAM32M": 4, "RAM64X1S": 1, "RAM64X1D": 2, "RAM64M": 4,
    "RAM128X1S": 2, "RAM128X1D": 4, "RAM256X1S": 4, "SRL16E": 1, "SRLC16E": 1, "SRLC32E": 1,
    "RAM32M16": 8, "RAM64M8": 8, "RAM256X1D": 8, "RAM512X1S": 8, "RAM64X8SW": 8, "RAM32X16DR8": 8,
}
BRAM36_SHARE: Dict[str, float] = {"RAMB36E1": 1.0, "FIFO36E1": 1.0, "RAMB36E2": 1.0,
                                  "RAMB18E1": 0.5, "FIFO18E1": 0.5, "RAMB18E2": 0.5}
_FF_CELL = re.compile(r"^(FD[A-Z0-9_]*|LD[CP]E[_0-9]*)$")  # FDRE/FDSE/FDCE/FDPE, and latches as Vivado counts


class HwSynthError(Exception):
    """A tool or input problem (no yosys, no RTL, a failed run): one line, exit code 2."""


def parse_stat_json(text: str) -> Dict[str, int]:
    """Cell counts of the whole design from yosys's ``stat -json`` output.

    The ``design`` entry already multiplies out any hierarchy kept by ``keep_hierarchy``;
    without it (no top known), the modules are summed.
    """
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise HwSynthError(f"yosys stat -json output is not JSON: {exc}") from None
    section = data.get("design")
    if section is None:
        cells: Dict[str, int] = {}
        for mod in data.get("modules", {}).values():
            for name, n in mod.get("num_cells_by_type", {}).items():
                cells[name] = cells.get(name, 0) + int(n)
        return cells
    return {str(k): int(v) for k, v in section.get("num_cells_by_type", {}).items()}


@dataclass(frozen=True)
class Counts:
    """Device resources, in the units of Table 1, from a cell count."""

    lut_logic: int
    lutram: int  # LUT sites used as memory (RAM32M = 4, SRL16E = 1, ...)
    ff: int
    bram36: float  # RAMB18 counts as half
    dsp: int
    other: Dict[str, int]  # CARRY4, MUXF7, ...: not in Table 1

    @property
    def lut(self) -> int:
        return self.lut_logic + self.lutram

    def by_key(self) -> Dict[str, float]:
        return {"LUT": self.lut, "LUT_LOGIC": self.lut_logic, "LUTRAM": self.lutram, "FF": self.ff,
                "BRAM36": self.bram36, "DSP48E1": self.dsp}


def count_resources(cells: Mapping[str, int]) -> Counts:
    """Sort yosys's Xilinx cells into Table 1's resources."""
    lut_logic = lutram = ff = dsp = 0
    bram = 0.0
    other: Dict[str, int] = {}
    for name, n in cells.items():
        if name in LUT_CELLS:
            lut_logic += n
        elif name in LUTRAM_LUTS:
            lutram += LUTRAM_LUTS[name] * n
        elif name in BRAM36_SHARE:
            bram += BRAM36_SHARE[name] * n
        elif name.startswith("DSP48"):
            dsp += n
        elif _FF_CELL.match(name):
            ff += n
        else:
            other[name] = n
    return Counts(lut_logic, lutram, ff, bram, dsp, other)


# --------------------------------------------------------------------------- running yosys


def rtl_dir() -> Path:
    """``stereocam/overlays/rtl``, found through the installed package as the simulations find it."""
    return hdl.rtl_dir()


def default_cache_dir() -> Path:
    """``synth/`` beside the other HDL builds (:func:`stereocam.overlays.rtl.toolchain.build_root`)."""
    return hdl.build_root() / "synth"


def find_sources(rtl: Path, top: str = TOP) -> List[Path]:
    """The ``*.v`` files of ``rtl``, sorted; refuses a folder without them or without ``top``."""
    where = "the rectify core's Verilog goes in stereocam/overlays/rtl/"
    if not rtl.is_dir():
        raise HwSynthError(f"no RTL: {rtl} is not a folder ({where})")
    sources = sorted(p for p in rtl.iterdir() if p.suffix in SOURCE_SUFFIXES and p.is_file())
    if not sources:
        raise HwSynthError(f"no RTL: {rtl} has no *.v files ({where})")
    decl = re.compile(rf"^\s*module\s+{re.escape(top)}\b", re.M)
    if not any(decl.search(p.read_text(encoding="utf-8", errors="replace")) for p in sources):
        raise HwSynthError(f"no module {top} in {rtl}/*.v")
    return sources


def yosys_version(yosys: str) -> str:
    """``Yosys 0.23 (git sha1 ...)``: part of the cache key."""
    try:
        out = subprocess.run([yosys, "-V"], capture_output=True, text=True, timeout=60, check=True).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        raise HwSynthError(f"cannot run {yosys} -V: {exc}") from None
    return out.strip()


def find_yosys() -> str:
    path = shutil.which("yosys")
    if path is None:
        raise HwSynthError("yosys not found on PATH: install it with `apt-get install yosys` "
                           "(Debian 12 has 0.23, which this flow is written for)")
    return path


def include_dirs(sources_dir: Path, extra_sources: Sequence[Path] = ()) -> List[Path]:
    """The folders whose headers the sources may include: their own, then those of the shared
    modules (the RTL root, whose ``prelude.vh`` every RTL file includes)."""
    return list(dict.fromkeys([Path(sources_dir), *(Path(p).parent for p in extra_sources)]))


def yosys_script(sources: Sequence[Path], includes: Sequence[Path], top: str, parameters: Mapping[str, int],
                 stat_json: str, defines: Mapping[str, str], netlist_json: Optional[str] = None) -> str:
    """The yosys script: read, set the build's parameters on the top, synthesise, count."""
    def q(p: Path) -> str:
        return '"' + str(p) + '"'

    # yosys 0.23 takes an -I folder's quotes literally (it finds a file's own folder by itself)
    read = ["read_verilog", "-sv", *(arg for folder in includes for arg in ("-I", str(folder)))]
    read += [f"-D{k}={v}" if v else f"-D{k}" for k, v in defines.items()]
    lines = [" ".join(read + [q(p) for p in sources])]
    if parameters:
        lines.append("chparam " + " ".join(f"-set {k} {int(v)}" for k, v in parameters.items()) + f" {top}")
    lines += [SYNTH_COMMAND.format(top=top), f"tee -q -o {stat_json} stat -json", "stat"]
    if netlist_json:
        lines.append(f"write_json {netlist_json}")
    return "\n".join(lines) + "\n"


def cache_key(sources_dir: Path, top: str, parameters: Mapping[str, int], defines: Mapping[str, str],
              version: str, extra_sources: Sequence[Path] = (), netlist: bool = False) -> str:
    """Hash of every source and header, the parameters, the defines, the flow and yosys's version."""
    h = hashlib.sha256()
    head = {"flow": FLOW_VERSION, "synth": SYNTH_COMMAND, "top": top, "yosys": version,
            "parameters": dict(sorted(parameters.items())), "defines": dict(sorted(defines.items()))}
    if netlist:  # only then, so that the keys of runs without a netlist stay as they were
        head["netlist"] = True
    h.update(json.dumps(head, sort_keys=True).encode())
    hashed = [p for p in sorted(sources_dir.iterdir()) if p.suffix in HASHED_SUFFIXES and p.is_file()]
    shared_dirs = include_dirs(sources_dir, extra_sources)[1:]
    headers = [h for folder in shared_dirs for h in sorted(folder.glob("*.vh"))]
    for p in [*hashed, *map(Path, extra_sources), *headers]:
        h.update(b"\0" + p.name.encode() + b"\0" + hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:20]


def _yosys_error(log: str, top: str) -> str:
    lines = [ln.strip() for ln in log.splitlines() if "ERROR:" in ln]
    if not lines:
        return "no ERROR line in its log"
    msg = lines[0][lines[0].index("ERROR:") + len("ERROR:"):].strip()
    m = re.search(r"Can't find object for defparam `(\w+)`", msg)
    if m:
        return f"{top} has no parameter {m.group(1)} that this build sets"
    return msg


@dataclass
class SynthResult:
    """What one yosys run found (or the cache remembered)."""

    top: str
    parameters: Dict[str, int]
    cells: Dict[str, int]
    yosys_version: str
    script: str
    seconds: float  # of the yosys run that produced it
    cached: bool
    log: Optional[Path]
    netlist: Optional[Path] = None  # yosys's write_json of the mapped design, when asked for

    @property
    def counts(self) -> Counts:
        return count_resources(self.cells)


def synthesize(sources_dir: Path, *, top: str = TOP, parameters: Optional[Mapping[str, int]] = None,
               defines: Optional[Mapping[str, str]] = None, cache_dir: Optional[Path] = None,
               timeout: float = DEFAULT_TIMEOUT_S, use_cache: bool = True,
               extra_sources: Sequence[Path] = (), netlist: bool = False) -> SynthResult:
    """Run yosys on every ``*.v`` in ``sources_dir`` and ``extra_sources`` (modules shared from another
    folder), or return the cached counts of an identical run.

    The cache key covers the sources, the parameters and yosys's version, so a change to
    any of them reruns yosys; an identical call returns at once.
    """
    parameters = dict(parameters or {})
    defines = dict(defines or {})
    sources = find_sources(sources_dir, top) + [Path(p) for p in extra_sources]
    yosys = find_yosys()
    version = yosys_version(yosys)
    cache = cache_dir or default_cache_dir()
    key = cache_key(sources_dir, top, parameters, defines, version, extra_sources, netlist)
    result_path = cache / f"{top}-{key}.json"
    log_path = cache / f"{top}-{key}.log"
    netlist_path = cache / f"{top}-{key}.netlist.json"
    kept = netlist_path if netlist else None
    if use_cache and result_path.is_file() and (not netlist or netlist_path.is_file()):
        try:
            saved = json.loads(result_path.read_text(encoding="utf-8"))
            return SynthResult(top, parameters, {k: int(v) for k, v in saved["cells"].items()}, version,
                               saved["script"], float(saved["seconds"]), True,
                               log_path if log_path.is_file() else None, kept)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a damaged cache entry: run again
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache, prefix=f".{key}-") as work:
        script = yosys_script(sources, include_dirs(sources_dir, extra_sources), top, parameters, "stat.json",
                              defines, "netlist.json" if netlist else None)
        (Path(work) / "synth.ys").write_text(script, encoding="utf-8")
        start = time.monotonic()
        try:
            proc = subprocess.run([yosys, "-q", "-l", "yosys.log", "-s", "synth.ys"], cwd=work,
                                  capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise HwSynthError(f"yosys did not finish within {timeout:g} s (see --timeout)") from None
        seconds = time.monotonic() - start
        log = Path(work, "yosys.log")
        log_text = log.read_text(encoding="utf-8", errors="replace") if log.is_file() else ""
        if log.is_file():
            os.replace(log, log_path)
        if proc.returncode != 0:
            detail = _yosys_error(log_text + "\n" + proc.stderr + "\n" + proc.stdout, top)
            raise HwSynthError(f"yosys failed (exit {proc.returncode}): {detail} (log: {log_path})")
        stat = Path(work, "stat.json")
        if not stat.is_file():
            raise HwSynthError(f"yosys wrote no stat.json (log: {log_path})")
        cells = parse_stat_json(stat.read_text(encoding="utf-8"))
        saved = {"top": top, "parameters": parameters, "defines": defines, "yosys": version,
                 "script": script, "seconds": seconds, "cells": cells}
        tmp = Path(work, "result.json")
        tmp.write_text(json.dumps(saved, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        if netlist:
            if not Path(work, "netlist.json").is_file():
                raise HwSynthError(f"yosys wrote no netlist.json (log: {log_path})")
            os.replace(Path(work, "netlist.json"), netlist_path)
        os.replace(tmp, result_path)
    return SynthResult(top, parameters, cells, version, script, seconds, False, log_path, kept)


# --------------------------------------------------------------------------- report


def over_floor(counts: Counts, build: str) -> List[str]:
    """``["DSP48E1 180 > 172", ...]``: every resource above this build's floor."""
    values = counts.by_key()
    return [f"{r.key} {_num(values[r.key])} > {_num(r.floor[build])}"
            for r in RESOURCES if build in r.floor and values[r.key] > r.floor[build]]


def report_dict(result: SynthResult, build: BuildParams, builds_from: str) -> Dict[str, Any]:
    """The ``--json`` object: the same numbers as the table."""
    values = result.counts.by_key()
    resources: Dict[str, Any] = {}
    for r in RESOURCES:
        v = values[r.key]
        floor = r.floor.get(build.name)
        resources[r.key] = {
            "yosys": v, "share_pct": round(100 * v / r.device, 1),
            "paper_share_pct": r.paper_share_pct, "paper_count": r.paper_count,
            "floor": floor, "goal": r.goal.get(build.name), "device": r.device,
            "over": floor is not None and v > floor,
        }
    over = over_floor(result.counts, build.name)
    return {
        "top": result.top, "device": DEVICE, "build": build.to_dict(), "builds_from": builds_from,
        "parameters": result.parameters,
        "yosys": {"version": result.yosys_version, "command": SYNTH_COMMAND.format(top=result.top),
                  "seconds": round(result.seconds, 2), "cached": result.cached,
                  "log": str(result.log) if result.log else None},
        "cells": dict(sorted(result.cells.items())), "other_cells": result.counts.other,
        "resources": resources, "over": over, "within_floor": not over, "note": NOTE,
    }


def _num(v: float) -> str:
    return f"{v:,.1f}" if v != int(v) else f"{int(v):,}"


def format_table(report: Mapping[str, Any]) -> str:
    """The text report: one row per resource, Table 1 and the floor beside yosys's count."""
    b = report["build"]
    y = report["yosys"]
    head = (f"{report['top']}, build {b['name']} (MAX_WIDTH {b['max_width']}, MAX_HEIGHT {b['max_height']}, "
            f"LB_ROWS {b['lb_rows']}, {'colour' if b['colour'] else 'gray'}; {report['builds_from']})\n"
            f"{y['version']}: {y['command']}, {y['seconds']:g} s{' (cached)' if y['cached'] else ''}")
    rows = [("resource", "this core (yosys)", f"paper Table 1 ({DEVICE} share)", "floor for this build",
             "device total")]
    for r in RESOURCES:
        e = report["resources"][r.key]
        paper = "-" if e["paper_share_pct"] is None else f"{e['paper_share_pct']} % (~{e['paper_count']:,})"
        floor = "-" if e["floor"] is None else f"<= {_num(e['floor'])}"
        if e["goal"] is not None:
            floor += f" (goal {_num(e['goal'])})"
        mine = f"{_num(e['yosys'])} ({e['share_pct']:.1f} %)" + ("  OVER" if e["over"] else "")
        rows.append((r.label, mine, paper, floor, f"{r.device:,}"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [head, ""] + ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
                          for row in rows]
    other = report["other_cells"]
    if other:
        lines.append("other cells: " + ", ".join(f"{k} {v:,}" for k, v in sorted(other.items())))
    lines += ["", NOTE]
    if report["over"]:
        lines.append(f"OVER the floor of build {b['name']}: " + ", ".join(report["over"]))
    else:
        lines.append(f"within the floor of build {b['name']}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- command line


def add_yosys_args(s: argparse.ArgumentParser, table: Mapping[str, BuildParams]) -> None:
    """The options every ``stereocam hw`` command that runs yosys on a build takes."""
    s.add_argument("--build", choices=sorted(table), default="gray" if "gray" in table else sorted(table)[0],
                   help="which build's parameters (default gray)")
    s.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    s.add_argument("--rtl", metavar="DIR", help="the Verilog folder (default stereocam/overlays/rtl)")
    s.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="S",
                   help=f"give up on yosys after S seconds (default {DEFAULT_TIMEOUT_S:g})")
    s.add_argument("--no-cache", action="store_true", help="run yosys even if an identical run is cached")


def add_synth_parser(hw_sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam hw synth``, added to the ``hw`` group by ``cli.build_parser``."""
    table, _ = builds()
    s = hw_sub.add_parser(
        "synth", help="synthesise the rectify core and the overlay's RTL with yosys; the whole "
                      "overlay against the device",
        description=f"Run yosys synth_xilinx -family xc7 on every *.v in stereocam/overlays/rtl/ (top {TOP}) "
                    f"with the "
                    f"build's parameters, and print its LUT, LUTRAM, FF, BRAM36 and DSP48E1 beside the "
                    f"paper's Table 1, the build's floor and the {DEVICE}'s totals; then the whole overlay "
                    f"of the block design: its camera input and frame gates synthesised, its Xilinx IP "
                    f"estimated from the product guides (cited), totals against the device. Results are "
                    f"cached in ~/.cache/stereocam/hdl/synth/. Exit 0 within the floor, 1 over it, "
                    f"2 on a tool or input error.")
    add_yosys_args(s, table)
    s.add_argument("--core-only", action="store_true",
                   help="the rectify core alone, without the whole overlay's table (camera input, "
                        "frame gates, Xilinx IP)")
    s.set_defaults(func=cmd_hw_synth)


def cmd_hw_synth(args: argparse.Namespace) -> int:
    """Exit 0 within the floor, 1 over it (naming what is over), 2 on a tool or input error."""
    try:
        table, builds_from = builds()
        build = table[args.build]
        rtl = Path(args.rtl) if args.rtl else rtl_dir()
        result = synthesize(rtl, parameters=build.parameters(), timeout=args.timeout,
                            use_cache=not args.no_cache, netlist=True)
        parts = None if args.core_only else overlay_parts(build, result, timeout=args.timeout,
                                                          use_cache=not args.no_cache)
    except HwSynthError as exc:
        print(f"stereocam hw synth: error: {exc}", file=sys.stderr)
        return 2
    report = report_dict(result, build, builds_from)
    if result.netlist is not None:
        report["dsp_cascade"] = dsp_map.summary(dsp_map.read_dsps(result.netlist))
    overlay = None if parts is None else overlay_dict(parts, build)
    if overlay is not None:
        report["overlay"] = overlay
    if args.json:
        print(json.dumps(report))
    else:
        print(format_table(report))
        if "dsp_cascade" in report:
            d = report["dsp_cascade"]
            print(f"DSP48E1 cascades: {d['PCIN']} of {d['DSP48E1']} take the previous DSP's P on PCIN, "
                  f"{d['C_from_P']} take another DSP's P through fabric into C, {d['PREG']} use PREG")
        if overlay is not None:
            print("\n" + format_overlay(overlay))
    code = 0
    if report["over"]:
        print(f"stereocam hw synth: over the floor of build {build.name}: {', '.join(report['over'])}",
              file=sys.stderr)
        code = 1
    if overlay is not None and overlay["over_device"]:
        print(f"stereocam hw synth: the whole overlay of build {build.name} is over the {DEVICE}: "
              f"{', '.join(overlay['over_device'])}", file=sys.stderr)
        code = 1
    if overlay is not None and overlay["over_floor"]:
        print(f"stereocam hw synth: the whole overlay of build {build.name} is over its floor: "
              f"{', '.join(overlay['over_floor'])}", file=sys.stderr)
        code = 1
    return code


# --------------------------------------------------------------------------- the whole overlay

#: The block design whose cells the whole-overlay table covers.
BLOCK_DESIGN = Path(__file__).resolve().parent.parent / "vivado" / "block_design.tcl"
CORE_VLNV_NAME = "rectify"
CAMERA_VLNV_NAME = "camera_in"
GATE_VLNV_NAME = "frame_gate"
STEREO_VLNV_NAME = "stereo"
OVERLAY_NOTE = ("RTL rows are yosys counts of the block design's own cores with its parameters; Xilinx IP "
                "rows are estimates from the product guides cited (not synthesised); Vivado's "
                "report_utilization of a real build replaces them.")
_CELL = re.compile(r"create_bd_cell\s+-type\s+ip\s+-vlnv\s+(\S+)\s+(\w+)")
_CONFIG_BLOCK = re.compile(r"set_property\s+-dict\s+\[list(.*?)\]\s+\[get_bd_cells\s+(\w+)\]", re.S)
_CONFIG_ITEM = re.compile(r"CONFIG\.(\w+)\s+(?:\{([^}]*)\}|(\$?\w+))")


@dataclass(frozen=True)
class BdCell:
    """One ``create_bd_cell`` of the block design and its ``CONFIG.*`` values."""

    name: str
    vlnv: str
    config: Dict[str, str]

    @property
    def ip(self) -> str:
        parts = self.vlnv.split(":")
        return parts[2] if len(parts) == 4 else self.vlnv


_BUILD_IF = re.compile(r'^\s*if \{\$STEREOCAM_BUILD eq "(\w+)"\} \{', re.M)


def _braced_end(text: str, start: int) -> int:
    """Index just past the brace that closes the one at ``text[start]``."""
    depth = 0
    for i in range(start, len(text)):
        depth += {"{": 1, "}": -1}.get(text[i], 0)
        if depth == 0:
            return i + 1
    raise HwSynthError("the block design has an unclosed brace")


def text_for_build(text: str, build: str) -> str:
    """``text`` with each ``if {$STEREOCAM_BUILD eq "<b>"} {...} else {...}`` replaced by the branch
    ``build`` takes (block_design.tcl's depth-only parts; the gray and colour builds take none)."""
    design = "depth" if build == STEREO_BUILD else "colour"
    while (m := _BUILD_IF.search(text)) is not None:
        body_end = _braced_end(text, m.end() - 1)
        chosen = text[m.end():body_end - 1] if m.group(1) == design else ""
        end = body_end
        rest = re.match(r"\s*else \{", text[end:])
        if rest is not None:
            else_end = _braced_end(text, end + rest.end() - 1)
            if m.group(1) != design:
                chosen = text[end + rest.end():else_end - 1]
            end = else_end
        text = text[:m.start()] + chosen + text[end:]
    return text


def block_design_cells(path: Path = BLOCK_DESIGN, build: str = "colour") -> List[BdCell]:
    """The IP cells of ``block_design.tcl`` in order for ``build`` (the depth build's own cells only in
    it), each with its literal ``CONFIG.*`` values (a later ``set_property`` wins)."""
    try:
        text = text_for_build(path.read_text(encoding="utf-8"), build)
    except OSError as exc:
        raise HwSynthError(f"cannot read the block design {path}: {exc}") from None
    config: Dict[str, Dict[str, str]] = {}
    for block, cell in _CONFIG_BLOCK.findall(text):
        for key, braced, bare in _CONFIG_ITEM.findall(block):
            config.setdefault(cell, {})[key] = braced if braced or not bare else bare
    cells = [BdCell(name, vlnv, config.get(name, {})) for vlnv, name in _CELL.findall(text)]
    if not cells:
        raise HwSynthError(f"no create_bd_cell in {path}")
    return cells


@dataclass(frozen=True)
class Part:
    """One row of the whole-overlay table: a block-design cell (or several alike) and its resources."""

    name: str  # row label
    cells: Tuple[str, ...]  # block-design cells it counts
    kind: str  # "yosys" (our RTL, synthesised) or "estimate" (Xilinx IP, from a product guide)
    lut: int
    ff: int
    bram36: float
    dsp: int
    source: str  # yosys run (top, parameters) or the product guide and table

    def values(self) -> Dict[str, float]:
        return {"LUT": self.lut, "FF": self.ff, "BRAM36": self.bram36, "DSP48E1": self.dsp}

    def to_dict(self) -> Dict[str, Any]:
        return {"name": self.name, "cells": list(self.cells), "kind": self.kind,
                "estimate": self.kind != "yosys", **self.values(), "source": self.source}


#: The device the totals are held against (the Zynq-7020's PL), by resource.
OVERLAY_DEVICE: Dict[str, int] = {"LUT": 53_200, "FF": 106_400, "BRAM36": 140, "DSP48E1": 220}

#: The whole overlay's floors, per build where the build has one (issue 23's for the depth build: LUT
#: at most 75 % of the device, BRAM36 at most 85 %, DSP48E1 at most 220, room left for Vivado's placer);
#: the gray and colour builds' floors are their rectify core's (:data:`RESOURCES`).
OVERLAY_FLOORS: Dict[str, Dict[str, float]] = {
    STEREO_BUILD: {"LUT": 0.75 * OVERLAY_DEVICE["LUT"], "BRAM36": 0.85 * OVERLAY_DEVICE["BRAM36"],
                   "DSP48E1": 220},
}


def _rtl_part(name: str, cells: Sequence[str], result: SynthResult) -> Part:
    c = result.counts
    n = len(cells)
    params = ", ".join(f"{k} {v}" for k, v in result.parameters.items())
    return Part(name, tuple(cells), "yosys", c.lut * n, c.ff * n, c.bram36 * n, c.dsp * n,
                f"yosys {SYNTH_COMMAND.format(top=result.top)} ({params})" + (f", x{n}" if n > 1 else ""))


def _config_text(config: Mapping[str, str]) -> str:
    return ", ".join(f"{k} {v}" for k, v in config.items()) or "defaults"


def overlay_parts(build: BuildParams, core: SynthResult, *, cells: Optional[Sequence[BdCell]] = None,
                  camera_dir: Optional[Path] = None, timeout: float = DEFAULT_TIMEOUT_S,
                  use_cache: bool = True) -> List[Part]:
    """Every cell of the block design as rows: the core (this build's), the camera input and each
    frame gate synthesised with the block design's parameters, the Xilinx IP estimated.

    A cell this cannot account for (an IP without an estimate) is refused, naming it.
    """
    cells = list(cells) if cells is not None else block_design_cells(build=build.name)
    camera = camera_dir or rtl_dir() / "camera"
    shared = [camera.parent / "rc_ram.v", camera.parent / "rc_fifo.v"]  # the rectify core's, in the gates
    camera_shared = [*shared, camera.parent / "rc_gray.v"]  # and in camera_in, with its gray
    parts: List[Part] = []
    gates: Dict[Tuple[Tuple[str, str], ...], List[str]] = {}
    for cell in cells:
        if cell.ip == CORE_VLNV_NAME:
            parts.append(_rtl_part(f"rectify core ({build.name})", [cell.name], core))
        elif cell.ip == CAMERA_VLNV_NAME:
            params = {"MAX_WIDTH": int(cell.config.get("MAX_WIDTH", ci.PARAMETERS["MAX_WIDTH"])),
                      "BAYER_PHASE": int(cell.config.get("BAYER_PHASE", ci.CFA_PHASES.index(ci.BAYER_PHASE)))}
            r = synthesize(camera, top=ci.TOP, parameters=params, extra_sources=camera_shared,
                           timeout=timeout, use_cache=use_cache)
            parts.append(_rtl_part("camera_in", [cell.name], r))
        elif cell.ip == GATE_VLNV_NAME:
            gates.setdefault(tuple(sorted(cell.config.items())), []).append(cell.name)
        elif cell.ip == STEREO_VLNV_NAME:
            continue  # stereo_parts, with the build's parameters
        else:
            try:
                est, fig = ip_estimates.estimate(cell.vlnv, cell.config)
            except KeyError:
                raise HwSynthError(f"block design cell {cell.name} ({cell.vlnv}) has no resource estimate in "
                                   f"stereocam/overlays/rtl/ip_estimates.py for its configuration "
                                   f"({_config_text(cell.config)}): add one from its product guide") from None
            parts.append(Part(f"{cell.ip} (estimate)", (cell.name,), "estimate", fig.lut, fig.ff, fig.bram36,
                              fig.dsp, f"{est.citation}: {est.basis}"))
    for config, names in gates.items():
        params = {**fg.PARAMETERS, **{k: int(v) for k, v in config}}
        r = synthesize(camera, top=fg.TOP, parameters=params, extra_sources=shared, timeout=timeout,
                       use_cache=use_cache)
        parts.append(_rtl_part(f"frame_gate x{len(names)}", names, r))
    if build.stereo is not None:
        parts += stereo_parts(build, cells, timeout=timeout, use_cache=use_cache)
    rank = {"rectify": 0, "stereo": 1, "camera_in": 2, "frame_gate": 3}
    return sorted(parts, key=lambda p: rank.get(p.name.split()[0], 3))


def synthesize_stereo(build: BuildParams, *, timeout: float = DEFAULT_TIMEOUT_S, use_cache: bool = True,
                      netlist: bool = False) -> SynthResult:
    """yosys on the stereo core (``rtl/stereo/`` with the shared RAM and FIFO) with the build's parameters."""
    rtl = rtl_dir()
    return synthesize(rtl / "stereo", top=STEREO_TOP, parameters=build.stereo_parameters(),
                      extra_sources=[rtl / "rc_ram.v", rtl / "rc_fifo.v"], timeout=timeout,
                      use_cache=use_cache, netlist=netlist)


def stereo_parts(build: BuildParams, cells: Sequence[BdCell], *, timeout: float = DEFAULT_TIMEOUT_S,
                 use_cache: bool = True) -> List[Part]:
    """The depth build's stereo core, synthesised with the build's parameters (its VDMA, split, HP3
    interconnect and the register interconnect's extra ports are cells of the block design's depth build,
    estimated as the others)."""
    names = [c.name for c in cells if c.ip == STEREO_VLNV_NAME]
    if not names:
        raise HwSynthError("the block design's cells have no stereo core: read them for the depth build "
                           "(block_design_cells(build='depth'))")
    core = synthesize_stereo(build, timeout=timeout, use_cache=use_cache)
    return [_rtl_part(f"stereo core ({build.name})", names, core)]


def overlay_totals(parts: Sequence[Part]) -> Dict[str, float]:
    """The sum of the parts, by resource."""
    total: Dict[str, float] = {k: 0 for k in OVERLAY_DEVICE}
    for p in parts:
        for k, v in p.values().items():
            total[k] += v
    return total


def overlay_dict(parts: Sequence[Part], build: BuildParams) -> Dict[str, Any]:
    """The ``overlay`` object of ``--json``: the rows, their totals, the share of the device."""
    total = overlay_totals(parts)
    over = [f"{k} {_num(v)} > {OVERLAY_DEVICE[k]:,}" for k, v in total.items() if v > OVERLAY_DEVICE[k]]
    floor = OVERLAY_FLOORS.get(build.name, {})
    over_floor = [f"{k} {_num(total[k])} > {_num(limit)}" for k, limit in floor.items() if total[k] > limit]
    return {"build": build.name, "device": DEVICE, "device_totals": dict(OVERLAY_DEVICE),
            "parts": [p.to_dict() for p in parts], "total": total,
            "share_pct": {k: round(100 * v / OVERLAY_DEVICE[k], 1) for k, v in total.items()},
            "over_device": over, "within_device": not over,
            "floor": dict(floor), "over_floor": over_floor, "within_floor": not over_floor,
            "note": OVERLAY_NOTE}


def format_overlay(overlay: Mapping[str, Any]) -> str:
    """The whole-overlay table: one row per part, the total and its share of the device."""
    rows: List[Tuple[str, ...]] = [("part", "cells", "LUT", "FF", "BRAM36", "DSP48E1", "source")]
    keys = ("LUT", "FF", "BRAM36", "DSP48E1")
    for p in overlay["parts"]:
        rows.append((p["name"], ",".join(p["cells"]), *(_num(p[k]) for k in keys), p["source"]))
    t = overlay["total"]
    rows.append(("total", "", *(_num(t[k]) for k in keys), ""))
    rows.append((f"% of {DEVICE}", "", *(f"{overlay['share_pct'][k]:.1f} %" for k in keys),
                 "of " + ", ".join(f"{k} {v:,}" for k, v in overlay["device_totals"].items())))
    widths = [max(len(r[i]) for r in rows) for i in range(6)]
    lines = [f"whole overlay, build {overlay['build']} (stereocam/overlays/vivado/block_design.tcl)", ""]
    for r in rows:
        cols = [c.ljust(w) if i < 2 else c.rjust(w)
                for i, (c, w) in enumerate(zip(r[:6], widths, strict=True))]
        lines.append("  ".join(cols) + "  " + r[6])
    lines += ["", overlay["note"]]
    if overlay["over_device"]:
        lines.append(f"OVER the {DEVICE}: " + ", ".join(overlay["over_device"]))
    else:
        lines.append(f"within the {DEVICE}")
    if overlay.get("floor"):
        limits = ", ".join(f"{k} <= {_num(v)}" for k, v in overlay["floor"].items())
        if overlay["over_floor"]:
            lines.append(f"OVER the floor of build {overlay['build']} ({limits}): "
                         + ", ".join(overlay["over_floor"]))
        else:
            lines.append(f"within the floor of build {overlay['build']} ({limits})")
    return "\n".join(line.rstrip() for line in lines)
