"""Emulated live cameras: what the emulated fabric's camera input asks of a source.

Every source delivers what the demosaic stage of the real board delivers:
one ``(H, W, 8)`` uint8 stream frame per :meth:`CameraSource.read` (left RGBY
in channels 0..3, right RGBY in 4..7, gray made exactly as
:func:`..spec.pixel.gray_of` makes it). The sources: the synthetic rig of
known calibration (:class:`.render.SyntheticRig`, with :mod:`.lens` and
:mod:`.scene`) and replay of recordings (:class:`.replay.ReplaySource`).
"""
from __future__ import annotations

from typing import Protocol, Tuple, runtime_checkable

import numpy as np

__all__ = ["CameraSource", "SourceClosedError"]


class SourceClosedError(ValueError):
    """``read`` on a source after its ``close()``."""


@runtime_checkable
class CameraSource(Protocol):
    """What the emulated fabric's camera input needs from a live source.

    ``read`` returns the stereo frame number ``index`` (>= 0) at time ``t``
    seconds as an ``(H, W, 8)`` uint8 array with ``(W, H) == frame_size``.
    It blocks while the frame is made (a few ms) and is deterministic in
    ``(index, t)``. The returned array may be shared with the source and
    read-only: a consumer that modifies it must copy it first. ``close()``
    is idempotent; ``read`` after it raises :class:`SourceClosedError`.
    """

    @property
    def frame_size(self) -> Tuple[int, int]: ...

    def read(self, index: int, t: float) -> np.ndarray: ...

    def close(self) -> None: ...
