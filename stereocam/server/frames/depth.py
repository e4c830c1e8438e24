"""The stereo core's output for a frame set: disparity, confidence and reasons, computed once per set.

Every consumer of depth (the disparity and depth views, the readout, captures, point clouds)
asks :func:`stereo_of`, so they all read the very same integers. Today the stereo core's model
computes them here from the rectified gray pair, exactly as the core would
(``overlays/STEREO_CORE.md``); where the fabric delivers the core's own output, this is the one
place that reads it instead.
"""
from __future__ import annotations

from ...overlays.model.stereo import StereoResult, compute
from ...overlays.spec import pixel
from ...overlays.spec.stereo import DEFAULT_PARAMS, StereoParams
from .pipeline import FrameSet

LEFT_Y = pixel.LEFT.start + pixel.Y
RIGHT_Y = pixel.RIGHT.start + pixel.Y


def stereo_of(fs: FrameSet, params: StereoParams = DEFAULT_PARAMS) -> StereoResult:
    """The stereo core's output for ``fs`` (cached in the set per parameters; blocks while computed).

    Raises ValueError when the frame is a size the core does not take (wider than its build).
    """
    def run() -> StereoResult:
        p = fs.processed
        return compute(p[..., LEFT_Y].copy(), p[..., RIGHT_Y].copy(), params)

    result: StereoResult = fs.cache.get(("stereo", params), run)
    return result
