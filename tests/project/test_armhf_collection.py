"""The armhf subset is collected where the test tools that environment lacks are missing.

The armhf env (Debian's armhf Python under qemu) has no Playwright, cocotb or nbclient: a conftest
that imports one at its top stops the whole armhf run at collection (CI failed so once, on
``tests/browser/conftest.py``). Here the subset is collected in a process where importing each of
them fails, as it does there.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ABSENT_ON_ARMHF = ("playwright", "cocotb", "cocotb_tools", "nbclient")


def test_the_armhf_subset_collects_without_the_tools_armhf_lacks(tmp_path: Path) -> None:
    for name in ABSENT_ON_ARMHF:
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(
            f"raise ModuleNotFoundError({f'No module named {name!r} (as on armhf)'!r})\n")
    env = dict(os.environ, STEREOCAM_TEST_ENV="armhf",
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(REPO)]))
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    tail = done.stdout[-3000:] + done.stderr[-2000:]
    assert done.returncode == 0, tail
    assert "error" not in done.stdout.splitlines()[-1], tail
    assert " collected" in done.stdout.splitlines()[-1], tail
