"""What the stereo core outputs for one frame, and the checks every path makes on its input."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..spec import stereo as spec


@dataclass(frozen=True)
class StereoResult:
    """Per pixel of the left image: the disparity code (x16, :data:`~spec.INVALID` where none),
    the confidence (0..255, 0 where invalid) and why a pixel is invalid (:data:`~spec.REASONS`)."""

    disp: np.ndarray  # (H, W) uint16
    conf: np.ndarray  # (H, W) uint8
    reason: np.ndarray  # (H, W) uint8

    @property
    def valid(self) -> np.ndarray:
        return self.disp != spec.INVALID

    def pixels(self) -> np.ndarray:
        """Disparity in pixels (float32), NaN where invalid."""
        out = self.disp.astype(np.float32) / spec.SUBPIX_ONE
        out[~self.valid] = np.nan
        return out

    def beats(self) -> np.ndarray:
        """The output stream's 32-bit beats, (H, W) uint32, as the RTL emits them."""
        return (self.disp.astype(np.uint32) << spec.OUT_DISP_LSB
                | self.conf.astype(np.uint32) << spec.OUT_CONF_LSB
                | self.reason.astype(np.uint32) << spec.OUT_REASON_LSB)

    @classmethod
    def from_beats(cls, beats: np.ndarray) -> "StereoResult":
        b = np.asarray(beats, np.uint32)
        return cls(((b >> spec.OUT_DISP_LSB) & 0xFFFF).astype(np.uint16),
                   ((b >> spec.OUT_CONF_LSB) & 0xFF).astype(np.uint8),
                   ((b >> spec.OUT_REASON_LSB) & ((1 << spec.REASON_BITS) - 1)).astype(np.uint8))

    def equal(self, other: "StereoResult") -> bool:
        return (np.array_equal(self.disp, other.disp) and np.array_equal(self.conf, other.conf)
                and np.array_equal(self.reason, other.reason))


def check_pair(left: np.ndarray, right: np.ndarray, p: spec.StereoParams,
               build: spec.Build = spec.DEFAULT_BUILD) -> None:
    """Raise :class:`ValueError` saying what is wrong with a pair or parameters the core would refuse."""
    for name, img in (("left", left), ("right", right)):
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 2:
            got = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
            raise ValueError(f"the {name} image must be 8-bit gray (H, W), not {got}")
    if left.shape != right.shape:
        raise ValueError(f"the images differ in size: left {left.shape[1]}x{left.shape[0]}, "
                         f"right {right.shape[1]}x{right.shape[0]}")
    problems = spec.size_problems(left.shape[1], left.shape[0], build) + p.problems(build)
    if problems:
        raise ValueError("; ".join(problems))
