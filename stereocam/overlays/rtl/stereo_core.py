"""The stereo core's RTL, compiled by Verilator, as a function of a rectified gray pair.

:class:`RtlStereo` runs ``stereo_core`` (``stereocam/overlays/rtl/stereo/``) in the harness program
the rectify core's :class:`~stereocam.overlays.rtl.core.RtlCore` uses (``sim/harness.cpp``, built
for the other top by :func:`build_stereo_harness`): Python hands it the register writes and a whole
frame, every AXI handshake happens in the program. :meth:`RtlStereo.compute` has the model's
signature (``stereocam/overlays/model/stereo.py: compute``) and returns the same
:class:`StereoResult`, so the two can be compared frame for frame.

The core takes ``MAX_DISP / PARALLEL`` clocks a pixel (4 in the ``depth`` build) and a few rows
of sweeps a frame: 4.16 clocks a pixel at 752x480 with 128 disparities, 1.5 million clocks. Under
Verilator that pair takes 4.3 s of the harness's CPU (0.23 pairs a second; 8 s of wall time on
this machine's two shared cores), the program 12 s to build, cached after (``stereocam bench depth
--rtl`` measures it). The harness evaluates each clock's low phase too, because the core's input
TREADY follows TUSER through logic (``registered_outputs=False``).
"""
from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Dict, List, Optional, Sequence, Type

import numpy as np

from ..model.stereo_result import StereoResult, check_pair
from ..spec import stereo as spec
from ..spec.rectify import RECTIFY_MAP
from . import toolchain as hdl
from .core import HarnessBuild, RtlCore, RtlError, build_harness

__all__ = ["RtlStereo", "build_stereo_harness", "stereo_sources", "stereo_parameters", "RtlError"]

TOP = "stereo_core"
_MAP = spec.STEREO_MAP
_CONTROL = _MAP["CONTROL"]
_FLAGS = _MAP["FLAGS"]
# The harness asks STATUS.BUSY at the rectify core's offset: the two cores share it.
assert (_MAP["STATUS"].offset, _MAP["STATUS"].bit("BUSY")) == (
    RECTIFY_MAP["STATUS"].offset, RECTIFY_MAP["STATUS"].bit("BUSY"))
assert _MAP.size == RECTIFY_MAP.size and _CONTROL.offset == RECTIFY_MAP["CONTROL"].offset


def stereo_sources() -> List[Path]:
    """The stereo core's Verilog and headers, the two rectify-core parts it instantiates and the
    prelude every RTL file includes."""
    rtl = hdl.rtl_dir()
    stereo = rtl / "stereo"
    shared = ["rc_ram.v", "rc_fifo.v", "prelude.vh"]
    return sorted([*stereo.glob("*.v"), *stereo.glob("*.vh")]) + [rtl / name for name in shared]


def stereo_parameters(build: spec.Build) -> Dict[str, int]:
    """The Verilog parameters of ``stereo_core`` for ``build``."""
    return {"MAX_WIDTH": build.max_width, "MAX_HEIGHT": build.max_height,
            "MAX_DISP": build.max_disp, "PARALLEL": build.parallel}


def build_stereo_harness(build: spec.Build = spec.DEFAULT_BUILD, *, jobs: int = 2,
                         sources: Optional[Sequence[Path]] = None,
                         root: Optional[Path] = None) -> HarnessBuild:
    """The harness program for ``stereo_core`` of ``build`` (cached like the rectify core's).

    ``stereo_core``'s input TREADY depends on TUSER through logic only, so the harness
    settles it before sampling (``registered_outputs=False``).
    """
    if build.max_disp != 4 * build.parallel:
        raise ValueError(f"build {build.name}: MAX_DISP ({build.max_disp}) must be 4 x PARALLEL "
                         f"({build.parallel}): the core's slots are 4 clocks")
    return build_harness(None, top=TOP, parameters=stereo_parameters(build),
                         sources=sources if sources is not None else stereo_sources(),
                         registered_outputs=False, root=root, jobs=jobs)


def stream_frame(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The core's input: the rectify core's 64-bit pixels, left gray in byte 3, right in byte 7."""
    h, w = left.shape
    frame = np.zeros((h, w, 8), np.uint8)
    frame[:, :, spec.IN_LEFT_GRAY_BYTE] = left
    frame[:, :, spec.IN_RIGHT_GRAY_BYTE] = right
    return frame


class RtlStereo:
    """``stereo_core`` of ``build`` under Verilator, a pair at a time (see the module docstring).

    ``gaps``: random TVALID gaps on the input and TREADY backpressure on the output (from
    ``seed``; None picks one, kept in :attr:`seed`), to exercise the handshakes.
    """

    def __init__(self, build: spec.Build = spec.DEFAULT_BUILD, *, gaps: bool = False,
                 seed: Optional[int] = None, jobs: int = 2, sources: Optional[Sequence[Path]] = None) -> None:
        self.build = build
        program = build_stereo_harness(build, jobs=jobs, sources=sources)
        self._sim = RtlCore(seed=seed, gaps=gaps, program=program)
        self.seed = self._sim.seed
        self.gaps = gaps
        self.harness = program
        self.clocks = 0  # of the last frame, first beat offered to last beat moved
        try:
            ident = self._sim.read(_MAP.offset("ID"))
            if ident != spec.CORE_ID:
                raise RtlError(f"{program.executable} reads ID {ident:#010x}, not the stereo core's "
                               f"{spec.CORE_ID:#010x}: rebuild it (remove {program.directory})")
            names = ("MAX_WIDTH", "MAX_HEIGHT", "MAX_DISP", "PARALLEL")
            got = tuple(self._sim.read(_MAP.offset(n)) for n in names)
            want = (build.max_width, build.max_height, build.max_disp, build.parallel)
            if got != want:
                raise RtlError(f"the simulated core reads back build {got}, not {want} ({build.name})")
        except BaseException:
            self._sim.close()
            raise

    def read(self, offset: int) -> int:
        return self._sim.read(offset)

    def write(self, offset: int, value: int) -> None:
        self._sim.write(offset, value)

    def program(self, params: spec.StereoParams, width: int, height: int) -> None:
        """Write the size and ``params``, then ENABLE and APPLY; RtlError if the core refuses them."""
        words = spec.register_values(params)
        self.write(_MAP.offset("WIDTH"), width)
        self.write(_MAP.offset("HEIGHT"), height)
        for reg in spec.PARAM_REGISTERS.values():
            self.write(_MAP.offset(reg), words[reg])
        self.write(_CONTROL.offset, words["CONTROL"] | _CONTROL.bit("ENABLE") | _CONTROL.bit("APPLY"))
        self._check_flags("after APPLY")

    def _check_flags(self, when: str) -> None:
        flags = self.read(_FLAGS.offset)
        if flags:
            self.write(_FLAGS.offset, flags)
            names = [f.name for f in _FLAGS.fields if flags >> f.lsb & 1] or [f"{flags:#x}"]
            raise RtlError(f"the stereo core raised {', '.join(names)} {when} (FLAGS {flags:#x}, "
                           f"now cleared; seed {self.seed})")

    def compute(self, left: np.ndarray, right: np.ndarray,
                params: spec.StereoParams = spec.DEFAULT_PARAMS) -> StereoResult:
        """The RTL's output for a rectified gray pair, as the model's ``compute`` returns it.

        ValueError (what to change) for a pair or parameters the build refuses; RtlError when
        the core misbehaves (wrong frame shape, a sticky error in FLAGS, a stall).
        """
        check_pair(left, right, params, self.build)
        h, w = left.shape
        self.program(params, w, h)
        # 4 clocks a pixel and the sweeps, heavy backpressure with gaps: 40 a pixel is generous.
        limit = 40 * (h + 8) * max(w, 64) + 1_000_000
        out = self._sim.process(stream_frame(left, right), max_clocks=limit)
        run = self._sim.last
        self.clocks = run.clocks
        self._check_flags("during the frame")
        if out is None or run.end != "idle" or len(run.emitted) != 1:
            raise RtlError(f"the stereo core completed {len(run.emitted)} frames for one {w}x{h} pair "
                           f"(end {run.end!r}, {run.beats_in} beats in, {run.beats_out} out; "
                           f"seed {self.seed})")
        if out.shape[:2] != (h, w):
            raise RtlError(f"the stereo core emitted a {out.shape[1]}x{out.shape[0]} frame for a "
                           f"{w}x{h} pair (seed {self.seed})")
        beats = np.ascontiguousarray(out).view("<u8")[:, :, 0]
        if int(beats.max(initial=0)) >> spec.OUT_BEAT_BITS:
            raise RtlError(f"output beats wider than {spec.OUT_BEAT_BITS} bits (seed {self.seed})")
        return StereoResult.from_beats(beats.astype(np.uint32))

    @property
    def clocks_per_pixel(self) -> float:
        """The last frame's clocks per pixel (from :attr:`clocks`)."""
        beats = self._sim.last.beats_out
        return self.clocks / beats if beats else 0.0

    def cpu_seconds(self) -> Optional[float]:
        """CPU time of the harness program so far (see :meth:`RtlCore.cpu_seconds`)."""
        return self._sim.cpu_seconds()

    def close(self) -> None:
        self._sim.close()

    def __enter__(self) -> "RtlStereo":
        return self

    def __exit__(self, exc_type: Optional[Type[BaseException]], exc: Optional[BaseException],
                 tb: Optional[TracebackType]) -> None:
        self.close()

    def __repr__(self) -> str:
        b = self.build
        return (f"RtlStereo({b.name}: {b.max_width}x{b.max_height}, {b.max_disp} disparities, "
                f"{b.parallel} a clock, gaps={self.gaps}, seed={self.seed})")
