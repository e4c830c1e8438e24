"""Running as a service: sd_notify, the watchdog, the unit, install-service, `stereocam serve` and SIGTERM."""
from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from stereocam import cli
from stereocam.server.frames.pipeline import Pipeline
from stereocam.server.http import app as app_module
from stereocam.server.http import systemd

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
WAIT_S = 120.0  # last-resort bound of a wait for something that does happen (a busy machine is slow)


def wait_until(condition, what: str) -> None:
    """Poll ``condition()`` until true; fail naming ``what`` after :data:`WAIT_S`."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {WAIT_S} s"
        time.sleep(0.01)


def datagram_socket(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.1)
    return sock


def received(sock: socket.socket) -> list:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except (socket.timeout, BlockingIOError):
            return out


# -- sd_notify and the watchdog ---------------------------------------------------------------------

def test_notify_writes_one_datagram(tmp_path) -> None:
    path = tmp_path / "notify"
    with datagram_socket(path) as sock:
        assert systemd.notify("READY=1", env={"NOTIFY_SOCKET": str(path)})
        assert received(sock) == ["READY=1"]
    assert systemd.notify("READY=1", env={}) is False
    assert systemd.notify("READY=1", env={"NOTIFY_SOCKET": str(tmp_path / "gone")}) is False


def test_notify_abstract_socket() -> None:
    name = f"stereocam-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(1)
    with sock:
        assert systemd.notify("WATCHDOG=1", env={"NOTIFY_SOCKET": "@" + name})
        assert sock.recv(100) == b"WATCHDOG=1"


def test_watchdog_interval() -> None:
    assert systemd.watchdog_interval({}) is None
    assert systemd.watchdog_interval({"WATCHDOG_USEC": "10000000"}) == 10.0
    assert systemd.watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid())}) == 5.0
    assert systemd.watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}) is None
    assert systemd.watchdog_interval({"WATCHDOG_USEC": "x"}) is None


async def test_watchdog_is_fed_only_while_the_pipeline_beats(monkeypatch) -> None:
    sent = []
    monkeypatch.setattr(app_module, "notify", lambda message: sent.append(message))

    class Stub:
        heartbeat_at = time.monotonic()

    stub = Stub()
    task = asyncio.create_task(app_module._watchdog(stub, 0.3))  # type: ignore[arg-type]
    try:
        deadline = time.monotonic() + WAIT_S
        while sent.count("WATCHDOG=1") < 2:  # the pipeline beats every 0.05 s: the watchdog is fed
            assert time.monotonic() < deadline, sent
            stub.heartbeat_at = time.monotonic()
            await asyncio.sleep(0.05)
        n = len(sent)
        await asyncio.sleep(0.5)  # the pipeline stalls
        assert len(sent) <= n + 1
    finally:
        task.cancel()


async def test_watchdog_is_fed_while_the_daemon_stops(start_daemon, monkeypatch) -> None:
    """systemd keeps a unit's watchdog armed while it stops: a stop longer than WatchdogSec (the fabric
    finishing a frame on a loaded machine) ended in SIGABRT on the Zynq VM. The stop is held here until
    the watchdog has been fed twice after STOPPING=1, then let go; the daemon then exits normally."""
    sent: list = []
    monkeypatch.setattr(app_module, "notify", lambda message: sent.append(message) or True)
    monkeypatch.setenv("WATCHDOG_USEC", "300000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    daemon = await start_daemon()
    release = threading.Event()
    stop_overlay = daemon.overlay.stop

    def held_stop() -> None:
        assert release.wait(WAIT_S), "the test never let the fabric stop"
        stop_overlay()

    monkeypatch.setattr(daemon.overlay, "stop", held_stop)
    stopping = asyncio.ensure_future(daemon.stop())

    def fed_after_stopping() -> int:
        return sent[sent.index("STOPPING=1"):].count("WATCHDOG=1") if "STOPPING=1" in sent else 0

    deadline = time.monotonic() + WAIT_S
    while fed_after_stopping() < 2:
        assert not stopping.done(), f"the daemon stopped without waiting for its fabric: {sent}"
        assert time.monotonic() < deadline, f"the watchdog was not fed while stopping: {sent}"
        await asyncio.sleep(0.02)
    release.set()
    await stopping
    fed = fed_after_stopping()
    await asyncio.sleep(0.3)  # three feeding periods (interval / 3): a feeder left running would ping again
    assert fed_after_stopping() == fed, "the watchdog is still fed after the daemon stopped"


def test_pipeline_heartbeat_stops_when_the_thread_is_stuck() -> None:
    from .daemon import make_overlay

    overlay = make_overlay(fps=30)
    overlay.start()
    stuck = {"on": False}
    real_grab = Pipeline.grab

    def grab(self):  # a driver call that never returns (until released)
        while stuck["on"]:
            stuck["inside"] = True
            time.sleep(0.01)
        return real_grab(self)

    pipeline = Pipeline(overlay, publish=lambda fs: None, wait_s=0.05)
    pipeline.grab = grab.__get__(pipeline)  # type: ignore[method-assign]

    def beats_after(t: float) -> bool:
        return pipeline.heartbeat_at > t

    try:
        started = time.monotonic()
        with pipeline:
            wait_until(lambda: beats_after(started), "a heartbeat")
            stuck["on"] = True
            wait_until(lambda: stuck.get("inside", False), "the pipeline thread in the stuck call")
            stuck_at = time.monotonic()
            # Stuck: no beat however long we wait (half a second here), and it is old.
            wait_until(lambda: time.monotonic() - stuck_at > 0.5, "half a second")
            assert not beats_after(stuck_at) and time.monotonic() - pipeline.heartbeat_at > 0.4
            stuck["on"] = False
            wait_until(lambda: beats_after(stuck_at), "a heartbeat once the call returned")
    finally:
        overlay.close()


# -- the unit and install-service -----------------------------------------------------------------

def test_unit_runs_the_daemon_as_a_notify_service_in_the_pynq_venv() -> None:
    text = systemd.unit_text()
    lines = text.splitlines()
    for line in ("Type=notify", "NotifyAccess=main", "WatchdogSec=10", "Restart=on-failure",
                 "KillSignal=SIGTERM", "WantedBy=multi-user.target", "StateDirectory=stereocam"):
        assert line in lines, line
    exec_start = next(line for line in lines if line.startswith("ExecStart="))
    assert "for f in /etc/profile.d/*.sh; do if [ -r $$f ]; then . $$f; fi; done;" in exec_start
    assert ("exec /usr/local/share/pynq-venv/bin/stereocam serve --config /etc/stereocam/stereocam.yaml"
            in exec_start)
    # systemd expands "$VAR" and "%x" itself: the script has only "$$" (a literal "$" for bash).
    assert "$" not in exec_start.replace("$$", "") and "%" not in exec_start
    config = systemd.default_config_text()
    assert "port: 8080\n" in config and "host: 0.0.0.0\n" in config
    assert systemd.DEFAULT_PORT not in systemd.RESERVED_PORTS


def test_board_unit_is_the_generated_one() -> None:
    assert (REPO / "stereocam" / "board" / "stereocam.service").read_text() == systemd.unit_text()


def test_unit_passes_systemd_analyze(tmp_path) -> None:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.fail("systemd-analyze is not installed (Debian package systemd)")
    unit = tmp_path / "stereocam.service"
    unit.write_text(systemd.unit_text())
    result = subprocess.run([tool, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


def test_install_service_writes_unit_and_config_then_starts(tmp_path) -> None:
    calls = []

    def run(cmd):
        calls.append(list(cmd))
        return subprocess.CompletedProcess(cmd, 0, "", "")

    config = tmp_path / "etc" / "stereocam.yaml"
    done = systemd.install_service(unit_dir=tmp_path / "units", config=config, venv=str(tmp_path / "venv"),
                                   port=8081, run=run)
    unit = tmp_path / "units" / "stereocam.service"
    assert unit.read_text() == systemd.unit_text(venv=str(tmp_path / "venv"), config=config)
    assert "port: 8081" in config.read_text() and oct(config.stat().st_mode & 0o777) == "0o600"
    assert calls == [["systemctl", "daemon-reload"], ["systemctl", "enable", "--now", "stereocam.service"]]
    assert done[0] == f"wrote {unit}" and any("does not exist" in line for line in done)
    config.write_text("port: 9999\n")
    systemd.install_service(unit_dir=tmp_path / "units", config=config, start=False, run=run)
    assert config.read_text() == "port: 9999\n", "an existing settings file is kept"


def test_install_service_refusals(tmp_path) -> None:
    for port in (80, 9090):
        with pytest.raises(systemd.ServiceError, match=f"port {port} is used by"):
            systemd.install_service(unit_dir=tmp_path, config=tmp_path / "c.yaml", port=port, start=False)

    def failing(cmd):
        return subprocess.CompletedProcess(cmd, 1, "", "Failed to connect to bus: No such file\n")

    with pytest.raises(systemd.ServiceError, match="systemctl daemon-reload failed: Failed to connect"):
        systemd.install_service(unit_dir=tmp_path, config=tmp_path / "c.yaml", run=failing)


def test_cli_install_service(tmp_path, capsys) -> None:
    assert cli.main(["install-service", "--print"]) == 0
    assert capsys.readouterr().out == systemd.unit_text()
    assert cli.main(["install-service", "--no-start", "--unit-dir", str(tmp_path), "--config",
                     str(tmp_path / "s.yaml"), "--port", "8090"]) == 0
    assert (tmp_path / "stereocam.service").is_file() and "port: 8090" in (tmp_path / "s.yaml").read_text()
    capsys.readouterr()
    assert cli.main(["install-service", "--no-start", "--unit-dir", str(tmp_path), "--port", "80"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stereocam install-service: error: port 80 is used by") and err.count("\n") == 1


# -- stereocam serve ----------------------------------------------------------------------------------

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stereocam(*args: str, **kwargs) -> subprocess.Popen:
    kwargs.setdefault("stdout", subprocess.DEVNULL)
    kwargs.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen([sys.executable, "-m", "stereocam.cli", *args], text=True, **kwargs)


def test_serve_config_errors_are_one_line(tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("max_stream: 3\n")
    with stereocam("serve", "--config", str(bad)) as proc:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert err.startswith(f"stereocam serve: error: {bad}: unknown key 'max_stream' "
                          "(did you mean 'max_streams'?); known keys: host, port,")
    assert err.count("\n") == 1


def test_serve_notifies_systemd_and_stops_on_sigterm_within_two_seconds(tmp_path) -> None:
    port = free_port()
    notify_path = tmp_path / "notify"
    env = dict(os.environ, NOTIFY_SOCKET=str(notify_path), WATCHDOG_USEC="1500000")
    log = tmp_path / "serve.log"
    with datagram_socket(notify_path) as sock, open(log, "w") as err, \
            stereocam("serve", "--backend", "emulated", "--port", str(port),
                      "--captures", str(tmp_path / "c"), "--fps", "20", env=env, stderr=err) as proc:
        try:
            deadline = time.monotonic() + WAIT_S
            messages: list = []
            while "READY=1" not in messages:
                assert proc.poll() is None, log.read_text()
                assert time.monotonic() < deadline, "no READY=1"
                messages += received(sock)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=WAIT_S) as resp:
                status = json.load(resp)
            assert status["backend"] == "emulated" and status["frame_size"] == [752, 480]
            url = f"http://127.0.0.1:{port}/stream/rect_left?fps=5"
            with urllib.request.urlopen(url, timeout=WAIT_S) as stream:
                assert stream.read(200).startswith(b"--frame\r\n")
                deadline = time.monotonic() + WAIT_S
                while "WATCHDOG=1" not in messages:  # fed while frames flow (every 0.5 s here)
                    assert time.monotonic() < deadline, f"no WATCHDOG=1: {messages}"
                    messages += received(sock)
                t0 = time.monotonic()
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=WAIT_S)
                took = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        messages += received(sock)
    assert proc.returncode == 0, log.read_text()
    assert took < 2.0, f"SIGTERM took {took:.2f} s"
    assert "STOPPING=1" in messages
    assert "Traceback" not in log.read_text()


def test_serve_names_a_source_typo_in_one_line(tmp_path) -> None:
    with stereocam("serve", "--backend", "emulated", "--port", "0", "--captures", str(tmp_path / "c"),
                   "--source", "synthtic") as proc:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert err.startswith("stereocam serve: error: --source 'synthtic': did you mean 'synthetic'? ")
    assert err.count("\n") == 1 and "Traceback" not in err


def test_serve_refuses_a_port_in_use(tmp_path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with stereocam("serve", "--backend", "emulated", "--port", str(port),
                       "--captures", str(tmp_path / "c"), "--fps", "10") as proc:
            _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"stereocam serve: error: cannot listen on 127.0.0.1:{port}: ")


# -- the calibration the daemon starts with --------------------------------------------------------

def test_default_calibration_is_the_rigs_and_files_are_accepted(tmp_path) -> None:
    from stereocam.bench.rectify import bench_calibration
    from stereocam.calibration.formats import write_opencv_pair
    from stereocam.calibration.stereo import rectify
    from stereocam.overlays.emulated.overlay import EmulatedOverlay
    from stereocam.overlays.emulated.render import SyntheticRig
    from stereocam.overlays.spec.rectify import camera_registers
    from stereocam.server.http.settings import Settings

    from .daemon import StillSource

    _, _, left, right = bench_calibration()
    overlay = EmulatedOverlay(source=SyntheticRig(motion=False), clock="stepped")  # not started: core idle
    try:
        state = app_module.program_default_calibration(overlay, Settings())
        config = overlay.fabric.rectify.read_config()
        w, h = overlay.fabric.frame_size  # the same as the benchmarks' calibration, as registers
        assert (config.left, config.right) == (camera_registers(left, w, h), camera_registers(right, w, h))
        assert state.id is not None and state.id.startswith("synthetic-rig-")
        assert state.rows_needed is not None and state.lb_rows == 80 and state.rows_needed <= 80

        rig_model = overlay.emulation.source.model
        intr, extr = write_opencv_pair(rig_model, rectify(rig_model, alpha=0.0), tmp_path)
        from_files = app_module.program_default_calibration(overlay, Settings(calibration=f"{intr},{extr}"))
        assert from_files.id is not None and from_files.id.startswith("opencv-")
        assert str(intr) in from_files.description
        loaded = overlay.fabric.rectify.read_config()
        assert loaded.left.fx == camera_registers(left, w, h).fx  # fx in 1/2**20 px: files round-trip exactly
    finally:
        overlay.close()

    source = StillSource()
    source.model = None  # a replayed recording: no known calibration
    overlay = EmulatedOverlay(source=source, clock="stepped")
    try:
        state = app_module.program_default_calibration(overlay, Settings())
        assert state.id is None and "passes frames through" in state.description
    finally:
        overlay.close()


def test_serve_refuses_a_bad_calibration_file(tmp_path) -> None:
    with stereocam("serve", "--backend", "emulated", "--port", "0", "--captures", str(tmp_path / "c"),
                   "--calibration", f"{tmp_path / 'no.yml'},{tmp_path / 'no2.yml'}") as proc:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert err.strip().splitlines()[-1] == f"stereocam serve: error: {tmp_path / 'no.yml'}: no such file"


@pytest.mark.parametrize("numba_runs", [False, True])
def test_serve_says_why_the_emulated_fabric_has_no_stereo_core(numba_runs, monkeypatch, caplog) -> None:
    """Unset, the emulated stereo core is there only where numba runs; its absence is said, once."""
    from stereocam.server.http.settings import Settings

    monkeypatch.setattr(app_module, "compiled_path_installed", lambda: numba_runs)
    with caplog.at_level("INFO", logger=app_module.__name__):
        overlay = app_module.open_configured_overlay(Settings(backend="emulated", source="synthetic"))
    try:
        has_core = overlay.stereo is not None
    finally:
        overlay.close()
    said = [r.getMessage() for r in caplog.records if "has no stereo core" in r.getMessage()]
    assert has_core == numba_runs
    assert len(said) == (0 if numba_runs else 1)
    if said:
        assert "stereocam[fast]" in said[0] and "StereoBM" in said[0]
