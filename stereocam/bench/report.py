"""How a ``stereocam bench`` suite reports: its figures on stdout, its exit code from its floor.

Every suite with a floor (budget, recording, robustness) ends the same way, so a script reading
any of them sees the same output and the same codes: 0 at or above the floor, 1 below it, 2 (with
a one-line error on stderr) when it could not measure at all.
"""
from __future__ import annotations

import json
import sys
from typing import Any, Callable, Dict, List, Tuple, Type

TextLines = Callable[[Dict[str, Any]], List[str]]


def print_figures(result: Dict[str, Any], as_json: bool, text_lines: TextLines) -> None:
    """``result`` as one JSON object (``--json``) or as the suite's text lines, flushed at once."""
    print(json.dumps(result) if as_json else "\n".join(text_lines(result)))
    sys.stdout.flush()


def run_suite(suite: str, measure: Callable[[], Dict[str, Any]], errors: Tuple[Type[BaseException], ...],
              as_json: bool, text_lines: TextLines) -> int:
    """Measure, print the figures and return the exit code (see the module docstring); ``errors`` are
    the failures that mean "could not measure", reported as ``stereocam bench SUITE: error: ...``."""
    try:
        result = measure()
    except errors as exc:
        print(f"stereocam bench {suite}: error: {exc}", file=sys.stderr)
        return 2
    print_figures(result, as_json, text_lines)
    return 0 if result["meets_floor"] else 1
