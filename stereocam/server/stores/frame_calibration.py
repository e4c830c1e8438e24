"""The calibration one frame ran with: one immutable record for captures, recordings and the page.

The daemon learns it per fabric frame from the frame's FRAME_COUNT against the calibration
changes it made (:meth:`..http.state.CalibrationState.for_frame`); that answer is a
:class:`FrameCalibration`, and every consumer takes it from there: a capture's ``meta.json``
(``calibration_id`` and ``calibration``), a recording's ``frames.jsonl`` lines
(``calibration_id``) and ``recording.json`` (``calibration``, of its first frame), and the
page's depth readouts (``GET /api/point``, ``GET /api/disparity``).

Its stored form, :meth:`FrameCalibration.to_json`, is what those files (and ``/api/status``'s
``calibration``) have always held, and :meth:`FrameCalibration.from_json` reads it back, old
files included. The depth figures (:class:`DepthScale`: Q, focal length, baseline) are not in
the stored form (the formats predate this record and do not change): a record read from a file
has none, and equality compares what a file keeps, so the record of a frame read from a capture,
from a recording and taken live are equal.

Here, below the frame path, because the stores read it back (they must not import
:mod:`..frames`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np

__all__ = ["FrameCalibration", "DepthScale", "UNITS_TO_M"]

UNITS_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
NONE_DESCRIPTION = "none: the core passes frames through unrectified"
CHANGED_DESCRIPTION = "unknown: the calibration changed while this frame was processed"
# Why a frame has no depth (GET /api/point's ``depth_unavailable``).
NO_DEPTH_CHANGED = "the calibration changed while this frame was processed: hover again"
NO_DEPTH_NONE = "no calibration is known: the core passes frames through (apply one in the calibration panel)"
NO_DEPTH_Q = "the calibration's Q matrix gives no depth (Q[3][2] is 0)"
NO_DEPTH_UNIT = "the calibration does not say the unit of its baseline (units: unknown)"
NO_DEPTH_STORED = "read from a file: captures and recordings do not keep the calibration's Q"
_INT_FIELDS = ("rows_needed", "lb_rows", "lb_delay")
_KNOWN_KEYS = ("id", "description") + _INT_FIELDS


@dataclass(frozen=True)
class DepthScale:
    """What depth needs of a calibration: its Q (OpenCV's ``stereoRectify``) and the unit of its T.

    Z = Q[2][3] / (Q[3][2] d + Q[3][3]) in the unit of T; f = Q[2][3] and B = 1 / |Q[3][2]|, so
    Z = f B / d where both rectified principal points agree (``CALIB_ZERO_DISPARITY``, what
    stereocam writes). Only made for a Q that gives depth (4x4, Q[3][2] not 0).
    """

    Q: Tuple[Tuple[float, ...], ...]
    units: str

    @classmethod
    def of(cls, calibration: Any) -> Optional["DepthScale"]:
        """The scale of a calibration (anything with ``rect.Q`` and ``units``); None when Q gives no depth."""
        Q = np.asarray(calibration.rect.Q, dtype=np.float64)
        if Q.shape != (4, 4) or Q[3, 2] == 0:
            return None
        return cls(Q=tuple(tuple(float(v) for v in row) for row in Q),
                   units=str(getattr(calibration, "units", "unknown")))

    @property
    def unit_m(self) -> Optional[float]:
        """Metres per unit of T; None when the calibration does not say its unit."""
        return UNITS_TO_M.get(self.units)

    @property
    def focal_px(self) -> float:
        return self.Q[2][3]

    @property
    def baseline_m(self) -> Optional[float]:
        unit = self.unit_m
        return None if unit is None else float(unit / abs(self.Q[3][2]))

    @property
    def doffs_px(self) -> float:
        """Q[3][3] / Q[3][2]: 0 when the rectified principal points agree."""
        return float(self.Q[3][3] / self.Q[3][2])


@dataclass(frozen=True)
class FrameCalibration:
    """The calibration a frame ran with (immutable; equal when a file would say the same).

    ``id`` names it (None: no calibration, the core passes frames through; or not ``known``),
    ``description`` says where it came from, ``rows_needed``/``lb_rows``/``lb_delay`` are the
    line-buffer fit. ``known`` False: the frame ran while a calibration was being programmed,
    so which one is not known (:meth:`unknown`). ``depth`` is the scale depth readouts use and
    ``depth_unavailable`` why a frame of this calibration has no depth (None when it has);
    neither is stored nor compared.
    """

    id: Optional[str] = None
    description: str = NONE_DESCRIPTION
    rows_needed: Optional[int] = None
    lb_rows: Optional[int] = None
    lb_delay: Optional[int] = None
    known: bool = True
    depth: Optional[DepthScale] = field(default=None, compare=False)
    depth_unavailable: Optional[str] = field(default=NO_DEPTH_NONE, compare=False)

    def __post_init__(self) -> None:
        if self.id is not None and not isinstance(self.id, str):
            raise ValueError(f"a calibration id is a string or null, not {type(self.id).__name__}")
        if not isinstance(self.description, str):
            raise ValueError(f"a calibration description is a string, not {type(self.description).__name__}")
        for name in _INT_FIELDS:
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
                raise ValueError(f"a calibration's {name} is a whole number of rows or null, "
                                 f"not {value!r:.40}")
        if not self.known and (self.id is not None or any(getattr(self, n) is not None for n in _INT_FIELDS)):
            raise ValueError("a calibration not known has no id and no line-buffer figures")

    @classmethod
    def of(cls, calibration: Any, *, id: Optional[str], description: str, rows_needed: Optional[int] = None,
           lb_rows: Optional[int] = None, lb_delay: Optional[int] = None) -> "FrameCalibration":
        """The record of a calibration programmed into the core (``calibration`` None: none is)."""
        depth = None if calibration is None else DepthScale.of(calibration)
        if calibration is None:
            why: Optional[str] = NO_DEPTH_NONE
        elif depth is None:
            why = NO_DEPTH_Q
        else:
            why = NO_DEPTH_UNIT if depth.unit_m is None else None
        return cls(id=id, description=description, rows_needed=rows_needed, lb_rows=lb_rows,
                   lb_delay=lb_delay, depth=depth, depth_unavailable=why)

    @classmethod
    def unknown(cls) -> "FrameCalibration":
        """The record of a frame that ran while a calibration was being programmed (either register set)."""
        return cls(description=CHANGED_DESCRIPTION, known=False, depth_unavailable=NO_DEPTH_CHANGED)

    def to_json(self) -> Dict[str, Any]:
        """The stored form: ``calibration`` of a capture's meta.json, a recording.json, ``/api/status``."""
        if not self.known:
            return {"id": None, "description": self.description}
        return {"id": self.id, "description": self.description, "rows_needed": self.rows_needed,
                "lb_rows": self.lb_rows, "lb_delay": self.lb_delay}

    @classmethod
    def from_json(cls, doc: Any) -> "FrameCalibration":
        """The record :meth:`to_json` wrote (any file written before reads back to the record it was).

        Keys it does not know are ignored. Raises ValueError, one line saying what is wrong,
        for anything else (not an object, a field of the wrong type).
        """
        if not isinstance(doc, Mapping):
            raise ValueError(f"a calibration is a JSON object, not {type(doc).__name__}")
        fields: Dict[str, Any] = {k: doc[k] for k in _KNOWN_KEYS if k in doc}
        if "description" not in fields:
            raise ValueError("a calibration without a description is not one stereocam wrote")
        known = fields.get("id") is not None or any(k in fields for k in _INT_FIELDS)
        return cls(**fields, known=known, depth_unavailable=NO_DEPTH_STORED if known else NO_DEPTH_CHANGED)
