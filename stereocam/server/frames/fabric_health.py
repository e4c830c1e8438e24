"""The fabric's faults as the daemon sees them, and getting every DMA channel and the mux going again.

A fault shows in the registers, not in a callback: a VDMA channel that
halts on a DMA error, a soft reset that does not finish, a mux commit that
never completes, cameras that stop sending. :class:`FabricHealth` polls the
DMA channels' status registers (the stereo core's output channel too, where the
bitstream has one) every :data:`POLL_S` on a thread of its
own (never the pipeline's: a hung reset would stall every stream), restarts
a halted channel at most every :data:`RETRY_S`, and re-commits the source
the daemon wants after a refused mux commit. :meth:`FabricHealth.faults`
lists the faults active now for ``/healthz``, ``/api/status`` and ``/metrics``
(through ``Extensions.faults``). A fault clears once its part works again:
a channel that ran :func:`settle_s` without halting, a mux that committed,
a frame from the cameras.
"""
from __future__ import annotations

import asyncio
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional

from prometheus_client.core import CounterMetricFamily, Metric

from ...overlays.interface import DEPTH_CHANNEL, Channel, DriverError, Overlay

log = logging.getLogger(__name__)

__all__ = ["FabricHealth", "POLL_S", "RETRY_S", "CHANNELS"]

POLL_S = 0.1  # status register reads: one per channel the overlay has, per poll
RETRY_S = 0.5  # at most one restart (or mux re-commit) per part per half second: each costs a reset
RECOVER_TIMEOUT_S = 0.25  # how long one restart waits for a halt or a reset before trying again later
CHANNELS: Dict[Channel, str] = {
    "vdma_raw.s2mm": "raw frames channel (vdma_raw S2MM)",
    "vdma_proc.s2mm": "processed frames channel (vdma_proc S2MM)",
    "vdma_proc.mm2s": "virtual camera channel (vdma_proc MM2S)",
    "vdma_depth.s2mm": "disparity channel (vdma_depth S2MM)",  # where the bitstream has a stereo core
}


@dataclass
class _Part:
    """One part's fault while it lasts."""

    what: str
    label: str
    since: Optional[float] = None  # wall clock when the fault began; None: healthy
    text: str = ""
    retried_at: float = float("-inf")  # monotonic
    clean_since: Optional[float] = None  # monotonic: running without a halt since a restart
    restarts: int = 0
    faults: int = 0  # faults seen since start

    def to_json(self) -> Dict[str, Any]:
        return {"what": self.what, "text": self.text, "since": self.since}


class FabricHealth:
    """Watches ``overlay`` while it streams; see the module doc.

    ``source()`` is the mux input the daemon wants (``"live"`` or
    ``"virtual"``), ``frame_age()`` the seconds since the last processed
    frame, ``period()`` the frame period (None before one is known).
    """

    def __init__(self, overlay: Overlay, *, source: Callable[[], str],
                 frame_age: Callable[[], Optional[float]], period: Callable[[], Optional[float]],
                 no_signal_s: float) -> None:
        self.overlay = overlay
        self._source = source
        self._frame_age = frame_age
        self._period = period
        self.no_signal_s = no_signal_s
        self.channels: Dict[Channel, _Part] = {
            name: _Part(name, label) for name, label in CHANNELS.items()
            if name != DEPTH_CHANNEL or overlay.stereo is not None}
        self.mux = _Part("mux", "the mux (AXI4-Stream switch)")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="stereocam-fabric-health", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the thread before the fabric stops (it would restart the stopped channels)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(RECOVER_TIMEOUT_S * 4 + 1.0)

    # -- what others ask ----------------------------------------------------------------
    def channel_ok(self, name: Channel) -> bool:
        """False while ``name`` is faulted: its lock may be held by a restart, so leave it alone."""
        return self.channels[name].since is None

    def faults(self) -> List[Dict[str, Any]]:
        """The faults active now (``Extensions.faults`` provider; never blocks on the fabric)."""
        with self._lock:
            out = [p.to_json() for p in (*self.channels.values(), self.mux) if p.since is not None]
        age = self._frame_age()
        if self._source() == "live" and self.overlay.streaming and not self._processed_faulted() \
                and age is not None and age > self.no_signal_s:
            out.append({"what": "cameras", "text": f"no frame from the cameras for {age:.1f} s",
                        "since": time.time() - age})
        return out

    def _processed_faulted(self) -> bool:
        return any(self.channels[n].since is not None for n in ("vdma_proc.s2mm",))

    def metrics(self) -> List[Metric]:
        """``stereocam_fabric_faults_total{part}``, ``stereocam_fabric_restarts_total{part}`` (counters only).

        The ``Extensions.metrics`` provider: never touches the fabric, so a scrape never waits on a restart.
        """
        with self._lock:
            faults = [(p.what, p.faults) for p in (*self.channels.values(), self.mux)]
            restarts = [(p.what, p.restarts) for p in self.channels.values()]
        seen = CounterMetricFamily("stereocam_fabric_faults",
                                   "Faults seen on a DMA channel or the mux since start.", labels=["part"])
        for part, count in faults:
            seen.add_metric([part], count)
        restarted = CounterMetricFamily("stereocam_fabric_restarts",
                                        "Restarts of a halted DMA channel since start.", labels=["part"])
        for part, count in restarts:
            restarted.add_metric([part], count)
        return [seen, restarted]

    # -- the mux ------------------------------------------------------------------------
    def mux_refused(self, wanted: str, exc: BaseException) -> None:
        """A commit did not finish (called by whoever switched): a fault until a commit lands."""
        with self._lock:
            part = self.mux
            if part.since is None:
                part.since, part.faults = time.time(), part.faults + 1
                log.warning("the mux did not commit %s (%s): retrying until it does", wanted, exc)
            part.text = f"the mux (AXI4-Stream switch) did not commit a change of source: {exc}"
            part.retried_at = time.monotonic()

    def mux_committed(self) -> None:
        with self._lock:
            part = self.mux
            if part.since is not None:
                log.info("the mux commits again (after %.1f s)", time.time() - part.since)
            part.since = None

    async def watch_mux(self, lock: asyncio.Lock, executor: Any) -> None:
        """While the mux is faulted, re-commit the wanted source every :data:`RETRY_S` (a loop task).

        ``lock`` is the virtual camera's: a re-commit never races a change of source.
        """
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(RETRY_S)
            if self.mux.since is None or time.monotonic() - self.mux.retried_at < RETRY_S:
                continue
            async with lock:
                wanted = self._source()
                try:
                    await loop.run_in_executor(executor, self.overlay.select, wanted, RECOVER_TIMEOUT_S)
                except DriverError as exc:
                    self.mux_refused(wanted, exc)
                except Exception as exc:  # a driver bug must not end the task
                    log.warning("re-committing the mux: %s", exc)
                else:
                    self.mux_committed()

    # -- the thread ---------------------------------------------------------------------
    def settle_s(self) -> float:
        """How long a restarted channel must run without halting to count as recovered."""
        return max(0.2, 3 * (self._period() or 0.0))

    def _run(self) -> None:
        while not self._stop.wait(POLL_S):
            if not self.overlay.streaming:
                continue
            for name, part in self.channels.items():
                try:
                    self._check(name, part)
                except Exception as exc:  # a driver bug must not end the thread
                    log.warning("checking the %s: %s", part.label, exc)

    def _check(self, name: Channel, part: _Part) -> None:
        status = self.overlay.channel_status(name)
        if not status.configured:
            return
        fatal = status.fatal
        halted = not status.running
        now = time.monotonic()
        if fatal or halted:
            what = f"halted on {', '.join(fatal)}" if fatal else "stopped"
            with self._lock:
                if part.since is None:
                    part.since, part.faults = time.time(), part.faults + 1
                    part.text = f"the {part.label} {what}"
                    log.warning("%s: restarting it", part.text)
                part.clean_since = None
            if now - part.retried_at < RETRY_S or self._stop.is_set():
                return
            part.retried_at = now
            try:
                self.overlay.restart_channel(name, RECOVER_TIMEOUT_S)
                part.restarts += 1
                text = f"the {part.label} {what}; restarted it"
            except DriverError as exc:
                text = f"the {part.label} {what}; restarting it failed: {exc}"
            with self._lock:
                part.text = text
            return
        if part.since is None:
            return
        if part.clean_since is None:
            part.clean_since = now
        elif now - part.clean_since >= self.settle_s():
            with self._lock:
                log.info("the %s runs again (after %.1f s)", part.label, time.time() - part.since)
                part.since, part.clean_since = None, None
