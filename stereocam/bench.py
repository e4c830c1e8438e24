"""``stereocam bench``: throughput of the model, the reference, the emulated fabric and OpenCV.

Everything is measured in one process on the same 752x480 stereo frames (all
8 channels) with the same calibration, and the headline figure is a ratio
against a peer measured in the same run (``ratio`` = model / OpenCV remap),
because the machines are shared and absolute numbers drift. Peers are timed
in alternating rounds so that a burst of load hits both.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from typing import TYPE_CHECKING, Callable, Dict, List, Tuple

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .overlays.spec.rectify import CameraParams
    from .stereo import Rectification, StereoModel

WIDTH, HEIGHT = 752, 480


def bench_calibration() -> "Tuple[StereoModel, Rectification, CameraParams, CameraParams]":
    """The synthetic rig's known calibration, rectified with alpha 0: (model, rect, left, right)."""
    from .overlays.emulated.cameras import SyntheticRig
    from .stereo import core_cameras, rectify

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
    from .overlays.emulated.cameras import SyntheticRig

    rig = SyntheticRig(size=(WIDTH, HEIGHT))
    try:
        return [np.ascontiguousarray(rig.read(i, i / 60.0)) for i in range(n)]
    finally:
        rig.close()


def _time_rounds(peers: Dict[str, Callable[[int], None]], seconds: float) -> Dict[str, float]:
    """Frames per second of each peer, alternating short rounds until ``seconds`` have passed.

    Each round times one call per peer; the result is 1 / median(round time).
    """
    samples: Dict[str, List[float]] = {k: [] for k in peers}
    for fn in peers.values():  # warm-up
        fn(0)
    deadline = time.perf_counter() + seconds
    i = 0
    while time.perf_counter() < deadline or min(len(v) for v in samples.values()) < 5:
        for name, fn in peers.items():
            t0 = time.perf_counter()
            fn(i)
            samples[name].append(time.perf_counter() - t0)
        i += 1
    return {k: 1.0 / statistics.median(v) for k, v in samples.items()}


def measure(seconds: float = 2.0) -> Dict[str, object]:
    import cv2

    from .overlays.model.fast import RectifyModel
    from .overlays.model.linebuffer import rows_needed
    from .overlays.model.reference import rectify_reference
    from .overlays.model.result import CoreOptions
    from .overlays.spec.rectify import DEFAULT_LB_ROWS

    model_cal, rect, left, right = bench_calibration()
    frames = bench_frames()
    fit = rows_needed([left, right], WIDTH, HEIGHT)
    options = CoreOptions(lb_rows=max(DEFAULT_LB_ROWS, fit.rows), lb_delay=fit.delay)
    model = RectifyModel(left, right, WIDTH, HEIGHT, options)
    out = np.empty_like(frames[0])

    maps = [
        cv2.initUndistortRectifyMap(K, D, R, P[:, :3], (WIDTH, HEIGHT), cv2.CV_16SC2)
        for K, D, R, P in ((model_cal.K1, model_cal.D1, rect.R1, rect.P1), (model_cal.K2, model_cal.D2, rect.R2, rect.P2))
    ]
    cv_out = np.empty_like(frames[0])

    def run_model(i: int) -> None:
        model.process(frames[i % len(frames)], out=out)

    def run_opencv(i: int) -> None:
        frame = frames[i % len(frames)]
        for cam, (m1, m2) in enumerate(maps):
            src = np.ascontiguousarray(frame[..., 4 * cam:4 * cam + 4])
            cv_out[..., 4 * cam:4 * cam + 4] = cv2.remap(src, m1, m2, cv2.INTER_LINEAR,
                                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    fps = _time_rounds({"model": run_model, "opencv": run_opencv}, seconds)
    run_opencv(0)
    agree = float(np.mean(model.process(frames[0]).frame == cv_out))

    # The reference is ~10 s a frame: time whole rows for ``seconds`` and scale to a frame.
    rows_done = 0
    t0 = time.perf_counter()
    while rows_done < 2 or time.perf_counter() - t0 < seconds:
        rectify_reference(frames[0], left, right, options, rows=range(rows_done % HEIGHT, rows_done % HEIGHT + 1))
        rows_done += 1
    reference_fps = rows_done / HEIGHT / (time.perf_counter() - t0)

    fabric = measure_fabric(left, right, frames, seconds)
    return {
        "frame": [WIDTH, HEIGHT],
        "channels": 8,
        "model_fps": round(fps["model"], 2),
        "reference_fps": round(reference_fps, 4),
        "reference_rows_timed": rows_done,
        "fabric_fps": round(fabric, 2),
        "opencv_remap_fps": round(fps["opencv"], 2),
        "ratio": round(fps["model"] / fps["opencv"], 3),
        "model_equals_opencv_share": round(agree, 5),
        "line_buffer_rows_needed": fit.rows,
    }


def measure_fabric(left: "CameraParams", right: "CameraParams", frames: List[np.ndarray], seconds: float) -> float:
    """Frame pairs per second through the drivers, emulated VDMA, mux and core (virtual camera path)."""
    from .overlays.emulated.overlay import EmulatedOverlay

    with EmulatedOverlay(clock="stepped") as ov:
        ov.rectify.program(left, right, WIDTH, HEIGHT, wait=False)
        ov.step()
        ov.rectify.check_applied()
        ov.fabric.select("virtual")
        ov.step(2)
        n = 0
        t0 = time.perf_counter()
        while n < 3 or time.perf_counter() - t0 < seconds:
            ov.fabric.send_virtual(frames[n % len(frames)])
            ov.step()
            ov.fabric.latest_processed()
            n += 1
        return n / (time.perf_counter() - t0)


def run_bench(args: argparse.Namespace) -> int:
    result = measure(seconds=args.seconds)
    if getattr(args, "serve", False):  # the daemon's MJPEG fan-out: stereocam/bench_serve.py
        from .bench_serve import ServeBenchError, measure_serve

        try:
            result["serve"] = measure_serve(seconds=args.serve_seconds)
        except ServeBenchError as exc:
            print(f"stereocam bench: error: serve: {exc}", file=sys.stderr)
            return 2
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:28s} {value}")
    sys.stdout.flush()
    return 0
