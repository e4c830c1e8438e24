"""``stereocam bench robustness``: the daemon under hostile and slow clients, each figure against its floor.

The floors, measured on ``stereocam serve`` run as a subprocess on the
emulated fabric (its log and its resident memory are its own):

``barrage``
    ``requests`` malformed requests (2,000 by default) from :func:`.malformed.malformed_requests`
    (multipart uploads, JSON bodies, YAML calibrations, headers, request lines, on
    every endpoint that takes them), sent as raw bytes over ``concurrency``
    connections at once while one MJPEG client reads ``/stream/rect_left``.
    ``stream_max_gap_s`` (floor 1 s): the longest time that client went without a
    part, from the first request sent to the last answer received (``stream_parts``
    parts, ``no_signal_parts`` of them "NO SIGNAL" frames); ``status_5xx`` (floor 0):
    answers 500-599; ``tracebacks`` (floor 0): lines of the daemon's log holding
    ``Traceback``; ``rss_delta_mb`` (floor 50): the daemon's resident memory after the
    barrage (``rss_end_mb``, waiting up to ``settle_s`` for it to come down) less the
    memory it had after a warm-up round (``rss_start_mb``, one request of each kind:
    lazy imports and first-use buffers are not a leak); ``rss_peak_mb`` is the most
    seen during the barrage. ``statuses`` counts the answers by status, ``unexpected``
    lists requests whose answer is not one the case allows (:meth:`.malformed_case.Case.complaint`).
``alias_bomb``
    ``PUT /api/calibration`` of three "billion laughs" calibrations (the classic one;
    a valid calibration followed by one; one after 240 KB of valid YAML), ``rounds``
    each: ``ms_max`` (floor 100 ms) and ``ms_median``, wall time per request on this
    side; ``statuses`` (400 expected).
``slow_reader``
    One client reads ``/stream/rect_right`` one part per ``read_interval_s`` through a
    4 KB receive buffer, ``reads`` times. The daemon records, for each frame it sends a
    client, how far that frame lagged the newest frame it had (``/api/status``,
    ``streams[].lag_max_frames`` and ``lag_max_s``): ``lag_max_periods`` (floor 2) is the
    largest in frame periods of the cameras (frame numbers count the cameras' frames, so a
    machine too busy for ``--fps`` does not inflate it), ``lag_max_s`` the same in seconds;
    ``read_age_max_s`` is the age of the parts when this client read them (from their
    ``X-Timestamp``), for comparison: a reader that takes one part every 0.5 s holds frames
    about that long in its own buffers.

``meets_floor`` is true when every floor is met; the command exits 1 otherwise (2
when the daemon does not start). Machines are shared: the figures are measured under
whatever load there is (``loadavg_1m`` says how much).

Blocking: :func:`measure_robustness` blocks (it runs its own event loop); the
``async`` functions of :mod:`.barrage`, :mod:`.alias_bomb` and :mod:`.slow_reader` are for
callers that have a daemon already (the tests). The requests are made in :mod:`.malformed`,
the daemon run in :mod:`.daemon_process`.
"""
from __future__ import annotations

import argparse
import asyncio
import os
import tempfile
from pathlib import Path
from typing import Any, Dict, List

from .alias_bomb import FLOOR_ALIAS_BOMB_MS, time_alias_bombs
from .barrage import FLOOR_5XX, FLOOR_RSS_DELTA_MB, FLOOR_STREAM_GAP_S, FLOOR_TRACEBACKS, run_barrage
from .daemon_process import daemon, daemon_facts, log_tracebacks
from .malformed import malformed_requests
from .raw_http import RobustnessBenchError
from .report import run_suite
from .slow_reader import FLOOR_LAG_PERIODS, slow_reader


def measure_robustness(*, requests: int = 2000, fps: float = 60.0, concurrency: int = 6, rounds: int = 5,
                       reads: int = 12, settle_s: float = 30.0) -> Dict[str, Any]:
    """Start the daemon, run the three measurements, stop it; one JSON-able dict (see the module doc)."""
    with tempfile.TemporaryDirectory(prefix="stereocam-bench-robustness-log-") as tmp:
        log_path = Path(tmp) / "daemon.log"
        with daemon(fps=fps, log_path=log_path) as (proc, base):
            port = int(base.rsplit(":", 1)[1])

            async def run() -> Dict[str, Any]:
                frame_size, calibration = await daemon_facts(port)
                cases = malformed_requests(requests, frame_size=frame_size, calibration_yaml=calibration)
                barrage = await run_barrage(port, proc.pid, cases, concurrency=concurrency, settle_s=settle_s)
                bombs = await time_alias_bombs(port, calibration, rounds=rounds)
                reader = await slow_reader(port, reads=reads)
                return {"barrage": barrage.figures(), "alias_bomb": bombs, "slow_reader": reader}

            result = asyncio.run(run())
            if proc.poll() is not None:
                raise RobustnessBenchError(f"the daemon exited with code {proc.returncode} during the bench")
        tracebacks = log_tracebacks(log_path.read_text(errors="replace"))
    result["barrage"]["tracebacks"] = len(tracebacks)
    result["barrage"]["traceback_lines"] = tracebacks[:10]
    client = result["slow_reader"]["client"]
    result["slow_reader"]["lag_max_s"] = client["lag_max_s"]
    result["slow_reader"]["lag_max_frames"] = client["lag_max_frames"]
    result["slow_reader"]["lag_max_periods"] = int(client["lag_max_frames"])
    result["fps"] = fps
    result["loadavg_1m"] = round(os.getloadavg()[0], 2)
    result["floor"] = {"stream_max_gap_s": FLOOR_STREAM_GAP_S, "status_5xx": FLOOR_5XX,
                       "tracebacks": FLOOR_TRACEBACKS, "rss_delta_mb": FLOOR_RSS_DELTA_MB,
                       "alias_bomb_ms": FLOOR_ALIAS_BOMB_MS, "slow_reader_lag_periods": FLOOR_LAG_PERIODS}
    result["meets"] = meets(result)
    result["meets_floor"] = all(result["meets"].values())
    return result


def meets(result: Dict[str, Any]) -> Dict[str, bool]:
    """Each floor against its figure in ``result``."""
    barrage, bomb, reader = result["barrage"], result["alias_bomb"], result["slow_reader"]
    return {
        "stream_max_gap_s": barrage["stream_max_gap_s"] <= FLOOR_STREAM_GAP_S,
        "status_5xx": barrage["status_5xx"] <= FLOOR_5XX,
        "tracebacks": barrage["tracebacks"] <= FLOOR_TRACEBACKS,
        "rss_delta_mb": barrage["rss_delta_mb"] <= FLOOR_RSS_DELTA_MB,
        "requests": barrage["requests"] >= 2000,
        "alias_bomb_ms": bomb["ms_max"] < FLOOR_ALIAS_BOMB_MS and set(bomb["statuses"]) == {"400"},
        "slow_reader_lag_periods": reader["lag_max_periods"] <= FLOOR_LAG_PERIODS,
    }


def text_lines(result: Dict[str, Any]) -> List[str]:
    """One line per figure: the figure, its floor, and whether it is met."""
    ok = result["meets"]
    barrage, bomb, reader = result["barrage"], result["alias_bomb"], result["slow_reader"]

    def mark(key: str) -> str:
        return "ok" if ok[key] else "MISSED"

    kinds = ", ".join(f"{k} {v}" for k, v in barrage["kinds"].items())

    return [
        f"malformed requests {barrage['requests']} in {barrage['seconds']} s ({kinds}); "
        f"answers {barrage['statuses']}: floor 2000 [{mark('requests')}]",
        f"5xx answers        {barrage['status_5xx']}: floor 0 [{mark('status_5xx')}]",
        f"log tracebacks     {barrage['tracebacks']}: floor 0 [{mark('tracebacks')}]",
        f"stream max gap     {barrage['stream_max_gap_s']} s ({barrage['stream_parts']} parts, "
        f"{barrage['no_signal_parts']} NO SIGNAL): floor {FLOOR_STREAM_GAP_S:g} s "
        f"[{mark('stream_max_gap_s')}]",
        f"memory             {barrage['rss_delta_mb']:+} MB ({barrage['rss_start_mb']} MB after the warm-up, "
        f"peak {barrage['rss_peak_mb']}, end {barrage['rss_end_mb']}): floor +{FLOOR_RSS_DELTA_MB:g} MB "
        f"[{mark('rss_delta_mb')}]",
        f"alias bomb         {bomb['ms_max']} ms at most, {bomb['ms_median']} ms median "
        f"({bomb['statuses']}): "
        f"floor {FLOOR_ALIAS_BOMB_MS:g} ms [{mark('alias_bomb_ms')}]",
        f"slow reader        frames lag the newest by {reader['lag_max_periods']} frame periods at most when "
        f"sent ({reader['lag_max_s']} s; parts {reader['read_age_max_s']} s old when read): "
        f"floor {FLOOR_LAG_PERIODS:g} [{mark('slow_reader_lag_periods')}]",
        f"machine            load {result['loadavg_1m']}, camera {result['fps']:g} fps",
    ]


def run_robustness(args: argparse.Namespace) -> int:
    """``stereocam bench robustness``: print the figures (text or ``--json``); exit 1 below a floor."""
    return run_suite("robustness",
                     lambda: measure_robustness(requests=args.requests, fps=args.fps,
                                                concurrency=args.concurrency, rounds=args.rounds,
                                                reads=args.reads, settle_s=args.settle),
                     (RobustnessBenchError,), args.json, text_lines)


def add_robustness_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench robustness``, a suite of ``stereocam bench`` (``sub`` is its subparsers)."""
    p = sub.add_parser("robustness",
                       help="the daemon under hostile and slow clients, against issue 10's floors",
                       description="Malformed requests, a YAML alias bomb and a slow stream reader against "
                                   "`stereocam serve` on the emulated fabric; each figure against its floor "
                                   "(exit 1 when one is missed).")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_arguments(p)
    p.set_defaults(func=run_robustness)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``stereocam bench robustness``."""
    p.add_argument("--requests", type=int, default=2000, metavar="N",
                   help="malformed requests (default 2000)")
    p.add_argument("--fps", type=float, default=60.0, help="the emulated cameras' rate (default 60)")
    p.add_argument("--concurrency", type=int, default=6, metavar="N", help="requests in flight (default 6)")
    p.add_argument("--rounds", type=int, default=5, metavar="N", help="PUTs of each alias bomb (default 5)")
    p.add_argument("--reads", type=int, default=12, metavar="N",
                   help="parts the slow reader reads (default 12)")
    p.add_argument("--settle", type=float, default=30.0, metavar="S",
                   help="seconds to wait for the memory to come down after the barrage (default 30)")
