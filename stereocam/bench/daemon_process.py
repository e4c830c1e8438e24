"""The daemon the robustness bench runs as a process: starting it, asking it, its memory and its log."""
from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path
from typing import Any, Iterator, List, Optional, Tuple

from .raw_http import RobustnessBenchError, get_json

TOKEN = "hostile-bench-token"


def _config_file(folder: Path) -> Path:
    path = folder / "stereocam.yaml"
    path.write_text(f"access_token: {TOKEN}\nprotect: control\n")
    return path


@contextlib.contextmanager
def daemon(*, fps: float, log_path: Path, folder: Optional[Path] = None,
           health_timeout: float = 60.0) -> Iterator[Tuple[Any, str]]:
    """``stereocam serve`` at ``fps`` with an access token (``protect: control``), its log in ``log_path``,
    its settings file, captures (``captures/``) and state in ``folder`` (a temporary one when None):
    ``(process, base URL)``."""
    from .serve import ServeBenchError, running_daemon

    with contextlib.ExitStack() as stack:
        if folder is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="stereocam-robustness-")))
        config = _config_file(folder)
        try:
            with running_daemon(fps=fps, log_path=log_path, health_timeout=health_timeout,
                                captures=folder / "captures", extra_args=["--config", str(config)]) as run:
                yield run
        except ServeBenchError as exc:
            raise RobustnessBenchError(str(exc)) from None


async def daemon_facts(port: int) -> Tuple[Tuple[int, int], str]:
    """The daemon's frame size and the calibration it runs (``GET /api/calibration``'s ``yaml``)."""
    status = await get_json(port, "/api/status")
    cal = await get_json(port, "/api/calibration")
    w, h = status["frame_size"]
    return (int(w), int(h)), str(cal["yaml"] or "")


def rss_mb(pid: int) -> float:
    """The resident memory of process ``pid`` (``VmRSS``), in MB (10^6 bytes)."""
    with open(f"/proc/{pid}/status", "rb") as f:
        for line in f:
            if line.startswith(b"VmRSS:"):
                return int(line.split()[1]) * 1024 / 1e6
    raise RobustnessBenchError(f"/proc/{pid}/status has no VmRSS")


def log_tracebacks(text: str) -> List[str]:
    """The lines of a daemon log that start a traceback, with the line before (what logged it)."""
    lines = text.splitlines()
    return [" | ".join(lines[max(0, i - 1):i + 1]) for i, line in enumerate(lines) if "Traceback" in line]
