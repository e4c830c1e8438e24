"""The stereo core's output for a frame set: disparity, confidence and reasons, read once per set.

Every consumer of depth (the disparity and depth views, the readout, the ruler, captures, point
clouds, Verify) asks :func:`stereo_of`, so they all read the very same integers: the fabric's own
output (``FrameSet.depth``, taken from the core's frame store by the pipeline while somebody holds
:meth:`~.pipeline.Pipeline.depth_wanted`). Where the overlay has no stereo core it gives None, and
the consumer falls back (the disparity view to OpenCV's StereoBM on the ARM).
"""
from __future__ import annotations

import dataclasses
from typing import Any, Dict, Optional

from ...overlays.interface import StereoControl
from ...overlays.model.stereo import StereoResult, compute
from ...overlays.spec import pixel
from ...overlays.spec.stereo import StereoParams
from .pipeline import FrameSet

LEFT_Y = pixel.LEFT.start + pixel.Y
RIGHT_Y = pixel.RIGHT.start + pixel.Y

#: What computes the disparity, as ``/api/status`` and the page say it.
BY_CORE = "stereo core"
BY_ARM = "ARM, OpenCV StereoBM"


class DepthNotTaken(LookupError):
    """The frame set was read without the core's output: hold ``Pipeline.depth_wanted`` and take the next."""


def disparity_by(has_stereo: bool) -> str:
    """Which computes the disparity: the fabric's stereo core, or the ARM where the bitstream has none."""
    return BY_CORE if has_stereo else BY_ARM


def matcher_section(stereo: StereoControl) -> Dict[str, Any]:
    """The stereo core's parameters and build as it holds them now (register reads, blocking): what a
    capture's ``depth`` section records beside the disparity, so that it can be computed again
    (``stereocam disparity``). ``error`` where the core cannot be read."""
    try:
        # read back from the registers, the build has no name
        build = {k: v for k, v in dataclasses.asdict(stereo.build).items() if k != "name"}
        return {"params": stereo.params().as_json(), "build": build}
    except Exception as exc:  # a capture is stored without it rather than refused
        return {"error": f"{type(exc).__name__}: {exc}"}


def needs_depth(fs: FrameSet) -> bool:
    """True when ``fs`` came from an overlay with a stereo core but without its output (take another)."""
    return fs.stereo and fs.depth is None


def stereo_of(fs: FrameSet) -> Optional[StereoResult]:
    """The stereo core's output for ``fs`` (read once, cached in the set; blocks while the emulated core
    computes it); None where the overlay has no stereo core. :class:`DepthNotTaken` for a set read
    without it."""
    if not fs.stereo:
        return None
    take = fs.depth
    if take is None:
        raise DepthNotTaken(f"frame {fs.frame} was read without the stereo core's output")
    result: StereoResult = fs.cache.get(("stereo",), lambda: StereoResult.from_beats(take()))
    return result


def model_of(fs: FrameSet, params: StereoParams) -> StereoResult:
    """The stereo core's model on ``fs``'s rectified gray pair with ``params`` (cached per parameters;
    blocks while computed): what Verify compares the core's output with. ValueError for a frame
    the core does not take."""
    def run() -> StereoResult:
        p = fs.processed
        return compute(p[..., LEFT_Y].copy(), p[..., RIGHT_Y].copy(), params)

    result: StereoResult = fs.cache.get(("stereo model", params), run)
    return result
