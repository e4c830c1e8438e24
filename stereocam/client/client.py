"""The client: one :class:`Client` per daemon, plain blocking calls (what a notebook cell wants).

Requests use the standard library (``urllib``); the WebSocket stream runs aiohttp on a private
event loop in a thread of its own (a notebook's kernel already runs a loop in the main thread),
which ``close()`` ends. Images come back as numpy arrays in RGB order (``(H, W, 3)``, uint8) or
gray (``(H, W)``): PNG where the API gives it (lossless, the daemon's pixels exactly), JPEG for
the streams (``Frame.lossy`` says so).
"""
from __future__ import annotations

import asyncio
import io
import json
import struct
import threading
import urllib.error
import urllib.parse
import urllib.request
import uuid
import zipfile
from dataclasses import dataclass
from http.client import HTTPResponse
from pathlib import Path
from typing import (
    Any,
    BinaryIO,
    Coroutine,
    Dict,
    Iterator,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
    TypeVar,
    Union,
)

import cv2
import numpy as np

from stereocam.calibration.file import Calibration, parse_yaml

Image = Union[np.ndarray, bytes, str, Path]  # an array (RGB or gray), encoded image bytes, or a file
JSON = Dict[str, Any]
T = TypeVar("T")


class ClientError(Exception):
    """The daemon refused a request: ``status`` (the HTTP status; None for a WebSocket message)
    and ``message`` (the daemon's one line saying what to do)."""

    def __init__(self, status: Optional[int], message: str, *, method: str = "", path: str = "") -> None:
        self.status = status
        self.message = message
        self.method = method
        self.path = path
        where = f" {method} {path}".rstrip() if method or path else ""
        super().__init__(f"{status if status is not None else 'error'}{where}: {message}")


@dataclass(frozen=True)
class Frame:
    """One frame of a view: ``image`` (RGB or gray array), the daemon's frame ``number`` and capture
    ``timestamp`` (seconds since the epoch), ``signal`` (False: the daemon's NO SIGNAL frame) and
    ``lossy`` (True for JPEG: do not compare its pixels exactly)."""

    view: str
    image: np.ndarray
    number: int
    timestamp: float
    signal: bool
    lossy: bool


def decode_image(data: bytes) -> np.ndarray:
    """PNG/JPEG/BMP/TIFF bytes as an array: RGB ``(H, W, 3)``, RGBA, or gray ``(H, W)``, as stored."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"not a readable image ({len(data)} bytes)")
    if img.ndim == 3 and img.shape[2] == 3:
        return np.ascontiguousarray(img[..., ::-1])
    if img.ndim == 3 and img.shape[2] == 4:
        return np.ascontiguousarray(img[..., [2, 1, 0, 3]])
    return np.asarray(img)


def encode_png(image: np.ndarray) -> bytes:
    """An RGB or gray uint8 array as PNG bytes (lossless)."""
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f"an image must be uint8 (H, W) or (H, W, 3), not {image.dtype} {image.shape}")
    bgr = image[..., ::-1] if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise ValueError(f"cannot encode an image of shape {image.shape} as PNG")
    return bytes(buf.tobytes())


def _image_bytes(image: Image) -> bytes:
    if isinstance(image, np.ndarray):
        return encode_png(image)
    if isinstance(image, bytes):
        return image
    return Path(image).read_bytes()


def _multipart(fields: Sequence[Tuple[str, bytes]]) -> Tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    out = io.BytesIO()
    for name, data in fields:
        out.write(f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; filename=\"{name}\"\r\n"
                  "Content-Type: application/octet-stream\r\n\r\n".encode())
        out.write(data)
        out.write(b"\r\n")
    out.write(f"--{boundary}--\r\n".encode())
    return out.getvalue(), f"multipart/form-data; boundary={boundary}"


def _error_text(body: bytes) -> str:
    try:
        text = str(json.loads(body)["error"])
    except (ValueError, KeyError, TypeError):
        text = body.decode("utf-8", "replace").strip() or "(no message)"
    return text


class Client:
    """A daemon at ``url`` (e.g. ``http://board:8080``); ``token``: its ``access_token``, if set.

    Every call blocks until the daemon answers (at most ``timeout`` seconds without a byte) and
    raises :class:`ClientError` with the daemon's own message when it refuses.
    """

    def __init__(self, url: str = "http://127.0.0.1:8080", token: Optional[str] = None, *,
                 timeout: float = 60.0) -> None:
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout

    def __repr__(self) -> str:
        return f"Client({self.url!r}{', token=...' if self.token else ''})"

    # -- plumbing ------------------------------------------------------------------------------

    def _headers(self) -> Dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def _url(self, path: str, query: Optional[Mapping[str, Any]] = None) -> str:
        q = {k: v for k, v in (query or {}).items() if v is not None}
        return self.url + path + ("?" + urllib.parse.urlencode(q) if q else "")

    def _open(self, method: str, path: str, *, query: Optional[Mapping[str, Any]] = None,
              body: Optional[bytes] = None, content_type: Optional[str] = None) -> HTTPResponse:
        """The response (open: the caller reads and closes it); a 4xx/5xx raises ClientError."""
        headers = self._headers()
        if content_type:
            headers["Content-Type"] = content_type
        req = urllib.request.Request(self._url(path, query), data=body, method=method, headers=headers)
        try:
            resp: HTTPResponse = urllib.request.urlopen(req, timeout=self.timeout)
        except urllib.error.HTTPError as exc:
            with exc:
                raise ClientError(exc.code, _error_text(exc.read()), method=method, path=path) from None
        return resp

    def _request(self, method: str, path: str, **kwargs: Any) -> Tuple[bytes, Any]:
        with self._open(method, path, **kwargs) as resp:
            return resp.read(), resp.headers

    def _json(self, method: str, path: str, payload: Any = None, **kwargs: Any) -> Any:
        if payload is not None:
            kwargs.update(body=json.dumps(payload).encode(), content_type="application/json")
        data, _ = self._request(method, path, **kwargs)
        return json.loads(data) if data else None

    def _download(self, path: str, dest: Union[str, Path, BinaryIO]) -> None:
        with self._open("GET", path) as resp:
            if isinstance(dest, (str, Path)):
                tmp = Path(str(dest) + ".part")
                try:
                    with open(tmp, "wb") as f:
                        _copy(resp, f)
                    tmp.replace(dest)  # a download cut short never leaves a file looking whole
                finally:
                    tmp.unlink(missing_ok=True)
            else:
                _copy(resp, dest)

    def _frame(self, path: str, view: str, query: Mapping[str, Any]) -> Frame:
        data, headers = self._request("GET", path, query=query)
        return Frame(view=view, image=decode_image(data), number=int(headers.get("X-Frame-Number", -1)),
                     timestamp=float(headers.get("X-Timestamp", "nan")),
                     signal=headers.get("X-Signal") != "none", lossy=path.endswith(".jpg"))

    # -- daemon --------------------------------------------------------------------------------

    def status(self) -> JSON:
        """``GET /api/status``: backend, source, frame size, rates, faults, calibration, ..."""
        return dict(self._json("GET", "/api/status"))

    def views(self) -> List[JSON]:
        """The view registry (``GET /api/views``): each view's ``name``, ``caption``, ``gray``, ..."""
        return list(self._json("GET", "/api/views")["views"])

    # -- frames --------------------------------------------------------------------------------

    def snapshot(self, view: str, *, lossless: bool = True, gray: bool = False, scale: float = 1,
                 quality: Optional[int] = None) -> Frame:
        """One frame of ``view`` newer than the call: PNG (exact) unless ``lossless=False`` (JPEG)."""
        ext = "png" if lossless else "jpg"
        return self._frame(f"/snapshot/{view}.{ext}", view, _view_query(gray, scale, quality))

    def stream(self, view: str, *, fps: Optional[float] = None, quality: Optional[int] = None,
               gray: bool = False, scale: float = 1) -> "FrameStream":
        """Frames of one view over MJPEG (``/stream/{view}``), an iterator to close (or use ``with``)."""
        query = dict(_view_query(gray, scale, quality), fps=fps)
        return _MjpegStream(view, self._open("GET", f"/stream/{view}", query=query))

    def watch(self, views: Sequence[str], *, fps: Optional[float] = None, quality: Optional[int] = None,
              gray: bool = False, scale: float = 1) -> "FrameStream":
        """Frames of several views over the WebSocket (``/ws``), interleaved as they come; close it."""
        request: JSON = {"views": list(views)}
        for key, value in (("fps", fps), ("quality", quality)):
            if value is not None:
                request[key] = value
        if gray:
            request["gray"] = True
        if scale != 1:
            request["scale"] = scale
        ws_url = "ws" + self.url[len("http"):] + "/ws"
        return _WebSocketStream(ws_url, self._headers(), request, self.timeout)

    # -- source and virtual camera ---------------------------------------------------------------

    def source(self) -> str:
        """``live`` or ``virtual``."""
        return str(self._json("GET", "/api/source")["source"])

    def set_source(self, source: str) -> JSON:
        """Switch to ``live`` or back to the last ``virtual`` input (409 when there is none)."""
        return dict(self._json("PUT", "/api/source", {"source": source}))

    def upload(self, left: Optional[Image] = None, right: Optional[Image] = None, *,
               sbs: Optional[Image] = None, fit: Optional[str] = None) -> JSON:
        """Send a pair (or one side-by-side image) through the fabric as the virtual camera.

        Images are arrays (RGB or gray, sent as PNG), encoded bytes or file paths. ``fit``:
        ``exact`` (the default), ``crop``, ``pad`` or ``scale``. Returns the daemon's reply
        (``frame``, ``width``, ``height``, ``fit``).
        """
        body, ctype = _multipart(_pair_fields(left, right, sbs, fit))
        return dict(self._json("POST", "/api/virtual-camera", body=body, content_type=ctype))

    def preview(self, left: Optional[Image] = None, right: Optional[Image] = None, *,
                sbs: Optional[Image] = None, fit: Optional[str] = None) -> Tuple[np.ndarray, JSON]:
        """The pair as ``upload`` would fit it (side by side) and the ``fit`` report; nothing changes."""
        body, ctype = _multipart(_pair_fields(left, right, sbs, fit))
        data, headers = self._request("POST", "/api/virtual-camera/preview", body=body, content_type=ctype)
        return decode_image(data), json.loads(headers["X-Fit"])

    def replay_capture(self, capture_id: str) -> JSON:
        """Send a capture's raw pair through the fabric as the virtual camera."""
        return dict(self._json("POST", "/api/virtual-camera", {"capture": capture_id}))

    def play_recording(self, recording_id: str) -> JSON:
        """Play a recording through the fabric as the virtual camera (looping until another input)."""
        return dict(self._json("POST", "/api/virtual-camera", {"recording": recording_id}))

    def virtual_camera(self) -> JSON:
        """``GET /api/virtual-camera``: the input, its frame and what is playing."""
        return dict(self._json("GET", "/api/virtual-camera"))

    def virtual_result(self, side: str) -> Frame:
        """The fabric's processed (rectified) image of the virtual input, ``left`` or ``right`` (PNG)."""
        return self._frame(f"/api/virtual-camera/result/{side}.png", f"rect_{side}", {})

    def verify(self) -> JSON:
        """Run the virtual input through the model and compare with the fabric (``identical``, ...)."""
        return dict(self._json("POST", "/api/verify"))

    def verify_difference(self) -> np.ndarray:
        """The last Verify's difference image (left | right, black where equal)."""
        data, _ = self._request("GET", "/api/verify/difference.png")
        return decode_image(data)

    # -- depth -----------------------------------------------------------------------------------

    def point(self, x: int, y: int, *, frame: Optional[int] = None) -> JSON:
        """Pixel (x, y) of the rectified pair: its colours, ``disparity_px``, ``depth_m``, ``point_m``."""
        return dict(self._json("GET", "/api/point", query={"x": x, "y": y, "frame": frame}))

    def ruler(self, a: Tuple[int, int], b: Tuple[int, int], *, frame: Optional[int] = None) -> JSON:
        """The distance in metres between rectified-left pixels ``a`` and ``b`` (``distance_m``) and
        their 3-D points; of frame ``frame`` when given (one the daemon still holds, else 410)."""
        query = {"x0": a[0], "y0": a[1], "x1": b[0], "y1": b[1], "frame": frame}
        return dict(self._json("GET", "/api/ruler", query=query))

    def freeze(self, frame: Optional[int] = None) -> JSON:
        """Hold frame ``frame`` (None: the newest) so that ``point`` and ``ruler`` can read it at leisure;
        ``release`` lets it go."""
        if frame is None:
            return dict(self._json("POST", "/api/freeze"))
        return dict(self._json("POST", "/api/freeze", {"frame": frame}))

    def frozen(self) -> List[int]:
        """The frames held frozen, oldest first."""
        return [int(n) for n in self._json("GET", "/api/freeze")["frozen"]]

    def release(self, frame: int) -> None:
        """Let a frozen frame go."""
        self._request("DELETE", f"/api/freeze/{int(frame)}")

    def disparity_info(self) -> JSON:
        """What the disparity view's colours mean (``colors``, ``num_disparities``, ``focal_px``, ...)."""
        return dict(self._json("GET", "/api/disparity"))

    def stereo(self) -> JSON:
        """The stereo core (``GET /api/stereo``): ``present``, ``by`` (what computes the disparity) and,
        where there is a core, its ``params``, ``defaults``, ``limits``, ``build`` and ``status``."""
        return dict(self._json("GET", "/api/stereo"))

    def set_stereo(self, **params: Any) -> JSON:
        """Change the stereo core's parameters (``num_disp``, ``p1``, ``p2``, ``p2_edge``, ``edge_thresh``,
        ``uniqueness``, ``lr_tol``, ``lr_check``, ``subpixel``, ``median``); the others stay. A value
        the core refuses is a ClientError (422) with every problem, and the previous ones stay active."""
        return dict(self._json("PUT", "/api/stereo", dict(params)))

    # -- cameras and calibration -------------------------------------------------------------------

    def cameras(self) -> JSON:
        """Per camera the sensor values in use (``exposure_us``, ``gain``, ``aec``, ...) and ``health``."""
        return dict(self._json("GET", "/api/cameras"))

    def set_cameras(self, camera: str = "both", **values: Any) -> JSON:
        """Set ``exposure_us``, ``gain``, ``aec``, ``agc``, ``flip_h``, ``flip_v``, ``test_pattern`` on
        ``camera`` (``both``, ``left`` or ``right``); all checked first, so a refusal changes nothing."""
        return dict(self._json("PUT", "/api/cameras", dict(values, camera=camera)))

    def calibration(self) -> JSON:
        """What the core runs with (``GET /api/calibration``): id, registers' figures, model, ``yaml``."""
        return dict(self._json("GET", "/api/calibration"))

    def calibration_file(self) -> Optional[Calibration]:
        """The active calibration as the project's :class:`Calibration` (None when passing through)."""
        text = self.calibration().get("yaml")
        return parse_yaml(text, where="the daemon's calibration") if text else None

    def set_calibration(self, calibration: Union[str, Calibration]) -> JSON:
        """Program a stereocam calibration file's text (or a :class:`Calibration`) into the core."""
        text = calibration.to_yaml() if isinstance(calibration, Calibration) else calibration
        return dict(self._json("PUT", "/api/calibration", body=text.encode(),
                               content_type="application/yaml"))

    # -- captures --------------------------------------------------------------------------------

    def captures(self) -> List[JSON]:
        """The captures, newest first: ``id``, ``created``, ``frame``, ``files`` (name, bytes, sha256)."""
        return list(self._json("GET", "/api/captures")["captures"])

    def capture(self) -> JSON:
        """Store the next frame's raw and rectified pairs (lossless) with their metadata; its entry."""
        return dict(self._json("POST", "/api/captures"))

    def capture_info(self, capture_id: str) -> JSON:
        """A capture's listing entry plus its ``meta`` (meta.json)."""
        return dict(self._json("GET", f"/api/captures/{_quoted(capture_id)}"))

    def capture_file(self, capture_id: str, name: str) -> bytes:
        """A file of a capture as stored (e.g. ``rect_left.png``, ``meta.json``)."""
        data, _ = self._request("GET", f"/api/captures/{_quoted(capture_id)}/{_quoted(name)}")
        return bytes(data)

    def capture_images(self, capture_id: str) -> Dict[str, np.ndarray]:
        """Every image of a capture as an array, by name without ``.png`` (``raw_left``, ...)."""
        files = self.capture_info(capture_id)["files"]
        return {f["name"][:-4]: decode_image(self.capture_file(capture_id, f["name"]))
                for f in files if f["name"].endswith(".png")}

    def capture_disparity(self, capture_id: str) -> np.ndarray:
        """A capture's stereo-core disparity codes, (H, W) uint16: disparity x 16, 65535 where invalid."""
        return decode_image(self.capture_file(capture_id, "disparity.png"))

    def cloud(self, capture_id: Optional[str] = None) -> bytes:
        """A point cloud as binary PLY (metres, coloured): a capture's, or without one the newest frame's."""
        path = "/api/cloud.ply" if capture_id is None else f"/api/captures/{_quoted(capture_id)}/cloud.ply"
        data, _ = self._request("GET", path)
        return bytes(data)

    def download_capture(self, capture_id: str, dest: Union[str, Path, BinaryIO]) -> None:
        """The capture as a zip, to a file path (written whole or not at all) or an open binary file."""
        self._download(f"/api/captures/{_quoted(capture_id)}.zip", dest)

    def delete_capture(self, capture_id: str) -> None:
        """Move a capture to the trash (``restore_capture`` brings it back within 10 minutes)."""
        self._request("DELETE", f"/api/captures/{_quoted(capture_id)}")

    def restore_capture(self, capture_id: str) -> JSON:
        """Bring a deleted capture back from the trash; its listing entry."""
        return dict(self._json("POST", f"/api/captures/{_quoted(capture_id)}/restore"))

    # -- recordings ------------------------------------------------------------------------------

    def recordings(self) -> JSON:
        """``{"recordings": [...], "recording": running id or None, "last_error": ...}``."""
        return dict(self._json("GET", "/api/recordings"))

    def recording_info(self, recording_id: str) -> JSON:
        """A recording's entry (plus ``meta`` once done)."""
        return dict(self._json("GET", f"/api/recordings/{_quoted(recording_id)}"))

    def start_recording(self, seconds: Optional[float] = None) -> JSON:
        """Record every raw pair for ``seconds`` (None: until ``stop_recording``); the new entry."""
        if seconds is None:
            return dict(self._json("POST", "/api/recordings"))
        return dict(self._json("POST", "/api/recordings", {"seconds": seconds}))

    def stop_recording(self, recording_id: str) -> JSON:
        """Stop a recording; its finished entry once written."""
        return dict(self._json("POST", f"/api/recordings/{_quoted(recording_id)}/stop"))

    def recording_frame(self, recording_id: str, index: int, side: str = "left") -> np.ndarray:
        """Frame ``index`` (0: the first) of a finished recording, one camera, exactly as stored."""
        data, _ = self._request("GET", f"/api/recordings/{_quoted(recording_id)}/frames/{int(index)}/"
                                       f"{_quoted(side)}.png")
        return decode_image(data)

    def download_recording(self, recording_id: str, dest: Union[str, Path, BinaryIO]) -> None:
        """A finished recording as a zip (file path written whole or not at all, or an open binary file)."""
        self._download(f"/api/recordings/{_quoted(recording_id)}.zip", dest)

    def open_recording(self, recording_id: str) -> "Recording":
        """A finished recording downloaded into memory, its frames readable as arrays."""
        buf = io.BytesIO()
        self.download_recording(recording_id, buf)
        return Recording(buf)

    def delete_recording(self, recording_id: str) -> None:
        """Delete a finished recording (for good)."""
        self._request("DELETE", f"/api/recordings/{_quoted(recording_id)}")


class Recording:
    """A recording's zip (a path or a binary file): ``meta`` (recording.json), ``frames`` (the lines
    of frames.jsonl), and each frame's raw pair as arrays (``pair(i)``, or iterate), bit for bit."""

    def __init__(self, source: Union[str, Path, BinaryIO]) -> None:
        self._zip = zipfile.ZipFile(source)
        names = self._zip.namelist()
        metas = [n for n in names if n.endswith("/recording.json") and n.count("/") == 1]
        if len(metas) != 1:
            raise ValueError("not a stereocam recording zip: it has no <id>/recording.json")
        self._folder = metas[0].split("/")[0]
        self.meta: JSON = json.loads(self._zip.read(metas[0]))
        lines = self._zip.read(f"{self._folder}/frames.jsonl").decode().splitlines()
        self.frames: List[JSON] = [json.loads(line) for line in lines if line.strip()]

    @property
    def id(self) -> str:
        return str(self.meta["id"])

    def __len__(self) -> int:
        return len(self.frames)

    def image(self, name: str) -> np.ndarray:
        """A file of the recording (e.g. ``left_000000.png``) as an array."""
        return decode_image(self._zip.read(f"{self._folder}/{name}"))

    def pair(self, index: int) -> Tuple[np.ndarray, np.ndarray]:
        """Frame ``index``'s raw (left, right) pair as the cameras delivered it."""
        line = self.frames[index]
        return self.image(line["left"]), self.image(line["right"])

    def __iter__(self) -> Iterator[Tuple[np.ndarray, np.ndarray]]:
        for i in range(len(self.frames)):
            yield self.pair(i)

    def close(self) -> None:
        self._zip.close()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FrameStream:
    """An iterator of :class:`Frame` over a stream; ``close()`` (or ``with``) ends the connection."""

    def __iter__(self) -> "FrameStream":
        return self

    def __next__(self) -> Frame:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _MjpegStream(FrameStream):
    """``multipart/x-mixed-replace`` parts read off the response as they arrive."""

    def __init__(self, view: str, resp: HTTPResponse) -> None:
        self.view = view
        self._resp = resp

    def __next__(self) -> Frame:
        if self._resp.closed:
            raise StopIteration
        line = self._resp.readline()
        while line and line.strip() != b"--frame":
            line = self._resp.readline()
        if not line:
            self.close()
            raise StopIteration
        headers: Dict[str, str] = {}
        while True:
            line = self._resp.readline()
            if not line or not line.strip():
                break
            key, _, value = line.decode("latin-1").partition(":")
            headers[key.strip().lower()] = value.strip()
        length = int(headers.get("content-length", "-1"))
        data = self._resp.read(length) if length >= 0 else b""
        if length < 0 or len(data) < length:
            self.close()
            raise StopIteration
        return Frame(view=self.view, image=decode_image(data), number=int(headers.get("x-frame-number", -1)),
                     timestamp=float(headers.get("x-timestamp", "nan")),
                     signal=headers.get("x-signal") != "none", lossy=True)

    def close(self) -> None:
        self._resp.close()


class _WebSocketStream(FrameStream):
    """``/ws`` on a private event loop in a thread of its own.

    Its own thread, not the caller's: in Jupyter the kernel's loop already runs in the main
    thread, where another loop cannot be run. ``next()`` waits for the thread's answer;
    ``close()`` closes the socket and ends the thread.
    """

    def __init__(self, url: str, headers: Dict[str, str], request: JSON, timeout: float) -> None:
        import aiohttp  # only the WebSocket stream needs it

        self._aiohttp = aiohttp
        self._timeout = timeout
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="stereocam-ws", daemon=True)
        self._thread.start()
        self._session: Any = None
        self._ws: Any = None
        try:
            self._run(self._connect(url, headers, request))
        except aiohttp.WSServerHandshakeError as exc:
            self.close()
            message = exc.message or "WebSocket refused"
            raise ClientError(exc.status, message, method="GET", path="/ws") from None
        except BaseException:
            self.close()
            raise

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result()

    async def _connect(self, url: str, headers: Dict[str, str], request: JSON) -> None:
        self._session = self._aiohttp.ClientSession()
        self._ws = await self._session.ws_connect(url, headers=headers, heartbeat=None,
                                                  timeout=self._aiohttp.ClientWSTimeout(ws_close=self._timeout))
        await self._ws.send_str(json.dumps(request))

    async def _receive(self) -> Optional[Frame]:
        aiohttp = self._aiohttp
        msg = await self._ws.receive(timeout=self._timeout)
        if msg.type == aiohttp.WSMsgType.BINARY:
            data = msg.data
            (n,) = struct.unpack(">I", data[:4])
            head = json.loads(data[4:4 + n])
            return Frame(view=head["view"], image=decode_image(data[4 + n:]), number=int(head["frame"]),
                         timestamp=float(head["timestamp"]), signal=bool(head["signal"]), lossy=True)
        if msg.type == aiohttp.WSMsgType.TEXT:
            raise ClientError(None, _error_text(msg.data.encode()), method="WS", path="/ws")
        return None  # closed

    def __next__(self) -> Frame:
        if self._loop.is_closed():
            raise StopIteration
        frame = self._run(self._receive())
        if frame is None:
            self.close()
            raise StopIteration
        return frame

    def close(self) -> None:
        if self._loop.is_closed():
            return
        try:
            self._run(self._close())
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
            self._loop.close()

    async def _close(self) -> None:
        if self._ws is not None:
            await self._ws.close()
        if self._session is not None:
            await self._session.close()


def _view_query(gray: bool, scale: float, quality: Optional[int]) -> Dict[str, Any]:
    return {"gray": 1 if gray else None, "scale": scale if scale != 1 else None, "quality": quality}


def _pair_fields(left: Optional[Image], right: Optional[Image], sbs: Optional[Image],
                 fit: Optional[str]) -> List[Tuple[str, bytes]]:
    if sbs is not None:
        if left is not None or right is not None:
            raise ValueError("give left and right, or sbs: not both")
        fields = [("sbs", _image_bytes(sbs))]
    elif left is not None and right is not None:
        fields = [("left", _image_bytes(left)), ("right", _image_bytes(right))]
    else:
        raise ValueError("give both left and right images, or one side-by-side image as sbs=")
    if fit is not None:
        fields.append(("fit", fit.encode()))
    return fields


def _quoted(part: str) -> str:
    return urllib.parse.quote(part, safe="")


def _copy(src: HTTPResponse, dst: BinaryIO) -> None:
    while True:
        chunk = src.read(1 << 16)
        if not chunk:
            return
        dst.write(chunk)


__all__ = ["Client", "ClientError", "Frame", "FrameStream", "Recording", "decode_image", "encode_png"]
