"""The overlay's IP instances: names, identities and what each driver needs from the metadata.

Written once: the board overlay binds drivers by these names and checks the
VLNV of what it finds there; the emulated fabric places its blocks under the
same names.

The stereo core (``STEREO_CORE.md``) is optional: a bitstream may have it or not, and the
daemon asks (:data:`OPTIONAL_INSTANCES`). Where it is, it sits after the rectify core on the
rectified stream (a broadcaster feeds both the processed channel and the stereo core) and its
32-bit output beats reach DDR through a channel of their own: a third VDMA, ``vdma_depth``,
S2MM only. The broadcaster gives every rectified frame to both channels or to neither, so frame
store ``k`` of one holds the disparity of frame store ``k`` of the other; the block design also
wires ``vdma_depth`` as genlock slave of ``vdma_proc``'s S2MM, which the drivers do not enable
(``GenlockEn``) yet. Its stream takes the core's 32-bit beats and the VDMA packs two to a 64-bit
memory word (the left pixel in the low word), so the channel is started ``width / 2``
eight-byte pixels wide (:data:`DEPTH_PIXELS_PER_BEAT`) and a store reads back as ``(H, W)``
uint32 beats. The block design (``vivado/``) builds them with ``build.tcl -build depth``: its
address map is then :data:`ADDRESS_MAP` and :data:`OPTIONAL_ADDRESS_MAP`, its interrupts
:data:`INTERRUPTS` and :data:`OPTIONAL_INTERRUPTS`. The default build (``colour``) has neither.
"""
from __future__ import annotations

from typing import Dict, Tuple

from .rectify import VLNV as RECTIFY_VLNV
from .stereo import VLNV as STEREO_VLNV

BITSTREAM = "stereocam.bit"  # with stereocam.hwh beside it

VDMA_VLNVS: Tuple[str, ...] = ("xilinx.com:ip:axi_vdma:6.2", "xilinx.com:ip:axi_vdma:6.3")
SWITCH_VLNVS: Tuple[str, ...] = ("xilinx.com:ip:axis_switch:1.1",)

# Base addresses of the IP register windows in the PS7's M_AXI_GP0 range, as the block design
# (stereocam/overlays/vivado/block_design.tcl) assigns them and the .hwh reports them; the emulated fabric
# places its blocks at the same addresses.
ADDRESS_MAP: Dict[str, int] = {
    "vdma_raw": 0x4300_0000,
    "vdma_proc": 0x4301_0000,
    "rectify": 0x43C0_0000,
    "mux": 0x43C1_0000,
}
WINDOW_SIZE = 0x1_0000  # 64 KiB per IP
NUM_FSTORES = 3  # frame stores of each VDMA channel (C_NUM_FSTORES)

# instance name -> accepted VLNVs
INSTANCES: Dict[str, Tuple[str, ...]] = {
    "vdma_raw": VDMA_VLNVS,  # S2MM: raw camera frames to DDR
    "vdma_proc": VDMA_VLNVS,  # MM2S: virtual camera; S2MM: rectified frames to DDR
    "mux": SWITCH_VLNVS,  # SI0 live cameras, SI1 virtual camera -> rectify core
    "rectify": (RECTIFY_VLNV,),
}

#: The optional instances: present in a ``depth`` build, absent from today's bitstream.
STEREO = "stereo"
DEPTH_VDMA = "vdma_depth"
OPTIONAL_INSTANCES: Dict[str, Tuple[str, ...]] = {
    STEREO: (STEREO_VLNV,),  # the stereo core's AXI4-Lite registers (STEREO_MAP)
    DEPTH_VDMA: VDMA_VLNVS,  # S2MM only: the stereo core's output beats to DDR
}
OPTIONAL_ADDRESS_MAP: Dict[str, int] = {
    STEREO: 0x43C2_0000,
    DEPTH_VDMA: 0x4302_0000,
}
DEPTH_PIXELS_PER_BEAT = 2  # 32-bit output beats per 64-bit stream beat of vdma_depth

#: The one fabric clock (the PS7's FCLK_CLK0): AXI4-Lite registers, every stream, the HP ports.
#: stereocam/overlays/vivado/settings.tcl sets it in MHz (STEREOCAM_FCLK0_MHZ); a test checks they agree.
FABRIC_CLOCK_HZ = 100_000_000

#: The interrupt lines into the PS7's IRQ_F2P, in order (the xlconcat's In0 first, IRQ_F2P[0]):
#: (cell, pin). Their interrupt numbers follow this order; the .hwh reports them to pynq.
INTERRUPTS: Tuple[Tuple[str, str], ...] = (
    ("vdma_raw", "s2mm_introut"),
    ("vdma_proc", "mm2s_introut"),
    ("vdma_proc", "s2mm_introut"),
)
#: The depth build's interrupt lines, after :data:`INTERRUPTS` (IRQ_F2P[3] on).
OPTIONAL_INTERRUPTS: Tuple[Tuple[str, str], ...] = (
    (DEPTH_VDMA, "s2mm_introut"),
)

#: The sensors' two-wire interface: both MT9V034s on one bus, the PS7's I2C0 routed through EMIO
#: to the external interface port :data:`SENSOR_I2C_PORT` (the block design's; Vivado's wrapper
#: names its pins ``<port>_scl_io`` and ``<port>_sda_io``, each an IOBUF). Linux names the PS's
#: I2C0 ``/dev/i2c-0`` (the cadence driver, its node ``i2c0`` enabled in the boot image's device
#: tree); the board profile's ``i2c.bus`` must be :data:`SENSOR_I2C_BUS` (a test checks).
SENSOR_I2C_CONTROLLER = "I2C0"
SENSOR_I2C_PORT = "cam_iic"
SENSOR_I2C_BUS = 0

#: The board's pin map (stereocam/overlays/vivado/pins/<board>.pins, one line per external port
#: bit: port, package pin, I/O standard) is named for the board profile (``name:``) it serves.
PIN_MAP_SUFFIX = ".pins"
PIN_PLACEHOLDER = "FILL_IN"
