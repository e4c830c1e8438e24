"""The guest side of ``stereocam bench a9``: run each per-frame operation of the daemon between two marks.

Runs as armhf code under ``qemu-arm`` with the ``insn_marks`` plugin (``stereocam.bench.a9.run``),
in the armhf environment's Debian userland (numpy, OpenCV and libjpeg-turbo as a PYNQ-like board
has them), with the checkout on ``PYTHONPATH``. A mark is the system call the plugin watches
(``os.sched_get_priority_min`` of an impossible policy); the plugin writes the instruction count
at each. This script prints, as one JSON line on stdout, the operations in mark order: each name,
its first mark and how many times it ran between that mark and the next, so that the host divides.

It imports only what it measures, and measures what the daemon runs per frame: the views'
rendering (``views.render``), the JPEG and PNG encodes (``encoders.encode_image``) at the page's
sizes and qualities, the pipeline's copy of a frame store, StereoBM and its colour map (the
disparity view on a bitstream without a stereo core), a recording's frame (``recorder.encode_pair``)
and the start-up's imports.
"""
from __future__ import annotations

import functools
import json
import os
import sys
from typing import Any, Callable, Dict, List

MARK_TAG = 0x5C00_0000  # insn_marks.c: MARK_TAG | index


def mark(index: int) -> None:
    """The marker system call: EINVAL for the guest, a count in the plugin's file."""
    try:
        os.sched_get_priority_min(MARK_TAG | index)
    except OSError:
        pass


class Marks:
    """Numbers the marks and remembers what ran between them."""

    def __init__(self) -> None:
        self.next = 0
        self.ops: List[Dict[str, Any]] = []

    def measure(self, name: str, fn: Callable[[], Any], reps: int = 1, *, warm: bool = True) -> None:
        if warm:
            fn()  # first calls build caches, look up symbols, fault pages in: the steady state is wanted
        start = self.next
        mark(start)
        for _ in range(reps):
            fn()
        mark(start + 1)
        self.next += 2
        self.ops.append({"name": name, "mark": start, "reps": reps})


def main() -> int:
    marks = Marks()
    # The start-up's imports, as `stereocam serve` makes them: the CLI, then the daemon's modules.
    marks.measure("import.cli", lambda: __import__("stereocam.cli"), warm=False)
    marks.measure("import.serve", lambda: __import__("stereocam.server.http.app"), warm=False)

    import cv2
    import numpy as np

    from stereocam.overlays.emulated.render import SyntheticRig
    from stereocam.server.frames import views
    from stereocam.server.frames.encoders import encode_image
    from stereocam.server.frames.pipeline import FrameSet
    from stereocam.server.frames.recorder import encode_pair

    cv2.setNumThreads(0)  # as the daemon runs OpenCV under its budget (cpu_budget.single_threaded_opencv)
    frame = SyntheticRig(size=(752, 480), motion=False).read(0, 0.0)
    frame.flags.writeable = False

    def frame_set() -> FrameSet:
        return FrameSet(seq=0, frame=1, fabric_count=1, timestamp=0.0, monotonic=0.0, source="live",
                        processed=frame, raw=frame)

    def rendering(view: str, as_gray: bool, scale: float) -> Callable[[], Any]:
        return lambda: views.render(frame_set(), view, as_gray, scale)

    marks.measure("copy.frame", lambda: np.array(frame, copy=True), reps=5)
    for view in views.VIEWS:
        if views.uses_disparity_worker(view):
            continue
        for as_gray in (False, True) if view in views.GRAY_VIEWS else (False,):
            kind = "gray" if as_gray else "colour"
            for scale in (1.0, 0.5):
                marks.measure(f"render.{view}.{kind}.x{scale:g}", rendering(view, as_gray, scale), reps=3)
    colour = views.render(frame_set(), "rect_left")
    gray = views.render(frame_set(), "rect_left", True)
    wide = views.render(frame_set(), "sbs")
    half = cv2.resize(colour, (376, 240), interpolation=cv2.INTER_AREA)
    for quality in (50, 80, 95):
        encode = functools.partial(encode_image, colour, ".jpg", quality)
        marks.measure(f"jpeg.colour.q{quality}", encode, reps=3)
    marks.measure("jpeg.gray.q80", lambda: encode_image(gray, ".jpg", 80), reps=3)
    marks.measure("jpeg.colour_wide.q80", lambda: encode_image(wide, ".jpg", 80), reps=2)
    marks.measure("jpeg.colour_half.q80", lambda: encode_image(half, ".jpg", 80), reps=5)
    marks.measure("png.colour", lambda: encode_image(colour, ".png"), reps=2)
    marks.measure("png.gray", lambda: encode_image(gray, ".png"), reps=2)
    # a recording's frame: both cameras of the raw frame as the recorder stores them (PNGs, the Y plane's too)
    marks.measure("record.pair", lambda: encode_pair(frame), reps=1)
    left, right = frame[..., views._Y["left"]].copy(), frame[..., views._Y["right"]].copy()
    marks.measure("stereobm.full", lambda: views.disparity_map(left, right))
    marks.measure("stereobm.half", lambda: views.disparity_map(left, right, 0.5), reps=2)
    disp = views.disparity_map(left, right)
    marks.measure("stereobm.colour_map", lambda: views.colour_disparity(disp), reps=3)
    print(json.dumps({"frame": [752, 480], "ops": marks.ops, "python": sys.version.split()[0],
                      "numpy": np.__version__, "opencv": cv2.__version__}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
