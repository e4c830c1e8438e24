"""overlays/RECTIFY_CORE.md and overlays/spec/rectify.py describe the same core."""
from __future__ import annotations

import re
from pathlib import Path

from stereocam.overlays.spec.rectify import (
    CAMERA_BASE, PARAM_NAMES, PARAM_RANGE, RECTIFY_MAP, param_offset,
)

DOC = (Path(__file__).parents[1] / "overlays" / "RECTIFY_CORE.md").read_text()


def test_every_control_register_is_documented_with_offset_access_and_reset() -> None:
    rows = {}
    for m in re.finditer(r"^\| (0x[0-9a-f]{3}) \| (\w+) \| (\w+) \| (0x[0-9a-f]+) \|(.*)\|$", DOC, re.M):
        rows[m.group(2)] = (int(m.group(1), 16), m.group(3), int(m.group(4), 16), m.group(5))
    control = [r for r in RECTIFY_MAP if r.offset < min(CAMERA_BASE.values())]
    assert set(rows) == {r.name for r in control}
    for reg in control:
        offset, access, reset, fields = rows[reg.name]
        assert (offset, access, reset) == (reg.offset, reg.access.value, reg.reset), reg.name
        for f in reg.fields:
            bits = f"[{f.lsb + f.width - 1}:{f.lsb}]" if f.width > 1 else f"[{f.lsb}]"
            assert f"{f.name}{bits}" in fields, f"{reg.name}.{f.name}"


def test_parameter_blocks_match_the_document() -> None:
    assert "Left camera block at `0x100`, right camera block at `0x200`" in DOC
    assert CAMERA_BASE == {"L": 0x100, "R": 0x200}
    assert " ".join(PARAM_NAMES[:9]) in DOC
    for i, name in enumerate(PARAM_NAMES[9:], start=9):
        lo, hi = PARAM_RANGE[name]
        assert re.search(rf"^\| {i} \| {name} \| .* \| \[{lo:g}, {hi:g}\] \|$", DOC, re.M), name
    assert RECTIFY_MAP["L_FX_LO"].offset == 0x148 == param_offset("L", "FX")
    assert RECTIFY_MAP["R_P2_HI"].offset == 0x284
    assert "`L_FX_LO` at 0x148, `R_P2_HI` at 0x284" in DOC
