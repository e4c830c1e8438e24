"""The API behind the capture viewer and the live views' readouts.

- ``GET /api/captures/{id}/thumb.jpg``: a small JPEG of the rectified left frame; safe against path
  tricks and symbolic links; cached.
- ``DELETE /api/captures/{id}`` moves the capture into the store's trash and
  ``POST /api/captures/{id}/restore`` brings it back bit for bit; the trash is purged by age and
  when a save is short of space.
- ``GET /api/point``: the rectified pixels, the disparity of the very map the disparity view shows,
  and the depth from the calibration's Q; on the synthetic rig within 2 % of the true depth.
- ``GET /api/disparity``: the disparity view's colour table and depth scale.
"""
from __future__ import annotations

import hashlib
import os
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Dict, Iterator

import cv2
import numpy as np
import pytest

from stereocam.server.frames.views import disparity_map
from stereocam.server.http.state import CALIBRATION, CAPTURES, FEED
from stereocam.server.stores import captures as captures_module
from stereocam.server.stores.captures import TRASH_DIR, TRASH_KEEP_S, CaptureNotFound, CaptureStore

from ..rig_truth import static_depth
from .daemon import (  # noqa: F401
    FULL,
    bad_id_status,
    make_overlay,
    start_uncalibrated,
    wait_for_frames,
)

# -- the store: trash, restore, thumbnails ----------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.now = datetime(2026, 11, 22, 4, 5, 12, tzinfo=timezone.utc)

    def __call__(self) -> datetime:
        return self.now


def frames(seed: int = 0) -> Dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {}
    for name in captures_module.FRAME_NAMES:  # smooth: a JPEG thumbnail keeps it
        coarse = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
        out[name] = cv2.resize(coarse, (64, 48), interpolation=cv2.INTER_LINEAR)
    return out


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def store(tmp_path: Path, clock: Clock) -> Iterator[CaptureStore]:
    yield CaptureStore(tmp_path / "captures", min_free_bytes=0, clock=clock)


def _hashes(folder: Path) -> Dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_trash_hides_and_restore_brings_back_bit_for_bit(store: CaptureStore) -> None:
    info = store.save(frames(1), {"frame": 1})
    before = _hashes(store.root / info.id)
    store.trash(info.id)
    assert store.list() == []
    with pytest.raises(CaptureNotFound):
        store.get(info.id)
    restored = store.restore(info.id)
    assert restored.id == info.id and restored.error is None
    assert _hashes(store.root / info.id) == before
    assert [c.id for c in store.list()] == [info.id]
    with pytest.raises(CaptureNotFound, match="not in the trash"):
        store.restore(info.id)
    # Deleted, restored and deleted again within one tick of the clock: both kept apart.
    store.trash(info.id)
    store.restore(info.id)
    store.trash(info.id)
    assert store.restore(info.id).id == info.id


def test_the_trash_is_purged_by_age_and_when_space_is_short(store: CaptureStore, clock: Clock,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    old = store.save(frames(1), {"frame": 1})
    store.trash(old.id)
    clock.now += timedelta(seconds=TRASH_KEEP_S + 1)
    young = store.save(frames(2), {"frame": 2})
    store.trash(young.id)  # purges what is older than TRASH_KEEP_S
    with pytest.raises(CaptureNotFound):
        store.restore(old.id)
    assert [p.name.split(".")[0] for p in (store.root / TRASH_DIR).iterdir()] == [young.id]
    # Short of space: the trash goes first, then the save is refused only if that was not enough.
    free = iter([100, 10**12])
    monkeypatch.setattr(store, "free_bytes", lambda: next(free))
    saved = store.save(frames(3), {"frame": 3})
    assert list((store.root / TRASH_DIR).iterdir()) == []
    assert [c.id for c in store.list()] == [saved.id]
    # A new store (a restart) keeps the young trash, drops the old.
    store.trash(saved.id)
    CaptureStore(store.root, min_free_bytes=0, clock=clock)
    assert store.restore(saved.id).id == saved.id


def test_restore_refuses_bad_ids_and_a_symlinked_trash(store: CaptureStore, tmp_path: Path) -> None:
    for bad in ("..", "../x", "20261122T040512Z-000001-ABCD", ".trash"):
        with pytest.raises(captures_module.InvalidCaptureId):
            store.restore(bad)
    info = store.save(frames(1), {"frame": 1})
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    os.symlink(outside, store.root / TRASH_DIR)
    with pytest.raises(captures_module.CaptureError, match="not a folder"):
        store.trash(info.id)
    assert [c.id for c in store.list()] == [info.id] and list(outside.iterdir()) == []


def test_thumbnail_is_the_rectified_left_frame_small(store: CaptureStore) -> None:
    f = frames(4)
    info = store.save(f, {"frame": 4})
    jpeg = store.thumbnail(info.id, width=32)
    thumb = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert thumb.shape == (24, 32, 3)
    expected = cv2.resize(cv2.cvtColor(f["rect_left"], cv2.COLOR_RGB2BGR), (32, 24),
                          interpolation=cv2.INTER_AREA)
    assert np.abs(thumb.astype(int) - expected).mean() < 12
    # A symbolic link in place of rect_left.png is not followed: the raw left frame is used.
    folder = store.root / info.id
    secret = store.root.parent / "secret.png"
    cv2.imwrite(str(secret), np.zeros((48, 64, 3), np.uint8))
    (folder / "rect_left.png").unlink()
    os.symlink(secret, folder / "rect_left.png")
    thumb = cv2.imdecode(np.frombuffer(store.thumbnail(info.id, width=64), np.uint8), cv2.IMREAD_COLOR)
    raw = cv2.cvtColor(f["raw_left"], cv2.COLOR_RGB2BGR)
    assert np.abs(thumb.astype(int) - raw).mean() < 12
    (folder / "raw_left.png").write_bytes(b"not a png")
    with pytest.raises(captures_module.CaptureDamaged):
        store.thumbnail(info.id)


# -- over HTTP -------------------------------------------------------------------------------------

async def test_thumb_restore_and_path_tricks_over_http(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        cid = (await resp.json())["id"]
    async with d.http.get(f"/api/captures/{cid}/thumb.jpg") as resp:
        assert resp.status == 200 and resp.content_type == "image/jpeg"
        first = await resp.read()
    thumb = cv2.imdecode(np.frombuffer(first, np.uint8), cv2.IMREAD_COLOR)
    w, h = d.overlay.fabric.frame_size
    assert thumb.shape[1] == 160 and abs(thumb.shape[0] - round(h * 160 / w)) <= 1
    async with d.http.get(f"/api/captures/{cid}/rect_left.png") as resp:
        rect = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_COLOR)
    small = cv2.resize(rect, (thumb.shape[1], thumb.shape[0]), interpolation=cv2.INTER_AREA)
    assert np.abs(small.astype(int) - thumb).mean() < 12
    async with d.http.get(f"/api/captures/{cid}/thumb.jpg") as resp:
        assert await resp.read() == first  # from the cache
    # thumb.jpg is not a file of the capture: the listing and the zip are as before.
    async with d.http.get(f"/api/captures/{cid}") as resp:
        assert "thumb.jpg" not in [f["name"] for f in (await resp.json())["files"]]
    for bad in ("..", "..%2F..%2Fetc", "%2E%2E", "20260101T000000Z-000001-ABCD", "x" * 40, ".trash"):
        for method, path in (("GET", f"/api/captures/{bad}/thumb.jpg"),
                             ("POST", f"/api/captures/{bad}/restore")):
            async with d.http.request(method, path) as resp:
                assert resp.status == bad_id_status(bad, path), (method, path, resp.status)
                assert "error" in await resp.json()
    # Delete (into the trash), then undo.
    async with d.http.delete(f"/api/captures/{cid}") as resp:
        assert resp.status == 204
    async with d.http.get("/api/captures") as resp:
        assert (await resp.json())["captures"] == []
    async with d.http.get(f"/api/captures/{cid}/thumb.jpg") as resp:
        assert resp.status == 404
    async with d.http.post(f"/api/captures/{cid}/restore") as resp:
        assert resp.status == 200
        body = await resp.json()
        assert body["id"] == cid and resp.headers["Location"] == f"/api/captures/{cid}"
    async with d.http.get("/api/captures") as resp:
        assert [c["id"] for c in (await resp.json())["captures"]] == [cid]
    async with d.http.post(f"/api/captures/{cid}/restore") as resp:
        assert resp.status == 404
    # Restore is a change: another origin may not.
    async with d.http.delete(f"/api/captures/{cid}") as resp:
        assert resp.status == 204
    async with d.http.post(f"/api/captures/{cid}/restore", headers={"Origin": "http://evil.example"}) as resp:
        assert resp.status == 403
    assert d.app[CAPTURES].list() == []


@pytest.mark.slow
async def test_point_reads_the_disparity_map_and_gives_depth_from_q(start_daemon) -> None:
    # The ARM's StereoBM (a fabric without the stereo core; the core's readout: test_stereo_daemon.py).
    d = await start_daemon(overlay=make_overlay(size=FULL, fps=5.0, calibrate=False, stereo=False))
    await wait_for_frames(d)
    rect = d.app[CALIBRATION].now.calibration.rect  # what GET /api/calibration's "rectification" shows
    rectification = {"R1": rect.R1.tolist(), "P1": rect.P1.tolist()}
    Q = np.asarray(rect.Q)
    async with d.http.get("/api/disparity") as resp:
        scale = await resp.json()
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(1, -1), cv2.COLORMAP_JET)[0]
    assert scale["colors"] == [f"#{r:02x}{g:02x}{b:02x}" for b, g, r in lut.tolist()]
    assert scale["num_disparities"] == 128 and scale["min_disparity"] == 0
    assert scale["frame_size"] == list(FULL)
    assert scale["focal_px"] == pytest.approx(Q[2, 3])
    assert scale["baseline_m"] == pytest.approx(1 / abs(Q[3, 2]))
    assert scale["baseline_m"] == pytest.approx(0.060, rel=0.05)

    u, v = 615, 381  # on the back wall, never reached by the moving planes
    truth = static_depth(rectification, u, v)
    assert truth is not None
    async with d.http.get(f"/api/point?x={u}&y={v}") as resp:
        assert resp.status == 200, await resp.text()
        p = await resp.json()
    assert (p["x"], p["y"], p["width"], p["height"]) == (u, v, *FULL)
    # The values and the disparity of that frame, as the daemon has it.
    fs = d.app[FEED].last_frame
    assert fs is not None
    if fs.frame == p["frame"]:
        px = fs.processed[v, u]
        assert p["rect_left"] == dict(zip("rgby", px[0:4].tolist(), strict=True))
        assert p["rect_right"] == dict(zip("rgby", px[4:8].tolist(), strict=True))
    disp = p["disparity_px"]
    assert disp is not None and disp > 0
    x, y, z, w = Q @ np.array([u, v, disp, 1.0])
    assert p["depth_m"] == pytest.approx(z / w) and p["point_m"] == pytest.approx([x / w, y / w, z / w])
    assert p["depth_m"] == pytest.approx(p["focal_px"] * p["baseline_m"] / disp)
    assert abs(p["depth_m"] - truth) / truth < 0.02, (p, truth)
    # The disparity is the block matcher's on that frame's rectified gray pair.
    if fs.frame == p["frame"]:
        ref = disparity_map(fs.processed[..., 3], fs.processed[..., 7])[v, u] / 16
        assert disp == ref
    # Asking for the frame shown, when it is at hand, answers for that frame.
    async with d.http.get(f"/api/point?x=0&y=0&frame={p['frame']}") as resp:
        q = await resp.json()
        assert q["x"] == 0 and q["y"] == 0
    for query in ("x=1", "y=1", "x=-1&y=0", f"x={FULL[0]}&y=0", "x=0&y=480", "x=a&y=1", "x=1&y=1&z=2",
                  "x=1.5&y=1"):
        async with d.http.get("/api/point?" + query) as resp:
            assert resp.status == 400, query
            assert "error" in await resp.json()


async def test_point_without_a_calibration_says_why_there_is_no_depth(start_daemon) -> None:
    d = await start_uncalibrated(start_daemon)
    async with d.http.get("/api/point?x=10&y=10") as resp:
        assert resp.status == 200
        p = await resp.json()
    assert p["depth_m"] is None and p["point_m"] is None and "no calibration" in p["depth_unavailable"]
    async with d.http.get("/api/disparity") as resp:
        scale = await resp.json()
    assert scale["focal_px"] is None and scale["baseline_m"] is None and len(scale["colors"]) == 256
