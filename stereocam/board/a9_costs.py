"""What the board's Cortex-A9 pays for each per-frame operation of the daemon: the table
``stereocam bench a9`` counts (``a9_costs.json`` here), read where the daemon plans its CPU.

The table gives instructions per run of each operation, counted as armhf code under QEMU, and
milliseconds at 650 MHz over a range of cycles per instruction. Its ``fingerprint`` is the hash of
the files whose code it measured (:data:`MEASURED`): :func:`is_current` is false once one of them
changed without the table being measured again (a test holds it true).
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple

PACKAGE = Path(__file__).resolve().parent.parent  # stereocam/
TABLE = Path(__file__).resolve().parent / "a9_costs.json"
#: The files whose code the table measures (relative to the package).
MEASURED: Tuple[str, ...] = (
    "bench/a9/measure.py",
    "server/frames/views.py",
    "server/frames/encoders.py",
    "server/frames/recorder.py",
    "server/stores/capture_images.py",
    "overlays/spec/pixel.py",
)


class A9TableError(Exception):
    """The table is missing or unreadable: say which file and how to write it."""


def fingerprint(root: Path = PACKAGE) -> str:
    """The hash of :data:`MEASURED` as they are now."""
    digest = hashlib.sha256()
    for name in MEASURED:
        digest.update(name.encode() + b"\0" + (root / name).read_bytes() + b"\0")
    return digest.hexdigest()[:16]


@lru_cache(maxsize=4)
def load_table(path: Path = TABLE) -> Dict[str, Any]:
    """The table (read once per path)."""
    try:
        table: Dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise A9TableError(f"cannot read the A9 cost table {path}: {exc}; `stereocam bench a9` writes it"
                           ) from None
    return table


def is_current(table: Optional[Mapping[str, Any]] = None) -> bool:
    """True when the table was measured on the code as it is now."""
    table = table if table is not None else load_table()
    return bool(table.get("fingerprint") == fingerprint())


def board_seconds(table: Optional[Mapping[str, Any]] = None, *,
                  cpi: Optional[float] = None) -> Dict[str, float]:
    """Seconds per run of each operation on the board at ``cpi`` (default the range's upper end: a plan
    had rather leave CPU over than fall behind)."""
    table = table if table is not None else load_table()
    cpu = table["cpu"]
    rate = float(cpu["clock_hz"]) / (cpi if cpi is not None else float(cpu["cpi"][1]))
    return {name: float(op["instructions"]) / rate for name, op in table["ops"].items()}


#: The frame the table was counted on (its ``render.*`` and ``jpeg.*`` rows).
FRAME = (752, 480)
_WIDE = ("sbs",)  # views twice the frame's width (server/frames/views.py REGISTRY: wide)


def view_seconds(seconds: Mapping[str, float], view: str, gray: bool, scale: float, quality: int,
                 frame_size: Tuple[int, int]) -> Optional[float]:
    """A frame of ``view`` on the board: its render at ``scale`` (the table's row, full size or half)
    and its JPEG at ``quality``, the table's encode of that kind per pixel times the view's pixels
    (qualities between those counted take the next one up). None for what the table did not count:
    another frame size or scale, or the disparity views (their render is the shared match's)."""
    kind = "gray" if gray else "colour"
    render = seconds.get(f"render.{view}.{kind}.x{scale:g}")
    if render is None or tuple(frame_size) != FRAME:
        return None
    counted = sorted(int(name.rsplit(".q", 1)[1]) for name in seconds if name.startswith(f"jpeg.{kind}.q"))
    if not counted:
        return None
    q = next((c for c in counted if c >= quality), counted[-1])
    per_pixel = seconds[f"jpeg.{kind}.q{q}"] / (FRAME[0] * FRAME[1])
    width = FRAME[0] * (2 if view in _WIDE else 1)
    return render + per_pixel * round(width * scale) * round(FRAME[1] * scale)
