"""The daemon's CPU budget: what each view costs it, and the frame rates that fit in a number of cores.

On the board two 650 MHz Cortex-A9 cores run the system, the daemon and the
DMA path's cache maintenance. A 752x480 colour JPEG costs them 12-24 ms and
StereoBM a third of a second, so seven views at 60 fps would need several
times the machine: without a budget every view falls behind at once. Here:

- **Costs are measured**, in CPU seconds of the thread that did the work
  (``time.thread_time``, so a busy machine does not inflate them): per
  encoder key the render, scaling and JPEG encode of one frame; the disparity
  match of one frame; the pipeline's copy of a processed and of a raw frame.
  Each is a running average, seeded with a prior until measured.
- **The daemon's CPU is measured** as the process's CPU time minus that of
  the threads that emulate hardware (the overlay's ``emulation_threads``: off
  the board the emulated fabric runs in the daemon's process; it is the
  fabric, not the daemon).
- **Every half second a plan** gives each watched encoder a rate: its
  target (what its fastest client asked, at most what the fabric delivers,
  the disparity view at most ``disparity_fps``) or, when the sum of the costs
  at those rates does not fit, one common rate ``R`` for all of them (each
  view at ``min(target, R)``: a cheap view is not starved for an expensive
  one, and no view falls behind the others), found by bisection. A view
  nobody watches has no encoder and costs nothing; the pipeline copies frames
  only as fast as the fastest planned view (and every frame while a capture,
  snapshot or Verify waits for one).
- **Feedback** corrects what the cost model misses (sending, Python glue):
  the plan's budget is scaled by a gain that shrinks when the measured CPU
  exceeds the budget and grows back while it is under, so the daemon's own
  CPU settles at the budget whatever the model's error.
- A watched view never stops: over budget it still gets :data:`MIN_FPS`.

OpenCV runs single-threaded under the budget (:func:`single_threaded_opencv`):
its worker pool would spend more CPU for the same work (3.2 against 2.5 ms
of CPU for a remap here) and hide the work from the thread that asked for it.

Event-loop thread for :meth:`CpuBudget.plan` and :meth:`CpuBudget.status`;
:meth:`CpuBudget.charge` from any thread.
"""
from __future__ import annotations

import collections
import functools
import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Collection, Deque, Dict, Hashable, Iterable, List, Mapping, Optional, Tuple

__all__ = ["BOARD_CORES", "MIN_FPS", "PLAN_PERIOD_S", "Demand", "ViewPlan", "CpuBudget", "DaemonCpu",
           "plan_rates", "default_cores", "single_threaded_opencv", "Priors", "HOST_PRIORS", "board_priors"]

BOARD_CORES = 1.0  # of the Zynq-7020's two: the other is the system's (kernel, DMA cache maintenance, sshd)
MIN_FPS = 1.0  # a watched view never stops, even over budget
PLAN_PERIOD_S = 0.5
WINDOW_S = 2.0  # the daemon's CPU is measured over this long
HEADROOM = 0.9  # plan to this share of the budget: the rest absorbs what changes between plans
SMOOTHING = 0.25  # weight of a new cost sample in its running average

# Priors, used until a cost has been measured once: CPU seconds per byte of the image worked on
# (this machine: a 752x480 colour JPEG 2.3 ms, a copy of an 8-channel frame 0.6 ms, StereoBM 22 ms).
PRIOR_ENCODE_S_PER_BYTE = 2.2e-9
PRIOR_COPY_S_PER_BYTE = 0.2e-9
PRIOR_MATCH_S_PER_PIXEL = 60e-9


@dataclass(frozen=True)
class Priors:
    """What a cost is taken to be until it has been measured: per byte of the image rendered and
    encoded, per byte of a frame copied, per pixel of the disparity match (and its colour map);
    ``view`` where a table knows a view's render and encode better than bytes do (a thumbnail is
    the full view rendered, then scaled: more than its bytes say)."""

    encode_s_per_byte: float = PRIOR_ENCODE_S_PER_BYTE
    copy_s_per_byte: float = PRIOR_COPY_S_PER_BYTE
    match_s_per_pixel: float = PRIOR_MATCH_S_PER_PIXEL
    source: str = "this machine's (cpu_budget.py)"
    view: Optional[Callable[[str, bool, float, int, Tuple[int, int]], Optional[float]]] = field(
        default=None, compare=False)

    def view_seconds(self, view: str, gray: bool, scale: float, quality: int, frame_size: Tuple[int, int],
                     view_size: Tuple[int, int]) -> float:
        """A frame of ``view``: the table's where it has one, else by the bytes of ``view_size``."""
        known = self.view(view, gray, scale, quality, frame_size) if self.view is not None else None
        if known is not None:
            return known
        return self.encode_s_per_byte * view_size[0] * view_size[1] * (1 if gray else 3)


HOST_PRIORS = Priors()


def board_priors(seconds: Optional[Mapping[str, float]] = None, *, arm_scale: float = 1.0) -> Priors:
    """The priors of the board's Cortex-A9, from the table ``stereocam bench a9`` counted
    (:func:`stereocam.board.a9_costs.board_seconds`, at the upper end of its cycles per instruction):
    a colour view's render and JPEG at quality 80, the copy of a frame store, StereoBM (at
    ``arm_scale``, views.ARM_SCALES) with its colour map; all at 752x480. A9TableError when the table
    cannot be read."""
    from ...board.a9_costs import board_seconds, view_seconds

    s = seconds if seconds is not None else board_seconds()
    pixels = 752 * 480
    return Priors(
        view=functools.partial(view_seconds, s),
        encode_s_per_byte=(s["render.rect_left.colour.x1"] + s["jpeg.colour.q80"]) / (3 * pixels),
        copy_s_per_byte=s["copy.frame"] / (8 * pixels),
        match_s_per_pixel=(s["stereobm.full" if arm_scale == 1.0 else "stereobm.half"]
                           + s["stereobm.colour_map"]) / pixels,
        source="the Cortex-A9 table (stereocam/board/a9_costs.json)",
    )

COPY = "copy"  # the pipeline's copy of a processed frame
RAW_COPY = "raw_copy"  # ... and of a raw frame
MATCH = "match"  # the disparity view's block matching of one frame


def default_cores(backend: str, *, board: bool = False) -> float:
    """The budget when none is configured: :data:`BOARD_CORES` on the board (the pynq backend, or
    ``board``: the emulated fabric on a board without its bitstream), the whole machine off it."""
    return BOARD_CORES if backend == "pynq" or board else float(os.cpu_count() or 1)


class single_threaded_opencv:
    """``with single_threaded_opencv():`` OpenCV without its worker pool, as before on leaving."""

    def __enter__(self) -> "single_threaded_opencv":
        import cv2

        self._before = cv2.getNumThreads()
        cv2.setNumThreads(1)
        return self

    def __exit__(self, *exc: object) -> None:
        import cv2

        cv2.setNumThreads(self._before)


# -- measuring -----------------------------------------------------------------------------------

class DaemonCpu:
    """CPU seconds the daemon has used: the process's, minus its threads named in ``excluded()``.

    ``excluded`` returns the names of Python threads that emulate hardware; their
    CPU is read with ``pthread_getcpuclockid`` (Linux). A rate over the last
    :data:`WINDOW_S` comes from :meth:`sample` calls (loop thread).
    """

    def __init__(self, excluded: Callable[[], Collection[str]] = tuple,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._excluded = excluded
        self._clock = clock
        self._samples: Deque[Tuple[float, float]] = collections.deque()

    def seconds(self) -> float:
        names = set(self._excluded())
        spent = 0.0
        if names:
            for thread in threading.enumerate():
                if thread.name in names and thread.ident is not None:
                    try:
                        spent += time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
                    except (OSError, AttributeError):  # ended meanwhile, or not Linux
                        pass
        return time.process_time() - spent

    def sample(self) -> Optional[float]:
        """Record now; the cores used over the last :data:`WINDOW_S` (None until two samples)."""
        now, used = self._clock(), self.seconds()
        self._samples.append((now, used))
        while len(self._samples) > 2 and now - self._samples[1][0] >= WINDOW_S:
            self._samples.popleft()
        (t0, u0) = self._samples[0]
        return max(0.0, (used - u0) / (now - t0)) if now > t0 else None


class Costs:
    """Running averages of CPU seconds per frame, by what was done (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seconds: Dict[Hashable, float] = {}
        self._counts: Dict[Hashable, int] = collections.Counter()

    def charge(self, what: Hashable, seconds: float) -> None:
        with self._lock:
            before = self._seconds.get(what)
            self._seconds[what] = seconds if before is None else before + SMOOTHING * (seconds - before)
            self._counts[what] += 1

    def get(self, what: Hashable, prior: float) -> float:
        with self._lock:
            return self._seconds.get(what, prior)

    def measured(self, what: Hashable) -> bool:
        with self._lock:
            return what in self._seconds


# -- planning ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Demand:
    """One watched encoder as the plan sees it.

    ``key`` names it; ``asked`` is the highest rate a client asked for, ``target``
    that capped by what the fabric delivers (and ``disparity_fps``), ``cost`` its
    CPU seconds per frame, ``raw`` whether it needs the raw frames copied,
    ``match`` the block matching it needs per frame (the disparity view).
    """

    key: Hashable
    asked: float
    target: float
    cost: float
    raw: bool = False
    match: float = 0.0


def plan_cost(demands: Iterable[Demand], rate: float, copy: float, raw_copy: float) -> float:
    """Cores used with every demand at ``min(target, rate)``: encodes, the pipeline's copies and the
    matching, which the disparity and depth views share (one worker matches each frame once, at the
    rate of the faster of them)."""
    total, fastest, fastest_raw, match = 0.0, 0.0, 0.0, 0.0
    for d in demands:
        r = min(d.target, rate)
        total += r * d.cost
        fastest = max(fastest, r)
        if d.raw:
            fastest_raw = max(fastest_raw, r)
        match = max(match, r * d.match)
    return total + match + fastest * copy + fastest_raw * raw_copy


def plan_rates(demands: List[Demand], cores: float, copy: float, raw_copy: float) -> Tuple[float, bool]:
    """``(R, limited)``: the common rate cap that fits ``cores`` (``inf`` when every target fits).

    Over budget even at :data:`MIN_FPS`, ``R`` is :data:`MIN_FPS`.
    """
    top = max((d.target for d in demands), default=0.0)
    if top <= 0 or plan_cost(demands, top, copy, raw_copy) <= cores:
        return math.inf, False
    lo, hi = MIN_FPS, top
    if plan_cost(demands, lo, copy, raw_copy) > cores:
        return MIN_FPS, True
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if plan_cost(demands, mid, copy, raw_copy) <= cores:
            lo = mid
        else:
            hi = mid
    return lo, True


@dataclass(frozen=True)
class ViewPlan:
    """What the plan gave one encoder, and why (for status, metrics and the page)."""

    key: Hashable
    asked: float
    target: float
    planned: float
    cost_s: float
    reason: str

    @property
    def limited(self) -> bool:
        return self.planned < self.target - 1e-9


class CpuBudget:
    """The plan of the module doc, over ``cores`` cores.

    ``excluded_threads`` returns the names of threads that emulate hardware
    (not counted as the daemon's CPU).
    """

    def __init__(self, cores: float, *, excluded_threads: Callable[[], Collection[str]] = tuple,
                 clock: Callable[[], float] = time.monotonic, priors: Priors = HOST_PRIORS) -> None:
        if not cores > 0:
            raise ValueError(f"a CPU budget must be more than 0 cores, got {cores!r}")
        self.cores = float(cores)
        self.priors = priors
        self.costs = Costs()
        self.cpu = DaemonCpu(excluded_threads, clock)
        self.gain = 1.0
        self.used: Optional[float] = None  # cores the daemon used over the last WINDOW_S
        self.rate_cap = math.inf  # the common rate R of the last plan
        self.plans: Dict[Hashable, ViewPlan] = {}
        self.copy_rate = 0.0  # frames/s the views need copied by the pipeline

    # -- costs (any thread) ----------------------------------------------------------------------
    def charge(self, what: Hashable, seconds: float) -> None:
        self.costs.charge(what, seconds)

    def cost(self, what: Hashable, prior: float) -> float:
        return self.costs.get(what, prior)

    # -- the plan (loop thread) ------------------------------------------------------------------
    def plan(self, demands: List[Demand], *, frame_bytes: int) -> Dict[Hashable, ViewPlan]:
        """Rates for ``demands`` (see the module doc); also sets :attr:`copy_rate` and the gain."""
        used = self.cpu.sample()
        self.used = used
        copy = self.costs.get(COPY, self.priors.copy_s_per_byte * frame_bytes)
        raw_copy = self.costs.get(RAW_COPY, self.priors.copy_s_per_byte * frame_bytes)
        if used is not None and demands:
            if used > self.cores:  # over: shrink at once, in proportion
                self.gain *= max(0.5, (HEADROOM * self.cores / used) ** 0.5)
            elif self.rate_cap < math.inf and used < 0.8 * self.cores:  # limited and under: grow back
                self.gain *= min(1.15, (HEADROOM * self.cores / max(used, 1e-3)) ** 0.25)
            self.gain = min(4.0, max(0.02, self.gain))
        cores = HEADROOM * self.cores * self.gain
        rate, limited = plan_rates(demands, cores, copy, raw_copy)
        self.rate_cap = rate
        plans: Dict[Hashable, ViewPlan] = {}
        for d in demands:
            planned = min(d.target, rate)
            if limited and planned < d.target:
                reason = (f"CPU budget: {self.cores:g} cores shared by {len(demands)} "
                          f"view{'s' if len(demands) != 1 else ''}")
            elif d.target < d.asked:
                reason = "the fabric's rate" if d.match == 0 else "the disparity rate (disparity_fps)"
            else:
                reason = ""
            plans[d.key] = ViewPlan(d.key, d.asked, d.target, planned, d.cost + d.match, reason)
        self.plans = plans
        # The pipeline copies as fast as the fastest view (it copies every frame once that reaches the
        # fabric's rate) and, with no view watched, none: captures and snapshots ask for theirs.
        self.copy_rate = max((p.planned for p in plans.values()), default=0.0)
        return plans

    def status(self) -> Dict[str, object]:
        return {
            "cores": self.cores,
            "used_cores": None if self.used is None else round(self.used, 3),
            "limited": any(p.limited for p in self.plans.values()),
            "rate_cap_fps": None if math.isinf(self.rate_cap) else round(self.rate_cap, 2),
            "gain": round(self.gain, 3),
            "priors": self.priors.source,
        }


def merge_reasons(plans: Mapping[Hashable, ViewPlan]) -> List[str]:
    """The distinct reasons of ``plans``, in order (for a one-line summary)."""
    return list(dict.fromkeys(p.reason for p in plans.values() if p.reason))
