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

Start-up (issue 25): the unit says ``TimeoutStartSec`` (:data:`START_TIMEOUT_SEC`), and from the first
line of ``stereocam serve`` until ``READY=1`` the daemon extends it (:func:`loading`, a thread sending
``EXTEND_TIMEOUT_USEC`` and ``STATUS=loading ...``). The unit pulls in ``modprobe@.service`` for the
drivers whose device classes ``DeviceAllow=`` names (:data:`DRIVER_MODULES`), since systemd resolves
them when the unit starts; a device refused anyway (:class:`LateDriver`) ends the daemon with
:data:`LATE_DRIVER_EXIT`, which the unit restarts on (``RestartForceExitStatus=``).
"""
from __future__ import annotations

import os
import shlex
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Callable, List, Optional, Sequence

__all__ = [
    "notify", "watchdog_interval", "unit_text", "default_config_text", "install_service", "ServiceError",
    "PYNQ_VENV", "UNIT_NAME", "RESERVED_PORTS", "DEVICES", "loading", "loaded", "under_systemd", "LateDriver",
    "START_TIMEOUT_SEC", "EXTEND_EVERY_S", "EXTEND_WINDOW_S", "LATE_DRIVER_EXIT", "DRIVER_MODULES",
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
# TimeoutStartSec: from the unit's start to READY=1. On QEMU's xilinx-zynq-a9 (one emulated A9, the armhf
# rootfs on an emulated SD card) READY came after 93 s (issue 25), just over systemd's 90 s default; the
# imports alone count 5.7-8.5 s on a 650 MHz A9. 300 s is three times the emulated start, for a slow SD card
# and a first start that compiles .pyc files; beyond it, the daemon's own EXTEND_TIMEOUT_USEC (below) keeps
# a start that is still loading alive, up to MAX_START_S.
START_TIMEOUT_SEC = 300
EXTEND_EVERY_S = 5.0  # while loading, the daemon extends the start timeout this often ...
EXTEND_WINDOW_S = 30.0  # ... to this long from then (EXTEND_TIMEOUT_USEC, systemd >= 236)
MAX_START_S = 900.0  # and stops extending after this long: a start hung for 15 minutes fails
# The exit status of a daemon refused a device whose driver loaded after the unit started
# (EX_TEMPFAIL): the unit restarts on it whatever Restart= says, and the restart re-reads DeviceAllow=.
LATE_DRIVER_EXIT = 75
# Kernel modules whose device nodes DeviceAllow= names (char-i2c, char-uio): loaded before the unit starts,
# through systemd's own modprobe@.service, so their device classes exist when the unit's device list is made.
DRIVER_MODULES = (
    ("i2c-dev", "/dev/i2c-*, char-i2c"),
    ("uio_pdrv_genirq", "/dev/uio*, char-uio (PYNQ's device tree binds the fabric's interrupts to it)"),
)
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


def under_systemd(env: Optional[dict] = None) -> bool:
    """True when systemd runs this process as a service (it sets ``INVOCATION_ID``; ``NOTIFY_SOCKET`` too)."""
    e = env if env is not None else os.environ
    return bool(e.get("INVOCATION_ID") or e.get("NOTIFY_SOCKET"))


class LateDriver(Exception):
    """A device node exists but the service may not open it: its driver loaded after the unit started.

    ``stereocam serve`` exits with :data:`LATE_DRIVER_EXIT`, which the unit restarts on.
    """

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(
            f"{path} exists but the service may not open it ({reason}): its driver was probably loaded after "
            f"the service started, and systemd allows only the devices present then (DeviceAllow=). "
            f"Exiting with status {LATE_DRIVER_EXIT} so that the unit restarts and reads the device list "
            f"again; `systemctl restart stereocam` does the same")
        self.path = path


class _StartTimeout:
    """The thread behind :func:`loading`: ``EXTEND_TIMEOUT_USEC`` and ``STATUS=`` every ``every`` s."""

    def __init__(self, every: float, window: float, limit: float) -> None:
        self.every, self.window, self.limit = every, window, limit
        self.status = ""
        self.started = time.monotonic()
        self.done = threading.Event()
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._run, name="stereocam-start-timeout", daemon=True)

    def send(self) -> None:
        with self.lock:  # one pair at a time, in order: never a STATUS after loaded()'s
            if self.done.is_set():
                return
            notify(f"EXTEND_TIMEOUT_USEC={int(self.window * 1e6)}")
            notify(f"STATUS={self.status}")

    def _run(self) -> None:
        while not self.done.wait(self.every):
            if time.monotonic() - self.started > self.limit:
                notify(f"STATUS={self.status} (for {self.limit:.0f} s: no more start timeout extensions)")
                return
            self.send()


_start_timeout: Optional[_StartTimeout] = None


def loading(what: str, *, every: float = EXTEND_EVERY_S, window: float = EXTEND_WINDOW_S,
            limit: float = MAX_START_S) -> None:
    """Say the daemon is loading ``what``: ``STATUS=loading <what>`` (``systemctl status`` shows it) and,
    from the first call until :func:`loaded`, ``EXTEND_TIMEOUT_USEC`` of ``window`` s every ``every`` s.

    Nothing without ``NOTIFY_SOCKET`` (no thread either). Call from the thread that starts the daemon;
    the first call starts a daemon thread, so it is as cheap as it can be before the imports.
    """
    global _start_timeout
    if not os.environ.get("NOTIFY_SOCKET"):
        return
    if _start_timeout is None:
        _start_timeout = _StartTimeout(every, window, limit)
        _start_timeout.status = f"loading {what}"
        _start_timeout.send()
        _start_timeout.thread.start()
        return
    if not _start_timeout.done.is_set():
        _start_timeout.status = f"loading {what}"
        _start_timeout.send()


def loaded() -> None:
    """Loading is over (the daemon sends ``READY=1`` next): no more extensions or loading statuses."""
    if _start_timeout is not None:
        with _start_timeout.lock:
            _start_timeout.done.set()


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
    modprobe = " ".join(f"modprobe@{module}.service" for module, _ in DRIVER_MODULES)
    module_notes = "\n".join(f"#   {module}: {what}" for module, what in DRIVER_MODULES)
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
# The drivers of the devices allowed below, loaded before the unit starts (systemd's own modprobe@.service;
# a module that is built in or missing is not an error). systemd makes the unit's device list from the
# drivers loaded when it starts: a device whose driver loads later is refused, the daemon then exits with
# status {LATE_DRIVER_EXIT} and the unit restarts it (RestartForceExitStatus= below).
{module_notes}
Wants={modprobe}
After={modprobe}

[Service]
Type=notify
NotifyAccess=main
# From start to READY=1: 93 s on QEMU's emulated Zynq A9 (imports 5.7-8.5 s on a real A9); three times
# that for a slow SD card. While it loads, the daemon also extends it by {EXTEND_WINDOW_S:.0f} s every \
{EXTEND_EVERY_S:.0f} s
# (EXTEND_TIMEOUT_USEC), up to {MAX_START_S:.0f} s, and says what it loads (systemctl status).
TimeoutStartSec={START_TIMEOUT_SEC}
# The environment a login shell on the PYNQ image gets: /etc/environment, then every
# /etc/profile.d/*.sh (pynq_venv.sh activates {venv}; xrt_setup.sh sets XILINX_XRT,
# without which pynq finds no device).
# They are shell scripts, so bash sources them and then execs the daemon, which keeps the main PID.
ExecStart=/bin/bash -c '{script}'
Environment=PYTHONUNBUFFERED=1
# The daemon starts each log line with its priority (<3> error, <4> warning, <6> info, <7> debug).
SyslogIdentifier=stereocam
# The daemon pings the watchdog while its frame pipeline runs (a stalled pipeline is restarted) and
# while it stops (systemd keeps the watchdog armed then; TimeoutStopSec bounds the stop).
WatchdogSec={watchdog_sec}
Restart=on-failure
RestartSec=2
# Status {LATE_DRIVER_EXIT}: a device's driver loaded after the unit started; a restart allows it.
RestartForceExitStatus={LATE_DRIVER_EXIT}
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
