"""The board profile: loaded once at start, every mistake named with its key, never a hang."""
from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any, Dict

import pytest
import yaml

from stereocam import cli
from stereocam.board.profile import (
    DEFAULT_ETC,
    DEFAULT_PROFILE,
    ETC_ENV,
    ProfileError,
    etc_dir,
    find_profile,
    load_board_profile,
    load_profile,
    profile_from_dict,
)
from stereocam.drivers.i2c import LinuxI2CBus
from stereocam.server.http import app as app_module
from stereocam.server.http import routes_cameras

from ..server.daemon import start_daemon_fixture  # noqa: F401

pytestmark = pytest.mark.armhf


@pytest.fixture
def raw() -> Dict[str, Any]:
    """The default profile as parsed YAML, to break one key at a time."""
    data = yaml.safe_load(DEFAULT_PROFILE.read_text(encoding="utf-8"))
    assert isinstance(data, dict)
    return copy.deepcopy(data)


def test_the_default_profile() -> None:
    p = load_profile()
    assert (p.name, p.overlay) == ("zynq-stereo", "stereocam.bit")
    assert p.frame_size == (752, 480) and p.fps == 60
    assert (p.i2c_bus, p.left_address, p.right_address, p.i2c_device) == (0, 0x48, 0x58, "/dev/i2c-0")
    assert (p.sync, p.master, p.aec_target_bin, p.pixel_clock_hz) == ("master-slave", "left", 32, 26_600_000)
    assert p.controls == {"exposure_us": 15266, "gain": 1.0, "aec": False, "agc": False, "flip_h": False,
                          "flip_v": False, "test_pattern": None}
    assert p.source == str(DEFAULT_PROFILE) and DEFAULT_PROFILE.parent.name == "board"


def break_(raw: Dict[str, Any], path: str, value: Any = KeyError) -> Dict[str, Any]:
    *parents, key = path.split(".")
    node = raw
    for part in parents:
        node = node[part]
    if value is KeyError:
        del node[key]
    else:
        node[key] = value
    return raw


@pytest.mark.parametrize("path, value, message", [
    ("i2c.lefft", 0x48, "i2c: unknown key(s) i2c.lefft (known: bus, left, right, timeout_s)"),
    ("colour", True,
     "top level: unknown key(s) colour (known: name, overlay, frame, i2c, sensors, controls)"),
    ("frame.fps", KeyError, "frame: missing key(s) frame.fps"),
    ("controls", KeyError, "top level: missing key(s) controls"),
    ("i2c.left", 0x50,
     "i2c.left: 0x50 is not an address an MT9V034 can be strapped to (0x48, 0x4c, 0x58, 0x5c)"),
    ("i2c.right", 0x48, "i2c.right: both sensors at 0x48: they need different address straps"),
    ("i2c.bus", "zero", "i2c.bus: must be a whole number in 0..255, not 'zero'"),
    ("i2c.timeout_s", 60, "i2c.timeout_s: 60 s is out of range: 0.01..10"),
    ("frame.width", 1024, "frame.width: 1024 is out of range: 1..752"),
    ("frame.fps", 90, "frame.fps: 90 is out of range: 0.96..65.23 for a 752x480 window at 26.6 MHz"),
    ("sensors.sync", "stereo", "sensors.sync: 'stereo' is not one of: master-slave, snapshot"),
    ("sensors.master", "middle", "sensors.master: 'middle' is not one of: left, right"),
    ("sensors.master", KeyError,
     "sensors.master: missing: with sync master-slave, say which sensor is master"),
    ("sensors.aec_target_bin", 0, "sensors.aec_target_bin: 0 is out of range: 1..64"),
    ("sensors.pixel_clock_hz", 50_000_000,
     "sensors.pixel_clock_hz: 50000000 is out of range: 13000000..27000000"),
    ("overlay", "stereocam.hwh", "overlay: 'stereocam.hwh' is not a bitstream file name (*.bit)"),
    ("controls.gain", 8, "controls: gain 8 is out of range: 1.0..4.0"),
    ("controls.exposure_us", 20000,
     "controls.exposure_us: exposure 20000 us is out of range: 31.8045..16666 us (1..524 rows of 31.80 us: "
     "at most one frame, 524 rows at 60.0 fps; a longer exposure would lower the frame rate)"),
    ("controls.exposure", 10, "controls: unknown key(s) controls.exposure"),
    ("i2c", [0, 0x48], "i2c: must be a mapping with keys bus, left, right, timeout_s, but is a list"),
])
def test_a_wrong_profile_is_named(raw: Dict[str, Any], path: str, value: Any, message: str) -> None:
    with pytest.raises(ProfileError) as err:
        profile_from_dict(break_(raw, path, value), source="test.yaml")
    assert message in str(err.value)
    assert str(err.value).startswith("board profile test.yaml: ")
    assert isinstance(err.value, ValueError)


def test_master_is_refused_with_snapshot_sync(raw: Dict[str, Any]) -> None:
    break_(raw, "sensors.sync", "snapshot")
    with pytest.raises(ProfileError, match="sensors.master: applies to sync master-slave only .* remove it"):
        profile_from_dict(raw)
    p = profile_from_dict(break_(raw, "sensors.master"))
    assert p.sync == "snapshot" and p.master is None


def test_profile_files(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match=r"board profile .*nope\.yaml does not exist: give the path"):
        load_profile(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ni2c: [unclosed\n", encoding="utf-8")
    with pytest.raises(ProfileError, match=r"bad\.yaml: not valid YAML: line 3, column 1"):
        load_profile(bad)
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing\n", encoding="utf-8")
    with pytest.raises(ProfileError, match=r"empty\.yaml: top level: must be a mapping .* is empty"):
        load_profile(empty)
    good = tmp_path / "good.yaml"
    text = DEFAULT_PROFILE.read_text(encoding="utf-8")
    good.write_text(text.replace("bus: 0 ", "bus: 2 "), encoding="utf-8")
    assert load_profile(str(good)).i2c_bus == 2


def test_a_profile_naming_a_missing_bus_fails_fast_at_start(tmp_path: Path) -> None:
    """The wrong bus is reported per sensor, in health, within milliseconds: no hang, no exception."""
    (tmp_path / "i2c-0").touch()
    profile = profile_from_dict(yaml.safe_load(DEFAULT_PROFILE.read_text(encoding="utf-8").replace(
        "bus: 0 ", "bus: 7 ")))
    bus = LinuxI2CBus(profile.i2c_bus, timeout=profile.i2c_timeout, device_dir=str(tmp_path))
    sensors = profile.stereo_sensors(bus)
    t0 = time.monotonic()
    health = sensors.start()
    assert time.monotonic() - t0 < 1.0
    assert not health["ok"]
    for cam in ("left", "right"):
        assert health[cam]["error"] == (
            f"{tmp_path}/i2c-7 does not exist (buses present: {tmp_path}/i2c-0): "
            "check the board profile's i2c.bus, and that the i2c-dev module is loaded")
    assert sensors.read() == {"left": None, "right": None}


# -- which profile: --board, the settings' board, /etc/stereocam/board.yaml, the packaged one --------

def profile_file(path: Path, **changes: Any) -> Path:
    """The default profile, its ``name`` and ``controls.exposure_us`` changed, written to ``path``."""
    data = yaml.safe_load(DEFAULT_PROFILE.read_text(encoding="utf-8"))
    data["name"] = changes.get("name", data["name"])
    data["controls"]["exposure_us"] = changes.get("exposure_us", data["controls"]["exposure_us"])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_the_search_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    etc = tmp_path / "etc"
    etc.mkdir()
    assert find_profile(etc=etc) == DEFAULT_PROFILE, "no machine profile: the packaged one"
    machine = profile_file(etc / "board.yaml", name="machine")
    assert find_profile(etc=etc) == machine and load_board_profile(etc=etc).name == "machine"
    given = profile_file(tmp_path / "given.yaml", name="given")
    assert find_profile(given, etc=etc) == given and load_board_profile(str(given), etc=etc).name == "given"
    monkeypatch.setenv(ETC_ENV, str(etc))
    assert etc_dir() == etc and find_profile() == machine
    monkeypatch.delenv(ETC_ENV)
    assert etc_dir() == DEFAULT_ETC == Path("/etc/stereocam")


def test_profile_file_errors_say_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ETC_ENV, str(tmp_path / "etc"))
    with pytest.raises(ProfileError) as err:
        load_board_profile(tmp_path / "nope.yaml")
    assert str(err.value) == (
        f"board profile {tmp_path / 'nope.yaml'} does not exist: give the path of a profile (--board FILE or "
        f"the settings' board key; without one, {tmp_path / 'etc' / 'board.yaml'} if it exists, else "
        f"{DEFAULT_PROFILE})")
    with pytest.raises(ProfileError, match=f"board profile {tmp_path} is a folder: give the profile's file, "
                                           f"e.g. {tmp_path / 'board.yaml'}"):
        load_board_profile(tmp_path)


def serve_error(capsys: pytest.CaptureFixture, *args: str) -> str:
    """``stereocam serve ARGS`` in this process; the one line it prints on stderr (exit 2, no traceback)."""
    assert cli.main(["serve", "--backend", "emulated", "--port", "0", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("stereocam serve: error: "), err
    return err[len("stereocam serve: error: "):].rstrip("\n")


def test_serve_checks_the_profile_at_start_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    etc = tmp_path / "etc"
    monkeypatch.setenv(ETC_ENV, str(etc))
    opened: list = []
    monkeypatch.setattr(app_module, "run", lambda config, **kw: opened.append(config) or 0)
    bad = tmp_path / "bad.yaml"
    bad.write_text(DEFAULT_PROFILE.read_text(encoding="utf-8").replace("left: 0x48", "left: 0x50"))
    assert serve_error(capsys, "--board", str(bad)) == (
        f"board profile {bad}: i2c.left: 0x50 is not an address an MT9V034 can be strapped to "
        "(0x48, 0x4c, 0x58, 0x5c)")
    assert serve_error(capsys, "--board", str(tmp_path / "gone.yaml")).startswith(
        f"board profile {tmp_path / 'gone.yaml'} does not exist: ")
    settings = tmp_path / "settings.yaml"
    settings.write_text(f"board: {bad}\n")
    assert serve_error(capsys, "--config", str(settings)).startswith(f"board profile {bad}: i2c.left: ")
    etc.mkdir()
    (etc / "board.yaml").write_text("i2c: {bus: 0}\n")
    assert serve_error(capsys).startswith(
        f"board profile {etc / 'board.yaml'}: top level: missing key(s) name")
    assert opened == [], "nothing is opened with a wrong profile"


def test_serve_hands_the_daemon_the_profile_found(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    etc = tmp_path / "etc"
    monkeypatch.setenv(ETC_ENV, str(etc))
    opened: list = []
    monkeypatch.setattr(app_module, "run", lambda config, **kw: opened.append(config.board) or 0)
    serve = ["serve", "--backend", "emulated", "--port", "0"]
    assert cli.main(serve) == 0
    machine = profile_file(etc / "board.yaml", name="machine")
    assert cli.main(serve) == 0
    key = profile_file(tmp_path / "key.yaml", name="key")
    settings = tmp_path / "settings.yaml"
    settings.write_text(f"board: {key}\n")
    assert cli.main([*serve, "--config", str(settings)]) == 0
    flag = profile_file(tmp_path / "flag.yaml", name="flag")
    assert cli.main([*serve, "--config", str(settings), "--board", str(flag)]) == 0
    assert opened == [str(DEFAULT_PROFILE), str(machine), str(key), str(flag)]


async def test_the_daemon_runs_the_sensors_with_the_configs_profile(start_daemon, tmp_path: Path) -> None:
    board = profile_file(tmp_path / "board.yaml", name="slow-shutter", exposure_us=5000)
    d = await start_daemon(extensions=[routes_cameras.setup], board=str(board))
    async with d.http.get("/api/cameras") as resp:
        body = await resp.json()
    assert resp.status == 200, body
    for cam in ("left", "right"):
        assert abs(body[cam]["exposure_us"] - 5000) < 60, body[cam]  # whole rows of the sensor
