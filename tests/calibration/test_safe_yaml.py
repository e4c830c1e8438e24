"""Hostile YAML is refused before it is expanded: aliases, deep nesting, huge text; in every file we read."""
from __future__ import annotations

import time
from pathlib import Path

import pytest

from stereocam.board.profile import ProfileError, load_profile
from stereocam.calibration.file import CalibrationFileError, load_calibration, parse_yaml
from stereocam.calibration.safe_yaml import MAX_DEPTH, YamlRefused, load
from stereocam.server.http.settings import Settings, SettingsError

pytestmark = pytest.mark.armhf


@pytest.fixture(params=["libyaml", "python"], autouse=True)
def parser(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Every test runs with PyYAML's C parser (the board's) and the pure-Python one (where it is missing)."""
    import yaml

    if request.param == "python":
        monkeypatch.delattr(yaml, "CSafeLoader", raising=False)
    else:
        assert hasattr(yaml, "CSafeLoader"), "this environment's PyYAML has no libyaml"
    return str(request.param)


def alias_bomb(levels: int = 12, width: int = 10) -> str:
    """The "billion laughs": ``width ** levels`` leaves from a few hundred bytes."""
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


def test_an_alias_is_refused_before_anything_is_expanded() -> None:
    text = alias_bomb()
    assert len(text) < 2048
    start = time.monotonic()
    with pytest.raises(YamlRefused, match=r"^line 2: YAML aliases \(\*a0\) are not accepted"):
        load(text)
    assert time.monotonic() - start < 5  # expanding 10**12 leaves would take hours, not seconds


def test_nesting_is_limited() -> None:
    ok = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    nested = load(ok)
    for _ in range(MAX_DEPTH - 1):
        nested = nested[0]
    assert nested == []
    block = "".join(f"{' ' * i}k:\n" for i in range(200)) + " " * 200 + "v"
    for deep in ("[" * 100_000 + "]" * 100_000, block):
        with pytest.raises(YamlRefused, match="nested more than 32 levels deep|nested too deeply"):
            load(deep)


def test_size_and_syntax_are_one_line_refusals() -> None:
    with pytest.raises(YamlRefused, match="^2,001 characters, more than the 2,000 accepted$"):
        load("x" * 2001, max_chars=2000)
    with pytest.raises(YamlRefused, match=r"^not valid YAML: line 1, column 5: mapping values are not"):
        load("a: b: c")
    assert load("a: [1, 2]\nb: {c: 3.5}\n") == {"a": [1, 2], "b": {"c": 3.5}}


def test_every_yaml_reader_refuses_the_bomb(tmp_path: Path) -> None:
    bomb = alias_bomb()
    with pytest.raises(CalibrationFileError, match="YAML aliases"):
        parse_yaml("schema_version: 2\n" + bomb, where="calibration")
    for name, prefix, call, error in (
        ("c.yaml", "", lambda p: Settings.from_file(p), SettingsError),
        ("profile.yaml", "", lambda p: load_profile(p), ProfileError),
        ("left.yaml", "# a ROS camera_matrix file\n",
         lambda p: load_calibration(f"{p},{p}", image_size=(752, 480)), CalibrationFileError),
    ):
        path = tmp_path / name
        path.write_text(prefix + bomb)
        line = 2 + prefix.count("\n")
        with pytest.raises(error, match=rf"{name}: line {line}: YAML aliases \(\*a0\) are not accepted"):
            call(path)
