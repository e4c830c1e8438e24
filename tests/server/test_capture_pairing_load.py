"""200 captures under load, each replayed through the virtual camera: none pairs frames.

A capture's rectified pair must be what the core makes of its raw pair, whatever else the daemon
is doing. Here the emulated cameras see a moving scene (every frame differs) while four MJPEG
clients, the page's WebSocket and a poller of status, snapshots, listings and zips keep the
daemon busy and captures are asked for four at a time; then each capture's raw pair goes down
the virtual camera (``POST /api/virtual-camera {"capture": id}``) and what the fabric returns
must equal the capture's rectified pair, pixel for pixel.
"""
from __future__ import annotations

import asyncio
import json
import time
from typing import Dict, List, Set

import cv2
import numpy as np
import pytest

from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.model.stereo import compiled_path_installed
from stereocam.server.http.state import CAPTURES

from ..slowness import SLOWNESS
from .daemon import SMALL, wait_for_frames  # noqa: F401

CAPTURES_N = 200
CAMERA_FPS = 50.0  # the cameras' rate: a replay waits a few frames for the fabric, so this sets its pace
STREAM_FPS = 25
AT_ONCE = 4
STREAM_VIEWS = ("rect_left", "rect_right", "sbs", "raw_left")
BOUND_S = 120.0  # a last resort against a hang: nothing here waits this long on a working daemon


def decode(data: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None, "not a decodable image"
    return image


async def read_stream(daemon, view: str, parts: Dict[str, int], stop: asyncio.Event) -> None:
    """An MJPEG client that reads every part of ``/stream/<view>`` until ``stop``, counting them."""
    async with daemon.session().get(f"/stream/{view}?fps={STREAM_FPS}") as resp:
        assert resp.status == 200, await resp.text()
        while not stop.is_set():
            head = await asyncio.wait_for(resp.content.readuntil(b"\r\n\r\n"), BOUND_S)
            fields = dict(line.split(b": ", 1) for line in head.strip().split(b"\r\n") if b": " in line)
            if b"Content-Length" in fields:
                await asyncio.wait_for(resp.content.readexactly(int(fields[b"Content-Length"]) + 2), BOUND_S)
                parts[view] += 1


async def watch_websocket(daemon, counts: Dict[str, int], stop: asyncio.Event) -> None:
    async with daemon.session().ws_connect("/ws") as ws:
        await ws.send_str(json.dumps({"views": ["anaglyph", "rect_right"], "fps": STREAM_FPS}))
        while not stop.is_set():
            msg = await ws.receive(timeout=BOUND_S)
            assert msg.type.name == "BINARY", msg
            counts["ws"] += 1


async def poll(daemon, counts: Dict[str, int], stop: asyncio.Event) -> None:
    """Status, snapshots, the capture listing, a capture's zip: what pages and scripts ask meanwhile."""
    http = daemon.session()
    while not stop.is_set():
        for path in ("/api/status", "/snapshot/rect_left.png", "/snapshot/raw_right.jpg", "/api/captures",
                     "/metrics", "/healthz"):
            async with http.get(path) as resp:
                assert resp.status == 200, (path, await resp.text())
                body = await resp.read()
            if path == "/api/captures":
                listing = json.loads(body)["captures"]
                if listing:
                    async with http.get(f"/api/captures/{listing[0]['id']}.zip") as resp:
                        assert resp.status == 200
                        await resp.read()
            counts["polls"] += 1


@pytest.mark.timeout(900)  # a busy machine makes this slower, never red
async def test_200_captures_under_load_each_pair_raw_and_rectified_of_one_frame(start_daemon) -> None:
    # With a stereo core where the daemon would give the emulated fabric one (its model compiled):
    # on its numpy path, beside 200 captures that each wait for its output, the streams starve.
    overlay = EmulatedOverlay(source=SyntheticRig(size=SMALL, motion=True), fps=CAMERA_FPS,
                              stereo=compiled_path_installed())
    # The emulated fabric is a thread of this very process, beside 200 captures, streams and polls:
    # a machine busy with other work can hold it up for more than the default second a capture
    # waits for a fresh frame (2 x no_signal_s). What is checked here is pairing, not that wait.
    d = await start_daemon(overlay=overlay, no_signal_s=min(60.0, 5.0 * SLOWNESS))
    await wait_for_frames(d, 3)
    store = d.app[CAPTURES]

    stop = asyncio.Event()
    parts = {view: 0 for view in STREAM_VIEWS}
    counts = {"ws": 0, "polls": 0}
    load = [asyncio.ensure_future(read_stream(d, view, parts, stop)) for view in STREAM_VIEWS]
    load += [asyncio.ensure_future(watch_websocket(d, counts, stop)),
             asyncio.ensure_future(poll(d, counts, stop))]

    ids: List[str] = []
    gate = asyncio.Semaphore(AT_ONCE)

    async def capture() -> None:
        async with gate:
            async with d.http.post("/api/captures") as resp:
                assert resp.status == 201, await resp.text()
                ids.append((await resp.json())["id"])

    try:
        while min(parts.values()) == 0 or counts["ws"] == 0:  # the load is on before the first capture
            assert not any(t.done() for t in load), [t.exception() for t in load if t.done()]
            await asyncio.sleep(0.02)
        t0 = time.monotonic()
        await asyncio.gather(*(capture() for _ in range(CAPTURES_N)))
        capture_s = time.monotonic() - t0
        during = dict(parts, **counts)
        assert not any(t.done() for t in load), [t.exception() for t in load if t.done()]
    finally:
        stop.set()
        for task in load:
            task.cancel()
        await asyncio.gather(*load, return_exceptions=True)
    assert len(set(ids)) == CAPTURES_N
    assert all(n > 0 for n in during.values()), during  # every client was served while captures ran

    raws: Set[bytes] = set()
    mixed: Dict[str, List[str]] = {}
    for cid in ids:
        meta = store.get(cid).to_json(meta=True)["meta"]
        assert meta["source"] == "live" and meta["pairing"] == "checked", (cid, meta["pairing"])
        raws.add(store.read_file(cid, "raw_left.png") + store.read_file(cid, "raw_right.png"))
        async with d.http.post("/api/virtual-camera", json={"capture": cid}) as resp:
            assert resp.status == 200, await resp.text()
            assert (await resp.json())["input"] == f"capture {cid}"
        for side in ("left", "right"):
            async with d.http.get(f"/api/virtual-camera/result/{side}.png") as resp:
                assert resp.status == 200
                replayed = decode(await resp.read())
            stored = decode(store.read_file(cid, f"rect_{side}.png"))
            if replayed.shape != stored.shape or replayed.tobytes() != stored.tobytes():
                mixed.setdefault(cid, []).append(f"rect_{side}")
    assert not mixed, f"{len(mixed)} of {CAPTURES_N} captures mix frames: {list(mixed.items())[:5]}"
    # The scene moved from capture to capture, so a raw pair from another frame would have shown
    # (captures asked for at the same moment may share a frame).
    assert len(raws) >= CAPTURES_N // 2, f"only {len(raws)} distinct raw pairs in {CAPTURES_N} captures"
    print(f"{CAPTURES_N} captures in {capture_s:.1f} s under load {during}, replayed in "
          f"{time.monotonic() - t0 - capture_s:.1f} s")
