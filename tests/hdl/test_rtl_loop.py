"""The closed loop on the core's RTL: ``stereocam rectify --core rtl`` and ``serve --core rtl``.

The RTL runs compiled by Verilator (``stereocam.overlays.rtl.core.RtlCore``) behind the same drivers,
emulated VDMAs and mux as the model. Its output must equal the model's byte for byte, and
Verify must see a fault planted in a copy of the RTL.
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import List, Tuple

import cv2
import numpy as np
import pytest

from stereocam.calibration.stereo import StereoModel, core_cameras, rectify
from stereocam.cli import main
from stereocam.overlays.emulated.overlay import EmulatedOverlay
from stereocam.overlays.rtl.core import RtlCore, rtl_sources
from stereocam.overlays.spec import pixel
from stereocam.overlays.spec.rectify import DEFAULT_BUILD
from stereocam.server.frames.views import VIEWS
from stereocam.server.http.app import RTL_TIMEOUT_S, ServeError, open_configured_overlay
from stereocam.server.http.settings import Settings

from ..sample import SampleCalibration, calibrate_sample, pair_paths, write_opencv_files
from ..server.daemon import SMALL, TEST_FPS, StillSource, read_parts, start_daemon_fixture, wait_for_frames  # noqa: F401
from ..server.test_server_api import decode_png, encode, model_output, pair_form, pattern_pair

# A first run builds the RTL (and the faulty copy) with Verilator: a minute each on a busy machine.
pytestmark = pytest.mark.timeout(900)

SAMPLE_PAIRS = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
WAIT_S = 300.0  # a condition the simulated core must reach; generous for a busy machine


def rectify_both(tmp_path: Path, cal: str, left: Path, right: Path) -> Tuple[Path, Path]:
    """``stereocam rectify`` with the model and with the RTL: the two output folders."""
    outs = tmp_path / "model", tmp_path / "rtl"
    for core, out in zip(("model", "rtl"), outs, strict=True):
        args = ["rectify", "--core", core, "--calibration", cal, "-o", str(out), str(left), str(right)]
        assert main(args) == 0
    return outs


def assert_same_files(a: Path, b: Path) -> None:
    for name in ("left.png", "right.png"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs between model and RTL"


def test_rectify_core_rtl_equals_the_model_on_the_opencv_sample_pairs(tmp_path, capsys) -> None:
    intr, extr = write_opencv_files(calibrate_sample(), tmp_path)
    for i in SAMPLE_PAIRS:
        model, rtl = rectify_both(tmp_path / f"pair{i}", f"{intr},{extr}", *pair_paths(i))
        assert_same_files(model, rtl)
        assert cv2.imread(str(rtl / "left.png"), cv2.IMREAD_UNCHANGED).any()
    out = capsys.readouterr().out
    assert out.count("the RTL under Verilator") == len(SAMPLE_PAIRS)


def random_rig(rng: np.random.Generator, size: Tuple[int, int]) -> SampleCalibration:
    """A plausible stereo rig: focal length, principal point, distortion, rotation and baseline at random."""
    w, h = size

    def camera() -> Tuple[np.ndarray, np.ndarray]:
        f = rng.uniform(0.7, 1.3) * w
        K = np.array([[f, 0, w / 2 + rng.uniform(-15, 15)],
                      [0, f * rng.uniform(0.98, 1.02), h / 2 + rng.uniform(-15, 15)],
                      [0, 0, 1]])
        return K, rng.normal(0, [0.1, 0.03, 0.001, 0.001])

    (K1, D1), (K2, D2) = camera(), camera()
    R, _ = cv2.Rodrigues(rng.normal(0, 0.005, 3))
    T = np.array([-rng.uniform(0.05, 0.15), rng.normal(0, 0.002), rng.normal(0, 0.002)])
    model = StereoModel(K1, D1, K2, D2, R, T, size)
    rect = rectify(model, alpha=float(rng.uniform(0, 1)))
    left, right = core_cameras(model, rect)
    return SampleCalibration(model, rect, left, right, 0.0)


def test_rectify_core_rtl_equals_the_model_with_random_calibrations(tmp_path, capsys) -> None:
    """Colour pairs at 752x480 through random rigs; a rig needing more rows than the core has is
    refused by both."""
    rng = np.random.default_rng(20261122)
    compared = refused = 0
    while compared < 4:
        case = tmp_path / f"case{compared + refused}"
        case.mkdir()
        intr, extr = write_opencv_files(random_rig(rng, (752, 480)), case)
        paths: List[Path] = []
        for side in ("left", "right"):
            coarse = rng.integers(0, 256, (60, 94, 3), dtype=np.uint8)
            paths.append(case / f"{side}.png")
            cv2.imwrite(str(paths[-1]), cv2.resize(coarse, (752, 480), interpolation=cv2.INTER_CUBIC))
        argv = ["--calibration", f"{intr},{extr}", *map(str, paths)]
        codes = [main(["rectify", "--core", core, "-o", str(case / core), *argv])
                 for core in ("model", "rtl")]
        if codes == [2, 2]:  # needs more line-buffer rows: both say so
            refused += 1
            assert capsys.readouterr().err.count("line-buffer rows but the core buffers 80") == 2
            assert refused < 8, "most random rigs should fit the core"
            continue
        assert codes == [0, 0]
        assert_same_files(case / "model", case / "rtl")
        assert cv2.imread(str(case / "rtl" / "left.png"), cv2.IMREAD_UNCHANGED).shape == (480, 752, 3)
        compared += 1


def rtl_overlay(sources: "List[Path] | None" = None) -> EmulatedOverlay:
    """The emulated fabric on a still frame of the rig with the RTL as its rectify core."""
    core = RtlCore(DEFAULT_BUILD, sources=sources)
    return EmulatedOverlay(source=StillSource(SMALL), fps=TEST_FPS, core=core, core_kind="rtl",
                           timeout=RTL_TIMEOUT_S)


async def fresh_parts(d, view: str) -> List[int]:
    """Frame numbers of three parts of ``/stream/<view>``."""
    async with d.http.get(f"/stream/{view}") as resp:
        assert resp.status == 200, await resp.text()
        parts = await read_parts(resp, 3, timeout=WAIT_S)
    return [int(headers["x-frame-number"]) for headers, _ in parts]


async def test_serve_core_rtl_shows_every_view_live_and_verify_finds_it_identical(start_daemon) -> None:
    d = await start_daemon(overlay=rtl_overlay())
    async with d.http.get("/api/status") as resp:
        status = await resp.json()
    assert status["core_impl"] == "rtl" and status["core"]["colour"] is True
    await wait_for_frames(d, 2, timeout=WAIT_S)
    for view in VIEWS:
        numbers = await fresh_parts(d, view)
        assert numbers == sorted(numbers) and numbers[-1] > numbers[0], (view, numbers)
    # Live: the rectified views are the model's output for the camera frame, bit for bit.
    raw = StillSource(SMALL).frame
    expected = model_output(d, raw)
    for side, channels in (("left", [2, 1, 0]), ("right", [6, 5, 4])):
        async with d.http.get(f"/snapshot/rect_{side}.png") as resp:
            np.testing.assert_array_equal(decode_png(await resp.read()), expected[..., channels])
    # Virtual camera and Verify.
    left, right = pattern_pair(4)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200, await resp.text()
    async with d.http.post("/api/verify") as resp:
        report = await resp.json()
    assert resp.status == 200, report
    assert report["identical"] is True and report["differing"] == 0
    assert report["regions"] == {"left": None, "right": None} and report["examples"] == []


FAULT_SITE = ".du(frac_interp[FB-1:0]),"
FAULT = ".du(frac_interp[FB-1:0] ^ (g == 0 ? 5'd4 : 5'd0)),"  # bit 2 of the R channel's horizontal weight


def faulty_rtl(folder: Path) -> List[Path]:
    """A copy of the core's RTL with one bit of one interpolation weight inverted (the R channel's)."""
    folder.mkdir()
    for src in rtl_sources():
        shutil.copy(src, folder / src.name)
    datapath = folder / "rc_datapath.v"
    text = datapath.read_text()
    assert text.count(FAULT_SITE) == 1, "the fault site moved: update FAULT_SITE"
    datapath.write_text(text.replace(FAULT_SITE, FAULT))
    return sorted(folder.iterdir())


async def test_verify_reports_a_fault_planted_in_the_rtl(start_daemon, tmp_path) -> None:
    d = await start_daemon(overlay=rtl_overlay(faulty_rtl(tmp_path / "rtl")))
    left, right = pattern_pair(5)
    async with d.http.post("/api/virtual-camera", data=pair_form(encode(left), encode(right))) as resp:
        assert resp.status == 200, await resp.text()
    async with d.http.post("/api/verify") as resp:
        report = await resp.json()
    assert report["identical"] is False
    differing = {name for name, c in report["channels"].items() if c["differing"]}
    assert differing == {"L_R", "R_R"}, report["channels"]  # the R channel of both cameras, nothing else
    assert report["channels"]["L_R"]["max_diff"] >= 1 and report["cameras"]["left"]["differing"] > 0
    # The pixels: what the fabric returned against the model, and the difference image marks exactly those.
    expected = model_output(d, pixel.pack(pixel.rgby(left), pixel.rgby(right)))
    actual = np.zeros_like(expected)
    for side, channels in (("left", [2, 1, 0]), ("right", [6, 5, 4])):
        async with d.http.get(f"/api/virtual-camera/result/{side}.png") as resp:
            actual[..., channels] = decode_png(await resp.read())
    wrong = expected[..., [0, 4]] != actual[..., [0, 4]]
    assert wrong.any() and report["channels"]["L_R"]["differing"] == int(wrong[..., 0].sum())
    async with d.http.get("/api/verify/difference.png") as resp:
        diff = decode_png(await resp.read())
    marked = diff.any(axis=2)
    h, w = expected.shape[:2]
    np.testing.assert_array_equal(marked[:, :w], wrong[..., 0])
    np.testing.assert_array_equal(marked[:, w:], wrong[..., 1])
    ys, xs = np.nonzero(wrong[..., 0])
    assert report["regions"]["left"] == {"x0": int(xs.min()), "y0": int(ys.min()),
                                         "x1": int(xs.max()), "y1": int(ys.max())}
    first = report["first_difference"]
    assert wrong[first["y"], first["x"]].any() and first["expected"][0] != first["actual"][0]


def test_serve_core_rtl_opens_the_rtl_behind_the_emulated_fabric(tmp_path) -> None:
    overlay = open_configured_overlay(Settings(core="rtl", backend="auto", captures=str(tmp_path / "c")))
    try:
        assert overlay.core_kind == "rtl" and isinstance(overlay.emulation.core, RtlCore)
        assert "RTL" in overlay.choice.reason and overlay.fabric.rectify.colour is True
    finally:
        overlay.close()
    assert overlay.emulation.core._proc.poll() is not None  # the harness process ended with the overlay


def test_serve_core_rtl_refuses_what_cannot_work(tmp_path, capsys) -> None:
    with pytest.raises(ServeError, match="--core rtl .*emulated fabric.*--backend emulated"):
        open_configured_overlay(Settings(core="rtl", backend="pynq"))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ServeError, match="no rectify_core.v there"):
        open_configured_overlay(Settings(core="rtl", rtl_dir=str(empty)))
    broken = tmp_path / "broken"
    broken.mkdir()
    for src in rtl_sources():
        shutil.copy(src, broken / src.name)
    (broken / "rc_interp.v").write_text("module rc_interp(\n")  # a syntax error
    with pytest.raises(ServeError, match="(?s)did not build.*rc_interp.v:1"):
        open_configured_overlay(Settings(core="rtl", rtl_dir=str(broken)))
    assert main(["serve", "--core", "rtl", "--backend", "pynq", "--port", "0",
                 "--captures", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereocam serve: error: --core rtl") and "Traceback" not in err
