"""The daemon's settings: strict files, exact messages, command-line overrides."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereocam.server.http.settings import Settings, SettingsError

pytestmark = pytest.mark.armhf


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_defaults() -> None:
    c = Settings()
    assert (c.host, c.port, c.backend) == ("127.0.0.1", 8080, "auto")
    assert c.calibration is None and c.access_token is None
    assert c.max_streams >= 20 and c.default_fps == 60 and 1 <= c.default_quality <= 100
    assert c.captures_path == Path("~/.local/share/stereocam/captures").expanduser()


def test_yaml_and_json_files(tmp_path) -> None:
    y = write(tmp_path, "c.yaml",
              "host: 0.0.0.0\nport: 9000\nmax_streams: 4\naccess_token: abcdefgh123\nfps: 30\n")
    c = Settings.from_file(y)
    assert (c.host, c.port, c.max_streams, c.access_token, c.fps) == ("0.0.0.0", 9000, 4, "abcdefgh123", 30.0)
    assert isinstance(c.fps, float)
    j = write(tmp_path, "c.json", json.dumps({"backend": "emulated", "stream_timeout_s": 2}))
    assert Settings.from_file(j).backend == "emulated"
    assert Settings.from_file(write(tmp_path, "empty.yaml", "")) == Settings()
    assert Settings.from_file(y).public()["access_token"] == "set" and "abcdefgh123" not in str(c.public())


def test_unknown_keys_are_named_with_a_suggestion(tmp_path) -> None:
    path = write(tmp_path, "c.yaml", "max_stream: 4\n")
    with pytest.raises(SettingsError) as info:
        Settings.from_file(path)
    message = str(info.value)
    assert message.startswith(
        f"{path}: unknown key 'max_stream' (did you mean 'max_streams'?); known keys: host, port")
    with pytest.raises(SettingsError, match=r"unknown key 'xyzzy'; known keys"):
        Settings.from_mapping({"xyzzy": 1})


@pytest.mark.parametrize("text,message", [
    ("port: 70000", "port must be >= 0 and <= 65535, got 70000"),
    ("port: '80'", "port must be a whole number, got '80'"),
    ("port: true", "port must be a whole number, got True"),
    ("backend: fpga", "backend must be one of auto, pynq, emulated, got 'fpga'"),
    ("core: verilog", "core must be one of model, rtl, got 'verilog'"),
    ("protect: reads", "protect must be all or control, got 'reads'"),
    ("allowed_hosts: ['board:8080']",
     "allowed_hosts must be a list of host names (no ports or spaces), got ['board:8080']"),
    ("allowed_hosts: [3]", "allowed_hosts must be a list of host names (no ports or spaces), got [3]"),
    ("core_build: big", "core_build must be one of gray, colour, got 'big'"),
    ("core_build: [colour]", "core_build must be one of gray, colour, got ['colour']"),
    ("backend: {emulated: 1}", "backend must be one of auto, pynq, emulated, got {'emulated': 1}"),
    ("rtl_dir: ''", "rtl_dir must be a non-empty string or null, got ''"),
    ("rtl_dir: my-rtl", "rtl_dir 'my-rtl' is for the RTL core: set core to rtl (--core rtl) as well, "
                        "or leave rtl_dir out"),
    ("default_quality: 0", "default_quality must be >= 1 and <= 100, got 0"),
    ("default_fps: 0", "default_fps must be > 0 and <= 120, got 0"),
    ("stream_timeout_s: .nan", "stream_timeout_s must be > 0 and <= 3600, got nan"),
    ("host: ''", "host must be a non-empty string, got ''"),
    ("access_token: short", "access_token must be at least 8 characters without spaces"),
    ("calibration: 3", "calibration must be a non-empty string or null, got 3"),
    ("- a\n- b", "the configuration must be a mapping of settings, got list"),
])
def test_bad_values_are_named(tmp_path, text, message) -> None:
    path = write(tmp_path, "c.yaml", text + "\n")
    with pytest.raises(SettingsError) as info:
        Settings.from_file(path)
    assert str(info.value) == f"{path}: {message}"


def test_unreadable_files(tmp_path) -> None:
    with pytest.raises(SettingsError, match=r"nope.yaml: no such file"):
        Settings.from_file(tmp_path / "nope.yaml")
    with pytest.raises(SettingsError,
                       match=r"not valid YAML: line 2, column 7: mapping values are not allowed"):
        Settings.from_file(write(tmp_path, "bad.yaml", "host: a\n  port: [\n"))
    with pytest.raises(SettingsError, match=r"not valid JSON"):
        Settings.from_file(write(tmp_path, "bad.json", "{host"))


def test_command_line_overrides_the_file(tmp_path) -> None:
    path = write(tmp_path, "c.yaml", "host: 0.0.0.0\nport: 9000\n")
    c = Settings.load(path, port=9100, host=None, captures="/tmp/x")
    assert (c.host, c.port, c.captures) == ("0.0.0.0", 9100, "/tmp/x")
    with pytest.raises(SettingsError, match="port must be"):
        Settings.load(None, port=-1)
    with pytest.raises(SettingsError, match="unknown setting 'colour'"):
        Settings().replace(colour=1)


def test_config_is_keyword_only_and_frozen() -> None:
    c = Settings(port=1234)
    with pytest.raises(TypeError):
        Settings("0.0.0.0")  # type: ignore[misc]
    with pytest.raises(AttributeError):
        c.port = 1  # type: ignore[misc]
    with pytest.raises(SettingsError, match="max_streams must be"):
        Settings(max_streams=0)


def test_connection_bounds_are_settings_checked_at_the_door(tmp_path) -> None:
    """Issue 20 item 4: the header and keep-alive timeouts and the connection cap, from a file."""
    c = Settings()
    assert (c.header_timeout_s, c.keepalive_timeout_s, c.max_connections) == (10.0, 60.0, 256)
    path = tmp_path / "s.yaml"
    path.write_text("header_timeout_s: 2\nkeepalive_timeout_s: 5\nmax_connections: 64\n")
    c = Settings.from_file(path)
    assert (c.header_timeout_s, c.keepalive_timeout_s, c.max_connections) == (2.0, 5.0, 64)
    for key, value, words in (("header_timeout_s", 0, "header_timeout_s must be > 0"),
                              ("keepalive_timeout_s", "long", "keepalive_timeout_s must be a number"),
                              ("max_connections", 2, "max_connections must be >= 4"),
                              ("max_connections", 1.5, "max_connections must be a whole number")):
        with pytest.raises(SettingsError, match=words):
            Settings(**{key: value})
