"""The Vivado scripts of ``stereocam/overlays/vivado/`` against the spec the drivers and the emulated fabric
read.

Vivado is not installed where the tests run, so no bitstream is built here. Instead:

* the scripts are read as text: a small Tcl word splitter (they are written in the regular style of
  Vivado's ``write_bd_tcl``) gives their commands, whose cell names, VLNVs, parameters, connections
  and addresses are checked against ``stereocam/overlays/spec/``, the RTL's module headers and the drivers;
* each script is then run in a plain Tcl interpreter (Python's ``tkinter.Tcl``, else ``tclsh``) with
  every Vivado command replaced by a recorder: that proves the scripts are valid Tcl, that their
  control flow (options, placeholder checks, output names) works, and that what they hand Vivado is
  what the text says.

Expected values always come from the spec modules, never from this file.
"""
from __future__ import annotations

import math
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Set, Tuple

import pytest

from stereocam.board.profile import load_profile
from stereocam.drivers.vdma import VDMA
from stereocam.overlays import backend
from stereocam.overlays.emulated.logic import EmulatedFabric, StreamCore
from stereocam.overlays.emulated.regblock import EmulationError, RegisterBlock
from stereocam.overlays.fabric import bind
from stereocam.overlays.spec import (
    axis_switch,
    camera_in,
    frame_gate,
    mt9v034,
    overlay,
    pixel,
    rectify,
    stereo,
    vdma,
)

from ..vivado_stub import TclRun, bracketed, connect_net, options, run_tcl, tcl_commands, tcl_list, unbrace

REPO_ROOT = Path(__file__).resolve().parents[2]
VIVADO_DIR = REPO_ROOT / "stereocam" / "overlays" / "vivado"
RTL_DIR = REPO_ROOT / "stereocam" / "overlays" / "rtl"
SCRIPTS = ("settings.tcl", "package_ip.tcl", "block_design.tcl", "build.tcl")
PS7 = "processing_system7_0"
PS7_DATA = f"{PS7}/Data"  # the PS7's address space: GP0's register windows
GP0_RANGE = (0x4000_0000, 0x8000_0000)  # Zynq-7000 M_AXI_GP0 (UG585, "System Address Map")
HP_PORT = re.compile(rf"{PS7}/S_AXI_HP(\d)")  # the PS7's four AXI3 high-performance ports (UG585)
INTERCONNECT = "xilinx.com:ip:axi_interconnect:"
CHANNELS = {  # VDMA channel -> (include parameter, stream interface, memory interface, address space)
    "S2MM": ("c_include_s2mm", "S_AXIS_S2MM", "M_AXI_S2MM", "Data_S2MM"),
    "MM2S": ("c_include_mm2s", "M_AXIS_MM2S", "M_AXI_MM2S", "Data_MM2S"),
}
STREAM_WIDTH = {"S2MM": "c_s_axis_s2mm_tdata_width", "MM2S": "c_m_axis_mm2s_tdata_width"}
USE_FSYNC_TUSER = "2"  # PG020 "Fsync Options": c_use_s2mm_fsync 2 = "s2mm tuser" (start of frame on TUSER)


def read_script(name: str) -> str:
    return (VIVADO_DIR / name).read_text()


def settings() -> Dict[str, str]:
    """The plain ``set NAME value`` lines of settings.tcl."""
    out: Dict[str, str] = {}
    for words in tcl_commands(read_script("settings.tcl")):
        if words[0] == "set" and len(words) == 3 and not words[2].startswith("["):
            out[words[1]] = unbrace(words[2])
    return out


def substitute(word: str, variables: Dict[str, str]) -> str:
    """``$NAME`` and ``${NAME}`` of settings.tcl replaced by their values (others left as written)."""
    return re.sub(r"\$\{?(\w+)\}?", lambda m: variables.get(m.group(1), m.group(0)), word)



# ---- the block design, as block_design.tcl writes it ------------------------------------------------

@dataclass
class Address:
    space: str
    segment: str
    offset: int
    range: int


@dataclass
class BlockDesign:
    cells: Dict[str, str] = field(default_factory=dict)  # name -> VLNV
    config: Dict[str, Dict[str, str]] = field(default_factory=dict)  # name -> CONFIG.<key> -> value
    intf_nets: List[Tuple[str, str]] = field(default_factory=list)  # interface pin pairs
    nets: List[List[str]] = field(default_factory=list)  # "cell/pin" or "port" per net
    ports: Dict[str, Dict[str, str]] = field(default_factory=dict)  # external port -> its options
    intf_ports: Dict[str, Dict[str, str]] = field(default_factory=dict)  # external interface port -> options
    addresses: List[Address] = field(default_factory=list)

    def connected(self, pin: str) -> Set[str]:
        """Interface pins joined to ``pin``."""
        return {b if a == pin else a for a, b in self.intf_nets if pin in (a, b)}

    def net_of(self, pin: str) -> List[str]:
        """The net that holds ``pin`` (empty if none)."""
        nets = [net for net in self.nets if pin in net]
        assert len(nets) <= 1, f"{pin} is on {len(nets)} nets"
        return nets[0] if nets else []

    def address(self, space: str, segment: str) -> Address:
        found = [a for a in self.addresses if a.space == space and a.segment == segment]
        assert len(found) == 1, f"{segment} is assigned {len(found)} times in {space}"
        return found[0]


BUILD_CONDITION = re.compile(r'\{\$STEREOCAM_BUILD eq "(\w+)"\}')


def parse_block_design(text: str, variables: Dict[str, str], bd: Optional[BlockDesign] = None) -> BlockDesign:
    """What ``text`` builds, for the build ``variables["STEREOCAM_BUILD"]`` (default colour): the body of
    an ``if {$STEREOCAM_BUILD eq "<build>"} {...} else {...}`` is read as that build chooses."""
    bd = BlockDesign() if bd is None else bd
    for raw in tcl_commands(text):
        words = [substitute(w, variables) for w in raw]
        verb = words[0]
        build = BUILD_CONDITION.fullmatch(raw[1]) if verb == "if" and len(raw) > 2 else None
        if build is not None:
            chosen = variables.get("STEREOCAM_BUILD", "colour") == build.group(1)
            body = raw[2] if chosen else (raw[4] if len(raw) > 4 and raw[3] == "else" else "{}")
            parse_block_design(unbrace(body), variables, bd)
        elif verb == "create_bd_cell":
            opts, rest = options(words[1:], {"-type", "-vlnv"})
            assert opts["-type"] == "ip", words
            bd.cells[rest[-1]] = opts["-vlnv"]
        elif verb == "set_property" and words[1] == "-dict":
            pairs = bracketed(words[2])
            assert pairs[0] == "list" and len(pairs) % 2 == 1, words
            target = bracketed(words[3])
            assert target[0] == "get_bd_cells", words
            cfg = bd.config.setdefault(target[1], {})
            for key, value in zip(pairs[1::2], pairs[2::2], strict=True):
                assert key.startswith("CONFIG."), key
                cfg[key[len("CONFIG."):]] = value
        elif verb == "set_property" and words[1].startswith("CONFIG."):
            target = bracketed(words[3])
            bd.config.setdefault(target[1], {})[words[1][len("CONFIG."):]] = unbrace(words[2])
        elif verb == "connect_bd_intf_net":
            pins = [bracketed(w)[1] for w in words[1:] if w.startswith("[")]
            assert len(pins) == 2, words
            bd.intf_nets.append((pins[0], pins[1]))
        elif verb == "connect_bd_net":
            pins = [bracketed(w)[1] for w in words[1:] if w.startswith("[")]
            bd.nets = connect_net(bd.nets, pins)
        elif verb == "create_bd_port":
            opts, rest = options(words[1:], {"-dir", "-from", "-to", "-type", "-freq_hz"})
            bd.ports[rest[-1]] = opts
        elif verb == "create_bd_intf_port":
            opts, rest = options(words[1:], {"-mode", "-vlnv"})
            bd.intf_ports[rest[-1]] = opts
        elif verb == "assign_bd_address":
            opts, rest = options(words[1:], {"-offset", "-range", "-target_address_space"})
            space = bracketed(opts["-target_address_space"])
            segment = bracketed(rest[-1])
            assert space[0] == "get_bd_addr_spaces" and segment[0] == "get_bd_addr_segs", words
            offset, size = int(opts["-offset"], 0), int(opts["-range"], 0)
            bd.addresses.append(Address(space[1], segment[1], offset, size))
    return bd


# ---- the packaged IP, as package_ip.tcl describes it -------------------------------------------------

@dataclass
class PackagedIP:
    project: str
    top: str
    vlnv: str = ""
    params: Dict[str, Tuple[int, int, int]] = field(default_factory=dict)  # name -> (default, min, max)
    interfaces: List[str] = field(default_factory=list)  # bus interfaces the script requires
    clock: Tuple[str, str, List[str]] = ("", "", [])  # clock, reset, the interfaces it runs
    free_clocks: List[str] = field(default_factory=list)
    windows: Dict[str, int] = field(default_factory=dict)  # AXI4-Lite interface -> register window bytes


def ip_params_tcl() -> Dict[str, str]:
    """The arrays of the generated ip_params.tcl, as "NAME(ip)" -> its word as written."""
    return {words[1]: words[2] for words in tcl_commands(read_script("ip_params.tcl"))
            if words[0] == "set"}


def parse_package(text: str) -> Dict[str, PackagedIP]:
    """The IPs package_ip.tcl packages, by VLNV; a section starts at stereocam_packaging_project."""
    generated = ip_params_tcl()

    def value(word: str) -> str:
        m = re.fullmatch(r"\$(\w+\(\w+\))", word)
        return generated[m.group(1)] if m else word

    ips: List[PackagedIP] = []
    vendor = library = name = version = ""
    for words in tcl_commands(text):
        verb = words[0]
        if verb == "stereocam_packaging_project":
            if ips:
                ips[-1].vlnv = f"{vendor}:{library}:{name}:{version}"
            ips.append(PackagedIP(project=words[1], top=words[2]))
            vendor = library = name = version = ""
        elif not ips:
            continue
        elif verb == "ipx::package_project":
            opts, _ = options(words[1:], {"-root_dir", "-vendor", "-library", "-taxonomy"})
            vendor, library = opts["-vendor"], opts["-library"]
        elif verb == "set_property" and words[1] == "name" and words[-1] == "$core":
            name = words[2]
        elif verb == "set_property" and words[1] == "version" and words[-1] == "$core":
            version = words[2]
        elif verb == "stereocam_user_param":
            ips[-1].params[words[2]] = (int(words[3]), int(words[4]), int(words[5]))
        elif verb == "stereocam_user_params":
            for param in tcl_list(generated[f"STEREOCAM_IP_PARAMS({words[2]})"]):
                pname, default, low, high = tcl_list(param)
                ips[-1].params[pname] = (int(default), int(low), int(high))
        elif verb == "stereocam_require_interfaces":
            ips[-1].interfaces = tcl_list(words[2])
        elif verb == "stereocam_clock":
            ips[-1].clock = (words[2], words[3], tcl_list(words[4]))
        elif verb == "stereocam_free_clock":
            ips[-1].free_clocks.append(words[2])
        elif verb == "stereocam_register_window":
            ips[-1].windows[words[2]] = int(value(words[3]), 0)
    if ips:
        ips[-1].vlnv = f"{vendor}:{library}:{name}:{version}"
    return {ip.vlnv: ip for ip in ips}


# ---- Verilog module headers ---------------------------------------------------------------------------

@dataclass
class Module:
    parameters: List[str]
    ports: Dict[str, Tuple[str, Optional[int]]]  # name -> (direction, width if numeric)


def header_defines() -> Dict[str, str]:
    """Every numeric ```define`` of the RTL's headers (the generated ``*_spec.vh``), by name."""
    out: Dict[str, str] = {}
    for path in sorted(RTL_DIR.rglob("*.vh")):
        for name, value in re.findall(r"^`define\s+(\w+)\s+(\d+)\b", path.read_text(), re.M):
            out[name] = value
    return out


def _bound(text: str) -> Optional[int]:
    """A range bound of digits, ``+`` and ``-`` (``12-1``, after the header's macros are expanded)."""
    if not re.fullmatch(r"[\d\s+-]+", text):
        return None
    total, sign = 0, 1
    for token in re.findall(r"\d+|[+-]", text):
        if token in "+-":
            sign = 1 if token == "+" else -1
        else:
            total += sign * int(token)
    return total


def verilog_module(text: str, name: str) -> Optional[Module]:
    """Parameters and ports of module ``name``'s ANSI header in ``text`` (None if it is not there).

    Macros of the RTL's headers are expanded, so a port ``[`RC_ADDR_W-1:0]`` has its width."""
    defines = header_defines()
    text = re.sub(r"`(\w+)", lambda d: defines.get(d.group(1), d.group(0)), text)
    m = re.search(rf"\bmodule\s+{name}\b(.*?)\);", re.sub(r"//[^\n]*|/\*.*?\*/", "", text, flags=re.S), re.S)
    if m is None:
        return None
    header = m.group(1)
    params = re.findall(r"\bparameter\s+(?:integer\s+)?(\w+)\s*=", header)
    ports: Dict[str, Tuple[str, Optional[int]]] = {}
    for direction, rng, port in re.findall(
            r"\b(input|output|inout)\s+(?:wire\s+|reg\s+)?(?:signed\s+)?(\[[^\]]*\])?\s*(\w+)", header):
        width: Optional[int] = 1
        if rng:
            msb, _, lsb = rng[1:-1].partition(":")
            hi, lo = _bound(msb), _bound(lsb)
            width = abs(hi - lo) + 1 if hi is not None and lo is not None else None
        ports[port] = (direction, width)
    return Module(params, ports)


# ---- fixtures ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def variables() -> Dict[str, str]:
    return settings()


@pytest.fixture(scope="module")
def bd(variables: Dict[str, str]) -> BlockDesign:
    return parse_block_design(read_script("block_design.tcl"), variables)


@pytest.fixture(scope="module")
def depth_bd(variables: Dict[str, str]) -> BlockDesign:
    """The depth build's block design (build.tcl -build depth)."""
    return parse_block_design(read_script("block_design.tcl"), {**variables, "STEREOCAM_BUILD": "depth"})


@pytest.fixture(scope="module")
def packaged() -> Dict[str, PackagedIP]:
    return parse_package(read_script("package_ip.tcl"))


def vdma_channels(bd: BlockDesign, name: str) -> List[str]:
    """The channels a VDMA cell is built with."""
    return [ch for ch, (include, *_) in CHANNELS.items() if bd.config[name].get(include) == "1"]


def vdmas(bd: BlockDesign) -> List[str]:
    """The design's VDMA cells."""
    return [name for name, vlnv in bd.cells.items() if vlnv in overlay.VDMA_VLNVS]


def hp_port(bd: BlockDesign, master: str) -> Tuple[str, int]:
    """(interconnect, n): a VDMA master reaches S_AXI_HP<n> through one AXI interconnect of one SI and
    one MI (PG059's conversion-only use: the AXI4 -> AXI3 protocol converter the HP port needs)."""
    (slave,) = bd.connected(master)
    hub, slot = slave.split("/")
    assert bd.cells[hub].startswith(INTERCONNECT) and slot == "S00_AXI", slave
    assert (bd.config[hub]["NUM_SI"], bd.config[hub]["NUM_MI"]) == ("1", "1"), hub
    (port,) = bd.connected(f"{hub}/M00_AXI")
    match = HP_PORT.fullmatch(port)
    assert match is not None, f"{hub}/M00_AXI -> {port}"
    return hub, int(match.group(1))


def hp_ddr(n: int) -> str:
    """The DDR segment the PS7 gives S_AXI_HP<n> (PG082)."""
    return f"{PS7}/S_AXI_HP{n}/HP{n}_DDR_LOWOCM"


def memory_ports(bd: BlockDesign) -> Dict[Tuple[str, str], Tuple[str, int]]:
    """(VDMA, channel) -> (interconnect, HP port n), for every VDMA channel of the design."""
    return {(name, ch): hp_port(bd, f"{name}/{CHANNELS[ch][2]}") for name in vdmas(bd)
            for ch in vdma_channels(bd, name)}


def hp_enabled(bd: BlockDesign) -> List[int]:
    """The HP ports the PS7 is configured with."""
    return [n for n in range(4) if bd.config[PS7].get(f"PCW_USE_S_AXI_HP{n}") == "1"]


# ---- identities ---------------------------------------------------------------------------------------

def test_every_instance_the_drivers_bind_is_in_the_design_with_an_accepted_vlnv(bd: BlockDesign) -> None:
    for name, accepted in overlay.INSTANCES.items():
        assert name in bd.cells, f"the block design has no cell {name!r}"
        assert bd.cells[name] in accepted, f"{name} is {bd.cells[name]}, the drivers accept {accepted}"
    assert bd.cells["vdma_raw"] in vdma.VLNV and bd.cells["vdma_proc"] in vdma.VLNV
    assert bd.cells["mux"] == axis_switch.VLNV
    assert bd.cells["rectify"] == rectify.VLNV
    assert bd.cells[camera_in.INSTANCE] == camera_in.VLNV
    for gate in frame_gate.INSTANCES:
        assert bd.cells[gate] == frame_gate.VLNV, gate


def test_the_packaged_ip_are_the_cores_the_design_instantiates(packaged: Dict[str, PackagedIP],
                                                               bd: BlockDesign) -> None:
    assert set(packaged) == {rectify.VLNV, camera_in.VLNV, frame_gate.VLNV, stereo.VLNV}
    assert packaged[rectify.VLNV].top == "rectify_core"
    assert packaged[camera_in.VLNV].top == camera_in.TOP
    assert packaged[frame_gate.VLNV].top == frame_gate.TOP
    assert packaged[stereo.VLNV].top == "stereo_core"
    user_cells = {vlnv for vlnv in bd.cells.values() if not vlnv.startswith("xilinx.com:")}
    assert user_cells == set(packaged) - {stereo.VLNV}, "the colour build has no stereo core"


# ---- the rectify core and the camera input IP ---------------------------------------------------------

def test_rectify_build_parameters_are_the_default_build(packaged: Dict[str, PackagedIP],
                                                        bd: BlockDesign) -> None:
    build = rectify.DEFAULT_BUILD
    expected = {"MAX_WIDTH": build.max_width, "MAX_HEIGHT": build.max_height, "LB_ROWS": build.lb_rows,
                "COLOUR": int(build.colour)}
    params = packaged[rectify.VLNV].params
    assert {name: default for name, (default, _, _) in params.items()} == expected
    assert {name: int(value) for name, value in bd.config["rectify"].items()} == expected
    for name, (default, low, high) in params.items():
        assert low <= default <= high, name
    for name in ("MAX_WIDTH", "MAX_HEIGHT"):
        assert params[name][2] < 2 ** rectify.SIZE_BITS, f"{name} must stay below 2**SIZE_BITS"
    other = rectify.BUILDS["gray"] if build.colour else rectify.BUILDS["colour"]
    assert params["COLOUR"][1] <= int(other.colour) <= params["COLOUR"][2], "both builds must be allowed"


def test_every_verilog_parameter_of_each_top_is_a_user_parameter(packaged: Dict[str, PackagedIP]) -> None:
    module = verilog_module((RTL_DIR / "rectify_core.v").read_text(), "rectify_core")
    assert module is not None
    assert set(packaged[rectify.VLNV].params) == set(module.parameters)
    cam = packaged[camera_in.VLNV].params
    assert {name: default for name, (default, _, _) in cam.items()} == camera_in.PARAMETERS
    module = verilog_module((RTL_DIR / "camera" / f"{frame_gate.TOP}.v").read_text(), frame_gate.TOP)
    assert module is not None
    assert set(packaged[frame_gate.VLNV].params) == set(module.parameters) == set(frame_gate.PARAMETERS)


def test_camera_parameters_in_the_design_are_the_spec_defaults(bd: BlockDesign,
                                                                packaged: Dict[str, PackagedIP]) -> None:
    assert {k: int(v) for k, v in bd.config[camera_in.INSTANCE].items()} == camera_in.PARAMETERS
    params = packaged[camera_in.VLNV].params
    for name, (default, low, high) in params.items():
        assert low <= default <= high, name
    # The limits the spec states, where it states them (the camera spec is being written alongside).
    if hasattr(camera_in, "MAX_WIDTH_LIMIT"):
        assert params["MAX_WIDTH"][1:] == (camera_in.MIN_WIDTH, camera_in.MAX_WIDTH_LIMIT)
    if "BAYER_PHASE" in camera_in.PARAMETERS:
        phases = len(camera_in.CFA_PHASES)
        assert params["BAYER_PHASE"][1:] == (0, phases - 1), "every phase must be buildable"


def test_frame_gate_parameters_are_the_spec_defaults(bd: BlockDesign,
                                                     packaged: Dict[str, PackagedIP]) -> None:
    params = packaged[frame_gate.VLNV].params
    assert {name: default for name, (default, _, _) in params.items()} == frame_gate.PARAMETERS
    assert params["DEPTH"][1:] == frame_gate.DEPTH_RANGE
    for gate in frame_gate.INSTANCES:
        assert {k: int(v) for k, v in bd.config[gate].items()} == frame_gate.PARAMETERS, gate
        # a line passes a gate only if it fits (the gate forwards whole lines only)
        depth = int(bd.config[gate]["DEPTH"])
        assert depth >= int(bd.config[camera_in.INSTANCE]["MAX_WIDTH"]), gate


def test_frame_gate_interfaces_are_the_spec_ports(packaged: Dict[str, PackagedIP]) -> None:
    ip = packaged[frame_gate.VLNV]
    clock, reset, busifs = ip.clock
    assert frame_gate.PORTS[clock] == frame_gate.PORTS[reset] == ("input", 1)
    assert set(ip.interfaces) == {clock, reset, *busifs}
    assert sorted(busifs) == ["m_axis", "s_axis"]
    for busif in busifs:
        out = "output" if busif == "m_axis" else "input"
        assert frame_gate.PORTS[f"{busif}_tdata"] == (out, pixel.BYTES_PER_PIXEL * 8)
        assert frame_gate.PORTS[f"{busif}_tready"][0] == ("input" if out == "output" else "output")
        assert {f"{busif}_{s}" for s in ("tvalid", "tuser", "tlast")} <= set(frame_gate.PORTS)
    module = verilog_module((RTL_DIR / "camera" / f"{frame_gate.TOP}.v").read_text(), frame_gate.TOP)
    assert module is not None
    assert {name: (d, w) for name, (d, w) in module.ports.items()} == frame_gate.PORTS
    assert not ip.windows and not ip.free_clocks


def test_rectify_interfaces_match_the_rtl_ports(packaged: Dict[str, PackagedIP]) -> None:
    ip = packaged[rectify.VLNV]
    module = verilog_module((RTL_DIR / "rectify_core.v").read_text(), "rectify_core")
    assert module is not None
    clock, reset, busifs = ip.clock
    assert module.ports[clock][0] == "input" and module.ports[reset][0] == "input"
    assert set(ip.interfaces) == {clock, reset, *busifs}
    for busif in busifs:
        assert any(port.startswith(busif + "_") for port in module.ports), f"no {busif}_* ports"
    (lite,) = ip.windows
    assert ip.windows[lite] == rectify.RECTIFY_MAP.size
    assert module.ports[f"{lite}_awaddr"][1] == int(math.log2(rectify.RECTIFY_MAP.size))
    streams = [b for b in busifs if b != lite]
    assert sorted(streams) == ["m_axis", "s_axis"]
    for busif in streams:
        assert module.ports[f"{busif}_tdata"][1] == pixel.BYTES_PER_PIXEL * 8
        assert module.ports[f"{busif}_tuser"][1] == 1 and module.ports[f"{busif}_tlast"][1] == 1


def test_camera_interfaces_are_the_spec_ports(packaged: Dict[str, PackagedIP]) -> None:
    ip = packaged[camera_in.VLNV]
    clock, reset, busifs = ip.clock
    for port in (clock, reset, *ip.free_clocks):
        assert camera_in.PORTS[port] == ("input", 1), port
    assert set(ip.interfaces) == {clock, reset, *busifs}
    for busif in busifs:
        assert camera_in.PORTS[f"{busif}_tdata"] == ("output", pixel.BYTES_PER_PIXEL * 8)
        assert {f"{busif}_{s}" for s in ("tvalid", "tready", "tuser", "tlast")} <= set(camera_in.PORTS)
    assert sorted(ip.free_clocks) == sorted(f"{cam}_pclk" for cam in camera_in.CAMERAS)


def test_camera_rtl_when_present_has_the_spec_ports() -> None:
    """The camera RTL is written elsewhere; whatever top module it has must keep the spec's ports."""
    for path in sorted((RTL_DIR / "camera").glob("*.v")):
        module = verilog_module(path.read_text(), camera_in.TOP)
        if module is not None:
            assert set(module.ports) == set(camera_in.PORTS), path
            for name, (direction, width) in module.ports.items():
                assert direction == camera_in.PORTS[name][0], name
                assert width in (None, camera_in.PORTS[name][1]), name
            assert set(module.parameters) >= set(camera_in.PARAMETERS)


def test_the_packaged_rtl_is_every_file_of_the_core() -> None:
    """package_ip.tcl globs rc_*.v and *.vh: a module file named otherwise would be left out of the IP."""
    text = read_script("package_ip.tcl")
    assert "rectify_core.v" in text and "*.vh" in text and "rc_*.v" in text
    names = {p.name for p in RTL_DIR.iterdir() if p.suffix in (".v", ".vh", ".sv")}
    assert "rectify_spec.vh" in names and "rc_regs_decode.vh" in names
    assert names == ({"rectify_core.v"} | {p.name for p in RTL_DIR.glob("rc_*.v")}
                     | {p.name for p in RTL_DIR.glob("*.vh")})


# ---- VDMAs, mux, broadcaster ------------------------------------------------------------------------------

def test_vdma_frame_stores_stream_widths_and_start_of_frame(bd: BlockDesign) -> None:
    ports = memory_ports(bd)
    for name in ("vdma_raw", "vdma_proc"):
        cfg = bd.config[name]
        assert int(cfg["c_num_fstores"]) == overlay.NUM_FSTORES
        assert 1 <= overlay.NUM_FSTORES <= vdma.MAX_FSTORES
        assert cfg["c_include_sg"] == "0", "the drivers use register direct mode"
        for ch in vdma_channels(bd, name):
            low = ch.lower()
            _, n = ports[name, ch]
            assert int(cfg[STREAM_WIDTH[ch]]) == pixel.BYTES_PER_PIXEL * 8, (name, ch)
            hp_width = bd.config[PS7][f"PCW_S_AXI_HP{n}_DATA_WIDTH"]
            assert cfg[f"c_m_axi_{low}_data_width"] == hp_width, (name, ch)
            assert cfg[f"c_{low}_sof_enable"] == "1", (name, ch)
        if "S2MM" in vdma_channels(bd, name):
            assert cfg["c_use_s2mm_fsync"] == USE_FSYNC_TUSER, name
            assert cfg["c_s_axis_s2mm_tdata_width.VALUE_SRC"] == "USER", name


def test_vdma_channels_are_the_ones_the_streams_use(bd: BlockDesign) -> None:
    assert vdma_channels(bd, "vdma_raw") == ["S2MM"], "vdma_raw only writes the raw frames"
    assert sorted(vdma_channels(bd, "vdma_proc")) == ["MM2S", "S2MM"]
    for name in ("vdma_raw", "vdma_proc"):
        for ch, (_, stream, memory, _) in CHANNELS.items():
            used = bool(bd.connected(f"{name}/{stream}")) and bool(bd.connected(f"{name}/{memory}"))
            assert used == (ch in vdma_channels(bd, name)), (name, ch)


def test_the_driver_accepts_the_vdma_build(bd: BlockDesign) -> None:
    fabric = EmulatedFabric(clock="stepped")
    try:
        for name in ("vdma_raw", "vdma_proc"):
            cfg = bd.config[name]
            VDMA(fabric.blocks[name], fabric.ddr, num_fstores=int(cfg["c_num_fstores"]),
                 addr_width=int(cfg["c_addr_width"]), name=name)
    finally:
        fabric.close()


def test_mux_is_a_control_register_switch_of_the_spec_size(bd: BlockDesign) -> None:
    cfg = bd.config["mux"]
    assert int(cfg["NUM_SI"]) == axis_switch.NUM_INPUTS
    assert int(cfg["NUM_MI"]) == axis_switch.NUM_OUTPUTS
    # The driver writes CTRL and MI0_MUX (PG085): they exist only with control register routing.
    assert "CTRL" in axis_switch.AXIS_SWITCH_MAP and cfg["ROUTING_MODE"] == "1"


STREAM_MASTER = re.compile(r"(^m_axis$|^M\d\d_AXIS$|^M_AXIS_)")  # our cores, broadcaster/switch, VDMA


def stream_edges(bd: BlockDesign) -> Set[Tuple[str, str]]:
    """The design's AXI4-Stream connections as (master pin, slave pin)."""
    edges = set()
    for a, b in bd.intf_nets:
        # an external interface port has no cell: its name is its pin
        masters = [p for p in (a, b) if STREAM_MASTER.search(p.split("/")[-1])]
        slaves = [p for p in (a, b) if re.search(r"(^s_axis$|^S\d\d_AXIS$|^S_AXIS)", p.split("/")[-1])]
        if masters or slaves:
            assert len(masters) == len(slaves) == 1, f"{a} -- {b}: not one stream master and one slave"
            edges.add((masters[0], slaves[0]))
    return edges


def test_stream_graph_is_camera_to_gates_to_raw_vdma_and_mux(bd: BlockDesign) -> None:
    """Every stream connection, exactly: camera_in -> broadcaster; M00 -> gate_raw -> vdma_raw S2MM;
    M01 -> gate_live -> mux live input; virtual camera -> mux; mux -> rectify -> vdma_proc S2MM."""
    (split_in,) = bd.connected(f"{camera_in.INSTANCE}/m_axis")
    split = split_in.split("/")[0]
    assert bd.cells[split].startswith("xilinx.com:ip:axis_broadcaster:")
    assert int(bd.config[split]["NUM_MI"]) == len(frame_gate.INSTANCES)
    expected = {
        (f"{camera_in.INSTANCE}/m_axis", f"{split}/S_AXIS"),
        *((f"{split}/M{i:02d}_AXIS", f"{gate}/s_axis") for i, gate in enumerate(frame_gate.INSTANCES)),
        (f"{frame_gate.GATE_RAW}/m_axis", "vdma_raw/S_AXIS_S2MM"),
        (f"{frame_gate.GATE_LIVE}/m_axis", f"mux/S{axis_switch.LIVE:02d}_AXIS"),
        ("vdma_proc/M_AXIS_MM2S", f"mux/S{axis_switch.VIRTUAL:02d}_AXIS"),
        ("mux/M00_AXIS", "rectify/s_axis"),
        ("rectify/m_axis", "vdma_proc/S_AXIS_S2MM"),
    }
    assert stream_edges(bd) == expected
    assert frame_gate.INSTANCES[0] == frame_gate.GATE_RAW and frame_gate.INSTANCES[1] == frame_gate.GATE_LIVE
    cfg = bd.config[split]
    assert int(cfg["S_TDATA_NUM_BYTES"]) == int(cfg["M_TDATA_NUM_BYTES"]) == pixel.BYTES_PER_PIXEL
    assert cfg["S_TUSER_WIDTH"] == cfg["M_TUSER_WIDTH"] == "1" and cfg["HAS_TLAST"] == "1"


def test_nothing_downstream_can_hold_the_broadcaster(bd: BlockDesign) -> None:
    """A broadcaster passes a beat only when every output takes it: each output must be a frame gate,
    whose s_axis_tready is tied high in its RTL (never logic that could fall)."""
    (split_in,) = bd.connected(f"{camera_in.INSTANCE}/m_axis")
    split = split_in.split("/")[0]
    consumers = [slave for master, slave in stream_edges(bd) if master.startswith(f"{split}/")]
    assert consumers and all(bd.cells[c.split("/")[0]] == frame_gate.VLNV for c in consumers), consumers
    text = (RTL_DIR / "camera" / f"{frame_gate.TOP}.v").read_text()
    assert re.findall(r"^\s*assign\s+s_axis_tready\s*=\s*(.+?);", text, re.M) == ["1'b1"]


# ---- memory, interrupts, clocks, resets ------------------------------------------------------------------

@pytest.mark.parametrize("build", ["colour", "depth"])
def test_every_vdma_channel_reaches_ddr_through_its_own_hp_port(build: str, bd: BlockDesign,
                                                                depth_bd: BlockDesign) -> None:
    """Each VDMA master on an HP port of its own, through a 1:1 interconnect of its own (no arbitration
    between channels in the fabric), the port enabled 64 bits wide, its DDR segment the only one the
    channel's address space sees, at 0; the ports from HP0 up, none enabled and left unused."""
    design = depth_bd if build == "depth" else bd
    ports = memory_ports(design)
    hubs = [hub for hub, _ in ports.values()]
    numbers = sorted(n for _, n in ports.values())
    assert len(set(hubs)) == len(hubs), "one interconnect per channel"
    assert numbers == list(range(len(ports))) == hp_enabled(design), "one HP port per channel, from HP0"
    for (name, ch), (_, n) in ports.items():
        assert design.config[PS7][f"PCW_S_AXI_HP{n}_DATA_WIDTH"] == "64", n
        assert design.config[name][f"c_m_axi_{ch.lower()}_data_width"] == "64", (name, ch)
        space = f"{name}/{CHANNELS[ch][3]}"
        assert [a.segment for a in design.addresses if a.space == space] == [hp_ddr(n)], space
        address = design.address(space, hp_ddr(n))
        assert address.offset == 0 and address.range & (address.range - 1) == 0


@pytest.mark.parametrize("build", ["colour", "depth"])
def test_every_memory_interconnect_runs_on_the_fabric_clock_and_the_interconnect_resets(
        build: str, bd: BlockDesign, depth_bd: BlockDesign) -> None:
    """Clocked and reset as the register interconnect is: FCLK_CLK0 on ACLK and both slots and on the HP
    port's ACLK; ARESETN on interconnect_aresetn, the slots' resets on peripheral_aresetn."""
    design = depth_bd if build == "depth" else bd
    (ctrl_in,) = design.connected(f"{PS7}/M_AXI_GP0")
    ctrl = ctrl_in.split("/")[0]
    clock = set(design.net_of(f"{PS7}/FCLK_CLK0"))
    interconnect_reset = set(design.net_of(f"{ctrl}/ARESETN"))
    peripheral_reset = set(design.net_of(f"{ctrl}/S00_ARESETN"))
    assert "rst_ps7_0/interconnect_aresetn" in interconnect_reset
    assert "rst_ps7_0/peripheral_aresetn" in peripheral_reset
    for hub, n in memory_ports(design).values():
        assert {f"{PS7}/S_AXI_HP{n}_ACLK", f"{hub}/ACLK", f"{hub}/S00_ACLK", f"{hub}/M00_ACLK"} <= clock, hub
        assert f"{hub}/ARESETN" in interconnect_reset, hub
        assert {f"{hub}/S00_ARESETN", f"{hub}/M00_ARESETN"} <= peripheral_reset, hub


@pytest.mark.parametrize("build", ["colour", "depth"])
def test_vdma_bursts_are_axi3_legal(build: str, bd: BlockDesign, depth_bd: BlockDesign) -> None:
    """The HP ports are AXI3: bursts of at most 16 beats (the VDMA's default is 8), set explicitly, so
    the interconnect's protocol converter passes every burst whole."""
    design = depth_bd if build == "depth" else bd
    for name, ch in memory_ports(design):
        assert design.config[name][f"c_{ch.lower()}_max_burst_length"] == "16", (name, ch)


def test_every_vdma_interrupt_reaches_irq_f2p_in_the_spec_order(bd: BlockDesign) -> None:
    introuts = {f"{name}/{ch.lower()}_introut"
                for name in ("vdma_raw", "vdma_proc") for ch in vdma_channels(bd, name)}
    assert introuts == {f"{cell}/{pin}" for cell, pin in overlay.INTERRUPTS}
    concat = [name for name, vlnv in bd.cells.items() if vlnv.startswith("xilinx.com:ip:xlconcat:")]
    assert len(concat) == 1
    inputs = []
    for cell, pin in overlay.INTERRUPTS:
        (other,) = [p for p in bd.net_of(f"{cell}/{pin}") if p != f"{cell}/{pin}"]
        assert other.startswith(concat[0] + "/In"), pin
        inputs.append(int(other.rsplit("In", 1)[1]))
    assert inputs == list(range(len(overlay.INTERRUPTS))), "In0.. in the order of overlay.INTERRUPTS"
    assert int(bd.config[concat[0]]["NUM_PORTS"]) == len(overlay.INTERRUPTS)
    assert set(bd.net_of(f"{concat[0]}/dout")) == {f"{concat[0]}/dout", f"{PS7}/IRQ_F2P"}
    assert bd.config[PS7]["PCW_USE_FABRIC_INTERRUPT"] == "1" and bd.config[PS7]["PCW_IRQ_F2P_INTR"] == "1"


def test_one_clock_runs_every_interface(bd: BlockDesign, variables: Dict[str, str]) -> None:
    clock = bd.net_of(f"{PS7}/FCLK_CLK0")
    assert hp_enabled(bd)
    expected = {f"{PS7}/M_AXI_GP0_ACLK", *(f"{PS7}/S_AXI_HP{n}_ACLK" for n in hp_enabled(bd)), "rectify/aclk",
                f"{camera_in.INSTANCE}/aclk", "mux/aclk", "mux/s_axi_ctrl_aclk",
                *(f"{gate}/aclk" for gate in frame_gate.INSTANCES)}
    (split_in,) = bd.connected(f"{camera_in.INSTANCE}/m_axis")
    expected.add(f"{split_in.split('/')[0]}/aclk")
    for name in ("vdma_raw", "vdma_proc"):
        expected.add(f"{name}/s_axi_lite_aclk")
        for ch in vdma_channels(bd, name):
            low = ch.lower()
            expected.add(f"{name}/m_axi_{low}_aclk")
            expected.add(f"{name}/{'s_axis_s2mm' if ch == 'S2MM' else 'm_axis_mm2s'}_aclk")
    assert expected <= set(clock), expected - set(clock)
    assert bd.config[PS7]["PCW_FPGA0_PERIPHERAL_FREQMHZ"] == variables["STEREOCAM_FCLK0_MHZ"]
    assert float(variables["STEREOCAM_FCLK0_MHZ"]) * 1e6 == overlay.FABRIC_CLOCK_HZ
    assert bd.config[PS7]["PCW_USE_M_AXI_GP0"] == "1"


def test_the_stream_clock_keeps_up_with_the_cameras() -> None:
    aclk = overlay.FABRIC_CLOCK_HZ
    assert aclk / rectify.CLOCKS_PER_BEAT >= mt9v034.PIXEL_CLOCK_HZ, "the core: a beat per pixel clock"
    # camera_in: aclk >= pclk * (WIDTH + LINE_OVERHEAD_CLOCKS) / (WIDTH + horizontal blanking), blanking >= 0
    width = camera_in.PARAMETERS["MAX_WIDTH"]
    overhead = getattr(camera_in, "LINE_OVERHEAD_CLOCKS", 0)
    assert aclk >= mt9v034.PIXEL_CLOCK_HZ * (width + overhead) / width


def test_every_core_reset_is_the_peripheral_reset(bd: BlockDesign) -> None:
    resets = [net for net in bd.nets if any(p.endswith("/peripheral_aresetn") for p in net)]
    assert len(resets) == 1
    pins = set(resets[0])
    assert {"rectify/aresetn", f"{camera_in.INSTANCE}/aresetn", "mux/aresetn", "vdma_raw/axi_resetn",
            "vdma_proc/axi_resetn", *(f"{gate}/aresetn" for gate in frame_gate.INSTANCES)} <= pins


# ---- addresses -------------------------------------------------------------------------------------------

def test_register_windows_are_the_address_map(bd: BlockDesign) -> None:
    windows = [a for a in bd.addresses if a.space == PS7_DATA]
    assert {a.segment.split("/")[0] for a in windows} == set(overlay.ADDRESS_MAP)
    assert len(windows) == len(overlay.ADDRESS_MAP)
    sizes = {"vdma_raw": vdma.VDMA_MAP.size, "vdma_proc": vdma.VDMA_MAP.size,
             "mux": axis_switch.AXIS_SWITCH_MAP.size, "rectify": rectify.RECTIFY_MAP.size}
    for a in windows:
        name = a.segment.split("/")[0]
        assert a.offset == overlay.ADDRESS_MAP[name], f"{name} at {a.offset:#x}"
        assert a.range == overlay.WINDOW_SIZE, f"{name} window {a.range:#x}"
        assert a.range >= sizes[name] and a.offset % a.range == 0
        assert GP0_RANGE[0] <= a.offset and a.offset + a.range <= GP0_RANGE[1]
    ends = sorted((a.offset, a.offset + a.range) for a in windows)
    assert all(e0 <= s1 for (_, e0), (s1, _) in zip(ends, ends[1:], strict=False)), "windows overlap"


def test_every_register_window_hangs_off_gp0(bd: BlockDesign) -> None:
    windows = [a for a in bd.addresses if a.space == PS7_DATA]
    (ctrl_in,) = bd.connected(f"{PS7}/M_AXI_GP0")
    ctrl = ctrl_in.split("/")[0]
    assert int(bd.config[ctrl]["NUM_MI"]) == len(windows)
    masters = set()
    for a in windows:
        cell, busif, _ = a.segment.split("/")
        (port,) = bd.connected(f"{cell}/{busif}")
        masters.add(port)
    assert masters == {f"{ctrl}/M{i:02d}_AXI" for i in range(len(windows))}


def test_rectify_segment_is_the_packaged_register_block(bd: BlockDesign,
                                                        packaged: Dict[str, PackagedIP]) -> None:
    (segment,) = [a.segment for a in bd.addresses if a.segment.startswith("rectify/")]
    (lite,) = packaged[rectify.VLNV].windows
    assert segment == f"rectify/{lite}/reg0"
    assert "add_address_block reg0" in read_script("package_ip.tcl")


# ---- camera pins and constraints --------------------------------------------------------------------------

def camera_pins() -> Dict[str, Tuple[str, int]]:
    return {n: p for n, p in camera_in.PORTS.items() if n.split("_")[0] in camera_in.CAMERAS}


def test_camera_pins_are_external_ports_wired_to_the_camera_ip(bd: BlockDesign) -> None:
    assert set(bd.ports) == set(camera_pins())
    for name, (direction, width) in camera_pins().items():
        opts = bd.ports[name]
        assert opts["-dir"] == {"input": "I", "output": "O"}[direction], name
        got = int(opts["-from"]) - int(opts["-to"]) + 1 if "-from" in opts else 1
        assert got == width, name
        assert set(bd.net_of(name)) == {name, f"{camera_in.INSTANCE}/{name}"}
        if name.endswith("_pclk"):
            assert opts["-type"] == "clk" and int(opts["-freq_hz"]) >= mt9v034.PIXEL_CLOCK_HZ


def test_xdc_clocks_the_pixel_clocks_and_leaves_the_pins_to_the_pin_map(bd: BlockDesign) -> None:
    xdc = tcl_commands(read_script("stereocam.xdc"))
    clocks: Dict[str, float] = {}
    for words in xdc:
        assert "PACKAGE_PIN" not in " ".join(words), "pins are the board's pin map's, not the xdc's"
        if words[0] == "create_clock":
            opts, rest = options(words[1:], {"-period", "-name"})
            (port,) = bracketed(rest[-1])[1:]
            clocks[port] = float(opts["-period"])
    pclks = {n for n in camera_pins() if n.endswith("_pclk")}
    assert set(clocks) == pclks
    for port, period in clocks.items():
        assert period <= 1e9 / mt9v034.PIXEL_CLOCK_HZ, port
        assert period == pytest.approx(1e9 / int(bd.ports[port]["-freq_hz"]), abs=1e-3), port


# ---- the sensors' I2C, and the board's pin map -----------------------------------------------------------

IIC_VLNV = "xilinx.com:interface:iic_rtl:1.0"
PINS_DIR = VIVADO_DIR / "pins"


def read_pin_map(text: str) -> Dict[str, Tuple[str, str, Dict[str, str]]]:
    """A pin map as build.tcl reads it: port -> (package pin, I/O standard, other properties)."""
    entries: Dict[str, Tuple[str, str, Dict[str, str]]] = {}
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        assert len(words) >= 3, f"line {number}: {line}"
        props = dict(w.split("=", 1) for w in words[3:])
        assert words[0] not in entries, f"line {number}: {words[0]} placed twice"
        entries[words[0]] = (words[1], words[2], props)
    return entries


def external_port_bits(bd: BlockDesign) -> Set[str]:
    """Every bit of the design's external ports as the wrapper names it (an IIC interface: its IOBUFs)."""
    bits = {f"{name}[{i}]" if "-from" in opts else name
            for name, opts in bd.ports.items()
            for i in range(int(opts.get("-to", 0)), int(opts.get("-from", 0)) + 1)}
    for name, opts in bd.intf_ports.items():
        assert opts["-vlnv"] == IIC_VLNV, f"{name}: the wrapper's pins of {opts['-vlnv']} are not known here"
        bits |= {f"{name}_scl_io", f"{name}_sda_io"}
    return bits


def test_the_ps7_i2c0_reaches_the_sensors_through_emio(bd: BlockDesign) -> None:
    ps7 = bd.config[PS7]
    controller = overlay.SENSOR_I2C_CONTROLLER
    assert ps7[f"PCW_{controller}_PERIPHERAL_ENABLE"] == "1"
    assert ps7[f"PCW_{controller}_{controller}_IO"] == "EMIO", "the sensors hang off the PL's pins"
    port = overlay.SENSOR_I2C_PORT
    assert bd.intf_ports[port] == {"-mode": "Master", "-vlnv": IIC_VLNV}
    assert bd.connected(port) == {f"{PS7}/IIC_{controller[-1]}"}


def test_the_board_profile_opens_the_bus_the_overlay_wires() -> None:
    board = load_profile()
    assert board.i2c_bus == overlay.SENSOR_I2C_BUS
    assert board.i2c_device == f"/dev/i2c-{overlay.SENSOR_I2C_BUS}"
    assert {board.left_address, board.right_address} <= set(mt9v034.I2C_ADDRESSES)
    assert board.left_address != board.right_address, "both sensors share the bus: two addresses"
    assert (PINS_DIR / f"{board.name}{overlay.PIN_MAP_SUFFIX}").is_file(), "the board's pin map"


def test_the_pin_map_places_every_external_port_bit_and_nothing_else(
        bd: BlockDesign, variables: Dict[str, str]) -> None:
    path = PINS_DIR / f"{variables['STEREOCAM_BOARD']}{overlay.PIN_MAP_SUFFIX}"
    pins = read_pin_map(path.read_text())
    assert set(pins) == external_port_bits(bd)
    assert {pin for pin, _, _ in pins.values()} == {overlay.PIN_PLACEHOLDER}, "the user fills them in"
    for port, (_, standard, props) in pins.items():
        assert standard.startswith("LVCMOS"), port
        if port.startswith(overlay.SENSOR_I2C_PORT):
            assert props == {"PULLUP": "true"}, port
    assert variables["STEREOCAM_BOARD"] == load_profile().name


def test_xdc_bounds_every_crossing_and_groups_no_clocks(variables: Dict[str, str]) -> None:
    """Issue 22 item 2: no asynchronous clock groups (which leave the crossings untimed); each pixel
    clock <-> FCLK_CLK0 direction has a data-path-only max delay of at most the destination's period,
    and the multi-bit crossings of camera_in's RTL a bus skew bound of at most one FCLK_CLK0 period."""
    xdc = tcl_commands(read_script("stereocam.xdc"))
    assert not [w for w in xdc if w[0] == "set_clock_groups"]
    fclk_ns = 1e3 / float(variables["STEREOCAM_FCLK0_MHZ"])
    periods = {"clk_fpga_0": fclk_ns}
    delays: Dict[Tuple[str, str], float] = {}
    skews: List[Tuple[str, str, float]] = []
    for words in xdc:
        if words[0] == "create_clock":
            opts, _ = options(words[1:], {"-period", "-name"})
            periods[opts["-name"]] = float(opts["-period"])
        elif words[0] == "set_max_delay":
            opts, rest = options(words[1:], {"-from", "-to"})
            assert "-datapath_only" in opts, words
            (src,) = bracketed(opts["-from"])[1:]
            (dst,) = bracketed(opts["-to"])[1:]
            delays[(src, dst)] = float(rest[-1])
        elif words[0] == "set_bus_skew":
            opts, rest = options(words[1:], {"-from", "-to"})
            patterns = []
            for end in ("-from", "-to"):
                cmd = bracketed(opts[end])
                assert cmd[:3] == ["get_cells", "-hier", "-filter"], words
                patterns.append(re.fullmatch(r"NAME =~ (\S+)", cmd[3]).group(1))  # type: ignore[union-attr]
            skews.append((patterns[0], patterns[1], float(rest[-1])))
    pclks = [name for name in periods if name != "clk_fpga_0"]
    assert len(pclks) == 2
    for pclk in pclks:
        for src, dst in ((pclk, "clk_fpga_0"), ("clk_fpga_0", pclk)):
            assert (src, dst) in delays, f"no set_max_delay -datapath_only from {src} to {dst}"
            assert 0 < delays[(src, dst)] <= min(periods[dst], periods[src]) + 1e-9, (src, dst)
    assert set(delays) == {(p, "clk_fpga_0") for p in pclks} | {("clk_fpga_0", p) for p in pclks}
    # the buses the RTL crosses (ci_lfifo: wgray_reg, rhold_reg; camera_in: tag_gray_reg), both cameras
    rtl = "".join((RTL_DIR / "camera" / f).read_text() for f in ("ci_lfifo.v", "camera_in.v", "ci_rx.v"))
    wanted = {(f"fifo{i}_inst/{reg}", f"fifo{i}_inst/{sync}")
              for i in (0, 1) for reg, sync in (("wgray_reg", "wsync_inst"), ("rhold_reg", "rsync_inst"))}
    wanted |= {("tag_gray_reg", f"rx{i}_inst/tag_sync_inst") for i in (0, 1)}
    found = set()
    for src, dst, skew in skews:
        assert 0 < skew <= fclk_ns + 1e-9, (src, dst)
        assert dst.endswith("/meta_reg_reg[*]"), dst
        for a, b in wanted:
            if a in src and b in dst:
                found.add((a, b))
        for name in re.findall(r"(\w+)_reg\[\*\]$", src) + re.findall(r"/(\w+_inst)/", src + dst):
            assert name in rtl, f"{name} of the xdc is not in camera_in's RTL"
    assert found == wanted


# ---- settings, outputs, documentation ---------------------------------------------------------------------

def test_settings_name_the_overlay_files_the_backend_looks_for(variables: Dict[str, str]) -> None:
    assert variables["STEREOCAM_OVERLAY"] + ".bit" == overlay.BITSTREAM
    assert variables["STEREOCAM_PART"] in (VIVADO_DIR / "README.md").read_text()


def test_one_vivado_version_is_named_everywhere(variables: Dict[str, str]) -> None:
    version = variables["STEREOCAM_VIVADO_VERSION"]
    assert re.fullmatch(r"20\d\d\.\d", version)
    for path in sorted(VIVADO_DIR.iterdir()):
        if path.is_file():
            named = set(re.findall(r"\b20[12]\d\.\d\b", path.read_text()))
            assert named <= {version}, f"{path.name} names Vivado {named - {version}}"
    assert version in (VIVADO_DIR / "README.md").read_text()
    assert version in (VIVADO_DIR / "build.sh").read_text()


def test_readme_states_the_address_map_and_that_nothing_was_built(variables: Dict[str, str]) -> None:
    text = (VIVADO_DIR / "README.md").read_text()
    for name, base in overlay.ADDRESS_MAP.items():
        assert re.search(rf"`{name}`.*0x{base:08X}", text, re.I), f"README: {name} at 0x{base:08X}"
    assert "has not yet been built or run on a board" in text
    assert frame_gate.VLNV in text
    for gate in frame_gate.INSTANCES:
        assert f"`{gate}`" in text, f"README does not describe {gate}"
    assert "placeholder" in text and "FILL_IN" in text
    for script in (*SCRIPTS, "build.sh", "stereocam.xdc"):
        assert f"`{script}`" in text, f"README does not describe {script}"


def test_scripts_keep_lines_short() -> None:
    for path in sorted(VIVADO_DIR.iterdir()):
        if path.is_file():
            for number, line in enumerate(path.read_text().splitlines(), 1):
                assert len(line) <= 120, f"{path.name}:{number} is {len(line)} characters"


# ---- the drivers bind to what the design builds --------------------------------------------------------

def test_the_drivers_bind_to_the_block_design(bd: BlockDesign) -> None:
    """The ip_dict pynq would read from this design's .hwh, handed to the real bind() over emulated IP."""
    ip_dict = {}
    for a in (a for a in bd.addresses if a.space == PS7_DATA):
        name = a.segment.split("/")[0]
        cfg = bd.config.get(name, {})
        parameters = {"C_NUM_FSTORES": cfg.get("c_num_fstores", ""), "NUM_SI": cfg.get("NUM_SI", "")}
        ip_dict[name] = {"phys_addr": a.offset, "addr_range": a.range, "type": bd.cells[name],
                         "parameters": {k: v for k, v in parameters.items() if v}}
    hw = EmulatedFabric(clock="stepped", num_fstores=int(bd.config["vdma_raw"]["c_num_fstores"]))
    by_address = {overlay.ADDRESS_MAP[name]: block for name, block in hw.blocks.items()}

    def open_window(address: int, length: int) -> "RegisterBlock | StreamCore":
        if address not in by_address:
            raise EmulationError(f"no IP at {address:#x}")
        block = by_address[address]
        assert isinstance(block, RegisterBlock) and length >= block.map.size
        return block

    try:
        fabric = bind(ip_dict, open_window, hw.ddr.allocate, backend="emulated", frame_size=hw.frame_size)
        assert fabric.raw_vdma.num_fstores == fabric.proc_vdma.num_fstores == overlay.NUM_FSTORES
        assert fabric.mux.inputs == axis_switch.NUM_INPUTS
        fabric.close()
    finally:
        hw.close()


@pytest.fixture
def rtl_copy(tmp_path: Path) -> Path:
    """The RTL folder as package_ip.tcl reads it, with a stand-in camera top until the real one exists."""
    rtl = tmp_path / "rtl"
    (rtl / "camera").mkdir(parents=True)
    for path in RTL_DIR.iterdir():
        if path.is_file():
            (rtl / path.name).symlink_to(path)
    cams = sorted((RTL_DIR / "camera").glob("*.v")) if (RTL_DIR / "camera").is_dir() else []
    for path in [*cams, *sorted((RTL_DIR / "camera").glob("*.vh"))]:
        (rtl / "camera" / path.name).symlink_to(path)
    if not cams:
        (rtl / "camera" / "camera_in.v").write_text(f"module {camera_in.TOP}; endmodule\n")
    (rtl / "stereo").mkdir()
    for path in sorted((RTL_DIR / "stereo").iterdir()):
        (rtl / "stereo" / path.name).symlink_to(path)
    return rtl


def _fake_vivado_outputs(proj: Path, variables: Dict[str, str]) -> Tuple[Path, Path]:
    """The bitstream and handoff impl_1 and the block design would leave in the project."""
    bd_name = variables["STEREOCAM_BD_NAME"]
    bit = proj / f"{bd_name}.runs" / "impl_1" / f"{bd_name}_wrapper.bit"
    hwh = proj / f"{bd_name}.gen" / "sources_1" / "bd" / bd_name / "hw_handoff" / f"{bd_name}.hwh"
    for path, data in ((bit, "bitstream"), (hwh, "<MODULES/>")):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(data)
    return bit, hwh


def _filled_pins(tmp_path: Path) -> Tuple[Path, Dict[str, str]]:
    """A copy of the board's pin map with a made-up pin per port, and what it places where."""
    text = (PINS_DIR / "zynq-stereo.pins").read_text()
    lines, placed = [], {}
    for line in text.splitlines():
        words = line.split()
        if words and not words[0].startswith("#"):
            placed[words[0]] = f"P{len(placed)}"
            line = line.replace(overlay.PIN_PLACEHOLDER, placed[words[0]])
        lines.append(line)
    path = tmp_path / "board.pins"
    path.write_text("\n".join(lines) + "\n")
    return path, placed


def test_build_tcl_runs_the_whole_flow_and_leaves_the_overlay_where_pynq_looks(
        tmp_path: Path, rtl_copy: Path, variables: Dict[str, str], bd: BlockDesign,
        monkeypatch: pytest.MonkeyPatch) -> None:
    proj, out = tmp_path / "proj", tmp_path / "out"
    bit, hwh = _fake_vivado_outputs(proj, variables)
    pins, placed = _filled_pins(tmp_path)
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, preset={"STEREOCAM_RTL_DIR": str(rtl_copy)},
                  argv=["-out", str(out), "--proj", str(proj), "-pins", str(pins), "-jobs", "1"])
    assert run.error == ""
    # the packaged IP
    assert run.projects() == ["pkg_rectify", "pkg_camera_in", "pkg_frame_gate", "pkg_stereo",
                              variables["STEREOCAM_BD_NAME"]]
    packaged_rtl = [{Path(p).name for p in tcl_list(c[-1])} for c in run.of("add_files")[:4]]
    assert packaged_rtl[0] == {p.name for p in RTL_DIR.iterdir() if p.suffix in (".v", ".vh")}
    camera = {p.name for p in (RTL_DIR / "camera").iterdir() if p.suffix in (".v", ".vh")}
    # the rectify core's RAM and FIFO, used by both camera IPs and the stereo IP, and the prelude all include
    shared = {"rc_ram.v", "rc_fifo.v", "prelude.vh"}
    assert packaged_rtl[1] == camera - {f"{frame_gate.TOP}.v"} | shared | {"rc_gray.v"}, \
        "camera_in: its top, ci_*.v, headers, and the rectify core's gray"
    assert packaged_rtl[2] == {Path(name).name for name in frame_gate.SOURCES}
    assert packaged_rtl[3] == {p.name for p in (RTL_DIR / "stereo").iterdir()} | shared
    names = [c[1] for c in run.of("set_property") if c[0] in ("name", "version") and c[-1] == "core"]
    cores = (rectify, camera_in, frame_gate, stereo)
    assert names == [part for ip in cores for part in ip.VLNV.split(":")[2:]]
    # the block design as the text says
    assert {c[-1]: c[c.index("-vlnv") + 1] for c in run.of("create_bd_cell")} == bd.cells
    recorded: Dict[str, Dict[str, str]] = {}
    for c in run.of("set_property"):
        if c[0] == "-dict" and c[-1] in bd.cells:
            pairs = tcl_list(c[1])
            recorded.setdefault(c[-1], {}).update(
                (k[len("CONFIG."):], v) for k, v in zip(pairs[::2], pairs[1::2], strict=True))
    assert recorded == bd.config
    assigned = [(c[c.index("-target_address_space") + 1], c[-2], int(c[c.index("-offset") + 1], 0))
                for c in run.of("assign_bd_address")]
    assert assigned == [(a.space, a.segment, a.offset) for a in bd.addresses]
    # the flow
    verbs = [c[0] for c in run.calls]
    order = ["validate_bd_design", "make_wrapper", "launch_runs", "wait_on_run", "launch_runs", "wait_on_run"]
    assert [v for v in verbs if v in order] == order
    assert run.of("launch_runs")[1][:3] == ["impl_1", "-to_step", "write_bitstream"]
    assert ["-fileset", "constrs_1", "-norecurse", str(VIVADO_DIR / "stereocam.xdc")] in run.of("add_files")
    pins_xdc = proj / "pins.xdc"
    assert ["-fileset", "constrs_1", "-norecurse", str(pins_xdc)] in run.of("add_files")
    written: Dict[str, str] = {}
    for words in tcl_commands(pins_xdc.read_text()):
        assert words[:2] == ["set_property", "-dict"], words
        values = tcl_list(words[2])
        props = dict(zip(values[::2], values[1::2], strict=True))
        (port,) = tcl_list(bracketed(words[3])[1])
        written[port] = props["PACKAGE_PIN"]
        assert props["IOSTANDARD"] == "LVCMOS33", port
        assert props.get("PULLUP") == ("true" if port.startswith(overlay.SENSOR_I2C_PORT) else None), port
    assert written == placed
    # the outputs, found by the backend's own search
    assert (out / overlay.BITSTREAM).read_text() == bit.read_text()
    assert (out / overlay.BITSTREAM).with_suffix(".hwh").read_text() == hwh.read_text()
    # the routed timing summary beside the bitstream, of the run that was opened
    assert run.of("open_run") == [["impl_1"]]
    summary = (out / overlay.BITSTREAM).with_suffix(".timing.rpt").read_text()
    assert summary.startswith("Timing summary: WNS 0.412")
    assert [c[c.index("-delay_type") + 1] for c in run.of("get_timing_paths")] == ["max", "min"]
    monkeypatch.delenv("STEREOCAM_BITSTREAM", raising=False)
    monkeypatch.setattr(backend, "DEFAULT_BITSTREAM_DIRS", (out,))
    assert backend.find_bitstream() == out / overlay.BITSTREAM


def test_build_tcl_writes_into_the_checkouts_overlays_folder(tmp_path: Path, rtl_copy: Path) -> None:
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=["-to", "package", "-proj", str(tmp_path / "p")],
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy)}, read=["stereocam_out"])
    assert run.error == ""
    assert Path(run.variables["stereocam_out"]) == REPO_ROOT / "stereocam" / "overlays"
    # backend.py's first folder is its own (the installed stereocam/overlays/ package, this folder in a
    # checkout)
    assert backend.DEFAULT_BITSTREAM_DIRS[0] == Path(backend.__file__).parent
    assert (REPO_ROOT / "stereocam" / "overlays" / Path(backend.__file__).name).is_file()
    assert "launch_runs" not in [c[0] for c in run.calls], "-to package stops after packaging"


def test_build_tcl_refuses_placeholder_pins_naming_them_except_for_synthesis(
        tmp_path: Path, rtl_copy: Path, bd: BlockDesign) -> None:
    common = ["-out", str(tmp_path / "out"), "-proj", str(tmp_path / "p")]
    preset = {"STEREOCAM_RTL_DIR": str(rtl_copy)}
    refused = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=common, preset=preset)
    assert "still has placeholder pins (FILL_IN)" in refused.error
    named = refused.error.split(" ports: ", 1)[1].split(". Fill in", 1)[0]
    assert set(named.split(", ")) == external_port_bits(bd)
    assert not refused.projects(), "refused before any work"
    # one line left: only that port is named
    pins, _ = _filled_pins(tmp_path)
    pins.write_text(pins.read_text().replace("cam1_frame_valid    P25", "cam1_frame_valid    FILL_IN"))
    one = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=[*common, "-pins", str(pins)], preset=preset)
    assert "for 1 ports: cam1_frame_valid." in one.error
    synth = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=[*common, "-to", "synth"], preset=preset)
    assert synth.error == ""
    assert [c[0] for c in synth.of("launch_runs")] == ["synth_1"]
    assert [c for c in synth.of("add_files") if "constrs_1" in c] == [
        ["-fileset", "constrs_1", "-norecurse", str(VIVADO_DIR / "stereocam.xdc")]], "timing, no pins"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("line, message", [
    ("cam0_pclk Y18", "line 2: expected 'port package_pin iostandard"),
    ("cam0_pclk Y18 LVCMOS33 PULLUP", "line 2: 'PULLUP' is not a NAME=value property"),
])
def test_build_tcl_names_a_malformed_pin_map_line(tmp_path: Path, line: str, message: str) -> None:
    pins = tmp_path / "bad.pins"
    pins.write_text(f"# a board\n{line}\n")
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=["-pins", str(pins), "-proj", str(tmp_path / "p")])
    assert f"{pins} {message}" in run.error


@pytest.mark.parametrize("argv, message", [
    (["-bogus", "1"], "unknown option '-bogus'"),
    (["-to"], "option '-to' needs a value"),
    (["-to", "everything"], "-to must be one of package, bd, synth, impl, bit"),
    (["-jobs", "0"], "-jobs must be a positive number"),
])
def test_build_tcl_rejects_bad_options(tmp_path: Path, argv: List[str], message: str) -> None:
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=argv)
    assert message in run.error
    assert run.calls == [], "options are checked before Vivado is asked anything"


def test_package_ip_refuses_a_missing_camera_rtl(tmp_path: Path, rtl_copy: Path) -> None:
    for path in (rtl_copy / "camera").iterdir():
        path.unlink()
    run = run_tcl(VIVADO_DIR / "package_ip.tcl", tmp_path, argv=[str(tmp_path / "repo")],
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy)}, read=["STEREOCAM_IP_REPO"])
    assert "no camera input RTL" in run.error
    assert run.variables["STEREOCAM_IP_REPO"] == str(tmp_path / "repo")
    assert run.projects() == ["pkg_rectify"], "the rectify core was packaged before"


def test_package_ip_refuses_a_missing_frame_gate_rtl(tmp_path: Path, rtl_copy: Path) -> None:
    (rtl_copy / "camera" / f"{frame_gate.TOP}.v").unlink()
    run = run_tcl(VIVADO_DIR / "package_ip.tcl", tmp_path, argv=[str(tmp_path / "repo")],
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy)})
    assert f"no {frame_gate.TOP}.v in" in run.error and "frame_gate IP cannot be packaged" in run.error
    assert run.projects() == ["pkg_rectify", "pkg_camera_in"], "the other cores were packaged before"


# ---- the stubbed Vivado checks what real Vivado would refuse ----------------------------------------------

def vivado_copy(tmp_path: Path, script: str, old: str, new: str) -> Path:
    """A copy of the scripts' folder with ``old`` replaced by ``new`` (once) in ``script``."""
    folder = tmp_path / "vivado"
    shutil.copytree(VIVADO_DIR, folder, ignore=shutil.ignore_patterns("build"))
    path = folder / script
    text = path.read_text()
    assert text.count(old) >= 1, f"{old!r} is not in {script}"
    path.write_text(text.replace(old, new, 1))
    return folder


def build_run(tmp_path: Path, folder: Path, rtl: Path) -> TclRun:
    """build.tcl of ``folder`` through the block design, in the stubbed Vivado."""
    return run_tcl(folder / "build.tcl", tmp_path, argv=["-to", "bd", "-proj", str(tmp_path / "p")],
                   preset={"STEREOCAM_RTL_DIR": str(rtl)})


def test_the_scripts_as_they_are_pass_the_stubbed_vivado(tmp_path: Path, rtl_copy: Path) -> None:
    run = build_run(tmp_path, vivado_copy(tmp_path, "settings.tcl", "", ""), rtl_copy)
    assert run.error == ""
    assert set(run.design.cells) >= set(overlay.INSTANCES)
    assert set(run.packaged) == {rectify.VLNV, camera_in.VLNV, frame_gate.VLNV, stereo.VLNV}
    # the register window and the user parameters come from the spec (through ip_params.tcl)
    rect = run.packaged[rectify.VLNV]
    assert rect.ranges == {"s_axil/reg0": rectify.RECTIFY_MAP.size}
    declared = rect.registers["s_axil/reg0"]
    assert {n: int(r["address_offset"], 0) for n, r in declared.items()} == {
        reg.name: reg.offset for reg in rectify.RECTIFY_MAP}
    assert {n: int(r["reset_value"], 0) for n, r in declared.items()} == {
        reg.name: reg.reset for reg in rectify.RECTIFY_MAP}
    build = rectify.DEFAULT_BUILD
    defaults = {"MAX_WIDTH": build.max_width, "MAX_HEIGHT": build.max_height, "LB_ROWS": build.lb_rows,
                "COLOUR": int(build.colour)}
    assert {n: (int(p.default), p.low, p.high) for n, p in rect.params.items()} == {
        n: (defaults[n], *limits) for n, limits in rectify.BUILD_LIMITS.items()}
    gate = run.packaged[frame_gate.VLNV].params["DEPTH"]
    assert (int(gate.default), gate.low, gate.high) == (
        frame_gate.PARAMETERS["DEPTH"], *frame_gate.DEPTH_RANGE)
    assert {n: int(p.default) for n, p in run.packaged[camera_in.VLNV].params.items()} == camera_in.PARAMETERS


@pytest.mark.parametrize("script, old, new, message", [
    ("block_design.tcl", "xilinx.com:ip:axi_interconnect:2.1 axi_mem_raw",
     "xilinx.com:ip:axi_interconnect:9.9 axi_mem_raw",
     "IP definition not found for VLNV xilinx.com:ip:axi_interconnect:9.9: Vivado 2022.1 has "
     "xilinx.com:ip:axi_interconnect:2.1"),
    ("block_design.tcl", "CONFIG.PCW_USE_S_AXI_HP1 {1}", "CONFIG.PCW_USE_S_AXI_HP1 {0}",
     "get_bd_intf_pins: processing_system7_0 (xilinx.com:ip:processing_system7:5.5) has no interface "
     "'S_AXI_HP1'"),
    ("block_design.tcl", "CONFIG.PCW_S_AXI_HP2_DATA_WIDTH {64}", "CONFIG.PCW_S_AXI_HP2_DATA_WIDTH {128}",
     "set_property CONFIG.PCW_S_AXI_HP2_DATA_WIDTH on processing_system7_0 "
     "(xilinx.com:ip:processing_system7:5.5): '128' is not one of 32, 64"),
    ("block_design.tcl", "xilinx.com:ip:proc_sys_reset:5.0", "xilinx.com:ip:proc_sys_reset:0.1",
     "IP definition not found for VLNV xilinx.com:ip:proc_sys_reset:0.1"),
    ("block_design.tcl", "CONFIG.HAS_TKEEP {0}", "CONFIG.HAS_TKEEPZ {0}",
     "set_property CONFIG.HAS_TKEEPZ on camera_split (xilinx.com:ip:axis_broadcaster:1.1): "
     "xilinx.com:ip:axis_broadcaster:1.1 has no parameter HAS_TKEEPZ (PG085"),
    ("block_design.tcl", "CONFIG.c_s2mm_max_burst_length {16}", "CONFIG.c_s2mm_max_burst_length {999}",
     "set_property CONFIG.c_s2mm_max_burst_length on vdma_raw (xilinx.com:ip:axi_vdma:6.3): '999' is not one "
     "of 2, 4, 8, 16, 32, 64, 128, 256 (PG020"),
    ("block_design.tcl", "CONFIG.NUM_MI {4}", "CONFIG.NUM_MI {65}",
     "set_property CONFIG.NUM_MI on axi_ctrl (xilinx.com:ip:axi_interconnect:2.1): 65 is outside 1..64"),
    ("block_design.tcl", "stereocam:user:rectify:2.0 rectify", "stereocam:user:rectify:1.0 rectify",
     "IP definition not found for VLNV stereocam:user:rectify:1.0: not in Vivado 2022.1's catalog, and "
     "package_ip.tcl packaged stereocam:user:camera_in:1.0, stereocam:user:frame_gate:1.0, "
     "stereocam:user:rectify:2.0"),
    ("package_ip.tcl", "set_property version 1.0 $core\nset_property display_name {stereocam camera input}",
     "set_property version 1.1 $core\nset_property display_name {stereocam camera input}",
     "IP definition not found for VLNV stereocam:user:camera_in:1.0"),
    ("block_design.tcl", "CONFIG.DEPTH {1024} \\\n] [get_bd_cells gate_raw]",
     "CONFIG.DEPTH {8} \\\n] [get_bd_cells gate_raw]",
     "set_property CONFIG.DEPTH on gate_raw (stereocam:user:frame_gate:1.0): 8 is outside 16..32768"),
    ("block_design.tcl", "[get_bd_pins vdma_raw/s2mm_introut]", "[get_bd_pins vdma_raw/mm2s_introut]",
     "get_bd_pins: vdma_raw (xilinx.com:ip:axi_vdma:6.3) has no pin 'mm2s_introut' in its configuration"),
    ("block_design.tcl", "[get_bd_pins camera_in/cam1_line_valid]", "[get_bd_pins camera_in/cam1_lv]",
     "get_bd_pins: camera_in (stereocam:user:camera_in:1.0) has no pin 'cam1_lv'"),
    ("block_design.tcl", "[get_bd_intf_pins axi_ctrl/M03_AXI]", "[get_bd_intf_pins axi_ctrl/M04_AXI]",
     "get_bd_intf_pins: axi_ctrl (xilinx.com:ip:axi_interconnect:2.1) has no interface 'M04_AXI'"),
    ("block_design.tcl", "CONFIG.ROUTING_MODE {1}", "CONFIG.ROUTING_MODE {0}",
     "get_bd_intf_pins: mux (xilinx.com:ip:axis_switch:1.1) has no interface 'S_AXI_CTRL'"),
    ("block_design.tcl", "[get_bd_addr_segs rectify/s_axil/reg0]", "[get_bd_addr_segs rectify/s_axil/Reg]",
     "get_bd_addr_segs: rectify (stereocam:user:rectify:2.0) has no address segment 's_axil/Reg' "
     "in its configuration (segments: s_axil/reg0;"),
    ("block_design.tcl", "CONFIG.PCW_I2C0_I2C0_IO {EMIO}", "CONFIG.PCW_I2C0_I2C0_IO {MIO 10 .. 11}",
     "get_bd_intf_pins: processing_system7_0 (xilinx.com:ip:processing_system7:5.5) has no interface "
     "'IIC_0'"),
])
def test_the_stubbed_vivado_stops_on_what_vivado_would_refuse(tmp_path: Path, rtl_copy: Path, script: str,
                                                                old: str, new: str, message: str) -> None:
    run = build_run(tmp_path, vivado_copy(tmp_path, script, old, new), rtl_copy)
    assert message in run.error
    assert run.calls[-1][0] in ("create_bd_cell", "set_property", "get_bd_pins", "get_bd_intf_pins",
                                "get_bd_addr_segs"), "Vivado stops at the failing command"


@pytest.mark.parametrize("kind, slack", [("max", "-0.031"), ("min", "-0.002")])
def test_build_tcl_stops_on_negative_routed_slack_and_writes_no_overlay(
        tmp_path: Path, rtl_copy: Path, variables: Dict[str, str], kind: str, slack: str) -> None:
    """A negative WNS (setup) or WHS (hold) stops the build, naming the slack and the report: no .bit."""
    proj, out = tmp_path / "proj", tmp_path / "out"
    _fake_vivado_outputs(proj, variables)
    pins, _ = _filled_pins(tmp_path)
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path,
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy), f"stereocam_fake_slack(timing_{kind})": slack},
                  argv=["-out", str(out), "--proj", str(proj), "-pins", str(pins), "-jobs", "1"])
    name = {"max": "WNS", "min": "WHS"}[kind]
    assert f"routed timing fails: {name} {slack} ns" in run.error
    runs = proj / f"{variables['STEREOCAM_BD_NAME']}.runs"
    report = runs / "impl_1" / f"{variables['STEREOCAM_OVERLAY']}.timing.rpt"
    assert str(report) in run.error and report.is_file()
    assert not (out / overlay.BITSTREAM).exists()


# ---- the depth build: the stereo core and its VDMA (build.tcl -build depth) --------------------------------

def test_the_builds_are_the_ones_build_tcl_offers(variables: Dict[str, str]) -> None:
    assert tcl_list(variables["STEREOCAM_BUILDS"]) == ["colour", "depth"]
    assert "build colour" in read_script("build.tcl"), "the default build is today's overlay"


def test_the_depth_build_adds_the_optional_instances_and_nothing_else_changes_name(
        bd: BlockDesign, depth_bd: BlockDesign) -> None:
    for name, accepted in overlay.OPTIONAL_INSTANCES.items():
        assert name not in bd.cells, f"the colour build has {name}"
        assert depth_bd.cells.get(name) in accepted, f"{name}: {depth_bd.cells.get(name)}, not in {accepted}"
    assert depth_bd.cells[overlay.STEREO] == stereo.VLNV
    added = set(depth_bd.cells) - set(bd.cells)
    depth_memory, _ = hp_port(depth_bd, f"{overlay.DEPTH_VDMA}/M_AXI_S2MM")
    assert added == set(overlay.OPTIONAL_INSTANCES) | {"rectified_split", depth_memory}
    assert all(depth_bd.cells[name] == vlnv for name, vlnv in bd.cells.items())
    # the gray rectify core: the colour one's block RAM and the stereo core's do not fit together
    assert int(depth_bd.config["rectify"]["COLOUR"]) == int(rectify.BUILDS["gray"].colour) == 0
    user_cells = {vlnv for vlnv in depth_bd.cells.values() if not vlnv.startswith("xilinx.com:")}
    assert stereo.VLNV in user_cells


def test_depth_register_windows_are_both_address_maps(depth_bd: BlockDesign) -> None:
    windows = {a.segment.split("/")[0]: a for a in depth_bd.addresses if a.space == PS7_DATA}
    expected = {**overlay.ADDRESS_MAP, **overlay.OPTIONAL_ADDRESS_MAP}
    assert {name: a.offset for name, a in windows.items()} == expected
    assert windows[overlay.STEREO].segment == f"{overlay.STEREO}/s_axil/reg0"
    assert windows[overlay.STEREO].range >= stereo.STEREO_MAP.size
    assert windows[overlay.DEPTH_VDMA].range >= vdma.VDMA_MAP.size
    for a in windows.values():
        assert a.range == overlay.WINDOW_SIZE and a.offset % a.range == 0
        assert GP0_RANGE[0] <= a.offset and a.offset + a.range <= GP0_RANGE[1]
    ends = sorted((a.offset, a.offset + a.range) for a in windows.values())
    assert all(e0 <= s1 for (_, e0), (s1, _) in zip(ends, ends[1:], strict=False)), "windows overlap"


@pytest.mark.parametrize("build", ["colour", "depth"])
def test_every_register_port_of_the_interconnect_reaches_one_window(build: str, bd: BlockDesign,
                                                                     depth_bd: BlockDesign) -> None:
    design = depth_bd if build == "depth" else bd
    (ctrl,) = design.connected(f"{PS7}/M_AXI_GP0")
    hub = ctrl.split("/")[0]
    slaves = {design.address(PS7_DATA, a.segment).segment.split("/")[0]
              for a in design.addresses if a.space == PS7_DATA}
    ports = int(design.config[hub]["NUM_MI"])
    assert ports == len(slaves)
    reached = set()
    for i in range(ports):
        (slave,) = design.connected(f"{hub}/M{i:02d}_AXI")
        reached.add(slave.split("/")[0])
        assert {f"{hub}/M{i:02d}_ACLK"} <= set(design.net_of(f"{PS7}/FCLK_CLK0")), i
    assert reached == slaves


def test_depth_stream_graph_splits_the_rectified_stream_to_the_stereo_core(bd: BlockDesign,
                                                                           depth_bd: BlockDesign) -> None:
    """rectify -> rectified_split: M00 -> vdma_proc S2MM as before, M01 -> stereo -> vdma_depth S2MM;
    every other stream connection as in the colour build."""
    expected = (stream_edges(bd) - {("rectify/m_axis", "vdma_proc/S_AXIS_S2MM")}) | {
        ("rectify/m_axis", "rectified_split/S_AXIS"),
        ("rectified_split/M00_AXIS", "vdma_proc/S_AXIS_S2MM"),
        ("rectified_split/M01_AXIS", f"{overlay.STEREO}/s_axis"),
        (f"{overlay.STEREO}/m_axis", f"{overlay.DEPTH_VDMA}/S_AXIS_S2MM"),
    }
    assert stream_edges(depth_bd) == expected
    cfg = depth_bd.config["rectified_split"]
    assert depth_bd.cells["rectified_split"].startswith("xilinx.com:ip:axis_broadcaster:")
    assert int(cfg["NUM_MI"]) == 2
    assert int(cfg["S_TDATA_NUM_BYTES"]) == int(cfg["M_TDATA_NUM_BYTES"]) == pixel.BYTES_PER_PIXEL
    assert cfg["S_TUSER_WIDTH"] == cfg["M_TUSER_WIDTH"] == "1" and cfg["HAS_TLAST"] == "1"


def test_vdma_depth_writes_the_stereo_cores_beats_to_ddr(bd: BlockDesign, depth_bd: BlockDesign) -> None:
    name = overlay.DEPTH_VDMA
    cfg = depth_bd.config[name]
    assert vdma_channels(depth_bd, name) == ["S2MM"], "vdma_depth only writes"
    assert int(cfg["c_num_fstores"]) == overlay.NUM_FSTORES and cfg["c_include_sg"] == "0"
    stream, memory = int(cfg["c_s_axis_s2mm_tdata_width"]), int(cfg["c_m_axi_s2mm_data_width"])
    assert stream == stereo.OUT_BEAT_BITS, "one stream beat per output beat of the core"
    hub, n = hp_port(depth_bd, f"{name}/M_AXI_S2MM")
    assert memory == int(depth_bd.config[PS7][f"PCW_S_AXI_HP{n}_DATA_WIDTH"])
    assert memory // stream == overlay.DEPTH_PIXELS_PER_BEAT, "the driver's width / 2 eight-byte pixels"
    assert (cfg["c_use_s2mm_fsync"], cfg["c_s2mm_sof_enable"]) == (USE_FSYNC_TUSER, "1")
    assert cfg["c_s_axis_s2mm_tdata_width.VALUE_SRC"] == "USER"
    # genlock slave (PG020: mode 1) of vdma_proc's S2MM, the master (mode 0, the default)
    assert cfg["c_s2mm_genlock_mode"] == "1"
    assert depth_bd.config["vdma_proc"].get("c_s2mm_genlock_mode", "0") == "0"
    assert set(depth_bd.net_of(f"{name}/s2mm_frame_ptr_in")) == {
        f"{name}/s2mm_frame_ptr_in", "vdma_proc/s2mm_frame_ptr_out"}
    # an HP port and interconnect of its own; the colour build's channels keep theirs
    colour = memory_ports(bd)
    assert {k: v for k, v in memory_ports(depth_bd).items() if k[0] != name} == colour
    assert n not in {m for _, m in colour.values()} and hub not in {h for h, _ in colour.values()}
    assert depth_bd.address(f"{name}/Data_S2MM", hp_ddr(n)).offset == 0
    fabric = EmulatedFabric(clock="stepped")
    try:  # the driver takes this build of the channel
        VDMA(fabric.blocks["vdma_raw"], fabric.ddr, num_fstores=int(cfg["c_num_fstores"]),
             addr_width=int(cfg["c_addr_width"]), name=name)
    finally:
        fabric.close()


def test_depth_interrupts_follow_the_colour_builds_in_the_spec_order(depth_bd: BlockDesign) -> None:
    lines = overlay.INTERRUPTS + overlay.OPTIONAL_INTERRUPTS
    (concat,) = [n for n, vlnv in depth_bd.cells.items() if vlnv.startswith("xilinx.com:ip:xlconcat:")]
    assert int(depth_bd.config[concat]["NUM_PORTS"]) == len(lines)
    for i, (cell, pin) in enumerate(lines):
        assert set(depth_bd.net_of(f"{cell}/{pin}")) == {f"{cell}/{pin}", f"{concat}/In{i}"}


def test_depth_clock_and_reset_reach_every_new_part(depth_bd: BlockDesign) -> None:
    clock = set(depth_bd.net_of(f"{PS7}/FCLK_CLK0"))
    assert {"rectified_split/aclk", f"{overlay.STEREO}/aclk", f"{overlay.DEPTH_VDMA}/s_axi_lite_aclk",
            f"{overlay.DEPTH_VDMA}/m_axi_s2mm_aclk", f"{overlay.DEPTH_VDMA}/s_axis_s2mm_aclk"} <= clock
    resets = [net for net in depth_bd.nets if any(p.endswith("/peripheral_aresetn") for p in net)]
    assert len(resets) == 1, "one reset net, as in the colour build"
    assert {"rectified_split/aresetn", f"{overlay.STEREO}/aresetn", f"{overlay.DEPTH_VDMA}/axi_resetn",
            "axi_ctrl/M04_ARESETN", "axi_ctrl/M05_ARESETN"} <= set(resets[0])


def test_stereo_build_parameters_are_the_depth_build(packaged: Dict[str, PackagedIP],
                                                     depth_bd: BlockDesign) -> None:
    build = stereo.DEFAULT_BUILD
    expected = {"MAX_WIDTH": build.max_width, "MAX_HEIGHT": build.max_height, "MAX_DISP": build.max_disp,
                "PARALLEL": build.parallel}
    params = packaged[stereo.VLNV].params
    assert {name: default for name, (default, _, _) in params.items()} == expected
    assert {name: (low, high) for name, (_, low, high) in params.items()} == stereo.BUILD_LIMITS
    assert {name: int(value) for name, value in depth_bd.config[overlay.STEREO].items()} == expected
    module = verilog_module((RTL_DIR / "stereo" / "stereo_core.v").read_text(), "stereo_core")
    assert module is not None and set(module.parameters) == set(params)
    assert params["MAX_WIDTH"][2] < 2 ** stereo.SIZE_BITS and params["MAX_HEIGHT"][2] < 2 ** stereo.SIZE_BITS
    # the frame the rectify core sends fits the stereo core
    assert build.max_width >= rectify.DEFAULT_BUILD.max_width
    assert build.max_height >= rectify.DEFAULT_BUILD.max_height


def test_stereo_interfaces_match_the_rtl_ports(packaged: Dict[str, PackagedIP]) -> None:
    ip = packaged[stereo.VLNV]
    module = verilog_module((RTL_DIR / "stereo" / "stereo_core.v").read_text(), "stereo_core")
    assert module is not None
    clock, reset, busifs = ip.clock
    assert module.ports[clock][0] == "input" and module.ports[reset][0] == "input"
    assert set(ip.interfaces) == {clock, reset, *busifs}
    assert ip.windows == {"s_axil": stereo.STEREO_MAP.size}
    assert module.ports["s_axil_awaddr"][1] in (None, int(math.log2(stereo.STEREO_MAP.size)))
    assert sorted(b for b in busifs if b != "s_axil") == ["m_axis", "s_axis"]
    assert module.ports["s_axis_tdata"] == ("input", pixel.BYTES_PER_PIXEL * 8)
    assert module.ports["m_axis_tdata"] == ("output", stereo.OUT_BEAT_BITS)
    for busif in ("s_axis", "m_axis"):
        assert module.ports[f"{busif}_tuser"][1] == 1 and module.ports[f"{busif}_tlast"][1] == 1


def test_the_packaged_stereo_rtl_is_every_file_of_the_core() -> None:
    """package_ip.tcl globs stereo/sc_*.v and stereo/*.vh, and names the shared rc_ram.v, rc_fifo.v and
    prelude.vh: the same files the simulators and yosys read (stereo_sources)."""
    from stereocam.overlays.rtl.stereo_core import stereo_sources

    text = read_script("package_ip.tcl")
    assert "stereo_core.v" in text and "sc_*.v" in text and "prelude.vh" in text
    folder = RTL_DIR / "stereo"
    globbed = ({folder / "stereo_core.v"} | set(folder.glob("sc_*.v")) | set(folder.glob("*.vh"))
               | {RTL_DIR / name for name in ("rc_ram.v", "rc_fifo.v", "prelude.vh")})
    assert globbed == {p.resolve() for p in stereo_sources()} | set()
    assert {p for p in folder.iterdir() if p.suffix in (".v", ".vh", ".sv")} <= globbed


def test_the_depth_build_passes_the_stubbed_vivado_with_the_stereo_core_as_the_spec_says(
        tmp_path: Path, rtl_copy: Path, depth_bd: BlockDesign) -> None:
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=["-to", "bd", "-build", "depth", "-proj",
                                                            str(tmp_path / "p")],
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy)})
    assert run.error == ""
    assert {name: cell.vlnv for name, cell in run.design.cells.items()} == depth_bd.cells
    core = run.packaged[stereo.VLNV]
    assert core.ranges == {"s_axil/reg0": stereo.STEREO_MAP.size}
    declared = core.registers["s_axil/reg0"]
    assert {n: (int(r["address_offset"], 0), int(r["reset_value"], 0)) for n, r in declared.items()} == {
        reg.name: (reg.offset, reg.reset) for reg in stereo.STEREO_MAP}
    assert {n: (p.low, p.high) for n, p in core.params.items()} == stereo.BUILD_LIMITS
    assert set(run.design.net_of(f"{overlay.DEPTH_VDMA}/s2mm_frame_ptr_in")) == {
        f"{overlay.DEPTH_VDMA}/s2mm_frame_ptr_in", "vdma_proc/s2mm_frame_ptr_out"}


def test_build_tcl_refuses_a_build_it_does_not_have(tmp_path: Path, rtl_copy: Path) -> None:
    run = run_tcl(VIVADO_DIR / "build.tcl", tmp_path, argv=["-to", "bd", "-build", "deep", "-proj",
                                                            str(tmp_path / "p")],
                  preset={"STEREOCAM_RTL_DIR": str(rtl_copy)})
    assert "-build must be one of colour, depth, not 'deep'" in run.error
    assert run.of("create_bd_design") == []
