"""Stream outputs: MJPEG over HTTP, snapshots, and the page's WebSocket.

Every client is one task that loops "wait for a newer encoded frame of my
key, write it": it shares the bytes the encoder produced (no per-client
encode, no per-client queue), skips whatever it missed while its write was
blocked, and paces itself to the ``fps`` it asked for. A client whose write
does not complete within ``stream_timeout_s`` is aborted by the sweeper
(:meth:`StreamClients.sweep`); beyond ``max_streams`` clients (MJPEG and
WebSocket together) the answer is 503. Each client records how far the
frames it was sent lagged the newest frame at the moment they were sent
(``lag_max_frames``, ``lag_max_s`` in ``/api/status`` ``streams``): the
newest-frame rule, checked as it runs.

Routes (see API.md): ``GET /stream/{view}``, ``GET /snapshot/{view}.jpg|png``,
``GET /ws``.
"""
from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import math
import struct
import termios
import time
from dataclasses import dataclass, field
from typing import Any, Awaitable, Callable, Dict, Iterator, Optional, Tuple

from aiohttp import WSCloseCode, WSMsgType, web

from ..errors import ApiError, parse_json
from ..frames.depth import needs_depth
from ..frames.encoders import BOUNDARY, Encoded, EncoderKey, Pacer, encoded_for, png_for
from ..frames.feed import BroadcastClosed, Latest
from ..frames.pipeline import FrameSet
from ..frames.views import GRAY_VIEWS, RAW_VIEWS, VIEWS, needs_disparity
from .errors import shutting_down
from .settings import MAX_FPS
from .state import ENCODERS, EXECUTORS, FEED, PIPELINE, SETTINGS

log = logging.getLogger(__name__)

__all__ = ["StreamClients", "StreamClient", "STREAMS", "StreamParams", "parse_params", "send_newest",
           "setup_routes"]



# -- clients -------------------------------------------------------------------------------

@dataclass(eq=False)
class StreamClient:
    kind: str  # "mjpeg" | "ws"
    view: str
    peer: str
    transport: Optional[asyncio.BaseTransport]  # aborted when the client is dropped
    started: float = field(default_factory=time.monotonic)
    writing_since: Optional[float] = None  # monotonic start of the write in progress
    frames: int = 0
    ws: Optional[web.WebSocketResponse] = None
    last_frame: Optional[int] = None  # the frame number of the last frame sent
    lag_max_s: float = 0.0  # the most a frame sent lagged the newest frame the daemon had, when it was sent
    lag_max_frames: int = 0  # the same in frame numbers

    def sending(self, encoded: Encoded, newest: Optional[FrameSet]) -> None:
        """Note that ``encoded`` is about to be written; ``newest`` is the newest frame set the pipeline
        has delivered (the feed's ``last_frame``). A frame that lags it is one a client gets late:
        a slow reader must still get the newest frame when it can take one."""
        self.writing_since = time.monotonic()
        if not encoded.signal:
            return
        self.last_frame = encoded.frame
        if newest is not None:
            self.lag_max_s = max(self.lag_max_s, newest.timestamp - encoded.timestamp)
            self.lag_max_frames = max(self.lag_max_frames, newest.frame - encoded.frame)

    def to_json(self) -> Dict[str, Any]:
        return {"kind": self.kind, "view": self.view, "peer": self.peer, "frames": self.frames,
                "seconds": round(time.monotonic() - self.started, 1), "last_frame": self.last_frame,
                "lag_max_s": round(self.lag_max_s, 4), "lag_max_frames": self.lag_max_frames}


class StreamClients:
    """Who is streaming: the ``max_streams`` limit, the write timeout, closing on shutdown (loop thread)."""

    def __init__(self, *, max_streams: int, timeout: float) -> None:
        self.max_streams = max_streams
        self.timeout = timeout
        self.clients: Dict[int, StreamClient] = {}
        self.total = 0
        self.refused = 0
        self.dropped = 0
        self.closing = False

    def __len__(self) -> int:
        return len(self.clients)

    def full(self) -> bool:
        return len(self.clients) >= self.max_streams

    def admit(self) -> None:
        """Raise the 503 for a new client while the daemon stops or ``max_streams`` clients watch."""
        if self.closing:
            raise shutting_down()
        if self.full():
            self.refused += 1
            raise ApiError(f"too many streams: {self.max_streams} clients are watching already "
                           "(max_streams); close one or try again later", status=503,
                           headers={"Retry-After": "5"})

    @contextlib.contextmanager
    def client(self, request: web.Request, kind: str, view: str) -> Iterator[StreamClient]:
        c = StreamClient(kind=kind, view=view, peer=str(request.remote or "?"), transport=request.transport)
        self.clients[id(c)] = c
        self.total += 1
        try:
            yield c
        finally:
            self.clients.pop(id(c), None)

    def by_kind(self) -> Dict[str, int]:
        out = {"mjpeg": 0, "ws": 0}
        for c in self.clients.values():
            out[c.kind] = out.get(c.kind, 0) + 1
        return out

    def _drop(self, c: StreamClient) -> None:
        """Abort the client's connection: what it buffered is discarded and its next write fails."""
        self.dropped += 1
        transport = c.transport
        if isinstance(transport, asyncio.Transport) and not transport.is_closing():
            transport.abort()

    async def sweep(self) -> None:
        """Drop clients whose write has been blocked for ``timeout`` s (run as a task; cancel to stop)."""
        period = max(0.05, min(1.0, self.timeout / 4))
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            for c in list(self.clients.values()):
                if c.writing_since is not None and now - c.writing_since > self.timeout:
                    log.info("dropping %s client %s of %s: a frame write took over %.1f s",
                             c.kind, c.peer, c.view, self.timeout)
                    self._drop(c)

    async def close_all(self, grace: float = 0.3) -> None:
        """Shutdown: clients end by themselves when the broadcasts close; abort whoever is still there."""
        self.closing = True
        sockets = [c.ws for c in self.clients.values() if c.ws is not None and not c.ws.closed]
        if sockets:
            closing = [asyncio.ensure_future(ws.close(code=WSCloseCode.GOING_AWAY, message=b"shutting down"))
                       for ws in sockets]
            await asyncio.wait(closing, timeout=grace)
        deadline = time.monotonic() + grace
        while self.clients and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        for c in list(self.clients.values()):
            self._drop(c)


STREAMS: "web.AppKey[StreamClients]" = web.AppKey("stereocam.streams", StreamClients)


# -- parameters ------------------------------------------------------------------------------

@dataclass(frozen=True)
class StreamParams:
    view: str
    fps: float
    quality: int
    gray: bool
    scale: float = 1.0

    @property
    def key(self) -> EncoderKey:
        return EncoderKey(self.view, self.quality, self.gray, self.scale)


SCALES = (0.25, 0.5, 1.0)  # a few sizes, so that clients share encoders: thumbnails and the full view


class BadParams(ApiError):
    """A stream's view or parameters refused: answered as JSON, or sent on the page's socket."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message, status=status)


def _flag(name: str, value: Optional[str]) -> bool:
    if value is None:
        return False
    if value.lower() in ("1", "true", "yes", "on"):
        return True
    if value.lower() in ("0", "false", "no", "off", ""):
        return False
    raise BadParams(400, f"{name} must be 1 or 0, got {value[:20]!r}")


def parse_params(view: str, query: Any, *, default_fps: float, default_quality: int) -> StreamParams:
    """Validate a view name and the ``fps``, ``quality`` and ``gray`` query parameters (404 / 400)."""
    if view not in VIEWS:
        raise BadParams(404, f"unknown view {view[:40]!r}: the views are {', '.join(VIEWS)}")
    # token: for security.py
    unknown = [k for k in query if k not in ("fps", "quality", "gray", "scale", "token")]
    if unknown:
        raise BadParams(400, f"unknown query parameter {unknown[0][:40]!r}: use fps, quality, gray and scale")
    fps: float = default_fps
    if "fps" in query:
        try:
            fps = float(query["fps"])
        except ValueError:
            fps = float("nan")
        if not (0 < fps <= MAX_FPS):
            raise BadParams(400, f"fps must be a number in (0, {MAX_FPS:g}], got {query['fps'][:20]!r}")
    quality = default_quality
    if "quality" in query:
        try:
            quality = int(query["quality"])
        except ValueError:
            quality = -1
        if not 1 <= quality <= 100:
            raise BadParams(400, f"quality must be a whole number in 1..100, got {query['quality'][:20]!r}")
    gray = _flag("gray", query.get("gray")) and view in GRAY_VIEWS
    scale = 1.0
    if "scale" in query:
        try:
            scale = float(query["scale"])
        except ValueError:
            scale = float("nan")
        if scale not in SCALES:
            raise BadParams(400, f"scale must be one of {', '.join(f'{s:g}' for s in SCALES)} (of the view's "
                                 f"size), got {query['scale'][:20]!r}")
    return StreamParams(view, fps, quality, gray, scale)


def _params(request: web.Request, view: str) -> StreamParams:
    config = request.app[SETTINGS]
    return parse_params(view, request.query, default_fps=config.default_fps,
                        default_quality=config.default_quality)


# -- pacing -----------------------------------------------------------------------------------

QUEUE_POLL_S = 0.005  # how often a stream checks whether the client took its last frame


def queued_bytes(transport: Optional[asyncio.BaseTransport]) -> int:
    """Bytes written to a client that have not reached it: the transport's buffer and the socket's
    send queue (unsent and unacknowledged bytes, ``SIOCOUTQ``)."""
    if not isinstance(transport, asyncio.Transport) or transport.is_closing():
        return 0
    queued = transport.get_write_buffer_size()
    sock = transport.get_extra_info("socket")
    if sock is not None:
        try:
            queued += struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0" * 4))[0]
        except (OSError, ValueError):  # not a TCP socket, or closed meanwhile
            pass
    return queued


async def until_taken(client: "StreamClient", limit: int) -> None:
    """Wait until at most ``limit`` written bytes are still on their way to ``client``.

    A frame is then chosen when the client can take it, so a slow reader gets the newest
    frame instead of one that waited seconds in socket buffers (mb of them). The
    caller keeps ``writing_since`` set: a client that takes nothing is still dropped.
    """
    while queued_bytes(client.transport) > limit:
        await asyncio.sleep(QUEUE_POLL_S)


async def _next(encoder_output: "Latest[Encoded]", seq: int, pacer: Pacer) -> Tuple[int, Encoded]:
    seq, encoded = await encoder_output.wait_newer(seq)
    loop = asyncio.get_running_loop()
    delay = pacer.wait(loop.time())
    if delay > 0:
        await asyncio.sleep(delay)
        seq, encoded = encoder_output.current()  # the newest after the pause
    return seq, encoded


async def send_newest(request: web.Request, client: StreamClient, params: StreamParams,
                      write: Callable[[Encoded], Awaitable[int]], *,
                      running: Callable[[], bool] = lambda: True) -> None:
    """Send ``client`` the newest encoded frame of ``params``, paced to its ``fps``, while ``running()``.

    The first frame sent is one captured after this call (as a snapshot's is): what the encoder
    holds may be older (an encoder shared with a slower client), and a client reading one frame
    (``ffmpeg -frames 1``) must not get a picture from before it asked.
    ``write`` sends one frame (the MJPEG part or the WebSocket message) and returns its size:
    the next frame is chosen once that frame has left the daemon's buffers (:func:`until_taken`).
    Returns when the broadcast closes (shutdown) or the connection breaks.
    """
    loop = asyncio.get_running_loop()
    feed = request.app[FEED]
    asked = time.time()  # the frames' clock (FrameSet.timestamp, NoSignal.timestamp)
    with request.app[ENCODERS].subscribe(params.key, params.fps) as encoder:
        pacer = Pacer(params.fps)
        seq = 0
        first = True
        try:
            while running():
                seq, encoded = await _next(encoder.output, seq, pacer)
                if first and encoded.timestamp < asked:
                    continue  # older than the request: the encoder's next frame is newer
                first = False
                client.sending(encoded, feed.last_frame)
                size = await write(encoded)
                await until_taken(client, size)  # the frame before has reached the client
                client.writing_since = None
                client.frames += 1
                pacer.sent(loop.time())
        except (BroadcastClosed, ConnectionError):
            pass  # shutdown, the client went away, or the sweeper aborted the transport


# -- handlers ---------------------------------------------------------------------------------

async def stream_handler(request: web.Request) -> web.StreamResponse:
    params = _params(request, request.match_info["view"])
    streams = request.app[STREAMS]
    streams.admit()
    resp = web.StreamResponse(headers={
        "Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        "Cache-Control": "no-cache, no-store, must-revalidate",
        "Pragma": "no-cache",
        "X-Content-Type-Options": "nosniff",
    })

    async def write(encoded: Encoded) -> int:
        await resp.write(encoded.part)
        return len(encoded.part)

    with streams.client(request, "mjpeg", params.view) as client:
        try:
            await resp.prepare(request)
        except ConnectionError:
            return resp  # the client went away
        await send_newest(request, client, params, write)
    return resp


async def snapshot_handler(request: web.Request) -> web.StreamResponse:
    fmt = request.match_info["fmt"]
    params = _params(request, request.match_info["view"])
    app = request.app
    feed, config = app[FEED], app[SETTINGS]
    timeout = config.frame_wait_s
    need_raw = params.view in RAW_VIEWS
    need_depth = needs_disparity(params.view)
    pipeline = app[PIPELINE]
    asked = time.time()

    def wanted(fs: FrameSet) -> bool:  # grabbed after the request came, with what the view needs
        return (fs.timestamp >= asked and (not need_raw or fs.raw is not None)
                and not (need_depth and needs_depth(fs)))

    try:
        with pipeline.raw_wanted() if need_raw else contextlib.nullcontext(), \
                pipeline.depth_wanted() if need_depth else contextlib.nullcontext():
            frame_set = await feed.next_frame(timeout=timeout, accept=wanted)
    except asyncio.TimeoutError:
        raise ApiError(f"no signal: the fabric sent no frame within {timeout:g} s; "
                       "check the cameras (GET /api/status)", status=503) from None
    except BroadcastClosed:
        raise shutting_down() from None
    loop = asyncio.get_running_loop()
    executor = app[EXECUTORS].encode
    if fmt == "jpg":
        encoded = await loop.run_in_executor(executor, encoded_for, params.key, frame_set,
                                             app[ENCODERS].observe)
        body, headers, ctype = bytes(encoded.jpeg), encoded.headers(), "image/jpeg"
    else:
        body = await loop.run_in_executor(executor, png_for, frame_set, params.view, params.gray,
                                          params.scale)
        headers = {"X-Frame-Number": str(frame_set.frame), "X-Timestamp": f"{frame_set.timestamp:.6f}"}
        ctype = "image/png"
    headers["Cache-Control"] = "no-store"
    headers["Content-Disposition"] = f'inline; filename="{params.view}-{frame_set.frame}.{fmt}"'
    return web.Response(body=body, content_type=ctype, headers=headers)


async def ws_handler(request: web.Request) -> web.StreamResponse:
    """The page's socket: ``{"views": [...], "fps": N, "quality": Q, "gray": bool}`` in, frames out."""
    streams = request.app[STREAMS]
    streams.admit()
    # No permessage-deflate: JPEG does not compress, and deflating every frame per client costs CPU.
    ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=64 * 1024, compress=False)
    try:
        await ws.prepare(request)  # a bad handshake is an HTTPBadRequest, answered as JSON by the app
    except ValueError:  # aiohttp decodes Sec-WebSocket-Key before checking it: a key that is not ASCII
        raise ApiError("WebSocket handshake error: Sec-WebSocket-Key must be 16 bytes in base64",
                       status=400) from None
    senders: Dict[str, "asyncio.Task[None]"] = {}

    def stop_senders() -> None:
        for task in senders.values():
            task.cancel()
        senders.clear()

    with streams.client(request, "ws", "-") as client:
        client.ws = ws
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    await ws.send_json({"error": "send JSON text: {\"views\": [...], \"fps\": N}"})
                    continue
                try:
                    wanted = _ws_request(request, msg.data)
                except BadParams as exc:
                    await ws.send_json({"error": exc.message})
                    continue
                if isinstance(wanted, Ping):  # answered at once; the subscription stays as it is
                    await ws.send_json({"pong": wanted.value})
                    continue
                stop_senders()
                client.view = ",".join(p.view for p in wanted) or "-"
                for p in wanted:
                    sender = _ws_sender(request, ws, client, p)
                    senders[p.view] = asyncio.get_running_loop().create_task(sender)
        except ConnectionError:
            pass
        finally:
            stop_senders()
    return ws


@dataclass(frozen=True)
class Ping:
    """``{"ping": N}`` on the page's socket: answered ``{"pong": N}`` (the page's round-trip time)."""

    value: float


VIEW_OPTIONS = ("fps", "quality", "scale")  # what a view's own entry in "views" may set


def _ws_request(request: web.Request, text: str) -> "list[StreamParams] | Ping":
    """A subscription (each view with its own fps, quality and scale when its entry says so) or a ping."""
    try:
        doc = parse_json(text)
    except ValueError:
        raise BadParams(400, 'not JSON: send {"views": ["rect_left", ...], "fps": N}') from None
    if not isinstance(doc, dict):
        raise BadParams(400, 'send a JSON object {"views": [...], "fps": N}')
    if "ping" in doc:
        value = doc["ping"]
        if set(doc) != {"ping"} or isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise BadParams(400, 'a ping is {"ping": N} alone, N a number')
        return Ping(float(value))
    unknown = [k for k in doc if k not in ("views", "fps", "quality", "gray", "scale", "full")]
    if unknown:
        raise BadParams(400, f"unknown key {str(unknown[0])[:40]!r}: use views, fps, quality, gray, scale "
                             "and full")
    full = doc.get("full", [])
    if not isinstance(full, list) or not all(isinstance(v, str) and v in VIEWS for v in full):
        raise BadParams(400, f"full must be a list of view names ({', '.join(VIEWS)}): the views sent at "
                             "full size whatever scale says")
    views = doc.get("views", [])
    if not isinstance(views, list) or len(views) > len(VIEWS):
        raise BadParams(400, f"views must be a list of view names ({', '.join(VIEWS)}) or of "
                             '{"view": NAME, "fps": N, "quality": Q, "scale": S} objects')
    query = {k: str(int(v) if isinstance(v, bool) else v) for k, v in doc.items()
             if k not in ("views", "full")}
    full_query = {k: v for k, v in query.items() if k != "scale"}
    out: Dict[str, StreamParams] = {}
    for entry in views:
        name, own = _view_entry(entry)
        if name in out:
            continue  # the first entry of a view counts
        base = full_query if name in full else query
        try:
            out[name] = _params_from(request, name, {**base, **own})
        except BadParams as exc:
            status = exc.status or 400
            raise BadParams(status, exc.message if name not in VIEWS else f"{name}: {exc.message}") from None
    return list(out.values())


def _view_entry(entry: Any) -> Tuple[str, Dict[str, str]]:
    """A ``views`` entry: a view name, or ``{"view": NAME, "fps"?, "quality"?, "scale"?}`` (its own
    settings, over the message's)."""
    if isinstance(entry, str):
        return entry, {}
    if not isinstance(entry, dict) or not isinstance(entry.get("view"), str):
        raise BadParams(400, 'each entry of views is a view name or {"view": NAME, "fps": N, "quality": Q, '
                             '"scale": S}')
    name: str = entry["view"]
    unknown = [k for k in entry if k != "view" and k not in VIEW_OPTIONS]
    if unknown:
        raise BadParams(400, f"{name[:40]}: unknown key {str(unknown[0])[:40]!r}: a view's entry may set "
                             "fps, quality and scale")
    own: Dict[str, str] = {}
    for k in VIEW_OPTIONS:
        if k not in entry:
            continue
        v = entry[k]
        # bool and null are not numbers (parse_params refuses the text with the range it wants)
        own[k] = repr(v) if isinstance(v, bool) or v is None else str(v)
    return name, own


def _params_from(request: web.Request, view: str, query: Dict[str, str]) -> StreamParams:
    config = request.app[SETTINGS]
    return parse_params(view, query, default_fps=config.default_fps, default_quality=config.default_quality)


async def _ws_sender(request: web.Request, ws: web.WebSocketResponse, client: StreamClient,
                     params: StreamParams) -> None:
    async def write(encoded: Encoded) -> int:
        message = encoded.ws_sent_at(time.time())  # the frames' clock: FrameSet.timestamp
        await ws.send_bytes(message)
        return len(message)

    await send_newest(request, client, params, write, running=lambda: not ws.closed)


def setup_routes(app: web.Application) -> None:
    app.router.add_get("/stream/{view}", stream_handler)
    app.router.add_get(r"/snapshot/{view}.{fmt:jpg|png}", snapshot_handler)
    app.router.add_get("/ws", ws_handler)
