"""The import-linter contracts (pyproject.toml) excuse no import: a loop is broken, never ignored;
and the daemon's state keys have one style."""
from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from typing import Any, Dict

from aiohttp import web

try:
    import tomllib
except ImportError:  # Python 3.10 (the board env): pytest's own dependency, the same parser
    import tomli as tomllib  # type: ignore[no-redef]

import stereocam.server.http

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def _importlinter() -> Dict[str, Any]:
    with PYPROJECT.open("rb") as f:
        config: Dict[str, Any] = tomllib.load(f)["tool"]["importlinter"]
    return config


def test_no_contract_ignores_an_import() -> None:
    config = _importlinter()
    assert "ignore_imports" not in config
    for contract in config["contracts"]:
        assert "ignore_imports" not in contract, (
            f"contract {contract['name']!r} ignores imports: break the loop instead "
            f"({contract['ignore_imports']})")


def test_the_http_modules_import_no_loop() -> None:
    acyclic = [c for c in _importlinter()["contracts"] if c["type"] == "acyclic_siblings"]
    assert any("stereocam.server.http" in c["ancestors"] for c in acyclic)


def test_every_app_key_names_its_type_and_the_package() -> None:
    """One style for every ``web.AppKey`` of server/http: ``AppKey("stereocam.<what>", Type)``."""
    keys = {}
    for info in pkgutil.iter_modules(stereocam.server.http.__path__, "stereocam.server.http."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, web.AppKey) and value._name.startswith(info.name + "."):  # declared here
                keys[f"{info.name}.{name}"] = value
    assert len(keys) > 15
    for where, key in keys.items():
        module = where.rsplit(".", 1)[0]
        given = key._name[len(module) + 1:]  # aiohttp puts the declaring module in front
        assert given.startswith("stereocam."), f"{where}: name it AppKey('stereocam.<what>', T): {given!r}"
        assert getattr(key, "_t", None) is not None, f"{where}: give the AppKey its type"
