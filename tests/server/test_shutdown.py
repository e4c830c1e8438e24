"""SIGTERM while a ``PUT /api/calibration`` is being worked on.

``stereocam/server/API.md``, ``stereocam/server/http/app.py`` and ``stereocam/board/stereocam.service``
promise: SIGTERM stops the
streams and the VDMA channels and returns the mux to live within 2 s. A valid calibration file
with a large ``quality`` section (figures for people: parsed, not checked) takes the daemon
seconds to check; SIGTERM during that check took up to 8.8 s, because the exit waited for the
worker thread doing it (and the write of the file after it). The daemon now stops the check
(nothing has changed yet: :meth:`Executors.abandon`), answers 503 and exits; the calibration
files stay as they were. A change already being programmed and written is let finish.
"""
from __future__ import annotations

import asyncio
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Any, Callable, Tuple

import aiohttp
import pytest

from stereocam.bench.serve import wait_healthy
from stereocam.calibration.file import MAX_FILE_CHARS, Calibration, load_calibration
from stereocam.calibration.stereo import rectify
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.server.http import routes_calibration, routes_calibration_panel
from stereocam.server.http.routes_calibration import ACTIVE, previous_path
from stereocam.server.http.state import Executors

from .test_server_service import free_port, stereocam

pytestmark = pytest.mark.slow

STOP_BOUND_S = 2.0  # stereocam/server/API.md: "SIGTERM stops the streams ... within 2 s"
NESTING = 16  # levels of the quality section's lists: each level adds parser events per character
WAIT_S = 60.0  # last-resort bound of a wait for something that does happen (a busy machine is slow)
YAML = {"Content-Type": "application/yaml"}


async def until(condition: Callable[[], bool], what: str) -> None:
    """Poll ``condition()`` on the event loop until true; fail naming ``what`` after :data:`WAIT_S`."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {WAIT_S} s"
        await asyncio.sleep(0.01)


def rig_calibration(alpha: float, model: Any = None) -> Calibration:
    """A calibration of ``model``, by default the synthetic rig's (752x480, what `stereocam serve` runs)."""
    if model is None:
        with SyntheticRig(motion=False) as rig:
            model = rig.model
    return Calibration.derive(model, rectify(model, alpha=alpha), alpha=alpha, source="test rig")


def long_calibration(cal: Calibration) -> str:
    """``cal``'s file with a quality section that fills the size limit: valid, and seconds to check.

    The text is what :meth:`Calibration.to_yaml` writes for that quality section (deeply nested
    lists, built here as text: dumping them takes seconds too).
    """
    head = (cal.to_yaml() + "quality:  # figures of `stereocam calibrate`, for people; not checked on load\n"
            "  x:\n")
    line = "  " + "- " * NESTING + "[0]\n"
    text = head + line * ((MAX_FILE_CHARS - len(head)) // len(line))
    assert len(text) <= MAX_FILE_CHARS
    return text


def wait_for_log(log: Path, text: str, proc, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while text not in log.read_text():
        assert proc.poll() is None, f"the daemon exited ({proc.returncode}):\n{log.read_text()}"
        assert time.monotonic() < deadline, f"no {text!r} in the log within {timeout} s:\n{log.read_text()}"
        time.sleep(0.02)


def read_answer(sock: socket.socket, timeout: float = 10.0) -> Tuple[int, bytes]:
    """The HTTP status and body the daemon sent on ``sock`` before closing it; (0, b"") for none."""
    sock.settimeout(timeout)
    data = b""
    while True:
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            break
        if not chunk:
            break
        data += chunk
    if not data:
        return 0, b""
    head, _, body = data.partition(b"\r\n\r\n")
    status_line = head.split(b"\r\n", 1)[0]
    assert status_line.startswith(b"HTTP/1.1 "), data[:200]
    return int(status_line.split()[1]), body


def test_sigterm_during_a_long_calibration_put_stops_within_two_seconds(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    good, new = rig_calibration(0.0), rig_calibration(0.5)
    assert good.id != new.id
    saved = state / "calibration.yaml"
    good.save(saved)
    good_text = saved.read_text()
    body = long_calibration(new).encode()

    port = free_port()
    log = tmp_path / "serve.log"
    args = ("serve", "--backend", "emulated", "--port", str(port), "--fps", "20",
            "--captures", str(tmp_path / "captures"), "--state-dir", str(state))
    with open(log, "w") as err, stereocam(*args, stderr=err) as proc:
        try:
            wait_healthy(f"http://127.0.0.1:{port}", proc, timeout=60.0)
            assert f"calibration {good.id}: calibration file {saved}" in log.read_text()
            with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
                sock.sendall(b"PUT /api/calibration HTTP/1.1\r\n"
                             + f"Host: 127.0.0.1:{port}\r\nContent-Type: application/yaml\r\n"
                               f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
                wait_for_log(log, "calibration check started (PUT /api/calibration)", proc)
                t0 = time.monotonic()
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=30)
                took = time.monotonic() - t0
                status, answer = read_answer(sock)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = log.read_text()
    assert proc.returncode == 0, text
    # The documented bound itself, measured from the signal to the exit (not the daemon's start,
    # nor the PUT's upload): with the fix the exit takes a fraction of it even on a loaded 2-core
    # machine, so no margin is added. Before it the exit waited for the check (several seconds).
    assert took <= STOP_BOUND_S, f"SIGTERM took {took:.2f} s (the check was still running?)\n{text}"
    assert "fabric stopped: mux on live, VDMA channels stopped" in text
    assert "Traceback" not in text
    # The client gets a proper answer or a closed connection; the files are one calibration, never a mix.
    assert status in (0, 200, 503), (status, answer[:300])
    if status == 200:
        assert load_calibration(saved).id == new.id
        assert previous_path(saved).read_text() == good_text
    else:
        assert saved.read_text() == good_text
        assert not previous_path(saved).exists()
    if status == 503:
        assert b"the daemon is stopping" in answer and b"previous calibration stays active" in answer
    assert sorted(p.name for p in state.iterdir() if p.name.endswith(".tmp")) == []


# -- the parts, in the daemon's own process ---------------------------------------------------

async def test_abandon_stops_a_busy_check_and_cancels_its_await() -> None:
    executors = Executors.create(1)
    started, ended = threading.Event(), threading.Event()

    def busy() -> None:  # pure Python that would run for ever, as a parse of a large file runs long
        started.set()
        try:
            while True:
                pass
        finally:
            ended.set()

    try:
        assert await executors.run_abandonable(lambda x: x + 1, 41) == 42
        with pytest.raises(ValueError, match="bad"):
            await executors.run_abandonable(lambda: int("bad"))
        job = asyncio.ensure_future(executors.run_abandonable(busy))
        await until(started.is_set, "the job started")
        executors.abandon()
        with pytest.raises(asyncio.CancelledError):
            await job
        await until(ended.is_set, "the job's thread stopped")
        with pytest.raises(RuntimeError, match="the daemon is stopping"):
            await executors.run_abandonable(busy)
    finally:
        executors.shutdown()


async def test_stopping_lets_a_calibration_being_written_finish(start_daemon, tmp_path, monkeypatch) -> None:
    daemon = await start_daemon(extensions=(routes_calibration.setup,))
    model = daemon.overlay.emulation.source.model
    old, new = rig_calibration(0.0, model), rig_calibration(0.6, model)
    saved = tmp_path / "calibration.yaml"  # <captures>/../calibration.yaml
    async with daemon.http.put("/api/calibration", data=old.to_yaml(), headers=YAML) as r:
        assert r.status == 200, await r.text()
    old_text = saved.read_text()
    entered, release = threading.Event(), threading.Event()
    real_apply = routes_calibration._apply

    def gated_apply(*args):  # the change holds here until the daemon has begun to stop
        entered.set()
        assert release.wait(WAIT_S)
        return real_apply(*args)

    monkeypatch.setattr(routes_calibration, "_apply", gated_apply)
    put = asyncio.ensure_future(daemon.http.put("/api/calibration", data=new.to_yaml(), headers=YAML))
    await until(entered.is_set, "the PUT programming the core")
    stop = asyncio.ensure_future(daemon.stop(close_sessions=False))
    await until(daemon.app[ACTIVE].stopping.is_set, "the shutdown begun")
    release.set()
    async with await put as r:
        assert r.status == 200, await r.text()
        assert (await r.json())["id"] == new.id
    took = await stop
    assert took <= STOP_BOUND_S, f"the shutdown took {took:.2f} s"
    assert load_calibration(saved).id == new.id
    assert previous_path(saved).read_text() == old_text
    await daemon.close_sessions()


async def test_put_refuses_a_file_the_next_start_could_not_read(start_daemon, tmp_path) -> None:
    """The file is written as :meth:`Calibration.to_yaml` lays it out: a compact quality section
    grows, and past the size limit the next start would refuse the file (and start without it)."""
    daemon = await start_daemon(extensions=(routes_calibration.setup,))
    head = rig_calibration(0.3, daemon.overlay.emulation.source.model).to_yaml()
    text = head + "quality:\n  x: [" + ",".join(["0"] * ((MAX_FILE_CHARS - len(head) - 20) // 2)) + "]\n"
    assert len(text) <= MAX_FILE_CHARS
    async with daemon.http.put("/api/calibration", data=text, headers=YAML) as r:
        assert r.status == 422, await r.text()
        error = (await r.json())["error"]
    assert error.startswith("refused, the previous calibration stays active: its file would be ")
    assert error.endswith(f"more than the {MAX_FILE_CHARS:,} a calibration file may have: "
                          "shorten its quality section")
    assert not (tmp_path / "calibration.yaml").exists()


async def test_stopping_abandons_a_running_calibration_compute(start_daemon, monkeypatch) -> None:
    """The panel's compute (seconds of corner detection and calibration; minutes on the board's
    ARM cores) reads the stored pairs and writes nothing: stopping stops it rather than the
    exit waiting for it to end."""
    daemon = await start_daemon(extensions=(routes_calibration.setup, routes_calibration_panel.setup))
    entered, ended, release = threading.Event(), threading.Event(), threading.Event()

    def long_compute(*args: Any, **kwargs: Any) -> Any:  # Python that runs until released
        entered.set()
        try:
            while not release.is_set():
                time.sleep(0.001)
            raise AssertionError("the compute was let run to its end")
        finally:
            ended.set()

    monkeypatch.setattr(routes_calibration_panel, "compute", long_compute)
    post = asyncio.ensure_future(daemon.http.post("/api/calibration/compute"))
    try:
        await until(entered.is_set, "the compute started")
        took = await daemon.stop(close_sessions=False)
        assert took <= STOP_BOUND_S, f"the shutdown took {took:.2f} s"
        await until(ended.is_set, "the compute's thread stopped")  # without being released
        with pytest.raises(aiohttp.ClientError):  # the request was cut short: no candidate was answered
            async with await post as r:
                await r.read()
        assert daemon.app[routes_calibration_panel.PANEL].progress["state"] == "failed"
    finally:
        release.set()
        post.cancel()
        await daemon.close_sessions()
