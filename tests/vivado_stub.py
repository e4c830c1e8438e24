"""A stubbed Vivado for the tests: the scripts of ``stereocam/overlays/vivado/`` run in plain Tcl.

Every Vivado command is replaced by a recorder (:data:`VIVADO_COMMANDS`), and the recorded calls are
then replayed, in order, through :class:`FakeVivado`, which checks them as Vivado would stop on them:

* ``ipx::*`` (package_ip.tcl) packages our own IP: its VLNV, its user parameters with their ranges,
  its register block, and the interfaces and pins the packager infers from the top module's ports;
* ``create_bd_cell`` accepts a Xilinx VLNV only at the version the running release's catalog has
  (:mod:`tests.vivado_catalog`), and our own IP only as packaged;
* ``set_property CONFIG.*`` accepts only the IP's documented parameters and values;
* ``get_bd_pins``, ``get_bd_intf_pins``, ``get_bd_ports``, ``get_bd_addr_spaces`` and
  ``get_bd_addr_segs`` (the endpoints of every connection and address) must name what the cell
  has in its configuration at that point.

The first failure ends the run as Vivado's error would: :attr:`TclRun.error` says what and where,
and :attr:`TclRun.design` holds the block design built so far (cells, parameters, nets, addresses),
which :mod:`tests.pynq_hwh` writes as the ``.hwh``.
"""
from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Set, Tuple

from .vivado_catalog import AXIMM, AXIS, CATALOG, RELEASES, VALUE_SOURCES, CatalogIP, Int, Param

#: What the stubbed ``version -short`` answers: the release whose IP catalog the stub has.
FAKE_VERSION = "2022.1"


# ---- a small Tcl reader -----------------------------------------------------------------------------

Command = List[str]


def _word_end(text: str, i: int) -> int:
    """Index just past the Tcl word that starts at ``text[i]`` (braced, quoted or bare)."""
    n = len(text)
    if text[i] == "{":
        depth, j = 0, i
        while j < n:
            if text[j] == "\\":  # an escaped character counts as neither brace
                j += 2
                continue
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            if depth == 0:
                return j + 1
            j += 1
        raise ValueError("unbalanced braces")
    quoted = text[i] == '"'
    j = i + 1 if quoted else i
    brackets = 0
    while j < n:
        c = text[j]
        if c == "\\":
            j += 2
            continue
        if c == "[":
            brackets += 1
        elif c == "]":
            brackets -= 1
        elif c == "{" and brackets > 0:
            j = _word_end(text, j)
            continue
        elif quoted and c == '"' and brackets == 0:
            return j + 1
        elif not quoted and brackets == 0 and c in " \t\n;":
            return j
        j += 1
    if quoted or brackets:
        raise ValueError("unbalanced quotes or brackets")
    return j


def tcl_commands(text: str) -> List[Command]:
    """The commands of a Tcl script (top level only), each as its words with braces and brackets kept."""
    text = re.sub(r"\\\n[ \t]*", " ", text)
    commands: List[Command] = []
    words: Command = []
    i = 0
    while i < len(text):
        c = text[i]
        if c in " \t\r":
            i += 1
        elif c in "\n;":
            if words:
                commands.append(words)
                words = []
            i += 1
        elif c == "#" and not words:
            while i < len(text) and text[i] != "\n":
                i += 1
        else:
            end = _word_end(text, i)
            words.append(text[i:end])
            i = end
    if words:
        commands.append(words)
    return commands


def unbrace(word: str) -> str:
    """The value of a braced or quoted word."""
    if len(word) >= 2 and (word[0], word[-1]) in (("{", "}"), ('"', '"')):
        return word[1:-1]
    return word


def tcl_list(word: str) -> List[str]:
    """The elements of a Tcl list value."""
    commands = tcl_commands(unbrace(word).replace("\n", " "))
    return [unbrace(w) for w in commands[0]] if commands else []


def bracketed(word: str) -> Command:
    """The command inside ``[...]`` (one command), its words unbraced."""
    assert word.startswith("[") and word.endswith("]"), f"expected [command], got {word!r}"
    (command,) = tcl_commands(word[1:-1])
    return [unbrace(w) for w in command]


def options(words: Sequence[str], valued: Set[str]) -> Tuple[Dict[str, str], List[str]]:
    """``-flag value`` pairs (for the flags in ``valued``; other flags count as switches) and the rest."""
    opts: Dict[str, str] = {}
    rest: List[str] = []
    it = iter(words)
    for w in it:
        if w.startswith("-") and w in valued:
            opts[w] = next(it)
        elif w.startswith("-") and not w[1:2].isdigit():
            opts[w] = ""
        else:
            rest.append(w)
    return opts, rest


def connect_net(nets: List[List[str]], pins: Sequence[str]) -> List[List[str]]:
    """``nets`` after ``connect_bd_net`` of ``pins``: Vivado adds the pins to the net one of them is
    already on (a net joins a pin once), else they make a new net."""
    joined = [net for net in nets if set(net) & set(pins)]
    merged = [p for net in joined for p in net]
    return [net for net in nets if net not in joined] + [merged + [p for p in pins if p not in merged]]


# ---- running the scripts in Tcl, Vivado's commands recorded -----------------------------------------------

# Every Vivado command the scripts may call, and what the stand-in returns (a Tcl body; $args are the
# command's arguments). Any other command that is not Tcl's own fails as "invalid command name".
_FIRST = "return [lindex $args 0]"
_LAST = "return [lindex $args end]"
VIVADO_COMMANDS: Dict[str, str] = {
    # project
    "version": "return $::stereocam_fake_version",
    "create_project": "", "close_project": "", "current_project": "return project",
    "add_files": "", "get_files": _LAST, "current_fileset": "return sources_1", "update_compile_order": "",
    "update_ip_catalog": "", "get_property": "return [stereocam_fake_property {*}$args]", "set_property": "",
    # block design
    "create_bd_design": "", "create_bd_cell": _LAST, "get_bd_cells": _FIRST, "apply_bd_automation": "",
    "create_bd_port": _LAST, "get_bd_ports": _FIRST, "get_bd_pins": _FIRST, "get_bd_intf_pins": _FIRST,
    "create_bd_intf_port": _LAST, "get_bd_intf_ports": _FIRST,
    "connect_bd_net": "", "connect_bd_intf_net": "", "assign_bd_address": "",
    "get_bd_addr_spaces": _FIRST, "get_bd_addr_segs": _FIRST,
    "validate_bd_design": "", "save_bd_design": "", "make_wrapper": "return /nowhere/stereocam_wrapper.v",
    "generate_target": "",
    # runs
    "launch_runs": "", "wait_on_run": "", "get_runs": _FIRST,
    # routed timing: the summary file, and the worst setup (max) and hold (min) paths' slack
    "open_run": "", "report_timing_summary": "stereocam_fake_summary {*}$args",
    "get_timing_paths": "return timing_[lindex $args [expr {[lsearch $args -delay_type] + 1}]]",
    # IP packaging
    "ipx::package_project": "", "ipx::current_core": "return core",
    "ipx::get_bus_interfaces": _FIRST, "ipx::get_bus_parameters": _FIRST, "ipx::add_bus_parameter": _FIRST,
    "ipx::associate_bus_interfaces": "", "ipx::infer_bus_interface": "",
    "ipx::get_memory_maps": "", "ipx::remove_memory_map": "", "ipx::add_memory_map": _FIRST,
    "ipx::add_address_block": _FIRST, "ipx::add_register": _FIRST,
    "ipx::get_user_parameters": _FIRST, "ipx::get_hdl_parameters": _FIRST,
    "ipx::create_xgui_files": "", "ipx::update_checksums": "", "ipx::check_integrity": "",
    "ipx::save_core": "",
}

_PRELUDE = r"""
set ::stereocam_calls {}
set ::stereocam_fake_version @FAKE_VERSION@
namespace eval ipx {}
proc stereocam_fake_property {name object} {
    switch -- $name {
        PROGRESS {return 100%}
        STATUS {return {write_bitstream Complete!}}
        DIRECTORY {return [file join $::stereocam_proj $::STEREOCAM_BD_NAME.runs $object]}
        SLACK {return $::stereocam_fake_slack($object)}
        default {return $object}
    }
}
set ::stereocam_fake_slack(timing_max) 0.412
set ::stereocam_fake_slack(timing_min) 0.051
proc stereocam_fake_summary args {
    set f [open [lindex $args [expr {[lsearch $args -file] + 1}]] w]
    puts $f "Timing summary: WNS $::stereocam_fake_slack(timing_max) WHS $::stereocam_fake_slack(timing_min)"
    close $f
}
"""


@dataclass
class TclRun:
    calls: List[List[str]]
    error: str
    variables: Dict[str, str]
    design: "Design" = field(default_factory=lambda: Design())
    packaged: Dict[str, "OwnIP"] = field(default_factory=dict)

    def of(self, verb: str) -> List[List[str]]:
        return [c[1:] for c in self.calls if c[0] == verb]

    def projects(self) -> List[str]:
        """The names of the projects created, in order (create_project -force NAME DIR -part PART)."""
        return [options(c, {"-part"})[1][0] for c in self.of("create_project")]


def _brace(value: str) -> str:
    assert not re.search(r"[{}\\]", value), value
    return "{" + value + "}"


def run_tcl(script: Path, tmp: Path, *, argv: Sequence[str] = (), preset: Optional[Dict[str, str]] = None,
            read: Sequence[str] = ()) -> TclRun:
    """Source ``script`` in the stubbed Vivado: the calls, its error (or the first the stub found), the
    variables ``read``, and the block design it built."""
    out = tmp / "tcl-run.txt"
    stubs = "\n".join(f"proc {name} args {{lappend ::stereocam_calls [list {name} {{*}}$args]; {body}}}"
                      for name, body in VIVADO_COMMANDS.items())
    prelude = _PRELUDE.replace("@FAKE_VERSION@", FAKE_VERSION)
    lines = [prelude, stubs, f"set argv [list {' '.join(_brace(a) for a in argv)}]"]
    lines += [f"set {k} {_brace(v)}" for k, v in (preset or {}).items()]
    lines.append(f"""
set stereocam_status [catch {{source {_brace(str(script))}}} stereocam_message]
set f [open {_brace(str(out))} w]
proc hex {{s}} {{return [binary encode hex [encoding convertto utf-8 $s]]}}
foreach c $::stereocam_calls {{puts $f [join [lmap w $c {{hex $w}}] " "]}}
puts $f "= [hex [expr {{$stereocam_status == 1 ? $stereocam_message : {{}}}}]]"
foreach v {{{' '.join(read)}}} {{
    puts $f "$ [hex $v] [hex [expr {{[info exists ::$v] ? [set ::$v] : {{}}}}]]"
}}
close $f
""")
    driver = tmp / "tcl-driver.tcl"
    driver.write_text("\n".join(lines))
    interp = None
    try:
        import tkinter
        interp = tkinter.Tcl()
    except Exception as exc:  # no _tkinter, or a Tcl without its library: try tclsh
        reason = str(exc)
    if interp is not None:
        interp.eval(f"source {_brace(str(driver))}")
    else:
        tclsh = shutil.which("tclsh")
        if tclsh is None:
            raise RuntimeError(f"the Vivado scripts need Tcl: Python's tkinter ({reason}) or tclsh "
                               "(Debian: tcl)")
        subprocess.run([tclsh, str(driver)], check=True, timeout=120)

    def unhex(word: str) -> str:
        return bytes.fromhex(word).decode()

    run = TclRun([], "", {})
    for line in out.read_text().splitlines():
        if line.startswith("= "):
            run.error = unhex(line[2:].strip())
        elif line.startswith("$ "):
            _, name, value = (line.split(" ") + [""])[:3]
            run.variables[unhex(name)] = unhex(value)
        else:
            run.calls.append([unhex(w) for w in line.split(" ")])
    vivado = FakeVivado()
    stop, error = vivado.replay(run.calls)
    if error:  # Vivado stops at the failing command: nothing after it ran
        run.calls, run.error = run.calls[:stop + 1], error
    run.design, run.packaged = vivado.design, vivado.packaged
    return run



# ---- the checking model -----------------------------------------------------------------------------

class VivadoError(Exception):
    """What Vivado would stop with."""


@dataclass
class OwnIP:
    """An IP package_ip.tcl packaged: what a cell of it has."""

    vlnv: str
    top: str
    params: Dict[str, Param] = field(default_factory=dict)
    interfaces: Dict[str, Tuple[str, str]] = field(default_factory=dict)  # name -> (bus VLNV, mode)
    pins: List[str] = field(default_factory=list)
    segments: Dict[str, str] = field(default_factory=dict)  # "intf/block" -> interface
    ranges: Dict[str, int] = field(default_factory=dict)  # "intf/block" -> bytes decoded
    # "intf/block" -> its registers, each name -> {address_offset, size, access, reset_value}
    registers: Dict[str, Dict[str, Dict[str, str]]] = field(default_factory=dict)
    hdl_ports: Dict[str, Tuple[str, int]] = field(default_factory=dict)  # name -> (direction, width)
    hdl_params: List[str] = field(default_factory=list)


@dataclass
class Cell:
    name: str
    vlnv: str
    config: Dict[str, str]
    ip: Optional[CatalogIP] = None
    own: Optional[OwnIP] = None

    @property
    def doc(self) -> str:
        top = self.own.top if self.own else "?"
        return self.ip.doc if self.ip else f"packaged by package_ip.tcl from {top}"

    def params(self) -> Dict[str, Param]:
        return dict(self.ip.params) if self.ip else dict(self.own.params if self.own else {})

    def interfaces(self) -> Dict[str, Tuple[str, str]]:
        if self.ip:
            types = self.ip.intf_types(self.config)
            return {name: types.get(name, ("", "")) for name in self.ip.interfaces(self.config)}
        return dict(self.own.interfaces) if self.own else {}

    def pins(self) -> List[str]:
        if self.ip:
            return self.ip.pins(self.config)
        return list(self.own.pins) if self.own else []

    def spaces(self) -> List[str]:
        return self.ip.spaces(self.config) if self.ip else []

    def segments(self) -> Dict[str, str]:
        if self.ip:
            return self.ip.segments(self.config)
        return dict(self.own.segments) if self.own else {}

    def interrupts(self) -> List[str]:
        return self.ip.interrupts(self.config) if self.ip else []


@dataclass
class Assignment:
    space: str  # cell/space
    segment: str  # cell/intf/segment
    offset: int
    range: int


@dataclass
class Design:
    """The block design as the scripts built it in the stubbed Vivado."""

    name: str = ""
    cells: Dict[str, Cell] = field(default_factory=dict)
    ports: Dict[str, Dict[str, str]] = field(default_factory=dict)
    intf_ports: Dict[str, Dict[str, str]] = field(default_factory=dict)
    nets: List[List[str]] = field(default_factory=list)
    intf_nets: List[Tuple[str, str]] = field(default_factory=list)
    addresses: List[Assignment] = field(default_factory=list)

    def net_of(self, pin: str) -> List[str]:
        for net in self.nets:
            if pin in net:
                return net
        return []

    def peer(self, intf: str) -> Optional[str]:
        for a, b in self.intf_nets:
            if intf in (a, b):
                return b if a == intf else a
        return None


_BUS = re.compile(r"^([sm]_axi[sl]?)_")


def _hdl_module(sources: Sequence[str], top: str) -> Tuple[List[str], Dict[str, Tuple[str, int]]]:
    """The parameters and ports of module ``top``'s ANSI header among ``sources`` (numeric widths)."""
    for source in sources:
        path = Path(source)
        if path.suffix != ".v" or not path.is_file():
            continue
        text = re.sub(r"//[^\n]*|/\*.*?\*/", "", path.read_text(), flags=re.S)
        m = re.search(rf"\bmodule\s+{top}\b(.*?)\);", text, re.S)
        if m is None:
            continue
        ports: Dict[str, Tuple[str, int]] = {}
        for direction, rng, name in re.findall(
                r"\b(input|output|inout)\s+(?:wire\s+|reg\s+)?(?:signed\s+)?(\[[^\]]*\])?\s*(\w+)",
                m.group(1)):
            width = 1
            nums = re.fullmatch(r"\[\s*(\d+)\s*:\s*(\d+)\s*\]", rng or "")
            if nums:
                width = abs(int(nums.group(1)) - int(nums.group(2))) + 1
            ports[name] = (direction, width)
        return re.findall(r"\bparameter\s+(?:integer\s+)?(\w+)\s*=", m.group(1)), ports
    return [], {}


# get_bd_* of a cell's member: (what Vivado calls it, path depth, the cell's method listing them)
_MEMBERS: Dict[str, Tuple[str, int, str]] = {
    "get_bd_pins": ("pin", 2, "pins"),
    "get_bd_intf_pins": ("interface", 2, "interfaces"),
    "get_bd_addr_spaces": ("address space", 2, "spaces"),
    "get_bd_addr_segs": ("address segment", 3, "segments"),
}


class FakeVivado:
    """Vivado's answers to the recorded calls, in order: :meth:`call` raises :class:`VivadoError`."""

    def __init__(self, release: str = FAKE_VERSION) -> None:
        if release not in RELEASES:
            raise ValueError(f"no IP catalog for Vivado {release}")
        self.release = release
        self.catalog = RELEASES[release]
        self.packaged: Dict[str, OwnIP] = {}
        self.design = Design()
        self._sources: List[str] = []
        self._top = ""
        self._core: Optional[OwnIP] = None
        self._core_parts: Dict[str, str] = {}
        self._block: Optional[Tuple[str, str]] = None
        self._register = ""

    # -- helpers

    def _cell(self, name: str, verb: str) -> Cell:
        cell = self.design.cells.get(name)
        if cell is None:
            raise VivadoError(f"{verb}: no cell '{name}' in the block design "
                              f"(cells: {', '.join(self.design.cells) or 'none'})")
        return cell

    def _split(self, path: str, verb: str, parts: int) -> Tuple[Cell, str]:
        pieces = path.split("/", 1)
        if len(pieces) != 2 or len(path.split("/")) != parts:
            raise VivadoError(f"{verb}: '{path}' is not a cell/name path")
        return self._cell(pieces[0], verb), pieces[1]

    # -- IP packaging (package_ip.tcl)

    def _package(self, verb: str, args: List[str]) -> None:
        if verb == "ipx::package_project":
            opts = dict(zip(args[::2], args[1::2], strict=False))
            self._core_parts = {"vendor": opts.get("-vendor", ""), "library": opts.get("-library", "")}
            hdl_params, ports = _hdl_module(self._sources, self._top)
            if not ports:
                raise VivadoError(f"ipx::package_project: no module {self._top} among the sources")
            own = OwnIP("", self._top, hdl_ports=ports, hdl_params=hdl_params)
            for port in ports:
                m = _BUS.match(port)
                if m:
                    bus = m.group(1)
                    own.interfaces[bus] = (AXIMM if bus.endswith(("axi", "axil")) else AXIS,
                                           "SLAVE" if bus.startswith("s_") else "MASTER")
                else:
                    own.pins.append(port)
            self._core = own
        elif self._core is None:
            return
        elif verb == "ipx::add_address_block":
            block, memory_map = args[0], args[1]
            self._core.segments[f"{memory_map}/{block}"] = memory_map
            self._block = (block, f"{memory_map}/{block}")
        elif verb == "ipx::add_register":
            if self._block is None or args[1] != self._block[0]:
                raise VivadoError(f"ipx::add_register {args[0]}: no address block '{args[1]}'")
            registers = self._core.registers.setdefault(self._block[1], {})
            if args[0] in registers:
                raise VivadoError(f"ipx::add_register: {args[0]} is in {self._block[1]} already")
            registers[args[0]] = {}
            self._register = args[0]
        elif verb == "ipx::get_user_parameters":
            self._register = ""
            name = args[0]
            if name not in self._core.hdl_params:
                raise VivadoError(f"ipx::get_user_parameters: {self._top} has no parameter {name}")
            self._core.params.setdefault(name, Int(0, -(1 << 31), (1 << 31) - 1))
        elif verb == "ipx::save_core":
            own = self._core
            parts = ("vendor", "library", "name", "version")
            own.vlnv = ":".join(self._core_parts.get(k, "") for k in parts)
            self.packaged[own.vlnv] = own
            self._core = None

    def _core_property(self, prop: str, value: str, target: str) -> None:
        assert self._core is not None
        if target == "core" and prop in ("name", "version"):
            self._core_parts[prop] = value
            return
        if self._block and self._register and target == self._register:
            self._core.registers[self._block[1]][target][prop] = value
            return
        if self._block and target == self._block[0]:
            if prop == "range":
                self._core.ranges[self._block[1]] = int(value, 0)
            return
        if target in self._core.params:
            param = self._core.params[target]
            if prop == "value_validation_range_minimum":
                self._core.params[target] = Param(param.default, int(value), param.high, None)
            elif prop == "value_validation_range_maximum":
                self._core.params[target] = Param(param.default, param.low, int(value), None)
            elif prop == "value":
                self._core.params[target] = Param(value, param.low, param.high, None)

    # -- the block design

    def _create_cell(self, args: List[str]) -> None:
        opts, _ = options(args, {"-type", "-vlnv"})
        name, vlnv = args[-1], opts.get("-vlnv", "")
        if name in self.design.cells:
            raise VivadoError(f"create_bd_cell: a cell named '{name}' exists already")
        base, _, version = vlnv.rpartition(":")
        if base in CATALOG:
            have = self.catalog[base]
            if version != have:
                raise VivadoError(f"create_bd_cell {name}: IP definition not found for VLNV {vlnv}: Vivado "
                                  f"{self.release} has {base}:{have} ({CATALOG[base].doc})")
            ip = CATALOG[base]
            self.design.cells[name] = Cell(name, vlnv, ip.defaults(), ip=ip)
            return
        own = self.packaged.get(vlnv)
        if own is None:
            raise VivadoError(f"create_bd_cell {name}: IP definition not found for VLNV {vlnv}: not in "
                              f"Vivado "
                              f"{self.release}'s catalog, and package_ip.tcl packaged "
                              f"{', '.join(sorted(self.packaged)) or 'nothing'}")
        self.design.cells[name] = Cell(name, vlnv, {k: p.default for k, p in own.params.items()}, own=own)

    def _configure(self, cell: Cell, pairs: List[str]) -> None:
        params = cell.params()
        for key, value in zip(pairs[::2], pairs[1::2], strict=True):
            if not key.startswith("CONFIG."):
                raise VivadoError(f"set_property {key} on cell {cell.name}: only CONFIG.* properties "
                                  "configure it")
            name = key[len("CONFIG."):]
            where = f"set_property {key} on {cell.name} ({cell.vlnv})"
            if name.endswith(".VALUE_SRC"):
                base = name[:-len(".VALUE_SRC")]
                if base not in params:
                    raise VivadoError(f"{where}: {cell.vlnv} has no parameter {base} ({cell.doc})")
                if value not in VALUE_SOURCES:
                    raise VivadoError(f"{where}: {value!r} is not one of {', '.join(sorted(VALUE_SOURCES))}")
                continue
            if name not in params:
                raise VivadoError(f"{where}: {cell.vlnv} has no parameter {name} ({cell.doc})")
            problem = params[name].problem(value)
            if problem:
                raise VivadoError(f"{where}: {problem} ({cell.doc})")
            cell.config[name] = value

    def _get(self, verb: str, args: List[str]) -> None:
        path = args[0] if args else ""
        d = self.design
        if verb == "get_bd_cells":
            self._cell(path, verb)
        elif verb == "get_bd_ports":
            if path not in d.ports:
                raise VivadoError(f"get_bd_ports: no external port '{path}'")
        elif verb == "get_bd_intf_ports":
            if path not in d.intf_ports:
                raise VivadoError(f"get_bd_intf_ports: no external interface port '{path}'")
        elif verb in _MEMBERS:
            what, depth, listed = _MEMBERS[verb]
            cell, name = self._split(path, verb, depth)
            have = getattr(cell, listed)()
            if name not in have:
                raise VivadoError(f"{verb}: {cell.name} ({cell.vlnv}) has no {what} '{name}' in its "
                                  f"configuration ({listed}: {', '.join(have) or 'none'}; {cell.doc})")

    def call(self, words: List[str]) -> None:
        """One recorded call."""
        verb, args = words[0], words[1:]
        d = self.design
        if verb == "add_files":
            self._sources = [w for w in args if not w.startswith("-")][-1].split() if args else []
        elif verb == "set_property" and len(args) == 3 and args[0] == "top":
            self._top = args[1]
        elif verb.startswith("ipx::"):
            self._package(verb, args)
        elif verb == "set_property" and self._core is not None and len(args) == 3:
            self._core_property(*args)
        elif verb == "create_bd_design":
            d.name = args[-1]
        elif verb == "create_bd_cell":
            self._create_cell(args)
        elif verb == "set_property" and args and args[-1] in d.cells:
            if args[0] == "-dict":
                self._configure(d.cells[args[-1]], tcl_list(args[1]))
            else:
                self._configure(d.cells[args[-1]], args[:2])
        elif verb.startswith("get_bd_"):
            self._get(verb, args)
        elif verb == "apply_bd_automation":
            cell = self._cell(args[-1], verb)
            opts, _ = options(args, {"-rule", "-config"})
            config = tcl_list(opts.get("-config", ""))
            settings = dict(zip(config[::2], config[1::2], strict=False))
            for intf in re.split(r"[,\s]+", settings.get("make_external", "").strip()):  # PS7: FIXED_IO, DDR
                if not intf:
                    continue
                if intf not in cell.interfaces():
                    raise VivadoError(f"apply_bd_automation: {cell.name} has no interface '{intf}'")
                d.intf_ports[intf] = {"-mode": "Master"}
                d.intf_nets.append((f"{cell.name}/{intf}", intf))
        elif verb == "create_bd_port":
            opts, rest = options(args, {"-dir", "-from", "-to", "-type", "-freq_hz"})
            d.ports[rest[-1]] = opts
        elif verb == "create_bd_intf_port":
            opts, rest = options(args, {"-mode", "-vlnv"})
            d.intf_ports[rest[-1]] = opts
        elif verb == "connect_bd_net":
            # Vivado adds the pins to the net a pin is already on (a net joins a pin once)
            d.nets = connect_net(d.nets, args)
        elif verb == "connect_bd_intf_net":
            if len(args) != 2:
                raise VivadoError(f"connect_bd_intf_net: needs two interfaces, got {args}")
            d.intf_nets.append((args[0], args[1]))
        elif verb == "assign_bd_address":
            opts, rest = options(args, {"-offset", "-range", "-target_address_space"})
            d.addresses.append(Assignment(opts["-target_address_space"], rest[-1], int(opts["-offset"], 0),
                                          int(opts["-range"], 0)))

    def replay(self, calls: List[List[str]]) -> Tuple[int, str]:
        """Replay ``calls``: (index of the failing call, Vivado's error), or (len(calls), "")."""
        for i, words in enumerate(calls):
            try:
                self.call(words)
            except VivadoError as exc:
                return i, f"ERROR: [stub Vivado {self.release}] {exc}"
        return len(calls), ""
