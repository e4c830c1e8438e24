"""Bitstreams for pynq without Vivado: a ``.hwh`` written from the spec and a ``.bit`` with a real header.

pynq reads an overlay's IP (names, VLNVs, addresses, parameters) from the
``.hwh`` Vivado writes beside the ``.bit``. :func:`write_overlay` writes both
files for the stereocam block design as :mod:`stereocam.overlays.spec.overlay`
describes it (or a variant of it, or another design altogether), small
enough to read: the PS7 with its GP0 address map, one module per IP with the
parameters Vivado records for it. pynq's own metadata parser
(``pynqmetadata``) reads them as it reads a real ``.hwh``. The ``.bit`` has
the header pynq parses (design, part, date, time, data length) and a short
payload that differs per design, so that each design hashes differently.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Tuple
from xml.sax.saxutils import quoteattr

from stereocam.overlays.spec.axis_switch import NUM_INPUTS, NUM_OUTPUTS
from stereocam.overlays.spec.overlay import ADDRESS_MAP, INSTANCES, NUM_FSTORES, WINDOW_SIZE
from stereocam.overlays.spec.rectify import DEFAULT_BUILD, Build

PART = "xc7z020clg400-1"
PS7 = "processing_system7_0"
PS7_VLNV = "xilinx.com:ip:processing_system7:5.5"

# The PS7 parameters pynq's metadata reads (PL clocks): FCLK0 at 100 MHz from the IO PLL, the others off.
_PS7_CLOCKS: Dict[str, str] = {}
for _i in range(4):
    _PS7_CLOCKS.update({
        f"PCW_FPGA_FCLK{_i}_ENABLE": "1" if _i == 0 else "0",
        f"PCW_FCLK{_i}_PERIPHERAL_CLKSRC": "IO PLL",
        f"PCW_FCLK{_i}_PERIPHERAL_DIVISOR0": "5" if _i == 0 else "1",
        f"PCW_FCLK{_i}_PERIPHERAL_DIVISOR1": "2" if _i == 0 else "1",
        f"PCW_FPGA{_i}_PERIPHERAL_FREQMHZ": "100" if _i == 0 else "50",
    })


@dataclass(frozen=True)
class Ip:
    """One addressable IP of a block design: instance name, VLNV, base address, parameters."""

    name: str
    vlnv: str
    base: int
    parameters: Mapping[str, str] = field(default_factory=dict)
    size: int = WINDOW_SIZE
    interface: str = "S_AXI_LITE"


def vdma_parameters(num_fstores: int = NUM_FSTORES) -> Dict[str, str]:
    """What Vivado records for an AXI VDMA with both channels, 32-bit addresses (PG020 names)."""
    return {"C_NUM_FSTORES": str(num_fstores), "C_INCLUDE_MM2S": "1", "C_INCLUDE_S2MM": "1",
            "C_M_AXI_MM2S_ADDR_WIDTH": "32", "C_M_AXI_S2MM_ADDR_WIDTH": "32",
            "C_MM2S_LINEBUFFER_DEPTH": "2048", "C_S2MM_LINEBUFFER_DEPTH": "2048", "C_INCLUDE_SG": "0"}


def rectify_parameters(build: Build = DEFAULT_BUILD, *, lb_rows: Optional[int] = None) -> Dict[str, str]:
    """The rectify core's Verilog parameters (``stereocam/overlays/rtl/rectify_core.v``), as the IP packager
    records them."""
    return {"MAX_WIDTH": str(build.max_width), "MAX_HEIGHT": str(build.max_height),
            "LB_ROWS": str(build.lb_rows if lb_rows is None else lb_rows), "COLOUR": str(int(build.colour))}


def stereocam_ips(*, num_fstores: int = NUM_FSTORES, build: Build = DEFAULT_BUILD,
                  lb_rows: Optional[int] = None) -> List[Ip]:
    """The stereocam overlay's addressable IP, from the spec (names, VLNVs, addresses)."""
    params = {
        "vdma_raw": vdma_parameters(num_fstores),
        "vdma_proc": vdma_parameters(num_fstores),
        "mux": {"NUM_SI": str(NUM_INPUTS), "NUM_MI": str(NUM_OUTPUTS), "ROUTING_MODE": "1",
                "TDATA_NUM_BYTES": "8"},
        "rectify": rectify_parameters(build, lb_rows=lb_rows),
    }
    interface = {"vdma_raw": "S_AXI_LITE", "vdma_proc": "S_AXI_LITE", "mux": "S_AXI_CTRL",
                 "rectify": "s_axil"}
    return [Ip(name, INSTANCES[name][-1], ADDRESS_MAP[name], params[name], interface=interface[name])
            for name in INSTANCES]


def _params(values: Mapping[str, str], indent: str) -> str:
    return "".join(
        f'{indent}<PARAMETER NAME={quoteattr(k)} VALUE={quoteattr(v)}/>\n' for k, v in values.items()
    )


def hwh(design: str, ips: List[Ip]) -> str:
    """The ``.hwh`` XML of a Zynq-7020 design whose GP0 port reaches ``ips``."""
    ranges = "".join(
        f'        <MEMRANGE ADDRESSBLOCK="Reg" BASENAME="C_BASEADDR" BASEVALUE="0x{ip.base:08X}" '
        f'HIGHNAME="C_HIGHADDR" HIGHVALUE="0x{ip.base + ip.size - 1:08X}" INSTANCE={quoteattr(ip.name)} '
        f'IS_DATA="TRUE" IS_INSTRUCTION="TRUE" MASTERBUSINTERFACE="M_AXI_GP0" MEMTYPE="REGISTER" '
        f'SLAVEBUSINTERFACE={quoteattr(ip.interface)}/>\n'
        for ip in ips)
    modules = "".join(
        f'    <MODULE FULLNAME={quoteattr("/" + ip.name)} INSTANCE={quoteattr(ip.name)} IPTYPE="PERIPHERAL" '
        f'IS_ENABLE="1" MODCLASS="PERIPHERAL" MODTYPE={quoteattr(ip.vlnv.split(":")[2])} '
        f'VLNV={quoteattr(ip.vlnv)}>\n'
        f'      <PARAMETERS>\n{_params(ip.parameters, "        ")}      </PARAMETERS>\n'
        f'      <PORTS/>\n'
        f'      <BUSINTERFACES>\n'
        f'        <BUSINTERFACE BUSNAME="ps7_axi_periph_M{i:02d}_AXI" DATAWIDTH="32" '
        f'NAME={quoteattr(ip.interface)} '
        f'TYPE="SLAVE" VLNV="xilinx.com:interface:aximm:1.0"/>\n'
        f'      </BUSINTERFACES>\n'
        f'    </MODULE>\n'
        for i, ip in enumerate(ips))
    return (
        '<?xml version="1.0" encoding="UTF-8" standalone="no" ?>\n'
        '<EDKSYSTEM EDWVERSION="1.2" TIMESTAMP="Mon Jan  1 00:00:00 2024" VIVADOVERSION="2022.1">\n'
        f'  <SYSTEMINFO ARCH="zynq" DEVICE="7z020" NAME={quoteattr(design)} PACKAGE="clg400" '
        'SPEEDGRADE="-1"/>\n'
        '  <EXTERNALPORTS/>\n'
        '  <EXTERNALINTERFACES/>\n'
        '  <MODULES>\n'
        f'    <MODULE FULLNAME="/{PS7}" INSTANCE="{PS7}" IPTYPE="PERIPHERAL" IS_ENABLE="1" IS_PL="FALSE" '
        f'MODTYPE="processing_system7" VLNV="{PS7_VLNV}">\n'
        f'      <PARAMETERS>\n{_params(_PS7_CLOCKS, "        ")}      </PARAMETERS>\n'
        '      <PORTS/>\n'
        '      <BUSINTERFACES>\n'
        f'        <BUSINTERFACE BUSNAME="{PS7}_M_AXI_GP0" DATAWIDTH="32" NAME="M_AXI_GP0" TYPE="MASTER" '
        'VLNV="xilinx.com:interface:aximm:1.0"/>\n'
        '      </BUSINTERFACES>\n'
        f'      <MEMORYMAP>\n{ranges}      </MEMORYMAP>\n'
        '    </MODULE>\n'
        f'{modules}'
        '  </MODULES>\n'
        '</EDKSYSTEM>\n'
    )


def bit(design: str, payload: bytes) -> bytes:
    """A ``.bit`` file: Xilinx's header (as ``pynq`` parses it) and ``payload`` as configuration data."""

    def text(key: bytes, value: str) -> bytes:
        data = value.encode("ascii") + b"\0"
        return key + struct.pack(">h", len(data)) + data

    magic = bytes.fromhex("0ff00ff00ff00ff000")
    data = payload + b"\0" * (-len(payload) % 4)
    return (struct.pack(">h", len(magic)) + magic + struct.pack(">h", 1)
            + text(b"a", f"{design};UserID=0XFFFFFFFF;Version=2022.1") + text(b"b", PART.split("-")[0][2:])
            + text(b"c", "2024/01/01") + text(b"d", "00:00:00") + b"e" + struct.pack(">i", len(data)) + data)


def write_overlay(folder: Path, design: str = "stereocam", ips: Optional[List[Ip]] = None) -> Path:
    """Write ``<design>.bit`` and ``<design>.hwh`` into ``folder``; return the ``.bit``'s path.

    ``ips`` defaults to the stereocam overlay (:func:`stereocam_ips`).
    """
    ips = stereocam_ips() if ips is None else ips
    folder.mkdir(parents=True, exist_ok=True)
    text = hwh(design, ips)
    (folder / f"{design}.hwh").write_text(text, encoding="utf-8")
    path = folder / f"{design}.bit"
    path.write_bytes(bit(design, text.encode("utf-8")))
    return path


def ip_table(ips: List[Ip]) -> Dict[str, Tuple[str, int]]:
    """name -> (VLNV, base address): what pynq's ``ip_dict`` must say about these IP."""
    return {ip.name: (ip.vlnv, ip.base) for ip in ips}


def pynq_for_tests() -> "Optional[object]":
    """pynq, for the tests that exist only where it imports: in the board env it must (an error, not a skip).

    Elsewhere None, and those modules define no tests (a skipped test is not allowed in CI).
    """
    import os

    from stereocam.overlays.pynq import import_pynq

    if os.environ.get("STEREOCAM_TEST_ENV") == "board":
        return import_pynq()
    try:
        return import_pynq()
    except ImportError:
        return None
