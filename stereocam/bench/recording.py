"""``stereocam bench recording``: how long a stop takes to be done, and what a frame costs on disk.

The daemon (``stereocam serve``) runs as a subprocess on the emulated fabric at ``fps``. After
``warmup`` seconds, a recording until stopped runs for ``seconds``; then ``POST .../stop``
is timed until its answer (the recording done: every frame written, synced, listed):

- ``stop_to_done_s``: that time (floor: under :data:`FLOOR_STOP_S`);
- ``queued_at_stop``: frames taken but not written just before the stop;
- ``bytes_per_frame``: the recording's bytes over its frames (both cameras' PNGs);
- ``rgb_png_bytes_per_frame``: the same frames (up to :data:`SAMPLE_FRAMES`) as the captures'
  level-3 RGB PNG, the format recordings used before, for comparison;
- ``frames``, ``fps`` (the cameras' rate while recording), ``skipped`` (frames the writer
  could not keep up with), ``missed``, and ``loadavg_1m``: the machine is shared.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any, Dict, List, Optional

from .report import run_suite
from .serve import ServeBenchError, running_daemon

FLOOR_STOP_S = 2.0
SAMPLE_FRAMES = 20


def _call(base: str, method: str, path: str) -> Any:
    req = urllib.request.Request(base + path, method=method, data=b"" if method == "POST" else None)
    with urllib.request.urlopen(req, timeout=300) as resp:
        return json.loads(resp.read() or b"null")


def _rgb_png_bytes(folder: Path, frames: int) -> Optional[int]:
    """Mean bytes per frame of up to :data:`SAMPLE_FRAMES` frames of ``folder`` as level-3 RGB PNGs."""
    import cv2

    from ..server.stores.capture_images import CAPTURE_PNG

    lines = [json.loads(line) for line in (folder / "frames.jsonl").read_text().splitlines()[:SAMPLE_FRAMES]]
    total = 0
    for line in lines:
        for side in ("left", "right"):
            image = cv2.imread(str(folder / line[side]), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise OSError(f"cannot read {folder / line[side]}")
            if image.ndim == 2:
                image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
            ok, buf = cv2.imencode(".png", image, list(CAPTURE_PNG))
            total += len(buf)
    return total // len(lines) if lines and frames else None


def measure_recording(*, fps: float = 60.0, seconds: float = 10.0, warmup: float = 3.0) -> Dict[str, Any]:
    """One recording of ``seconds`` on a daemon started here, then its stop timed; blocks."""
    state = Path(tempfile.mkdtemp(prefix="stereocam-bench-recording-"))
    try:
        with running_daemon(fps=fps, extra_args=("--state-dir", str(state))) as (_, base):
            time.sleep(warmup)
            rid = _call(base, "POST", "/api/recordings")["id"]
            time.sleep(seconds)
            queued = _call(base, "GET", f"/api/recordings/{rid}").get("queued")
            t0 = time.monotonic()
            done = _call(base, "POST", f"/api/recordings/{rid}/stop")
            stop_s = time.monotonic() - t0
            meta = _call(base, "GET", f"/api/recordings/{rid}")["meta"]
            camera_fps = _call(base, "GET", "/api/status").get("fps", {}).get("camera")
        frames = int(done["frames"])
        rgb = _rgb_png_bytes(state / "recordings" / rid, frames)
    finally:
        shutil.rmtree(state, ignore_errors=True)
    per_frame = done["bytes"] // frames if frames else None
    result: Dict[str, Any] = {
        "fabric_fps": fps, "seconds": seconds, "stop_to_done_s": round(stop_s, 3), "queued_at_stop": queued,
        "frames": frames, "fps": meta.get("fps"), "camera_fps": camera_fps, "skipped": meta.get("skipped"),
        "missed": meta.get("missed"), "bytes_per_frame": per_frame, "rgb_png_bytes_per_frame": rgb,
        "frame_size": done.get("frame_size"), "loadavg_1m": round(os.getloadavg()[0], 2),
    }
    result["meets_floor"] = stop_s < FLOOR_STOP_S
    return result


def text_lines(r: Dict[str, Any]) -> List[str]:
    def mb(n: Optional[int]) -> str:
        return "?" if n is None else f"{n / 1e6:.2f} MB"

    return [
        f"recording          {r['seconds']:g} s at {r['fps']} fps ({r['frames']} frames of "
        f"{'x'.join(map(str, r['frame_size'] or []))}, emulated fabric asked {r['fabric_fps']:g} fps; "
        f"load average {r['loadavg_1m']})",
        f"stop to done       {r['stop_to_done_s']:.2f} s ({r['queued_at_stop']} frames queued at the stop); "
        f"floor {FLOOR_STOP_S:g} s",
        f"per frame          {mb(r['bytes_per_frame'])} "
        f"(as level-3 RGB PNG: {mb(r['rgb_png_bytes_per_frame'])})",
        f"kept up            skipped {r['skipped']}, missed {r['missed']}",
        "meets floor        " + ("yes" if r["meets_floor"] else "NO: stop_to_done_s"),
    ]


def run_recording(args: argparse.Namespace) -> int:
    """``stereocam bench recording``: print the figures (text or ``--json``); exit 1 below the floor."""
    return run_suite("recording",
                     lambda: measure_recording(fps=args.fps, seconds=args.seconds, warmup=args.warmup),
                     (ServeBenchError, OSError), args.json, text_lines)


def add_recording_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench recording``, a suite of ``stereocam bench`` (``sub`` is its subparsers)."""
    p = sub.add_parser("recording", help="a recording's stop-to-done time and bytes per frame",
                       description="`stereocam serve` on the emulated fabric records SECONDS until stopped; "
                                   "the stop is timed until the recording is done (exit 1 at "
                                   f"{FLOOR_STOP_S:g} s or more), and its bytes per frame are compared "
                                   "with level-3 RGB PNG.")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--fps", type=float, default=60.0, help="the emulated cameras' rate asked (default 60)")
    p.add_argument("--seconds", type=float, default=10.0, help="recorded this long (default 10)")
    p.add_argument("--warmup", type=float, default=3.0, help="seconds before recording (default 3)")
    p.set_defaults(func=run_recording)
