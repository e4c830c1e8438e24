"""`stereocam serve` imports only what it serves with (issue 25 item 4: imports cost 5.7-8.5 s on the A9).

Each check runs in a fresh Python, so that nothing a test imported before counts.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from stereocam.cli import command_of

REPO = Path(__file__).resolve().parents[2]
# What the serve path leaves for later: the benchmarks and the HDL tools (other commands), the HTTP client
# (a library for scripts), SciPy (nothing of the daemon needs it), numba (the stereo tools' fast path) and
# Pillow (the uploads' reader, imported at the first upload).
DEFERRED = ("stereocam.bench", "stereocam.overlays.rtl.synth", "stereocam.overlays.rtl.timing",
            "stereocam.client", "scipy", "numba", "PIL")
# What `import stereocam.cli` leaves for later: everything heavy, so that `serve`'s start-up notifier
# (systemd.loading) runs before it.
HEAVY = ("numpy", "cv2", "aiohttp", "PIL", "yaml", "stereocam.server.http.app", "stereocam.overlays")


def loaded_after(code: str) -> list:
    """The modules a fresh Python has loaded after running ``code``."""
    script = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))\n"
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    return list(json.loads(done.stdout.splitlines()[-1]))


def matching(modules: list, prefixes: tuple) -> list:
    return [m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes)]


def test_importing_the_cli_imports_nothing_heavy() -> None:
    modules = loaded_after("import stereocam.cli")
    assert matching(modules, HEAVY) == []


def test_the_serve_path_does_not_import_the_deferred_modules() -> None:
    """Everything `stereocam serve` imports before READY=1: its parser, the daemon, its extensions, the
    emulated fabric (the fallback on a board without its bitstream)."""
    modules = loaded_after(
        "import stereocam.cli as cli\n"
        "cli.build_parser(cli.command_of(['serve', '--port', '0'])).parse_args(['serve', '--port', '0'])\n"
        "from stereocam.server.http import app\n"
        "app.default_extensions()\n"
        "import stereocam.overlays.emulated.overlay\n")
    assert "stereocam.server.http.app" in modules and "aiohttp" in modules, "the check saw the serve path"
    assert matching(modules, DEFERRED) == []
    # ... which the other commands still have.
    everything = loaded_after("import stereocam.cli as cli\ncli.build_parser()")
    assert {"stereocam.bench.budget", "stereocam.overlays.rtl.synth"} <= set(everything)


def test_the_command_is_found_before_the_parser_is_built() -> None:
    assert command_of(["serve", "--port", "1"]) == "serve"
    assert command_of(["--log-level", "debug", "-v", "serve"]) == "serve"
    assert command_of(["bench", "budget"]) == "bench"
    assert command_of(["--help"]) is None and command_of([]) is None and command_of(["--version"]) is None


def test_help_still_lists_every_command_and_suite() -> None:
    done = subprocess.run([sys.executable, "-m", "stereocam.cli", "bench", "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "budget" in done.stdout and "robustness" in done.stdout, done.stderr
    done = subprocess.run([sys.executable, "-m", "stereocam.cli", "--help"], cwd=REPO, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0 and all(c in done.stdout for c in ("serve", "bench", "hw", "rectify"))
    assert done.stderr == ""
