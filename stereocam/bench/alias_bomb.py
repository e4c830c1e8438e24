"""The "billion laughs" in a calibration, and the time the daemon takes to refuse it."""
from __future__ import annotations

import statistics
import time
from typing import Any, Dict, List, Optional

from .daemon_process import TOKEN
from .raw_http import http_request, send_raw

FLOOR_ALIAS_BOMB_MS = 100.0


def billion_laughs(levels: int = 12, width: int = 10, indent: str = "", prefix: str = "a") -> str:
    """The "billion laughs": ``width ** levels`` leaves from a few hundred bytes."""
    lines = [f"{indent}{prefix}0: &{prefix}0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"{indent}{prefix}{i}: &{prefix}{i} [{', '.join([f'*{prefix}{i - 1}'] * width)}]")
    return "\n".join(lines) + "\n"


def alias_bombs(calibration_yaml: str) -> Dict[str, str]:
    """The three calibrations the ``alias_bomb`` figure times (see :mod:`.robustness`)."""
    filler = "notes:\n" + "".join(f"  - [{i}.5, {i}.25, {i}.125, {i}.0625]\n" for i in range(9000))
    return {"classic": billion_laughs(),
            "after a calibration": calibration_yaml + "bomb:\n" + billion_laughs(indent="  "),
            "after 240 KB": calibration_yaml + filler[:240_000 - len(calibration_yaml)].rsplit("\n", 1)[0]
            + "\nbomb:\n" + billion_laughs(indent="  ")}


async def time_alias_bombs(port: int, calibration_yaml: str, *, rounds: int = 5,
                           token: Optional[str] = TOKEN) -> Dict[str, Any]:
    """PUT each of :func:`alias_bombs` ``rounds`` times: wall time per answer and the statuses."""
    times: Dict[str, List[float]] = {}
    statuses: Dict[str, int] = {}
    for _ in range(rounds):
        for name, text in alias_bombs(calibration_yaml).items():
            data = http_request(b"PUT", b"/api/calibration", text.encode(), token=token,
                                headers=[(b"Content-Type", b"application/yaml")])
            t0 = time.perf_counter()
            status, answer = await send_raw(port, data)
            times.setdefault(name, []).append(time.perf_counter() - t0)
            key = str(status)
            statuses[key] = statuses.get(key, 0) + 1
    every = [t for ts in times.values() for t in ts]
    return {
        "rounds": rounds,
        "ms_max": round(1000 * max(every), 2),
        "ms_median": round(1000 * statistics.median(every), 2),
        "ms_max_by_file": {name: round(1000 * max(ts), 2) for name, ts in times.items()},
        "ms_median_by_file": {name: round(1000 * statistics.median(ts), 2) for name, ts in times.items()},
        "bytes_by_file": {name: len(text.encode()) for name, text in alias_bombs(calibration_yaml).items()},
        "statuses": statuses,
    }
