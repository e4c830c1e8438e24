"""Packaging: PEP 621 metadata, the LICENSE, ``--version``, the sdist, and the offline install on the image.

The sdist is built from a copy of the tree with setuptools' own PEP 517 hook
(what ``python -m build --sdist`` calls), the wheel from that sdist by pip
without an index or build isolation (what a board without network does), and
the wheel is installed, offline, into a fresh venv made like the PYNQ image's:
``--system-site-packages``, its dependencies already there (here: this env's
packages, minus stereocam, on a ``.pth`` path).
"""
from __future__ import annotations

import ast
import email
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Set

import pytest

import stereocam
from stereocam.server.http import systemd

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
VERSION = stereocam.__version__
README = (REPO / "README.md").read_text(encoding="utf-8")
PACKAGE = REPO / "stereocam"  # the package as it is in git: no links, no folder map
NOT_SOURCES = shutil.ignore_patterns(".venv*", ".git", "build", "dist", "*.egg-info", "test-artifacts",
                                     "__pycache__", ".*_cache", "*.pyc")
OFFLINE = {"PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PIP_NO_INPUT": "1"}


@dataclass(frozen=True)
class Dists:
    sdist: Path
    wheel: Path


def run(cmd: List[str], **kwargs) -> "subprocess.CompletedProcess[str]":
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    env.update(OFFLINE)
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=110, env=env, **kwargs)
    assert done.returncode == 0, f"{' '.join(cmd)}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def dists(tmp_path_factory: pytest.TempPathFactory) -> Dists:
    """An sdist of a copy of this tree, and the wheel pip builds from that sdist offline."""
    root = tmp_path_factory.mktemp("packaging")
    src = root / "src"
    shutil.copytree(REPO, src, ignore=NOT_SOURCES)
    hook = "import sys; from setuptools import build_meta; print(build_meta.build_sdist(sys.argv[1]))"
    name = run([sys.executable, "-c", hook, str(root / "sdist")], cwd=src).stdout.strip().splitlines()[-1]
    sdist = root / "sdist" / name
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-index", "--no-build-isolation",
         "--no-cache-dir", "-w", str(root / "wheels"), str(sdist)], cwd=root)
    wheels = list((root / "wheels").glob("*.whl"))
    assert [w.name for w in wheels] == [f"stereocam-{VERSION}-py3-none-any.whl"]
    return Dists(sdist, wheels[0])


def wheel_metadata(wheel: Path) -> email.message.Message:
    with zipfile.ZipFile(wheel) as z:
        return email.message_from_string(z.read(f"stereocam-{VERSION}.dist-info/METADATA").decode())


def test_version_is_the_packages() -> None:
    done = run([sys.executable, "-m", "stereocam.cli", "--version"])
    assert done.stdout == f"stereocam {VERSION}\n"
    assert importlib.metadata.version("stereocam") == VERSION


def test_license_is_bsd_3_clause(dists: Dists) -> None:
    text = (REPO / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License\n\nCopyright (c) ")
    assert "3. Neither the name of the copyright holder nor the names of its" in text
    meta = wheel_metadata(dists.wheel)
    assert meta["License-Expression"] == "BSD-3-Clause" and meta["License-File"] == "LICENSE"
    with zipfile.ZipFile(dists.wheel) as z:
        assert z.read(f"stereocam-{VERSION}.dist-info/licenses/LICENSE").decode() == text


def test_sdist_ships_the_package_and_no_tests(dists: Dists) -> None:
    with tarfile.open(dists.sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
        pkg_info = tar.extractfile(f"stereocam-{VERSION}/PKG-INFO").read().decode()  # type: ignore[union-attr]
    assert not any(n == "tests" or n.startswith("tests/") for n in names), "its tests need the repository"
    assert {"LICENSE", "README.md", "pyproject.toml", "setup.py", "stereocam/board/stereocam.service",
            "stereocam/board/zynq-stereo.yaml", "stereocam/server/http/static/index.html",
            "stereocam/overlays/rtl/rectify_core.v", "stereocam/cli.py"} <= names
    assert not any(n.endswith((".pyc", ".egg-info/")) or "__pycache__" in n for n in names)
    meta = email.message_from_string(pkg_info)
    assert (meta["Name"], meta["Version"]) == ("stereocam", VERSION)
    assert meta["License-Expression"] == "BSD-3-Clause"
    assert meta["Description-Content-Type"] == "text/markdown"
    assert meta.get_payload().strip() == README.strip(), "the README is the description"


def expected_files() -> Set[str]:
    """Every module of the package and its package data, as installed paths."""
    out: Set[str] = set()
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(REPO)
        if "vivado" in rel.parts or "__pycache__" in rel.parts:
            continue  # not a package: the overlay's build scripts are data
        if (path.parent / "__init__.py").exists():
            out.add(str(rel))
    out |= {f"stereocam/board/{p.name}" for p in (PACKAGE / "board").glob("*.service")}
    out |= {f"stereocam/board/{p.name}" for p in (PACKAGE / "board").glob("*.yaml")}
    static = PACKAGE / "server" / "http" / "static"
    out |= {f"stereocam/server/http/static/{p.name}" for p in static.iterdir() if p.is_file()}
    out |= {f"stereocam/overlays/rtl/{p.name}" for p in (PACKAGE / "overlays" / "rtl").glob("*.v")}
    return out


def test_the_wheel_built_offline_from_the_sdist_is_complete_and_described(dists: Dists) -> None:
    with zipfile.ZipFile(dists.wheel) as z:
        names = set(z.namelist())
        entry_points = z.read(f"stereocam-{VERSION}.dist-info/entry_points.txt").decode()
    missing = expected_files() - names
    assert not missing, sorted(missing)
    assert not any(n.startswith("tests/") for n in names)
    assert "[console_scripts]\nstereocam = stereocam.cli:main\n" in entry_points
    assert "[pynq.lib]\nstereocam-guard = stereocam.overlays.pynq.guard\n" in entry_points
    meta = wheel_metadata(dists.wheel)
    assert meta.get_payload().strip() == README.strip(), "the README is the description"
    requires = meta.get_all("Requires-Dist")
    assert "aiohttp>=3.9" in requires
    assert 'opencv-python-headless>=4.5.4; platform_machine != "armv7l"' in requires


# The package's third-party imports and the distributions that provide them.
PROVIDERS = {"numpy": "numpy", "cv2": "opencv-python-headless", "aiohttp": "aiohttp", "PIL": "pillow",
             "yaml": "pyyaml", "scipy": "scipy", "prometheus_client": "prometheus-client", "pynq": "pynq",
             "numba": "numba"}  # pynq and numba: the extras "board" and "fast" (Requires-Dist with extra ==)


def test_every_third_party_import_is_a_declared_dependency(dists: Dists) -> None:
    imported: Set[str] = set()
    for path in PACKAGE.rglob("*.py"):
        if {"rtl", "vivado", "__pycache__"} & set(path.relative_to(REPO).parts):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imported.add(node.module.split(".")[0])
    third_party = imported - set(sys.stdlib_module_names) - {"stereocam"}
    assert third_party <= set(PROVIDERS), f"say which distribution provides {third_party - set(PROVIDERS)}"
    declared = {re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].lower()
                for r in wheel_metadata(dists.wheel).get_all("Requires-Dist")}
    assert {PROVIDERS[m] for m in third_party} <= declared, sorted(declared)


def image_like_venv(root: Path) -> Path:
    """A fresh venv as on the PYNQ image (--system-site-packages) whose site already has the dependencies.

    They are this env's packages (numpy, OpenCV, aiohttp, ...) without stereocam, on a path a
    ``.pth`` file adds, as the image's system packages are.
    """
    here = Path(sysconfig.get_paths()["purelib"])
    deps = root / "image-packages"
    deps.mkdir()
    for entry in here.iterdir():
        name = entry.name.lower()
        if name.startswith(("stereocam", "__editable__")) or entry.suffix == ".pth" or name == "__pycache__":
            continue
        (deps / entry.name).symlink_to(entry)
    venv = root / "pynq-venv"
    run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)])
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = run([str(venv / "bin" / "python"), "-c", purelib])
    Path(site.stdout.strip(), "image-packages.pth").write_text(f"{deps}\n")
    return venv


def test_offline_install_on_the_image_just_works(dists: Dists, tmp_path: Path) -> None:
    readme = README
    command = "python3 -m pip install --no-index --no-build-isolation --find-links ."
    assert f"sudo /usr/local/share/pynq-venv/bin/{command} stereocam-{VERSION}-py3-none-any.whl" in readme
    venv = image_like_venv(tmp_path)
    python = str(venv / "bin" / "python3")
    run([python, *command.split()[1:], dists.wheel.name], cwd=dists.wheel.parent)  # as documented
    # Run from elsewhere than the repository: what runs is what was installed.
    version = run([str(venv / "bin" / "stereocam"), "--version"], cwd=tmp_path).stdout
    assert version == f"stereocam {VERSION}\n"
    probe = ("import stereocam.server.http.app as a, stereocam.board.profile as p, importlib.metadata as m; "
             "print(a.__file__); print(p.DEFAULT_PROFILE.is_file()); "
             "print([e.value for e in m.entry_points(group='pynq.lib')])")
    where, profile, guards = run([python, "-c", probe], cwd=tmp_path).stdout.splitlines()
    assert Path(where).is_relative_to(venv) and profile == "True"
    assert guards == "['stereocam.overlays.pynq.guard']", "pynq imports the fabric guard"
    unit = run([str(venv / "bin" / "stereocam"), "install-service", "--print"], cwd=tmp_path).stdout
    assert unit == systemd.unit_text()


def test_an_old_setuptools_is_told_to_install_the_wheel(tmp_path: Path) -> None:
    """The image's setuptools (59.6) would build a package named UNKNOWN: setup.py stops it, saying why."""
    fake = tmp_path / "old" / "setuptools"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('__version__ = "59.6.0"\n\n'
                                      'def setup():\n    raise SystemExit("built")\n')
    env: Dict[str, str] = dict(os.environ, PYTHONPATH=str(tmp_path / "old"))
    done = subprocess.run([sys.executable, str(REPO / "setup.py"), "--name"], capture_output=True, text=True,
                          env=env, cwd=tmp_path, timeout=60)
    assert done.returncode == 1
    assert done.stderr == ("building stereocam from source needs setuptools >= 77 (this one is 59.6.0): "
                           "install a stereocam wheel instead (README, 'On the board'), or pip install "
                           "'setuptools>=77' first\n")


def test_every_module_is_a_file_git_knows() -> None:
    """One path per file: what a traceback names (the module's origin) is what ``git ls-files`` lists
    (tests/project/test_python_start.py: and no link under stereocam/ gives one a second path)."""
    import importlib.util
    import pkgutil

    names = ["stereocam"] + [m.name for m in pkgutil.walk_packages(stereocam.__path__, "stereocam.")]
    origins = {Path(str(importlib.util.find_spec(n).origin)).relative_to(REPO).as_posix()  # type: ignore[union-attr]
               for n in names}
    tracked = set(subprocess.run(["git", "ls-files", "stereocam"], cwd=REPO, capture_output=True, text=True,
                                 check=True).stdout.split())
    assert origins <= tracked, sorted(origins - tracked)
    tracked_modules = {p for p in tracked
                       if p.endswith(".py") and (REPO / p).parent.joinpath("__init__.py").exists()}
    assert origins == tracked_modules
