"""AXI4-Stream Switch register table (Xilinx PG085), used as the live/virtual source mux.

The switch is built with "Use control register routing" (PG085, "Switch
Properties"), two slave interfaces and one master interface:

* SI0 (:data:`LIVE`): the demosaiced stereo stream of the two cameras;
* SI1 (:data:`VIRTUAL`): the "proc" VDMA's MM2S channel, i.e. frames written
  to DDR by the processor (the virtual camera);
* MI0: the rectify core's input.

Registers (PG085, "Register Space"): the Control register at 0x00 commits
the double-buffered ``MIx_MUX`` registers when ``REG_UPDATE`` (bit 1) is
written; the switch then goes through a ~16-cycle soft reset and the bit
clears itself. ``MIx_MUX`` registers sit at 0x40 + 4*x: bits 3:0 select the
slave interface, bit 31 disables the master interface. All other bits are
reserved.

The reset value of the ``MIx_MUX`` registers is our assumption (PG085 does
not state it): master disabled. Software always selects a source explicitly.
"""

from __future__ import annotations

from .regs import Access, Field, Register, RegisterMap

VLNV = "xilinx.com:ip:axis_switch:1.1"

LIVE = 0  # SI0: live cameras
VIRTUAL = 1  # SI1: virtual camera (DDR via VDMA MM2S)
INPUT_NAMES = {LIVE: "live", VIRTUAL: "virtual"}
NUM_INPUTS = 2
NUM_OUTPUTS = 1
MAX_INTERFACES = 16  # PG085: 1..16 slave and master interfaces
MI_MUX_BASE = 0x40


def mi_mux_name(mi: int) -> str:
    return f"MI{mi}_MUX"


def axis_switch_map(outputs: int = NUM_OUTPUTS) -> RegisterMap:
    """The register map of a switch with ``outputs`` master interfaces (PG085 "MI_MUX[0-15]")."""
    if not 1 <= outputs <= MAX_INTERFACES:
        raise ValueError(f"an AXI4-Stream switch has 1..{MAX_INTERFACES} master interfaces, not {outputs}")
    regs = [
        Register(
            "CTRL",
            0x00,
            Access.RW,
            0,
            fields=(
                Field(
                    "REG_UPDATE",
                    1,
                    access=Access.SC,
                    doc="commit the MIx_MUX registers; clears itself when the switch is back",
                ),
            ),
            doc="control register (PG085 'Control Register')",
        )
    ]
    for mi in range(outputs):
        regs.append(
            Register(
                mi_mux_name(mi),
                MI_MUX_BASE + 4 * mi,
                Access.RW,
                0x8000_0000,
                fields=(
                    Field("MUX", 0, 4, doc="slave interface routed to this master"),
                    Field("DISABLE", 31, doc="1 = master interface disabled"),
                ),
                doc=f"MI{mi} source select, staged until CTRL.REG_UPDATE (PG085 'MI_MUX[0-15]')",
            )
        )
    return RegisterMap(
        "axis_switch", regs, size=0x1_0000, doc="Xilinx AXI4-Stream Switch, control register routing"
    )


AXIS_SWITCH_MAP = axis_switch_map(NUM_OUTPUTS)
