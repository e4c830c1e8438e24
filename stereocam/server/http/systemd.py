"""systemd integration: ``sd_notify`` (no dependency), the service unit, ``stereocam install-service``.

The unit (``stereocam/board/stereocam.service`` is :func:`unit_text` with the defaults)
runs the daemon as ``Type=notify``: it says ``READY=1`` once it listens, and
sends ``WATCHDOG=1`` only while the frame pipeline's thread is alive and
iterating, so a pipeline stuck in a driver call gets the service killed and
restarted (``Restart=on-failure``). It runs in the PYNQ image's virtual
environment (``/usr/local/share/pynq-venv``) with the environment a login
shell on the image gets: ``/etc/environment`` (exported, as pam_env does),
then every ``/etc/profile.d/*.sh`` in order, as ``/etc/profile`` does. On a
PYNQ 3 image those are ``pynq_venv.sh`` (activates the venv), ``xrt_setup.sh``
(``XILINX_XRT=/usr``: without it pynq registers no device, "No Devices Found")
and ``boardname.sh`` (``BOARD``). They are shell scripts, not
``EnvironmentFile``s, so the unit sources them in ``bash -c`` and then
``exec``s the daemon (which keeps the main PID, as ``NotifyAccess=main``
needs). Port 8080: the PYNQ image serves on 80 and Jupyter on 9090.

Hardened to what the daemon needs (``systemd-analyze security``: 2.2, "OK";
a test keeps it at most 5.0): root with only ``CAP_SYS_RAWIO`` (pynq maps the
fabric's registers through ``/dev/mem``, and insists on root), a read-only
system but for the state folder, ``/run/stereocam`` (the fabric lock), and
what pynq writes when it programs the fabric (``/lib/firmware`` and its own
record in the venv), only the devices the board needs (``/dev/mem``,
``/dev/uio*``, ``/dev/i2c-*``, XRT's ``/dev/dri/renderD*``), a system-call
filter. Its log lines carry syslog priorities (see :func:`stereocam.cli.setup_logging`).
"""
from __future__ import annotations

import os
import shlex
import socket
import subprocess
from pathlib import Path
from typing import Callable, List, Optional, Sequence

__all__ = [
    "notify", "watchdog_interval", "unit_text", "default_config_text", "install_service", "ServiceError",
    "PYNQ_VENV", "UNIT_NAME", "RESERVED_PORTS", "DEVICES",
]

PYNQ_VENV = "/usr/local/share/pynq-venv"
UNIT_NAME = "stereocam.service"
DEFAULT_UNIT_DIR = Path("/etc/systemd/system")
DEFAULT_CONFIG = Path("/etc/stereocam/stereocam.yaml")
DEFAULT_CAPTURES = "/var/lib/stereocam/captures"  # StateDirectory=stereocam
DEFAULT_PORT = 8080
WATCHDOG_SEC = 10
# The daemon's fd limit: its connections (max_connections, 256 by default, lowered by the daemon
# to fit below this) and its own files with room to spare. Said, not left to systemd's default.
LIMIT_NOFILE = 2048
RESERVED_PORTS = {80: "the PYNQ image's web server", 9090: "Jupyter on the PYNQ image"}
# DeviceAllow= of the unit: what pynq and our drivers open (read from pynq 3/4's sources).
DEVICES = (
    ("/dev/mem", "the fabric's registers (pynq's MMIO maps them)"),
    ("char-uio", "/dev/uio*, the fabric's interrupts"),
    ("char-i2c", "/dev/i2c-*, the sensors' two-wire bus"),
    ("char-drm", "/dev/dri/renderD*, XRT's zocl, which allocates the frame buffers"),
)


class ServiceError(Exception):
    """The service cannot be installed as asked; the message says why and what to do."""


# -- sd_notify ------------------------------------------------------------------------------

def notify(message: str, *, env: Optional[dict] = None) -> bool:
    """Send ``message`` (e.g. ``"READY=1"``) to systemd; False when not run by systemd (no ``NOTIFY_SOCKET``).

    The protocol: one datagram on the unix socket named by ``NOTIFY_SOCKET``
    (a leading ``@`` means the abstract namespace). Never raises for a
    socket problem: the daemon must run the same without systemd.
    """
    path = (env if env is not None else os.environ).get("NOTIFY_SOCKET")
    if not path:
        return False
    address = "\0" + path[1:] if path.startswith("@") else path
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.connect(address)
            sock.sendall(message.encode("utf-8"))
        return True
    except OSError:
        return False


def watchdog_interval(env: Optional[dict] = None) -> Optional[float]:
    """Seconds of ``WatchdogSec`` when systemd asks this process for watchdog pings, else None."""
    e = env if env is not None else os.environ
    usec, pid = e.get("WATCHDOG_USEC"), e.get("WATCHDOG_PID")
    if not usec:
        return None
    if pid and pid.isdigit() and int(pid) != os.getpid():
        return None
    try:
        seconds = int(usec) / 1e6
    except ValueError:
        return None
    return seconds if seconds > 0 else None


# -- the unit ------------------------------------------------------------------------------

def unit_text(*, venv: str = PYNQ_VENV, config: Path = DEFAULT_CONFIG, watchdog_sec: int = WATCHDOG_SEC,
              etc: str = "/etc") -> str:
    """The systemd unit; host, port and captures are in the config file it names.

    ``etc`` is where ``environment`` and ``profile.d/`` are read from (tests give a folder of their own).
    """
    stereocam = f"{venv.rstrip('/')}/bin/stereocam"
    etc = etc.rstrip("/") or "/"
    # In a unit, "$$" is a literal "$": systemd expands nothing in the script, bash does.
    script = (
        f"set -a; if [ -r {etc}/environment ]; then . {etc}/environment; fi; set +a; "
        f"for f in {etc}/profile.d/*.sh; do if [ -r $$f ]; then . $$f; fi; done; "
        f"exec {shlex.quote(stereocam)} serve --config {shlex.quote(str(config))}"
    )
    for path in (venv, str(config), etc):
        for bad in ("$", "%", '"', "'", "\\", " ", ";"):
            if bad in path:
                raise ServiceError(f"a path with {bad!r} cannot go into the unit's ExecStart: {path}")
    devices = "\n".join(f"DeviceAllow={name} rw" for name, _ in DEVICES)
    device_notes = "\n".join(f"#   {name}: {why}" for name, why in DEVICES)
    return f"""\
# stereocam: the Zynq stereo camera daemon (live rectified video, captures, virtual camera, verify).
# Installed by `stereocam install-service`, which rewrites this file: change settings with a drop-in
# (`systemctl edit stereocam`), e.g. ReadWritePaths=/home/xilinx/captures for captures elsewhere.
# Settings (host, port, captures, access token, log_level, board): {config}.
# The board profile: /etc/stereocam/board.yaml if it exists, else the packaged one.
# Logs: journalctl -u {UNIT_NAME} (add -p err for errors only).
[Unit]
Description=stereocam stereo camera daemon
After=network-online.target
Wants=network-online.target

[Service]
Type=notify
NotifyAccess=main
# The environment a login shell on the PYNQ image gets: /etc/environment, then every
# /etc/profile.d/*.sh (pynq_venv.sh activates {venv}; xrt_setup.sh sets XILINX_XRT,
# without which pynq finds no device).
# They are shell scripts, so bash sources them and then execs the daemon, which keeps the main PID.
ExecStart=/bin/bash -c '{script}'
Environment=PYTHONUNBUFFERED=1
# The daemon starts each log line with its priority (<3> error, <4> warning, <6> info, <7> debug).
SyslogIdentifier=stereocam
# The daemon pings the watchdog only while its frame pipeline runs: a stalled pipeline is restarted.
WatchdogSec={watchdog_sec}
Restart=on-failure
RestartSec=2
# SIGTERM stops the streams and the VDMA channels and returns the mux to live within 2 s.
KillSignal=SIGTERM
TimeoutStopSec=5
# Open files and sockets: the daemon keeps its connections below this (max_connections, lowered to
# fit; idle ones shed first), so a flood of idle sockets cannot take the last fd.
LimitNOFILE={LIMIT_NOFILE}
# /var/lib/stereocam: captures, calibration.yaml, calibration-pairs/; /run/stereocam: the fabric lock.
StateDirectory=stereocam
RuntimeDirectory=stereocam
WorkingDirectory=/var/lib/stereocam
UMask=0027

# Hardening. Root, because pynq maps the fabric's registers through /dev/mem and insists on root,
# with no capability but the raw I/O that opening /dev/mem needs.
NoNewPrivileges=yes
CapabilityBoundingSet=CAP_SYS_RAWIO
# Read-only system, but for the folders above and what pynq writes when it programs the fabric:
# the bitstream's .bin in /lib/firmware, and its record of the loaded one in its own package in the
# venv ("-": if present).
ProtectSystem=strict
ReadWritePaths=-/lib/firmware -{venv.rstrip('/')}/lib
ProtectHome=yes
PrivateTmp=yes
PrivateMounts=yes
# Only these devices, and /dev/null and the like:
{device_notes}
DevicePolicy=closed
{devices}
# Not PrivateDevices= (it hides those devices) nor ProtectKernelTunables= (it makes /sys read-only, and
# pynq programs the fabric through /sys/class/fpga_manager). Not MemoryDenyWriteExecute= either: nothing
# we know of writes code, but a library that does (a ctypes/cffi callback on a libffi without static
# trampolines) would stop the daemon at start, and the unit has not run on a board yet.
ProtectKernelModules=yes
ProtectKernelLogs=yes
ProtectControlGroups=yes
ProtectClock=yes
ProtectHostname=yes
ProtectProc=invisible
RestrictNamespaces=yes
RestrictRealtime=yes
RestrictSUIDSGID=yes
LockPersonality=yes
# IP for the web page; unix for sd_notify and the journal; netlink for glibc's address lookups.
RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK
SystemCallArchitectures=native
SystemCallFilter=@system-service
SystemCallFilter=~@privileged @resources
SystemCallErrorNumber=EPERM

[Install]
WantedBy=multi-user.target
"""


def default_config_text(*, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                        captures: str = DEFAULT_CAPTURES) -> str:
    return f"""\
# stereocam serve settings (keys: see `stereocam serve --help` and stereocam/server/http/settings.py).
host: {host}
port: {port}
backend: auto
captures: {captures}
# access_token: a-long-random-string   # when set, every state-changing request needs it
"""


def _atomic_write(path: Path, text: str, mode: int = 0o644) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.chmod(tmp, mode)
    os.replace(tmp, path)


def install_service(
    *,
    unit_dir: Path = DEFAULT_UNIT_DIR,
    config: Path = DEFAULT_CONFIG,
    venv: str = PYNQ_VENV,
    host: str = "0.0.0.0",
    port: int = DEFAULT_PORT,
    captures: str = DEFAULT_CAPTURES,
    start: bool = True,
    run: Callable[[Sequence[str]], "subprocess.CompletedProcess[str]"] = lambda cmd: subprocess.run(
        list(cmd), capture_output=True, text=True, check=False),
) -> List[str]:
    """Write the unit (and a config file if there is none), then ``daemon-reload`` and ``enable --now``.

    Returns what was done, one line each. Raises :class:`ServiceError` for a
    reserved port, a file that cannot be written or a failing ``systemctl``.
    """
    if port in RESERVED_PORTS:
        raise ServiceError(f"port {port} is used by {RESERVED_PORTS[port]}: "
                           f"choose another (default {DEFAULT_PORT})")
    done: List[str] = []
    unit = unit_dir / UNIT_NAME
    try:
        text = unit_text(venv=venv, config=config)
        _atomic_write(unit, text)
        done.append(f"wrote {unit}")
        if not config.exists():
            _atomic_write(config, default_config_text(host=host, port=port, captures=captures), 0o600)
            done.append(f"wrote {config} (host {host}, port {port}, captures {captures})")
        else:
            done.append(f"kept {config} (edit it for host, port, captures, access_token)")
    except OSError as exc:
        where = exc.filename or unit
        raise ServiceError(f"cannot write {where}: {exc.strerror}; run as root (sudo)") from None
    if not Path(venv, "bin", "stereocam").exists():
        done.append(f"warning: {venv}/bin/stereocam does not exist: pip install stereocam into {venv} first")
    if start:
        for cmd in (["systemctl", "daemon-reload"], ["systemctl", "enable", "--now", UNIT_NAME]):
            try:
                result = run(cmd)
            except OSError as exc:
                raise ServiceError(f"cannot run {' '.join(cmd)}: {exc.strerror}") from None
            if result.returncode != 0:
                reason = (result.stderr or result.stdout or "").strip().splitlines()
                why = reason[-1] if reason else f"exit {result.returncode}"
                raise ServiceError(f"{' '.join(cmd)} failed: {why}")
            done.append(" ".join(cmd))
    return done
