"""The ``serve`` benchmark: MJPEG fan-out of the daemon on the emulated fabric.

The daemon (``stereocam serve``) runs as a subprocess at ``fps`` so that its
CPU time can be read from ``/proc/<pid>/stat`` (the daemon and any process it
starts). This process then opens N concurrent MJPEG clients (aiohttp, parsing
the multipart parts itself) on ``/stream/<view>`` for ``seconds``, for each N
in ``clients`` (1 then 20 by default), and reports per N:

- ``delivered_fps_mean`` / ``delivered_fps_min``: parts per second received per client;
- ``cpu_s_per_frame``: daemon CPU seconds in the window / frames delivered to one client
  (the mean client). With one encode per frame however many watch (STYLE.md,
  "latest frame wins"), this barely grows with N, hence ``cpu_ratio_<N>_vs_<1>``;
- ``latency_ms_p50`` / ``_p95``: from the part's ``X-Timestamp`` (the frame's capture
  time) to the part's last byte arriving at the client, over every part of every client;
- ``pipeline_fps`` / ``pipeline_drops``: the daemon's own counters (``/api/status`` ``frames``,
  ``drops``) over the window, and ``camera_fps`` (the camera stage's rate at the end), so a low
  delivered rate can be told apart from a slow pipeline or fabric;
- ``bench_client_cpu_s`` (this process's CPU time in the window) and ``loadavg_1m``: the machine is
  shared (2 cores), so read the figures against the load they were measured under.

Measurement windows: every client connects and receives for ``warmup`` seconds first; then
counters, CPU times and wall clock are snapshotted, and again ``seconds`` later. Only parts that
complete inside the window count. Waits are bounded: a daemon that never becomes healthy, or a
client that stalls, ends the run with :class:`ServeBenchError` naming what did not happen.

Blocking: :func:`measure_serve` blocks (it runs its own event loop); call it from plain code,
not from inside a running event loop.
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

FLOOR_DELIVERED_FPS = 55.0
FLOOR_CPU_RATIO = 1.2
HEALTH_TIMEOUT_S = 60.0
STALL_TIMEOUT_S = 10.0


class ServeBenchError(Exception):
    """The daemon did not start, died, or a stream stalled; the message says which."""


# -- the daemon subprocess ------------------------------------------------------------------
def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def daemon_command(port: int, fps: float, captures: Path, extra_args: Sequence[str] = ()) -> List[str]:
    """The ``stereocam serve`` command line the benchmark (and the browser test) starts."""
    return [sys.executable, "-m", "stereocam.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
            "--fps", f"{fps:g}", "--captures", str(captures), *extra_args]


def wait_healthy(base: str, proc: "subprocess.Popen[bytes]", timeout: float = HEALTH_TIMEOUT_S) -> None:
    """Poll ``GET /healthz`` until it answers 200; raise if the daemon exits or ``timeout`` passes."""
    deadline = time.monotonic() + timeout
    last = "no answer"
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ServeBenchError(
                f"the daemon exited with code {proc.returncode} before /healthz answered 200")
        try:
            with urllib.request.urlopen(base + "/healthz", timeout=2.0) as resp:
                if resp.status == 200:
                    return
                last = f"HTTP {resp.status}"
        except urllib.error.HTTPError as exc:
            last = f"HTTP {exc.code}"
        except (urllib.error.URLError, OSError) as exc:
            last = str(getattr(exc, "reason", exc))
        time.sleep(0.2)
    raise ServeBenchError(f"the daemon's /healthz did not answer 200 within {timeout:g} s (last: {last})")


@contextlib.contextmanager
def running_daemon(
    *, fps: float, port: Optional[int] = None, captures: Optional[Path] = None,
    log_path: Optional[Path] = None, health_timeout: float = HEALTH_TIMEOUT_S, extra_args: Sequence[str] = (),
) -> Iterator[Tuple["subprocess.Popen[bytes]", str]]:
    """Start ``stereocam serve`` on 127.0.0.1, wait until healthy, yield ``(process, base_url)``.

    ``extra_args`` go to ``stereocam serve`` as they are (e.g. ``--config FILE``).
    The daemon's stdout and stderr go to ``log_path`` (a temporary file when None); on a
    failed start its tail is part of the error. On exit the daemon gets SIGINT, then SIGKILL
    after 10 s.
    """
    tmp = Path(tempfile.mkdtemp(prefix="stereocam-bench-serve-"))
    port = port or free_port()
    captures = captures or tmp / "captures"
    captures.mkdir(parents=True, exist_ok=True)
    log_path = log_path or tmp / "daemon.log"
    base = f"http://127.0.0.1:{port}"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(daemon_command(port, fps, captures, extra_args), stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        try:
            wait_healthy(base, proc, health_timeout)
        except ServeBenchError as exc:
            tail = log_path.read_text(errors="replace").strip().splitlines()[-15:]
            raise ServeBenchError(f"{exc}; daemon log ({log_path}):\n" + "\n".join(tail)) from None
        yield proc, base
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        shutil.rmtree(tmp, ignore_errors=True)


# -- CPU time of a process tree ----------------------------------------------------------
_TICK = os.sysconf("SC_CLK_TCK")


def _stat_fields(pid: int) -> List[str]:
    with open(f"/proc/{pid}/stat", "rb") as f:
        data = f.read().decode("ascii", "replace")
    # Field 2 (comm) is in parentheses and may hold spaces: split after its closing one.
    return data[data.rindex(")") + 2:].split()


def tree_cpu_seconds(pid: int) -> float:
    """utime + stime of ``pid`` and of its live descendants, plus children it has reaped."""
    children: Dict[int, List[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                ppid = int(_stat_fields(int(entry))[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    total = 0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            f = _stat_fields(p)
        except OSError:
            continue
        # Fields 14-17 of proc(5): utime stime cutime cstime (index 11.. after comm).
        total += int(f[11]) + int(f[12]) + int(f[13]) + int(f[14])
        todo.extend(children.get(p, []))
    return total / _TICK


# -- MJPEG clients --------------------------------------------------------------------------
@dataclass
class ClientStats:
    parts: List[Tuple[float, float, int]] = field(default_factory=list)  # (arrival, latency s, frame)
    error: Optional[str] = None


def part_headers(block: bytes) -> Dict[bytes, bytes]:
    """The headers of one multipart part (``name: value`` lines), names lower-cased."""
    headers = {}
    for line in block.split(b"\r\n"):
        name, sep, value = line.partition(b":")
        if sep:
            headers[name.strip().lower()] = value.strip()
    return headers


async def _mjpeg_client(session: "object", url: str, stats: ClientStats, stop: asyncio.Event) -> None:
    """Read parts of one multipart/x-mixed-replace stream until ``stop``; record each part."""
    import aiohttp

    assert isinstance(session, aiohttp.ClientSession)
    try:
        async with session.get(url) as resp:
            if resp.status != 200:
                stats.error = f"GET {url}: HTTP {resp.status}: {(await resp.text())[:200]}"
                return
            content = resp.content
            while not stop.is_set():
                block = await asyncio.wait_for(content.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
                headers = part_headers(block)
                if b"content-length" not in headers:
                    continue  # a preamble or a stray blank line before the next boundary
                length = int(headers[b"content-length"])
                await asyncio.wait_for(content.readexactly(length), STALL_TIMEOUT_S)
                now = time.time()
                ts = float(headers.get(b"x-timestamp", b"nan"))
                frame = int(headers.get(b"x-frame-number", b"-1"))
                stats.parts.append((time.monotonic(), now - ts, frame))
    except asyncio.TimeoutError:
        stats.error = f"GET {url}: no part for {STALL_TIMEOUT_S:g} s"
    except (aiohttp.ClientError, asyncio.IncompleteReadError, ValueError) as exc:
        if not stop.is_set():
            stats.error = f"GET {url}: {type(exc).__name__}: {exc}"


async def _status_counters(session: "object", base: str) -> Dict[str, Optional[float]]:
    """``frames``, ``drops`` and the camera stage's fps from ``/api/status`` (None where missing)."""
    import aiohttp

    assert isinstance(session, aiohttp.ClientSession)
    out: Dict[str, Optional[float]] = {"frames": None, "drops": None, "camera_fps": None}
    try:
        async with session.get(base + "/api/status") as resp:
            data = await resp.json()
    except Exception:  # noqa: BLE001 - diagnostic figures only; the run goes on without them
        return out
    for key in ("frames", "drops"):
        if isinstance(data.get(key), (int, float)):
            out[key] = float(data[key])
    fps = data.get("fps")
    if isinstance(fps, dict) and isinstance(fps.get("camera"), (int, float)):
        out["camera_fps"] = float(fps["camera"])
    return out


def _delta(a: Optional[float], b: Optional[float]) -> Optional[float]:
    return None if a is None or b is None else b - a


def _percentile(values: Sequence[float], q: float) -> float:
    s = sorted(values)
    if not s:
        return float("nan")
    k = (len(s) - 1) * q
    lo = int(k)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


async def _run_clients(base: str, pid: int, n: int, *, view: str, seconds: float, warmup: float,
                       query: str) -> Dict[str, object]:
    import aiohttp

    url = f"{base}/stream/{view}" + (f"?{query}" if query else "")
    stop = asyncio.Event()
    stats = [ClientStats() for _ in range(n)]
    connector = aiohttp.TCPConnector(limit=0)
    no_timeout = aiohttp.ClientTimeout(total=None)
    async with aiohttp.ClientSession(connector=connector, timeout=no_timeout) as session:
        tasks = [asyncio.ensure_future(_mjpeg_client(session, url, s, stop)) for s in stats]
        try:
            await asyncio.sleep(warmup)
            status0 = await _status_counters(session, base)
            cpu0, own0, t0 = tree_cpu_seconds(pid), time.process_time(), time.monotonic()
            await asyncio.sleep(seconds)
            cpu1, own1, t1 = tree_cpu_seconds(pid), time.process_time(), time.monotonic()
            status1 = await _status_counters(session, base)
        finally:
            stop.set()
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
    errors = [s.error for s in stats if s.error]
    if errors:
        raise ServeBenchError(f"{len(errors)} of {n} clients failed; first: {errors[0]}")
    window = t1 - t0
    per_client = [sum(1 for t, _, _ in s.parts if t0 <= t <= t1) for s in stats]
    latencies = [lat for s in stats for t, lat, _ in s.parts if t0 <= t <= t1]
    mean_frames = statistics.mean(per_client)
    if mean_frames == 0:
        raise ServeBenchError(f"no part of /stream/{view} arrived in {window:.2f} s with {n} clients")
    cpu = cpu1 - cpu0
    frames = _delta(status0["frames"], status1["frames"])
    drops = _delta(status0["drops"], status1["drops"])
    return {
        "clients": n,
        "window_s": round(window, 3),
        "delivered_fps_mean": round(mean_frames / window, 2),
        "delivered_fps_min": round(min(per_client) / window, 2),
        "frames_per_client_mean": round(mean_frames, 1),
        "daemon_cpu_s": round(cpu, 3),
        "daemon_cpu_share": round(cpu / window, 3),
        "cpu_s_per_frame": round(cpu / mean_frames, 5),
        "latency_ms_p50": round(1000 * _percentile(latencies, 0.5), 2),
        "latency_ms_p95": round(1000 * _percentile(latencies, 0.95), 2),
        "pipeline_fps": None if frames is None else round(frames / window, 2),
        "pipeline_drops": None if drops is None else int(drops),
        "camera_fps": status1["camera_fps"],
        "bench_client_cpu_s": round(own1 - own0, 3),
        "loadavg_1m": round(os.getloadavg()[0], 2),
    }


def measure_serve(*, seconds: float = 5.0, clients: Sequence[int] = (1, 20), fps: float = 60.0,
                  view: str = "rect_left", warmup: float = 1.0, query: str = "",
                  health_timeout: float = HEALTH_TIMEOUT_S) -> Dict[str, object]:
    """Start the daemon, run each client count in turn, stop the daemon; one JSON-able dict.

    ``cpu_ratio_<last>_vs_<first>`` compares ``cpu_s_per_frame`` of the last and first
    client counts (``cpu_ratio_20_vs_1`` by default). ``meets_floor`` applies the
    floors (delivered fps >= 55 for every client count, ratio <= 1.2); it is only
    meaningful at the default 60 fps.
    """
    if not clients or any(n < 1 for n in clients):
        raise ValueError(f"clients must be positive counts, got {list(clients)}")
    runs: Dict[str, Dict[str, object]] = {}
    with running_daemon(fps=fps, health_timeout=health_timeout) as (proc, base):
        for n in clients:
            runs[str(n)] = asyncio.run(_run_clients(base, proc.pid, n, view=view, seconds=seconds,
                                                    warmup=warmup, query=query))
            if proc.poll() is not None:
                raise ServeBenchError(
                    f"the daemon exited with code {proc.returncode} during the {n}-client run")
    first, last = runs[str(clients[0])], runs[str(clients[-1])]
    ratio = float(last["cpu_s_per_frame"]) / float(first["cpu_s_per_frame"])  # type: ignore[arg-type]
    ratio_key = f"cpu_ratio_{clients[-1]}_vs_{clients[0]}"
    meets = (all(float(r["delivered_fps_min"]) >= FLOOR_DELIVERED_FPS for r in runs.values())  # type: ignore[arg-type]
             and ratio <= FLOOR_CPU_RATIO)
    return {
        "view": view,
        "fps_target": fps,
        "seconds": seconds,
        "runs": runs,
        ratio_key: round(ratio, 3),
        "floor": {"delivered_fps_min": FLOOR_DELIVERED_FPS, "cpu_ratio": FLOOR_CPU_RATIO},
        "meets_floor": bool(meets),
    }


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m stereocam.bench.serve", description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--clients", default="1,20", help="comma-separated client counts (default 1,20)")
    p.add_argument("--fps", type=float, default=60.0)
    p.add_argument("--view", default="rect_left")
    args = p.parse_args(list(argv) if argv is not None else None)
    counts = [int(x) for x in args.clients.split(",") if x.strip()]
    try:
        result = measure_serve(seconds=args.seconds, clients=counts, fps=args.fps, view=args.view)
    except ServeBenchError as exc:
        print(f"bench_serve: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
