"""The malformed requests of the barrage: every family of cases, filled up with random mutations."""
from __future__ import annotations

import random
from typing import Dict, List, Optional, Sequence, Tuple

from .daemon_process import TOKEN
from .malformed_bodies import json_cases, yaml_cases
from .malformed_case import ANSWERED, Case, CaseBuilder, flip_bits
from .malformed_headers import header_cases, line_cases
from .malformed_uploads import upload_cases


def malformed_requests(count: int = 2000, *, frame_size: Tuple[int, int] = (752, 480),
                       calibration_yaml: Optional[str] = None, token: Optional[str] = TOKEN,
                       seed: int = 10) -> List[Case]:
    """``count`` malformed requests for a daemon of ``frame_size``, in a shuffled order.

    Every kind (``upload``, ``json``, ``yaml``, ``header``, ``line``) and every endpoint that
    takes a body is there (about 1,600 structured cases); random mutations of them (a bit
    flipped in the request line, cut short) fill up to ``count``, and a ``count`` below the
    structured cases takes a seeded sample of them. ``calibration_yaml`` is a
    calibration the daemon would accept (``GET /api/calibration``'s ``yaml``): its fields
    are each replaced by hostile values. ``token`` is the daemon's access token (it goes
    on every state-changing request but the ones about tokens). Deterministic for a seed.
    """
    rng = random.Random(seed)
    b = CaseBuilder(token)
    upload_cases(b, frame_size, rng)
    json_cases(b)
    yaml_cases(b, calibration_yaml, rng)
    header_cases(b)
    line_cases(b, rng)
    cases = list(b.cases)
    structured = [c for c in cases
                  if c.kind in ("json", "line", "header") and c.answered and len(c.data) < 20_000]
    while len(cases) < count:  # a bit flipped in the request line, or the request cut short and closed
        base = rng.choice(structured)
        line_end = base.data.find(b"\r\n")
        if rng.random() < 0.5 and line_end > 0:
            data = flip_bits(base.data[:line_end], rng, 1, 0) + base.data[line_end:]
            cases.append(Case(base.kind, "a flipped bit in the request line of " + base.name, data,
                              frozenset(ANSWERED)))
        else:
            data = base.data[:rng.randrange(1, len(base.data))]
            cases.append(Case(base.kind, "cut short: " + base.name, data, frozenset(), answered=False))
    if len(cases) > count:
        return rng.sample(cases, count)
    rng.shuffle(cases)
    return cases


def warmup_requests(cases: Sequence[Case]) -> List[Case]:
    """One request of each kind and leading word of its name: what a warm-up round sends."""
    seen: Dict[Tuple[str, str], Case] = {}
    for c in cases:
        seen.setdefault((c.kind, c.name.split(" ")[0]), c)
    return list(seen.values())
