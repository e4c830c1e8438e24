"""Fixtures for the daemon's tests: an emulated overlay on a still frame, the daemon served on 127.0.0.1.

Import what a module needs. The fixture is ``start_daemon``: tests/server/conftest.py gives it
to every module there; elsewhere, import it as
``from ..server.daemon import start_daemon_fixture  # noqa: F401``.

- :func:`make_overlay` builds an :class:`EmulatedOverlay` whose cameras show
  one rendered frame of the synthetic rig (rendered once per size and
  process), at a low frame rate, so a running daemon costs little CPU.
  ``clock="stepped"`` gives a fabric that moves only on ``overlay.step()``.
- ``start_daemon(**settings)`` (fixture) starts the real server
  (:func:`stereocam.server.http.app.serve`, the production runner, with production's
  extensions unless ``extensions=`` names others) on
  127.0.0.1 with a free port and returns a :class:`Daemon`: ``.http`` is an
  ``aiohttp.ClientSession`` on its base URL, ``.app`` the application,
  ``.overlay`` the overlay. Every daemon is stopped (and its overlay closed)
  at the end of the test; ``await daemon.stop()`` stops one earlier and
  returns the seconds the shutdown took.

Every wait here waits for its condition; its bound (:data:`WAIT_S` unless a test says
otherwise) is a last resort that only a hang reaches, so a busy machine makes a test slower,
not red.
"""
from __future__ import annotations

import asyncio
import contextlib
import functools
import io
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, AsyncIterator, Awaitable, Callable, Dict, Iterator, List, Optional, Tuple

import aiohttp
import numpy as np
import pytest
from aiohttp import FormData, web
from PIL import Image

from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.server.frames.pipeline import FrameSet
from stereocam.server.http.app import create_app, default_extensions, program_default_calibration, serve
from stereocam.server.http.settings import Settings
from stereocam.server.http.state import CALIBRATION

from ..slowness import SLOWNESS

SMALL = (376, 240)
W, H = SMALL  # the width and height of a test daemon's frames unless a test gives another size
FULL = (752, 480)
TEST_FPS = 25.0
# The last-resort bound of a wait for something that does happen (start, stop, frames, parts).
WAIT_S = 60.0 * SLOWNESS


class HandFeed:
    """What a recording needs of the pipeline (``raw_wanted``, ``every_frame``): the test calls
    ``sink`` with the frames it makes, so a recorder sees exactly those, when the test says."""

    def __init__(self) -> None:
        self.sink: Optional[Callable[[FrameSet], None]] = None

    def raw_wanted(self) -> contextlib.AbstractContextManager[None]:
        return contextlib.nullcontext()

    @contextlib.contextmanager
    def every_frame(self, sink: Callable[[FrameSet], None]) -> Iterator[None]:
        self.sink = sink
        try:
            yield
        finally:
            self.sink = None


@functools.lru_cache(maxsize=4)
def rig_frame(size: Tuple[int, int] = SMALL) -> Tuple[np.ndarray, Any]:
    """One rendered ``(H, W, 8)`` frame of the synthetic rig (read-only) and the rig's calibration model."""
    with SyntheticRig(size=size, motion=False) as rig:
        frame = rig.read(0, 0.0)
        model = rig.model
    frame.flags.writeable = False
    return frame, model


class StillSource:
    """A camera source that shows one frame forever (the CameraSource protocol, plus the rig's ``model``)."""

    def __init__(self, size: Tuple[int, int] = SMALL) -> None:
        self.frame, self.model = rig_frame(size)
        self.reads = 0

    @property
    def frame_size(self) -> Tuple[int, int]:
        h, w = self.frame.shape[:2]
        return w, h

    def read(self, index: int, t: float) -> np.ndarray:
        self.reads += 1
        return self.frame

    def close(self) -> None:
        pass


def make_overlay(*, size: Tuple[int, int] = SMALL, fps: float = TEST_FPS, clock: str = "realtime",
                 calibrate: bool = True, stereo: bool = True) -> EmulatedOverlay:
    """``stereo`` False: a fabric without the stereo core (today's bitstream)."""
    overlay = EmulatedOverlay(source=StillSource(size), fps=fps, clock=clock, stereo=stereo)
    if calibrate:
        program_default_calibration(overlay, Settings())
    return overlay


@dataclass
class Daemon:
    app: web.Application
    overlay: EmulatedOverlay
    config: Settings
    url: str
    http: aiohttp.ClientSession
    _stop: asyncio.Event
    _task: "asyncio.Task[None]"
    stopped: bool = False
    extra_sessions: List[aiohttp.ClientSession] = field(default_factory=list)

    @property
    def port(self) -> int:
        return int(self.url.rstrip("/").rsplit(":", 1)[1])

    def session(self, **kwargs: Any) -> aiohttp.ClientSession:
        """Another client session on the daemon (closed with it)."""
        s = aiohttp.ClientSession(base_url=self.url, **kwargs)
        self.extra_sessions.append(s)
        return s

    async def stop(self, *, close_sessions: bool = True, close_overlay: bool = True) -> float:
        """Stop serving (as SIGTERM does) and return how long the shutdown took."""
        if self.stopped:
            return 0.0
        self.stopped = True
        if close_sessions:
            await self.close_sessions()
        t0 = time.monotonic()
        self._stop.set()
        await asyncio.wait_for(self._task, WAIT_S)
        took = time.monotonic() - t0
        if close_overlay:
            close_overlay_when_idle(self.overlay)
        return took

    async def json(self, method: str, path: str, **kwargs: Any) -> Tuple[int, Any]:
        """``method path`` (``kwargs`` as ``aiohttp`` takes them): the answer's status and JSON body."""
        async with self.http.request(method, path, **kwargs) as resp:
            return resp.status, await resp.json()

    async def close_sessions(self) -> None:
        for s in [self.http, *self.extra_sessions]:
            await s.close()


StartDaemon = Callable[..., Awaitable[Daemon]]


async def start_uncalibrated(start_daemon: StartDaemon) -> Daemon:
    """A daemon with frames coming that says what one whose core passes frames through says: no
    calibration, so no depth."""
    daemon = await start_daemon()
    await wait_for_frames(daemon)
    in_effect = daemon.app[CALIBRATION]
    in_effect.swap(replace(in_effect.now, calibration=None))
    return daemon


def close_overlay_when_idle(overlay: EmulatedOverlay) -> None:
    """Stop the fabric's frame clock, waiting for the tick in progress, then close the overlay.

    ``overlay.close()`` gives that tick 2 s and then raises ClockStopTimeout; a full-size tick on a
    busy machine can take longer, so the wait here is WAIT_S (a tick that never ends still fails).
    """
    overlay.emulation.clock.stop(timeout=WAIT_S)
    overlay.close()


@pytest.fixture(name="start_daemon")
async def start_daemon_fixture(tmp_path: Path) -> AsyncIterator[StartDaemon]:
    """``start_daemon(**settings)``: see the module doc."""
    running: List[Daemon] = []

    async def start(*, overlay: Optional[EmulatedOverlay] = None, calibrate: bool = True,
                    extensions: Any = None, **settings: Any) -> Daemon:
        settings.setdefault("captures", str(tmp_path / "captures"))
        settings.setdefault("port", 0)
        settings.setdefault("min_free_mb", 0)
        config = Settings(**settings)
        if overlay is None:
            overlay = make_overlay(calibrate=False)
        calibration = program_default_calibration(overlay, config) if calibrate else None
        if extensions is None:  # production's app, as `stereocam serve` builds it
            extensions = default_extensions()
        app = create_app(config, overlay, calibration=calibration, extensions=extensions)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        ready: "asyncio.Future[str]" = loop.create_future()
        task = loop.create_task(serve(app, config, stop=stop, handle_signals=False,
                                      on_ready=lambda url: ready.set_result(url)))
        done, _ = await asyncio.wait({task, ready}, timeout=WAIT_S, return_when=asyncio.FIRST_COMPLETED)
        if ready not in done:
            overlay.close()
            if task in done:
                task.result()  # raises what went wrong
            raise TimeoutError(f"the daemon did not start within {WAIT_S} s")
        url = ready.result()
        daemon = Daemon(app=app, overlay=overlay, config=config, url=url,
                        http=aiohttp.ClientSession(base_url=url), _stop=stop, _task=task)
        running.append(daemon)
        return daemon

    yield start
    for daemon in running:
        await daemon.stop()
        await daemon.close_sessions()
        close_overlay_when_idle(daemon.overlay)


async def until(condition: Callable[[], bool], what: str) -> None:
    """Wait (on the loop) until ``condition()``; fail naming ``what`` after the last-resort WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {WAIT_S} s"
        await asyncio.sleep(0.02)


async def wait_for_frames(daemon: Daemon, n: int = 2, timeout: float = WAIT_S) -> None:
    """Wait until the pipeline has seen ``n`` frames complete (copied or not: nobody may be watching)."""
    from stereocam.server.http.state import PIPELINE

    pipeline = daemon.app[PIPELINE]
    deadline = time.monotonic() + timeout
    while pipeline.frames_seen < n:
        if time.monotonic() > deadline:
            raise AssertionError(f"only {pipeline.frames_seen} frames in {timeout} s")
        await asyncio.sleep(0.02)


def parse_parts(data: bytes) -> List[Tuple[dict, bytes]]:
    """The complete parts of a multipart/x-mixed-replace body with boundary ``frame``: (headers, body)."""
    parts = []
    pos = 0
    while True:
        start = data.find(b"--frame\r\n", pos)
        if start < 0:
            break
        head_end = data.find(b"\r\n\r\n", start)
        if head_end < 0:
            break
        headers = {}
        for line in data[start + 9:head_end].decode("ascii").split("\r\n"):
            k, v = line.split(":", 1)
            headers[k.strip().lower()] = v.strip()
        length = int(headers["content-length"])
        body_start = head_end + 4
        if len(data) < body_start + length + 2:
            break
        parts.append((headers, data[body_start:body_start + length]))
        assert data[body_start + length:body_start + length + 2] == b"\r\n"
        pos = body_start + length + 2
    return parts


async def read_parts(resp: aiohttp.ClientResponse, n: int, timeout: float = WAIT_S
                     ) -> List[Tuple[dict, bytes]]:
    """Read a stream response until ``n`` complete parts arrived."""
    buf = b""
    deadline = time.monotonic() + timeout
    while True:
        parts = parse_parts(buf)
        if len(parts) >= n:
            return parts[:n]
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise AssertionError(f"only {len(parts)} of {n} parts within {timeout} s")
        chunk = await asyncio.wait_for(resp.content.readany(), remaining)
        if not chunk:
            raise AssertionError(f"the stream ended after {len(parts)} parts")
        buf += chunk


def png(array: np.ndarray) -> bytes:
    """``array`` (gray, or RGB in that order) as a PNG file."""
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def pair_form(left: np.ndarray, right: np.ndarray, fit: "str | None" = None) -> FormData:
    """A pair (PNG files ``left`` and ``right``) to upload to the virtual camera, with ``fit`` if given."""
    out = FormData()
    out.add_field("left", png(left), filename="left.png", content_type="image/png")
    out.add_field("right", png(right), filename="right.png", content_type="image/png")
    if fit is not None:
        out.add_field("fit", fit)
    return out


async def show_pair(daemon: Daemon, left: np.ndarray, right: np.ndarray) -> Dict[str, Any]:
    """Put a pair on the virtual camera (the raw frames the daemon works on from now on): its answer."""
    async with daemon.http.post("/api/virtual-camera", data=pair_form(left, right)) as resp:
        assert resp.status == 200, await resp.text()
        answer: Dict[str, Any] = await resp.json()
        return answer


def bad_id_status(bad: str, path: str) -> int:
    """A dot segment (``..``, ``%2E%2E``) is removed from the URL before routing, leaving a path that
    no route has: 404. Any other id that is not a capture id (``..`` inside ``...zip`` included): 400."""
    return 404 if bad in ("..", "%2E%2E") and not path.endswith(".zip") else 400
