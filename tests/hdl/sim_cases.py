"""Which simulators each case of a co-simulation test runs under.

Icarus builds in a second and runs every case; a Verilator build takes some 10-30 s (cached), so
Verilator runs the cases a test picks, and every case with ``STEREOCAM_COSIM_FULL=1``
(``./scripts/cosim``).
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from typing import TypeVar

import pytest

from stereocam.overlays.rtl import toolchain as hdl

FULL = os.environ.get("STEREOCAM_COSIM_FULL", "") not in ("", "0")

Case = TypeVar("Case")


def sim_cases(cases: Iterable[Case], name: Callable[[Case], str],
              verilator: Callable[[Case], bool]) -> list[object]:
    """``(sim, case)`` parameters, id ``{sim}-{name(case)}``: every case under Icarus, under Verilator
    those for which ``verilator(case)`` is true (every case with :data:`FULL`)."""
    return [pytest.param(sim, case, id=f"{sim}-{name(case)}")
            for case in cases
            for sim in hdl.SIMULATORS
            if sim == "icarus" or verilator(case) or FULL]
