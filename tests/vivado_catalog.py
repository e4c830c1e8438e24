"""The Xilinx IP the Vivado scripts instantiate, as the stubbed Vivado of the tests knows it.

Data, not code: for each IP its version in each Vivado release the README names, its documented
``CONFIG.*`` parameters (type, range or enumeration, default) and the interfaces, pins, address
spaces and address segments a cell has for a given configuration. The stubbed ``create_bd_cell``,
``set_property``, ``get_bd_pins`` ... of :mod:`tests.vivado_stub` check the scripts against it.

Sources (the product guide and the table or section each figure comes from):

* PG020 AXI VDMA v6.3 (2022-06-08), ch. 4 "Vivado IDE Parameter to User Parameter Relationship" and
  "Line Buffer Depth", "Frame Buffers", "Fsync Options"; ch. 2 "Port Descriptions";
* PG085 AXI4-Stream Infrastructure IP Suite (2022-08-08), "Switch Properties" (NUM_SI, NUM_MI 1..16,
  TDATA 0..512 bytes, TID/TDEST 0..32 bits, control register routing), "AXI4-Stream Broadcaster";
* PG082 Processing System 7 v5.5, ch. 4 (the ``PCW_*`` parameters of the Zynq-7000 configuration
  wizard: only those these scripts may set are listed; any other is an error until it is added here
  with its source) and ch. 2 "Port Descriptions" (FCLK_CLK0, FCLK_RESET0_N, IRQ_F2P, M_AXI_GP0,
  S_AXI_HP0..S_AXI_HP3 with their S_AXI_HPn_ACLK and the HPn_DDR_LOWOCM segment, IIC_0 over EMIO);
  PCW_S_AXI_HPn_DATA_WIDTH is 32 or 64 (the HP ports' AXI3 data width);
* PG164 Processor System Reset v5.0, ch. 4 "User Parameters" and ch. 2 "Port Descriptions";
* PG059 AXI Interconnect v2.1, "AXI Interconnect Core Parameters" (NUM_SI 1..16, NUM_MI 1..64) and
  its port naming (Snn_AXI, Mnn_AXI, ACLK/ARESETN and one ACLK/ARESETN per slot); NUM_SI 1 with
  NUM_MI 1 is its conversion-only use (no crossbar), as in PYNQ's board designs;
* Concat v2.1 (xlconcat, documented in Vivado's IP catalog only): NUM_PORTS, In<i>, dout.

Where a range here is narrower than the guide's (xlconcat's NUM_PORTS, the broadcaster's TUSER), it
is the part of it that was checked; widen it with the source when a script needs more.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, FrozenSet, List, Mapping, Optional, Tuple

#: The Vivado releases the README names (stereocam/overlays/vivado/README.md, "What you need"), and
#: the version of each Xilinx IP in that release's catalog.
RELEASES: Dict[str, Dict[str, str]] = {
    "2022.1": {
        "xilinx.com:ip:processing_system7": "5.5",
        "xilinx.com:ip:proc_sys_reset": "5.0",
        "xilinx.com:ip:axi_interconnect": "2.1",
        "xilinx.com:ip:axi_vdma": "6.3",
        "xilinx.com:ip:axis_switch": "1.1",
        "xilinx.com:ip:axis_broadcaster": "1.1",
        "xilinx.com:ip:xlconcat": "2.1",
    },
}

#: Values a ``CONFIG.<name>.VALUE_SRC`` may take (UG994, "Parameter Propagation").
VALUE_SOURCES = frozenset({"USER", "DEFAULT", "PROPAGATED", "CONSTANT"})


@dataclass(frozen=True)
class Param:
    """One documented parameter: an integer range, an enumeration, or free text."""

    default: str
    low: Optional[int] = None
    high: Optional[int] = None
    values: Optional[FrozenSet[str]] = None

    def problem(self, value: str) -> Optional[str]:
        """Why ``value`` is not accepted (None if it is)."""
        if self.values is not None:
            if value not in self.values:
                return f"{value!r} is not one of {', '.join(sorted(self.values, key=_order))}"
            return None
        if self.low is not None and self.high is not None:
            try:
                number = int(value, 0)
            except ValueError:
                return f"{value!r} is not an integer"
            if not self.low <= number <= self.high:
                return f"{value} is outside {self.low}..{self.high}"
        return None


def _order(text: str) -> Tuple[int, str]:
    return (int(text), "") if text.isdigit() else (1 << 62, text)


def Int(default: int, low: int, high: int) -> Param:
    return Param(str(default), low=low, high=high)


def OneOf(default: object, *values: object) -> Param:
    return Param(str(default), values=frozenset(str(v) for v in values))


def Text(default: str = "") -> Param:
    return Param(default)


BOOL = OneOf(0, 0, 1)
Config = Mapping[str, str]


@dataclass(frozen=True)
class CatalogIP:
    """A Xilinx IP: its documented parameters and, per configuration, what a cell of it has."""

    doc: str
    params: Mapping[str, Param]
    interfaces: Callable[[Config], List[str]]
    pins: Callable[[Config], List[str]]
    spaces: Callable[[Config], List[str]] = lambda c: []
    segments: Callable[[Config], Dict[str, str]] = lambda c: {}  # "intf/segment" -> interface
    # interface -> (VLNV of the bus, mode) for the .hwh
    intf_types: Callable[[Config], Dict[str, Tuple[str, str]]] = lambda c: {}
    interrupts: Callable[[Config], List[str]] = lambda c: []
    #: the pins a cell drives (the others are its inputs), for the .hwh's PORT DIR
    outputs: FrozenSet[str] = frozenset()
    #: the HDL (model) parameters Vivado records in the .hwh beside the user parameters
    model: Callable[[Config], Dict[str, str]] = lambda c: {}
    iptype: str = "PERIPHERAL"

    def defaults(self) -> Dict[str, str]:
        return {name: p.default for name, p in self.params.items()}


def _on(config: Config, name: str) -> bool:
    return config.get(name) == "1"


def _n(config: Config, name: str) -> int:
    return int(config[name])


AXIMM = "xilinx.com:interface:aximm:1.0"
AXIS = "xilinx.com:interface:axis:1.0"
IIC = "xilinx.com:interface:iic_rtl:1.0"

# ---- PG020 AXI VDMA ---------------------------------------------------------------------------------

_BURSTS = (2, 4, 8, 16, 32, 64, 128, 256)  # PG020 "Maximum Burst Size"
_LINEBUFFER = (128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768)  # PG020 "Line Buffer Depth"
_MM_WIDTH = (32, 64, 128, 256, 512, 1024)  # PG020 "Memory Map Data Width"
_STREAM_WIDTH = tuple(8 * i for i in range(1, 129))  # PG020 "Stream Data Width": 8..1024 bits, bytes

_VDMA_PARAMS: Dict[str, Param] = {
    "c_include_sg": BOOL,
    "c_num_fstores": Int(3, 1, 32),  # "Frame Buffers"
    "c_addr_width": Int(32, 32, 64),  # "Address Width (32-64)"
    "c_enable_vidprmtr_reads": BOOL,
    "c_flush_on_fsync": BOOL,
    "c_enable_debug_all": BOOL,
    "c_dynamic_resolution": OneOf(1, 0, 1),
}
for _ch, _mm, _st in (("mm2s", "c_m_axi_mm2s_data_width", "c_m_axis_mm2s_tdata_width"),
                      ("s2mm", "c_m_axi_s2mm_data_width", "c_s_axis_s2mm_tdata_width")):
    _VDMA_PARAMS.update({
        f"c_include_{_ch}": OneOf(1, 0, 1),
        _mm: OneOf(64, *_MM_WIDTH),
        _st: OneOf(32, *_STREAM_WIDTH),
        f"c_{_ch}_linebuffer_depth": OneOf(512, *_LINEBUFFER),
        f"c_{_ch}_max_burst_length": OneOf(8, *_BURSTS),
        f"c_include_{_ch}_dre": BOOL,
        f"c_{_ch}_genlock_mode": OneOf(0, 0, 1, 2, 3),  # master, slave, dynamic master, dynamic slave
        f"c_{_ch}_genlock_num_masters": Int(1, 1, 16),
        f"c_{_ch}_sof_enable": BOOL,
        f"c_{_ch}_enable_mux": BOOL,
    })
# "Fsync Options": MM2S 0 none (free running), 1 mm2s_fsync; S2MM 0 none, 1 s2mm_fsync, 2 s2mm tuser
_VDMA_PARAMS["c_use_mm2s_fsync"] = OneOf(0, 0, 1)
_VDMA_PARAMS["c_use_s2mm_fsync"] = OneOf(0, 0, 1, 2)


def _vdma_channels(c: Config) -> List[str]:
    return [ch for ch in ("MM2S", "S2MM") if _on(c, f"c_include_{ch.lower()}")]


def _vdma_interfaces(c: Config) -> List[str]:
    out = ["S_AXI_LITE"]
    if "MM2S" in _vdma_channels(c):
        out += ["M_AXI_MM2S", "M_AXIS_MM2S"]
    if "S2MM" in _vdma_channels(c):
        out += ["M_AXI_S2MM", "S_AXIS_S2MM"]
    return out


def _genlock_in(c: Config, ch: str) -> bool:
    """PG020 "Genlock Synchronization": a channel that follows (slave, dynamic slave) or watches
    (dynamic master) another has ``<ch>_frame_ptr_in``, unless the core pairs its two channels
    internally (both on, one master and one slave of the same kind, one master each)."""
    modes = {x: int(c.get(f"c_{x.lower()}_genlock_mode", "0")) for x in _vdma_channels(c)}
    if modes.get(ch, 0) == 0:
        return False
    internal = len(modes) == 2 and sorted(modes.values()) in ([0, 1], [2, 3]) and all(
        int(c.get(f"c_{x.lower()}_genlock_num_masters", "1")) == 1 for x in modes)
    return not internal


def _vdma_pins(c: Config) -> List[str]:
    out = ["s_axi_lite_aclk", "axi_resetn"]
    if "MM2S" in _vdma_channels(c):
        out += ["m_axi_mm2s_aclk", "m_axis_mm2s_aclk", "mm2s_introut", "mm2s_frame_ptr_out"]
    if "S2MM" in _vdma_channels(c):
        out += ["m_axi_s2mm_aclk", "s_axis_s2mm_aclk", "s2mm_introut", "s2mm_frame_ptr_out"]
    out += [f"{ch.lower()}_frame_ptr_in" for ch in _vdma_channels(c) if _genlock_in(c, ch)]
    return out


def _vdma_types(c: Config) -> Dict[str, Tuple[str, str]]:
    out = {"S_AXI_LITE": (AXIMM, "SLAVE")}
    if "MM2S" in _vdma_channels(c):
        out.update({"M_AXI_MM2S": (AXIMM, "MASTER"), "M_AXIS_MM2S": (AXIS, "MASTER")})
    if "S2MM" in _vdma_channels(c):
        out.update({"M_AXI_S2MM": (AXIMM, "MASTER"), "S_AXIS_S2MM": (AXIS, "SLAVE")})
    return out


VDMA = CatalogIP(
    doc="PG020 (AXI VDMA v6.3)",
    params=_VDMA_PARAMS,
    interfaces=_vdma_interfaces,
    pins=_vdma_pins,
    spaces=lambda c: [f"Data_{ch}" for ch in _vdma_channels(c)],
    segments=lambda c: {"S_AXI_LITE/Reg": "S_AXI_LITE"},
    intf_types=_vdma_types,
    interrupts=lambda c: [f"{ch.lower()}_introut" for ch in _vdma_channels(c)],
    outputs=frozenset({"mm2s_introut", "s2mm_introut", "mm2s_frame_ptr_out", "s2mm_frame_ptr_out"}),
    # the core's generics are the user parameters in capitals; both channels' address widths are c_addr_width
    model=lambda c: {**{k.upper(): v for k, v in c.items()},
                     **{f"C_M_AXI_{ch}_ADDR_WIDTH": c["c_addr_width"] for ch in ("MM2S", "S2MM")}},
)

# ---- PG085 AXI4-Stream switch and broadcaster ------------------------------------------------------

_SWITCH_PARAMS: Dict[str, Param] = {
    "NUM_SI": Int(2, 1, 16), "NUM_MI": Int(1, 1, 16),  # "Switch Properties"
    "ROUTING_MODE": OneOf(0, 0, 1),  # "Use Control Register Routing"
    "TDATA_NUM_BYTES": Int(1, 0, 512),
    "HAS_TSTRB": BOOL, "HAS_TKEEP": BOOL, "HAS_TLAST": BOOL,
    "TID_WIDTH": Int(0, 0, 32), "TDEST_WIDTH": Int(0, 0, 32), "TUSER_WIDTH": Int(0, 0, 4096),
    "HAS_ACLKEN": BOOL,
    "ARB_ON_MAX_XFERS": Int(1, 0, 65535), "ARB_ON_NUM_CYCLES": Int(0, 0, 65535), "ARB_ON_TLAST": BOOL,
    "ARB_ALGORITHM": OneOf(0, 0, 1), "DECODER_REG": BOOL,
}


def _switch_types(c: Config) -> Dict[str, Tuple[str, str]]:
    out = {f"S{i:02d}_AXIS": (AXIS, "SLAVE") for i in range(_n(c, "NUM_SI"))}
    out.update({f"M{i:02d}_AXIS": (AXIS, "MASTER") for i in range(_n(c, "NUM_MI"))})
    if _on(c, "ROUTING_MODE"):
        out["S_AXI_CTRL"] = (AXIMM, "SLAVE")
    return out


SWITCH = CatalogIP(
    doc="PG085 (AXI4-Stream Switch v1.1)",
    params=_SWITCH_PARAMS,
    interfaces=lambda c: list(_switch_types(c)),
    pins=lambda c: ["aclk", "aresetn"] + (["s_axi_ctrl_aclk", "s_axi_ctrl_aresetn"]
                                          if _on(c, "ROUTING_MODE") else []),
    segments=lambda c: {"S_AXI_CTRL/Reg": "S_AXI_CTRL"} if _on(c, "ROUTING_MODE") else {},
    intf_types=_switch_types,
)

_BROADCASTER_PARAMS: Dict[str, Param] = {
    "NUM_MI": Int(2, 2, 16),
    "S_TDATA_NUM_BYTES": Int(1, 1, 512), "M_TDATA_NUM_BYTES": Int(1, 1, 512),
    "S_TUSER_WIDTH": Int(0, 0, 2048), "M_TUSER_WIDTH": Int(0, 0, 2048),
    "HAS_TREADY": OneOf(1, 0, 1), "HAS_TSTRB": BOOL, "HAS_TKEEP": BOOL, "HAS_TLAST": BOOL,
    "TID_WIDTH": Int(0, 0, 32), "TDEST_WIDTH": Int(0, 0, 32), "HAS_ACLKEN": BOOL,
}

BROADCASTER = CatalogIP(
    doc="PG085 (AXI4-Stream Broadcaster v1.1)",
    params=_BROADCASTER_PARAMS,
    interfaces=lambda c: ["S_AXIS"] + [f"M{i:02d}_AXIS" for i in range(_n(c, "NUM_MI"))],
    pins=lambda c: ["aclk", "aresetn"],
    intf_types=lambda c: {"S_AXIS": (AXIS, "SLAVE"),
                          **{f"M{i:02d}_AXIS": (AXIS, "MASTER") for i in range(_n(c, "NUM_MI"))}},
)

# ---- PG082 Processing System 7 ----------------------------------------------------------------------

_PS7_PARAMS: Dict[str, Param] = {
    "PCW_USE_M_AXI_GP0": OneOf(1, 0, 1), "PCW_USE_M_AXI_GP1": BOOL,
    "PCW_USE_S_AXI_HP0": BOOL, "PCW_USE_S_AXI_HP1": BOOL, "PCW_USE_S_AXI_HP2": BOOL,
    "PCW_USE_S_AXI_HP3": BOOL,
    **{f"PCW_S_AXI_HP{i}_DATA_WIDTH": OneOf(64, 32, 64) for i in range(4)},
    "PCW_EN_CLK0_PORT": OneOf(1, 0, 1), "PCW_EN_CLK1_PORT": BOOL,
    "PCW_EN_RST0_PORT": OneOf(1, 0, 1), "PCW_EN_RST1_PORT": BOOL,
    "PCW_FPGA_FCLK0_ENABLE": OneOf(1, 0, 1), "PCW_FPGA_FCLK1_ENABLE": BOOL,
    "PCW_FPGA0_PERIPHERAL_FREQMHZ": Int(50, 1, 250), "PCW_FPGA1_PERIPHERAL_FREQMHZ": Int(50, 1, 250),
    "PCW_USE_FABRIC_INTERRUPT": BOOL, "PCW_IRQ_F2P_INTR": BOOL,
    "PCW_I2C0_PERIPHERAL_ENABLE": BOOL,
    "PCW_I2C0_I2C0_IO": OneOf("EMIO", "EMIO", "MIO 10 .. 11", "MIO 14 .. 15", "MIO 18 .. 19",
                              "MIO 22 .. 23", "MIO 26 .. 27", "MIO 30 .. 31", "MIO 34 .. 35",
                              "MIO 38 .. 39", "MIO 42 .. 43", "MIO 46 .. 47", "MIO 50 .. 51"),
}


def _ps7_interfaces(c: Config) -> List[str]:
    out = ["DDR", "FIXED_IO"]
    out += ["M_AXI_GP0"] if _on(c, "PCW_USE_M_AXI_GP0") else []
    out += [f"S_AXI_HP{i}" for i in range(4) if _on(c, f"PCW_USE_S_AXI_HP{i}")]
    if _on(c, "PCW_I2C0_PERIPHERAL_ENABLE") and c.get("PCW_I2C0_I2C0_IO") == "EMIO":
        out.append("IIC_0")
    return out


def _ps7_pins(c: Config) -> List[str]:
    out = ["M_AXI_GP0_ACLK"] if _on(c, "PCW_USE_M_AXI_GP0") else []
    out += [f"S_AXI_HP{i}_ACLK" for i in range(4) if _on(c, f"PCW_USE_S_AXI_HP{i}")]
    out += [f"FCLK_CLK{i}" for i in range(2) if _on(c, f"PCW_EN_CLK{i}_PORT")]
    out += [f"FCLK_RESET{i}_N" for i in range(2) if _on(c, f"PCW_EN_RST{i}_PORT")]
    if _on(c, "PCW_USE_FABRIC_INTERRUPT") and _on(c, "PCW_IRQ_F2P_INTR"):
        out.append("IRQ_F2P")
    return out


def _ps7_types(c: Config) -> Dict[str, Tuple[str, str]]:
    out = {"DDR": ("xilinx.com:interface:ddrx:1.0", "MASTER"),
           "FIXED_IO": ("xilinx.com:display_processing_system7:fixedio:1.0", "MASTER")}
    if _on(c, "PCW_USE_M_AXI_GP0"):
        out["M_AXI_GP0"] = (AXIMM, "MASTER")
    out.update({f"S_AXI_HP{i}": (AXIMM, "SLAVE") for i in range(4) if _on(c, f"PCW_USE_S_AXI_HP{i}")})
    if "IIC_0" in _ps7_interfaces(c):
        out["IIC_0"] = (IIC, "MASTER")
    return out


PS7 = CatalogIP(
    doc="PG082 (Processing System 7 v5.5)",
    params=_PS7_PARAMS,
    interfaces=_ps7_interfaces,
    pins=_ps7_pins,
    spaces=lambda c: ["Data"],
    segments=lambda c: {f"S_AXI_HP{i}/HP{i}_DDR_LOWOCM": f"S_AXI_HP{i}"
                        for i in range(4) if _on(c, f"PCW_USE_S_AXI_HP{i}")},
    intf_types=_ps7_types,
    outputs=frozenset({"FCLK_CLK0", "FCLK_CLK1", "FCLK_RESET0_N", "FCLK_RESET1_N"}),
)

# ---- PG059 AXI Interconnect ---------------------------------------------------------------------------


def _slots(c: Config) -> List[str]:
    return [f"S{i:02d}" for i in range(_n(c, "NUM_SI"))] + [f"M{i:02d}" for i in range(_n(c, "NUM_MI"))]


INTERCONNECT = CatalogIP(
    doc="PG059 (AXI Interconnect v2.1)",
    params={"NUM_SI": Int(1, 1, 16), "NUM_MI": Int(2, 1, 64), "STRATEGY": OneOf(0, 0, 1, 2),
            "ENABLE_ADVANCED_OPTIONS": BOOL},
    interfaces=lambda c: [f"{s}_AXI" for s in _slots(c)],
    pins=lambda c: ["ACLK", "ARESETN"] + [f"{s}_{p}" for s in _slots(c) for p in ("ACLK", "ARESETN")],
    intf_types=lambda c: {f"{s}_AXI": (AXIMM, "SLAVE" if s[0] == "S" else "MASTER") for s in _slots(c)},
    iptype="BUS",
)

# ---- PG164 Processor System Reset, xlconcat ---------------------------------------------------------

RESET = CatalogIP(
    doc="PG164 (Processor System Reset v5.0)",
    params={"C_EXT_RST_WIDTH": Int(4, 1, 16), "C_AUX_RST_WIDTH": Int(4, 1, 16),
            "C_EXT_RESET_HIGH": OneOf(0, 0, 1), "C_AUX_RESET_HIGH": OneOf(0, 0, 1),
            "C_NUM_BUS_RST": Int(1, 1, 8), "C_NUM_PERP_RST": Int(1, 1, 16),
            "C_NUM_INTERCONNECT_ARESETN": Int(1, 1, 8), "C_NUM_PERP_ARESETN": Int(1, 1, 16)},
    interfaces=lambda c: [],
    pins=lambda c: ["slowest_sync_clk", "ext_reset_in", "aux_reset_in", "mb_debug_sys_rst", "dcm_locked",
                    "mb_reset", "bus_struct_reset", "peripheral_reset", "interconnect_aresetn",
                    "peripheral_aresetn"],
    outputs=frozenset({"mb_reset", "bus_struct_reset", "peripheral_reset", "interconnect_aresetn",
                       "peripheral_aresetn"}),
)

CONCAT = CatalogIP(
    doc="Concat v2.1 (xlconcat, Vivado IP catalog)",
    params={"NUM_PORTS": Int(2, 1, 32), **{f"IN{i}_WIDTH": Int(1, 1, 1024) for i in range(32)}},
    interfaces=lambda c: [],
    pins=lambda c: [f"In{i}" for i in range(_n(c, "NUM_PORTS"))] + ["dout"],
    outputs=frozenset({"dout"}),
)

#: "vendor:library:name" -> the IP
CATALOG: Dict[str, CatalogIP] = {
    "xilinx.com:ip:processing_system7": PS7,
    "xilinx.com:ip:proc_sys_reset": RESET,
    "xilinx.com:ip:axi_interconnect": INTERCONNECT,
    "xilinx.com:ip:axi_vdma": VDMA,
    "xilinx.com:ip:axis_switch": SWITCH,
    "xilinx.com:ip:axis_broadcaster": BROADCASTER,
    "xilinx.com:ip:xlconcat": CONCAT,
}
assert all(set(versions) == set(CATALOG) for versions in RELEASES.values())
