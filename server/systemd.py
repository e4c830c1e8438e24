"""systemd integration: ``sd_notify`` (no dependency), the service unit, ``stereocam install-service``.

The unit (``board/stereocam.service`` is :func:`unit_text` with the defaults)
runs the daemon as ``Type=notify``: it says ``READY=1`` once it listens, and
sends ``WATCHDOG=1`` only while the frame pipeline's thread is alive and
iterating, so a pipeline stuck in a driver call gets the service killed and
restarted (``Restart=on-failure``). It runs in the PYNQ image's virtual
environment (``/usr/local/share/pynq-venv``) with the environment PYNQ's
own shells get: ``/etc/environment`` and ``/etc/profile.d/pynq_venv.sh``
(which activates the venv and exports ``BOARD``, ``XILINX_XRT``...). That
file is a shell script, not an ``EnvironmentFile``, so the unit sources it
in ``bash -c`` and then ``exec``s the daemon (which keeps the main PID, as
``NotifyAccess=main`` needs). Port 8080: the PYNQ image serves on 80 and
Jupyter on 9090.
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
    "PYNQ_VENV", "PYNQ_ENV_FILE", "UNIT_NAME", "RESERVED_PORTS",
]

PYNQ_VENV = "/usr/local/share/pynq-venv"
PYNQ_ENV_FILE = "/etc/profile.d/pynq_venv.sh"
UNIT_NAME = "stereocam.service"
DEFAULT_UNIT_DIR = Path("/etc/systemd/system")
DEFAULT_CONFIG = Path("/etc/stereocam/stereocam.yaml")
DEFAULT_CAPTURES = "/var/lib/stereocam/captures"  # StateDirectory=stereocam
DEFAULT_PORT = 8080
WATCHDOG_SEC = 10
RESERVED_PORTS = {80: "the PYNQ image's web server", 9090: "Jupyter on the PYNQ image"}


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

def unit_text(*, venv: str = PYNQ_VENV, env_file: str = PYNQ_ENV_FILE, config: Path = DEFAULT_CONFIG,
              watchdog_sec: int = WATCHDOG_SEC) -> str:
    """The systemd unit; host, port and captures are in the config file it names."""
    stereocam = f"{venv.rstrip('/')}/bin/stereocam"
    script = (
        "if [ -r /etc/environment ]; then set -a; . /etc/environment; set +a; fi; "
        f". {shlex.quote(env_file)}; "
        f"exec {shlex.quote(stereocam)} serve --config {shlex.quote(str(config))}"
    )
    for bad in ("$", "%", '"', "\\"):
        if bad in script:
            raise ServiceError(f"paths with {bad!r} cannot go into the unit's ExecStart: {script}")
    return f"""\
# stereocam: the Zynq stereo camera daemon (live rectified video, captures, virtual camera, verify).
# Installed by `stereocam install-service`; settings (host, port, captures, access token) are in
# {config}. Logs: journalctl -u {UNIT_NAME}
[Unit]
Description=stereocam stereo camera daemon
After=network-online.target
Wants=network-online.target

[Service]
Type=notify
NotifyAccess=main
# PYNQ's environment is a shell script (it activates {venv}), so source it, then exec the daemon.
ExecStart=/bin/bash -c '{script}'
Environment=PYTHONUNBUFFERED=1
# The daemon pings the watchdog only while its frame pipeline runs: a stalled pipeline is restarted.
WatchdogSec={watchdog_sec}
Restart=on-failure
RestartSec=2
# SIGTERM stops the streams and the VDMA channels and returns the mux to live within 2 s.
KillSignal=SIGTERM
TimeoutStopSec=5
StateDirectory=stereocam
WorkingDirectory=/var/lib/stereocam

[Install]
WantedBy=multi-user.target
"""


def default_config_text(*, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                        captures: str = DEFAULT_CAPTURES) -> str:
    return f"""\
# stereocam serve settings (keys: see `stereocam serve --help` and server/config.py).
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
    env_file: str = PYNQ_ENV_FILE,
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
        text = unit_text(venv=venv, env_file=env_file, config=config)
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
