"""How much slower than an idle host this test environment may be: the one factor for every bound.

A bound in a test (pytest-timeout's per-test timeout, a last-resort wait) catches a hang; it must
never catch a slow machine. The suite runs on shared two-core machines with other work beside it
(a load of 5-20 is normal), and the armhf env runs Debian's Python under qemu-user, 10-30 times
slower than the host. So every bound is written as the time an idle host needs, with room, and
multiplied by :data:`SLOWNESS` here. ``STEREOCAM_TEST_SLOWNESS`` overrides the factor.
"""
from __future__ import annotations

import os

#: The factor by environment (``STEREOCAM_TEST_ENV``); a host env, or a run by hand, gets ``host``.
FACTORS = {"armhf": 10.0, "host": 3.0}


def _slowness() -> float:
    given = os.environ.get("STEREOCAM_TEST_SLOWNESS")
    if given:
        try:
            value = float(given)
        except ValueError:
            raise SystemExit(f"STEREOCAM_TEST_SLOWNESS={given!r} is not a number (try 3)") from None
        if not value >= 1.0:
            raise SystemExit(f"STEREOCAM_TEST_SLOWNESS={given!r} must be at least 1")
        return value
    return FACTORS.get(os.environ.get("STEREOCAM_TEST_ENV", ""), FACTORS["host"])


SLOWNESS = _slowness()
