"""The guard pynq imports into every Overlay-making process: no download while the daemon owns the fabric.

Like the other pynq tests these exist only where pynq imports (the board env), and there
they must.
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any, List, Optional

import pytest

from stereocam.overlays.pynq.lock import LOCK_ENV, FabricBusy, FabricLock

from ..pynq_hwh import pynq_for_tests

pynq: Optional[Any] = pynq_for_tests()

HOLDER = textwrap.dedent("""
    import sys
    from stereocam.overlays.pynq.lock import FabricLock
    lock = FabricLock()
    lock.acquire("stereocam.bit")
    print("held", flush=True)
    sys.stdin.read()
""")

if pynq is not None:
    from stereocam.overlays.pynq import guard as pynq_guard

    @pytest.fixture
    def lock_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
        path = tmp_path / "fabric.lock"
        monkeypatch.setenv(LOCK_ENV, str(path))
        return path

    def test_pynq_imports_the_guard_in_every_overlay_process() -> None:
        """Registered under pynq.lib, the group Overlay._register_drivers imports before any download."""
        import pynqutils

        modules = [ext.module_name for ext in pynqutils.setup_utils.ExtensionsManager("pynq.lib").list]
        assert "stereocam.overlays.pynq.guard" in modules
        from pynq.pl_server.embedded_device import EmbeddedDevice

        assert getattr(EmbeddedDevice.download, "_stereocam_guarded", False)
        before = EmbeddedDevice.download
        assert pynq_guard.install() and EmbeddedDevice.download is before  # wrapped once, not twice

    def test_a_download_is_refused_while_another_process_holds_the_fabric(lock_path: Path) -> None:
        calls: List[Any] = []

        def download(device: Any, bitstream: Any, parser: Any = None) -> str:
            calls.append(bitstream)
            return "downloaded"

        guarded = pynq_guard.guarded(download)
        assert guarded("device", "free.bit") == "downloaded" and calls == ["free.bit"]
        env = {**os.environ, LOCK_ENV: str(lock_path), "INVOCATION_ID": "0123456789abcdef"}
        with subprocess.Popen([sys.executable, "-c", HOLDER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              env=env, text=True) as holder:
            try:
                assert holder.stdout is not None and holder.stdout.readline() == "held\n"
                busy = (rf"^refusing to load base.bit: the fabric is in use by the "
                        rf"stereocam service \(pid {holder.pid}: .*\) since .*: stop "
                        r"it with `systemctl stop stereocam` first")
                with pytest.raises(FabricBusy, match=busy):
                    guarded("device", "base.bit")
                assert calls == ["free.bit"]  # never reached the device
            finally:
                holder.communicate("")  # end of stdin: the holder exits and the kernel drops its lock
        assert guarded("device", "base.bit") == "downloaded" and calls == ["free.bit", "base.bit"]

    def test_the_daemon_itself_may_download(lock_path: Path) -> None:
        """The process that holds the lock (the daemon programming its own overlay) is let through."""
        own = FabricLock()
        own.acquire("stereocam.bit")
        try:
            assert pynq_guard.guarded(lambda device, bit: bit)("device", "stereocam.bit") == "stereocam.bit"
        finally:
            own.release()
