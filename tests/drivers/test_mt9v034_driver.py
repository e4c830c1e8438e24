"""MT9V034 driver: the exact I2C transactions of each sequence, against a recording bus double.

Register numbers are written out here on purpose (not taken from the table):
they pin the table to the Linux driver's ``mt9v032.c`` and the data sheet.
Also the Linux I2C bus's messages, with the ioctl faked (no hardware), and
the stereo pair's recovery of a sensor that stops answering, on the emulated bus.
"""
from __future__ import annotations

import errno
import logging
import os
import time
from pathlib import Path
from typing import Any, List, Tuple

import pytest

from stereocam.drivers.i2c import (
    I2C_M_RD,
    I2C_RDWR,
    I2C_TIMEOUT,
    I2CBus,
    I2CDenied,
    I2CError,
    I2CNack,
    I2CTimeout,
    LinuxI2CBus,
)
from stereocam.drivers.mmio import DriverError, RegisterRangeError
from stereocam.drivers.mt9v034 import (
    MT9V034,
    ChipIdError,
    SensorRangeError,
    SensorSettings,
    SensorUnavailable,
    SettingsError,
    StereoSensors,
)
from stereocam.overlays.emulated.sensors import EmulatedSensorPair
from stereocam.overlays.spec import mt9v034 as spec
from tests.doubles import RecordingI2C, UnexpectedAccess

pytestmark = pytest.mark.armhf

A = 0x48  # the left sensor's address on our board
ROW_US = 846 / 26.6  # 752 + 94 pixel clocks at 26.6 MHz


def sensor(*ops: Tuple[str, int, int, Any]) -> Tuple[MT9V034, RecordingI2C]:
    bus = RecordingI2C(ops)
    return MT9V034(bus, A, name="left"), bus


def row_time_reads(width: int = 752, hblank: int = 94) -> List[Tuple[str, int, int, Any]]:
    return [("r", A, 0x04, width), ("r", A, 0x05, hblank)]


def frame_reads(height: int = 480, vblank: int = 44) -> List[Tuple[str, int, int, Any]]:
    """The reads of a frame's length, WINDOW_HEIGHT and VERTICAL_BLANKING (60 fps: 480 + 44 rows)."""
    return [("r", A, 0x03, height), ("r", A, 0x06, vblank)]


# -- the register table -----------------------------------------------------------------

def test_register_table_matches_the_linux_driver() -> None:
    m = spec.MT9V034_MAP
    expected = {"CHIP_VERSION": 0x00, "COLUMN_START": 0x01, "ROW_START": 0x02, "WINDOW_HEIGHT": 0x03,
                "WINDOW_WIDTH": 0x04, "HORIZONTAL_BLANKING": 0x05, "VERTICAL_BLANKING": 0x06,
                "CHIP_CONTROL": 0x07, "COARSE_SHUTTER_WIDTH_TOTAL": 0x0B, "RESET": 0x0C, "READ_MODE": 0x0D,
                "ANALOG_GAIN": 0x35, "TEST_PATTERN": 0x7F, "AEC_AGC_DESIRED_BIN": 0xA5,
                "MAX_ANALOG_GAIN": 0xAB, "MAX_COARSE_SHUTTER_WIDTH": 0xAD, "AEC_AGC_ENABLE": 0xAF,
                "AGC_OUTPUT": 0xBA, "AEC_OUTPUT": 0xBB}
    for name, address in expected.items():
        assert m.address(name) == address, name
    assert m["CHIP_VERSION"].reset == spec.CHIP_ID == 0x1324
    assert m["READ_MODE"].bit("ROW_FLIP") == 1 << 4 and m["READ_MODE"].bit("COLUMN_FLIP") == 1 << 5
    assert m["READ_MODE"].reset == 0x0300 and m["CHIP_CONTROL"].reset == 0x0388
    assert m["AEC_AGC_ENABLE"].reset == 0x0303
    assert m["COARSE_SHUTTER_WIDTH_TOTAL"].limit() == (0, 32765)
    assert m["HORIZONTAL_BLANKING"].limit() == (61, 1023)
    assert m["ANALOG_GAIN"].limit("GAIN") == (16, 64)
    assert spec.row_time_us() == pytest.approx(ROW_US)
    assert spec.frame_rate(480, 45, spec.row_time_us()) == pytest.approx(59.89, abs=0.01)
    with pytest.raises(ValueError, match="16 bits"):
        spec.Register16("X", 0x10, reset=0x1_0000)
    with pytest.raises(ValueError, match="8-bit"):
        spec.Register16("X", 0x100)


# -- reset and identity ---------------------------------------------------------------------

def test_reset_writes_soft_reset_then_clears_it() -> None:
    s, bus = sensor(("w", A, 0x0C, 0x0001), ("w", A, 0x0C, 0x0000))
    s.reset()
    bus.assert_done()


def test_check_id_accepts_the_mt9v034() -> None:
    s, bus = sensor(("r", A, 0x00, 0x1324))
    assert s.check_id() == 0x1324
    bus.assert_done()


@pytest.mark.parametrize("found, says", [
    (0x1313, "that is an MT9V022/MT9V032 rev3"),
    (0xFFFF, "no known Aptina sensor reads that: check the board profile's address"),
])
def test_a_wrong_chip_id_is_named(found: int, says: str) -> None:
    s, bus = sensor(("r", A, 0x00, found))
    with pytest.raises(ChipIdError) as err:
        s.check_id()
    msg = str(err.value)
    assert msg.startswith("left: R0x00 CHIP_VERSION at I2C address 0x48 reads")
    assert f"{found:#06x}" in msg and "0x1324" in msg and says in msg
    assert isinstance(err.value, DriverError)
    bus.assert_done()


def test_a_nack_reaches_the_caller_unchanged() -> None:
    nack = I2CNack("no acknowledge", bus="test", address=A, register=0)
    s, bus = sensor(("r", A, 0x00, nack))
    with pytest.raises(I2CNack) as err:
        s.check_id()
    assert err.value is nack


def test_only_the_four_strap_addresses_are_accepted() -> None:
    with pytest.raises(SensorRangeError, match=r"0x48, 0x4c, 0x58, 0x5c"):
        MT9V034(RecordingI2C(), 0x10, name="left")


# -- window, frame rate -----------------------------------------------------------------------------

def test_full_window() -> None:
    s, bus = sensor(("w", A, 0x01, 1), ("w", A, 0x02, 4), ("w", A, 0x04, 752), ("w", A, 0x03, 480),
                    ("w", A, 0x05, 94))
    s.configure_window(752, 480)
    bus.assert_done()


def test_a_small_window_is_centred_and_keeps_the_minimum_row_time() -> None:
    s, bus = sensor(("w", A, 0x01, 1 + 216), ("w", A, 0x02, 4 + 120), ("w", A, 0x04, 320),
                    ("w", A, 0x03, 240), ("w", A, 0x05, 690 - 320))
    s.configure_window(320, 240)
    bus.assert_done()


def test_window_out_of_range_is_refused_before_any_write() -> None:
    s, bus = sensor()
    with pytest.raises(SensorRangeError, match=r"left: window width 800 is out of range: 1\.\.752"):
        s.configure_window(800, 480)
    with pytest.raises(SensorRangeError, match=r"window height 0 is out of range: 1\.\.480"):
        s.configure_window(752, 0)
    assert not bus.done


def test_frame_rate_sets_vertical_blanking() -> None:
    s, bus = sensor(*row_time_reads(), ("r", A, 0x03, 480), ("w", A, 0x06, 44))
    assert s.set_frame_rate(60) == pytest.approx(60.0, abs=0.02)
    bus.assert_done()
    s, bus = sensor(*row_time_reads(), ("r", A, 0x03, 480))
    with pytest.raises(SensorRangeError, match=r"frame rate 100 fps is out of range: 0\.\d+\.\.65\.\d+ fps"):
        s.set_frame_rate(100)
    bus.assert_done()


# -- exposure and gain ---------------------------------------------------------------------------------

def test_exposure_in_microseconds_is_whole_rows_of_the_row_time() -> None:
    rows = round(10_000 / ROW_US)
    assert rows == 314
    s, bus = sensor(*row_time_reads(), *frame_reads(), ("w", A, 0x0B, rows))
    s.exposure_us = 10_000
    bus.assert_done()
    s, bus = sensor(*row_time_reads(), ("r", A, 0x0B, 480))
    assert s.exposure_us == pytest.approx(480 * ROW_US)
    bus.assert_done()
    s, bus = sensor(("w", A, 0x0B, 1000), ("r", A, 0x0B, 1000))
    s.exposure_rows = 1000
    assert s.exposure_rows == 1000
    bus.assert_done()


def test_exposure_follows_the_row_time_of_the_window() -> None:
    row_us = 690 / 26.6  # a 320-wide window: 320 + 370 clocks
    s, bus = sensor(*row_time_reads(320, 370), *frame_reads(), ("w", A, 0x0B, round(10_000 / row_us)))
    s.exposure_us = 10_000
    bus.assert_done()


def test_exposure_is_one_row_to_one_frame_and_beyond_is_refused_naming_the_range() -> None:
    """At 60 fps a frame is 524 rows (16.67 ms). 999999 us used to be written as 31442 rows, the
    sensor then running at 1 fps, without a word; an exposure longer than the frame is refused with
    the range, and nothing is written."""
    frame_us = 524 * ROW_US
    for us in (999_999, 2_000_000, frame_us + ROW_US):
        s, bus = sensor(*row_time_reads(), *frame_reads())
        with pytest.raises(SensorRangeError) as err:
            s.exposure_us = us
        assert str(err.value) == (
            f"left: exposure {us:g} us is out of range: {ROW_US:g}..{frame_us:.0f} us (1..524 rows of "
            f"{ROW_US:.2f} us: at most one frame, 524 rows at 60.0 fps; a longer exposure would lower the "
            "frame rate)")
        bus.assert_done()  # the timing was read, nothing was written
    s, bus = sensor(*row_time_reads(), *frame_reads(), ("w", A, 0x0B, 524))
    s.exposure_us = frame_us  # one frame is the most
    bus.assert_done()
    s, bus = sensor(*row_time_reads(), *frame_reads(vblank=32288))  # the slowest frame: R0x0B's own limit
    with pytest.raises(SensorRangeError) as err:
        s.exposure_us = 2_000_000
    assert str(err.value) == (f"left: exposure 2e+06 us is out of range: {ROW_US:g}..{32765 * ROW_US:.0f} us "
                              f"(1..32765 rows of {ROW_US:.2f} us)")
    bus.assert_done()
    s, bus = sensor()
    with pytest.raises(SensorRangeError, match=r"exposure \(rows\) 40000 is out of range: 0\.\.32765"):
        s.exposure_rows = 40_000
    with pytest.raises(RegisterRangeError, match="whole number"):
        s.exposure_rows = 12.5  # type: ignore[assignment]
    assert not bus.done


def test_the_exposure_range_is_the_specs_for_the_timing_read() -> None:
    s, bus = sensor(*row_time_reads(320, 370), *frame_reads(240, 100))
    assert s.exposure_range() == spec.ExposureRange.at(width=320, hblank=370, height=240, vblank=100)
    bus.assert_done()
    got = spec.ExposureRange.at(width=320, hblank=370, height=240, vblank=100)
    assert (got.lo, got.hi, got.frame_rows) == (1, 340, 340)
    assert got.hi_us == pytest.approx(340 * 690 / 26.6) and got.fps == pytest.approx(26.6e6 / (340 * 690))


def test_gain_is_sixteenths() -> None:
    s, bus = sensor(("w", A, 0x35, 40), ("w", A, 0x35, 16), ("w", A, 0x35, 64), ("r", A, 0x35, 0x0020))
    s.gain = 2.5
    s.gain = 1.0
    s.gain = 4.0
    assert s.gain == 2.0
    bus.assert_done()


@pytest.mark.parametrize("bad", [0.5, 4.01, float("nan"), "2", True])
def test_gain_out_of_range_names_the_range(bad: Any) -> None:
    s, bus = sensor()
    with pytest.raises(ValueError, match=r"1\.0\.\.4\.0|finite number"):
        s.gain = bad
    assert not bus.done


# -- automatic exposure and gain -------------------------------------------------------------------------

def test_aec_on_with_limits_writes_limits_then_the_enable_bit() -> None:
    max_rows = round(8000 / ROW_US)
    s, bus = sensor(*row_time_reads(), ("w", A, 0xAD, max_rows), ("w", A, 0xA5, 40),
                    ("r", A, 0xAF, 0x0302), ("w", A, 0xAF, 0x0303))
    s.set_aec(True, max_exposure_us=8000, target=40)
    bus.assert_done()


def test_aec_and_agc_off_clear_only_their_bit() -> None:
    s, bus = sensor(("r", A, 0xAF, 0x0303), ("w", A, 0xAF, 0x0302),
                    ("r", A, 0xAF, 0x0302), ("w", A, 0xAF, 0x0300))
    s.set_aec(False)
    s.set_agc(False)
    bus.assert_done()


def test_agc_on_with_a_gain_limit() -> None:
    s, bus = sensor(("w", A, 0xAB, 48), ("r", A, 0xAF, 0x0300), ("w", A, 0xAF, 0x0302))
    s.set_agc(True, max_gain=3.0)
    bus.assert_done()


def test_aec_and_agc_limits_out_of_range() -> None:
    s, bus = sensor()
    with pytest.raises(SensorRangeError, match=r"AEC/AGC target bin 65 is out of range: 1\.\.64"):
        s.set_aec(True, target=65)
    with pytest.raises(SensorRangeError, match=r"max_gain 5 is out of range: 1\.0\.\.4\.0"):
        s.set_agc(True, max_gain=5)
    with pytest.raises(SettingsError, match="aec must be true or false"):
        s.set_aec("on")  # type: ignore[arg-type]
    assert not bus.done
    s, bus = sensor(*row_time_reads())
    expected = r"left: max_exposure 0 us is out of range: 31\.80\d*\.\.1042075 us \(1\.\.32765 rows"
    with pytest.raises(SensorRangeError, match=expected):
        s.set_aec(True, max_exposure_us=0)
    bus.assert_done()


# -- readout: flips, test pattern, sync ---------------------------------------------------------------

def test_flips_keep_the_reserved_bits() -> None:
    s, bus = sensor(("r", A, 0x0D, 0x0300), ("w", A, 0x0D, 0x0320),
                    ("r", A, 0x0D, 0x0320), ("w", A, 0x0D, 0x0330),
                    ("r", A, 0x0D, 0x0330), ("w", A, 0x0D, 0x0300))
    s.flip(True, False)
    s.flip(v=True)  # h left alone
    s.flip(False, False)
    s.flip()  # nothing to change: no transaction
    bus.assert_done()


@pytest.mark.parametrize("name, word", [
    ("gray_vertical", 0x2800), ("gray_horizontal", 0x3000), ("gray_diagonal", 0x3800),
    ("plain", 0x6600), (None, 0x0000), ("off", 0x0000),
])
def test_test_pattern_words(name: Any, word: int) -> None:
    s, bus = sensor(("w", A, 0x7F, word))
    s.test_pattern(name)
    bus.assert_done()


def test_unknown_test_pattern_is_refused() -> None:
    s, bus = sensor()
    with pytest.raises(SensorRangeError, match="'bars' is not one of: gray_vertical, gray_horizontal"):
        s.test_pattern("bars")
    assert not bus.done


@pytest.mark.parametrize("mode, before, after", [
    ("slave", 0x0388, 0x0380), ("snapshot", 0x0388, 0x0398), ("master", 0x0380, 0x0388),
])
def test_sync_modes(mode: str, before: int, after: int) -> None:
    s, bus = sensor(("r", A, 0x07, before), ("w", A, 0x07, after))
    s.set_sync(mode)
    bus.assert_done()
    with pytest.raises(SensorRangeError, match="'stereo' is not one of: slave, master, snapshot"):
        s.set_sync("stereo")


def test_settings_report_the_auto_values_when_auto_is_on() -> None:
    s, bus = sensor(("r", A, 0xAF, 0x0301), *row_time_reads(), *frame_reads(), ("r", A, 0xBB, 300),
                    ("r", A, 0x35, 32), ("r", A, 0x0D, 0x0310), ("r", A, 0x7F, 0x3000))
    assert s.settings() == {"exposure_us": round(300 * ROW_US, 3), "exposure_rows": 300,
                            "exposure_range_us": [round(ROW_US, 3), round(524 * ROW_US, 3)], "gain": 2.0,
                            "aec": True, "agc": False, "flip_h": False, "flip_v": True,
                            "test_pattern": "gray_horizontal"}
    bus.assert_done()
    s, bus = sensor(("r", A, 0xAF, 0x0002), *row_time_reads(), *frame_reads(), ("r", A, 0x0B, 100),
                    ("r", A, 0xBA, 24),
                    ("r", A, 0x0D, 0x0320), ("r", A, 0x7F, 0))
    got = s.settings()
    assert (got["exposure_rows"], got["gain"], got["aec"], got["agc"]) == (100, 1.5, False, True)
    assert got["flip_h"] is True
    bus.assert_done()


def test_the_recording_double_catches_a_wrong_transaction() -> None:
    s, bus = sensor(("w", A, 0x0C, 0x0002))
    with pytest.raises(UnexpectedAccess, match="driver wrote 0x0001 to R0x0C at 0x48, expected 0x0002"):
        s.reset()
    bus = RecordingI2C([("r", A, 0x00, 0x1324)])
    with pytest.raises(AssertionError, match="1 expected transactions never happened"):
        bus.assert_done()


# -- settings requests -----------------------------------------------------------------------------------

def test_settings_from_a_request() -> None:
    s = SensorSettings.from_dict({"exposure_us": 5000, "gain": 2, "aec": False, "test_pattern": None})
    assert s.given() == {"exposure_us": 5000, "gain": 2, "aec": False, "test_pattern": "off"}
    assert SensorSettings.from_dict({}).given() == {}


@pytest.mark.parametrize("body, message", [
    ({"exposure": 10}, "unknown camera setting(s): 'exposure' (known: exposure_us, gain, aec, agc, flip_h, "
                       "flip_v, test_pattern)"),
    ({"gain": 5.0}, "gain 5 is out of range: 1.0..4.0"),
    ({"gain": None}, "gain may not be null"),
    ({"aec": "yes"}, "aec must be true or false, not 'yes'"),
    ({"exposure_us": -1}, "exposure_us must be > 0"),
    ({"exposure_us": 0}, "exposure_us must be > 0"),
    ({"test_pattern": "bars"}, "test_pattern 'bars' is not one of"),
    ([1, 2], "camera settings must be an object"),
])
def test_bad_requests_are_refused_with_a_reason(body: Any, message: str) -> None:
    with pytest.raises(ValueError) as err:
        SensorSettings.from_dict(body)
    assert message in str(err.value)


# -- the stereo pair: a sensor that stops answering, then answers again ---------------------------------

B = 0x58  # the right sensor's address


def bring_up(addr: int, chip_control: int) -> List[Tuple[str, int, int, Any]]:
    """What start() does to one sensor (752x480 at 60 fps, AEC target 32, defaults {"gain": 2.0})."""
    return [("w", addr, 0x0C, 0x0001), ("w", addr, 0x0C, 0x0000), ("r", addr, 0x00, 0x1324),
            ("w", addr, 0x01, 1), ("w", addr, 0x02, 4), ("w", addr, 0x04, 752), ("w", addr, 0x03, 480),
            ("w", addr, 0x05, 94),
            ("r", addr, 0x04, 752), ("r", addr, 0x05, 94), ("r", addr, 0x03, 480), ("w", addr, 0x06, 44),
            ("r", addr, 0x07, 0x0388), ("w", addr, 0x07, chip_control),
            ("w", addr, 0xA5, 32),
            ("w", addr, 0x35, 32)]


def test_check_reads_one_register_per_sensor_and_sets_a_returning_one_up_again() -> None:
    """The periodic check is one CHIP_VERSION read per sensor; a returning sensor gets start()'s sequence."""
    bus = RecordingI2C([*bring_up(A, 0x0388), *bring_up(B, 0x0380)])
    pair = StereoSensors(MT9V034(bus, A, name="left"), MT9V034(bus, B, name="right"),
                         defaults={"gain": 2.0}, aec_target=32)
    assert pair.start()["ok"]
    bus.assert_done()
    bus.expect(("r", A, 0x00, 0x1324), ("r", B, 0x00, 0x1324))
    assert pair.check()["ok"]
    bus.assert_done()
    nack = I2CNack("no acknowledge reading R0x00", bus="test", address=A, register=0)
    for _ in range(3):  # silent: one read, no bring-up, no writes
        bus.expect(("r", A, 0x00, nack), ("r", B, 0x00, 0x1324))
        health = pair.check()
        bus.assert_done()
        assert not health["left"]["ok"] and health["right"]["ok"]
    bus.expect(("r", A, 0x00, 0x1324), *bring_up(A, 0x0388), ("r", B, 0x00, 0x1324))
    assert pair.check()["ok"]
    bus.assert_done()


def test_check_does_nothing_before_start() -> None:
    bus = RecordingI2C()
    pair = StereoSensors(MT9V034(bus, A, name="left"), MT9V034(bus, B, name="right"))
    assert pair.check()["left"]["error"] == "not started"
    assert pair.faults() == []  # not started is not a fault
    assert not bus.done


SET_UP = ("COLUMN_START", "ROW_START", "WINDOW_WIDTH", "WINDOW_HEIGHT", "HORIZONTAL_BLANKING",
          "VERTICAL_BLANKING", "CHIP_CONTROL", "AEC_AGC_DESIRED_BIN")


def test_a_sensor_that_answers_again_gets_its_set_up_and_the_controls_last_applied(
        caplog: pytest.LogCaptureFixture) -> None:
    """On the emulated bus: the silent sensor loses power; it comes back as the user left it."""
    emulated = EmulatedSensorPair(None)
    pair = StereoSensors(MT9V034(emulated.bus, A, name="left"), MT9V034(emulated.bus, B, name="right"),
                         frame_size=(640, 400), fps=30.0, aec_target=40,
                         defaults={"exposure_us": 10_000, "gain": 1.0, "aec": False, "agc": False})
    assert pair.start()["ok"]
    pair.apply({"exposure_us": 5000, "gain": 2.5, "flip_h": True, "test_pattern": "gray_vertical"},
               camera="left")
    pair.apply({"agc": True}, camera="left")
    pair.apply({"gain": 3.0}, camera="right")
    wanted = pair.read()
    left = wanted["left"]
    assert left is not None and left["flip_h"] and left["agc"] and left["test_pattern"] == "gray_vertical"
    assert abs(left["exposure_us"] - 5000) < 32  # whole rows
    set_up = {name: emulated.left.get(name) for name in SET_UP}
    assert set_up["VERTICAL_BLANKING"] != spec.MT9V034_MAP["VERTICAL_BLANKING"].reset  # 30 fps, not 60
    assert pair.controls("left") == {"exposure_us": 5000, "gain": 2.5, "aec": False, "agc": True,
                                     "flip_h": True, "test_pattern": "gray_vertical"}

    with caplog.at_level(logging.DEBUG, logger="stereocam.drivers.mt9v034"):
        before = time.time()
        emulated.left.answering = False
        emulated.left.power_on()  # the glitch cut its power too: every register is back at reset
        got = pair.read()
        assert got["left"] is None and got["right"] == wanted["right"]
        for _ in range(5):  # the daemon's refresh re-probes a few times a second
            health = pair.check()
            assert not health["left"]["ok"] and health["right"]["ok"]
        (fault,) = pair.faults()
        assert fault["what"] == "sensor.left"
        assert fault["text"].startswith("left sensor (I2C 0x48) is not answering: no acknowledge reading")
        assert "the right sensor, its slave, gets no frame timing" in fault["text"]
        assert before <= fault["since"] <= time.time()
        with pytest.raises(SensorUnavailable) as refused:
            pair.apply({"gain": 4.0}, camera="left")  # refused: not remembered either
        assert str(refused.value).startswith("left sensor (I2C 0x48) is unavailable: no acknowledge")
        assert "as soon as it answers: check its cable and power" in str(refused.value)

        emulated.left.answering = True
        assert pair.check()["ok"]
    assert pair.faults() == []
    assert {name: emulated.left.get(name) for name in SET_UP} == set_up
    assert pair.read() == wanted  # the user's exposure, gain, AGC, flip and test pattern, not the defaults
    assert emulated.left.get("COARSE_SHUTTER_WIDTH_TOTAL") == left["exposure_rows"]

    lines = [r for r in caplog.records if r.levelno >= logging.INFO]
    assert [r.levelno for r in lines] == [logging.ERROR, logging.INFO], [r.getMessage() for r in lines]
    assert lines[0].getMessage().startswith("camera sensor left: no acknowledge reading R0x")
    assert lines[1].getMessage().startswith("camera sensor left: answers again after ")
    assert "set up again (master) with the controls last applied" in lines[1].getMessage()

    pair.start()  # a fresh start forgets what was applied
    assert pair.controls("left") == pair.defaults.given()
    with pytest.raises(SettingsError, match="camera 'both' is not one of: left, right"):
        pair.controls("both")


def test_a_wrong_part_answering_is_logged_once_per_change(caplog: pytest.LogCaptureFixture) -> None:
    """While down, bus errors are quiet; a part that answers with another chip id is news, once."""
    emulated = EmulatedSensorPair(None)
    pair = StereoSensors(MT9V034(emulated.bus, A, name="left"), MT9V034(emulated.bus, B, name="right"))
    assert pair.start()["ok"]
    with caplog.at_level(logging.INFO, logger="stereocam.drivers.mt9v034"):
        emulated.right.answering = False
        for _ in range(3):
            pair.check()
        emulated.right.answering = True
        emulated.right.chip_id = 0x1313  # another part strapped there
        for _ in range(3):
            health = pair.check()
        assert not health["right"]["ok"] and "0x1313" in health["right"]["error"]
        (fault,) = pair.faults()
        assert fault["text"].startswith("right sensor (I2C 0x58) is unavailable: R0x00 CHIP_VERSION at I2C")
        emulated.right.chip_id = spec.CHIP_ID
        assert pair.check()["ok"]
    assert [r.getMessage()[:40] for r in caplog.records] == [
        "camera sensor right: no acknowledge read",
        "camera sensor right: R0x00 CHIP_VERSION ",
        "camera sensor right: answers again after",
    ]


# -- the Linux bus, with the device faked ------------------------------------------------------------------

class FakeI2CDev:
    """Stands in for os.open/fcntl.ioctl/os.close on /dev/i2c-N: records messages, answers reads."""

    def __init__(self, answer: bytes = b"\x13\x24", error: int = 0) -> None:
        self.answer = answer
        self.error = error
        self.opened: List[str] = []
        self.closed: List[int] = []
        self.timeouts: List[int] = []
        self.messages: List[List[Tuple[int, int, bytes]]] = []

    def open(self, path: str, flags: int) -> int:
        assert flags == os.O_RDWR
        self.opened.append(path)
        return 7

    def close(self, fd: int) -> None:
        self.closed.append(fd)

    def ioctl(self, fd: int, request: int, arg: Any) -> int:
        assert fd == 7
        if request == I2C_TIMEOUT:
            self.timeouts.append(arg)
            return 0
        assert request == I2C_RDWR
        msgs = [arg.msgs[i] for i in range(arg.nmsgs)]
        if self.error:
            raise OSError(self.error, os.strerror(self.error))
        for m in msgs:
            if m.flags & I2C_M_RD:
                for i, b in enumerate(self.answer[:m.len]):
                    m.buf[i] = b
        self.messages.append([(m.addr, m.flags, bytes(m.buf[:m.len])) for m in msgs])
        return len(msgs)


def linux_bus(dev: FakeI2CDev, **kw: Any) -> LinuxI2CBus:
    return LinuxI2CBus(0, opener=dev.open, ioctl=dev.ioctl, closer=dev.close, **kw)


def test_linux_bus_messages_are_those_of_the_sensor() -> None:
    dev = FakeI2CDev()
    bus = linux_bus(dev)
    assert isinstance(bus, I2CBus)
    assert dev.opened == []  # nothing touched until the first transaction
    bus.write16(0x48, 0x0B, 0x01E0)
    assert bus.read16(0x58, 0x00) == 0x1324
    assert dev.opened == ["/dev/i2c-0"] and dev.timeouts == [10]  # 0.1 s in units of 10 ms
    assert dev.messages == [
        [(0x48, 0, b"\x0b\x01\xe0")],  # S addr+W reg hi lo P
        [(0x58, 0, b"\x00"), (0x58, I2C_M_RD, b"\x13\x24")],  # S addr+W reg Sr addr+R hi lo P
    ]
    bus.close()
    bus.close()
    assert dev.closed == [7]


def test_linux_bus_refuses_what_no_transaction_can_carry() -> None:
    bus = linux_bus(FakeI2CDev())
    for args in ((0x80, 0, 0), (0x48, 0x100, 0), (0x48, 0, 0x1_0000), (0x48, 0, -1)):
        with pytest.raises(RegisterRangeError, match="out of range"):
            bus.write16(*args)


@pytest.mark.parametrize("code, kind, says", [
    (errno.ENXIO, I2CNack, "no acknowledge reading R0x00 of the device at I2C address 0x48 on /dev/i2c-0"),
    (errno.EREMOTEIO, I2CNack, "is the sensor powered"),
    (errno.ETIMEDOUT, I2CTimeout, "timed out reading R0x00 of the device at I2C address 0x48"),
    (errno.EAGAIN, I2CError, "lost arbitration"),
    (errno.EINVAL, I2CError, "failed reading R0x00"),
])
def test_linux_bus_errors_are_named(code: int, kind: type, says: str) -> None:
    bus = linux_bus(FakeI2CDev(error=code))
    with pytest.raises(kind) as err:
        bus.read16(0x48, 0x00)
    e = err.value
    assert isinstance(e, I2CError) and says in str(e)
    assert (e.address, e.register, e.bus) == (0x48, 0, "/dev/i2c-0")


def test_linux_bus_that_does_not_exist_says_which_do(tmp_path: Path) -> None:
    (tmp_path / "i2c-1").touch()
    bus = LinuxI2CBus(3, device_dir=str(tmp_path))
    with pytest.raises(I2CError) as err:
        bus.read16(0x48, 0)
    assert f"{tmp_path}/i2c-3 does not exist (buses present: {tmp_path}/i2c-1)" in str(err.value)
    assert "board profile's i2c.bus" in str(err.value)


@pytest.mark.parametrize("code", [errno.EPERM, errno.EACCES])
def test_linux_bus_refused_by_permission_is_its_own_error(tmp_path: Path, code: int) -> None:
    """EPERM (a service's device list: DeviceAllow=) and EACCES (the node's mode) raise I2CDenied, which the
    daemon tells apart from a missing bus (routes_cameras: under systemd, a driver loaded too late)."""
    (tmp_path / "i2c-0").touch()

    def refuse(path: str, flags: int) -> int:
        raise PermissionError(code, os.strerror(code), path)

    bus = LinuxI2CBus(0, device_dir=str(tmp_path), opener=refuse)
    with pytest.raises(I2CDenied) as err:
        bus.open()
    assert isinstance(err.value, I2CError) and err.value.bus == f"{tmp_path}/i2c-0"
    assert str(err.value).startswith(f"permission denied opening {tmp_path}/i2c-0: run the daemon as root")
