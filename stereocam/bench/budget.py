"""``stereocam bench budget``: the daemon within a CPU budget, every view watched, then one.

The daemon (``stereocam serve --cpu-budget CORES``) runs as a subprocess on the
emulated fabric, so its CPU can be read from ``/proc/<pid>/task/*/stat``: every
thread but the emulated fabric's (``emulated-fabric``, named so in the kernel
too: off the board the fabric runs in the daemon's process, and it is the
hardware, not the daemon). This process watches views over one WebSocket, as
the page does, and counts the frames of each view it receives.

Two phases, each after ``warmup`` seconds for the plan to settle:

- ``all``: every view of the registry (``stereocam/server/frames/views.py``) for
  ``seconds``: ``daemon_cores`` (mean over the window), ``daemon_cores_max_10s``
  (the worst 10-s stretch), each view's ``delivered_fps``;
- ``one``: ``rect_left`` alone for ``one_seconds``: its ``delivered_fps``
  against ``camera_fps``, the fabric's rate (``/api/status``).

Floors: within ``cores + 0.05`` cores over the window, every view
at least 2 fps; one view at (at least 90 % of) the fabric's rate.
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import struct
import time
from typing import Any, Dict, List, Sequence, Tuple

from ..server.frames import views
from .report import run_suite
from .serve import ServeBenchError, running_daemon

VIEWS = views.VIEWS  # the daemon's view registry: every view is watched in the "all" phase
FABRIC_THREAD = "emulated-fabric"
FLOOR_OVER_CORES = 0.05
FLOOR_VIEW_FPS = 2.0
FLOOR_ONE_SHARE = 0.9
_TICK = os.sysconf("SC_CLK_TCK")


def daemon_cpu_seconds(pid: int, excluded: str = FABRIC_THREAD) -> float:
    """utime + stime of every thread of ``pid`` whose kernel name is not ``excluded``."""
    total = 0
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm", encoding="ascii", errors="replace") as f:
                name = f.read().strip()
            if name == excluded:
                continue
            fields = _stat_fields_task(pid, tid)
        except OSError:  # the thread ended meanwhile
            continue
        total += int(fields[11]) + int(fields[12])
    return total / _TICK


def _stat_fields_task(pid: int, tid: str) -> List[str]:
    with open(f"/proc/{pid}/task/{tid}/stat", "rb") as f:
        data = f.read().decode("ascii", "replace")
    return data[data.rindex(")") + 2:].split()


class Watcher:
    """One WebSocket watching ``views``; counts each view's frames with their arrival times."""

    def __init__(self) -> None:
        self.arrivals: Dict[str, List[float]] = collections.defaultdict(list)

    async def run(self, base: str, views: Sequence[str], fps: float, stop: asyncio.Event) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(base.replace("http", "ws", 1) + "/ws", max_msg_size=0) as ws:
                await ws.send_json({"views": list(views), "fps": fps})
                while not stop.is_set():
                    try:
                        msg = await asyncio.wait_for(ws.receive(), timeout=0.5)
                    except asyncio.TimeoutError:
                        continue
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        n = struct.unpack(">I", msg.data[:4])[0]
                        header = json.loads(msg.data[4:4 + n])
                        if header.get("signal", True):
                            self.arrivals[header["view"]].append(time.monotonic())
                    elif msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                        raise ServeBenchError(f"the daemon closed the WebSocket: {msg.type}")

    def rate(self, view: str, t0: float, t1: float) -> float:
        n = sum(1 for t in self.arrivals.get(view, ()) if t0 <= t < t1)
        return n / (t1 - t0)


async def _status(base: str) -> Dict[str, Any]:
    import aiohttp

    async with aiohttp.ClientSession() as session:
        async with session.get(base + "/api/status") as resp:
            body: Dict[str, Any] = await resp.json()
            return body


async def _phase(base: str, pid: int, views: Sequence[str], *, seconds: float, warmup: float,
                 fps: float) -> Dict[str, Any]:
    watcher, stop = Watcher(), asyncio.Event()
    task = asyncio.ensure_future(watcher.run(base, views, fps, stop))
    try:
        await asyncio.sleep(warmup)
        if task.done():
            task.result()
        t0, c0 = time.monotonic(), daemon_cpu_seconds(pid)
        stretches: List[Tuple[float, float]] = [(t0, c0)]
        while time.monotonic() - t0 < seconds:
            await asyncio.sleep(min(10.0, seconds - (time.monotonic() - t0)))
            stretches.append((time.monotonic(), daemon_cpu_seconds(pid)))
        t1, c1 = stretches[-1]
        status = await _status(base)
    finally:
        stop.set()
        await asyncio.gather(task, return_exceptions=True)
    worst = max(((b[1] - a[1]) / (b[0] - a[0]) for a, b in zip(stretches, stretches[1:], strict=False)
                 if b[0] > a[0]),
                default=0.0)
    return {
        "views": list(views),
        "seconds": round(t1 - t0, 1),
        "daemon_cores": round((c1 - c0) / (t1 - t0), 3),
        "daemon_cores_max_10s": round(worst, 3),
        "delivered_fps": {v: round(watcher.rate(v, t0, t1), 2) for v in views},
        "camera_fps": status.get("fps", {}).get("camera"),
        "planned_fps": {e["view"]: e["planned_fps"] for e in status.get("encoders", [])},
        "limited_by": sorted({e["limited_by"] for e in status.get("encoders", []) if e["limited_by"]}),
    }


def _full_rate(one: Dict[str, Any]) -> bool:
    camera = float(one["camera_fps"] or 0.0)
    return camera > 0 and one["delivered_fps"]["rect_left"] >= FLOOR_ONE_SHARE * camera


def measure_budget(*, cores: float = 0.3, fps: float = 30.0, seconds: float = 60.0, one_seconds: float = 10.0,
                   one_until: float = 0.0, warmup: float = 5.0, client_fps: float = 60.0) -> Dict[str, Any]:
    """Both phases of the module doc against a daemon started here; blocks (its own event loop).

    ``one_until`` > 0 repeats the one-view window until one reaches the fabric's rate or that many
    seconds have passed (``one["tries"]`` says how many it took): on a machine shared with other
    work a window can lose frames to the scheduler, which says nothing of the budget. The bench
    measures one window, as asked."""
    extra = ("--cpu-budget", f"{cores:g}")
    with running_daemon(fps=fps, extra_args=extra) as (proc, base):
        async def both() -> Tuple[Dict[str, Any], Dict[str, Any]]:
            every = await _phase(base, proc.pid, VIEWS, seconds=seconds, warmup=warmup, fps=client_fps)
            deadline, tries = time.monotonic() + one_until, 0
            while True:
                one = await _phase(base, proc.pid, ("rect_left",), seconds=one_seconds, warmup=warmup,
                                   fps=client_fps)
                tries += 1
                if _full_rate(one) or time.monotonic() >= deadline:
                    one["tries"] = tries
                    return every, one

        every, one = asyncio.run(both())
    checks = {
        "all_cores": every["daemon_cores"] <= cores + FLOOR_OVER_CORES,
        "all_views_fps": min(every["delivered_fps"].values()) >= FLOOR_VIEW_FPS,
        "one_full_rate": _full_rate(one),
    }
    return {"cores": cores, "fabric_fps": fps, "all": every, "one": one, "checks": checks,
            "meets_floor": all(checks.values()), "loadavg_1m": round(os.getloadavg()[0], 2)}


def text_lines(result: Dict[str, Any]) -> List[str]:
    every, one = result["all"], result["one"]
    lines = [f"budget             {result['cores']:g} cores, emulated fabric at {result['fabric_fps']:g} fps "
             f"(load average {result['loadavg_1m']})",
             f"all {len(VIEWS)} views      daemon {every['daemon_cores']} cores over {every['seconds']} s "
             f"(worst 10 s: {every['daemon_cores_max_10s']}); floor {result['cores'] + FLOOR_OVER_CORES:g}"]
    for view, rate in every["delivered_fps"].items():
        lines.append(f"  {view:<16} {rate:6.2f} fps delivered (planned {every['planned_fps'].get(view)})")
    lines.append(f"  limited by: {'; '.join(every['limited_by']) or 'nothing'}")
    lines.append(f"one view           rect_left {one['delivered_fps']['rect_left']} fps of the fabric's "
                 f"{one['camera_fps']} (daemon {one['daemon_cores']} cores)")
    missed = [k for k, ok in result["checks"].items() if not ok]
    lines.append("meets floor        " + ("yes" if result["meets_floor"] else "NO: " + ", ".join(missed)))
    return lines


def run_budget(args: argparse.Namespace) -> int:
    """``stereocam bench budget``: print the figures (text or ``--json``); exit 1 below a floor."""
    return run_suite("budget", lambda: measure_budget(cores=args.cores, fps=args.fps, seconds=args.seconds,
                                                      one_seconds=args.one_seconds),
                     (ServeBenchError,), args.json, text_lines)


def add_budget_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench budget``, a suite of ``stereocam bench`` (``sub`` is its subparsers)."""
    p = sub.add_parser("budget", help="the daemon within a CPU budget, every view watched, then one",
                       description="`stereocam serve --cpu-budget CORES` on the emulated fabric, its CPU "
                                   "read from /proc (the emulated fabric's threads excluded), every view "
                                   "watched over a WebSocket, then one (exit 1 below a floor).")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--cores", type=float, default=0.3, help="the budget (default 0.3)")
    p.add_argument("--fps", type=float, default=30.0, help="the emulated cameras' rate (default 30)")
    p.add_argument("--seconds", type=float, default=60.0, help="every view watched this long (default 60)")
    p.add_argument("--one-seconds", type=float, default=10.0, help="one view watched this long (default 10)")
    p.set_defaults(func=run_budget)
