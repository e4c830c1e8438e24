"""A frame set's depth as files: the stereo core's disparity and confidence PNGs and its point cloud.

What a capture stores beside the rectified pair and what ``GET /api/cloud.ply`` answers, both
from :func:`.depth.stereo_of` (the one place the core's output is read) and the calibration the
frame ran with (its Q and the unit of its T, :class:`..stores.frame_calibration.DepthScale`).
Blocking (the stereo core's model may run, PNG and PLY encoding): call from a worker thread.
"""
from __future__ import annotations

from typing import Any, Dict, Optional, Tuple

from ...calibration import cloud, disparity_images
from ...overlays.model.stereo import StereoResult
from ...overlays.spec import stereo as spec
from ..errors import ApiError, Kind
from ..stores.frame_calibration import FrameCalibration
from .depth import DepthNotTaken, stereo_of
from .pipeline import FrameSet

__all__ = ["CLOUD_FILE", "cloud_unavailable", "frame_cloud", "depth_files"]

CLOUD_FILE = "cloud.ply"


def cloud_unavailable(calibration: Optional[FrameCalibration]) -> Optional[str]:
    """Why a frame of ``calibration`` (None: not known) has no point cloud; None when it has one."""
    if calibration is None:
        return FrameCalibration.unknown().depth_unavailable
    return calibration.depth_unavailable


def frame_cloud(fs: FrameSet, calibration: Optional[FrameCalibration], what: str) -> bytes:
    """The PLY of ``fs`` (``what`` names the frame in its comment), points in metres by its calibration.

    :class:`..errors.ApiError`: CONFLICT when the calibration gives no depth (none, unknown, no
    Q, no unit), UNUSABLE when the frame is a size the stereo core does not take.
    """
    why = cloud_unavailable(calibration)
    depth = calibration.depth if calibration is not None else None
    if why is not None or depth is None or depth.unit_m is None:
        raise ApiError(f"no point cloud of {what}: {why or 'the calibration gives no depth'}",
                       kind=Kind.CONFLICT)
    result = _stereo(fs, what)
    pc = cloud.reproject(result.disp, depth.Q, depth.unit_m, cloud.left_colour(fs.processed))
    return cloud.ply_bytes(pc, f"{what}, calibration {calibration.id if calibration else None}")


def _stereo(fs: FrameSet, what: str) -> StereoResult:
    """The stereo core's output for ``fs``; ApiError saying why there is none."""
    try:
        result = stereo_of(fs)
    except DepthNotTaken:
        raise ApiError(f"no depth of {what}: it was read without the stereo core's output; try again",
                       kind=Kind.UNAVAILABLE) from None
    except ValueError as exc:
        raise ApiError(f"no depth of {what}: {exc}", kind=Kind.UNUSABLE) from None
    if result is None:
        raise ApiError(f"no depth of {what}: this bitstream has no stereo core (the disparity view's "
                       "StereoBM runs on the ARM for display only); `stereocam disparity` computes the "
                       "core's disparity of a capture's rectified pair", kind=Kind.CONFLICT)
    return result


def depth_files(fs: FrameSet, calibration: Optional[FrameCalibration], what: str
                ) -> Tuple[Dict[str, bytes], Dict[str, Any]]:
    """The files a capture of ``fs`` stores for depth and its meta.json section ``depth`` naming them.

    Never raises for what the frame or calibration lack: the section says why a file is missing
    (``unavailable``: no depth at all; ``cloud_unavailable``: no cloud).
    """
    try:
        result = _stereo(fs, what)
    except ApiError as exc:
        return {}, {"unavailable": exc.message}
    files = {disparity_images.DISPARITY_FILE: disparity_images.disparity_png(result.disp),
             disparity_images.CONFIDENCE_FILE: disparity_images.confidence_png(result.conf)}
    section: Dict[str, Any] = {
        "disparity": disparity_images.DISPARITY_FILE, "disparity_scale": spec.SUBPIX_ONE,
        "invalid": spec.INVALID, "confidence": disparity_images.CONFIDENCE_FILE,
        "valid_pixels": int(result.valid.sum()), "cloud": None, "cloud_unavailable": None,
    }
    try:
        files[CLOUD_FILE] = frame_cloud(fs, calibration, what)
        section["cloud"] = CLOUD_FILE
    except ApiError as exc:
        section["cloud_unavailable"] = exc.message
    return files, section
