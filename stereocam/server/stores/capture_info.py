"""What a capture store reports about a capture, read from its folder and its meta.json.

A damaged capture (meta.json missing or not JSON, a file missing or of the
wrong size) is described, never hidden: listing a store must not fail
because of one bad folder.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple

from ...calibration.image_files import CAPTURE_FILES
from .errors import gone
from .files import read_member
from .frame_calibration import FrameCalibration
from .ids import created_from_id

__all__ = ["CaptureFile", "CaptureInfo", "META_FILE", "read_info"]

META_FILE = "meta.json"
_MAX_META_BYTES = 4 << 20


@dataclass(frozen=True)
class CaptureFile:
    name: str
    bytes: int
    sha256: Optional[str] = None  # from meta.json; None if not recorded there (meta.json itself, damage)

    def to_json(self) -> Dict[str, Any]:
        return {"name": self.name, "bytes": self.bytes, "sha256": self.sha256}


@dataclass(frozen=True)
class CaptureInfo:
    """One stored capture, as listed.

    ``files`` are the regular files in the capture's folder (``meta.json``
    included), ``bytes`` their total size. ``error`` is None for a sound
    capture, else a one-line description of what is wrong with it (meta.json
    missing or not JSON, a file missing or of the wrong size): damaged
    captures are listed, never hidden. ``meta`` is the parsed meta.json
    (empty when it cannot be read); :attr:`calibration` the record of the
    calibration the frame ran with, read from it.
    """

    id: str
    created: str
    frame: Optional[int]
    source: Optional[str]
    calibration_id: Optional[str]
    files: Tuple[CaptureFile, ...]
    bytes: int
    error: Optional[str] = None
    meta: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def calibration(self) -> Optional[FrameCalibration]:
        """The calibration the frame ran with (meta.json's ``calibration``); None when absent or not one.

        A damaged field reads as absent, as ``calibration_id`` does: a listing never fails on it.
        """
        try:
            return FrameCalibration.from_json(self.meta.get("calibration"))
        except ValueError:
            return None

    def to_json(self, *, meta: bool = False) -> Dict[str, Any]:
        """A JSON-ready dict; ``meta=True`` adds the whole meta.json under ``"meta"``."""
        out: Dict[str, Any] = {
            "id": self.id,
            "created": self.created,
            "frame": self.frame,
            "source": self.source,
            "calibration_id": self.calibration_id,
            "files": [f.to_json() for f in self.files],
            "bytes": self.bytes,
            "error": self.error,
        }
        if meta:
            out["meta"] = dict(self.meta)
        return out


def read_info(cid: str, folder: Path) -> CaptureInfo:
    """The capture ``cid`` in ``folder``, damage described in ``error``; NotFound if deleted meanwhile."""
    problems: List[str] = []
    sizes: Dict[str, int] = {}
    try:
        with os.scandir(folder) as entries:
            for entry in entries:
                if entry.is_symlink():
                    problems.append(f"{entry.name} is a symbolic link, not a file")
                elif entry.is_file(follow_symlinks=False):
                    sizes[entry.name] = entry.stat(follow_symlinks=False).st_size
    except (FileNotFoundError, NotADirectoryError):  # deleted meanwhile
        raise gone("capture", cid) from None
    problems.sort()

    doc: Dict[str, Any] = {}
    doc_ok = False
    try:
        loaded = json.loads(read_member(folder, META_FILE, _MAX_META_BYTES).decode("utf-8"))
        if not isinstance(loaded, dict):
            raise ValueError("not a JSON object")
        doc, doc_ok = loaded, True
    except FileNotFoundError:
        problems.insert(0, f"{META_FILE} is missing")
    except OSError as exc:
        problems.insert(0, f"{META_FILE} cannot be read ({exc.strerror or exc})")
    except ValueError as exc:  # includes JSONDecodeError and UnicodeDecodeError
        problems.insert(0, f"{META_FILE} is damaged ({' '.join(str(exc).split())[:80] or 'bad JSON'})")

    hashes: Dict[str, str] = {}
    if doc_ok:
        listed = doc.get("files")
        if not isinstance(listed, list) or not all(
            isinstance(f, dict) and isinstance(f.get("name"), str) and isinstance(f.get("bytes"), int)
            for f in listed
        ):
            problems.append(f"{META_FILE} has no valid file list")
            listed = []
        for f in listed:
            name, size = f["name"], f["bytes"]
            if isinstance(f.get("sha256"), str):
                hashes[name] = f["sha256"]
            if name not in sizes:
                problems.append(f"{name} is missing")
            elif sizes[name] != size:
                problems.append(f"{name} is {sizes[name]} bytes, {META_FILE} says {size}")
    else:
        for name in CAPTURE_FILES:
            if name not in sizes:
                problems.append(f"{name} is missing")

    if problems and not os.path.isdir(folder):  # deleted while we looked: not damage
        raise gone("capture", cid)
    created = doc.get("created")
    if not isinstance(created, str) or not created:
        created = created_from_id(cid)
    frame = doc.get("frame")
    if isinstance(frame, bool) or not isinstance(frame, int):
        frame = int(cid.split("-")[1])
    source = doc.get("source") if isinstance(doc.get("source"), str) else None
    calib = doc.get("calibration_id") if isinstance(doc.get("calibration_id"), str) else None
    files = tuple(CaptureFile(n, sizes[n], hashes.get(n)) for n in sorted(sizes))
    return CaptureInfo(
        id=cid,
        created=created,
        frame=frame,
        source=source,
        calibration_id=calib,
        files=files,
        bytes=sum(sizes.values()),
        error="; ".join(problems) or None,
        meta=doc,
    )
