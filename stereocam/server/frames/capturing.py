"""Capturing: the next frame set with its raw pair, paired by the closed loop, stored as a capture.

What ``POST /api/captures`` and the calibration panel's pairs share, with no
HTTP here: :class:`CaptureService` is handed the stages it uses (feed,
pipeline, overlay, virtual camera's models, the calibration in effect, a
runner for blocking work) and ``sections``, the hook for what every capture
stores besides the frames (the extensions' sections: sensors, ...); a caller
adds its own fields with ``extra``. The HTTP routes only translate.

Loop thread: :meth:`CaptureService.fresh_raw_frame` and :meth:`CaptureService.store`
are coroutines; the blocking parts (register dump, model, PNG encoding, disk)
go to ``run``. :meth:`CaptureService.paired_raw` blocks.
"""
from __future__ import annotations

import asyncio
import time
from datetime import datetime, timezone
from typing import Any, Awaitable, Callable, Dict, Optional, Protocol, Tuple, TypeVar

import numpy as np

from ...overlays.interface import Overlay
from ...overlays.spec import pixel
from ..errors import ApiError, Kind
from ..stores.captures import CaptureInfo, CaptureStore
from ..stores.frame_calibration import FrameCalibration
from .cloud import depth_files
from .depth import matcher_section, needs_depth
from .feed import BroadcastClosed, FrameFeed
from .pipeline import FrameSet, Pipeline
from .virtual_camera import VirtualCamera

__all__ = ["CaptureService", "CalibrationSource", "CHANGE_WAIT_S"]

T = TypeVar("T")
CHANGE_WAIT_S = 30.0  # how long a capture waits out a calibration change (programming and file write)


class _Changing(Protocol):
    @property
    def changing(self) -> bool: ...


class CalibrationSource(Protocol):
    """The calibration in effect: which one a frame ran with (None: unknown), and whether one is changing."""

    @property
    def now(self) -> _Changing: ...

    def for_frame(self, count: int) -> Optional[FrameCalibration]: ...


class Run(Protocol):
    """Runs a blocking call off the event loop (the daemon's ``work`` threads)."""

    def __call__(self, fn: Callable[..., T], *args: Any) -> Awaitable[T]: ...


class CaptureService:
    """Grab a fresh frame set with its raw pair and store it in a :class:`.captures.CaptureStore`.

    ``frame_wait_s`` says how long a grab waits for a frame (read at each grab);
    ``sections`` returns the fields every capture's meta.json gets besides the frame's own.
    """

    def __init__(self, *, feed: FrameFeed, pipeline: Pipeline, overlay: Overlay, virtual: VirtualCamera,
                 calibration: CalibrationSource, run: Run, frame_wait_s: Callable[[], float],
                 sections: Callable[[], Dict[str, Any]] = dict) -> None:
        self.feed, self.pipeline, self.overlay, self.virtual = feed, pipeline, overlay, virtual
        self.calibration = calibration
        self.run = run
        self.frame_wait_s = frame_wait_s
        self.sections = sections

    async def fresh_raw_frame(self) -> FrameSet:
        """The first frame set grabbed after now that carries its raw pair.

        Raises :class:`.errors.ApiError` (unavailable) when no frame comes in time (no signal)
        or the daemon is stopping.
        """
        feed, pipeline, calibration = self.feed, self.pipeline, self.calibration
        timeout = self.frame_wait_s()
        asked = time.time()

        # Grabbed after the request, with its raw pair (and the stereo core's output, where there is a
        # core), of a known calibration.
        def wanted(f: FrameSet) -> bool:
            known = calibration.for_frame(f.fabric_count) is not None
            return f.timestamp >= asked and f.raw is not None and known and not needs_depth(f)

        change_ends = time.monotonic() + CHANGE_WAIT_S
        try:
            with pipeline.raw_wanted(), pipeline.pairs_wanted(), pipeline.depth_wanted():
                while True:
                    try:
                        return await feed.next_frame(timeout=timeout, accept=wanted)
                    except asyncio.TimeoutError:
                        # Frames of a calibration change in progress are refused, not missing: wait it out.
                        if not (calibration.now.changing and time.monotonic() < change_ends):
                            raise
        except asyncio.TimeoutError:
            raise ApiError(f"no signal: no frame came within {timeout:g} s, nothing was captured",
                           kind=Kind.UNAVAILABLE) from None
        except BroadcastClosed:
            raise ApiError("the daemon is shutting down", kind=Kind.UNAVAILABLE) from None

    def paired_raw(self, fs: FrameSet) -> Tuple[np.ndarray, str]:
        """The raw pair whose rectified frame ``fs.processed`` is, and how that is known (blocking).

        The pipeline copies the latest raw and processed stores together, but the raw channel
        can complete the next frame before the core has finished this one, so the latest raw
        store may be a frame ahead; for captures it also copies the store before
        (``fs.raw_previous``). The closed loop decides: the raw frame that the model turns into
        exactly the processed one. "checked" when one does; "unverified" when neither does (a
        core that differs from the model, which Verify shows), and the latest raw pair is kept.
        """
        assert fs.raw is not None
        if fs.source == "virtual":
            return fs.raw, "virtual input"
        overlay, models = self.overlay, self.virtual.models
        for candidate in (fs.raw, fs.raw_previous):
            if candidate is not None and np.array_equal(models.run(overlay, candidate), fs.processed):
                return candidate, "checked"
        return fs.raw, "unverified"

    async def store(self, store: CaptureStore, fs: FrameSet,
                    extra: Optional[Dict[str, Any]] = None, *, depth: bool = True) -> CaptureInfo:
        """Save ``fs`` (raw and rectified pairs, metadata: registers, calibration, sections) in ``store``.

        With ``depth`` also the stereo core's disparity and confidence and, under a calibration
        with depth, the point cloud (:func:`.cloud.depth_files`; meta.json's ``depth`` names them
        or says why they are missing). Raises :class:`.captures.CaptureError` (disk full, I/O)
        with nothing stored.
        """
        overlay = self.overlay
        try:
            registers: Dict[str, Any] = await self.run(overlay.rectify.dump)
        except Exception as exc:
            registers = {"error": str(exc)}
        # The calibration this frame ran with (a change since it was grabbed does not relabel it).
        calibration = self.calibration.for_frame(fs.fabric_count) or FrameCalibration.unknown()
        assert fs.raw is not None
        try:
            raw, pairing = await self.run(self.paired_raw, fs)
        except Exception as exc:  # a model that cannot run (no registers?): store what was copied, say so
            raw, pairing = fs.raw, f"unverified ({type(exc).__name__}: {exc})"
        meta: Dict[str, Any] = {
            "frame": fs.frame,
            "pairing": pairing,
            "fabric_count": fs.fabric_count,
            "time": fs.timestamp,
            "time_utc": datetime.fromtimestamp(fs.timestamp, timezone.utc).isoformat(timespec="milliseconds"),
            "source": fs.source,
            "calibration_id": calibration.id,
            "calibration": calibration.to_json(),
            "backend": overlay.backend,
            "frame_size": list(fs.size),
            "registers": registers,
        }
        if fs.source == "virtual":
            meta["virtual_input"] = self.virtual.origin
        meta.update(self.sections())
        meta.update(extra or {})
        files: Dict[str, bytes] = {}
        if depth:
            files, meta["depth"] = await self.run(depth_files, fs, calibration, f"frame {fs.frame}")
            stereo = overlay.stereo
            if stereo is not None and "unavailable" not in meta["depth"]:
                # as the core holds them when the capture is stored, as "registers" is
                meta["depth"]["matcher"] = await self.run(matcher_section, stereo)
        frames = {"raw_left": raw[..., pixel.LEFT], "raw_right": raw[..., pixel.RIGHT],
                  "rect_left": fs.processed[..., pixel.LEFT], "rect_right": fs.processed[..., pixel.RIGHT]}
        return await self.run(store.save, frames, meta, sorted(files.items()))
