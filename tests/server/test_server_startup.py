"""Starting as the board's service (issue 25): the start timeout extended while the daemon loads and
STATUS= saying what it loads; a board without its bitstream said loudly, within the board's budget; a
device refused because its driver loaded after the unit started stops the daemon with the status the
unit restarts on."""
from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import List

import pytest

from stereocam import cli
from stereocam.drivers.i2c import LinuxI2CBus
from stereocam.server.frames.cpu_budget import BOARD_CORES
from stereocam.server.http import routes_cameras, systemd

from ..overlays.test_fabric import zynq_device_tree
from .test_server_service import datagram_socket, free_port, received, wait_until

WAIT_S = 120.0  # last-resort bound of a wait for something that does happen


def drain(sock: socket.socket) -> List[str]:
    """What has arrived so far (``received`` waits for a pause, which a fast sender never makes)."""
    out = []
    timeout = sock.gettimeout()
    sock.setblocking(False)  # (with a timeout, recv polls for it even with MSG_DONTWAIT)
    try:
        while True:
            try:
                out.append(sock.recv(4096).decode())
            except BlockingIOError:
                return out
    finally:
        sock.settimeout(timeout)


@pytest.fixture
def notify_socket(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A real datagram socket as ``NOTIFY_SOCKET``; :func:`systemd.loading`'s thread reset around the test."""
    path = tmp_path / "notify"
    monkeypatch.setattr(systemd, "_start_timeout", None)
    with datagram_socket(path) as sock:
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        yield sock
        systemd.loaded()
        if systemd._start_timeout is not None:
            systemd._start_timeout.thread.join(WAIT_S)


# -- the start timeout ----------------------------------------------------------------------------

def test_loading_extends_the_start_timeout_every_period_until_loaded(notify_socket: socket.socket) -> None:
    messages: List[str] = []
    systemd.loading("Python modules", every=0.02, window=7.0)
    extend = "EXTEND_TIMEOUT_USEC=7000000"

    def extensions() -> int:
        messages.extend(drain(notify_socket))
        return messages.count(extend)

    wait_until(lambda: extensions() >= 3, "three extensions")
    assert messages[:2] == [extend, "STATUS=loading Python modules"], "at once, before the first period"
    systemd.loading("the fabric")
    wait_until(lambda: extensions() and "STATUS=loading the fabric" in messages, "the new status")
    systemd.loaded()
    thread = systemd._start_timeout.thread  # type: ignore[union-attr]
    thread.join(WAIT_S)
    assert not thread.is_alive(), "loaded() ends the thread"
    messages.extend(drain(notify_socket))
    systemd.loading("late")  # after loaded(): nothing more
    assert drain(notify_socket) == []


def test_loading_stops_extending_after_its_limit(notify_socket: socket.socket) -> None:
    systemd.loading("something that hangs", every=0.02, window=1.0, limit=0.1)
    thread = systemd._start_timeout.thread  # type: ignore[union-attr]
    thread.join(WAIT_S)
    assert not thread.is_alive(), "a start that hangs is not extended for ever: systemd fails it"
    messages = drain(notify_socket)
    assert messages[-1] == "STATUS=loading something that hangs (for 0 s: no more start timeout extensions)"


def test_loading_without_systemd_starts_no_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.setattr(systemd, "_start_timeout", None)
    systemd.loading("Python modules")
    assert systemd._start_timeout is None
    systemd.loaded()


@pytest.mark.slow
def test_serve_extends_its_start_timeout_and_says_what_it_loads_before_ready(tmp_path: Path) -> None:
    """A real `stereocam serve`: EXTEND_TIMEOUT_USEC and STATUS=loading ... come before READY=1."""
    port = free_port()
    path = tmp_path / "notify"
    env = dict(os.environ, NOTIFY_SOCKET=str(path))
    log = tmp_path / "serve.log"
    with datagram_socket(path) as sock, open(log, "w") as err, subprocess.Popen(
            [sys.executable, "-m", "stereocam.cli", "serve", "--backend", "emulated", "--port", str(port),
             "--captures", str(tmp_path / "c"), "--fps", "5"],
            env=env, stdout=subprocess.DEVNULL, stderr=err) as proc:
        try:
            messages: List[str] = []
            deadline = time.monotonic() + WAIT_S
            while "READY=1" not in messages:
                assert proc.poll() is None, log.read_text()
                assert time.monotonic() < deadline, f"no READY=1: {messages}"
                messages += received(sock)
            while not any(m.startswith("STATUS=serving on") for m in messages):
                assert time.monotonic() < deadline, f"no STATUS=serving on: {messages}"
                messages += received(sock)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=WAIT_S)
    ready = messages.index("READY=1")
    before = messages[:ready]
    assert before[0] == f"EXTEND_TIMEOUT_USEC={int(systemd.EXTEND_WINDOW_S * 1e6)}", messages
    assert before[1] == "STATUS=loading Python modules"
    # In this order; each repeated every EXTEND_EVERY_S while it lasts (on a busy machine, it does).
    statuses = list(dict.fromkeys(m for m in before if m.startswith("STATUS=")))
    assert statuses[1:] == ["STATUS=loading the fabric (the overlay and its bitstream)",
                            "STATUS=loading the calibration",
                            "STATUS=loading the camera sensors and the fabric's streams"], messages
    assert not any(m.startswith("EXTEND_TIMEOUT_USEC=") for m in messages[ready:]), "none after READY"
    assert proc.returncode == 0, log.read_text()


# -- a board without its bitstream ------------------------------------------------------------------

def board_site(tmp_path: Path) -> Path:
    """A folder with a ``pynq`` package in it: on ``sys.path``, the machine is a board as backend.py tells."""
    site = tmp_path / "board-site"
    (site / "pynq").mkdir(parents=True)
    (site / "pynq" / "__init__.py").write_text("# stands for PYNQ's package: importable, never imported\n")
    return site


@pytest.mark.slow
def test_a_board_without_its_bitstream_says_so_loudly_within_the_boards_budget(tmp_path: Path) -> None:
    """`--backend auto` with pynq importable and the bitstream missing: the emulated fabric, a warning in the
    log naming the file and what to do, `backend_warning` in /api/status, and the board's CPU budget."""
    port = free_port()
    missing = tmp_path / "overlay" / "stereocam.bit"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(board_site(tmp_path)), env.get("PYTHONPATH")) if p)
    env["STEREOCAM_DEVICE_TREE"] = str(zynq_device_tree(tmp_path))
    env.pop("STEREOCAM_BITSTREAM", None)
    log = tmp_path / "serve.log"
    with open(log, "w") as err, subprocess.Popen(
            [sys.executable, "-m", "stereocam.cli", "serve", "--backend", "auto", "--bitstream", str(missing),
             "--host", "127.0.0.1", "--port", str(port), "--captures", str(tmp_path / "c"), "--fps", "5"],
            env=env, stdout=subprocess.DEVNULL, stderr=err) as proc:
        try:
            status: dict = {}

            def answered() -> bool:
                assert proc.poll() is None, log.read_text()
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=10) as resp:
                        status.update(json.load(resp))
                        return True
                except OSError:
                    return False

            wait_until(answered, "/api/status")
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=WAIT_S)
    warning = status["backend_warning"]
    assert status["backend"] == "emulated" and warning, status
    assert f"stereocam.bit is not at {missing}" in warning and "EMULATED fabric" in warning
    assert "Vivado (stereocam/overlays/vivado/README.md)" in warning and "--backend emulated" in warning
    assert status["cpu"]["cores"] == BOARD_CORES, "the board's budget, not the whole machine's"
    lines = [line for line in log.read_text().splitlines() if " WARNING stereocam.overlays.backend: " in line]
    assert len(lines) == 1 and lines[0].endswith(warning), log.read_text()


# -- a driver loaded after the unit started --------------------------------------------------------

def refused_bus(tmp_path: Path, code: int = errno.EPERM) -> LinuxI2CBus:
    """``/dev/i2c-0`` as a service sees it when i2c-dev loaded after the unit started: there, refused."""
    (tmp_path / "i2c-0").touch()

    def refuse(path: str, flags: int) -> int:
        raise PermissionError(code, os.strerror(code), path)

    return LinuxI2CBus(0, device_dir=str(tmp_path), opener=refuse)


@pytest.mark.slow
def test_a_refused_bus_under_systemd_stops_serve_with_the_status_the_unit_restarts_on(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    bus = refused_bus(tmp_path)
    monkeypatch.setattr(routes_cameras, "sensor_bus", lambda overlay, profile, **options: bus)
    monkeypatch.setenv("INVOCATION_ID", "0123456789abcdef0123456789abcdef")  # what systemd sets
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    code = cli.main(["serve", "--backend", "emulated", "--host", "127.0.0.1", "--port", "0", "--fps", "5",
                     "--captures", str(tmp_path / "c")])
    assert code == systemd.LATE_DRIVER_EXIT == 75
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith(f"stereocam serve: error: {tmp_path}/i2c-0 exists but the service may not open it "
                          "(permission denied): its driver was probably loaded after the service started")
    assert "status 75 so that the unit restarts" in err and "systemctl restart stereocam" in err


def test_a_refused_bus_off_systemd_is_left_to_the_sensors_report(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Not a service: nothing restarts it, so the daemon serves on and reports the sensors (as before)."""
    for name in ("INVOCATION_ID", "NOTIFY_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    routes_cameras._open_bus(refused_bus(tmp_path, errno.EACCES))  # no exception
    monkeypatch.setenv("INVOCATION_ID", "x")
    with pytest.raises(systemd.LateDriver):
        routes_cameras._open_bus(refused_bus(tmp_path, errno.EACCES))
    missing = LinuxI2CBus(7, device_dir=str(tmp_path))  # no node at all: the profile's bus is wrong
    routes_cameras._open_bus(missing)  # left to the sensors' start, which names the buses present
