"""The camera input's clock-domain crossings under injected skew (issue 22, item 2, "Safe crossings").

Built with ``CI_SKEW_SIM``, every ``ci_sync`` delays each bit's change by 0 or 1 destination clocks at
random (``stereocam/overlays/rtl/camera/ci_sync.v``), and ``tb_camera_in_skew.py`` compares the whole
stream with the model over 62 frames (22 of 64 x 10, 40 of 6 x 10; aclk 142.9 MHz, pixel clocks 24.4
and 25.6 MHz) with random and bursty backpressure, while a monitor checks that every pointer sample on
each side is a value its source held, in order. Measured on today's RTL: 0 of 16,480 beats differ,
0 bad samples. The RTL before the fix (its ``camera_in.v`` and ``ci_lfifo.v``, today's undone by
``tests/hdl/data/unsafe_crossings.patch``, with today's ``ci_rx.v`` and skew-injecting ``ci_sync.v``),
same bench and skew, is a standing check that the test sees what it is for: 2,400 beats differ,
56 frames of 62 come out (several cut short, the rest shifted), with 364 write-pointer and 1,041
read-pointer samples no source value explains.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from stereocam.overlays.spec import camera_in as spec

from .cocotb_run import run_cocotb
from .test_camera_in_rtl import FULL, camera_dir, camera_sources

# The crossings' fix undone: a patch from today's camera_in.v and ci_lfifo.v back to the RTL before it
# (line-sized gray jumps, ungated reads; commit 876e7d9), so a clone of any depth runs the comparison.
UNSAFE_PATCH = Path(__file__).parent / "data" / "unsafe_crossings.patch"
UNSAFE_FILES = ("camera_in.v", "ci_lfifo.v")
REGENERATE = ("git diff HEAD 876e7d9 -- stereocam/overlays/rtl/camera/camera_in.v "
              "stereocam/overlays/rtl/camera/ci_lfifo.v > tests/hdl/data/unsafe_crossings.patch")


def unsafe_sources(folder: Path) -> list[Path]:
    """The camera input's sources with the crossings' fix undone, in ``folder``."""
    for name in UNSAFE_FILES:
        shutil.copy(camera_dir() / name, folder / name)
    # outside a repository, git apply is a plain patch tool; -p5 strips a/stereocam/overlays/rtl/camera/
    done = subprocess.run(["git", "apply", "-p5", str(UNSAFE_PATCH)], cwd=folder, capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0, (f"{UNSAFE_PATCH.name} no longer applies to today's RTL "
                                  f"({done.stderr.strip()}); regenerate it: {REGENERATE}")
    return [folder / p.name if p.name in UNSAFE_FILES else p for p in camera_sources()]


def run_skew(sources: list[Path], expect: str, out_dir: Path) -> dict[str, object]:
    """Build ``sources`` with CI_SKEW_SIM (Verilator, MAX_WIDTH 64), run the skew bench: its numbers."""
    result = out_dir / "skew.json"
    env = {"STEREOCAM_CI_MAX_WIDTH": "64", "COCOTB_RANDOM_SEED": "1", "STEREOCAM_SKEW_EXPECT": expect,
           "STEREOCAM_SKEW_RESULT": str(result), "COCOTB_TEST_FILTER": r"tb_camera_in_skew\.skewed_frames$"}
    if FULL:
        env["STEREOCAM_COSIM_FULL"] = "1"
    run_cocotb(spec.TOP, sources, "tb_camera_in_skew", sim="verilator", parameters={"MAX_WIDTH": 64},
               defines={"CI_SKEW_SIM": 1}, includes=[camera_dir()], extra_env=env, test_dir=out_dir)
    numbers: dict[str, object] = json.loads(result.read_text())
    print(f"{expect}: {numbers}")
    return numbers


@pytest.mark.timeout(1800)
def test_skewed_crossings_are_bit_exact(tmp_path: Path) -> None:
    """0 differing beats over at least 20 whole frames with random backpressure and skewed crossings."""
    numbers = run_skew(camera_sources(), "exact", tmp_path)
    assert numbers["differing_beats"] == 0
    assert numbers["frames_got"] == numbers["frames_want"] == numbers["frames_sent"]
    assert isinstance(numbers["frames_got"], int) and numbers["frames_got"] >= 20
    assert numbers["bad_pointer_samples"] == {"wptr": 0, "rptr": 0}


@pytest.mark.timeout(1800)
def test_the_unsafe_rtl_slips_under_the_same_skew(tmp_path: Path) -> None:
    """The RTL before the fix, same bench and skew: its stream slips (beats differ from the model), and its
    crossings deliver pointer values their sources never held."""
    old = tmp_path / "unsafe"
    old.mkdir()
    sources = unsafe_sources(old)
    numbers = run_skew(sources, "slips", tmp_path)
    bad = numbers["bad_pointer_samples"]
    assert isinstance(bad, dict) and sum(bad.values()) > 0
    assert isinstance(numbers["differing_beats"], int) and numbers["differing_beats"] > 0


def test_synchronisers_are_async_reg_and_the_skew_is_simulation_only() -> None:
    """Both flops of ci_sync carry ASYNC_REG; the skew injection is inside `ifdef CI_SKEW_SIM; no other
    module of the IP samples another clock's signal without a ci_sync (each crossing's source
    register feeds a ci_sync instance)."""
    text = (camera_dir() / "ci_sync.v").read_text()
    assert '(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] meta_reg' in text
    assert '(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] sync_reg' in text
    inside = text[text.index("`ifdef CI_SKEW_SIM"):text.index("`else")]
    assert "$random" in inside and text.count("$random") == inside.count("$random")
    lfifo = (camera_dir() / "ci_lfifo.v").read_text()
    for source in ("wgray_reg", "rhold_reg", "rreq_reg", "wack_reg"):
        assert f".in({source})" in lfifo, source
    top = (camera_dir() / "camera_in.v").read_text()
    assert ".tag_gray(tag_gray_reg)" in top and "tag_sync_inst (.clk(pclk), .in(tag_gray)" in (
        camera_dir() / "ci_rx.v").read_text()
