"""cocotb testbench for stereocam/overlays/rtl/stereo/sc_input.v, the stereo core's stream input.

Run by ``tests/hdl/test_stereo_front.py``. A stream of frames, good ones and each kind of bad one the
header names (a short row, a long row, TUSER inside a frame, beats between frames), goes in with random
TVALID gaps and a row limit that holds rows back now and then. What comes out must be what the header
says: every beat of a frame's rows written once at its column and row (the long row's extra beats and the
beats between frames not at all), no row past the limit, a SIZE_ERROR pulse for each bad event and none
for a good frame, and the rows counted.
"""
from __future__ import annotations

from typing import Any

import cocotb
from cocotb.triggers import FallingEdge, Timer

from .unit_bench import pulse_reset, start_unit

W, H = 12, 5


def frame(rng: Any, kind: str) -> list[tuple[int, int, int, int]]:
    """The beats (tuser, tlast, left, right) of one W x H frame of ``kind``: ``good``, ``short`` (row 1
    ends 3 early), ``long`` (row 2 runs 3 past the width), ``cut`` (TUSER on row 3's fifth beat: the
    next frame starts there)."""
    beats = []
    for r in range(H):
        n = W - 3 if kind == "short" and r == 1 else W + 3 if kind == "long" and r == 2 else W
        for c in range(n):
            if kind == "cut" and r == 3 and c == 4:
                return beats
            beats.append((int(r == 0 and c == 0), int(c == n - 1), rng.randrange(256), rng.randrange(256)))
    return beats


def expected(beats: list[tuple[int, int, int, int]]) -> tuple[list[tuple[int, int, int]], int]:
    """The writes (col, row, data) and the number of SIZE_ERROR events the header's rules give."""
    writes: list[tuple[int, int, int]] = []
    errors, in_frame, skipping, col, row = 0, False, False, 0, 0
    for tuser, tlast, left, right in beats:
        if in_frame and tuser:  # the frame ends; the beat then starts the next one
            errors, in_frame = errors + 1, False
        if not in_frame:
            if not tuser:
                errors += 1
                continue
            in_frame, skipping, col, row = True, False, 0, 0
        if skipping:
            skipping = not tlast
            continue
        writes.append((col, row, right << 8 | left))
        if tlast or col == W - 1:
            if tlast != (col == W - 1):
                errors += 1
                skipping = not tlast
            col, row = 0, row + 1
            in_frame = row < H
        else:
            col += 1
    return writes, errors


@cocotb.test()
async def frames_good_and_bad(dut: Any) -> None:
    _, rng = start_unit(dut, 3)
    kinds = ["good", "short", "good", "long", "good", "cut", "good", "stray", "good", "good"]
    beats: list[tuple[int, int, int, int]] = []
    for kind in kinds:
        if kind == "stray":  # two beats between frames, without TUSER
            beats += [(0, 0, 1, 2), (0, 1, 3, 4)]
        else:
            beats += frame(rng, kind)
    want_writes, want_errors = expected(beats)
    for name, value in {"s_tvalid": 0, "s_tuser": 0, "s_tlast": 0, "s_tdata": 0, "enable": 1, "width": W,
                        "height": H, "accept_frame": 1, "row_limit": 2047}.items():
        getattr(dut, name).value = value
    await pulse_reset(dut, 3)
    writes: list[tuple[int, int, int]] = []
    errors, held, sent, clocks = 0, 0, 0, 0
    while sent < len(beats) or clocks < 20:
        await FallingEdge(dut.clk)
        errors += int(dut.size_error.value)
        rows = int(dut.rows_in.value)
        # now and then the engine holds the next row back: the limit just below the row being written
        limit = rows - 1 if rows > 0 and rng.random() < 0.15 else 2047
        dut.row_limit.value = limit
        valid = sent < len(beats) and rng.random() < 0.7
        tuser, tlast, left, right = beats[sent] if sent < len(beats) else (0, 0, 0, 0)
        dut.s_tvalid.value = int(valid)
        dut.s_tuser.value = tuser
        dut.s_tlast.value = tlast
        dut.s_tdata.value = right << 56 | left << 24 | rng.getrandbits(24) << 32 | rng.getrandbits(24)
        await Timer(1, "ns")
        if int(dut.lb_we.value):
            row = int(dut.lb_row.value)
            assert row <= int(dut.row_limit.value), f"row {row} written past the limit"
            writes.append((int(dut.lb_col.value), row, int(dut.lb_data.value)))
        held += int(valid and limit != 2047 and not int(dut.s_tready.value))
        if valid and int(dut.s_tready.value):
            sent += 1
        clocks = clocks + 1 if sent == len(beats) else 0
    assert held > 0, "the limit never held a beat back"
    first_wrong = next((i for i, (a, b) in enumerate(zip(writes, want_writes, strict=False)) if a != b), None)
    assert writes == want_writes, (len(writes), len(want_writes), first_wrong)
    assert errors == want_errors == 5, (errors, want_errors)
    assert int(dut.rows_in.value) == H
