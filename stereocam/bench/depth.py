"""``stereocam bench depth``: the stereo core's model, its speed and its accuracy, beside OpenCV's matchers.

Speed: each model path (compiled, numpy) and OpenCV's StereoBM (the daemon's ARM disparity today)
and StereoSGBM, timed in alternating rounds on the same 752x480 gray pairs of the synthetic rig
with 128 disparities, one call per pair each (``fps``, and ``ratio`` against StereoSGBM).

Accuracy (``--pairs DIR``): every folder of DIR in Middlebury 2014's layout (``im0.png``,
``im1.png``, ``disp0GT.pfm``, ``mask0nocc.png``, ``calib.txt``) is matched by the model and by
both OpenCV matchers on the same 8-bit gray pair (the core's gray, :func:`spec.pixel.gray_of`),
each with the scene's ``ndisp`` rounded up to a range it accepts (a multiple of the core's
PARALLEL for the model, of 16 for OpenCV). Over the non-occluded pixels with ground truth (mask
255): ``bad-1.0`` and ``bad-2.0``, the share whose disparity is off by more than 1 or 2 pixels or
missing, and ``density``, the share with a disparity. The floor: the model's mean bad-2.0 at most
StereoSGBM's in the same run, its density at least 85 %, and its speed at least 5 pairs a second.

RTL (``--rtl``): the stereo core's Verilog (the ``depth`` build: 752 px, 128 disparities, 32 a
clock) under Verilator (:class:`stereocam.overlays.rtl.stereo_core.RtlStereo`), on the same pairs
after the speed rounds, one pair after another: pairs a second (wall time of a pair, the harness
program doing the work; median; and ``fps_cpu`` from the program's CPU time, which a loaded machine
changes less), the clocks a pixel the core took (first input beat to last output
beat over the pixels; the design's own rate, whatever the simulator's), whether every output beat
equals the model's, and the program's build time (once, then cached). Not by default: a pair takes
seconds (4.3 s of CPU, 8 s of wall time, measured on this machine's 2 loaded cores; 4.16 clocks
a pixel) and the first build 10-60 s.
"""
from __future__ import annotations

import argparse
import math
import re
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple, Type

import numpy as np

from ..overlays.model import stereo as model
from ..overlays.spec import stereo as spec
from ..overlays.spec.pixel import gray_of
from .report import run_suite

FLOOR_FPS = 5.0
FLOOR_DENSITY = 0.85
WIDTH, HEIGHT = 752, 480
#: OpenCV StereoSGBM as issue 23 measured it: 3-way, block 5, P1 8*25, P2 32*25, uniqueness 10.
SGBM = {"blockSize": 5, "P1": 8 * 25, "P2": 32 * 25, "uniquenessRatio": 10}
#: OpenCV StereoBM as the daemon runs it today (server/frames/views.py, the paper's parameters).
BM = {"blockSize": 19, "uniquenessRatio": 15}

Matcher = Callable[[np.ndarray, np.ndarray, int], np.ndarray]  # gray pair, range -> disparity px (NaN: none)


class DepthBenchError(Exception):
    """The benchmark could not measure (a folder without pairs, an unreadable file)."""


def opencv_sgbm(left: np.ndarray, right: np.ndarray, num_disp: int) -> np.ndarray:
    import cv2

    m = cv2.StereoSGBM.create(minDisparity=0, numDisparities=num_disp, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
                              **SGBM)
    return _opencv_pixels(m.compute(left, right))


def opencv_bm(left: np.ndarray, right: np.ndarray, num_disp: int) -> np.ndarray:
    import cv2

    m = cv2.StereoBM.create(numDisparities=num_disp, blockSize=BM["blockSize"])
    m.setUniquenessRatio(BM["uniquenessRatio"])
    return _opencv_pixels(m.compute(left, right))


def _opencv_pixels(disp16: np.ndarray) -> np.ndarray:
    out = disp16.astype(np.float32) / 16.0
    out[disp16 < 0] = np.nan
    return out


def model_matcher(path: str) -> Matcher:
    def run(left: np.ndarray, right: np.ndarray, num_disp: int) -> np.ndarray:
        params = spec.DEFAULT_PARAMS.with_values(num_disp=num_disp)
        return model.compute(left, right, params, path=path).pixels()
    return run


def _round_up(n: int, step: int) -> int:
    return max(step, -(-n // step) * step)


# -- Middlebury ------------------------------------------------------------------------------------

def read_pfm(path: Path) -> np.ndarray:
    """A PFM image (Middlebury's ground truth): float32, top row first, infinity where unknown."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        if kind not in (b"Pf", b"PF"):
            raise DepthBenchError(f"{path}: not a PFM file (starts {kind[:8]!r})")
        dims = f.readline().split()
        scale = float(f.readline())
        w, h = int(dims[0]), int(dims[1])
        channels = 3 if kind == b"PF" else 1
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4", count=w * h * channels)
    img = data.reshape(h, w, channels) if channels == 3 else data.reshape(h, w)
    return np.flipud(img).astype(np.float32)


def read_ndisp(path: Path) -> int:
    match = re.search(r"^ndisp\s*=\s*(\d+)", path.read_text(), re.MULTILINE)
    if not match:
        raise DepthBenchError(f"{path}: no ndisp line")
    return int(match.group(1))


def scenes(folder: Path) -> List[Path]:
    found = sorted(p for p in folder.iterdir() if (p / "im0.png").is_file()) if folder.is_dir() else []
    if not found:
        raise DepthBenchError(f"{folder}: no scene folders with im0.png, im1.png, disp0GT.pfm, "
                              "mask0nocc.png and calib.txt")
    return found


def load_scene(folder: Path) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    from PIL import Image

    try:
        imgs = [np.asarray(Image.open(folder / n).convert("RGB")) for n in ("im0.png", "im1.png")]
        gt = read_pfm(folder / "disp0GT.pfm")
        mask = np.asarray(Image.open(folder / "mask0nocc.png").convert("L"))
        ndisp = read_ndisp(folder / "calib.txt")
    except (OSError, ValueError) as exc:
        raise DepthBenchError(f"{folder}: {exc}") from exc
    return gray_of(imgs[0]), gray_of(imgs[1]), gt, mask, ndisp


def score(disp: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> Dict[str, float]:
    """bad-1.0, bad-2.0 and density over the non-occluded pixels with ground truth (a missing one is bad)."""
    use = (mask == 255) & np.isfinite(gt)
    d = disp[use]
    g = gt[use]
    valid = np.isfinite(d)
    err = np.where(valid, np.abs(np.where(valid, d, 0) - g), np.inf)
    n = max(int(use.sum()), 1)
    return {"bad_1": float((err > 1.0).sum() / n), "bad_2": float((err > 2.0).sum() / n),
            "density": float(valid.sum() / n)}


def accuracy(folder: Path, matchers: Dict[str, Tuple[Matcher, int]]) -> Dict[str, Any]:
    """Per scene and mean scores of each matcher (``name -> (matcher, range step)``)."""
    per: Dict[str, Dict[str, Dict[str, float]]] = {}
    for scene in scenes(folder):
        left, right, gt, mask, ndisp = load_scene(scene)
        if left.shape[1] > spec.DEFAULT_BUILD.max_width:
            raise DepthBenchError(f"{scene}: {left.shape[1]} px wide, wider than the core's "
                                  f"{spec.DEFAULT_BUILD.max_width}: use the quarter-size (Q) pairs")
        per[scene.name] = {name: score(fn(left, right, _round_up(ndisp, step)), gt, mask)
                           for name, (fn, step) in matchers.items()}
    keys = ("bad_1", "bad_2", "density")
    mean = {name: {k: float(np.mean([s[name][k] for s in per.values()])) for k in keys} for name in matchers}
    return {"scenes": per, "mean": mean}


# -- speed ---------------------------------------------------------------------------------------

def bench_pairs(n: int = 2) -> List[Tuple[np.ndarray, np.ndarray]]:
    """Gray pairs of the synthetic rig at 752x480 (rendered images, not noise)."""
    from .rectify import bench_frames

    return [(np.ascontiguousarray(f[..., 3]), np.ascontiguousarray(f[..., 7])) for f in bench_frames(n)]


def speed(seconds: float, matchers: Dict[str, Matcher]) -> Dict[str, Dict[str, float]]:
    """Pairs per second of each matcher with 128 disparities, in alternating rounds on the same pairs
    (``bench.rectify``'s rounds: one warm-up call each, where the compiled path compiles)."""
    from .rectify import _time_rounds

    pairs = bench_pairs()

    def on_pair(fn: Matcher) -> Callable[[int], object]:
        return lambda i: fn(*pairs[i % len(pairs)], 128)

    timings = _time_rounds({name: on_pair(fn) for name, fn in matchers.items()}, seconds, min_rounds=3)
    out = {k: {"fps": t.rate, "rounds": float(t.rounds)} for k, t in timings.items()}
    for v in out.values():
        v["ratio_to_sgbm"] = v["fps"] / out["opencv_sgbm"]["fps"]
    return out


def rtl_speed(n: int = 2) -> Dict[str, Any]:
    """The stereo core's RTL under Verilator on ``n`` of the speed rounds' pairs (module docstring)."""
    from ..overlays.rtl.stereo_core import RtlStereo

    t0 = time.perf_counter()
    with RtlStereo(spec.DEFAULT_BUILD, seed=0) as core:
        build_s = time.perf_counter() - t0
        seconds: List[float] = []
        cpu: List[float] = []
        cpp: List[float] = []
        equal = True
        for left, right in bench_pairs(n):
            t, c = time.perf_counter(), core.cpu_seconds()
            got = core.compute(left, right)
            seconds.append(time.perf_counter() - t)
            c2 = core.cpu_seconds()
            if c is not None and c2 is not None:
                cpu.append(c2 - c)
            cpp.append(core.clocks_per_pixel)
            equal = equal and got.equal(model.compute(left, right))
    wall = float(np.median(seconds))
    cpu_s = float(np.median(cpu)) if cpu else None
    return {"fps": 1.0 / wall, "fps_cpu": 1.0 / cpu_s if cpu_s else None, "pairs": n,
            "seconds_per_pair": wall, "cpu_seconds_per_pair": cpu_s,
            "clocks_per_pixel": float(np.mean(cpp)), "equal_to_model": equal,
            "build_seconds": build_s, "built": core.harness.built}


def measure(seconds: float, pairs: Optional[Path], rtl: bool = False) -> Dict[str, Any]:
    if pairs is not None:
        scenes(pairs)  # a wrong folder fails now, not after the speed rounds
    paths = [model.fastest_path()] + (["numpy"] if model.fastest_path() != "numpy" else [])
    fast = model.fastest_path()
    timed: Dict[str, Matcher] = {f"model_{p}": model_matcher(p) for p in paths}
    timed.update(opencv_bm=opencv_bm, opencv_sgbm=opencv_sgbm)
    result: Dict[str, Any] = {"size": [WIDTH, HEIGHT], "num_disp": 128, "speed": speed(seconds, timed)}
    fps = result["speed"][f"model_{fast}"]["fps"]
    floor = fps >= FLOOR_FPS
    if rtl:
        result["rtl"] = rtl_speed()
        result["rtl"]["ratio_to_sgbm"] = result["rtl"]["fps"] / result["speed"]["opencv_sgbm"]["fps"]
        floor = floor and result["rtl"]["equal_to_model"]
    if pairs is not None:
        acc = accuracy(pairs, {"model": (model_matcher(fast), spec.DEFAULT_BUILD.parallel),
                               "opencv_bm": (opencv_bm, 16), "opencv_sgbm": (opencv_sgbm, 16)})
        result["accuracy"] = acc
        m = acc["mean"]
        floor = (floor and m["model"]["bad_2"] <= m["opencv_sgbm"]["bad_2"]
                 and m["model"]["density"] >= FLOOR_DENSITY)
    result["meets_floor"] = floor
    return result


def text_lines(r: Dict[str, Any]) -> List[str]:
    lines = [f"speed, {r['size'][0]}x{r['size'][1]} gray pairs, {r['num_disp']} disparities (pairs/s):"]
    for name, v in r["speed"].items():
        lines.append(f"  {name:<14} {v['fps']:7.2f}  ({v['ratio_to_sgbm']:.2f} x StereoSGBM)")
    if "rtl" in r:
        v = r["rtl"]
        cpu = "" if v["fps_cpu"] is None else f"{v['fps_cpu']:.2f} a CPU second of the harness; "
        lines.append(f"  {'rtl_verilator':<14} {v['fps']:7.2f}  ({v['ratio_to_sgbm']:.2f} x StereoSGBM; {cpu}"
                     f"{v['clocks_per_pixel']:.2f} clocks a pixel; {v['pairs']} pairs "
                     f"{'equal to' if v['equal_to_model'] else 'DIFFERENT from'} the model; program "
                     f"{'built in' if v['built'] else 'cached,'} {v['build_seconds']:.1f} s)")
    if "accuracy" in r:
        lines.append("accuracy (non-occluded pixels; a missing disparity counts as bad):")
        lines.append(f"  {'scene':<14} {'matcher':<12} {'bad-1.0':>8} {'bad-2.0':>8} {'density':>8}")
        rows = list(r["accuracy"]["scenes"].items()) + [("mean", r["accuracy"]["mean"])]
        for scene, by in rows:
            for name, s in by.items():
                lines.append(f"  {scene:<14} {name:<12} {100 * s['bad_1']:7.2f}% {100 * s['bad_2']:7.2f}% "
                             f"{100 * s['density']:7.2f}%")
    lines.append(f"floor (model >= {FLOOR_FPS:g} pairs/s; with --pairs: bad-2.0 <= StereoSGBM's, density >= "
                 f"{100 * FLOOR_DENSITY:g} %; with --rtl: the RTL equals the model): "
                 f"{'met' if r['meets_floor'] else 'NOT met'}")
    return lines


def run_depth(args: argparse.Namespace) -> int:
    pairs = Path(args.pairs) if args.pairs else None
    if not math.isfinite(args.seconds) or args.seconds <= 0:
        raise DepthBenchError(f"--seconds must be positive, not {args.seconds}")
    errors: Tuple[Type[BaseException], ...] = (DepthBenchError, ValueError)
    if args.rtl:
        from ..overlays.rtl.core import RtlError
        from ..overlays.rtl.toolchain import ToolMissing

        errors += (RtlError, ToolMissing)
    return run_suite("depth", lambda: measure(args.seconds, pairs, args.rtl), errors, args.json, text_lines)


def add_depth_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench depth``, a suite of ``stereocam bench``."""
    p = sub.add_parser("depth", help="the stereo model's speed and accuracy beside OpenCV's matchers",
                       description="Times the stereo core's model and OpenCV StereoBM/StereoSGBM on the same "
                                   "752x480 pairs; with --pairs, scores them on Middlebury-layout scenes.")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--seconds", type=float, default=3.0, help="time for the speed rounds (default 3)")
    p.add_argument("--pairs", metavar="DIR",
                   help="a folder of scene folders in Middlebury 2014's layout (im0.png, im1.png, "
                        "disp0GT.pfm, mask0nocc.png, calib.txt)")
    p.add_argument("--rtl", action="store_true",
                   help="also time the stereo core's RTL (the depth build) under Verilator on 2 of the "
                        "pairs, with its clocks a pixel, checked equal to the model (seconds a pair; the "
                        "first run builds the program, cached after)")
    p.set_defaults(func=run_depth)
