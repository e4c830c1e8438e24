"""The model cache Verify and capture pairing share: right under the work pool's concurrent calls."""
from __future__ import annotations

import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, List, Tuple

import numpy as np

from stereocam.overlays.model.result import CoreOptions
from stereocam.overlays.spec.rectify import CoreConfig, identity_registers
from stereocam.server.frames.virtual_camera import ModelCache

from ..interleave import at_every_bytecode

W, H = 16, 8
WORK_THREADS = 4  # the daemon's work pool (state.Executors.work)


class Core:
    """An overlay as the cache reads it: what its core's registers say (``core_setup``).

    Each instance's core draws its debug line on another row, so a frame's output says which
    register set it went through.
    """

    def __init__(self, row: int) -> None:
        regs = identity_registers(W, H)
        self.row = row
        self.setup = (CoreConfig(regs, regs, W, H), CoreOptions(bypass=True, debug_row=row))

    def core_setup(self) -> Tuple[CoreConfig, CoreOptions]:
        return self.setup


def test_concurrent_calls_with_alternating_registers_each_get_the_model_of_their_registers() -> None:
    """Four threads ask with alternating register sets, so the cache's key keeps changing under them:
    every answer is what the core set it read makes of the frame, never another set's."""
    cache = ModelCache()
    cores = [Core(row) for row in (1, 3, 5, 7)]
    frame = np.zeros((H, W, 8), np.uint8)

    def run(i: int) -> Tuple[int, List[int]]:
        core = cores[i % len(cores)]
        out: Any = cache.run(core, frame)  # type: ignore[arg-type]  # a stand-in overlay
        return core.row, np.flatnonzero(out.any(axis=(1, 2))).tolist()

    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    # In the cache's own code the GIL is offered to another thread before every bytecode: the threads
    # interleave at each point they can, not only where the scheduler happens to switch them.
    threading.settrace(at_every_bytecode(ModelCache.run.__code__, lambda: time.sleep(0)))
    try:
        with ThreadPoolExecutor(WORK_THREADS) as pool:
            answers = list(pool.map(run, range(4_000)))
    finally:
        threading.settrace(None)  # type: ignore[arg-type]
        sys.setswitchinterval(switch)
    wrong = [(asked, drawn) for asked, drawn in answers if drawn != [asked]]
    assert not wrong, f"{len(wrong)} of {len(answers)} calls ran another register set's model: {wrong[:5]}"
