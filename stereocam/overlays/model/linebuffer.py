"""How many input rows a calibration needs the core to buffer.

The core emits output row ``y`` while input row ``min(y + LB_DELAY, H - 1)``
is the newest one buffered, and it holds the ``LB_ROWS`` newest rows. Both
cameras share one window (they share the stream's control lines). For a
calibration this module finds the smallest delay that never needs a row not
yet received, and then the fewest rows that never need a row already
dropped: the figures the user compares with the bitstream's ``LB_ROWS``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Optional

import numpy as np

from .fast import Camera, SourceMap


@dataclass(frozen=True)
class LineBufferFit:
    delay: int  # value for LB_DELAY
    rows: int  # minimal LB_ROWS for this calibration

    def fits(self, lb_rows: int) -> bool:
        return self.rows <= lb_rows


def rows_needed(
    cameras: Iterable[Camera], width: int, height: int, maps: Optional[Iterable[SourceMap]] = None
) -> LineBufferFit:
    """Delay and rows the given cameras need together (``maps`` reuses precomputed source maps).

    ``cameras`` are calibrations (converted to registers for this frame size) or register sets.
    """
    smaps = list(maps) if maps is not None else [SourceMap.compute(p, width, height) for p in cameras]
    y = np.arange(height, dtype=np.int64)
    los, his = zip(*(m.neighbour_rows_needed(width, height) for m in smaps), strict=True)
    lo = np.minimum.reduce(los)
    hi = np.maximum.reduce(his)
    used = hi >= 0
    if not used.any():
        return LineBufferFit(delay=0, rows=1)
    delay = int(max(0, (hi - y)[used].max()))
    last = np.minimum(y + delay, height - 1)
    rows = int(max(1, (last - lo + 1)[used].max()))
    return LineBufferFit(delay=delay, rows=rows)
