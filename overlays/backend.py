"""Choosing the fabric: the board's (pynq) or the emulated one.

``auto`` takes pynq when it is importable *and* the bitstream is present,
otherwise the emulated fabric, and :attr:`Choice.reason` says why (the
daemon logs it), so nobody wonders which one they are looking at.
"""
from __future__ import annotations

import importlib.util
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from .spec.overlay import BITSTREAM

log = logging.getLogger(__name__)

BACKENDS = ("auto", "pynq", "emulated")
DEFAULT_BITSTREAM_DIRS = (Path(__file__).parent, Path("/usr/local/share/stereocam"))


class BackendError(RuntimeError):
    """The backend asked for cannot be used; the message says what is missing."""


@dataclass(frozen=True)
class Choice:
    backend: str
    reason: str
    bitstream: Optional[Path] = None


def find_bitstream(explicit: Optional[Path] = None) -> Optional[Path]:
    if explicit is not None:
        return explicit if explicit.is_file() else None
    env = os.environ.get("STEREOCAM_BITSTREAM")
    candidates = [Path(env)] if env else [d / BITSTREAM for d in DEFAULT_BITSTREAM_DIRS]
    return next((p for p in candidates if p.is_file()), None)


def choose(backend: str = "auto", *, bitstream: Optional[Path] = None) -> Choice:
    """Decide which fabric to use, without touching any hardware."""
    if backend not in BACKENDS:
        raise BackendError(f"--backend must be one of {', '.join(BACKENDS)}, not {backend!r}")
    if backend == "emulated":
        return Choice("emulated", "--backend emulated was asked for")
    has_pynq = importlib.util.find_spec("pynq") is not None
    bit = find_bitstream(bitstream)
    where = str(bitstream) if bitstream else f"$STEREOCAM_BITSTREAM or {' or '.join(str(d / BITSTREAM) for d in DEFAULT_BITSTREAM_DIRS)}"
    if backend == "pynq":
        if not has_pynq:
            raise BackendError("--backend pynq: the pynq package is not installed (run on the board's PYNQ image)")
        if bit is None:
            raise BackendError(f"--backend pynq: no bitstream found at {where}")
        return Choice("pynq", "--backend pynq was asked for", bit)
    if not has_pynq:
        return Choice("emulated", "pynq is not installed, so this is not a board")
    if bit is None:
        return Choice("emulated", f"pynq is installed but no bitstream was found at {where}")
    return Choice("pynq", f"pynq is installed and the bitstream is at {bit}", bit)


def open_overlay(backend: str = "auto", *, bitstream: Optional[Path] = None, **emulated_options: Any) -> Any:
    """An overlay object with ``.fabric``, ``.backend``, ``start()``, ``stop()``, ``close()``.

    ``emulated_options`` go to :class:`~.emulated.overlay.EmulatedOverlay`
    (source, fps, clock, build, lb_rows).
    """
    choice = choose(backend, bitstream=bitstream)
    log.info("fabric backend: %s (%s)", choice.backend, choice.reason)
    overlay: Any
    if choice.backend == "pynq":
        from .pynq.overlay import StereocamOverlay

        assert choice.bitstream is not None
        overlay = StereocamOverlay(choice.bitstream)
    else:
        from .emulated.overlay import EmulatedOverlay

        overlay = EmulatedOverlay(**emulated_options)
    overlay.choice = choice
    return overlay
