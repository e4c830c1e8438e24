"""``stereocam bench a9``: what each per-frame operation of the daemon costs a Cortex-A9, counted.

No board is needed. The operations run as armhf code (the armhf test environment's Debian
userland: its Python, numpy, OpenCV, libjpeg-turbo) under QEMU's user-mode emulator with a TCG
plugin of ours (``insn_marks.c``) that counts the instructions executed between marks the guest
script (``measure.py``) makes around each operation. Instructions become time through a stated
range of cycles per instruction at the board's 650 MHz: an A9 is dual-issue but stalls on memory,
and counting cannot say which; the range says so instead of one number.

The table it writes (``stereocam/board/a9_costs.json``, read by :mod:`stereocam.board.a9_costs`) is
what the CPU budget plans with on the board until it has measured a cost itself. Its
``fingerprint`` is the hash of the files whose code it measured (``a9_costs.MEASURED``): a test
fails when one of them changed and the table was not measured again.

Needs, on the host: a checkout (its ``scripts/_env.sh`` builds the armhf rootfs, cached),
Debian's ``qemu-user`` (a dynamic ``qemu-arm``: ``qemu-arm-static`` cannot load plugins), ``proot``
and a C compiler. libjpeg-turbo decides on NEON by reading ``/proc/cpuinfo``, which under proot is
the host's; ``JSIMD_FORCENEON=1`` gives it the NEON an A9 has.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Dict, List, Mapping, Sequence

from ...board.a9_costs import TABLE, fingerprint

HERE = Path(__file__).resolve().parent
PLUGIN_SOURCE = HERE / "insn_marks.c"
CLOCK_HZ = 650_000_000  # the Zynq-7020's Cortex-A9 (-1 speed grade) as PYNQ boards run it
CPI = (1.0, 1.5)  # cycles per instruction: the range the table states


class A9Error(Exception):
    """What the command cannot do, and what to do about it."""


def per_op(marks: Mapping[int, int], ops: Sequence[Mapping[str, Any]]) -> Dict[str, int]:
    """Instructions per run of each operation: the count between its two marks over its repetitions."""
    out: Dict[str, int] = {}
    for op in ops:
        start, reps = int(op["mark"]), int(op["reps"])
        if start not in marks or start + 1 not in marks:
            raise A9Error(f"the plugin saw no marks {start} and {start + 1} around {op['name']}")
        out[str(op["name"])] = round((marks[start + 1] - marks[start]) / max(1, reps))
    return out


def read_marks(text: str) -> Dict[int, int]:
    """The plugin's file: ``index count`` lines (and a final ``exit count``)."""
    marks: Dict[int, int] = {}
    for line in text.splitlines():
        key, _, value = line.partition(" ")
        if key.isdigit() and value.strip().isdigit():
            marks[int(key)] = int(value)
    return marks


def table_of(counts: Mapping[str, int], guest: Mapping[str, Any], qemu: str) -> Dict[str, Any]:
    """The table: each operation's instructions and milliseconds at :data:`CPI` and :data:`CLOCK_HZ`."""
    def ms(n: int, cpi: float) -> float:
        return round(n * cpi / CLOCK_HZ * 1000, 3)

    return {
        "about": "Instructions per run of each per-frame operation of the daemon, counted as armhf code "
                 "under QEMU with the insn_marks plugin, and milliseconds on a 650 MHz Cortex-A9 at 1.0 to "
                 "1.5 cycles per instruction. Written by `stereocam bench a9`: do not edit.",
        "cpu": {"name": "Cortex-A9", "clock_hz": CLOCK_HZ, "cpi": list(CPI)},
        "measured_with": {"qemu": qemu, "python": guest.get("python"), "numpy": guest.get("numpy"),
                          "opencv": guest.get("opencv"), "frame": guest.get("frame")},
        "fingerprint": fingerprint(),
        "ops": {name: {"instructions": n, "ms": [ms(n, CPI[0]), ms(n, CPI[1])]}
                for name, n in counts.items()},
    }


# -- running it ---------------------------------------------------------------------------------

def _tool(name: str, package: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise A9Error(f"{name} is not installed: apt-get install {package}")
    return path


def checkout_root() -> Path:
    root = HERE.parent.parent.parent  # the folder holding the stereocam package
    if not (root / "scripts" / "_env.sh").is_file():
        raise A9Error(f"{root} is not a stereocam checkout (no scripts/_env.sh): run the bench from a clone, "
                      "whose scripts build the armhf environment")
    return root


def armhf_rootfs(root: Path) -> Path:
    """The armhf environment's rootfs, built and cached by the checkout's scripts (minutes the first time)."""
    script = f'source "{root}/scripts/_env.sh" && setup_armhf >&2 && printf "%s" "$ARMHF_ROOTFS"'
    done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, check=False)
    if done.returncode != 0 or not done.stdout.strip():
        raise A9Error(f"the armhf rootfs could not be set up: {done.stderr.strip()[-800:]}")
    return Path(done.stdout.strip())


def build_plugin(out_dir: Path) -> Path:
    cc = shutil.which("cc") or _tool("gcc", "gcc")
    plugin = out_dir / "insn_marks.so"
    done = subprocess.run([cc, "-shared", "-fPIC", "-O2", "-fvisibility=hidden", "-Wall", "-o", str(plugin),
                           str(PLUGIN_SOURCE)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise A9Error(f"the plugin did not build: {done.stderr.strip()}")
    return plugin


def qemu_version(qemu: str) -> str:
    done = subprocess.run([qemu, "--version"], capture_output=True, text=True, check=False)
    first = (done.stdout.splitlines() or [""])[0]
    return first.replace("qemu-arm version ", "").strip() or "unknown"


def measure(*, timeout: float = 3600.0) -> Dict[str, Any]:
    """Run ``measure.py`` under ``qemu-arm`` with the plugin; the table of what it counted."""
    qemu = _tool("qemu-arm", "qemu-user")
    proot = _tool("proot", "proot")
    root = checkout_root()
    rootfs = armhf_rootfs(root)
    with tempfile.TemporaryDirectory(prefix="stereocam-a9-") as tmp:
        work = Path(tmp)
        build_plugin(work)
        env = {"PATH": "/usr/local/bin:/usr/bin:/bin", "HOME": "/root", "LANG": "C.UTF-8",
               "PYTHONPATH": str(root), "PYTHONDONTWRITEBYTECODE": "1", "JSIMD_FORCENEON": "1"}
        cmd = [sys.executable, str(root / "scripts" / "_enosys_exec.py"), proot,
               "-q", f"{qemu} -cpu cortex-a9 -plugin /a9/insn_marks.so,out=/a9/marks.txt",
               "-r", str(rootfs), "-b", "/dev", "-b", "/proc", "-b", "/sys", "-b", str(root),
               "-b", f"{work}:/a9", "-w", str(root), "/usr/bin/python3", "-m", "stereocam.bench.a9.measure"]
        try:
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            raise A9Error(f"the measurement did not finish within {timeout:g} s") from None
        if done.returncode != 0:
            raise A9Error(f"the measurement failed under qemu-arm: {done.stderr.strip()[-1200:]}")
        lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
        if not lines:
            raise A9Error(f"the guest printed no result: {done.stdout[-400:]} {done.stderr[-400:]}")
        guest = json.loads(lines[-1])
        marks = read_marks((work / "marks.txt").read_text())
    return table_of(per_op(marks, guest["ops"]), guest, qemu_version(qemu))


def format_table(table: Mapping[str, Any]) -> str:
    cpu = table["cpu"]
    lines = [f"{'operation':<34} {'instructions':>14}  ms on a {cpu['clock_hz'] / 1e6:g} MHz {cpu['name']} "
             f"(CPI {cpu['cpi'][0]:g} to {cpu['cpi'][1]:g})"]
    for name, op in table["ops"].items():
        lines.append(f"{name:<34} {op['instructions']:>14,}  {op['ms'][0]:>9.1f} to {op['ms'][1]:.1f}")
    return "\n".join(lines)


def add_parser(bench_sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """``stereocam bench a9``, added to the ``bench`` group by the CLI."""
    p = bench_sub.add_parser(
        "a9", help="count what each per-frame operation costs a Cortex-A9 (armhf code under QEMU)",
        description="What each per-frame operation of the daemon costs the board's 650 MHz Cortex-A9, "
                    "counted: the operations run as armhf code (the armhf test environment's Debian "
                    "userland) under qemu-arm with a plugin counting their instructions. Writes the "
                    "table the CPU budget plans with on the board. Needs a checkout, Debian's "
                    "qemu-user and proot, and a C compiler.")
    p.add_argument("--out", type=Path, default=TABLE, help=f"where the table goes (default {TABLE})")
    p.add_argument("--timeout", type=float, default=3600.0, help="give up after S seconds (default 3600)")
    p.add_argument("--json", action="store_true", help="print the table as JSON instead of text")
    p.set_defaults(func=cmd_bench_a9)


def cmd_bench_a9(args: argparse.Namespace) -> int:
    started = time.monotonic()
    try:
        table = measure(timeout=args.timeout)
        args.out.write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
    except (A9Error, OSError) as exc:
        print(f"stereocam bench a9: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(table) if args.json else format_table(table))
    print(f"wrote {args.out} ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    return 0


__all__: List[str] = ["A9Error", "add_parser", "per_op", "read_marks", "table_of", "measure"]
