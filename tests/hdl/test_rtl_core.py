"""``stereocam.overlays.rtl.core.RtlCore``: the core's RTL compiled by Verilator, against the emulated core.

The driver (``stereocam/drivers/rectify.py: RectifyCore``) programs both the RTL (``RtlCore``) and
the emulated core (``EmulatedRectifyCore``, the oracle) with the same calibration; the
same frames then go through both and every output byte, FLAGS, FRAME_COUNT and STATUS
must agree. Small builds (96x64, 16 buffered rows, colour and gray) keep each test to
seconds once its program is built (~17 s, cached in ``~/.cache/stereocam/hdl/harness/``); one test runs
752x480 frames through the real colour build. The small-build tests run with random TVALID
gaps and TREADY backpressure from seed 1 (``STEREOCAM_RTL_SEED`` chooses another).
"""
from __future__ import annotations

import contextlib
import gc
import os
from pathlib import Path
from typing import Iterator, List, Optional, Sequence, Tuple

import numpy as np
import pytest

from stereocam.bench import rectify as bench
from stereocam.calibration.stereo import StereoModel, camera_params, rectify
from stereocam.drivers.rectify import ConfigRefused, RectifyCore
from stereocam.overlays.emulated.rectify import EmulatedRectifyCore
from stereocam.overlays.model.linebuffer import rows_needed
from stereocam.overlays.rtl import toolchain as hdl
from stereocam.overlays.rtl.core import RtlBuildError, RtlCore, RtlError, build_harness, rtl_sources
from stereocam.overlays.spec.rectify import (
    BUILDS,
    CORE_ID,
    CORE_VERSION,
    RECTIFY_MAP,
    Build,
    CameraParams,
    CoreConfig,
    camera_registers,
    param_offset,
)

from ..overlays.test_model import camera_frame, random_frame, random_params

SMALL = {"colour": Build("small-colour", 96, 64, 16, colour=True),
         "gray": Build("small-gray", 96, 64, 16, colour=False)}
W, H = 96, 64
REG = {name: RECTIFY_MAP[name].offset for name in ("CONTROL", "STATUS", "FLAGS", "FRAME_COUNT", "WIDTH",
                                                   "HEIGHT", "LB_DELAY", "DEBUG_ROW")}
ENABLE, BYPASS, GRAY, DEBUG_LINE, APPLY = 1, 2, 4, 8, 16
LB_OVERFLOW, SIZE_ERROR, CONFIG_ERROR = 1, 2, 4
WATCHED = ("FLAGS", "FRAME_COUNT", "STATUS", "CONTROL")


def emulator(build: Build) -> EmulatedRectifyCore:
    return EmulatedRectifyCore(max_width=build.max_width, max_height=build.max_height,
                               lb_rows=build.lb_rows, colour=build.colour)


class Pair:
    """The RTL and the emulated core side by side, each with its own driver; every step goes to both."""

    def __init__(self, rtl: RtlCore, build: Build) -> None:
        self.rtl = rtl
        self.emu = emulator(build)
        self.drivers = (RectifyCore(rtl), RectifyCore(self.emu))

    def write(self, offset: int, value: int) -> None:
        self.rtl.write(offset, value)
        self.emu.write(offset, value)

    def registers(self) -> Tuple[dict, dict]:
        return ({n: self.rtl.read(REG[n]) for n in WATCHED}, {n: self.emu.read(REG[n]) for n in WATCHED})

    def same_registers(self, label: str) -> None:
        got, want = self.registers()
        assert got == want, f"{label}: registers {got}, emulated core {want} (seed {self.rtl.seed})"

    def frame(self, frame: np.ndarray, label: str) -> Optional[np.ndarray]:
        """One frame through both: outputs equal byte for byte, then the registers."""
        got = self.rtl.process(frame)
        want = self.emu.process(frame)
        same_frame(got, want, f"{label} (seed {self.rtl.seed}, {self.rtl.last.clocks} clocks)")
        self.same_registers(label)
        return got


def same_frame(got: Optional[np.ndarray], want: Optional[np.ndarray], label: str) -> None:
    if want is None or got is None:
        shapes = [None if f is None else f.shape for f in (got, want)]
        assert got is None and want is None, f"{label}: RTL output {shapes[0]}, emulated {shapes[1]}"
        return
    assert got.shape == want.shape, f"{label}: output {got.shape}, emulated {want.shape}"
    bad = np.argwhere(got != want)
    assert bad.size == 0, (f"{label}: {len(bad)} bytes differ, first at (y, x, byte) {tuple(bad[0])}: "
                           f"RTL {got[tuple(bad[0])]}, emulated {want[tuple(bad[0])]}")


@pytest.fixture
def core(request: pytest.FixtureRequest) -> Iterator[RtlCore]:
    """An RtlCore of the small build the test names (indirect parameter, default colour), with gaps."""
    name = getattr(request, "param", "colour")
    with RtlCore(SMALL[name], seed=int(os.environ.get("STEREOCAM_RTL_SEED", "1")), gaps=True) as rtl:
        yield rtl


def roll(deg: float, w: int, h: int) -> Tuple[float, ...]:
    """A rotation about the image centre: its rows span more input rows than 16 (LB_OVERFLOW)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    cx, cy = (w - 1) / 2, (h - 1) / 2
    m = (np.array([[1, 0, cx], [0, 1, cy], [0, 0, 1]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
         @ np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1]]))
    return tuple(float(v) for v in m.ravel())


# ---- mechanics ------------------------------------------------------------------------------------
def test_registers_reset_and_the_build_cache(core: RtlCore) -> None:
    """Identity and build registers over AXI4-Lite, as the driver reads them; reset; the cached program."""
    build = SMALL["colour"]
    again = build_harness(build)
    assert not again.built and again.executable == core.harness.executable, "the cached program"
    assert again.directory.parent == hdl.build_root() / "harness"
    emu = emulator(build)
    for name in ("ID", "VERSION", "MAX_WIDTH", "MAX_HEIGHT", "LB_ROWS", "CAPS", "CONTROL", "STATUS", "FLAGS",
                 "FRAME_COUNT", "WIDTH", "HEIGHT", "LB_DELAY", "DEBUG_ROW"):
        offset = RECTIFY_MAP[name].offset
        assert core.read(offset) == emu.read(offset), name
    assert core.read(0) == CORE_ID and core.read(4) == CORE_VERSION
    driver = RectifyCore(core)  # checks ID and VERSION, reads the build back
    assert (driver.max_width, driver.max_height, driver.lb_rows, driver.colour) == (96, 64, 16, True)
    # shadow registers read back what was written, a parameter's two words included; reset clears them
    fx = param_offset("L", "FX")
    core.write(REG["WIDTH"], 48)
    core.write(fx, 0x89ABCDEF)
    core.write(fx + 4, 0x12)
    assert (core.read(REG["WIDTH"]), core.read(fx), core.read(fx + 4)) == (48, 0x89ABCDEF, 0x12)
    core.reset()
    assert (core.read(REG["WIDTH"]), core.read(fx)) == (752, 0)
    assert core.clock(100) == [] and core.last.clocks_total == 100
    with pytest.raises(ValueError):
        core.write(0x1000, 0)
    with pytest.raises(ValueError):
        core.process(np.zeros((4, 4, 3), np.uint8))


def test_before_apply_and_bypass_pass_frames_through(core: RtlCore) -> None:
    """Before the first APPLY the reset size (752x480) holds: a 96x64 frame is dropped with SIZE_ERROR.
    With BYPASS the output is the input, beat for beat, at 2 clocks per beat."""
    pair = Pair(core, SMALL["colour"])
    rng = np.random.default_rng(5)
    pair.write(REG["CONTROL"], ENABLE)
    assert pair.frame(random_frame(rng, W, H), "before APPLY") is None
    assert core.read(REG["FLAGS"]) == SIZE_ERROR
    pair.write(REG["FLAGS"], 7)
    for name, value in (("WIDTH", W), ("HEIGHT", H)):
        pair.write(REG[name], value)
    pair.write(REG["CONTROL"], ENABLE | APPLY)  # every parameter still 0 (FX below 1 px): refused
    pair.same_registers("refused")
    assert core.read(REG["FLAGS"]) == CONFIG_ERROR
    pair.write(REG["FLAGS"], 7)
    params = random_params(rng, W, H)
    for driver in pair.drivers:
        driver.load(CoreConfig(camera_registers(params, W, H), camera_registers(params, W, H), W, H, 2))
    pair.write(REG["CONTROL"], ENABLE | BYPASS)
    for i in range(2):
        f = random_frame(rng, W, H)
        out = pair.frame(f, f"bypass {i}")
        assert out is not None and np.array_equal(out, f)
    with RtlCore(SMALL["colour"], gaps=False) as plain:  # no gaps: 2 clocks per beat plus the pipeline
        RectifyCore(plain).load(pair.drivers[0].read_config())
        plain.write(REG["CONTROL"], ENABLE | BYPASS)
        assert np.array_equal(plain.process(f), f)
        assert 2 * W * H < plain.clocks < 2 * W * H + 200, plain.clocks
        assert plain.last.out_waits == 0 and plain.last.in_waits > 0  # the input is faster than the core
    assert core.last.out_waits > W * H // 2, core.last  # with gaps: output backpressure
    assert core.clocks > 1.1 * plain.clocks, "gaps and backpressure slow the frame down"


def test_build_errors_name_their_cause(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A broken source: the error ends with Verilator's complaint. No tools: which package to install."""
    broken = tmp_path / "rc_broken.v"
    broken.write_text("module rc_broken(input wire a;\nendmodule\n")
    with pytest.raises(RtlBuildError, match=r"(?s)verilator exited with \d+.*rc_broken\.v"):
        build_harness(SMALL["colour"], sources=[*rtl_sources(), broken], root=tmp_path / "cache")
    empty = tmp_path / "bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    with pytest.raises(hdl.ToolMissing, match="apt-get install perl make g"):
        build_harness(SMALL["colour"], root=tmp_path / "cache")


def test_a_harness_that_died_is_reported(core: RtlCore) -> None:
    core._proc.kill()
    core._proc.wait()
    with pytest.raises(RtlError, match="not running.*exit code -9"):
        core.read(0)


def test_a_dropped_core_stops_its_harness() -> None:
    """Without close(): collecting the object kills and reaps the program, closing its pipes quietly."""
    rtl = RtlCore(SMALL["colour"])
    proc = rtl._proc
    del rtl
    gc.collect()
    assert proc.returncode is not None and proc.stdin is not None and proc.stdin.closed


# ---- against the emulated core ----------------------------------------------------------------------
def sample_rig(w: int, h: int) -> Tuple[CameraParams, CameraParams]:
    """OpenCV's stereo sample (tests/data/opencv-stereo-calib, calibrated once), scaled to ``w x h``."""
    from ..sample import calibrate_sample

    m = calibrate_sample().model
    s = np.diag([w / m.image_size[0], h / m.image_size[1], 1.0])
    model = StereoModel(s @ m.K1, m.D1, s @ m.K2, m.D2, m.R, m.T, (w, h))
    rect = rectify(model, alpha=0.0)
    return (camera_params(model.K1, model.D1, rect.R1, rect.P1),
            camera_params(model.K2, model.D2, rect.R2, rect.P2))


def calibrations(w: int, h: int) -> List[Tuple[str, CameraParams, CameraParams]]:
    """Two random camera pairs (tests/overlays/test_model.py; milder than its default, to fit 16
    rows at 96x64) and OpenCV's sample rig."""
    rng = np.random.default_rng(11)
    out = [(f"random{i}", random_params(rng, w, h, strength=0.5), random_params(rng, w, h, strength=0.5))
           for i in range(2)]
    return out + [("opencv-sample", *sample_rig(w, h))]


@pytest.mark.parametrize("core", ["colour", "gray"], indirect=True)
def test_calibrations_match_the_emulated_core(core: RtlCore) -> None:
    """Real calibrations programmed by the driver; colour and GRAY, DEBUG_LINE; every byte and flag."""
    build = core.build
    pair = Pair(core, build)
    rng = np.random.default_rng(7)
    for name, left, right in calibrations(W, H):
        for driver in pair.drivers:
            _, fit = driver.program(left, right, W, H)
            driver.set_mode(enable=True, gray=False, debug_line=False)
        assert fit.rows <= build.lb_rows
        pair.frame(camera_frame(rng, W, H), f"{name} colour")
        pair.frame(random_frame(rng, W, H), f"{name} colour, gray bytes not of R, G, B")
        row = int(rng.integers(0, H))
        for driver in pair.drivers:
            driver.set_mode(gray=True, debug_line=True, debug_row=row)
        pair.frame(camera_frame(rng, W, H), f"{name} GRAY, DEBUG_LINE")
    assert core.read(REG["FLAGS"]) == 0 and core.read(REG["FRAME_COUNT"]) == 9


def test_line_buffer_overflow_matches(core: RtlCore) -> None:
    """A roll the 16-row line buffer cannot hold (loaded past the driver's check): LB_OVERFLOW, same bytes."""
    pair = Pair(core, SMALL["colour"])
    left = CameraParams(roll(25.0, W, H), float(W), float(W), (W - 1) / 2, (H - 1) / 2, 0.0, 0.0, 0.0, 0.0)
    right = CameraParams(roll(-18.0, W, H), float(W), float(W), (W - 1) / 2, (H - 1) / 2, -0.3, 0.0, 0.0, 0.0)
    config = CoreConfig(camera_registers(left, W, H), camera_registers(right, W, H), W, H, 0)
    for driver in pair.drivers:
        driver.load(config)
        driver.enable()
    pair.frame(camera_frame(np.random.default_rng(3), W, H), "roll")
    assert core.read(REG["FLAGS"]) == LB_OVERFLOW


def test_refused_sets_and_enable(core: RtlCore) -> None:
    """CONFIG_ERROR keeps the old set (the driver raises on both); ENABLE 0 emits nothing."""
    pair = Pair(core, SMALL["colour"])
    rng = np.random.default_rng(9)
    good = random_params(rng, W, H)
    for driver in pair.drivers:
        driver.program(good, good, W, H)
        driver.enable()
    pair.frame(camera_frame(rng, W, H), "good")
    bad = [(param_offset("L", "FX"), 0), (param_offset("R", "N00") + 4, 1 << 12),
           (param_offset("L", "K1") + 4, 0x80000000), (REG["WIDTH"], 0), (REG["HEIGHT"], H + 1),
           (REG["LB_DELAY"], H)]
    config = pair.drivers[1].read_config()
    for offset, value in bad:
        pair.write(offset, value)
        pair.write(REG["CONTROL"], ENABLE | APPLY)
        pair.same_registers(f"refused write {value:#x} at {offset:#x}")
        assert core.read(REG["FLAGS"]) == CONFIG_ERROR
        pair.frame(camera_frame(rng, W, H), f"after the refused write at {offset:#x}: the old set")
        for driver in pair.drivers:
            with pytest.raises(ConfigRefused):
                driver.check_applied()
            driver.load(config)
    pair.write(REG["CONTROL"], 0)
    assert pair.frame(camera_frame(rng, W, H), "disabled") is None and core.last.end == "disabled"
    assert core.read(REG["FRAME_COUNT"]) == 1 + len(bad)


@pytest.mark.parametrize("bits", [0, BYPASS], ids=["rectify", "bypass"])
def test_malformed_frames_match(core: RtlCore, bits: int) -> None:
    """Frames of the wrong size: lines short and long (dropped), too few lines (dropped, or completed with
    zero rows once the next frame's TUSER ends them), too many lines (a normal frame)."""
    pair = Pair(core, SMALL["colour"])
    rng = np.random.default_rng(13)
    delay = 4
    params = random_params(rng, W, H)
    config = CoreConfig(camera_registers(params, W, H), camera_registers(params, W, H), W, H, delay)
    for driver in pair.drivers:
        driver.load(config)
    pair.write(REG["CONTROL"], ENABLE | bits)
    sizes: Sequence[Tuple[int, int]] = [
        (H, W - 5), (H, W + 3), (H, W), (1, W), (H, W), (delay, W), (H, W),
        (delay + 1, W), (H, W), (H // 2, W), (H - 1, W), (H, W), (H + 3, W), (H, W)]
    got: List[np.ndarray] = []
    want: List[np.ndarray] = []
    for h, w in sizes:
        frame = camera_frame(rng, w, h)
        core.process(frame)
        got += core.last.emitted
        out = pair.emu.process(frame)
        want += [] if out is None else [out]
        if h < H and w == W:  # too few lines: only the next TUSER ends the frame
            assert core.last.end == "waiting"
            # the rows whose input rows all came are out already (none: the frame will be dropped)
            assert core.pending_rows == max(0, h - (0 if bits else delay))
        else:
            assert core.last.end == "idle"
            assert len(got) == len(want), f"after a {h}x{w} frame: {len(got)} frames, emulated {len(want)}"
            pair.same_registers(f"after a {h}x{w} frame")
    for i, (g, e) in enumerate(zip(got, want, strict=True)):
        same_frame(g, e, f"output frame {i}")
    assert core.read(REG["FLAGS"]) & SIZE_ERROR


def test_where_the_hardware_differs_from_the_emulator(core: RtlCore) -> None:
    """The differences the class docstring lists, as the hardware must have them."""
    pair = Pair(core, SMALL["colour"])
    rng = np.random.default_rng(21)
    params = random_params(rng, W, H, strength=0.5)
    for driver in pair.drivers:
        driver.program(params, params, W, H)
        driver.enable()
    # A frame with too few lines ends at the next TUSER: until then no SIZE_ERROR, BUSY, not counted.
    short = camera_frame(rng, W, H - 24)
    assert core.process(short) is None and core.last.end == "waiting" and core.pending_rows > 0
    assert pair.emu.process(short) is not None
    got, want = pair.registers()
    assert (got["FLAGS"], got["STATUS"], got["FRAME_COUNT"]) == (0, 1, 0)
    assert (want["FLAGS"], want["STATUS"], want["FRAME_COUNT"]) == (SIZE_ERROR, 0, 1)
    pair.frame(camera_frame(rng, W, H), "the frame after")  # then they agree again
    assert len(core.last.emitted) == 2 and core.pending_rows == 0
    # No beats, no frame: neither core emits or flags anything for a 0-line frame.
    pair.write(REG["FLAGS"], 7)
    empty = np.zeros((0, W, 8), np.uint8)
    assert core.process(empty) is None and pair.emu.process(empty) is None
    assert core.read(REG["FLAGS"]) == 0 and pair.emu.read(REG["FLAGS"]) == 0
    # Read-only registers and holes in the map: ignored (holes read 0), where the emulator raises.
    core.write(0x000, 0)
    core.write(0x040, 5)
    assert core.read(0x000) == CORE_ID and core.read(0x040) == 0


# ---- the real colour build --------------------------------------------------------------------------
@pytest.mark.timeout(600)  # the build, when not cached (~20 s with two cores)
def test_full_size_frames_colour_build() -> None:
    """752x480 through the real colour build: passed through before the first APPLY, then a rendered
    frame rectified with the synthetic rig's calibration (LB_DELAY and rows as the driver plans them,
    as the bench does); about 2 clocks per beat."""
    build = BUILDS["colour"]
    w, h = 752, 480
    rng = np.random.default_rng(17)
    with RtlCore(build, seed=2, gaps=False) as rtl:
        pair = Pair(rtl, build)
        pair.write(REG["CONTROL"], ENABLE)
        frame = camera_frame(rng, w, h)
        out = pair.frame(frame, "before APPLY")
        assert out is not None and np.array_equal(out, frame)
        _, _, left, right = bench.bench_calibration()  # the synthetic rig's (OpenCV's sample needs 102 rows)
        for driver in pair.drivers:
            _, fit = driver.program(left, right, w, h)
        assert 0 < fit.delay and fit.rows <= build.lb_rows
        pair.frame(bench.bench_frames(1)[0], "synthetic rig 752x480")
        assert rtl.read(REG["FLAGS"]) == 0
        assert 2 * w * h < rtl.clocks < 2.2 * w * h, rtl.clocks


@pytest.mark.parametrize("core", ["colour", "gray"], indirect=True)
def test_random_sequences_match(core: RtlCore) -> None:
    """Seeded random sequences: new calibrations and frame sizes (some refused), control bits, DEBUG_ROW,
    flag clears and frames (some of the wrong size, some of random bytes), on both cores; outputs and
    registers compared whenever the RTL is idle. Registers are not touched while the RTL waits for the
    rest of a frame with too few lines (there the emulator has already ended it)."""
    frames_compared, flags_seen = 0, 0
    for seed in range(12):
        core.reset()
        rng = np.random.default_rng(100 + seed)
        pair = Pair(core, core.build)
        got: List[np.ndarray] = []
        want: List[np.ndarray] = []
        w, h = W, H
        for step in range(20):
            op = 9 if core.last.end == "waiting" else int(rng.integers(0, 10))
            label = f"sequence {seed}, step {step}"
            if op < 2:
                w, h = int(rng.integers(8, W + 1)), int(rng.integers(4, H + 1))
                strength = float(rng.uniform(0.2, 1.5))
                regs = [camera_registers(random_params(rng, w, h, strength=strength), w, h) for _ in range(2)]
                r = rng.random()  # LB_DELAY: planned, random, or at least MAX_HEIGHT (refused)
                delay = (min(rows_needed(regs, w, h).delay, H - 1) if r < 0.7
                         else int(rng.integers(0, H)) if r < 0.85 else int(rng.integers(H, H + 4)))
                for driver in pair.drivers:
                    with contextlib.suppress(ConfigRefused):
                        driver.load(CoreConfig(regs[0], regs[1], w, h, delay))
            elif op < 4:
                pair.write(REG["DEBUG_ROW"], int(rng.integers(0, H + 4)))
                pair.write(REG["CONTROL"], int(rng.integers(0, 16)) | int(rng.random() < 0.9))
            elif op < 5:
                flags_seen |= core.read(REG["FLAGS"])
                pair.write(REG["FLAGS"], 7)
            else:
                fh, fw, r = h, w, rng.random()
                if r < 0.15:
                    fh = int(rng.integers(1, h + 5))
                elif r < 0.25:
                    fw = int(rng.integers(1, W + 4))
                frame = camera_frame(rng, fw, fh) if rng.random() < 0.5 else random_frame(rng, fw, fh)
                core.process(frame)
                got += core.last.emitted
                out = pair.emu.process(frame)
                want += [] if out is None else [out]
                if core.last.end != "waiting":
                    assert len(got) == len(want), f"{label}: {len(got)} frames out, emulated {len(want)}"
                    for i in range(len(got)):
                        same_frame(got[i], want[i], f"{label}, frame {i}")
                    pair.same_registers(label)
        frames_compared += len(got)
        flags_seen |= core.read(REG["FLAGS"])
    print(f"{frames_compared} frames compared, FLAGS seen {flags_seen:#x}")
    assert frames_compared >= 30 and flags_seen == LB_OVERFLOW | SIZE_ERROR | CONFIG_ERROR
