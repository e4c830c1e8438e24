"""The ``faults`` benchmark: how fast the daemon reports and recovers from each kind of fault.

The floor: every injected fault of every kind reported within 1 s and
recovered within 2 s of its end, 100 times in a row, with no other stream
stalling. ``tests/server/test_faults.py`` checks the behaviour (each reported, each
recovered, frames going on) by waiting for conditions, so a busy machine makes
it slower, not red; this benchmark measures the times against the floor.

The daemon runs as a subprocess (``stereocam serve --allow-fault-injection``,
emulated fabric). One MJPEG client watches ``rect_left`` throughout. For each
round of each kind: inject over HTTP; poll ``/api/status`` every 20 ms until the
fault is listed (``report_s``); for a fault off the rectified frames' path, the
longest gap between the client's parts while it lasted (``gap_s``); end it; poll
until no fault is listed and ``/healthz`` is 200 (``recover_s``). Each figure is
the worst over the rounds. A ``mux_refuse`` fault is met when the daemon
switches: the round asks for the live source once, as a user would.
"""
from __future__ import annotations

import asyncio
import time
from typing import Any, Dict, List, Optional, Tuple

from .serve import ClientStats, ServeBenchError, _mjpeg_client, running_daemon

__all__ = ["measure_faults", "text_lines", "FLOORS", "KINDS"]

FLOORS = {"report_s": 1.0, "recover_s": 2.0, "gap_s": 1.0}
CHANNELS = ("vdma_raw.s2mm", "vdma_proc.s2mm", "vdma_proc.mm2s")
KINDS: List[Tuple[str, Optional[str], str]] = [
    ("camera_stall", None, "cameras"),
    *[(kind, ch, ch) for kind in ("dma_internal", "dma_slave", "dma_decode", "reset_hang")
      for ch in CHANNELS],
    ("mux_refuse", None, "mux"),
    ("sensor_silent", "left", "sensor.left"),
    ("sensor_silent", "right", "sensor.right"),
]
ON_THE_PROCESSED_PATH = {"cameras", "vdma_proc.s2mm"}
POLL_S = 0.02
LIMIT_S = 30.0  # a round that takes longer than this failed outright


async def _poll(what: str, check: Any) -> float:
    t0 = time.monotonic()
    while not await check():
        if time.monotonic() - t0 > LIMIT_S:
            raise ServeBenchError(f"{what}: not within {LIMIT_S:g} s")
        await asyncio.sleep(POLL_S)
    return time.monotonic() - t0


def _max_gap(parts: List[Tuple[float, float, int]], t0: float, t1: float) -> float:
    """The longest time without a part between ``t0`` and ``t1`` (monotonic)."""
    times = [t0] + [p[0] for p in parts if t0 <= p[0] <= t1] + [t1]
    return max(b - a for a, b in zip(times[:-1], times[1:], strict=True))


class _Daemon:
    """The daemon as the rounds see it over HTTP."""

    def __init__(self, http: Any) -> None:
        self.http = http

    async def faults(self) -> List[str]:
        async with self.http.get("/api/status") as resp:
            return [f["what"] for f in (await resp.json())["faults"]]

    async def listed(self, what: str) -> bool:
        return what in await self.faults()

    async def clear(self) -> bool:
        if await self.faults():
            return False
        async with self.http.get("/healthz") as resp:
            return bool(resp.status == 200)

    async def round(self, kind: str, target: Optional[str], what: str) -> Tuple[float, float, float, float]:
        """One fault: ``(report_s, recover_s, t0, t1)``, t0/t1 (monotonic) when it began and ended."""
        async with self.http.post("/api/faults", json={"kind": kind, "target": target}) as resp:
            if resp.status != 201:
                raise ServeBenchError(f"injecting {kind}: HTTP {resp.status}: {await resp.text()}")
            fault = await resp.json()
        t0 = time.monotonic()
        if what == "mux":  # met when the daemon switches
            async with self.http.put("/api/source", json={"source": "live"}):
                pass
        await _poll(f"{what} reported", lambda: self.listed(what))
        report = time.monotonic() - t0
        await asyncio.sleep(0.3)  # the fault lasts a while: the streams must go on through it
        async with self.http.delete(f"/api/faults/{fault['id']}"):
            pass
        t1 = time.monotonic()
        recover = await _poll(f"{what} recovered", self.clear)
        return report, recover, t0, t1


async def _rounds(base: str, rounds: int) -> Dict[str, Dict[str, Any]]:
    import aiohttp

    out: Dict[str, Dict[str, Any]] = {}
    async with aiohttp.ClientSession(base_url=base) as http:
        daemon = _Daemon(http)
        stats, stop = ClientStats(), asyncio.Event()
        client = asyncio.create_task(_mjpeg_client(http, base + "/stream/rect_left", stats, stop))
        try:
            await _poll("no fault at start", daemon.clear)
            for kind, target, what in KINDS:
                row: Dict[str, Any] = {"kind": kind, "part": what, "rounds": 0, "report_s": 0.0,
                                       "recover_s": 0.0, "gap_s": None}
                out[f"{kind}:{target or what}"] = row
                for _ in range(rounds):
                    report, recover, t0, t1 = await daemon.round(kind, target, what)
                    row["rounds"] += 1
                    row["report_s"] = max(row["report_s"], round(report, 3))
                    row["recover_s"] = max(row["recover_s"], round(recover, 3))
                    if what not in ON_THE_PROCESSED_PATH:
                        gap = round(_max_gap(stats.parts, t0, t1), 3)
                        row["gap_s"] = gap if row["gap_s"] is None else max(row["gap_s"], gap)
                    if stats.error:
                        raise ServeBenchError(stats.error)
        finally:
            stop.set()
            client.cancel()
            await asyncio.gather(client, return_exceptions=True)
    return out


def measure_faults(*, rounds: int = 100, fps: float = 60.0) -> Dict[str, Any]:
    """Run the rounds (blocks; its own event loop) and return the figures with ``floors`` and ``ok``."""
    with running_daemon(fps=fps, extra_args=["--allow-fault-injection"]) as (_proc, base):
        by_part = asyncio.run(_rounds(base, rounds))
    ok = all(row[key] is None or row[key] <= FLOORS[key]
             for row in by_part.values() for key in FLOORS)
    return {"rounds_per_kind": rounds, "fps": fps, "floors": FLOORS, "parts": by_part, "ok": ok}


def text_lines(result: Dict[str, Any]) -> List[str]:
    floors = result["floors"]
    lines = [f"faults: {result['rounds_per_kind']} rounds of each kind at {result['fps']:g} fps; worst "
             f"report (floor {floors['report_s']:g} s), recover (floor {floors['recover_s']:g} s), "
             f"rect_left gap during the fault (floor {floors['gap_s']:g} s)"]
    for row in result["parts"].values():
        marks = [("" if row[k] is None or row[k] <= floors[k] else " MISSED")
                 for k in ("report_s", "recover_s", "gap_s")]
        gap = "n/a (on its path)" if row["gap_s"] is None else f"{row['gap_s']:.3f} s{marks[2]}"
        lines.append(f"  {row['part']:15s} {row['kind']:13s} report {row['report_s']:.3f} s{marks[0]}, "
                     f"recover {row['recover_s']:.3f} s{marks[1]}, gap {gap}")
    lines.append("  all floors met" if result["ok"] else "  FLOOR MISSED")
    return lines
