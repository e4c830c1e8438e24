"""cocotb testbench for stereocam/overlays/rtl/stereo/sc_front.v, the stereo core's front end.

Run by ``tests/hdl/test_stereo_front.py``. Each frame of ``STEREOCAM_FRONT_FRAMES`` (JSON: size, image
kind, parameters, seed) is written into the line buffer as the schedule allows (rows 0..3 first, then
row e + 4 during sweep e, on random clocks, while the front reads the others) and swept slot by slot as
sc_sched will (rows 0 .. H + 2, columns -16 .. max(W, MAX_DISP + 32) - 1), with ``run`` dropping for
random whole slots and random single clocks. Every real pixel's sums S (lanes below NUM_DISP) must equal
``stereo_fast.aggregate`` of the model's costs, and arrive with the header's timing: groups 0..3 at
phases 0..3 of the third slot after the pixel's own, in raster order, nothing else valid.
"""
from __future__ import annotations

import json
import os
import random
from typing import Any

import cocotb
import numpy as np
from cocotb.triggers import FallingEdge

from stereocam.overlays.model import stereo_fast
from stereocam.overlays.spec import stereo as spec

from .unit_bench import params, pulse_reset, start_clock

LATENCY_SLOTS = 3  # the header's
PRE = 16  # the scheduler's columns before column 0


def frames() -> list[dict[str, Any]]:
    return list(json.loads(os.environ.get("STEREOCAM_FRONT_FRAMES", "[]")))


def images(kind: str, h: int, w: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A left and right gray pair: ``random`` (independent noise), ``shifted`` (a blocky texture with
    noise, the right image the left shifted by a few disparities, so paths see both edges and flat
    runs), ``flat`` (two constant images: every census word 0)."""
    if kind == "random":
        return (rng.integers(0, 256, (h, w), dtype=np.uint8), rng.integers(0, 256, (h, w), dtype=np.uint8))
    if kind == "flat":
        return np.full((h, w), 77, np.uint8), np.full((h, w), 200, np.uint8)
    assert kind == "shifted", kind
    shift = int(rng.integers(1, 7))
    blocks = rng.integers(0, 256, (h // 3 + 1, (w + shift) // 4 + 2))
    texture = np.kron(blocks, np.ones((3, 4)))[:h, :w + shift] + rng.integers(-6, 7, (h, w + shift))
    texture = np.clip(texture, 0, 255).astype(np.uint8)
    return texture[:, shift:shift + w].copy(), texture[:, :w].copy()


def expected_sums(left: np.ndarray, right: np.ndarray, p: spec.StereoParams) -> np.ndarray:
    c = stereo_fast.costs(stereo_fast.census(left), stereo_fast.census(right), p.num_disp)
    return stereo_fast.aggregate(c, left, p)


async def write_row(dut: Any, img_l: np.ndarray, img_r: np.ndarray, y: int, rng: random.Random,
                    p_idle: float) -> None:
    """Write row ``y`` into the line buffer, one pixel per clock with random idle clocks."""
    for x in range(img_l.shape[1]):
        while rng.random() < p_idle:
            dut.lb_we.value = 0
            await FallingEdge(dut.clk)
        dut.lb_we.value = 1
        dut.lb_col.value = x
        dut.lb_row.value = y
        dut.lb_data.value = int(img_l[y, x]) | (int(img_r[y, x]) << 8)
        await FallingEdge(dut.clk)
    dut.lb_we.value = 0


async def sweep_frame(dut: Any, case: dict[str, Any], max_disp: int, parallel: int) -> list[str]:
    """Write and sweep one frame; the problems found (empty when every pixel's sums are right)."""
    h, w = case["height"], case["width"]
    rng = random.Random(case["seed"])
    img_l, img_r = images(case["kind"], h, w, np.random.default_rng(case["seed"]))
    p = spec.DEFAULT_PARAMS.with_values(**case["params"])
    want = expected_sums(img_l, img_r, p)
    dut.width.value, dut.height.value = w, h
    for name in ("num_disp", "p1", "p2", "p2_edge", "edge_thresh"):
        getattr(dut, name).value = getattr(p, name)
    p_slot_gap, p_clock_gap = case.get("slot_gap", 0.08), case.get("clock_gap", 0.12)

    for y in range(min(4, h)):
        await write_row(dut, img_l, img_r, y, rng, 0.0)
    slot_of: dict[tuple[int, int], int] = {}
    got: dict[tuple[int, int], dict[int, list[int]]] = {}
    problems: list[str] = []
    order: list[tuple[int, int]] = []
    slot = 0
    ncols = max(w, max_disp + 32)
    mask = (1 << 10) - 1
    for e in range(h + 3):
        writer = cocotb.start_soon(write_row(dut, img_l, img_r, e + 4, rng, 0.5)) if e + 4 < h else None
        for c in range(-PRE, ncols):
            if rng.random() < p_slot_gap:
                dut.run.value = 0
                for _ in range(rng.randint(1, 6)):
                    await FallingEdge(dut.clk)
            if 0 <= e < h and 0 <= c < w:
                slot_of[(e, c)] = slot
            for ph in range(4):
                while rng.random() < p_clock_gap:
                    dut.run.value = 0
                    await FallingEdge(dut.clk)
                dut.run.value = 1
                dut.phase.value = ph
                dut.row.value = e & 0xFFF
                dut.col.value = c & 0xFFF
                if int(dut.m_valid.value):
                    x, yy, g = int(dut.m_x.value), int(dut.m_y.value), int(dut.m_group.value)
                    key = (yy, x)
                    if g != ph:
                        problems.append(f"pixel {key} group {g} at phase {ph}")
                    if slot_of.get(key, -99) + LATENCY_SLOTS != slot:
                        problems.append(f"pixel {key} group {g} in slot {slot}, "
                                        f"brought in at {slot_of.get(key)}")
                    total = int(dut.m_sum.value)
                    got.setdefault(key, {})[g] = [(total >> (10 * j)) & mask for j in range(parallel)]
                    if g == 0:
                        order.append(key)
                await FallingEdge(dut.clk)
            slot += 1
        if writer is not None:
            await writer
    dut.run.value = 0

    if order != [(y, x) for y in range(h) for x in range(w)]:
        problems.append(f"pixels out of raster order or missing: {len(order)} of {h * w}, first {order[:4]}")
    wrong = 0
    for (y, x), groups in sorted(got.items()):
        if sorted(groups) != [0, 1, 2, 3]:
            problems.append(f"pixel {(y, x)}: groups {sorted(groups)}")
            continue
        sums = [s for g in range(4) for s in groups[g]][:p.num_disp]
        ref = [int(v) for v in want[y, x]]
        if sums != ref:
            wrong += 1
            if wrong <= 4:
                bad = [d for d in range(p.num_disp) if sums[d] != ref[d]]
                problems.append(f"pixel (y {y}, x {x}): {len(bad)} lanes wrong, d {bad[:6]}: rtl "
                                f"{[sums[d] for d in bad[:6]]}, model {[ref[d] for d in bad[:6]]}")
    if wrong:
        problems.append(f"{wrong} of {h * w} pixels wrong")
    return problems


@cocotb.test()
async def sums_match_model(dut: Any) -> None:
    """Every frame of the case list: each real pixel's S for d < NUM_DISP equals the model's, on time."""
    p = params()
    max_disp, parallel = p["MAX_DISP"], p["PARALLEL"]
    start_clock(dut.clk)
    dut.run.value = 0
    dut.lb_we.value = 0
    dut.phase.value = 0
    dut.row.value = 0
    dut.col.value = 0
    await pulse_reset(dut, 3)
    await FallingEdge(dut.clk)
    problems: list[str] = []
    cases = frames()
    assert cases, "no frames given (STEREOCAM_FRONT_FRAMES)"
    for case in cases:
        found = await sweep_frame(dut, case, max_disp, parallel)
        name = f"{case['kind']} {case['width']}x{case['height']} {case['params']}"
        problems += [f"{name}: {m}" for m in found[:8]]
    assert not problems, f"{len(problems)} problems:\n" + "\n".join(problems[:16])
