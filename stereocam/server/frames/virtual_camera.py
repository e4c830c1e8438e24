"""The mux and the virtual camera as the daemon drives them: flows 4 (a frame through the core) and 6 (live).

:class:`VirtualCamera` puts a frame on the overlay's virtual camera, waits
for the processed frame that came from it, switches the source back to
live, and keeps the model the core's registers describe (:class:`ModelCache`)
for Verify and for pairing captures. Its async methods run on the event
loop; everything that touches the fabric runs on the executor they are
given. One change of source at a time (:attr:`VirtualCamera.lock`).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Dict, Optional, Tuple

import numpy as np

from ...overlays.interface import Channel, ChannelFault, DriverError, Overlay
from ...overlays.model.fast import RectifyModel
from ..errors import ApiError, Kind
from .depth import needs_depth
from .feed import FrameFeed
from .pipeline import COUNT_MOD, FrameSet, Pipeline, SourceState

if TYPE_CHECKING:  # pragma: no cover
    from .recorder import RecordingPlayer

log = logging.getLogger(__name__)

__all__ = ["VirtualCamera", "VerifyResult", "MuxRefused", "ModelCache", "ROUND_TRIP_FRAMES", "PARK_WAIT_S"]

ROUND_TRIP_FRAMES = 2  # frames after MM2S picks the store up until the core's output surely comes from it
PARK_WAIT_S = 5.0
VIRTUAL_CHANNEL: Channel = "vdma_proc.mm2s"
Executor = Optional[concurrent.futures.Executor]


class ModelCache:
    """The last :class:`RectifyModel` built, reused while the core's registers say the same thing.

    Called from several work threads at once (Verify, pairing captures): the cache is one
    immutable ``(key, model)`` pair, read once and replaced in one assignment, so a call
    always runs the model of the registers it read (the model itself is thread-safe).
    """

    def __init__(self) -> None:
        self._entry: Optional[Tuple[Any, RectifyModel]] = None

    def run(self, overlay: Overlay, frame: np.ndarray) -> np.ndarray:
        """What the core should make of ``frame`` as it is configured now (blocks: registers, the model)."""
        config, options = overlay.core_setup()
        key: Tuple[Any, ...] = (config, options)
        entry = self._entry
        if entry is None or entry[0] != key:
            entry = (key, RectifyModel(config.left, config.right, config.width, config.height, options))
            self._entry = entry
        return entry[1].process(frame).frame


@dataclass
class VerifyResult:
    report: Dict[str, Any]
    difference_png: bytes


class MuxRefused(ApiError):
    """The mux did not commit a change of source (unavailable): the daemon's source stays what it was."""

    def __init__(self, source: str, exc: BaseException) -> None:
        super().__init__(f"the mux did not switch to {source} ({exc}): the daemon retries until it commits "
                         "(see /api/status faults); try again in a moment", kind=Kind.UNAVAILABLE)


class VirtualCamera:
    """The mux and the virtual camera as the daemon drives them (loop thread; one change at a time).

    ``input`` is the last frame sent down MM2S (read-only ``(H, W, 8)``),
    ``result`` the processed frame set that came back for it.
    """

    def __init__(self, overlay: Overlay, pipeline: Pipeline, feed: FrameFeed, *,
                 round_trip_timeout: float = 2.0,
                 mux_refused: Callable[[str, BaseException], None] = lambda source, exc: None,
                 mux_committed: Callable[[], None] = lambda: None) -> None:
        self.overlay = overlay
        self.pipeline = pipeline
        self.feed = feed
        self.lock = asyncio.Lock()
        self.source = "live"
        self.input: Optional[np.ndarray] = None
        self.origin: Optional[str] = None
        self.result: Optional[FrameSet] = None
        self.effective_count = 0
        self.verify: Optional[VerifyResult] = None
        self.models = ModelCache()
        self.round_trip_timeout = round_trip_timeout
        self.player: Optional[RecordingPlayer] = None  # while a recording plays (recordings.py)
        # FabricHealth's: a commit the mux refused is a fault until one lands.
        self.mux_refused = mux_refused
        self.mux_committed = mux_committed

    def to_json(self) -> Dict[str, Any]:
        w, h = self.overlay.frame_size
        player = self.player
        return {"source": self.source, "input": self.origin,
                "frame": self.result.frame if self.result is not None else None,
                "width": w, "height": h,
                # A playing that failed stays reported (its error) until the next input replaces it.
                "playing": player.to_json() if player is not None and (player.running or player.error)
                else None}

    def _frames(self, n: float) -> float:
        """Seconds for ``n`` frame periods at the rate the fabric runs (1/60 s before one is known)."""
        return n * (self.pipeline.period or 1 / 60)

    def _send_blocking(self, frame: np.ndarray) -> int:
        """Mux to virtual, frame down MM2S, wait until the channel reads it; the FRAME_COUNT then.

        A channel that halted on a fatal error (a fault since the last upload) is restarted
        once and the frame sent again, so one fault does not fail every later upload.
        """
        self._select_blocking("virtual")
        overlay = self.overlay
        fatal = overlay.channel_status(VIRTUAL_CHANNEL).fatal
        if fatal:
            log.warning("virtual camera: MM2S channel halted on %s: restarting it", ", ".join(fatal))
            overlay.restart_channel(VIRTUAL_CHANNEL)
        try:
            overlay.send_virtual(frame)
        except ChannelFault as exc:
            log.warning("virtual camera: MM2S channel fault (%s): restarting it", exc)
            overlay.restart_channel(VIRTUAL_CHANNEL)
            overlay.send_virtual(frame)
        # Healthy, the channel takes it at the next frame; the bound only ends a wait for a broken one
        # (a loaded machine's frame clock can run late by a second or more).
        overlay.wait_virtual_taken(max(PARK_WAIT_S, self._frames(3), self.round_trip_timeout / 2))
        return int(self.pipeline.frame_count())

    def _select_blocking(self, source: str) -> None:
        try:
            self.overlay.select(source)
        except DriverError as exc:
            self.mux_refused(source, exc)
            raise MuxRefused(source, exc) from exc
        self.mux_committed()

    def _live_blocking(self) -> None:
        self._select_blocking("live")

    async def send(self, loop_executor: Executor, frame: np.ndarray, origin: str) -> FrameSet:
        """Flow 4: ``frame`` through the fabric; returns the processed set (ApiError, timeout, if none came).

        A recording playing through the virtual camera stops first.
        """
        frame.flags.writeable = False
        loop = asyncio.get_running_loop()
        await self.stop_player()
        async with self.lock:
            try:
                count = await loop.run_in_executor(loop_executor, self._send_blocking, frame)
            except MuxRefused:
                with contextlib.suppress(MuxRefused):
                    await self._back_to_live(loop_executor)
                raise
            except Exception as exc:
                with contextlib.suppress(MuxRefused):
                    await self._back_to_live(loop_executor)
                raise ApiError(f"the fabric did not take the virtual-camera frame: {exc}",
                               kind=Kind.TIMEOUT) from exc
            effective = (count + ROUND_TRIP_FRAMES) % COUNT_MOD
            self.pipeline.set_source(SourceState("virtual", frame, effective))
            self.source, self.input, self.origin, self.effective_count = "virtual", frame, origin, effective
            self.result = self.verify = None
            try:
                result = await self._virtual_frame()
            except asyncio.TimeoutError:
                await self._back_to_live(loop_executor)
                raise ApiError(f"the fabric returned no processed frame within "
                               f"{self._round_trip_s():g} s; is the rectify core enabled? "
                               "(GET /api/status); the source is live again", kind=Kind.TIMEOUT) from None
            self.result = result
            return result

    async def _virtual_frame(self, with_depth: bool = False) -> FrameSet:
        effective = self.effective_count

        def from_input(fs: FrameSet) -> bool:
            return (fs.source == "virtual" and (fs.fabric_count - effective) % COUNT_MOD < COUNT_MOD // 2
                    and not (with_depth and needs_depth(fs)))

        with self.pipeline.depth_wanted() if with_depth else contextlib.nullcontext():
            return await self.feed.next_frame(timeout=self._round_trip_s(), accept=from_input)

    def _round_trip_s(self) -> float:
        return max(self.round_trip_timeout, self._frames(ROUND_TRIP_FRAMES + 4))

    async def _back_to_live(self, executor: Executor) -> None:
        try:
            await asyncio.get_running_loop().run_in_executor(executor, self._live_blocking)
        finally:
            self.pipeline.set_source(SourceState())
            self.source = "live"

    async def select(self, executor: Executor, source: str) -> None:
        """Flow 6 (live) or back to the last virtual input (virtual).

        Virtual before any input is refused (ApiError, conflict), the source staying live: the mux
        would feed the core nothing, and the views would show live raw frames beside black
        rectified ones under a header saying virtual.

        A mux that does not take the change (its commit times out) is an ApiError (unavailable) naming
        the source the status then shows; nothing else changes.
        """
        await self.stop_player()
        async with self.lock:
            if source == "live":
                await self._back_to_live(executor)
                return
            if self.input is None:
                raise ApiError("the virtual camera has no input yet: upload a pair "
                               "(POST /api/virtual-camera) or send a capture to it first; "
                               "the source stays live", kind=Kind.CONFLICT)
            frame = self.input
        await self.send(executor, frame, self.origin or "upload")

    # -- a recording played through the core ---------------------------------------------------------
    async def stop_player(self) -> None:
        """Stop the recording playing, if one is (its last frame stays the input)."""
        player, self.player = self.player, None
        if player is not None:
            await player.stop()

    def _next_blocking(self, frame: np.ndarray) -> int:
        """The next frame of a sequence down MM2S (the mux is already on virtual); FRAME_COUNT then."""
        self.overlay.send_virtual(frame)
        self.overlay.wait_virtual_taken(max(PARK_WAIT_S, self._frames(3)))
        return int(self.pipeline.frame_count())

    async def show_next(self, executor: Executor, frame: np.ndarray) -> None:
        """Put the next frame of a playing sequence on the virtual camera (no round trip waited for).

        The pipeline labels the processed frames from ``ROUND_TRIP_FRAMES`` later with it as
        their raw pair, as for an upload.
        """
        frame.flags.writeable = False
        async with self.lock:
            if self.source != "virtual":
                raise ApiError("the source is no longer virtual", kind=Kind.CONFLICT)
            count = await asyncio.get_running_loop().run_in_executor(executor, self._next_blocking, frame)
            effective = (count + ROUND_TRIP_FRAMES) % COUNT_MOD
            self.pipeline.set_source(SourceState("virtual", frame, effective))
            self.input, self.effective_count = frame, effective

    async def actual_frame(self, with_depth: bool = False) -> FrameSet:
        """The fabric's output for the current input: a fresh frame while virtual, else the stored result.

        ``with_depth``: a fresh frame carries the stereo core's output, where there is a core.
        """
        if self.source == "virtual" and self.input is not None:
            return await self._virtual_frame(with_depth)
        assert self.result is not None
        return self.result
