"""The control API over HTTP: status, source, virtual camera, verify, captures, metrics, health."""
from __future__ import annotations

import errno
import io
import json
import os
import zipfile

import cv2
import numpy as np
import pytest
from aiohttp import FormData

from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.spec import pixel
from stereocam.server.http.metrics import METRICS
from stereocam.server.http.state import CAPTURES, FEED, PIPELINE, VIRTUAL
from stereocam.server.stores import files as store_files

from ..sample import png_claiming
from .daemon import (
    FULL,
    SMALL,
    TEST_FPS,
    H,
    StillSource,
    W,
    bad_id_status,
    read_parts,  # noqa: F401
    until,
    wait_for_frames,
)

pytestmark = pytest.mark.slow


def pattern_pair(seed: int = 1) -> "tuple[np.ndarray, np.ndarray]":
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8)
    base = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)
    return base, np.ascontiguousarray(np.roll(base, -12, axis=1))


def encode(rgb: np.ndarray, ext: str = ".png") -> bytes:
    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
    ok, buf = cv2.imencode(ext, img)
    assert ok
    return buf.tobytes()


def form(*fields: "tuple[str, bytes]") -> FormData:
    out = FormData()
    for name, data in fields:
        out.add_field(name, data, filename=f"{name}.img", content_type="application/octet-stream")
    return out


def pair_form(left: bytes, right: bytes) -> FormData:
    return form(("left", left), ("right", right))


def decode_png(data: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return img


def model_output(daemon, frame: np.ndarray) -> np.ndarray:
    config, options = daemon.overlay.core_setup()
    return RectifyModel(config.left, config.right, config.width, config.height, options).process(frame).frame


# -- status, source, operations -------------------------------------------------------------------

async def test_status_reports_the_daemon(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 3)
    status, s = await d.json("GET", "/api/status")
    assert status == 200
    assert s["backend"] == "emulated" and s["source"] == "live" and s["mux"] == "live"
    assert s["frame_size"] == [W, H] and s["signal"] is True
    # Nobody watches: the pipeline sees the frames and copies none (the CPU budget).
    assert s["fps"]["camera"] > 0 and s["fps"]["pipeline"] == 0
    assert s["frames_seen"] >= 3 and s["frames"] == 0 and s["drops"] >= 0
    assert s["cpu"]["cores"] == os.cpu_count() and s["cpu"]["limited"] is False and s["encoders"] == []
    assert s["core"]["frame_count"] > 0 and s["core"]["control"]["ENABLE"] == 1 and s["core"]["lb_rows"] == 80
    assert s["vdma"] == {"raw_s2mm": [], "proc_s2mm": [], "proc_mm2s": []}
    assert s["calibration"]["id"].startswith("synthetic-rig-") and s["calibration"]["lb_rows"] == 80
    assert s["clients"] == 0 and isinstance(s["uptime_s"], float) and s["errors"] == []


async def test_status_has_extension_sections(start_daemon) -> None:
    from prometheus_client.core import GaugeMetricFamily

    from stereocam.server.http.state import EXTENSIONS

    def setup(app) -> None:
        app[EXTENSIONS].status["sensors"] = lambda: {"exposure_us": 1000}
        app[EXTENSIONS].capture_meta["sensors"] = lambda: {"gain": 2}
        app[EXTENSIONS].metrics.append(lambda: [GaugeMetricFamily("stereocam_sensor_gain", "Gain.", value=2)])

    d = await start_daemon(extensions=[setup])
    async with d.http.get("/api/status") as resp:
        assert (await resp.json())["sensors"] == {"exposure_us": 1000}
    async with d.http.get("/metrics") as resp:
        assert "stereocam_sensor_gain 2.0" in (await resp.text()).splitlines()
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    async with d.http.get(f"/api/captures/{cid}") as resp:
        assert (await resp.json())["meta"]["sensors"] == {"gain": 2}


async def test_metrics_are_prometheus_text(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/stream/rect_left") as stream:
        await read_parts(stream, 3)
        async with d.http.get("/metrics") as resp:
            assert resp.status == 200
            assert resp.headers["Content-Type"].startswith("text/plain; version=0.0.4")
            text = await resp.text()
    for name in ('stereocam_stage_frames_per_second{stage="camera"}',
                 'stereocam_stage_frames_per_second{stage="pipeline"}',
                 'stereocam_view_encoded_frames_per_second{view="rect_left"}', "stereocam_frames_total",
                 "stereocam_drops_total", 'stereocam_encode_seconds_count{view="rect_left"}',
                 'stereocam_encode_seconds_sum{view="rect_left"}', 'stereocam_clients{kind="mjpeg"} 1.0',
                 "stereocam_uploads_total", "stereocam_errors_total"):
        assert name in text, name
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            float(value)


async def test_healthz(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 2)
    async with d.http.get("/healthz") as resp:
        assert resp.status == 200 and (await resp.text()).strip() == "ok"


async def test_source_get_and_put(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/api/source") as resp:
        assert await resp.json() == {"source": "live"}
    async with d.http.put("/api/source", json={"source": "virtual"}) as resp:  # nothing to show yet
        assert resp.status == 409 and "no input yet" in (await resp.json())["error"]
    assert d.overlay.fabric.source == "live"
    async with d.http.get("/api/status") as resp:
        status = await resp.json()
    assert status["source"] == status["mux"] == "live"
    left, right = pattern_pair(6)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200
    async with d.http.put("/api/source", json={"source": "live"}) as resp:
        assert await resp.json() == {"source": "live"}
    async with d.http.put("/api/source", json={"source": "virtual"}) as resp:  # back to that input
        assert resp.status == 200 and await resp.json() == {"source": "virtual"}
    assert d.overlay.fabric.source == "virtual"
    async with d.http.put("/api/source", json={"source": "live"}) as resp:
        assert await resp.json() == {"source": "live"}
    assert d.overlay.fabric.source == "live"
    for body, status in (({"source": "hdmi"}, 400), ({"src": "live"}, 400), (["live"], 400)):
        async with d.http.put("/api/source", json=body) as resp:
            assert resp.status == status and "error" in await resp.json()
    async with d.http.put("/api/source", data=b"{nope", headers={"Content-Type": "application/json"}) as resp:
        assert resp.status == 400
    async with d.http.put("/api/source", data=b"live") as resp:
        assert resp.status == 415
    async with d.http.post("/api/source", json={"source": "live"}) as resp:
        assert resp.status == 405 and "not allowed" in (await resp.json())["error"]


async def test_unknown_paths_are_json_404(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.get("/api/nothing") as resp:
        assert resp.status == 404 and (await resp.json())["error"] == "no such resource: /api/nothing"
    async with d.http.get("/static/../../etc/passwd") as resp:
        assert resp.status == 404


async def test_the_page_is_served_at_root(start_daemon) -> None:
    from stereocam.server.http.app import STATIC_DIR

    d = await start_daemon()
    async with d.http.get("/") as resp:
        if (STATIC_DIR / "index.html").is_file():
            assert resp.status == 200 and resp.content_type == "text/html"
        else:
            assert resp.status == 404


# -- virtual camera and verify ----------------------------------------------------------------------

async def test_virtual_camera_round_trip_is_returned_shown_and_verified_bit_exact(start_daemon) -> None:
    d = await start_daemon()
    left, right = pattern_pair()
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200, await resp.text()
        body = await resp.json()
    assert body["source"] == "virtual" and (body["width"], body["height"]) == (W, H)
    assert d.overlay.fabric.source == "virtual"
    frame = pixel.pack(pixel.rgby(left), pixel.rgby(right))
    expected = model_output(d, frame)
    async with d.http.get("/api/virtual-camera/result/left.png") as resp:
        assert int(resp.headers["X-Frame-Number"]) == body["frame"]
        np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., [2, 1, 0]])
    async with d.http.get("/api/virtual-camera/result/right.png") as resp:
        np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., [6, 5, 4]])
    async with d.http.get("/snapshot/rect_right.png") as resp:  # the views show the processed pair
        np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., [6, 5, 4]])
    async with d.http.get("/snapshot/raw_left.png") as resp:  # and the raw views its input
        np.testing.assert_array_equal(decode_png(await resp.read()), left[..., ::-1])
    status, report = await d.json("POST", "/api/verify")
    assert status == 200
    assert report["identical"] is True
    assert report["differing"] == 0 and report["share"] == 0 and report["max_diff"] == 0
    assert report["psnr_db"] is None
    assert set(report["channels"]) == set(pixel.CHANNELS)
    assert all(c["differing"] == 0 and c["max_diff"] == 0 for c in report["channels"].values())
    async with d.http.get("/api/verify/difference.png") as resp:
        diff = decode_png(await resp.read())
    assert diff.shape == (H, 2 * W, 3) and not diff.any()
    async with d.http.put("/api/source", json={"source": "live"}) as resp:
        assert resp.status == 200
    assert d.overlay.fabric.source == "live"


async def test_the_daemon_serves_a_gray_build_of_the_core(start_daemon) -> None:
    """The build is read back from the core (CAPS.COLOUR): views, status and Verify follow it."""
    from stereocam.overlays.spec.rectify import BUILDS

    overlay = EmulatedOverlay(source=StillSource(SMALL), fps=TEST_FPS, build=BUILDS["gray"])
    d = await start_daemon(overlay=overlay)
    async with d.http.get("/api/status") as resp:
        core = (await resp.json())["core"]
    assert core["colour"] is False and core["lb_rows"] == BUILDS["gray"].lb_rows
    left, right = pattern_pair(3)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200, await resp.text()
    frame = pixel.pack(pixel.rgby(left), pixel.rgby(right))
    expected = model_output(d, frame)
    assert (expected[..., 0] == expected[..., 3]).all() and (expected[..., 6] == expected[..., 7]).all()
    async with d.http.get("/api/virtual-camera/result/left.png") as resp:
        shown = decode_png(await resp.read())
    np.testing.assert_array_equal(shown, expected[..., [2, 1, 0]])
    assert expected[..., 3].any()
    async with d.http.post("/api/verify") as resp:
        assert (await resp.json())["identical"] is True


async def test_verify_reports_differences(start_daemon) -> None:
    d = await start_daemon()
    left, right = pattern_pair(2)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200
    async with d.http.put("/api/source", json={"source": "live"}) as resp:
        assert resp.status == 200
    d.overlay.fabric.rectify.set_mode(bypass=True)  # the model now expects a pass-through
    async with d.http.post("/api/verify") as resp:
        report = await resp.json()
    assert report["identical"] is False and report["differing"] > 0 and 0 < report["share"] <= 1
    assert report["max_diff"] > 0 and "max_difference" not in report and report["psnr_db"] > 0
    assert max(c["max_diff"] for c in report["channels"].values()) == report["max_diff"]
    async with d.http.get("/api/verify/difference.png") as resp:
        assert decode_png(await resp.read()).any()


async def test_verify_without_virtual_input_is_409(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.post("/api/verify") as resp:
        assert resp.status == 409 and "virtual-camera" in (await resp.json())["error"]
    async with d.http.get("/api/verify/difference.png") as resp:
        assert resp.status == 404
    async with d.http.get("/api/virtual-camera/result/left.png") as resp:
        assert resp.status == 404


@pytest.mark.parametrize("ext", [".png", ".bmp", ".jpg", ".tiff"])
async def test_virtual_camera_takes_a_side_by_side_image_in_every_format(start_daemon, ext) -> None:
    d = await start_daemon()
    left, right = pattern_pair(3)
    sbs = encode(np.hstack([left, right]), ext)
    async with d.http.post("/api/virtual-camera", data=form(("sbs", sbs))) as resp:
        assert resp.status == 200, await resp.text()
    vc = d.app[VIRTUAL]
    assert vc.input is not None and vc.input.shape == (H, W, 8)
    if ext != ".jpg":
        np.testing.assert_array_equal(vc.input[..., 0:3], left)
        np.testing.assert_array_equal(vc.input[..., 4:7], right)
    async with d.http.post("/api/verify") as resp:
        assert (await resp.json())["identical"] is True


async def test_virtual_camera_replays_a_capture(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        cid = (await resp.json())["id"]
    async with d.http.post("/api/virtual-camera", json={"capture": cid}) as resp:
        assert resp.status == 200, await resp.text()
        assert (await resp.json())["input"] == f"capture {cid}"
    _, raw = d.overlay.fabric.latest_raw()
    np.testing.assert_array_equal(d.app[VIRTUAL].input, raw)  # the still scene's raw frame, bit for bit
    async with d.http.post("/api/verify") as resp:
        assert (await resp.json())["identical"] is True
    async with d.http.post("/api/virtual-camera", json={"capture": "20260101T000000Z-000001-abcd"}) as resp:
        assert resp.status == 404
    async with d.http.post("/api/virtual-camera", json={"capture": "../../etc"}) as resp:
        assert resp.status == 400
    async with d.http.post("/api/virtual-camera", json={"capture": cid, "x": 1}) as resp:
        assert resp.status == 400


def bad_uploads() -> list:
    left, right = pattern_pair(4)
    good = encode(left)
    small = encode(cv2.resize(left, (W // 2, H // 2)))
    return [
        ("wrong size", pair_form(small, small), 422),
        ("unknown format", pair_form(b"GIF89a" + b"\0" * 100, good), 415),
        ("random bytes", pair_form(np.random.default_rng(0).bytes(5000), good), 415),
        ("truncated", pair_form(good[: len(good) // 2], good), 400),
        ("empty", pair_form(b"", good), 400),
        ("bomb", pair_form(png_claiming(60000, 60000), good), 413),
        ("missing right", form(("left", good)), 400),
        ("unknown field", form(("middle", good)), 400),
        ("both", form(("left", good), ("right", good), ("sbs", good)), 400),
    ]


async def test_bad_uploads_are_4xx_while_streaming_goes_on_and_nothing_changes(start_daemon) -> None:
    d = await start_daemon()
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    before = sorted(p.name for p in d.app[CAPTURES].root.rglob("*"))
    async with d.http.get("/stream/rect_left") as stream:
        await read_parts(stream, 1)
        for name, form, status in bad_uploads():
            async with d.http.post("/api/virtual-camera", data=form) as resp:
                assert resp.status == status, (name, await resp.text())
                text = await resp.text()
                error = json.loads(text)["error"]
                assert error and "\n" not in error and "Traceback" not in text, name
            parts = await read_parts(stream, 1)  # the stream goes on
            assert parts[0][0].get("x-signal") is None
        for body, ctype, status in ((b"not json", "application/json", 400), (b"x", "text/plain", 415)):
            async with d.http.post("/api/virtual-camera", data=body, headers={"Content-Type": ctype}) as resp:
                assert resp.status == status
    assert d.overlay.fabric.source == "live" and d.app[VIRTUAL].input is None
    assert sorted(p.name for p in d.app[CAPTURES].root.rglob("*")) == before
    async with d.http.get(f"/api/captures/{cid}") as resp:
        assert resp.status == 200 and (await resp.json())["error"] is None
    metrics = d.app[METRICS]
    assert metrics.uploads["rejected"] == len(bad_uploads()) + 2


async def test_oversized_uploads_are_413(start_daemon) -> None:
    d = await start_daemon(max_upload_bytes=200_000)
    big = np.random.default_rng(1).bytes(300_000)
    async with d.http.post("/api/virtual-camera", data=pair_form(big, big)) as resp:
        assert resp.status == 413 and "200000" in (await resp.json())["error"]

    boundary = "XyZ"
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"left\"; "
            "filename=\"l.png\"\r\n\r\n").encode()

    async def gen():  # no Content-Length: the upload reader stops at the limit
        yield body
        for _ in range(30):
            yield b"\x89" * 10_000
        yield f"\r\n--{boundary}--\r\n".encode()

    async with d.http.post("/api/virtual-camera", data=gen(),
                           headers={"Content-Type": f"multipart/form-data; boundary={boundary}"}) as resp:
        assert resp.status == 413
    async with d.http.put("/api/source", data=b"{" + b" " * 300_000 + b"}",
                          headers={"Content-Type": "application/json"}) as resp:
        assert resp.status == 413


# -- captures ---------------------------------------------------------------------------------------

async def test_capture_stores_a_synchronised_set(start_daemon) -> None:
    d = await start_daemon()
    await wait_for_frames(d, 2)
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201
        created = await resp.json()
    cid = created["id"]
    assert resp.headers["Location"] == f"/api/captures/{cid}"
    async with d.http.get("/api/captures") as resp:
        listing = (await resp.json())["captures"]
    assert [c["id"] for c in listing] == [cid]
    entry = listing[0]
    for key in ("id", "created", "frame", "source", "calibration_id", "files", "bytes"):
        assert key in entry
    assert entry["source"] == "live" and entry["calibration_id"].startswith("synthetic-rig-")
    names = {f["name"] for f in entry["files"]}
    assert {"raw_left.png", "raw_right.png", "rect_left.png", "rect_right.png", "meta.json"} <= names
    async with d.http.get(f"/api/captures/{cid}") as resp:
        meta = (await resp.json())["meta"]
    assert meta["frame"] == entry["frame"] and meta["source"] == "live"
    assert meta["registers"]["FRAME_COUNT"] > 0 and meta["registers"]["LB_ROWS"] == 80
    assert meta["backend"] == "emulated" and meta["frame_size"] == [W, H] and meta["time"] > 0
    # Raw and rectified are one set: the rectified pair is the model's output of the raw pair.
    async with d.http.get(f"/api/captures/{cid}.zip") as resp:
        assert resp.status == 200 and resp.content_type == "application/zip"
        assert f'filename="{cid}.zip"' in resp.headers["Content-Disposition"]
        archive = zipfile.ZipFile(io.BytesIO(await resp.read()))
    assert {n.split("/", 1)[1] for n in archive.namelist()} == names
    raw = np.dstack([pixel.rgby(cv2.cvtColor(decode_png(archive.read(f"{cid}/raw_{s}.png")),
                                             cv2.COLOR_BGR2RGB))
                     for s in ("left", "right")])
    expected = model_output(d, raw)
    rect_left = decode_png(archive.read(f"{cid}/rect_left.png"))
    np.testing.assert_array_equal(rect_left, expected[..., [2, 1, 0]])
    async with d.http.get(f"/api/captures/{cid}/rect_right.png") as resp:
        assert resp.content_type == "image/png"
        np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., [6, 5, 4]])
    async with d.http.get(f"/api/captures/{cid}/meta.json") as resp:
        assert json.loads(await resp.read())["id"] == cid
    async with d.http.get(f"/api/captures/{cid}/secret.txt") as resp:
        assert resp.status == 404
    async with d.http.delete(f"/api/captures/{cid}") as resp:
        assert resp.status == 204
    async with d.http.get("/api/captures") as resp:
        assert (await resp.json())["captures"] == []
    for method, path in (("GET", f"/api/captures/{cid}.zip"), ("DELETE", f"/api/captures/{cid}"),
                         ("GET", f"/api/captures/{cid}/meta.json")):
        async with d.http.request(method, path) as resp:
            assert resp.status == 404


@pytest.mark.parametrize("bad", ["..", "..%2F..%2Fetc", "etc%2Fpasswd", "x" * 40,
                                 "20260101T000000Z-000001-ABCD", "%2E%2E", "capture"])
async def test_capture_ids_cannot_escape_the_folder(start_daemon, bad) -> None:
    d = await start_daemon()
    for method, path in (("GET", f"/api/captures/{bad}.zip"), ("DELETE", f"/api/captures/{bad}"),
                         ("GET", f"/api/captures/{bad}"), ("GET", f"/api/captures/{bad}/meta.json")):
        async with d.http.request(method, path) as resp:
            assert resp.status == bad_id_status(bad, path), (method, path, resp.status)
            assert "error" in await resp.json()
    assert d.app[CAPTURES].root.exists()


async def test_full_disk_is_507_and_leaves_nothing(start_daemon, monkeypatch) -> None:
    d = await start_daemon()
    store = d.app[CAPTURES]

    def no_space(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store_files, "_os_write", no_space)
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 507
        error = (await resp.json())["error"]
    assert "full" in error and "\n" not in error
    assert list(store.root.iterdir()) == []
    monkeypatch.undo()
    monkeypatch.setattr(store, "free_bytes", lambda: 1000)
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 507
    assert list(store.root.iterdir()) == []
    async with d.http.get("/stream/rect_left") as stream:
        await read_parts(stream, 1)


async def test_capture_while_virtual_stores_the_virtual_input_and_output(start_daemon) -> None:
    d = await start_daemon()
    left, right = pattern_pair(5)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200
    async with d.http.post("/api/captures") as resp:
        cid = (await resp.json())["id"]
    async with d.http.get(f"/api/captures/{cid}") as resp:
        info = await resp.json()
    assert info["source"] == "virtual" and info["meta"]["virtual_input"].startswith("upload")
    async with d.http.get(f"/api/captures/{cid}/raw_left.png") as resp:
        np.testing.assert_array_equal(decode_png(await resp.read()), left[..., ::-1])


async def test_capture_without_signal_is_503(start_daemon) -> None:
    d = await start_daemon(no_signal_s=0.2)
    d.overlay.emulation.cameras_running = False
    feed = d.app[FEED]
    await until(lambda: not feed.signal, "the signal going (the last frame older than no_signal_s)")
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 503
    assert list(d.app[CAPTURES].root.iterdir()) == []
    assert d.app[PIPELINE].running


@pytest.mark.timeout(900)  # 40 full-size captures: slow on a busy machine, never red
async def test_every_capture_pairs_raw_and_rectified_of_one_frame(start_daemon) -> None:
    """A capture is the closed loop's ground truth: its rectified pair is the core's output for its raw
    pair, checked by the model and by replaying it through the virtual camera."""
    from stereocam.overlays.emulated.render import SyntheticRig

    overlay = EmulatedOverlay(source=SyntheticRig(size=FULL, motion=True), fps=60)  # as the daemon runs
    d = await start_daemon(overlay=overlay)
    await wait_for_frames(d, 3)
    store = d.app[CAPTURES]
    ids = []
    for _ in range(40):
        async with d.http.post("/api/captures") as resp:
            assert resp.status == 201, await resp.text()
            ids.append((await resp.json())["id"])
    raws = {}
    for cid in ids:
        meta = store.get(cid).to_json(meta=True)["meta"]
        assert meta["pairing"] == "checked" and isinstance(meta["fabric_count"], int), meta.get("pairing")
        raws[cid] = pixel.pack(*store.raw_pair(cid))
        expected = model_output(d, raws[cid])
        for side, channels in (("left", [0, 1, 2]), ("right", [4, 5, 6])):
            rect = cv2.cvtColor(decode_png(store.read_file(cid, f"rect_{side}.png")), cv2.COLOR_BGR2RGB)
            np.testing.assert_array_equal(rect, expected[..., channels], err_msg=f"{cid} rect_{side}")
    assert len({raw.tobytes() for raw in raws.values()}) > 10  # the scene moved: pairing mattered
    for cid in ids[::10]:  # the closed loop itself: replay the raw pair through the fabric
        async with d.http.post("/api/virtual-camera", json={"capture": cid}) as resp:
            assert resp.status == 200, await resp.text()
        async with d.http.get("/api/virtual-camera/result/left.png") as resp:
            replayed = decode_png(await resp.read())
        assert np.array_equal(replayed, decode_png(store.read_file(cid, "rect_left.png"))), cid


def _fault(vdma, channel: str, error: str = "VDMADecErr") -> None:
    """A fatal DMA error on one channel of an emulated VDMA (it halts, as the IP does)."""
    with vdma.lock:
        vdma._fatal(vdma.channels[channel], error)


async def test_a_raw_channel_fault_is_recovered_and_the_other_streams_go_on(start_daemon, caplog) -> None:
    """The raw S2MM channel was never restarted and froze every stream."""
    import logging

    caplog.set_level(logging.WARNING)
    d = await start_daemon()
    pipeline = d.app[PIPELINE]
    await wait_for_frames(d, 2)
    async with d.http.get("/snapshot/raw_left.png") as resp:
        assert resp.status == 200
    _fault(d.overlay.emulation.vdma_raw, "S2MM")
    frames = pipeline.frames
    async with d.http.get("/snapshot/raw_left.png") as resp:  # waits for a frame with its raw pair
        assert resp.status == 200, await resp.text()
    async with d.http.post("/api/captures") as resp:
        assert resp.status == 201, await resp.text()
    assert pipeline.frames > frames
    assert d.overlay.fabric.raw_vdma.s2mm.errors() == ()
    warnings = [r for r in caplog.records if "raw frames channel" in r.getMessage()]
    assert len(warnings) == 1, [r.getMessage() for r in warnings]  # one line, not one per frame


async def test_an_mm2s_fault_does_not_fail_the_next_upload(start_daemon) -> None:
    d = await start_daemon()
    left, right = pattern_pair(7)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200
    _fault(d.overlay.emulation.vdma_proc, "MM2S")
    left2, right2 = pattern_pair(8)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left2), encode(right2))) as resp:
        assert resp.status == 200, await resp.text()
    expected = model_output(d, pixel.pack(pixel.rgby(left2), pixel.rgby(right2)))
    async with d.http.get("/api/virtual-camera/result/left.png") as resp:
        np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., [2, 1, 0]])
