"""stereocam/overlays/RECTIFY_CORE.md, stereocam/overlays/spec/rectify.py and
stereocam/overlays/rtl/rectify_spec.vh describe the
same core."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from stereocam.overlays.spec import verilog
from stereocam.overlays.spec.rectify import (
    BUILDS,
    CAMERA_BASE,
    PARAM_FORMAT,
    PARAM_NAMES,
    PARAM_RANGE,
    RECTIFY_MAP,
    param_offset,
)
from stereocam.overlays.spec.regs import Access

pytestmark = pytest.mark.armhf

ROOT = Path(__file__).parents[2]
DOC = (ROOT / "stereocam" / "overlays" / "RECTIFY_CORE.md").read_text()


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


def _power(text: str) -> int:
    """'-2^35', '2^35 - 1', '2^20' -> int."""
    m = re.fullmatch(r"(-?)2\^(\d+)( - 1)?", text.strip())
    assert m, text
    value = (1 << int(m.group(2))) * (-1 if m.group(1) else 1)
    return value - 1 if m.group(3) else value


def test_parameter_blocks_match_the_document() -> None:
    assert "Left camera block at `0x100`,\nright camera block at `0x200`" in DOC
    assert CAMERA_BASE == {"L": 0x100, "R": 0x200}
    assert " ".join(PARAM_NAMES[:9]) in DOC
    n_row = re.search(r"^\| 0\.\.8 \| N00 .* \| (\d+) \| \[(.+?), (.+?)\] \|$", DOC, re.M)
    assert n_row and int(n_row.group(1)) == PARAM_FORMAT["N00"].frac
    assert (_power(n_row.group(2)), _power(n_row.group(3))) == PARAM_RANGE["N00"]
    for i, name in enumerate(PARAM_NAMES[9:], start=9):
        m = re.search(rf"^\| {i} \| {name} \| .* \| (\d+) \| \[(.+?), (.+?)\](.*)\|$", DOC, re.M)
        assert m, name
        assert int(m.group(1)) == PARAM_FORMAT[name].frac, name
        assert (_power(m.group(2)), _power(m.group(3))) == PARAM_RANGE[name], name
    assert RECTIFY_MAP["L_FX_LO"].offset == 0x148 == param_offset("L", "FX")
    assert RECTIFY_MAP["R_P2_HI"].offset == 0x284
    assert "`L_FX_LO` at 0x148, `R_P2_HI` at 0x284" in DOC


def test_builds_table_matches_the_spec() -> None:
    for b in BUILDS.values():
        row = f"| {b.name} | {b.max_width} | {b.max_height} | {b.lb_rows} | {int(b.colour)} |"
        assert row in DOC, row


def test_generated_files_are_up_to_date() -> None:
    """Regenerate with `python -m stereocam.overlays.spec.verilog` after changing the spec."""
    assert verilog.stale() == []
    header = verilog.header()
    for name in PARAM_NAMES:
        assert f"`define RC_{name}_W {PARAM_FORMAT[name].bits}" in header
    assert f"`define RC_REG_CONTROL {RECTIFY_MAP['CONTROL'].offset}" in header
    assert f"`define RC_ADDR_W {RECTIFY_MAP.size.bit_length() - 1}" in header


def test_register_decode_and_harness_offsets_come_from_the_map() -> None:
    """rc_regs's decode of every control register, and the harness's offsets, are generated from RECTIFY_MAP.

    tests/hdl/test_rc_regs.py then reads and writes every word of the window in simulation.
    """
    decode = verilog.regs_decode()
    harness = verilog.harness_header()
    for reg in verilog.control_registers():
        word = f"10'h{reg.offset >> 2:03x}"
        assert f"{word}: rd_word = rd_{reg.name.lower()};" in decode, reg.name
        strobe = f"assign wr_{reg.name.lower()} = do_write && aw_addr_reg == {word};"
        assert (strobe in decode) == (reg.access is not Access.RO), reg.name
        assert f"constexpr uint32_t RC_REG_{reg.name} = {reg.offset:#05x};" in harness, reg.name
    rtl = verilog.path("rc_regs.v").read_text()
    assert f'`include "{verilog.DECODE_NAME}"' in rtl
    assert "`RC_REG_" not in rtl, "rc_regs.v decodes a control register by hand"
    cpp = verilog.path("sim/harness.cpp").read_text()
    assert '#include "rectify_regs.h"' in cpp
    assert not re.search(r"\b0x0[0-9a-f]{2}\b", cpp), "harness.cpp types a register offset"
