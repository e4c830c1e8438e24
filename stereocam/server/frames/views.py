"""Views: the images the daemon shows, derived from a :class:`~.pipeline.FrameSet`.

``raw_left``/``raw_right`` (the cameras, or the virtual-camera input while
the source is virtual), ``rect_left``/``rect_right`` (the rectify core's
output), ``sbs`` (rectified left | right), ``anaglyph`` (red = rectified
left gray, green and blue = rectified right gray), ``disparity`` (the
fabric's stereo core, ``depth.py``; where the bitstream has none, OpenCV
StereoBM on the ARM with the paper's parameters: disparities 0 to 128,
block 19, uniqueness 15; JET colour map of 0 to 128 px, black where no
disparity was found) and ``depth`` (that disparity in metres through the
calibration's Q, Z = f B / d: a fixed JET scale, red at
:data:`DEPTH_NEAR_M` to blue at :data:`DEPTH_FAR_M` and beyond, black where
there is no disparity or no calibration gives depth). ``gray`` selects the
gray (Y) channel of the raw, rect and sbs views; the other views are always colour.

:func:`render` returns an image ready for ``cv2.imencode``: a contiguous
``(H, W, 3)`` BGR or ``(H, W)`` gray uint8 array, computed once per frame
set and view (cached in the set, shared by every thread) and read-only.
It blocks (numpy/OpenCV work): call it from a worker thread.

:class:`DisparityWorker` computes the disparity view off the hot path, at
most ``fps`` times a second and only while somebody holds it.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import dataclasses
import logging
import threading
import time
from typing import Any, Callable, Dict, Optional, Protocol, Tuple

import cv2
import numpy as np

from ...overlays.spec import pixel
from ...overlays.spec.stereo import SUBPIX_ONE
from ..stores.frame_calibration import DepthScale
from .depth import DepthNotTaken, needs_depth, stereo_of
from .pipeline import FrameSet, RateMeter

log = logging.getLogger(__name__)

__all__ = [
    "View", "REGISTRY", "VIEWS", "DISPARITY_WORKER", "uses_disparity_worker", "GRAY_VIEWS", "RAW_VIEWS",
    "ViewUnavailable", "render", "view_size", "disparity_map", "disparity_raw", "no_signal_image",
    "DisparityWorker", "STEREO_BM", "DEPTH_NEAR_M", "DEPTH_FAR_M", "needs_disparity",
]


@dataclasses.dataclass(frozen=True)
class View:
    """One view of the registry: everything the daemon, the page (``GET /api/views``), the bench
    and the tests know of it. ``renders`` says how (``camera`` (a camera of the raw or the
    rectified pair), ``hconcat`` (rectified left | right), ``anaglyph``, ``disparity``); ``gray``:
    ``gray=1`` gives its gray channel; ``raw``: it needs the raw pair copied out of the frame
    stores; ``worker``: the background worker that computes it (None: rendered per frame);
    ``wide``: twice the frame's width; ``readout``: the page's point readout (depth.js) works over
    it, its pixels being the rectified frame's; ``caption`` and ``alt``: the page's words for it."""

    name: str
    caption: str
    alt: str
    renders: str
    gray: bool = False
    raw: bool = False
    worker: Optional[str] = None
    wide: bool = False
    readout: bool = False

    def as_json(self) -> Dict[str, Any]:
        return dataclasses.asdict(self)


DISPARITY_WORKER = "disparity"  # the one worker: DisparityWorker, held while such a view is watched

# The one list of views, in the page's order (its figures, the 1..N shortcuts). A new view is a
# line here (and, for a new ``renders``, a branch of _render): the page (GET /api/views), the
# bench and the tests read this; tests/server/test_view_registry.py fails on a list of views elsewhere.
REGISTRY: Tuple[View, ...] = (
    View("raw_left", "raw left", "raw left camera", "camera", gray=True, raw=True),
    View("raw_right", "raw right", "raw right camera", "camera", gray=True, raw=True),
    View("rect_left", "rectified left", "rectified left", "camera", gray=True, readout=True),
    View("rect_right", "rectified right", "rectified right", "camera", gray=True, readout=True),
    View("sbs", "side by side (rectified)", "rectified side by side", "hconcat", gray=True, wide=True,
         readout=True),
    View("anaglyph", "anaglyph", "anaglyph", "anaglyph"),
    View("disparity", "disparity", "disparity", "disparity", worker=DISPARITY_WORKER, readout=True),
    View("depth", "depth (m)", "depth in metres", "depth", worker=DISPARITY_WORKER, readout=True),
)
VIEWS = tuple(v.name for v in REGISTRY)
GRAY_VIEWS = frozenset(v.name for v in REGISTRY if v.gray)
RAW_VIEWS = frozenset(v.name for v in REGISTRY if v.raw)
_BY_NAME = {v.name: v for v in REGISTRY}


def uses_disparity_worker(view: str) -> bool:
    """Whether ``view`` is computed by the :class:`DisparityWorker` (its registry entry says so)."""
    return _BY_NAME[view].worker == DISPARITY_WORKER


def needs_disparity(view: str) -> bool:
    """Whether ``view`` shows the disparity: its frames must carry the stereo core's output, where there
    is a core (hold ``Pipeline.depth_wanted`` while it is watched)."""
    return _BY_NAME[view].renders in ("disparity", "depth")

# The paper's block-matching parameters.
STEREO_BM = {"min_disparity": 0, "num_disparities": 128, "block_size": 19, "uniqueness_ratio": 15}

_FIRST = {"left": pixel.LEFT.start, "right": pixel.RIGHT.start}  # each camera's first byte of a pixel
_BGR = {side: [o + pixel.B, o + pixel.G, o + pixel.R] for side, o in _FIRST.items()}
_Y = {side: o + pixel.Y for side, o in _FIRST.items()}


class ViewUnavailable(LookupError):
    """The frame set lacks what the view needs (the raw pair or the stereo core's output was not read)."""


def view_size(view: str, frame_size: Tuple[int, int], scale: float = 1.0) -> Tuple[int, int]:
    """``(width, height)`` of ``view`` for frames of ``frame_size``, scaled by ``scale`` (at least 1 px)."""
    w, h = frame_size
    w = 2 * w if _BY_NAME[view].wide else w
    if scale == 1.0:
        return w, h
    return max(1, round(w * scale)), max(1, round(h * scale))


def render(fs: FrameSet, view: str, gray: bool = False, scale: float = 1.0) -> np.ndarray:
    """The image of ``view`` for ``fs`` (module doc), ``scale`` times its size (area-averaged);
    ViewUnavailable, or KeyError for a bad view."""
    if view not in VIEWS:
        raise KeyError(f"unknown view {view!r}")
    gray = bool(gray) and view in GRAY_VIEWS
    if scale != 1.0:
        def scaled() -> np.ndarray:
            full = render(fs, view, gray)
            size = (max(1, round(full.shape[1] * scale)), max(1, round(full.shape[0] * scale)))
            out = cv2.resize(full, size, interpolation=cv2.INTER_AREA)
            out.flags.writeable = False
            return out

        return fs.cache.get(("view", view, gray, scale), scaled)
    try:
        return fs.cache.get(("view", view, gray), lambda: _render(fs, view, gray))
    except DepthNotTaken as exc:
        raise ViewUnavailable(str(exc)) from None


def _camera(frame: np.ndarray, side: str, gray: bool) -> np.ndarray:
    if gray:
        out = np.ascontiguousarray(frame[..., _Y[side]])
    else:  # three plane copies: C-contiguous (fancy indexing is not, and OpenCV would copy it again)
        out = np.empty(frame.shape[:2] + (3,), dtype=np.uint8)
        for i, channel in enumerate(_BGR[side]):
            out[..., i] = frame[..., channel]
    out.flags.writeable = False
    return out


def _render(fs: FrameSet, view: str, gray: bool) -> np.ndarray:
    renders = _BY_NAME[view].renders
    if renders == "camera":
        side = "left" if view.endswith("_left") else "right"
        if view in RAW_VIEWS:
            if fs.raw is None:
                raise ViewUnavailable(f"frame {fs.frame} was read without its raw pair")
            return _camera(fs.raw, side, gray)
        return _camera(fs.processed, side, gray)
    if renders == "hconcat":
        out = cv2.hconcat([render(fs, "rect_left", gray), render(fs, "rect_right", gray)])
    elif renders == "anaglyph":
        p = fs.processed
        out = np.empty(p.shape[:2] + (3,), dtype=np.uint8)
        out[..., 0] = p[..., _Y["right"]]
        out[..., 1] = p[..., _Y["right"]]
        out[..., 2] = p[..., _Y["left"]]
    elif renders == "disparity":
        out = disparity_view(fs)
    elif renders == "depth":
        out = depth_view(fs)
    else:  # a registry entry whose kind has no branch here
        raise KeyError(f"view {view!r} renders as {renders!r}, which _render does not know")
    out.flags.writeable = False
    return out


# -- disparity --------------------------------------------------------------------------------

_local = threading.local()


#: The scales the ARM's StereoBM runs at (``FrameSet.arm_scale``). At 0.5, where its budget is the
#: board's (a Cortex-A9 takes 1.8-2.7 s for StereoBM at full size, stereocam/board/a9_costs.json), it
#: matches the pair at half size with half the disparities and a block of 9: the same range of
#: disparity in full-size pixels, an eighth of the work; the map is scaled back to full size.
ARM_SCALES = (1.0, 0.5)
HALF_BM = {"num_disparities": STEREO_BM["num_disparities"] // 2, "block_size": 9}


def arm_matcher(scale: float) -> Dict[str, int]:
    """StereoBM's parameters at ``scale`` (one of :data:`ARM_SCALES`)."""
    return dict(STEREO_BM) if scale == 1.0 else {**STEREO_BM, **HALF_BM}


def arm_status(scale: float, frame_size: Tuple[int, int], fps: float) -> Dict[str, Any]:
    """How the ARM computes the disparity views (``/api/status``'s ``disparity.arm``, the page's
    status panel): the size StereoBM matches at, its disparities and block, the views' rate at most,
    and the same in words."""
    p = arm_matcher(scale)
    w, h = (max(1, round(n * scale)) for n in frame_size)
    size = "full size" if scale == 1.0 else f"half size ({w}x{h})"
    return {"scale": scale, "size": [w, h], "num_disparities": p["num_disparities"],
            "block_size": p["block_size"], "max_fps": fps,
            "text": f"StereoBM at {size}, {p['num_disparities']} disparities, block {p['block_size']}, "
                    f"at most {fps:g} fps"}


def _matcher(scale: float = 1.0) -> Any:
    cache = getattr(_local, "bm", None)
    if cache is None:  # StereoBM objects are not thread-safe: one per thread
        cache = _local.bm = {}
    bm = cache.get(scale)
    if bm is None:
        p = arm_matcher(scale)
        bm = cv2.StereoBM.create(numDisparities=p["num_disparities"], blockSize=p["block_size"])
        bm.setMinDisparity(p["min_disparity"])
        bm.setUniquenessRatio(p["uniqueness_ratio"])
        cache[scale] = bm
    return bm


def disparity_map(left_gray: np.ndarray, right_gray: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """StereoBM disparities (int16, 1/16 pixel of the full-size pair; negative where none was found)
    of a rectified gray pair, matched at ``scale`` of its size (:data:`ARM_SCALES`)."""
    if scale not in ARM_SCALES:
        raise ValueError(f"the ARM's StereoBM runs at one of the scales {ARM_SCALES}, not {scale!r}")
    left, right = np.ascontiguousarray(left_gray), np.ascontiguousarray(right_gray)
    if scale == 1.0:
        return _matcher().compute(left, right)
    h, w = left.shape
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = _matcher(scale).compute(cv2.resize(left, size, interpolation=cv2.INTER_AREA),
                                    cv2.resize(right, size, interpolation=cv2.INTER_AREA))
    full = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)
    return full * np.int16(round(1 / scale))  # in full-size pixels; none stays negative


def colour_disparity(disp16: np.ndarray) -> np.ndarray:
    """JET colour map of 0..128 pixels of disparity; black where none was found (OpenCV's vector
    code throughout: numpy's masked assignment cost a Cortex-A9 more than the colour map)."""
    scale = 255.0 / (16 * (STEREO_BM["min_disparity"] + STEREO_BM["num_disparities"]))
    level = cv2.convertScaleAbs(disp16, alpha=scale)
    colour = cv2.applyColorMap(level, cv2.COLORMAP_JET)
    found = (disp16 >= 16 * STEREO_BM["min_disparity"]).view(np.uint8)
    return cv2.bitwise_and(colour, colour, mask=found)


def disparity_view(fs: FrameSet, charge: Optional[Callable[[str, float], None]] = None) -> np.ndarray:
    """The colour-mapped disparity of ``fs`` (cached in the set; blocks for tens of milliseconds).

    ``charge("match", seconds)`` gets the CPU time of the computation when it runs.
    """
    def compute() -> np.ndarray:
        cpu = time.thread_time()
        out = colour_disparity(disparity_raw(fs))
        out.flags.writeable = False
        if charge is not None:
            charge("match", time.thread_time() - cpu)
        return out

    return fs.cache.get(("disparity",), compute)


def disparity_raw(fs: FrameSet) -> np.ndarray:
    """The disparities of ``fs`` (int16, 1/16 px, negative where none; read-only; cached in the set, so
    the readout and the ruler read the very map the disparity view shows): the stereo core's output,
    or StereoBM's on the ARM where the overlay has no core. Blocks for tens of milliseconds;
    :class:`~.depth.DepthNotTaken` for a set read without the core's output."""
    def compute() -> np.ndarray:
        core = stereo_of(fs)
        if core is not None:
            out = core.disp.astype(np.int16)  # codes up to 16 x 128: they fit
            out[~core.valid] = -SUBPIX_ONE
        else:
            p = fs.processed
            out = disparity_map(p[..., _Y["left"]], p[..., _Y["right"]], fs.arm_scale)
        out.flags.writeable = False
        return out

    return fs.cache.get(("disparity16",), compute)


# -- depth in metres --------------------------------------------------------------------------

DEPTH_NEAR_M = 0.3  # red
DEPTH_FAR_M = 6.0  # blue, and everything farther


def depth_metres(disp16: np.ndarray, scale: DepthScale) -> np.ndarray:
    """Z in metres (float32) of 1/16-px disparities by the calibration's Q; NaN where none or not ahead."""
    Q = scale.Q
    unit = scale.unit_m
    d = disp16.astype(np.float32) / SUBPIX_ONE
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.float32(Q[2][3]) / (np.float32(Q[3][2]) * d + np.float32(Q[3][3]))
    z *= np.float32(unit if unit is not None else np.nan)
    z[(disp16 < 0) | ~np.isfinite(z) | (z <= 0)] = np.nan
    return z


def colour_depth(z: np.ndarray) -> np.ndarray:
    """JET from red at :data:`DEPTH_NEAR_M` to blue at :data:`DEPTH_FAR_M` (clipped); black where NaN."""
    span = DEPTH_FAR_M - DEPTH_NEAR_M
    level = np.nan_to_num(255.0 * (DEPTH_FAR_M - z) / span, nan=0.0)
    out = cv2.applyColorMap(np.clip(level, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
    out[np.isnan(z)] = 0
    return out


def depth_view(fs: FrameSet) -> np.ndarray:
    """The depth of ``fs`` in colour (cached in the set; blocks): black all over where the frame's
    calibration gives no depth in metres (none, or its unit unknown)."""
    def compute() -> np.ndarray:
        disp16 = disparity_raw(fs)
        cal = fs.calibration
        scale = cal.depth if cal is not None else None
        if scale is None or scale.unit_m is None:
            return np.zeros(disp16.shape + (3,), dtype=np.uint8)
        return colour_depth(depth_metres(disp16, scale))

    out: np.ndarray = fs.cache.get(("depth",), compute)
    return out


# -- no signal --------------------------------------------------------------------------------

def no_signal_image(size: Tuple[int, int], detail: str) -> np.ndarray:
    """A ``(H, W, 3)`` BGR frame saying NO SIGNAL, with one line of ``detail`` under it."""
    w, h = size
    out = np.full((h, w, 3), 40, dtype=np.uint8)
    out[:, :, 2] = 60
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines = (("NO SIGNAL", max(0.8, w / 300.0), 3, -0.05), (detail, max(0.4, w / 1500.0), 1, 0.12))
    for text, scale, thick, dy in lines:
        scale = min(scale, 3.0) if text == "NO SIGNAL" else scale
        (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
        while tw > w - 8 and scale > 0.3:
            scale *= 0.9
            (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
        org = (max(4, (w - tw) // 2), int(h * (0.5 + dy)) + th // 2)
        cv2.putText(out, text, org, font, scale, (235, 235, 235), thick, cv2.LINE_AA)
    return out


def no_signal_detail(since: float, last_frame: Optional[int]) -> str:
    stamp = time.strftime("%H:%M:%S", time.localtime(since))
    last = f" (last frame {last_frame})" if last_frame is not None else ""
    return f"no frame from the fabric since {stamp}{last}"


# -- the disparity worker ---------------------------------------------------------------------

class _Broadcast(Protocol):
    @property
    def closed(self) -> bool: ...

    def close(self) -> None: ...

    def publish(self, value: Any) -> None: ...

    def current(self) -> Tuple[int, Any]: ...

    async def wait_newer(self, seq: int) -> Tuple[int, Any]: ...


class DisparityWorker:
    """Publishes frame sets whose disparity view is ready, at most ``fps`` per second, while held.

    ``source`` and ``output`` are :class:`~.feed.Latest` broadcasts of
    feed items (frame sets and no-signal markers; markers pass straight
    through). The matching runs on a thread of its own, so it never delays
    the encoders. :meth:`acquire`/:meth:`release` count holders; the task
    runs only while there is one. Event-loop thread only.
    """

    def __init__(self, source: _Broadcast, output: _Broadcast, *, fps: float,
                 executor: Optional[concurrent.futures.Executor] = None,
                 charge: Optional[Callable[[str, float], None]] = None) -> None:
        self.source = source
        self.output = output
        self.fps = fps
        self.limit: Optional[float] = None  # the CPU budget's planned rate (None: no limit)
        self._charge = charge
        self._executor = executor or concurrent.futures.ThreadPoolExecutor(
            1, thread_name_prefix="stereocam-disparity")
        self._own_executor = executor is None
        self._holders = 0
        self._task: Optional[asyncio.Task[None]] = None
        self.meter = RateMeter()
        self.seconds = 0.0
        self.count = 0

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def acquire(self) -> None:
        self._holders += 1
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._run(), name="stereocam-disparity")

    def release(self) -> None:
        self._holders = max(0, self._holders - 1)
        if self._holders == 0 and self._task is not None:
            self._task.cancel()
            self._task = None

    async def close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            try:
                await task
            except asyncio.CancelledError:
                pass
        if self._own_executor:
            self._executor.shutdown(wait=False)

    async def _run(self) -> None:
        try:
            await self._loop()
        except Exception:
            if not self.source.closed:
                raise
            self.output.close()  # the feed closed (BroadcastClosed): shutdown

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        seq = 0
        next_at = 0.0
        while True:
            seq, item = await self.source.wait_newer(seq)
            if not item.signal:
                self.output.publish(item)
                continue
            wait = next_at - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
                seq, item = self.source.current()  # the newest, not the one that woke us
                if not item.signal:
                    continue
            if needs_depth(item):
                continue  # read before the worker held depth_wanted: the next one carries it
            started = loop.time()
            rate = self.fps if self.limit is None else min(self.fps, self.limit)
            next_at = started + 1.0 / max(rate, 1e-3)
            try:
                await loop.run_in_executor(self._executor, disparity_view, item, self._charge)
            except Exception as exc:  # a bad frame must not stop the view
                log.warning("disparity of frame %s failed: %s", getattr(item, "frame", "?"), exc)
                continue
            self.seconds += loop.time() - started
            self.count += 1
            self.meter.mark()
            self.output.publish(item)
