"""The Zynq VM's checks (scripts/zynq-vm): run once at boot, as root, by stereocam-vmcheck.service.

The service is installed as a user installs it (``stereocam install-service``) and then checked as a board
would meet it: READY within the unit's start timeout, the device nodes the board path opens reachable from
inside the unit's sandbox, the metrics endpoint, the memory left with every view watched, the watchdog
restarting a stopped daemon, a late-loading driver, a clean stop. Each check prints one line on the
console, ``ZYNQVM CHECK <name> ok|FAILED - <what was measured>``; then ``ZYNQVM DONE <passed> <failed>``,
and the machine reboots, which ends QEMU. Standard library only: it runs on Debian's python3.

"A process inside the unit's sandbox" is a child of this script moved into the unit's cgroup: the device
filter systemd attaches for ``DevicePolicy=closed``/``DeviceAllow=`` (a cgroup BPF program) is the cgroup's,
so it applies to every process in it, the daemon's and the probe's alike.
"""
from __future__ import annotations

import http.client
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

MARK = "ZYNQVM"
UNIT = "stereocam.service"
VENV = "/usr/local/share/pynq-venv"
PORT = 8080
BLOCK = Path("/etc/modprobe.d/zz-stereocam-vmcheck-block.conf")
DROP_IN = Path(f"/etc/systemd/system/{UNIT}.d/zz-vm-speed.conf")
# What the PYNQ image runs beside the daemon and the VM does not: Jupyter. A JupyterLab 4 server with one
# idle kernel measured 137 MiB resident on x86-64 (85 + 52; less on 32-bit ARM); 150 MiB is kept for it.
PYNQ_SERVICES_MIB = 150
MEM_FLOOR_MIB = 64
# How long a condition may take under emulation (one TCG-emulated A9 on a shared host) before it fails:
# the watchdog's restart took 630 s on a loaded machine (a fresh-clone run beside CPU-bound work).
WAIT_S = 1500.0
# Time the drop-in gives the emulated fabric to finish the frame it emulates when the daemon stops (56 s
# on that loaded machine); the check judges the rest of the stop at the A9's pace, not this.
EMULATION_STOP_S = 300

results: List[bool] = []


def say(*parts: object) -> None:
    print(MARK, *parts, flush=True)


def check(name: str, ok: bool, detail: str) -> bool:
    results.append(bool(ok))
    say("CHECK", name, "ok" if ok else "FAILED", "-", detail)
    return bool(ok)


def run(*cmd: str, timeout: float = WAIT_S) -> subprocess.CompletedProcess:
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, check=False)


def show(*props: str) -> Dict[str, str]:
    out = run("systemctl", "show", UNIT, *[f"--property={p}" for p in props]).stdout
    return dict(line.split("=", 1) for line in out.splitlines() if "=" in line)


def wait_for(what: Callable[[], bool], limit: float = WAIT_S, every: float = 1.0) -> bool:
    end = time.monotonic() + limit
    while time.monotonic() < end:
        if what():
            return True
        time.sleep(every)
    return what()


def meminfo() -> Dict[str, int]:
    """/proc/meminfo in KiB."""
    out = {}
    for line in Path("/proc/meminfo").read_text().splitlines():
        key, value = line.split(":", 1)
        out[key] = int(value.split()[0])
    return out


def uptime() -> float:
    """The guest's seconds since boot (the clock the journal's monotonic stamps use)."""
    return float(Path("/proc/uptime").read_text().split()[0])


def unit_cgroup() -> Path:
    """The unit's cgroup folder (cgroup 2)."""
    return Path(f"/sys/fs/cgroup{show('ControlGroup')['ControlGroup']}")


def loaded(module: str) -> bool:
    return Path("/sys/module", module.replace("-", "_")).is_dir()


def active_since_start() -> Optional[float]:
    """Seconds from the main process's start to the unit's READY (active), once it is active."""
    p = show("ActiveState", "SubState", "ExecMainStartTimestampMonotonic", "ActiveEnterTimestampMonotonic")
    if p.get("ActiveState") != "active" or p.get("SubState") != "running":
        return None
    start, ready = int(p["ExecMainStartTimestampMonotonic"]), int(p["ActiveEnterTimestampMonotonic"])
    return (ready - start) / 1e6


# The probe: a child moved into the unit's cgroup opens each node read-write; an I2C bus through the
# daemon's own driver (LinuxI2CBus.open, what the daemon calls when it brings the sensors up).
PROBE = r"""
import json, os, re, sys
procs, paths = sys.argv[1], sys.argv[2:]
with open(procs, "w") as f:
    f.write(str(os.getpid()))
from stereocam.drivers.i2c import I2CDenied, I2CError, LinuxI2CBus
out = {}
for path in paths:
    bus = re.fullmatch(r"/dev/i2c-(\d+)", path)
    try:
        if bus:
            with LinuxI2CBus(int(bus.group(1))):
                pass
        else:
            os.close(os.open(path, os.O_RDWR | os.O_CLOEXEC))
        out[path] = "opened"
    except I2CDenied:
        out[path] = "Operation not permitted"
    except I2CError as exc:
        out[path] = f"I2C error: {exc}"
    except OSError as exc:
        out[path] = os.strerror(exc.errno)
print(json.dumps(out))
"""

# The emulated fabric alone, as the daemon opens it, streaming: its anonymous memory beyond the imports,
# less the frame stores in its emulated DDR, which a board holds too (in CMA, through pynq.allocate).
EMULATION = r"""
import json, time
def anon():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("RssAnon:")) / 1024
import numpy, cv2
from stereocam.overlays.backend import open_overlay
from stereocam.overlays.model.stereo import compiled_path_installed
before = anon()
overlay = open_overlay("emulated", stereo=compiled_path_installed())
overlay.start()
first = overlay.frame_count()
end = time.monotonic() + 600
while overlay.frame_count() < first + 30 and time.monotonic() < end:
    time.sleep(0.5)
after = anon()
print(json.dumps({"frames": overlay.frame_count() - first, "anon_mib": after - before,
                  "ddr_mib": overlay.emulation.ddr.mem_used / 2**20}))
overlay.close()
"""


def probe(paths: List[str]) -> Dict[str, str]:
    """Open each path read-write from a process inside the unit's cgroup: 'opened' or the error's text."""
    procs = str(unit_cgroup() / "cgroup.procs")
    result = run(f"{VENV}/bin/python3", "-c", PROBE, procs, *paths, timeout=300)
    if result.returncode != 0:
        return {p: f"probe failed: {result.stderr.strip()[-200:]}" for p in paths}
    return json.loads(result.stdout)


def first(pattern: str) -> Optional[str]:
    found = sorted(Path("/dev").glob(pattern))
    return str(found[0]) if found else None


def watch(url: str, seen: Dict[str, int], stop: threading.Event) -> None:
    """Read an MJPEG stream until stopped, counting its bytes."""
    try:
        with urllib.request.urlopen(url, timeout=WAIT_S) as response:
            while not stop.is_set():
                chunk = response.read1(65536)  # what has come: a thumbnail at 1 fps is a few kB a second
                if not chunk:
                    return
                seen[url] = seen.get(url, 0) + len(chunk)
    except (OSError, http.client.HTTPException) as exc:
        seen.setdefault(url, 0)
        if not stop.is_set():
            say("note", f"stream {url}: {exc}")


# The VM's speed against the Cortex-A9's: the daemon's imports (`stereocam bench a9` counted them,
# "import.serve" in the packaged table) timed here, the page cache warm, as on a board's second start.
SPEED = r"""
import json, time
from importlib import resources
import stereocam.cli
start = time.perf_counter()
import stereocam.server.http.app
seconds = time.perf_counter() - start
table = json.loads(resources.files("stereocam.board").joinpath("a9_costs.json").read_text())
print(json.dumps({"seconds": seconds, "a9_ms": table["ops"]["import.serve"]["ms"]}))
"""


def a9_slowdown(cold: bool = True) -> Tuple[float, float, float]:
    """How many times longer this VM takes than a 650 MHz Cortex-A9 at 1.5 and at 1.0 cycles per instruction
    (a slow and a quick A9), and the seconds it took: QEMU's TCG on a shared host is several times slower,
    and more so while the host is busy (so a judgement at the A9's pace measures near its moment)."""
    if cold:
        run(f"{VENV}/bin/python3", "-c", SPEED)  # the page cache
    result = run(f"{VENV}/bin/python3", "-c", SPEED)
    if result.returncode != 0:
        raise RuntimeError(f"timing the daemon's imports failed: {result.stderr.strip()[-300:]}")
    got = json.loads(result.stdout)
    fast_ms, slow_ms = got["a9_ms"]
    return got["seconds"] / (slow_ms / 1000), got["seconds"] / (fast_ms / 1000), got["seconds"]


def board_stop_seconds() -> float:
    """TimeoutStopSec of the unit as stereocam ships it (what install-service writes)."""
    for unit in Path(VENV).glob("lib/python3*/site-packages/stereocam/board/stereocam.service"):
        for line in unit.read_text().splitlines():
            if line.startswith("TimeoutStopSec="):
                return float(line.split("=", 1)[1])
    raise RuntimeError(f"no TimeoutStopSec in the packaged unit under {VENV}")


def watched_memory() -> Dict[str, object]:
    """Every view the daemon lists watched as the page's thumbnails: the memory then."""
    with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/api/views", timeout=120) as response:
        names = [v["name"] for v in json.load(response)["views"]]
    stop = threading.Event()
    seen: Dict[str, int] = {}
    urls = [f"http://127.0.0.1:{PORT}/stream/{n}?scale=0.5" for n in names]
    threads = [threading.Thread(target=watch, args=(u, seen, stop), daemon=True) for u in urls]
    for t in threads:
        t.start()
    # Every stream has sent a good part of a frame, then a while longer for the memory to settle.
    flowing = wait_for(lambda: all(seen.get(u, 0) > 4096 for u in urls), limit=WAIT_S, every=2.0)
    time.sleep(30)
    info = meminfo()
    daemon_mib = int((unit_cgroup() / "memory.current").read_text()) / 2**20
    stop.set()
    end = time.monotonic() + 120
    for t in threads:  # each ends at its stream's next chunk
        t.join(timeout=max(0.0, end - time.monotonic()))
    return {"names": names, "flowing": flowing, "available": info["MemAvailable"] / 1024,
            "daemon": daemon_mib}


def emulation_memory() -> Dict[str, float]:
    result = run(f"{VENV}/bin/python3", "-c", EMULATION, timeout=WAIT_S)
    if result.returncode != 0:
        raise RuntimeError(f"measuring the emulated fabric failed: {result.stderr.strip()[-300:]}")
    return json.loads(result.stdout)


def memory_check(watched: Dict[str, object], emulation: Dict[str, float]) -> None:
    """What a 512 MiB board would have left: MemAvailable with every view watched, plus the emulated
    fabric's own memory (the board has no emulation), less a margin for PYNQ's own services."""
    available = float(watched["available"])
    own = max(0.0, emulation["anon_mib"] - emulation["ddr_mib"])
    left = available + own - PYNQ_SERVICES_MIB
    names = watched["names"]
    check("memory", bool(watched["flowing"]) and emulation["frames"] > 0 and left >= MEM_FLOOR_MIB,
          f"{len(names)} views watched ({', '.join(names)})"
          f"{'' if watched['flowing'] else ', NOT ALL FLOWING'}: MemAvailable {available:.0f} MiB, the "
          f"daemon's cgroup {float(watched['daemon']):.0f} MiB (page cache included); the emulated fabric's "
          f"own memory {own:.0f} MiB ({emulation['anon_mib']:.0f} MiB anonymous over "
          f"{emulation['frames']:.0f} frames, less its {emulation['ddr_mib']:.1f} MiB of frame stores, "
          f"which a board holds in CMA); left on a board: {available:.0f} + {own:.0f} - "
          f"{PYNQ_SERVICES_MIB} MiB for PYNQ's own services (Jupyter) = {left:.0f} MiB "
          f"(floor {MEM_FLOOR_MIB} MiB)")


def main() -> int:
    info = meminfo()
    say("BOOT", f"systemd reached multi-user {uptime():.0f} s after the kernel started;",
        f"MemTotal {info['MemTotal'] // 1024} MiB, CmaTotal {info.get('CmaTotal', 0) // 1024} MiB,",
        f"MemAvailable {info['MemAvailable'] // 1024} MiB; kernel {os.uname().release}")
    try:
        steps()
    except Exception as exc:  # a check that could not run is a failed check, said on the console
        check("run", False, f"{type(exc).__name__}: {exc}")
    passed = sum(results)
    # The guest's own clock at the end: the host compares it with its own (scripts/zynq-vm), since every
    # timeout above is counted on it.
    say("DONE", passed, len(results) - passed, f"{uptime():.1f}")
    run("systemctl", "--no-block", "reboot", timeout=60)
    return 0


def steps() -> None:
    # i2c-dev held back from modprobe@i2c-dev.service for the first start: its driver loads after the unit
    # started, as a driver loaded late by something else would.
    BLOCK.write_text("install i2c-dev /bin/true\n")
    check("i2c-dev held back", not loaded("i2c-dev"), "i2c-dev is not loaded before the service starts")

    # The unit's stop timeout is a board's: here, where the daemon runs slower than on an A9 and the emulated
    # fabric finishes the frame it emulates before it stops (seconds), systemd would kill it on the way. A
    # drop-in (as `systemctl edit` makes) gives it that many times the time and EMULATION_STOP_S for the
    # emulation; the stop check below judges the rest of the stop at the A9's pace against the unit's own
    # timeout.
    against_slow, against_quick, seconds = a9_slowdown()
    board_stop = board_stop_seconds()
    say("SPEED", f"the daemon's imports took {seconds:.1f} s here: {against_slow:.1f}-{against_quick:.1f} "
                 f"times a 650 MHz Cortex-A9's time (stereocam/board/a9_costs.json)")
    DROP_IN.parent.mkdir(parents=True, exist_ok=True)
    stop_s = math.ceil(board_stop * against_quick) + EMULATION_STOP_S
    DROP_IN.write_text(f"[Service]\nTimeoutStopSec={stop_s}\n")

    t0 = time.monotonic()
    install = run(f"{VENV}/bin/stereocam", "install-service")
    took = time.monotonic() - t0
    props = show("TimeoutStartUSec")
    ready = active_since_start()
    check("install-service", install.returncode == 0,
          f"exit {install.returncode} after {took:.0f} s: "
          + " / ".join((install.stdout + install.stderr).strip().splitlines()[-4:]))
    check("ready", ready is not None,
          f"READY=1 {ready:.0f} s after the daemon started, {ready / against_slow:.0f} s at a Cortex-A9's "
          f"pace (TimeoutStartSec={props.get('TimeoutStartUSec')})"
          if ready is not None else f"not active: {show('ActiveState', 'SubState', 'Result')}")

    # The drivers: uio_pdrv_genirq loaded by the unit's modprobe@ before it started; vgem (the render node,
    # as XRT's zocl gives one) and i2c-dev loaded now, after it started.
    BLOCK.unlink()
    late = {m: run("modprobe", m).returncode for m in ("vgem", "i2c-dev")}
    wait_for(lambda: first("dri/renderD*") is not None and first("i2c-*") is not None, limit=60)
    uio, render, i2c = first("uio*"), first("dri/renderD*"), first("i2c-*")
    check("drivers", loaded("uio_pdrv_genirq") and uio is not None and render is not None and i2c is not None,
          f"uio_pdrv_genirq loaded by modprobe@ before the unit ({uio}); after it started: vgem "
          f"(exit {late['vgem']}, {render}), i2c-dev (exit {late['i2c-dev']}, {i2c})")
    paths = ["/dev/mem"] + [p for p in (uio, render) if p] + ["/dev/mmcblk0"]
    opened = probe(paths + ([i2c] if i2c else []))
    wanted = {p: "opened" for p in paths if p != "/dev/mmcblk0"}
    check("devices", all(opened.get(p) == v for p, v in wanted.items())
          and opened.get("/dev/mmcblk0") == "Operation not permitted",
          "from inside the unit's sandbox: " + ", ".join(f"{p} {opened.get(p)}" for p in paths)
          + " (a block device: refused, as DevicePolicy=closed says)")
    if i2c:
        check("late i2c-dev refused", opened.get(i2c) == "Operation not permitted",
              f"{i2c}, whose driver loaded after the unit started, through the daemon's I2C driver: "
              f"{opened.get(i2c)} (systemd resolved DeviceAllow=char-i2c when the unit started; the daemon "
              f"says so and exits with status 75, and the restart below must allow it)")

    with urllib.request.urlopen(f"http://127.0.0.1:{PORT}/metrics", timeout=120) as response:
        body = response.read().decode("utf-8", "replace")
        kind = response.headers.get("Content-Type", "")
    families = sorted({line.split()[2] for line in body.splitlines() if line.startswith("# TYPE stereocam_")})
    check("metrics", kind.startswith("text/plain") and len(families) > 0,
          f"GET /metrics: {kind}, {len(families)} stereocam_ families")

    watched = watched_memory()

    # The watchdog: the daemon stopped (SIGSTOP) sends no WATCHDOG=1; systemd kills it after WatchdogSec and
    # restarts it. i2c-dev unloaded first: the restart's modprobe@i2c-dev must load it again, and the new
    # start's device list must allow /dev/i2c-*.
    before = show("MainPID", "NRestarts", "WatchdogUSec")
    run("rmmod", "i2c-dev")
    t0 = time.monotonic()
    os.kill(int(before["MainPID"]), signal.SIGSTOP)

    def restarted() -> bool:
        now = show("MainPID", "NRestarts", "ActiveState", "SubState")
        return (now.get("NRestarts") != before["NRestarts"]
                and now.get("MainPID") not in ("0", before["MainPID"])
                and now.get("ActiveState") == "active" and now.get("SubState") == "running")

    back = wait_for(restarted, limit=WAIT_S, every=2.0)
    took = time.monotonic() - t0
    journal = run("journalctl", "-u", UNIT, "--no-pager", "-o", "cat").stdout
    fired = "Watchdog timeout" in journal
    after = show("MainPID", "NRestarts")
    check("watchdog", back and fired,
          f"SIGSTOP to PID {before['MainPID']} (WatchdogSec {before.get('WatchdogUSec')}): "
          f"{'watchdog fired' if fired else 'NO watchdog timeout in the journal'}, "
          f"{'back' if back else 'NOT back'} as PID {after.get('MainPID')} "
          f"(restarts {after.get('NRestarts')}) after {took:.0f} s")
    i2c = first("i2c-*")
    opened = probe([i2c]) if i2c else {}
    check("i2c after restart", loaded("i2c-dev") and i2c is not None and opened.get(i2c) == "opened",
          f"modprobe@i2c-dev loaded i2c-dev again: {loaded('i2c-dev')}; {i2c} from inside the sandbox: "
          f"{opened.get(i2c)}")

    since = uptime()
    t0 = time.monotonic()
    stop = run("systemctl", "stop", UNIT)
    took = time.monotonic() - t0
    # What the daemon said while it stopped, with the guest's seconds since boot.
    journal = run("journalctl", "-u", UNIT, "--no-pager", "-o", "short-monotonic", "-n", "40").stdout
    emulated_s = 0.0
    for line in journal.splitlines():
        stamp = line[1:line.find("]")].strip() if line.startswith("[") else ""
        if stamp.replace(".", "", 1).isdigit() and float(stamp) >= since:
            say("journal", line)
            found = re.search(r"the emulated fabric in ([0-9.]+) s", line)
            if found:
                emulated_s = float(found.group(1))
    p = show("Result", "ActiveState", "TimeoutStopUSec", "ExecMainCode", "ExecMainStatus")
    # Result "success": the daemon left on SIGTERM (else "timeout", after a SIGKILL); and the rest of the stop
    # but the emulated fabric's (it finishes the frame it emulates first; a board's fabric stops at once),
    # at a slow A9's pace, within the TimeoutStopSec install-service wrote.
    clean = stop.returncode == 0 and p.get("Result") == "success" and p.get("ActiveState") == "inactive"
    # The host's load changes over the run (the other test envs beside the VM): the VM's speed measured
    # again now, and the slower of the two readings taken.
    after_slow, _, after_seconds = a9_slowdown(cold=False)
    say("SPEED", f"after the stop, the daemon's imports took {after_seconds:.1f} s here: {after_slow:.1f} "
                 f"times a slow Cortex-A9's time (before the start: {against_slow:.1f})")
    board_s = max(0.0, took - emulated_s) / max(against_slow, after_slow)
    check("stop", clean and board_s <= board_stop,
          f"systemctl stop took {took:.1f} s here, {emulated_s:.1f} s of it the emulated fabric's; the rest "
          f"{board_s:.1f} s at a Cortex-A9's pace (the unit's TimeoutStopSec={board_stop:g}; here "
          f"{p.get('TimeoutStopUSec')}), result {p.get('Result')}, main process code {p.get('ExecMainCode')} "
          f"status {p.get('ExecMainStatus')}")

    # With the service stopped, the emulated fabric alone, for the memory check's reckoning.
    memory_check(watched, emulation_memory())


if __name__ == "__main__":
    socket.setdefaulttimeout(WAIT_S)
    try:
        status = main()
    except BaseException as exc:  # never leave the VM running: the host waits for the reboot
        say("DONE", 0, 1, f"{type(exc).__name__}: {exc}")
        run("systemctl", "--no-block", "reboot", timeout=60)
        raise
    sys.exit(status)
