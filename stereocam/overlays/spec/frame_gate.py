"""The frame gate: an AXI4-Stream stage that takes every beat and forwards whole frames, or none.

Written once: the RTL (``stereocam/overlays/rtl/camera/frame_gate.v``), its model
(``stereocam/overlays/model/frame_gate.py``), the co-simulation (``tests/hdl/tb_frame_gate.py``)
and the Vivado scripts (``stereocam/overlays/vivado/``, checked by
``tests/overlays/test_overlay_build.py``) read it from here.

Why: the camera stream goes through an AXI4-Stream broadcaster to two consumers, ``vdma_raw``
(raw frames to DDR) and the mux's live input (the rectify core). A broadcaster passes a beat only
when every output takes it, so one consumer that stops (the mux routing the virtual camera, a VDMA
channel that is not running, the core holding its input) would stall the other and the cameras.
One gate on each broadcaster output never holds TREADY low, so the broadcaster and ``camera_in``
never wait; each branch gets whole frames when it keeps up and loses whole frames when it does
not, as on the emulated fabric (``stereocam/overlays/emulated/logic.py``: ``tick``), where the raw path
runs whatever the mux selects.

Ports (one clock, ``aclk``; ``aresetn`` active low, synchronous):

* ``s_axis_*``: the stream in (:mod:`.pixel`: 64-bit TDATA, TUSER = start of frame, TLAST = end
  of line). ``s_axis_tready`` is tied high: every beat offered is taken, in reset too.
* ``m_axis_*``: the same stream out, honouring ``m_axis_tready``.
"""
from __future__ import annotations

from typing import Dict, Tuple

from .stream import STREAM_BITS as STREAM_BITS  # the gate's TDATA width (its FIFO holds TUSER and TLAST too)
from .stream import stream_ports

VLNV = "stereocam:user:frame_gate:1.0"
TOP = "frame_gate"  # Verilog top module
GATE_RAW = "gate_raw"  # cell between the broadcaster's M00 and vdma_raw's S2MM
GATE_LIVE = "gate_live"  # cell between the broadcaster's M01 and the mux's live input (SI0)
INSTANCES: Tuple[str, str] = (GATE_RAW, GATE_LIVE)  # in the broadcaster's output order, M00 first

#: The IP's Verilog files (it shares the camera input's RAM and FIFO) and the prelude they include.
# Paths from rtl/camera/: the RAM, the FIFO and the prelude are the rectify core's (rtl/), shared.
SOURCES: Tuple[str, ...] = ("frame_gate.v", "../rc_ram.v", "../rc_fifo.v", "../prelude.vh")

# Verilog parameters of the top module and their defaults.
PARAMETERS: Dict[str, int] = {
    "DEPTH": 1024,  # beats the gate holds (see "Capacity" below)
}
#: The range of DEPTH a build accepts (the IP's user parameter). Any value in it works: the RAM is
#: the next power of two, the capacity is DEPTH itself.
DEPTH_RANGE: Tuple[int, int] = (16, 32768)

# Port name -> (direction, width)
PORTS: Dict[str, Tuple[str, int]] = {
    "aclk": ("input", 1),
    "aresetn": ("input", 1),
    **stream_ports("s_axis", master=False),
    **stream_ports("m_axis", master=True),
}

# =====================================================================================================
# Behaviour, clock by clock (the model is this text as a loop; the RTL matches it beat for beat and
# clock for clock, tests/hdl/test_frame_gate_rtl.py).
# =====================================================================================================
#
# The gate holds beats in a FIFO of DEPTH beats. A beat it holds is "committed" once the TLAST beat
# of its line has been taken in; only committed beats go out, oldest first, so every line that
# leaves the gate is a whole line. "The gate is empty" means it holds no committed beat (every
# committed beat has been taken by m_axis); "occupancy" counts every beat held, committed or not.
# Both are the values at the start of the clock (a beat leaving on m_axis in the same clock does
# not count as gone yet).
#
# Every clock with s_axis_tvalid high, the beat is taken (s_axis_tready is always high), and:
#
# * a beat with TUSER (a start of frame) first discards an uncommitted partial line, if the frame
#   before had one (counted as a cut of that frame: a malformed frame only). Then the new frame is
#   ADMITTED if the gate is empty, and the beat is stored; otherwise the frame is DROPPED: none of
#   its beats is stored, up to the next TUSER.
# * any other beat of an admitted frame is stored if the occupancy is below DEPTH. Otherwise the
#   frame is CUT: this beat, the uncommitted beats of its line and the rest of the frame up to the
#   next TUSER are dropped; the lines already committed still go out.
# * beats of a dropped or cut frame, and beats before the first TUSER after reset, are dropped.
#
# A line is committed in the clock its TLAST beat is stored; its first beat can be offered on m_axis
# LATENCY clocks later (in clock c + LATENCY for a TLAST taken in clock c), or as soon as the beat
# before it has left, whichever is later. From then on one beat per clock leaves while TREADY is
# high; m_axis never offers a beat before that, and holds an offered beat until it is taken (AXI).
#
# What downstream sees:
# * a frame admitted and never cut: all of it, unchanged;
# * a frame cut after r whole lines: its first r lines (TUSER on the first beat), then the next
#   frame's TUSER; r = 0: nothing at all;
# * a frame dropped: nothing.
#
# A cut frame is a well-formed frame of fewer lines, as the rules downstream expect:
# * the rectify core (stereocam/overlays/RECTIFY_CORE.md, "Malformed input"): the next TUSER arrives before
#   HEIGHT lines: SIZE_ERROR is raised; with r <= e(0) the frame is dropped, else the output frame is
#   completed with rows of 0 where their input rows are missing;
# * an S2MM VDMA channel started on TUSER (PG020; spec/vdma.py, stereocam/overlays/emulated/vdma.py):
#   SOFEarlyErr is raised (a sticky frame-size error, not one that halts the channel), the frame
#   store holds the r lines written, and the channel goes on with the next frame.
#
# Admission when empty means: behind a downstream that stops taking (the mux on the virtual camera, a
# VDMA channel halted), the next frame admitted fills the FIFO and is cut (a camera frame is far
# longer than DEPTH), its committed lines stay queued, the gate is never empty again, and every later
# frame is dropped whole, without ever holding s_axis. When downstream takes again, those queued lines leave
# first (one short frame: the "stale" frame, counted as cut), the frame in progress is dropped (it
# started while the gate was not empty), and the next frame passes whole.
#
# Capacity: a line passes only if it fits (DEPTH >= its length); the default holds one 752-beat line
# of the camera input and 272 beats more. camera_in sends a line in a burst of one beat per clock
# and then nothing until the next sensor line (~3,180 clocks at 100 MHz: 752 + 94 pixel clocks of
# 37.6 ns); the rectify core takes a beat every CLOCKS_PER_BEAT = 2 clocks, so it drains a line
# (1,504 clocks) before the next one arrives, and the FIFO never holds more than a line when nobody
# stalls. A stall downstream is absorbed as long as the beats not yet taken fit; starting at the
# worst moment (a line just committed) that is STALL_CLOCKS_RECTIFY clocks (22 us) into the rectify
# core, which after the stall drains at half the rate the next line arrives, and STALL_CLOCKS_VDMA
# (27 us: the 2,425 clocks to the next line and 272 of its beats) into a VDMA taking a beat per
# clock; longer at other moments. Frames arrive at least one sensor line apart (camera_in emits
# output row y while it takes input row y + 1), so a downstream that keeps up has always emptied the
# gate when the next frame starts.
LATENCY = 4  # clocks from the clock a line's TLAST is taken in to its first beat offered (gate empty)
THROUGHPUT_CLOCKS_PER_BEAT = 1  # in and out
#: The longest downstream stalls the default DEPTH absorbs at the fabric's rates (above), from the
#: model; tests/hdl/tb_frame_gate.py (camera_rate) checks them on the RTL.
STALL_CLOCKS_RECTIFY = 2221
STALL_CLOCKS_VDMA = 2700

# Internal: the output FIFO after the block RAM's two-clock read (rc_fifo, distributed RAM). Four
# words keep one beat per clock flowing while the RAM's reads are in flight.
OUTPUT_FIFO_DEPTH = 4


def ram_words(depth: int) -> int:
    """Words of the gate's block RAM for a DEPTH: the next power of two (the capacity stays DEPTH)."""
    if not DEPTH_RANGE[0] <= depth <= DEPTH_RANGE[1]:
        raise ValueError(f"DEPTH {depth} is outside {DEPTH_RANGE[0]}..{DEPTH_RANGE[1]}")
    return 1 << (depth - 1).bit_length()
