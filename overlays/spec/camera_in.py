"""The camera input path: two MT9V034 parallel receivers and the Bayer demosaic, as one IP.

Written once: the RTL (``overlays/rtl/camera/``), its Python model, the
block design script and the emulated cameras read the interface from here.

The IP has no register window: it turns the two sensors' parallel outputs
into the fabric's 64-bit stereo stream (:mod:`.pixel`) and nothing else.

Ports (Verilog names, camera 0 is the left camera, camera 1 the right):

* ``cam0_pclk``, ``cam0_data[9:0]``, ``cam0_line_valid``, ``cam0_frame_valid``
  and the same for ``cam1_``: the MT9V034's PIXCLK, DOUT[9:0], LINE_VALID and
  FRAME_VALID, sampled on the rising edge of PIXCLK. The two sensors are
  hardware-synchronised (one master, one slave on the same SYSCLK), so their
  frames and lines start together; each still has its own pixel clock pin.
* ``aclk``, ``aresetn``: the stream clock and its active-low reset.
* ``m_axis_tdata[63:0]``, ``m_axis_tvalid``, ``m_axis_tready``,
  ``m_axis_tuser`` (start of frame), ``m_axis_tlast`` (end of line): the
  AXI4-Stream of :mod:`.pixel`, one beat per pixel position of both cameras.
"""
from __future__ import annotations

from typing import Dict, Tuple

VLNV = "stereocam:user:camera_in:1.0"
INSTANCE = "camera_in"  # cell name in the block design
TOP = "camera_in"  # Verilog top module
DATA_BITS = 10  # MT9V034 DOUT width
STREAM_BITS = 64
CAMERAS: Tuple[str, str] = ("cam0", "cam1")  # left, right

# Verilog parameters of the top module and their defaults.
PARAMETERS: Dict[str, int] = {
    "MAX_WIDTH": 752,  # longest line the demosaic's line buffers hold
}

# Port name -> (direction, width)
PORTS: Dict[str, Tuple[str, int]] = {
    **{f"{cam}_{sig}": ("input", width)
       for cam in CAMERAS
       for sig, width in (("pclk", 1), ("data", DATA_BITS), ("line_valid", 1), ("frame_valid", 1))},
    "aclk": ("input", 1),
    "aresetn": ("input", 1),
    "m_axis_tdata": ("output", STREAM_BITS),
    "m_axis_tvalid": ("output", 1),
    "m_axis_tready": ("input", 1),
    "m_axis_tuser": ("output", 1),
    "m_axis_tlast": ("output", 1),
}
