"""``stereocam bench``: what the rectify core's software costs, each figure against a peer.

Everything is measured in one process on the same 752x480 stereo frames (4
rendered frames of the synthetic rig, all 8 channels: two cameras' RGBY) with
the same calibration. Machines are shared and absolute numbers drift, so each
headline figure is a ``ratio``: the subject's speed over its peer's, measured
in the same run (above 1: faster than the peer). Peers are timed in
alternating rounds, one call each per round with the same frame, their order
reversed every other round, so that a burst of load or a warm cache favours
neither; a figure is 1 / the median round time.

The results (named objects in the JSON, one line each in the text output):

``map_build``
    Time to turn a calibration into a running model: constructing
    ``RectifyModel(left, right, 752, 480, options)``, i.e. steps 1-4 of the
    core (homography, lens model, 1/32-pixel positions) for every output pixel
    of both cameras plus the line-buffer check. ``options`` are the ones the
    driver programs for this calibration (``LB_DELAY`` and rows from the
    line-buffer fit), so the model built is the one ``model_frame_rate`` runs.
    Peer: OpenCV building its own maps for the same calibration,
    ``cv2.initUndistortRectifyMap(K, D, R, P, size, CV_16SC2)`` for both
    cameras: the same lens model (k1, k2, p1, p2), the same rectification and
    the same map type (``CV_16SC2`` + ``CV_16UC1``, 1/32 pixel) as the model's.
``model_frame_rate``
    ``RectifyModel.process(frame, out=out)`` against :func:`opencv_remap`,
    which does the model's remap with ``cv2.remap`` and OpenCV's own maps in
    exactly the model's memory layout: the ``(H, W, 8)`` frame viewed
    as ``(H, W, 2)`` uint32 words (one camera's RGBY pixel per word), each
    camera's words copied out contiguously, remapped as ``(H, W, 4)`` uint8
    (``INTER_LINEAR``, ``BORDER_CONSTANT`` 0) into a new array, and copied back
    word by word into a preallocated output. The model's step 5 *is* OpenCV's
    fixed-point remap, so the peers differ only in whose maps they use and in
    what the model does around the remap (whatever else the core does to a
    frame, and its bookkeeping): that is what ``ratio`` measures. Each run
    checks that they give the same images: the maps agree (``map_agreement_share``:
    1 but for rare 1/32-pixel rounding ties) and the outputs are byte-identical
    wherever they agree (``identical_where_maps_agree``) on every bench frame.
``fabric_frame_rate``
    Frame pairs per second through the drivers, the emulated VDMA, mux and core
    (the virtual-camera path the daemon uses off the board), timed in the same
    rounds as ``model_frame_rate``; ``ratio`` is against the model, i.e. what
    the emulation around the model costs. The fabric returns each frame one
    call later (:data:`FABRIC_LATENCY`).
``reference``
    The per-pixel reference model (~10 s a frame): whole rows for ``seconds``,
    scaled to a frame; ``us_per_pixel`` is per output pixel position (both
    cameras, all channels); ``ratio`` is against the model. The rows it timed
    are checked against the model's output.
``cosim``
    The core's RTL under Verilator (:class:`stereocam.overlays.rtl.core.RtlCore`, the real
    colour build, programmed by the driver with the bench's calibration, streams
    without gaps) on the bench frames (the same 752x480 frames as the peers above),
    timed in alternating rounds of its own with the model: ``fps`` (frame pairs per
    second at 752x480, one ``process`` call per pair, both cameras), ``model_fps``
    (the model in those rounds), ``ratio``,
    ``clocks_per_frame`` (simulated clocks from a frame's first input beat to its
    last output beat) and ``beats_per_clock`` (output beats per clock: 0.5 is the
    core's 2 clocks per beat),
    ``sim_clocks_per_s`` (the simulator's speed) and ``equals_model`` (the RTL's
    output equals the model's on every bench frame). The first run builds the
    simulation (10-40 s, cached in ``~/.cache/stereocam/hdl/harness/``). ``null`` with a
    ``cosim_note`` saying what to install when Verilator or its tools are missing
    (the ``board`` env has no Verilator).
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING, Callable, Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .report import print_figures

if TYPE_CHECKING:  # pragma: no cover
    from ..calibration.stereo import Rectification, StereoModel
    from ..overlays.model.fast import RectifyModel
    from ..overlays.model.linebuffer import LineBufferFit
    from ..overlays.model.result import CoreOptions
    from ..overlays.spec.rectify import CameraParams

WIDTH, HEIGHT = 752, 480
CHANNELS = 8
FABRIC_LATENCY = 1  # calls: the fabric peer returns the output of the frame sent one call earlier
COSIM_NOTE = ("RTL frame pairs per second at 752x480 under Verilator (the colour build, "
              "stereocam.overlays.rtl.core.RtlCore), against the model on the same frames")
COSIM_MIN_ROUNDS = 3  # an RTL frame pair takes about 0.27 s (0.4 s with g++): enough to time, no more

Maps = List[Tuple[np.ndarray, np.ndarray]]


def bench_calibration() -> "Tuple[StereoModel, Rectification, CameraParams, CameraParams]":
    """The synthetic rig's known calibration, rectified with alpha 0: (model, rect, left, right)."""
    from ..calibration.stereo import core_cameras, rectify
    from ..overlays.emulated.render import SyntheticRig

    rig = SyntheticRig(size=(WIDTH, HEIGHT))
    try:
        model = rig.model
    finally:
        rig.close()
    rect = rectify(model, alpha=0.0)
    left, right = core_cameras(model, rect)
    return model, rect, left, right


def bench_frames(n: int = 4) -> List[np.ndarray]:
    """A few rendered frames of the synthetic rig (real image content, not noise)."""
    from ..overlays.emulated.render import SyntheticRig

    rig = SyntheticRig(size=(WIDTH, HEIGHT))
    try:
        return [np.ascontiguousarray(rig.read(i, i / 60.0)) for i in range(n)]
    finally:
        rig.close()


def bench_options(left: "CameraParams", right: "CameraParams") -> "Tuple[CoreOptions, LineBufferFit]":
    """The options the driver programs for this calibration (line-buffer rows and LB_DELAY), and the fit."""
    from ..overlays.model.linebuffer import rows_needed
    from ..overlays.model.result import CoreOptions
    from ..overlays.spec.rectify import DEFAULT_LB_ROWS

    fit = rows_needed([left, right], WIDTH, HEIGHT)
    return CoreOptions(lb_rows=max(DEFAULT_LB_ROWS, fit.rows), lb_delay=fit.delay), fit


def opencv_maps(model: "StereoModel", rect: "Rectification") -> Maps:
    """OpenCV's own ``CV_16SC2`` + ``CV_16UC1`` maps of both cameras for the calibration (map-build peer)."""
    import cv2

    return [
        cv2.initUndistortRectifyMap(K, D, R, P[:, :3], (WIDTH, HEIGHT), cv2.CV_16SC2)
        for K, D, R, P in ((model.K1, model.D1, rect.R1, rect.P1), (model.K2, model.D2, rect.R2, rect.P2))
    ]


def opencv_remap(frame: np.ndarray, maps: Maps, out: np.ndarray) -> np.ndarray:
    """The model's per-frame work done by ``cv2.remap`` with ``maps``, in the model's memory layout.

    As ``RectifyModel.process``: the ``(H, W, 8)`` uint8 frame is viewed as ``(H, W, 2)``
    uint32 words; each camera's words are copied out contiguously, remapped as ``(H, W, 4)``
    uint8 into a new array and copied back as words into ``out`` (C-contiguous, like ``frame``).
    """
    import cv2

    h, w = frame.shape[:2]
    words = np.ascontiguousarray(frame).view(np.uint32).reshape(h, w, 2)
    out_words = out.view(np.uint32).reshape(h, w, 2)
    for cam, (map1, map2) in enumerate(maps):
        src = np.ascontiguousarray(words[..., cam]).view(np.uint8).reshape(h, w, 4)
        res = cv2.remap(src, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out_words[..., cam] = res.view(np.uint32).reshape(h, w)
    return out


def map_agreement(maps: Maps, cameras: "Sequence[CameraParams]") -> np.ndarray:
    """``(H, W, 2)`` bool: where OpenCV's map of a camera gives the model's source position exactly.

    ``CV_16SC2`` holds the integer x, y and ``CV_16UC1`` the fraction index ``v * 32 + u``;
    decoded to 1/32 pixel they are compared with the model's :class:`SourceMap` (invalid
    model positions never agree).
    """
    from ..overlays.model.fast import SourceMap
    from ..overlays.spec.rectify import FRAC_BITS, FRAC_ONE

    agree = []
    for (map1, map2), params in zip(maps, cameras, strict=True):
        smap = SourceMap.compute(params, WIDTH, HEIGHT)
        frac = map2.astype(np.int64)
        iu = map1[..., 0].astype(np.int64) * FRAC_ONE + (frac & (FRAC_ONE - 1))
        iv = map1[..., 1].astype(np.int64) * FRAC_ONE + (frac >> FRAC_BITS)
        agree.append(smap.valid & (iu == smap.iu) & (iv == smap.iv))
    return np.stack(agree, axis=-1)


def identical_pixels(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(H, W, 2)`` bool: where two ``(H, W, 8)`` frames hold the same RGBY pixel of a camera."""
    h, w = a.shape[:2]
    return a.view(np.uint32).reshape(h, w, 2) == b.view(np.uint32).reshape(h, w, 2)


class FramePeers:
    """The model and its equal-layout OpenCV peer on the same frames, each with its own output buffer.

    ``run_model(i)`` and ``run_opencv(i)`` process ``frames[i % len(frames)]`` and return
    their (reused) output buffer.
    """

    def __init__(self, model: "RectifyModel", maps: Maps, frames: Sequence[np.ndarray]) -> None:
        self.model = model
        self.maps = maps
        self.frames = list(frames)
        self.model_out = np.empty_like(self.frames[0])
        self.opencv_out = np.empty_like(self.frames[0])

    def frame(self, i: int) -> np.ndarray:
        return self.frames[i % len(self.frames)]

    def run_model(self, i: int) -> np.ndarray:
        return self.model.process(self.frame(i), out=self.model_out).frame

    def run_opencv(self, i: int) -> np.ndarray:
        return opencv_remap(self.frame(i), self.maps, self.opencv_out)


@contextmanager
def fabric_peer(left: "CameraParams", right: "CameraParams",
                frames: Sequence[np.ndarray]) -> Iterator[Callable[[int], np.ndarray]]:
    """``run(i)``: send ``frames[i % n]`` through the emulated fabric's virtual camera, one frame period.

    It returns the processed frame the fabric holds then: that of the frame sent
    :data:`FABRIC_LATENCY` calls earlier.
    """
    from ..overlays.emulated.overlay import EmulatedOverlay

    with EmulatedOverlay(clock="stepped") as ov:
        ov.rectify.program(left, right, WIDTH, HEIGHT, wait=False)
        ov.step()
        ov.rectify.check_applied()
        ov.fabric.select("virtual")
        ov.step(2)

        def run(i: int) -> np.ndarray:
            ov.fabric.send_virtual(frames[i % len(frames)])
            ov.step()
            return ov.fabric.latest_processed()[1]

        yield run


class Timing(NamedTuple):
    median_s: float  # median time of one call
    rounds: int

    @property
    def rate(self) -> float:
        return 1.0 / self.median_s


def _time_rounds(peers: Dict[str, Callable[[int], object]], seconds: float,
                 min_rounds: int = 5) -> Dict[str, Timing]:
    """Time each peer in alternating rounds until ``seconds`` have passed (and ``min_rounds`` are done).

    Round ``i`` calls every peer once with ``i``, so all peers see the same frames; the order
    is reversed on odd rounds. One untimed warm-up call each (with 0) comes first.
    """
    samples: Dict[str, List[float]] = {k: [] for k in peers}
    order = list(peers.items())
    for _, fn in order:  # warm-up
        fn(0)
    deadline = time.perf_counter() + seconds
    i = 0
    while time.perf_counter() < deadline or i < min_rounds:
        for name, fn in (order if i % 2 == 0 else order[::-1]):
            t0 = time.perf_counter()
            fn(i)
            samples[name].append(time.perf_counter() - t0)
        i += 1
    return {k: Timing(statistics.median(v), len(v)) for k, v in samples.items()}


def _sig(x: float, digits: int = 4) -> float:
    """``x`` rounded to ``digits`` significant digits (ratios span 1e-4 to 10)."""
    if x == 0 or not math.isfinite(x):
        return x
    return round(x, digits - 1 - math.floor(math.log10(abs(x))))


class CosimRate(NamedTuple):
    """The RTL under Verilator on the bench frames (see ``cosim`` in the module docstring)."""

    rtl: Timing
    model: Timing  # timed in the same rounds
    clocks_per_frame: int  # median over the frames timed
    equals_model: bool  # on every bench frame it ran (the rounds' frames)

    def to_dict(self) -> Dict[str, object]:
        return {
            "fps": _sig(self.rtl.rate),
            "model_fps": _sig(self.model.rate),
            "ratio": _sig(self.rtl.rate / self.model.rate),
            "rounds": self.rtl.rounds,
            "clocks_per_frame": self.clocks_per_frame,
            "beats_per_clock": _sig(WIDTH * HEIGHT / self.clocks_per_frame),
            "sim_clocks_per_s": int(_sig(self.clocks_per_frame * self.rtl.rate)),
            "equals_model": self.equals_model,
        }


def cosim_rate(left: "CameraParams", right: "CameraParams", peers: FramePeers,
               seconds: float) -> CosimRate:
    """The RTL's frame rate on ``peers``' frames, against the model in alternating rounds.

    Raises :class:`stereocam.overlays.rtl.toolchain.ToolMissing` (saying what to install) when Verilator or
    its tools are missing; the first call builds the simulation program (cached).
    """
    from ..drivers.rectify import RectifyCore
    from ..overlays.rtl.core import RtlCore
    from ..overlays.spec.rectify import BUILDS

    with RtlCore(BUILDS["colour"], gaps=False) as rtl:
        driver = RectifyCore(rtl)
        driver.program(left, right, WIDTH, HEIGHT)
        driver.enable()
        outputs: Dict[int, np.ndarray] = {}
        clocks: List[int] = []

        def run_rtl(i: int) -> Optional[np.ndarray]:
            out = rtl.process(peers.frame(i))
            clocks.append(rtl.clocks)
            if out is not None:
                outputs[i % len(peers.frames)] = out
            return out

        timing = _time_rounds({"rtl": run_rtl, "model": peers.run_model}, seconds, COSIM_MIN_ROUNDS)
    # every frame the RTL emitted (one per call) equals the model's output of that frame
    equal = len(outputs) == min(len(peers.frames), timing["rtl"].rounds) and all(
        np.array_equal(out, peers.model.process(peers.frame(i)).frame) for i, out in outputs.items())
    return CosimRate(timing["rtl"], timing["model"], int(statistics.median(clocks)), equal)


def measure(seconds: float = 2.0) -> Dict[str, object]:
    """Every result of the module docstring; ``seconds`` per timed comparison (three of them)."""
    from ..overlays.model.fast import RectifyModel
    from ..overlays.model.reference import rectify_reference

    model_cal, rect, left, right = bench_calibration()
    frames = bench_frames()
    options, fit = bench_options(left, right)

    # Map build: calibration -> running model, against OpenCV building its maps.
    build = _time_rounds({
        "model": lambda i: RectifyModel(left, right, WIDTH, HEIGHT, options),
        "opencv": lambda i: opencv_maps(model_cal, rect),
    }, seconds)
    model = RectifyModel(left, right, WIDTH, HEIGHT, options)
    maps = opencv_maps(model_cal, rect)

    # Frame rate: model, equal-layout OpenCV remap and emulated fabric, the same frames in each round.
    peers = FramePeers(model, maps, frames)
    with fabric_peer(left, right, frames) as run_fabric:
        rate = _time_rounds({"model": peers.run_model, "opencv": peers.run_opencv, "fabric": run_fabric},
                            seconds)
    agree = map_agreement(maps, [left, right])
    identical = np.stack([identical_pixels(peers.run_model(i), peers.run_opencv(i))
                          for i in range(len(frames))])
    model_fps = rate["model"].rate

    first = model.process(frames[0])  # a fresh output: the reference's rows are checked against it
    expected = first.frame

    # The reference is ~10 s a frame: time whole rows for ``seconds`` and scale to a frame.
    rows_done = 0
    rows_equal = True
    t0 = time.perf_counter()
    while rows_done < 2 or time.perf_counter() - t0 < seconds:
        y = rows_done % HEIGHT
        ref = rectify_reference(frames[0], left, right, options, rows=range(y, y + 1))
        rows_equal &= bool(np.array_equal(ref.frame[y], expected[y]))
        rows_done += 1
    elapsed = time.perf_counter() - t0
    reference_fps = rows_done / HEIGHT / elapsed

    from ..overlays.rtl.toolchain import ToolMissing

    cosim_note = COSIM_NOTE
    try:
        cosim: Optional[Dict[str, object]] = cosim_rate(left, right, peers, seconds).to_dict()
    except ToolMissing as exc:
        cosim, cosim_note = None, f"{COSIM_NOTE}: not measured, {exc}"
    return {
        "frame": [WIDTH, HEIGHT],
        "channels": CHANNELS,
        "frames": len(frames),
        "line_buffer_rows_needed": fit.rows,
        "lb_delay": fit.delay,
        "map_build": {
            "model_ms": _sig(build["model"].median_s * 1e3),
            "opencv_ms": _sig(build["opencv"].median_s * 1e3),
            "ratio": _sig(build["opencv"].median_s / build["model"].median_s),
            "rounds": build["model"].rounds,
        },
        "model_frame_rate": {
            "model_fps": _sig(model_fps),
            "opencv_fps": _sig(rate["opencv"].rate),
            "ratio": _sig(model_fps / rate["opencv"].rate),
            "rounds": rate["model"].rounds,
            "map_agreement_share": _sig(float(agree.mean()), 6),
            "identical_share": _sig(float(identical.mean()), 6),
            "identical_where_maps_agree": bool(identical[:, agree].all()),
            "lb_overflow": first.lb_overflow,
        },
        "fabric_frame_rate": {
            "fps": _sig(rate["fabric"].rate),
            "ratio": _sig(rate["fabric"].rate / model_fps),
            "rounds": rate["fabric"].rounds,
        },
        "reference": {
            "fps": _sig(reference_fps),
            "us_per_pixel": _sig(elapsed / (rows_done * WIDTH) * 1e6),
            "ratio": _sig(reference_fps / model_fps),
            "rows_timed": rows_done,
            "equals_model": rows_equal,
        },
        "cosim": cosim,
        "cosim_note": cosim_note,
    }


def text_lines(result: Dict[str, object]) -> List[str]:
    """The text output: one line per result."""
    r = dict(result)
    lines: List[str] = []

    def add(name: str, text: str) -> None:
        lines.append(f"{name:18s} {text}")

    if "frame" in r:
        size = r.pop("frame")
        add("frames", f"{'x'.join(str(v) for v in size) if isinstance(size, list) else size}, "
                      f"{r.pop('channels', CHANNELS)} channels (two cameras' RGBY), "
                      f"{r.pop('frames', '?')} frames of the synthetic rig")
    if "line_buffer_rows_needed" in r:
        add("line buffer",
            f"{r.pop('line_buffer_rows_needed')} rows needed, LB_DELAY {r.pop('lb_delay', '?')}")
    mb = r.pop("map_build", None)
    if isinstance(mb, dict):
        add("map build", f"model {mb['model_ms']} ms, OpenCV initUndistortRectifyMap CV_16SC2 "
                         f"{mb['opencv_ms']} ms (both cameras): ratio {mb['ratio']} ({mb['rounds']} rounds)")
    fr = r.pop("model_frame_rate", None)
    if isinstance(fr, dict):
        same = "yes" if fr["identical_where_maps_agree"] else "NO"
        add("model frame rate", f"model {fr['model_fps']} fps, OpenCV remap in the same layout "
                                f"{fr['opencv_fps']} fps: ratio {fr['ratio']} ({fr['rounds']} rounds); "
                                f"identical output at {fr['identical_share']:.4%} of pixels, maps agree at "
                                f"{fr['map_agreement_share']:.4%}, identical wherever they agree: {same}")
    fb = r.pop("fabric_frame_rate", None)
    if isinstance(fb, dict):
        add("fabric frame rate", f"{fb['fps']} fps: ratio {fb['ratio']} to the model ({fb['rounds']} rounds)")
    ref = r.pop("reference", None)
    if isinstance(ref, dict):
        equal = "equal to" if ref["equals_model"] else "DIFFERENT from"
        add("reference", f"{ref['fps']} fps, {ref['us_per_pixel']} us per pixel: ratio {ref['ratio']} "
                         f"to the model ({ref['rows_timed']} rows timed, {equal} the model's)")
    if "cosim" in r:
        cosim, note = r.pop("cosim"), r.pop("cosim_note", "")
        if isinstance(cosim, dict):
            c = cosim
            same = "yes" if c["equals_model"] else "NO"
            add("cosim", f"{c['fps']} frame pairs per second at {WIDTH}x{HEIGHT} (RTL, colour build): "
                         f"ratio {c['ratio']} to the model ({c['rounds']} rounds); "
                         f"{c['clocks_per_frame']} clocks per frame ({c['beats_per_clock']} beats per "
                         f"clock), {c['sim_clocks_per_s']} simulated clocks/s; equal to the model: {same}")
        else:
            add("cosim", f"null: {note}")
    for key, value in r.items():
        add(key, json.dumps(value))
    return lines


def run_bench(args: argparse.Namespace) -> int:
    result = measure(seconds=args.seconds)
    if getattr(args, "serve", False):  # the daemon's MJPEG fan-out: stereocam/bench/serve.py
        from .serve import ServeBenchError, measure_serve

        try:
            result["serve"] = measure_serve(seconds=args.serve_seconds)
        except ServeBenchError as exc:
            print(f"stereocam bench: error: serve: {exc}", file=sys.stderr)
            return 2
    print_figures(result, args.json, text_lines)
    return 0
