"""Emulated MT9V034 sensors on the emulated I2C bus, acting on the synthetic rig's images.

Driven the way the daemon drives them: the board profile, ``StereoSensors``
over the pair's emulated bus, the fabric ticking the sensors every frame.
"""
from __future__ import annotations

import logging
from typing import Any, Iterator, Tuple

import numpy as np
import pytest

from stereocam.board.profile import BoardProfile, load_profile, profile_from_dict
from stereocam.drivers.i2c import I2CNack
from stereocam.drivers.mt9v034 import SensorError, SensorRangeError, SensorUnavailable, StereoSensors
from stereocam.overlays.emulated.i2c import EmulatedI2CBus
from stereocam.overlays.emulated.logic import EmulatedFabric
from stereocam.overlays.emulated.regblock import EmulationError
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.emulated.sensors import EmulatedMT9V034, EmulatedSensorPair, pattern_image
from stereocam.overlays.model.camera_in import demosaic, demosaic_camera
from stereocam.overlays.spec import mt9v034 as spec

pytestmark = pytest.mark.armhf

SIZE = (188, 120)
LEFT, RIGHT = slice(0, 4), slice(4, 8)


@pytest.fixture(scope="module")
def rig() -> Iterator[SyntheticRig]:
    """One still rig for the module: every pair sets each camera's whole sensor stage every frame."""
    with SyntheticRig(size=SIZE, motion=False) as r:
        yield r


@pytest.fixture(scope="module")
def profile() -> BoardProfile:
    return load_profile()


def rig_up(rig: SyntheticRig, profile: BoardProfile, **kw: Any) -> Tuple[EmulatedSensorPair, StereoSensors]:
    pair = EmulatedSensorPair.for_profile(profile, rig, **kw)
    return pair, profile.stereo_sensors(pair.bus)


@pytest.fixture
def started(rig: SyntheticRig, profile: BoardProfile) -> Tuple[EmulatedSensorPair, StereoSensors]:
    pair, sensors = rig_up(rig, profile)
    assert sensors.start()["ok"]
    return pair, sensors


def frame(pair: EmulatedSensorPair, rig: SyntheticRig, index: int = 0) -> np.ndarray:
    """One frame as the fabric makes it: the sensors latch, the rig renders, the sensors measure."""
    pair.start_frame(index)
    out = rig.read(index, 0.0)
    pair.end_frame(index, out)
    return out


# -- the register model ------------------------------------------------------------------------

def test_registers_behave_like_the_sensor() -> None:
    bus = EmulatedI2CBus(0)
    sensor = EmulatedMT9V034(camera=0)
    bus.attach(0x48, sensor)
    assert bus.read16(0x48, 0x00) == 0x1324
    assert bus.read16(0x48, 0x0D) == 0x0300 and bus.read16(0x48, 0xAF) == 0x0303
    with pytest.raises(EmulationError, match=r"read-only register CHIP_VERSION \(R0x00\)"):
        bus.write16(0x48, 0x00, 0)
    with pytest.raises(EmulationError, match="R0x99, where no register exists"):
        bus.read16(0x48, 0x99)
    with pytest.raises(EmulationError, match=r"WINDOW_WIDTH = 800 is outside 1\.\.752"):
        bus.write16(0x48, 0x04, 800)
    with pytest.raises(EmulationError, match=r"ANALOG_GAIN.GAIN = 8 is outside 16\.\.64"):
        bus.write16(0x48, 0x35, 8)
    bus.write16(0x48, 0x0C, 1)  # soft reset: self-clearing, registers kept
    assert bus.read16(0x48, 0x0C) == 0
    bus.write16(0x48, 0x0D, 0xF320)  # reserved bits 15:10 read 0
    assert bus.read16(0x48, 0x0D) == 0x0320
    with pytest.raises(EmulationError, match="already has a device"):
        bus.attach(0x48, EmulatedMT9V034(camera=1))


def test_the_pair_is_set_up_from_the_profile(started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    assert pair.bus.path == "emulated /dev/i2c-0" and pair.addresses == (0x48, 0x58)
    assert (pair.left.sensor_mode, pair.right.sensor_mode) == ("master", "slave")
    assert pair.sync_problem() is None
    assert pair.left.get("VERTICAL_BLANKING") == 44  # 60 fps
    assert pair.left.get("AEC_AGC_DESIRED_BIN") == 32
    assert sensors.read()["left"] == {"exposure_us": round(480 * spec.row_time_us(), 3), "exposure_rows": 480,
                                      "exposure_range_us": [round(spec.row_time_us(), 3),
                                                            round(524 * spec.row_time_us(), 3)],
                                      "gain": 1.0, "aec": False, "agc": False, "flip_h": False,
                                      "flip_v": False, "test_pattern": None}


def test_power_on_pair_is_not_synchronised(rig: SyntheticRig) -> None:
    pair = EmulatedSensorPair(rig)
    assert pair.sync_problem() == ("the sensors are not synchronised: left is master, right is master "
                                   "(need one master and one slave, or both snapshot)")


def test_snapshot_profile_puts_both_in_snapshot_mode(rig: SyntheticRig, profile: BoardProfile) -> None:
    raw = {"name": "x", "overlay": "x.bit", "frame": {"width": 752, "height": 480, "fps": 30},
           "i2c": {"bus": 1, "left": 0x4C, "right": 0x5C, "timeout_s": 0.1},
           "sensors": {"pixel_clock_hz": 26_600_000, "sync": "snapshot", "aec_target_bin": 20},
           "controls": profile.controls}
    pair, sensors = rig_up(rig, profile_from_dict(raw))
    assert sensors.start()["ok"]
    assert (pair.left.sensor_mode, pair.right.sensor_mode) == ("snapshot", "snapshot")
    assert pair.sync_problem() is None and pair.addresses == (0x4C, 0x5C)


# -- settings act on the images --------------------------------------------------------------------

def test_exposure_up_makes_the_picture_brighter(rig: SyntheticRig,
                                                started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    means = []
    for us in (4000, 8000, 16000):
        got = sensors.apply({"exposure_us": us})
        assert got["left"]["exposure_us"] == pytest.approx(us, abs=spec.row_time_us() / 2)  # type: ignore[index]
        f = frame(pair, rig)
        means.append((f[..., 3].mean(), f[..., 7].mean()))
    for cam in (0, 1):
        m = [x[cam] for x in means]
        assert 20 < m[0] < m[1] < m[2]
        assert m[1] / m[0] == pytest.approx(2.0, rel=0.05)  # brightness is proportional to exposure
    sensors.apply({"exposure_us": 4000, "gain": 2.0})
    f = frame(pair, rig)
    assert f[..., 3].mean() == pytest.approx(means[1][0], rel=0.02)  # 2x gain = 2x exposure
    sensors.apply({"exposure_us": 8000, "gain": 1.0}, camera="right")
    f = frame(pair, rig)
    assert f[..., 7].mean() == pytest.approx(means[1][1], rel=0.02)
    assert f[..., 3].mean() == pytest.approx(means[1][0], rel=0.02)  # left unchanged


def test_gain_raises_the_noise(rig: SyntheticRig, profile: BoardProfile) -> None:
    pair, sensors = rig_up(rig, profile, read_noise=1.5)
    sensors.start()
    spread = []
    for gain, us in ((1.0, 8000), (4.0, 2000)):  # the same brightness, four times the gain
        sensors.apply({"gain": gain, "exposure_us": us})
        a, b = frame(pair, rig, 1).astype(np.int16), frame(pair, rig, 2).astype(np.int16)
        spread.append(float((a[..., 0] - b[..., 0]).std()))  # red (gray averages noise down)
        assert a[..., 3].mean() == pytest.approx(frame(pair, rig, 0)[..., 3].mean(), abs=1)
    assert 1.5 < spread[0] < 3.0  # sqrt(2) * 1.5 DN
    assert spread[1] / spread[0] == pytest.approx(4.0, rel=0.2)


def test_flips_flip(rig: SyntheticRig, started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    plain = frame(pair, rig)

    def mirrored(f: np.ndarray, want: np.ndarray, cams: slice) -> None:
        """``f`` is the camera input's output for the flipped read-out: the mirror image, resampled by
        the CFA."""
        assert np.array_equal(f, demosaic(*rig.raw))
        got, ref = f[..., cams].astype(int), want[..., cams].astype(int)
        assert np.abs(got - ref).mean() < 0.5 * np.abs(got - plain[..., cams]).mean()
        assert np.abs(got.mean(axis=(0, 1)) - ref.mean(axis=(0, 1))).max() < 1.0

    assert sensors.apply({"flip_h": True}, camera="left")["left"]["flip_h"] is True  # type: ignore[index]
    f = frame(pair, rig)
    mirrored(f, plain[:, ::-1], LEFT)
    assert np.array_equal(f[..., RIGHT], plain[..., RIGHT])
    sensors.apply({"flip_h": False, "flip_v": True})
    f = frame(pair, rig)
    mirrored(f, plain[::-1], LEFT)
    mirrored(f, plain[::-1], RIGHT)
    sensors.apply({"flip_h": True})  # flip_v stays
    f = frame(pair, rig)
    mirrored(f, plain[::-1, ::-1], slice(0, 8))
    assert np.array_equal(f[..., [1, 5]], plain[::-1, ::-1][..., [1, 5]])  # green lands on green


def test_test_pattern_replaces_the_scene(rig: SyntheticRig,
                                         started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    scene = frame(pair, rig)
    got = sensors.apply({"test_pattern": "gray_vertical", "gain": 3.0, "flip_h": True}, camera="right")
    assert got["right"]["test_pattern"] == "gray_vertical"  # type: ignore[index]
    f = frame(pair, rig)
    ramp = pattern_image("gray_vertical", SIZE)
    assert ramp[0, 0] == 0 and ramp[0, -1] == 254 and np.all(np.diff(ramp[0].astype(int)) >= 0)
    # gray, unaffected by gain and flips (made after readout), through the camera input's demosaic
    assert np.array_equal(f[..., RIGHT], demosaic_camera(ramp.astype(np.uint16) << 2))
    assert np.abs(f[..., 7].astype(int) - ramp).max() <= 1
    assert np.array_equal(f[..., LEFT], scene[..., LEFT])
    sensors.apply({"test_pattern": "plain"})
    f = frame(pair, rig)
    assert np.all(f == 512 >> 2)
    sensors.apply({"test_pattern": None, "gain": 1.0, "flip_h": False})
    assert np.array_equal(frame(pair, rig), scene)


# -- automatic exposure and gain ------------------------------------------------------------------------

def fabric_with(pair: EmulatedSensorPair, rig: SyntheticRig) -> EmulatedFabric:
    return EmulatedFabric(source=rig, clock="stepped", sensors=pair, ddr_size=16 << 20)


def test_aec_converges_on_the_target_over_a_few_frames(
        rig: SyntheticRig, started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    sensors.apply({"exposure_us": 1500})
    sensors.left.set_aec(False, max_exposure_us=40_000)  # room to brighten
    fabric = fabric_with(pair, rig)
    fabric.step(1)
    assert pair.left.i2c_read16(0xBC) < 10  # dark: far below the target bin 32
    sensors.apply({"aec": True}, camera="left")
    bins = []
    for _ in range(15):
        fabric.step(1)
        bins.append(pair.left.i2c_read16(0xBC))
    assert fabric.counters.camera_frames == 16 and fabric.counters.camera_errors == 0
    assert abs(bins[-1] - 32) <= 1 and all(abs(b - 32) <= 1 for b in bins[-4:])  # converged, and stays
    first = next(i for i, b in enumerate(bins) if abs(b - 32) <= 2)
    assert 2 <= first <= 10  # over a few frames, not at once (AEC updates every 3rd frame)
    left = sensors.read()["left"]
    assert left is not None and left["aec"] and left["exposure_rows"] > 5 * round(1500 / spec.row_time_us())
    assert pair.right.i2c_read16(0xBC) < 10  # the right sensor's AEC is off
    frame_now = rig.read(99, 0.0)
    assert frame_now[..., 3].mean() == pytest.approx(128, abs=8)


def test_aec_stops_at_its_exposure_limit_and_agc_makes_up_the_rest(
        rig: SyntheticRig, started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    sensors.apply({"exposure_us": 1000})
    sensors.left.set_aec(True, max_exposure_us=5000)
    fabric = fabric_with(pair, rig)
    fabric.step(20)
    left = sensors.read()["left"]
    assert left is not None and left["gain"] == 1.0
    assert left["exposure_rows"] == round(5000 / spec.row_time_us())
    assert pair.left.i2c_read16(0xBC) < 16  # too dark: the limit holds
    sensors.left.set_agc(True, max_gain=4.0)
    fabric.step(30)
    left = sensors.read()["left"]
    assert left is not None and left["agc"] and left["gain"] > 2.0
    assert abs(pair.left.i2c_read16(0xBC) - 32) <= 2


# -- missing and wrong sensors ------------------------------------------------------------------------------

def test_a_sensor_that_does_not_answer(rig: SyntheticRig, profile: BoardProfile,
                                      caplog: pytest.LogCaptureFixture) -> None:
    pair, sensors = rig_up(rig, profile)
    pair.right.answering = False
    with pytest.raises(I2CNack) as err:
        pair.bus.read16(0x58, 0x00)
    assert str(err.value).startswith(
        "no acknowledge reading R0x00 of the device at I2C address 0x58 on emulated /dev/i2c-0: ")
    with caplog.at_level(logging.ERROR, logger="stereocam.drivers.mt9v034"):
        health = sensors.start()  # does not raise: the daemon keeps serving
    (record,) = caplog.records
    assert record.getMessage().startswith(
        "camera sensor right: no acknowledge writing 0x0001 to R0x0C of the device at I2C address 0x58")
    assert not health["ok"] and health["left"]["ok"] and not health["right"]["ok"]
    assert health["right"]["address"] == "0x58" and "no acknowledge" in health["right"]["error"]
    assert health["left"]["error"] is None and health["left"]["chip_id"] == "0x1324"
    with pytest.raises(SensorUnavailable) as unavailable:
        sensors.apply({"gain": 2.0})
    assert str(unavailable.value).startswith("right sensor (I2C 0x58) is unavailable: no acknowledge")
    assert "camera='left' or 'right'" in str(unavailable.value)
    got = sensors.apply({"gain": 2.0}, camera="left")  # the other one still works
    assert got["left"]["gain"] == 2.0 and got["right"] is None  # type: ignore[index]
    pair.right.answering = True  # cable reseated: start again
    assert sensors.start()["ok"]


def test_a_sensor_that_stops_answering_is_marked(started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    pair.left.answering = False
    with pytest.raises(SensorUnavailable, match="left sensor stopped answering: no acknowledge"):
        sensors.apply({"gain": 1.5})
    assert sensors.read()["left"] is None and sensors.read()["right"] is not None
    health = sensors.health()
    assert not health["left"]["ok"] and health["right"]["ok"]
    assert health["right"]["warning"] == "its master (left) is unavailable: it gets no frame timing"


def test_a_wrong_chip_is_reported(rig: SyntheticRig, profile: BoardProfile) -> None:
    pair, sensors = rig_up(rig, profile, chip_ids=(spec.CHIP_ID, 0x1313))
    health = sensors.start()
    assert health["left"]["ok"] and not health["right"]["ok"]
    assert health["right"]["error"] == (
        "right: R0x00 CHIP_VERSION at I2C address 0x58 reads 0x1313, not the MT9V034's 0x1324: "
        "that is an MT9V022/MT9V032 rev3, which this driver does not drive")


def test_a_refused_request_changes_nothing(started: Tuple[EmulatedSensorPair, StereoSensors]) -> None:
    pair, sensors = started
    before = sensors.read()
    with pytest.raises(SensorRangeError, match=r"left: exposure 2e\+06 us is out of range"):
        sensors.apply({"gain": 2.0, "exposure_us": 2_000_000})
    with pytest.raises(ValueError, match="unknown camera setting"):
        sensors.apply({"gain": 2.0, "exposur_us": 100})
    with pytest.raises(ValueError, match="camera 'middle' is not one of: both, left, right"):
        sensors.apply({"gain": 2.0}, camera="middle")
    assert sensors.read() == before


# -- the rig's hook ---------------------------------------------------------------------------------------

def test_rig_sensor_hook_validates(rig: SyntheticRig) -> None:
    with pytest.raises(ValueError, match="camera is 0"):
        rig.set_sensor(2)
    with pytest.raises(ValueError, match=r"must be finite and >= 0"):
        rig.set_sensor(0, gain=-1.0)
    with pytest.raises(ValueError, match=r"test_pattern must be a \(120, 188\) uint8 image"):
        rig.set_sensor(0, test_pattern=np.zeros((10, 10), np.uint8))


@pytest.mark.parametrize("us", [0, -5, 5.0])
def test_an_exposure_of_no_whole_row_is_refused(started: Tuple[EmulatedSensorPair, StereoSensors],
                                                us: float) -> None:
    """``exposure_us`` is > 0 and at least one row: zero, negative, or under half a row (0 rows)
    is refused with the range, and nothing changes."""
    _, sensors = started
    before = sensors.read()
    row_us = before["left"]["exposure_us"] / before["left"]["exposure_rows"]
    expected = (rf"left: exposure {us:g} us is out of range: {row_us:g}\.\." if us > 0
                else rf"exposure_us must be > 0 microseconds, not {us!r}")
    with pytest.raises(SensorError, match=expected):
        sensors.apply({"exposure_us": us})
    assert sensors.read() == before
    sensors.apply({"exposure_us": row_us})  # one row is the least
    assert sensors.read()["left"]["exposure_rows"] == 1
