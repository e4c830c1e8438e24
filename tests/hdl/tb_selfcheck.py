"""cocotb tests that check the harness, not a design: one passes, one fails on purpose.

``test_infra.py`` runs them to see that ``run_cocotb`` names a failing cocotb test and its
message, and that ``extra_env`` reaches the tests inside the simulator.
"""
from __future__ import annotations

import os
from typing import Any

import cocotb


@cocotb.test()
async def sees_extra_env(dut: Any) -> None:
    """``run_cocotb(extra_env=...)`` is visible inside the simulator."""
    assert os.environ.get("STEREOCAM_SELFCHECK") == "hello", os.environ.get("STEREOCAM_SELFCHECK")


@cocotb.test()
async def fails_on_purpose(dut: Any) -> None:
    """Fails only when asked, with a message the harness must pass on."""
    assert os.environ.get("STEREOCAM_SELFCHECK_FAIL") != "1", "deliberate failure 7f3a"
