"""The frame clock of the emulated cameras: one ``tick(index, t)`` per frame period.

The real sensors are free-running and hardware-synchronised; off board,
:class:`FrameClock` plays that part. In ``"realtime"`` mode a daemon thread
calls ``tick`` at ``fps`` on a drift-free schedule (frame ``n`` is due at
``start + n / fps``); a tick that comes more than one frame period late skips
the frames it missed (counted in :attr:`FrameClock.skipped`) instead of
bursting to catch up, like a camera whose consumer was too slow. In
``"stepped"`` mode nothing runs by itself: :meth:`FrameClock.step` calls
``tick`` synchronously (for tests).

In both modes ``t == index / fps``: the nominal capture time of frame
``index``, so a source fed by either mode renders the same frame for the
same index.
"""
from __future__ import annotations

import collections
import logging
import math
import threading
import time
from typing import Callable, Deque, Optional

log = logging.getLogger(__name__)

__all__ = ["FrameClock", "ClockError", "ClockStopTimeout", "Tick"]

Tick = Callable[[int, float], None]
STOP_WAIT_S = 2.0  # the least time stop() waits for a tick to end
STOP_WAIT_TICKS = 4.0  # ... or this many times the longest tick so far, when that is longer
STOP_BUSY_CAP_S = 120.0  # past the wait above, stop() waits on while the tick uses CPU, up to this
MODES = ("realtime", "stepped")


class ClockError(ValueError):
    """A FrameClock used against its contract (bad rate or mode, ``step`` on a realtime clock)."""


class ClockStopTimeout(TimeoutError):
    """``stop()`` gave up waiting for the clock thread: the tick callback did not return in time."""


class FrameClock:
    """Calls ``tick(index, t)`` once per frame at ``fps`` frames per second.

    Realtime mode: ``start()`` launches a daemon thread (``tick`` runs on
    it, never on the caller's thread); ``stop()`` asks it to end and joins it
    for at most ``timeout`` seconds. Both are idempotent, and ``with clock:``
    starts and stops it. A later ``start()`` goes on from the next index,
    keeping ``t == index / fps``. An exception raised by ``tick`` is logged
    and counted in :attr:`errors`; the clock keeps running.

    Stepped mode: ``step(n)`` runs ``n`` ticks now, on the caller's thread,
    and lets exceptions from ``tick`` propagate. ``start()``/``stop()`` are
    accepted and do nothing, so code can drive either kind of clock.

    Counters (read from any thread): :attr:`frames` ticks run, :attr:`skipped`
    frames skipped for lateness, :attr:`errors` ticks that raised,
    :attr:`index` the next frame index, :attr:`fps` the measured rate.
    """

    def __init__(self, fps: float, tick: Tick, *, mode: str = "realtime", name: str = "frame-clock") -> None:
        try:
            rate = float(fps)
        except (TypeError, ValueError):
            raise ClockError(f"fps must be a number of frames per second, got {fps!r}") from None
        if not (math.isfinite(rate) and 0 < rate <= 10_000):
            raise ClockError(f"fps must be in (0, 10000] frames per second, got {fps!r}")
        if mode not in MODES:
            raise ClockError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if not callable(tick):
            raise ClockError(f"tick must be a callable taking (index, t), got {tick!r}")
        self.target_fps = rate
        self.mode = mode
        self.name = name
        self._tick = tick
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._next = 0
        self._frames = 0
        self._skipped = 0
        self._errors = 0
        self._times: Deque[float] = collections.deque(maxlen=max(2, min(int(rate) + 1, 121)))
        self._longest_tick = 0.0  # seconds, of the realtime ticks so far

    # -- counters ------------------------------------------------------------

    @property
    def frames(self) -> int:
        """Ticks run so far (including ones that raised)."""
        return self._frames

    @property
    def skipped(self) -> int:
        """Frame indices skipped because the clock thread was late by more than a frame."""
        return self._skipped

    @property
    def errors(self) -> int:
        """Realtime ticks whose callback raised (each was logged)."""
        return self._errors

    @property
    def index(self) -> int:
        """The index the next tick will get (at least; lateness may skip some)."""
        return self._next

    @property
    def fps(self) -> float:
        """Measured tick rate over about the last second; the target rate in stepped mode.

        0.0 before a realtime clock has ticked twice.
        """
        if self.mode == "stepped":
            return self.target_fps
        with self._lock:
            times = list(self._times)
        if len(times) < 2 or times[-1] <= times[0]:
            return 0.0
        return (len(times) - 1) / (times[-1] - times[0])

    @property
    def running(self) -> bool:
        """True while the realtime thread is alive."""
        thread = self._thread
        return thread is not None and thread.is_alive()

    # -- lifecycle -----------------------------------------------------------

    def start(self) -> "FrameClock":
        """Start ticking in a daemon thread (realtime); no-op if running or stepped. Returns self."""
        if self.mode == "stepped":
            return self
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                if not self._stop.is_set():
                    return self
                raise ClockStopTimeout(
                    f"{self.name}: the previous clock thread is still inside tick(); "
                    f"wait for it (call stop() again) before starting again"
                )
            self._stop.clear()
            self._times.clear()
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout: Optional[float] = None) -> None:
        """Stop ticking and wait up to ``timeout`` s for the thread. Idempotent; no-op in stepped mode.

        ``timeout`` None: :data:`STOP_WAIT_S`, or :data:`STOP_WAIT_TICKS` times the longest tick
        so far when that is longer; then on, while the tick thread keeps using CPU (it is
        working, not blocked), up to :data:`STOP_BUSY_CAP_S`. A tick is a whole frame of the
        emulated fabric, and a slow or busy CPU (a Cortex-A9 emulating the fabric, qemu, a
        machine shared with other work) can take seconds over one, the first one included:
        stopping must wait for it, not call it a hang. A tick blocked in a call uses no CPU.
        Called from inside ``tick`` it only asks the thread to stop (the
        thread cannot wait for itself). Raises :class:`ClockStopTimeout` if
        ``tick`` is still running after ``timeout``; the thread stops after
        that tick returns, and ``stop()`` may be called again to wait.
        """
        thread = self._thread
        if thread is None:
            return
        self._stop.set()
        if thread is threading.current_thread():
            return
        if timeout is None:
            timeout = max(STOP_WAIT_S, STOP_WAIT_TICKS * self._longest_tick)
            thread.join(timeout)
            timeout += _join_while_busy(thread, STOP_WAIT_S, STOP_BUSY_CAP_S)
        else:
            thread.join(timeout)
        if thread.is_alive():
            raise ClockStopTimeout(
                f"{self.name}: tick() has not returned {timeout:g} s after stop(); it stops after the tick "
                f"ends: look for a blocking call in the tick callback"
            )
        with self._lock:
            if self._thread is thread:
                self._thread = None

    def __enter__(self) -> "FrameClock":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def step(self, n: int = 1) -> None:
        """Stepped mode: run ``n`` ticks now with ``t = index / fps``. Exceptions from ``tick`` propagate."""
        if self.mode != "stepped":
            raise ClockError("step() drives a stepped clock; this one is realtime: use start()/stop()")
        if n < 0:
            raise ClockError(f"step(n) needs n >= 0, got {n}")
        for _ in range(int(n)):
            index = self._next
            self._next += 1
            self._frames += 1
            self._tick(index, index / self.target_fps)

    # -- the thread ----------------------------------------------------------

    def _run(self) -> None:
        _name_os_thread(self.name)
        period = 1.0 / self.target_fps
        n = self._next
        base = time.monotonic() - n * period  # frame n is due at base + n * period
        while not self._stop.is_set():
            deadline = base + n * period
            delay = deadline - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                break
            late = time.monotonic() - deadline
            if late > period:
                missed = int(late / period)
                n += missed
                self._skipped += missed
            self._next = n + 1
            now = time.monotonic()
            with self._lock:
                self._times.append(now)
            self._frames += 1
            try:
                self._tick(n, n / self.target_fps)
            except Exception:
                self._errors += 1
                if self._errors <= 3 or self._errors % 100 == 0:
                    log.exception("%s: tick(%d) raised (error %d; the clock keeps running)", self.name, n,
                                  self._errors)
            self._longest_tick = max(self._longest_tick, time.monotonic() - now)
            n += 1


def _name_os_thread(name: str) -> None:
    """Give the calling thread ``name`` in the kernel too (``top -H``, ``/proc/<pid>/task/*/comm``):
    the emulated hardware's CPU can then be told from the daemon's by any tool. Linux only."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.prctl(15, name.encode("ascii", "replace")[:15], 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass


def _join_while_busy(thread: threading.Thread, window_s: float, cap_s: float) -> float:
    """Join ``thread`` in windows of ``window_s`` while it used CPU in the last one; the seconds waited.

    Stops at ``cap_s``, or at once where a thread's CPU clock cannot be read."""
    waited = 0.0
    try:
        clock = time.pthread_getcpuclockid(thread.ident or 0)
        used = time.clock_gettime(clock)
    except (AttributeError, OSError, OverflowError):
        return waited
    while thread.is_alive() and waited < cap_s:
        thread.join(window_s)
        waited += window_s
        try:
            now = time.clock_gettime(clock)
        except OSError:  # the thread ended: its clock is gone
            break
        if now - used < 1e-3:
            break  # no CPU in a whole window: blocked, not slow
        used = now
    return waited
