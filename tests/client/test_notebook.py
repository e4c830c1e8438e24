"""examples/stereocam.ipynb runs green against a real daemon (``stereocam serve`` as a subprocess).

The notebook is run as a user runs it: a Jupyter kernel (ipykernel) of this Python, driven by
nbclient, with ``STEREOCAM_URL`` pointing at the daemon. nbclient, nbformat and ipykernel are in
the current and board envs' requirements.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Dict, List

import pytest

import stereocam
from stereocam.bench.serve import running_daemon

from ..slowness import SLOWNESS

REPO = Path(stereocam.__file__).resolve().parents[1]
NOTEBOOK = REPO / "examples" / "stereocam.ipynb"
CELL_TIMEOUT_S = 120 * SLOWNESS  # a last resort: a cell waits for the daemon's frames

pytestmark = pytest.mark.slow


def notebook_json() -> Dict[str, Any]:
    data: Dict[str, Any] = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    return data


def test_the_notebook_is_kept_without_outputs() -> None:
    """Outputs are made by running it, never committed (they would hold one board's pictures)."""
    cells = notebook_json()["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert len(code) >= 5 and len(cells) > len(code)  # markdown explains the steps
    assert all(c["outputs"] == [] and c["execution_count"] is None for c in code)


def kernel_spec(folder: Path, env: Dict[str, str]) -> Path:
    """A kernelspec running ipykernel on this Python with ``env`` (the daemon's URL, this checkout)."""
    spec = folder / "kernels" / "stereocam-test"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "stereocam test", "language": "python", "env": env,
    }))
    return folder / "kernels"


# Run in a process of its own: Jupyter's client leaves its ZeroMQ sockets for the garbage collector
# (ResourceWarnings, errors under this suite's filterwarnings), and a user's kernel runs apart too.
RUNNER = """
import sys
import nbformat
from jupyter_client.kernelspec import KernelSpecManager
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient

notebook, kernels, workdir, timeout, out = sys.argv[1:]
km = KernelManager(kernel_name="stereocam-test", kernel_spec_manager=KernelSpecManager(kernel_dirs=[kernels]))
nb = nbformat.read(notebook, as_version=4)
try:
    NotebookClient(nb, km=km, timeout=float(timeout), resources={"metadata": {"path": workdir}}).execute()
finally:
    nbformat.write(nb, out)  # the run, outputs and all, as far as it went
"""


@pytest.mark.timeout(900)
def test_the_example_notebook_runs_green_against_a_daemon(tmp_path: Path, artifacts_dir: Path) -> None:
    config = tmp_path / "stereocam.yaml"
    config.write_text("no_signal_s: 15.0\n")  # a busy machine's slow frames are not "no signal"
    out = artifacts_dir / "stereocam.ipynb"
    with running_daemon(fps=10, captures=tmp_path / "captures", log_path=artifacts_dir / "daemon.log",
                        extra_args=["--config", str(config)]) as (_proc, base):
        path = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
        kernels = kernel_spec(tmp_path, {"STEREOCAM_URL": base, "PYTHONPATH": path})
        run = subprocess.run([sys.executable, "-c", RUNNER, str(NOTEBOOK), str(kernels), str(tmp_path),
                              str(CELL_TIMEOUT_S), str(out)],
                             capture_output=True, text=True, env={**os.environ, "PYTHONPATH": path})
    assert run.returncode == 0, run.stderr[-5000:]
    nb = json.loads(out.read_text(encoding="utf-8"))
    text = "\n".join(output_texts(nb))
    assert "identical: True - differing pixels: 0 - max difference: 0" in text
    assert f"{base}: emulated fabric, 752x480, source live" in text
    assert "\n404 " in text and "no_such_view" in text
    images = [o for c in nb["cells"] for o in c.get("outputs", []) if "image/png" in o.get("data", {})]
    assert len(images) == 3  # the rectified pair, the disparity map, the fabric's result of the input


def output_texts(nb: Dict[str, Any]) -> List[str]:
    out: List[str] = []
    for cell in nb["cells"]:
        for o in cell.get("outputs", []):
            if o.get("output_type") == "stream":
                out.append("".join(o["text"]))
            elif "text/plain" in o.get("data", {}):
                out.append("".join(o["data"]["text/plain"]))
    return out
