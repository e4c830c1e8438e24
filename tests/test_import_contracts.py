"""The import-linter contracts (pyproject.toml) excuse no import: a loop is broken, never ignored."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Dict

import pytest

tomllib = pytest.importorskip("tomllib")  # Python 3.11+; the contracts are checked on the dev machine

PYPROJECT = Path(__file__).resolve().parent.parent / "pyproject.toml"


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
