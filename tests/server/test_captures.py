"""The capture store: atomic saves, listing, zip download, delete, replay, and every way it can go wrong."""
from __future__ import annotations

import errno
import gc
import hashlib
import io
import json
import os
import subprocess
import threading
import zipfile
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Callable, Dict, Iterator, List

import cv2
import numpy as np
import pytest

from stereocam.overlays.emulated.replay import ReplaySource
from stereocam.overlays.spec import pixel
from stereocam.server.http.errors import status_of
from stereocam.server.stores import captures, folder_store
from stereocam.server.stores import files as store_files
from stereocam.server.stores.captures import (
    CaptureDamaged,
    CaptureDiskFull,
    CaptureError,
    CaptureInfo,
    CaptureNotFound,
    CaptureStore,
    InvalidCaptureId,
)

pytestmark = pytest.mark.armhf

W, H = 24, 16
T0 = datetime(2026, 11, 22, 4, 5, 12, 345678, tzinfo=timezone.utc)


def fixed_clock(t: datetime = T0) -> Callable[[], datetime]:
    return lambda: t


def stepping_clock(start: datetime = T0, step: timedelta = timedelta(seconds=1)) -> Callable[[], datetime]:
    lock = threading.Lock()
    state = {"t": start - step}

    def now() -> datetime:
        with lock:
            state["t"] += step
            return state["t"]

    return now


def colour_raw(seed: int, w: int = W, h: int = H) -> np.ndarray:
    """A raw RGBY camera view as the demosaic delivers it: Y = gray_of(RGB)."""
    rgb = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    return pixel.rgby(rgb)


def colour_rect(seed: int, w: int = W, h: int = H) -> np.ndarray:
    """A rectified RGBY view: Y interpolated on its own, so not gray_of(RGB) everywhere."""
    return np.random.default_rng(seed).integers(0, 256, (h, w, 4), dtype=np.uint8)


def gray_view(seed: int, w: int = W, h: int = H) -> np.ndarray:
    g = np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)
    return pixel.rgby(g)


def stream_frames(seed: int = 1) -> Dict[str, np.ndarray]:
    """Views of two (H, W, 8) stream frames, as the daemon has them."""
    raw = pixel.pack(colour_raw(seed), colour_raw(seed + 1))
    rect = pixel.pack(colour_rect(seed + 2), colour_rect(seed + 3))
    return {
        "raw_left": raw[..., pixel.LEFT], "raw_right": raw[..., pixel.RIGHT],
        "rect_left": rect[..., pixel.LEFT], "rect_right": rect[..., pixel.RIGHT],
    }


def meta(frame: int = 123, **extra: object) -> Dict[str, object]:
    out: Dict[str, object] = {
        "frame": frame, "time": 12.5, "source": "synthetic", "calibration_id": "rig-2026",
        "registers": {"CONTROL": np.uint32(1), "H_INV_L": np.array([1.0, 0.0, 0.5])},
        "camera": {"exposure_us": 8000, "gain": np.int64(16)},
    }
    out.update(extra)
    return out


@pytest.fixture
def store(tmp_path: Path) -> CaptureStore:
    return CaptureStore(tmp_path / "captures", min_free_bytes=0, clock=stepping_clock())


def read_png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None, path
    return np.asarray(image)


def tree(root: Path) -> List[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# -- save, list, get ---------------------------------------------------------

def test_save_stores_pngs_and_meta_and_lists_it(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta())
    assert isinstance(info, CaptureInfo) and info.error is None
    assert info.id == "20261122T040512Z-000123-" + info.id[-4:] and CaptureStore.valid_id(info.id)
    assert info.created == "2026-11-22T04:05:12.345Z"
    assert (info.frame, info.source, info.calibration_id) == (123, "synthetic", "rig-2026")
    folder = store.root / info.id
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["meta.json", "raw_left.png", "raw_right.png", "rect_left.png", "rect_left_y.png",
                     "rect_right.png", "rect_right_y.png"]
    assert [f.name for f in info.files] == names
    assert info.bytes == sum((folder / n).stat().st_size for n in names)

    doc = json.loads((folder / "meta.json").read_text())
    assert doc["id"] == info.id and doc["created"] == info.created and doc["format"] == "stereocam-capture/1"
    assert doc["registers"] == {"CONTROL": 1, "H_INV_L": [1.0, 0.0, 0.5]}  # numpy converted
    assert doc["camera"] == {"exposure_us": 8000, "gain": 16} and doc["time"] == 12.5
    assert doc["images"]["raw_left"] == {"file": "raw_left.png", "width": W, "height": H, "color": "rgb",
                                         "y_file": None}
    assert doc["images"]["rect_right"]["y_file"] == "rect_right_y.png"
    for entry in doc["files"]:
        data = (folder / entry["name"]).read_bytes()
        assert entry["bytes"] == len(data) and entry["sha256"] == hashlib.sha256(data).hexdigest()
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
    assert {f["name"] for f in doc["files"]} == set(names) - {"meta.json"}

    assert store.list() == [info]
    got = store.get(info.id)
    assert got == info and got.meta["camera"] == {"exposure_us": 8000, "gain": 16}
    assert info.meta == got.meta and info.to_json(meta=True) == got.to_json(meta=True)
    assert store.path(info.id) == folder
    js = got.to_json(meta=True)
    json.dumps(js, allow_nan=False)
    assert js["id"] == info.id and js["error"] is None and js["meta"]["frame"] == 123
    assert {f["name"]: f["sha256"] for f in js["files"]}["meta.json"] is None
    assert "meta" not in info.to_json()


def test_png_files_hold_exactly_the_pixels(store: CaptureStore) -> None:
    frames = stream_frames(7)
    info = store.save(frames, meta())
    folder = store.root / info.id
    raw = cv2.cvtColor(read_png(folder / "raw_left.png"), cv2.COLOR_BGR2RGB)
    assert np.array_equal(raw, frames["raw_left"][..., :3])
    y = read_png(folder / "rect_left_y.png")
    assert y.ndim == 2 and np.array_equal(y, frames["rect_left"][..., 3])


def test_gray_camera_is_stored_as_gray_png_and_replays_bit_exact(store: CaptureStore) -> None:
    frames = {"raw_left": gray_view(1), "raw_right": gray_view(2), "rect_left": gray_view(3),
              "rect_right": gray_view(4)}
    info = store.save(frames, meta())
    folder = store.root / info.id
    assert sorted(p.name for p in folder.iterdir()) == ["meta.json", "raw_left.png", "raw_right.png",
                                                         "rect_left.png", "rect_right.png"]
    png = read_png(folder / "raw_right.png")
    assert png.ndim == 2 and np.array_equal(png, frames["raw_right"][..., 0])
    assert store.get(info.id).meta["images"]["rect_left"]["color"] == "gray"
    left, right = store.raw_pair(info.id)
    assert np.array_equal(left, frames["raw_left"]) and np.array_equal(right, frames["raw_right"])


def test_raw_pair_round_trips_every_pixel_kind(store: CaptureStore) -> None:
    odd_y = colour_rect(9)  # colour with a Y that is not gray_of(RGB): kept in raw_left_y.png
    frames = {"raw_left": odd_y, "raw_right": colour_raw(10), "rect_left": colour_rect(11),
              "rect_right": colour_rect(12)}
    info = store.save(frames, meta())
    assert (store.root / info.id / "raw_left_y.png").is_file()
    assert not (store.root / info.id / "raw_right_y.png").exists()
    left, right = store.raw_pair(info.id)
    assert left.shape == (H, W, 4) and left.dtype == np.uint8 and left.flags.writeable
    assert np.array_equal(left, odd_y) and np.array_equal(right, frames["raw_right"])


def test_rgb_and_gray_inputs_are_accepted(store: CaptureStore) -> None:
    rgb = colour_raw(3)[..., :3].copy()
    gray = gray_view(4)[..., 0].copy()
    info = store.save({"raw_left": rgb, "raw_right": rgb, "rect_left": gray, "rect_right": gray}, meta())
    left, _ = store.raw_pair(info.id)
    assert np.array_equal(left, pixel.rgby(rgb))
    images = store.get(info.id).meta["images"]
    assert images["raw_left"]["color"] == "rgb" and images["rect_left"]["color"] == "gray"


def test_a_capture_replays_through_replaysource(store: CaptureStore) -> None:
    a = store.save(stream_frames(1), meta(frame=1))
    b = store.save(stream_frames(5), meta(frame=2))
    with ReplaySource(store.root, loop=False) as src:
        assert src.names == [a.id, b.id] and src.frame_size == (W, H)
        assert np.array_equal(src.read(0), pixel.pack(*store.raw_pair(a.id)))
        assert np.array_equal(src.read(1), pixel.pack(*store.raw_pair(b.id)))


def test_list_is_newest_first(store: CaptureStore) -> None:
    ids = [store.save(stream_frames(i), meta(frame=i)).id for i in range(3)]
    assert [c.id for c in store.list()] == ids[::-1]
    assert [c.frame for c in store.list()] == [2, 1, 0]


def test_frame_numbers_up_to_ten_digits_keep_valid_ids(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta(frame=4_294_967_295))
    assert "-4294967295-" in info.id and CaptureStore.valid_id(info.id)
    assert store.get(info.id).frame == 4_294_967_295


# -- concurrency and ids ----------------------------------------------------

def test_concurrent_saves_get_distinct_ids(tmp_path: Path) -> None:
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=fixed_clock())  # same second, same frame
    frames = stream_frames()
    results: List[str] = []
    errors: List[BaseException] = []

    def work() -> None:
        try:
            results.append(store.save(frames, meta(frame=7)).id)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors and len(results) == 12 and len(set(results)) == 12
    assert sorted(c.id for c in store.list()) == sorted(results)
    assert all(c.error is None for c in store.list())
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_listing_during_saves_and_deletes_never_shows_a_half_capture(tmp_path: Path) -> None:
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=fixed_clock())
    stop = threading.Event()
    seen: List[CaptureInfo] = []
    errors: List[BaseException] = []

    def lister() -> None:
        try:
            while not stop.is_set():
                seen.extend(store.list())
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    def saver(seed: int) -> None:
        try:
            for i in range(6):
                info = store.save(stream_frames(seed + i), meta(frame=seed + i))
                if i % 2:
                    store.delete(info.id)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    listers = [threading.Thread(target=lister) for _ in range(2)]
    savers = [threading.Thread(target=saver, args=(100 * k,)) for k in range(3)]
    for t in listers + savers:
        t.start()
    for t in savers:
        t.join(60)
    stop.set()
    for t in listers:
        t.join(60)
    assert not errors
    assert seen and all(c.error is None and len(c.files) == 7 for c in seen)
    assert len(store.list()) == 9


def test_an_id_collision_picks_another_suffix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    suffixes = iter(["abcd", "abcd", "abcd", "ef01"])
    monkeypatch.setattr(folder_store, "_random_suffix", lambda: next(suffixes))
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=fixed_clock())
    first = store.save(stream_frames(), meta(frame=5))
    second = store.save(stream_frames(), meta(frame=5))
    assert first.id.endswith("-abcd") and second.id.endswith("-ef01")
    assert len(store.list()) == 2


@pytest.mark.parametrize("bad", [
    "../x", "..", ".", "%2e%2e", "%2e%2e%2fetc", "/etc/passwd", "/", "", "x" * 10_000,
    "20261122T040512Z-000123-ab12/../../x", "20261122T040512Z-000123-ab12/", "a/b",
    "20261122T040512Z-000123-AB12", "20261122T040512Z-000123-ab12\n", " 20261122T040512Z-000123-ab12",
    "20261122T040512Z-123-ab12", "20261122T040512Z-12345678901-ab12", "20261122t040512z-000123-ab12",
    "２０２６１１２２T040512Z-000123-ab12", ".incoming-20261122T040512Z-000123-ab12",
    "20261122T040512Z-000123-ab12\x00", "20261122T040512Z-000123-ab1g", "..\\x",
])
def test_malformed_ids_are_refused_before_touching_the_disk(store: CaptureStore, bad: str) -> None:
    assert not CaptureStore.valid_id(bad)
    for call in (store.path, store.get, store.delete, store.raw_pair, store.zip_stream):
        with pytest.raises(InvalidCaptureId) as err:
            call(bad)
        assert status_of(err.value) == 400
        assert "capture ids look like 20261122T040512Z-000123-ab12" in err.value.message
        assert len(err.value.message) < 200 and "\n" not in err.value.message


@pytest.mark.parametrize("bad", [None, 123, b"20261122T040512Z-000123-ab12", ["x"]])
def test_non_string_ids_are_refused(store: CaptureStore, bad: object) -> None:
    assert not CaptureStore.valid_id(bad)
    with pytest.raises(InvalidCaptureId):
        store.get(bad)


def test_unknown_valid_id_is_404(store: CaptureStore) -> None:
    cid = "20261122T040512Z-000123-ab12"
    for call in (store.path, store.get, store.delete, store.raw_pair, store.zip_stream):
        with pytest.raises(CaptureNotFound, match=f"no capture {cid}") as err:
            call(cid)
        assert status_of(err.value) == 404 and err.value.to_json() == {"error": err.value.message}


def test_symlinks_never_lead_out_of_the_store(store: CaptureStore, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_text("keep me")
    real = store.save(stream_frames(), meta())
    for name in os.listdir(store.root / real.id):  # a complete-looking capture outside the store
        (outside / name).write_bytes((store.root / real.id / name).read_bytes())
    link = "20261122T000000Z-000001-dead"
    os.symlink(outside, store.root / link)
    assert [c.id for c in store.list()] == [real.id]
    for call in (store.path, store.get, store.raw_pair, store.zip_stream, store.delete):
        with pytest.raises(CaptureNotFound):
            call(link)
    assert (outside / "secret.txt").read_text() == "keep me" and (store.root / link).is_symlink()

    # a file inside a capture that is a symlink is reported, never read
    os.symlink(outside / "secret.txt", store.root / real.id / "notes.txt")
    info = store.get(real.id)
    assert info.error == "notes.txt is a symbolic link, not a file"
    assert "notes.txt" not in [f.name for f in info.files]
    with zipfile.ZipFile(io.BytesIO(b"".join(store.zip_stream(real.id)))) as zf:
        assert not [n for n in zf.namelist() if "notes" in n]


# -- listing robustness -------------------------------------------------------

def test_listing_ignores_junk(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta())
    root = store.root
    (root / "README.txt").write_text("not a capture")
    (root / "20261122T040512Z-000123-ffff").write_text("a file named like a capture")
    (root / "holiday-photos").mkdir()
    (root / ".incoming-20261122T040513Z-000124-aaaa").mkdir()  # a save in progress
    (root / ".deleting-20261122T040513Z-000125-bbbb-12345678").mkdir()
    (root / ".hidden").mkdir()
    (root / "20261122T040512Z-000123-ab12.zip").write_bytes(b"PK")
    assert [c.id for c in store.list()] == [info.id]


def test_a_damaged_capture_is_listed_with_an_error_not_dropped(store: CaptureStore) -> None:
    good = store.save(stream_frames(1), meta(frame=1))
    corrupt = store.save(stream_frames(2), meta(frame=2))
    no_meta = store.save(stream_frames(3), meta(frame=3))
    short = store.save(stream_frames(4), meta(frame=4))
    lost = store.save(stream_frames(5), meta(frame=5))
    not_object = store.save(stream_frames(6), meta(frame=6))
    (store.root / corrupt.id / "meta.json").write_bytes(b'{"id": "trunc')
    (store.root / no_meta.id / "meta.json").unlink()
    (store.root / short.id / "rect_left.png").write_bytes(b"\x89PNG")
    (store.root / lost.id / "raw_right.png").unlink()
    (store.root / not_object.id / "meta.json").write_bytes(b"[1, 2]")

    listed = {c.id: c for c in store.list()}
    assert len(listed) == 6
    assert listed[good.id].error is None
    bad = listed[corrupt.id]
    assert bad.error is not None and bad.error.startswith("meta.json is damaged (")
    assert bad.frame == 2 and bad.created == "2026-11-22T04:05:13.000Z"  # from the id
    assert bad.source is None and "raw_left.png" in [f.name for f in bad.files]
    assert listed[no_meta.id].error == "meta.json is missing"
    assert str(listed[short.id].error).startswith("rect_left.png is 4 bytes, meta.json says ")
    assert listed[lost.id].error == "raw_right.png is missing"
    assert listed[not_object.id].error == "meta.json is damaged (not a JSON object)"
    json.dumps([c.to_json() for c in listed.values()], allow_nan=False)

    # what is left of a damaged capture can still be downloaded, replayed where possible, deleted
    with zipfile.ZipFile(io.BytesIO(b"".join(store.zip_stream(corrupt.id)))) as zf:
        assert f"{corrupt.id}/raw_left.png" in zf.namelist() and zf.testzip() is None
    assert store.raw_pair(corrupt.id)[0].shape == (H, W, 4)
    with pytest.raises(CaptureDamaged, match=f"capture {lost.id} cannot be replayed: raw_right.png is missing"
                       ) as e:
        store.raw_pair(lost.id)
    assert status_of(e.value) == 422
    (store.root / good.id / "raw_left.png").write_bytes(b"\x89PNG\r\n\x1a\ngarbage")
    with pytest.raises(CaptureDamaged, match="raw_left.png is not a valid 8-bit image"):
        store.raw_pair(good.id)
    store.delete(corrupt.id)
    assert corrupt.id not in [c.id for c in store.list()]


# -- zip download -------------------------------------------------------------

def test_zip_holds_every_file_byte_for_byte(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta())
    chunks = list(store.zip_stream(info.id, chunk_size=1024))
    assert len(chunks) > 3 and all(isinstance(c, bytes) and c for c in chunks)
    with zipfile.ZipFile(io.BytesIO(b"".join(chunks))) as zf:
        assert zf.testzip() is None
        names = zf.namelist()
        assert names[:5] == [f"{info.id}/{n}" for n in ("meta.json", "raw_left.png", "raw_right.png",
                                                          "rect_left.png", "rect_right.png")]
        assert sorted(names) == sorted(f"{info.id}/{f.name}" for f in info.files)
        for zi in zf.infolist():
            name = zi.filename.split("/", 1)[1]
            assert zf.read(zi) == (store.root / info.id / name).read_bytes()
            expected = zipfile.ZIP_STORED if name.endswith(".png") else zipfile.ZIP_DEFLATED
            assert zi.compress_type == expected
            assert zi.date_time == (2026, 11, 22, 4, 5, 12)
    out = io.BytesIO()
    assert store.write_zip(info.id, out) == len(out.getvalue())
    with zipfile.ZipFile(out) as zf:
        assert zf.testzip() is None


def test_zip_survives_a_delete_while_streaming(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta())
    stream = store.zip_stream(info.id, chunk_size=512)
    first = next(stream)
    store.delete(info.id)
    data = first + b"".join(stream)
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        assert zf.testzip() is None and len(zf.namelist()) == len(info.files)


def test_an_abandoned_zip_stream_closes_its_files(store: CaptureStore) -> None:
    info = store.save(stream_frames(), meta())
    fds_before = len(os.listdir("/proc/self/fd"))
    stream = store.zip_stream(info.id)
    assert len(os.listdir("/proc/self/fd")) > fds_before
    del stream
    gc.collect()
    assert len(os.listdir("/proc/self/fd")) == fds_before
    started = store.zip_stream(info.id)
    next(started)
    started.close()  # type: ignore[attr-defined]
    gc.collect()
    assert len(os.listdir("/proc/self/fd")) == fds_before


def test_read_one_file(store: CaptureStore, tmp_path: Path) -> None:
    info = store.save(stream_frames(), meta())
    folder = store.root / info.id
    for f in info.files:
        assert store.read_file(info.id, f.name) == (folder / f.name).read_bytes()
    secret = tmp_path / "secret.txt"
    secret.write_text("keep out")
    os.symlink(secret, folder / "link.png")
    for bad in ("../meta.json", "meta.json/..", "/etc/passwd", "", "link.png", "nope.png", "RAW_LEFT.PNG",
                f"../{info.id}/meta.json", None):
        with pytest.raises(CaptureNotFound) as err:
            store.read_file(info.id, bad)
        assert status_of(err.value) == 404 and err.value.message.startswith(f"capture {info.id} has no file ")
        assert "; it has meta.json, raw_left.png, raw_right.png, rect_left.png" in err.value.message
    with pytest.raises(InvalidCaptureId):
        store.read_file("../x", "meta.json")
    with pytest.raises(CaptureNotFound, match="no capture 20261122T000000Z-000001-0000"):
        store.read_file("20261122T000000Z-000001-0000", "meta.json")


# -- delete -------------------------------------------------------------------

def test_delete_removes_the_capture(store: CaptureStore) -> None:
    keep = store.save(stream_frames(1), meta(frame=1))
    gone = store.save(stream_frames(2), meta(frame=2))
    store.delete(gone.id)
    assert [c.id for c in store.list()] == [keep.id]
    assert sorted(p.name for p in store.root.iterdir()) == [keep.id]
    with pytest.raises(CaptureNotFound):
        store.delete(gone.id)


def test_a_crash_mid_delete_never_leaves_a_half_capture_listed(
    store: CaptureStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    info = store.save(stream_frames(), meta())
    monkeypatch.setattr(folder_store, "remove_tree", lambda path: None)  # "crash" after the rename
    store.delete(info.id)
    assert store.list() == [] and any(p.name.startswith(".deleting-") for p in store.root.iterdir())
    monkeypatch.undo()
    CaptureStore(store.root, min_free_bytes=0)  # the next start-up clears it
    assert list(store.root.iterdir()) == []


def test_startup_removes_stale_temporary_folders_only(tmp_path: Path) -> None:
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=fixed_clock())
    info = store.save(stream_frames(), meta())
    stale = tmp_path / ".incoming-20261122T040512Z-000124-abcd"
    stale.mkdir()
    (stale / "raw_left.png").write_bytes(b"half")
    (tmp_path / ".deleting-20261122T040512Z-000125-abcd-0000").mkdir()
    (tmp_path / "notes.txt").write_text("mine")
    CaptureStore(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [info.id, "notes.txt"]


def test_root_must_be_a_folder(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    with pytest.raises(CaptureError, match="cannot use .*file as the capture folder"):
        CaptureStore(tmp_path / "file")
    with pytest.raises(ValueError, match="min_free_bytes"):
        CaptureStore(tmp_path / "ok", min_free_bytes=-1)


# -- bad arguments from the daemon ------------------------------------------------

@pytest.mark.parametrize("change, exc, message", [
    (lambda f, m: f.pop("rect_right"), ValueError, "missing rect_right"),
    (lambda f, m: f.update(depth=f["raw_left"]), ValueError, "unknown depth"),
    (lambda f, m: f.update(raw_left=f["raw_left"].astype(np.uint16)), TypeError, "must be uint8"),
    (lambda f, m: f.update(raw_left=np.zeros((H, W, 2), np.uint8)), ValueError, r"must be \(H, W, 4\) RGBY"),
    (lambda f, m: f.update(raw_left=np.zeros((0, W, 4), np.uint8)), ValueError, "is empty"),
    (lambda f, m: f.update(raw_right=colour_raw(1, w=W + 2)), ValueError, "must have the same size"),
    (lambda f, m: m.pop("frame"), ValueError, r"meta\['frame'\] must be the frame number"),
    (lambda f, m: m.update(frame=-1), ValueError, "frame number"),
    (lambda f, m: m.update(frame=True), ValueError, "frame number"),
    (lambda f, m: m.update(frame=10**10), ValueError, "frame number"),
    (lambda f, m: m.update(id="mine"), ValueError, "set by the store"),
    (lambda f, m: m.update(source=3), TypeError, "source"),
    (lambda f, m: m.update(extra=object()), ValueError, "not JSON-serialisable"),
    (lambda f, m: m.update(extra=float("nan")), ValueError, "not JSON-serialisable"),
])
def test_bad_frames_or_meta_raise_and_write_nothing(
    store: CaptureStore, change: Callable[..., object], exc: type, message: str
) -> None:
    frames, m = stream_frames(), meta()
    change(frames, m)
    with pytest.raises(exc, match=message):
        store.save(frames, m)
    assert list(store.root.iterdir()) == []


def test_a_naive_clock_is_refused(tmp_path: Path) -> None:
    store = CaptureStore(tmp_path, min_free_bytes=0, clock=lambda: datetime(2026, 1, 1))
    with pytest.raises(ValueError, match="aware datetime"):
        store.save(stream_frames(), meta())


# -- disk full and other write failures ------------------------------------------

def test_low_free_space_is_refused_before_writing(
    store: CaptureStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = store.save(stream_frames(1), meta(frame=1))
    store.min_free_bytes = 50_000_000
    monkeypatch.setattr(CaptureStore, "free_bytes", lambda self: 50_010_000)
    with pytest.raises(CaptureDiskFull) as err:
        store.save(stream_frames(2), meta(frame=2))
    assert status_of(err.value) == 507
    assert err.value.message.startswith(f"not enough free space for a capture in {store.root}: 50.0 MB free")
    assert "50.0 MB are kept free; delete old captures to make room" in err.value.message
    assert store.list() == [before] and sorted(p.name for p in store.root.iterdir()) == [before.id]


def failing_write(fail_on_call: int, err: int, *, partial: bool = False) -> Callable[[int, object], int]:
    """os.write failing with ``err`` from call ``fail_on_call`` on; before that it writes all it is
    given, or with ``partial`` only half (short writes, as a nearly full disk gives)."""
    calls = {"n": 0}

    def write(fd: int, data: object) -> int:
        calls["n"] += 1
        if calls["n"] >= fail_on_call:
            raise OSError(err, os.strerror(err))
        view = memoryview(data)  # type: ignore[arg-type]
        return os.write(fd, view[: max(1, len(view) // 2)] if partial else view)

    return write


# one write call per file: 7 PNGs (raw_left, raw_right, rect_left, its _y, rect_right, its _y) then meta.json
@pytest.mark.parametrize("fail_on_call, partial, step", [
    (1, False, "raw_left.png"), (2, False, "raw_right.png"), (4, False, "rect_left_y.png"),
    (7, False, "meta.json"), (2, True, "raw_left.png"), (12, True, "raw_left.png"),
])
@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EDQUOT])
def test_disk_full_midway_leaves_no_partial_files(
    store: CaptureStore, monkeypatch: pytest.MonkeyPatch,
    fail_on_call: int, partial: bool, step: str, err: int,
) -> None:
    before = store.save(stream_frames(1), meta(frame=1))
    snapshot = tree(store.root)
    monkeypatch.setattr(store_files, "_os_write", failing_write(fail_on_call, err, partial=partial))
    with pytest.raises(CaptureDiskFull) as exc:
        store.save(stream_frames(2), meta(frame=2))
    assert status_of(exc.value) == 507
    assert exc.value.message == (
        f"the capture disk is full ({os.strerror(err)}) while writing {step}: nothing was stored; "
        f"delete old captures to make room"
    )
    assert tree(store.root) == snapshot and store.list() == [before]


def test_disk_full_on_fsync_or_mkdir_leaves_nothing(
    store: CaptureStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_space(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store_files, "_os_fsync", no_space)
    with pytest.raises(CaptureDiskFull, match="while writing raw_left.png"):
        store.save(stream_frames(), meta())
    assert list(store.root.iterdir()) == []
    monkeypatch.undo()
    monkeypatch.setattr(folder_store.os, "mkdir", no_space)
    with pytest.raises(CaptureDiskFull, match="while creating the capture folder"):
        store.save(stream_frames(), meta())
    assert list(store.root.iterdir()) == []


def test_other_io_errors_are_500_and_leave_nothing(
    store: CaptureStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(store_files, "_os_write", failing_write(3, errno.EIO))
    with pytest.raises(CaptureError) as err:
        store.save(stream_frames(), meta())
    assert type(err.value) is CaptureError and status_of(err.value) == 500
    assert "failed (Input/output error); nothing was stored" in err.value.message
    assert list(store.root.iterdir()) == []


def test_an_exception_mid_save_leaves_nothing(store: CaptureStore, monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(fd: int, data: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(store_files, "_os_write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        store.save(stream_frames(), meta())
    assert list(store.root.iterdir()) == []


@pytest.fixture
def tiny_fs(tmp_path: Path) -> Iterator[Path]:
    """A real 1 MiB tmpfs. Needs root and mount rights, which the project's machines and CI have;
    elsewhere this fails (never skips) so a missing capability is noticed."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    try:
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                              capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.fail(f"cannot mount a tmpfs here: {exc}")
    if done.returncode != 0:
        pytest.fail(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True, timeout=20)


def noise_frames(seed: int, w: int, h: int) -> Dict[str, np.ndarray]:
    """Incompressible frames: PNG cannot shrink them."""
    return {name: colour_rect(seed + i, w, h) for i, name in enumerate(captures.FRAME_NAMES)}


def test_a_really_full_disk(tiny_fs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = CaptureStore(tiny_fs / "captures", min_free_bytes=0, clock=stepping_clock())
    small = store.save(stream_frames(), meta())
    snapshot = tree(store.root)
    big = noise_frames(1, 160, 120)  # 4 x (57.6 kB RGB + 19.2 kB Y): about 310 kB

    # first: more than fits, refused by the free-space check before writing
    huge = noise_frames(2, 320, 240)  # about 1.2 MB
    with pytest.raises(CaptureDiskFull, match="not enough free space"):
        store.save(huge, meta())
    assert tree(store.root) == snapshot

    # then: the check is fooled, the filesystem itself runs out (ENOSPC) halfway
    monkeypatch.setattr(CaptureStore, "free_bytes", lambda self: 1 << 40)
    with pytest.raises(CaptureDiskFull, match="the capture disk is full"):
        store.save(huge, meta())
    assert tree(store.root) == snapshot and store.list() == [small]
    monkeypatch.undo()

    # and the room it freed is usable: a capture that fits still works
    ok = store.save(big, meta())
    assert [c.id for c in store.list()] == [ok.id, small.id]
