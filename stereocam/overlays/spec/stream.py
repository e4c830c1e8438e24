"""The AXI4-Stream of pixels between the IPs (camera input, frame gates, rectify core): its width
and a top module's ports of it, as the IPs' specs list them.

Apart from :mod:`.pixel`, whose per-frame code the A9 cost table measures: this is the IPs' wiring.
"""
from __future__ import annotations

from typing import Dict, Tuple

from .pixel import BYTES_PER_PIXEL

STREAM_BITS = BYTES_PER_PIXEL * 8  # TDATA: one beat, one pixel


def stream_ports(prefix: str, *, master: bool) -> Dict[str, Tuple[str, int]]:
    """A top module's ports of one stream, ``<prefix>_tdata`` .. ``<prefix>_tlast``, as name ->
    (direction, width): the master drives TDATA, TVALID, TUSER (start of frame) and TLAST (end of
    line), the slave TREADY."""
    drive, take = ("output", "input") if master else ("input", "output")
    return {
        f"{prefix}_tdata": (drive, STREAM_BITS),
        f"{prefix}_tvalid": (drive, 1),
        f"{prefix}_tready": (take, 1),
        f"{prefix}_tuser": (drive, 1),
        f"{prefix}_tlast": (drive, 1),
    }
