"""Depth of one image pair off the board: what ``stereocam disparity`` runs and writes.

A pair is turned into the stereo core's input exactly as the fabric would: with a calibration,
rectified by the rectify core's model (:func:`rectify_with_model`, what ``stereocam rectify``
runs) and the stereo core takes the rectified gray channel; a pair already rectified is
converted with the demosaic's :func:`~stereocam.overlays.spec.pixel.gray_of`. The outputs are
the files of :mod:`.disparity_images` and, with a calibration, :mod:`.cloud`'s PLY, written
all or none (:func:`write_all`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np

from ..overlays.model.stereo import StereoResult, check_pair, compute
from ..overlays.spec import pixel
from ..overlays.spec import stereo as spec
from . import cloud, disparity_images
from .formats import ros_scale

__all__ = ["CORES", "CLOUD_FILE", "StereoInput", "rectify_with_model", "from_calibration", "from_rectified",
           "run", "depth_files", "write_all", "metres_per_unit"]

CORES = ("model",)  # what computes the disparity: the stereo core's bit-exact model
CLOUD_FILE = "cloud.ply"


@dataclass(frozen=True)
class StereoInput:
    """The stereo core's input for a pair: rectified gray left and right, and the left's colour (RGB)."""

    left: np.ndarray
    right: np.ndarray
    colour: np.ndarray


def rectify_with_model(cal: Any, left: np.ndarray, right: np.ndarray, lb_rows: int) -> np.ndarray:
    """The rectify core's model's (H, W, 8) output for a pair (gray or RGB, the calibration's size)."""
    from ..overlays.model.fast import RectifyModel
    from ..overlays.model.result import CoreOptions

    h, w = left.shape[:2]
    gray = left.ndim == 2 and right.ndim == 2
    options = CoreOptions(lb_rows=lb_rows, lb_delay=cal.fit.delay, gray=gray)
    frame = pixel.pack(pixel.rgby(left), pixel.rgby(right))
    out: np.ndarray = RectifyModel(cal.left, cal.right, w, h, options).process(frame).frame
    return out


def _check_size(image: np.ndarray, build: spec.Build) -> None:
    problems = spec.size_problems(image.shape[1], image.shape[0], build)
    if problems:
        raise ValueError(f"the images are {image.shape[1]}x{image.shape[0]} and the stereo core cannot take "
                         f"them ({'; '.join(problems)}): crop or scale the pair")


def from_calibration(cal: Any, left: np.ndarray, right: np.ndarray, lb_rows: int,
                     build: spec.Build = spec.DEFAULT_BUILD) -> StereoInput:
    """The core's input for a raw pair: rectified by the model, the gray channel of its output."""
    _check_size(left, build)
    out = rectify_with_model(cal, left, right, lb_rows)
    return StereoInput(np.ascontiguousarray(out[..., pixel.LEFT.start + pixel.Y]),
                       np.ascontiguousarray(out[..., pixel.RIGHT.start + pixel.Y]),
                       cloud.left_colour(out))


def _gray(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else pixel.gray_of(image)


def from_rectified(left: np.ndarray, right: np.ndarray,
                   build: spec.Build = spec.DEFAULT_BUILD) -> StereoInput:
    """The core's input for a pair already rectified (gray or RGB), up to the core's width."""
    _check_size(left, build)
    colour = left if left.ndim == 3 else np.repeat(left[..., None], 3, axis=2)
    return StereoInput(_gray(left), _gray(right), np.ascontiguousarray(colour))


def metres_per_unit(units: str) -> float:
    """Metres per unit of a calibration's T; ValueError saying what to give when it is not a known length."""
    scale = ros_scale(units)
    if scale is None:
        raise ValueError(f"the calibration's lengths are in {units!r}, not a known unit, so the point "
                         "cloud cannot be in metres: give --units (m, cm, mm or in), the unit of its T")
    return scale


def run(stereo: StereoInput, params: spec.StereoParams) -> StereoResult:
    """The stereo core's model on ``stereo`` (ValueError for a pair or parameters the core refuses)."""
    check_pair(stereo.left, stereo.right, params)
    return compute(stereo.left, stereo.right, params)


def depth_files(result: StereoResult, num_disp: int,
                cloud_of: Optional[Tuple[Any, float, str]] = None,
                colour: Optional[np.ndarray] = None) -> Dict[str, bytes]:
    """The files of one result: disparity (16-bit), its colour rendering, confidence and, given
    ``cloud_of`` = (Q, metres per unit, PLY comment), the point cloud coloured by ``colour``."""
    files = {
        disparity_images.DISPARITY_FILE: disparity_images.disparity_png(result.disp),
        disparity_images.COLOUR_FILE: disparity_images.colour_png(result.disp, num_disp),
        disparity_images.CONFIDENCE_FILE: disparity_images.confidence_png(result.conf),
    }
    if cloud_of is not None:
        Q, unit_m, comment = cloud_of
        files[CLOUD_FILE] = cloud.ply_bytes(cloud.reproject(result.disp, Q, unit_m, colour), comment)
    return files


def write_all(outdir: Path, files: Mapping[str, bytes]) -> None:
    """Write ``files`` into ``outdir`` (created if needed), all or none: each to a hidden temporary
    name first, then renamed. OSError as raised; the temporary files are removed."""
    outdir.mkdir(parents=True, exist_ok=True)
    temps: Dict[str, Path] = {}
    try:
        for name, data in files.items():
            tmp = outdir / f".{name}.{os.getpid()}.tmp"
            temps[name] = tmp
            tmp.write_bytes(data)
        for name, tmp in temps.items():
            tmp.replace(outdir / name)
    finally:
        for tmp in temps.values():
            try:
                tmp.unlink()
            except FileNotFoundError:
                pass
