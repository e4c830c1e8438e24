"""Fixtures every test module may use. Keep this file generic and small.

Tests run in three environments (see README, "Test environments");
``STEREOCAM_TEST_ENV`` says which: ``current``, ``board`` or ``armhf`` (unset when
pytest is run by hand).
"""
from __future__ import annotations

import os
import re
import shutil
import sys
from pathlib import Path

import pytest

from .slowness import SLOWNESS

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = Path(__file__).resolve().parent / "data"
ARTIFACTS_DIR = REPO_ROOT / "test-artifacts"


@pytest.fixture(autouse=True)
def _clear_aiohttp_middleware_cache():
    """Let each test's aiohttp application go when the test ends.

    aiohttp keeps a module-level ``lru_cache`` of built middleware chains
    (``aiohttp.web_app._cached_build_middleware``, 1024 entries), whose keys hold the
    handler and the application: every test's app, and its overlay, fabric and emulated
    DDR with it, would otherwise stay alive until the end of the run. A 32-bit process
    (the armhf env) runs out of address space long before. Versions without the cache
    have nothing to clear; a test that never imported aiohttp has nothing there either.
    """
    yield
    web_app = sys.modules.get("aiohttp.web_app")
    cache = getattr(web_app, "_cached_build_middleware", None)
    if cache is not None and hasattr(cache, "cache_clear"):
        cache.cache_clear()


@pytest.fixture(scope="session")
def test_env() -> str:
    """The test environment's name: ``current``, ``board``, ``armhf`` or ``""`` (run by hand)."""
    return os.environ.get("STEREOCAM_TEST_ENV", "")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """``tests/data``: read-only files shipped with the tests."""
    return DATA_DIR


@pytest.fixture
def artifacts_dir(request: pytest.FixtureRequest) -> Path:
    """A fresh folder for files a person may want to look at after the run.

    ``test-artifacts/<env>/<test id>/`` at the top of the checkout (ignored by
    git), e.g. browser screenshots. Emptied at the start of the test, kept after it.
    """
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", request.node.nodeid.removeprefix("tests/"))[:120]
    env = os.environ.get("STEREOCAM_TEST_ENV") or "manual"
    path = ARTIFACTS_DIR / env / name
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True, exist_ok=True)
    return path


# -- slow tests ----------------------------------------------------------------------------------
# The fast loop (`./scripts/test --fast`: the current env, `-m "not slow"`) leaves out the tests
# marked `slow` here, and only here: those that start another program (the daemon, a browser, a
# player, a simulator, yosys, pip), drive the daemon through many frames, or time something; and
# any test given a longer timeout than the default. A run without `-m` runs every test. An entry
# is a folder ("tests/hdl/"), a module or a test (node id, all its parameters). Chosen from
# `pytest --durations=0 -m "not slow" tests/`: keep the fast loop under a minute.
SLOW = (
    "tests/hdl/",  # Verilator builds, cocotb under Verilator and Icarus, yosys
    # Chromium through playwright (their long timeouts mark them too)
    "tests/test_browser.py",
    "tests/test_browser_calibration.py",
    "tests/test_browser_cameras.py",
    "tests/test_browser_page.py",
    "tests/test_browser_record.py",
    "tests/test_browser_views.py",
    # the daemon or scripts/serve as a subprocess, players (ffmpeg, VLC, OpenCV)
    "tests/test_board_service.py",
    "tests/test_hostile_clients.py",
    "tests/test_quick_start.py",
    "tests/test_server_service.py",
    "tests/test_server_streams.py",
    "tests/test_shutdown.py",
    # benchmarks, and tests that time or load the daemon for seconds to minutes
    "tests/test_bench.py",
    "tests/test_bench_robustness.py",
    "tests/test_bench_serve.py",
    "tests/test_cpu_budget.py",
    "tests/test_faults.py",
    "tests/test_recordings.py",
    "tests/test_recordings_durable.py",  # the daemon killed with SIGKILL, restarted; a disk filled 10 times
    # the daemon in process, driven through many frames (the quicker HTTP modules stay in)
    "tests/test_fit.py",
    "tests/test_server_api.py",
    "tests/test_server_calibration.py",
    "tests/test_server_calibration_panel.py",
    "tests/test_server_cameras.py",
    # yosys, pip wheel builds
    "tests/test_hw_synth.py",
    "tests/test_packaging.py",
    # single tests of a second or more in otherwise quick modules
    "tests/test_calibrate.py::test_synthetic_rig_calibrates_back_to_its_known_model",
    "tests/test_captures_viewer.py::test_point_reads_the_disparity_map_and_gives_depth_from_q",
    "tests/test_fabric.py::test_live_frames_come_out_rectified_bit_exact",
    "tests/test_stored_folders.py::test_a_huge_frames_file_is_indexed_not_held",
    "tests/test_targets.py::test_eight_holds_calibrate_back_to_the_rigs_truth",
    "tests/test_targets.py::test_target_is_a_camera_source_of_the_rigs_true_model",
    "tests/test_vdma_emulated.py::test_timeouts_name_the_register_that_never_changed",
)


def _is_slow(item: pytest.Item, default_timeout: float) -> bool:
    nodeid = item.nodeid
    for entry in SLOW:
        if entry.endswith("/"):
            if nodeid.startswith(entry):
                return True
        elif nodeid == entry or nodeid.startswith((entry + "::", entry + "[")):
            return True
    timeout = item.get_closest_marker("timeout")
    return bool(timeout and timeout.args and float(timeout.args[0]) > default_timeout)


def _mark_slow(config: pytest.Config, items: list[pytest.Item]) -> None:
    missing = sorted({e.split("::")[0] for e in SLOW if not (REPO_ROOT / e.split("::")[0]).exists()})
    if missing:
        raise pytest.UsageError(f"SLOW (tests/conftest.py) names missing paths: {', '.join(missing)}")
    try:
        default_timeout = float(config.getini("timeout") or 0)
    except ValueError:  # no pytest-timeout: no timeout marks to compare either
        default_timeout = float("inf")
    for item in items:
        if _is_slow(item, default_timeout):
            item.add_marker(pytest.mark.slow)


def _scale_timeouts(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test's timeout (its mark's, or the ini's) times the environment's slowness.

    The timeouts are written as what an idle host needs, with room; pytest-timeout's is a hang
    detector, and a busy machine or qemu must never trip it (tests/slowness.py).
    """
    try:
        default = float(config.getini("timeout") or 0)
    except ValueError:  # no pytest-timeout
        return
    for item in items:
        mark = item.get_closest_marker("timeout")
        kwargs = dict(mark.kwargs) if mark else {}
        given = mark.args[0] if mark and mark.args else kwargs.pop("timeout", None)
        base = float(given) if given is not None else default
        if base > 0:
            item.add_marker(pytest.mark.timeout(base * SLOWNESS, **kwargs), append=False)


# -- the armhf env's subset ---------------------------------------------------------------------
# The armhf env (README, "Test environments") runs Debian's armhf Python under qemu-user, many
# times slower than the host. When pytest gets no test paths there (./scripts/test, CI), it runs
# the modules below: what 32-bit numpy, an older numpy and OpenCV could break, and needs no
# browser, ffmpeg, VLC, systemd-analyze, Verilator, Icarus or pynq. The other modules are not
# collected and the tests named in ARMHF_DESELECT are deselected: nothing there is skipped at run
# time. Any module runs there when named: STEREOCAM_ENVS=armhf ./scripts/test tests/test_x.py.
ARMHF_SUBSET = (
    # the rectify core: model, register interface, camera input, the spec
    "tests/test_model.py",
    "tests/test_rectify_core.py",
    "tests/test_camera_in_model.py",
    "tests/test_spec_doc.py",
    # DMA and memory: VDMA driver and emulation, the emulated DDR
    "tests/test_vdma_driver.py",
    "tests/test_vdma_emulated.py",
    "tests/test_ddr.py",
    "tests/test_ddr_memory.py",
    # drivers and the emulated fabric around them
    "tests/test_mt9v034_driver.py",
    "tests/test_switch.py",
    "tests/test_clock.py",
    "tests/test_emulated_sensors.py",
    "tests/test_fabric.py",
    # calibration files, YAML, profiles, config, the rectify command
    "tests/test_calibration_file.py",
    "tests/test_safe_yaml.py",
    "tests/test_board_profile.py",
    "tests/test_server_settings.py",
    "tests/test_cli_rectify.py",
    # image decoding and capture files (Pillow, zip)
    "tests/test_uploads.py",
    "tests/test_captures.py",
    "tests/test_verify.py",
    # a Python start there finds the package on PYTHONPATH, every module at its path in git
    "tests/test_python_start.py",
)
# Tests of those modules that cannot pass in the armhf env, by node id, with the reason.
ARMHF_DESELECT: dict[str, str] = {
    "tests/test_camera_in_model.py::test_demosaic_is_fast_enough_for_the_live_path":
        "a time bound for the host's CPU, not for qemu",
    "tests/test_cli_rectify.py::test_console_script_runs":
        "the project is imported from the checkout there, not pip-installed: no console script",
    # OpenCV 4.6 on armhf maps a few positions whose undistortion diverges into the image
    # (x86 builds, 4.5.5 to 5.0, saturate them far outside): 24 of 1969 compared positions in
    # the worse case. The model's own map is bit for bit the same as on x86.
    "tests/test_model.py::test_positions_match_opencv_initundistortrectifymap[400--0.3-1.0]":
        "OpenCV's armhf map, not the model, differs for diverging positions",
    "tests/test_model.py::test_positions_match_opencv_initundistortrectifymap[700--0.45-1.0]":
        "OpenCV's armhf map, not the model, differs for diverging positions",
}


def _armhf_subset_run(config: pytest.Config) -> bool:
    """Whether this run is the armhf env's subset: armhf, and no test paths on the command line."""
    if os.environ.get("STEREOCAM_TEST_ENV") != "armhf":
        return False
    args_source = getattr(pytest.Config, "ArgsSource", None)
    return args_source is None or config.args_source != args_source.ARGS


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if collection_path.is_dir() or not collection_path.name.startswith("test_"):
        return None
    if not _armhf_subset_run(config):
        return None
    try:
        rel = collection_path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return None
    return True if rel not in ARMHF_SUBSET else None


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    _mark_slow(config, items)
    _scale_timeouts(config, items)
    if not _armhf_subset_run(config):
        return
    missing = [m for m in ARMHF_SUBSET if not (REPO_ROOT / m).is_file()]
    if missing:
        raise pytest.UsageError(f"ARMHF_SUBSET (tests/conftest.py) names missing files: {', '.join(missing)}")
    dropped = [item for item in items if item.nodeid in ARMHF_DESELECT]
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = [item for item in items if item.nodeid not in ARMHF_DESELECT]


def pytest_report_header(config: pytest.Config) -> str | None:
    if not _armhf_subset_run(config):
        return None
    return (f"armhf subset: {len(ARMHF_SUBSET)} modules, {len(ARMHF_DESELECT)} tests deselected "
            "(tests/conftest.py); name test paths to run others")
