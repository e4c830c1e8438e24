"""cocotb testbench for stereocam/overlays/rtl/rc_coord.v, the coordinate engine (steps 1-4, both cameras).

Run by ``tests/hdl/test_rc_coord.py`` through ``run_cocotb`` under Verilator and Icarus; it
is not a pytest module (cocotb imports it inside the simulator). The pytest side writes
the parameter sets to a JSON file named by ``RC_COORD_CASES``:
``{"cases": [{"name", "width", "height", "left": {REG: int}, "right": {REG: int},
"ready": probability of out_ready per clock, "seed"}]}`` (``COCOTB_TEST_FILTER`` picks the
cocotb tests to run).
Every output word of every frame is compared with ``positions()`` of the integer model
(``stereocam/overlays/model/fixed.py``); a case passes only with 0 differing words, exactly
``width * height`` words and nothing after them. Timing figures (clocks from start to the
first word, clocks per word, simulated positions per second) go to ``RC_COORD_REPORT``
when it is set.
"""
from __future__ import annotations

import json
import os
import random
import time
from dataclasses import dataclass

import cocotb
import numpy as np
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, RisingEdge

from stereocam.overlays.model.fixed import positions
from stereocam.overlays.spec.rectify import PARAM_NAMES, CameraRegs

from .unit_bench import add_to_report, drive, mismatches, start_clock

MASK64 = (1 << 64) - 1
# Clocks the engine may take to produce its first word after start (pipeline plus FIFO).
FIRST_WORD_LIMIT = 80


def _settings() -> dict:
    path = os.environ.get("RC_COORD_CASES")
    if not path:
        raise RuntimeError("RC_COORD_CASES is not set: run this testbench through tests/hdl/test_rc_coord.py")
    with open(path) as f:
        return json.load(f)


def _report(key: str, value: object) -> None:
    add_to_report("RC_COORD_REPORT", key, value)


def pack(values: dict) -> int:
    """A camera's 17 signed 64-bit parameters as the flat ``17 * 64``-bit vector, N00 at bit 0."""
    out = 0
    for i, name in enumerate(PARAM_NAMES):
        out |= (int(values[name]) & MASK64) << (64 * i)
    return out


@dataclass
class Expected:
    """The model's words for one frame, in raster order."""

    iu_l: np.ndarray
    iv_l: np.ndarray
    ok_l: np.ndarray
    iu_r: np.ndarray
    iv_r: np.ndarray
    ok_r: np.ndarray

    @classmethod
    def frame(cls, left: dict, right: dict, width: int, height: int) -> "Expected":
        ys, xs = np.mgrid[0:height, 0:width]
        xs, ys = xs.ravel(), ys.ravel()
        iu_l, iv_l, ok_l = positions(CameraRegs.from_values(left), xs, ys)
        iu_r, iv_r, ok_r = positions(CameraRegs.from_values(right), xs, ys)
        return cls(iu_l, iv_l, ok_l.astype(np.int64), iu_r, iv_r, ok_r.astype(np.int64))

    def word(self, k: int) -> tuple:
        return (int(self.iu_l[k]), int(self.iv_l[k]), int(self.ok_l[k]),
                int(self.iu_r[k]), int(self.iv_r[k]), int(self.ok_r[k]))

    def __len__(self) -> int:
        return len(self.iu_l)


class TB:
    def __init__(self, dut: SimHandleBase) -> None:
        self.dut = dut
        start_clock(dut.clk)
        drive(dut, start=0, out_ready=0, width=1, height=1, par_l=0, par_r=0)
        self.outputs = (dut.iu_l, dut.iv_l, dut.ok_l, dut.iu_r, dut.iv_r, dut.ok_r)

    async def reset(self) -> None:
        self.dut.rst.value = 1
        await ClockCycles(self.dut.clk, 3)
        self.dut.rst.value = 0
        await RisingEdge(self.dut.clk)

    def program(self, left: dict, right: dict, width: int, height: int) -> None:
        drive(self.dut, par_l=pack(left), par_r=pack(right), width=width, height=height)

    async def pulse_start(self) -> None:
        self.dut.start.value = 1
        await RisingEdge(self.dut.clk)
        self.dut.start.value = 0

    def read_word(self) -> tuple:
        iu_l, iv_l, ok_l, iu_r, iv_r, ok_r = self.outputs
        return (iu_l.value.to_signed(), iv_l.value.to_signed(), int(ok_l.value),
                iu_r.value.to_signed(), iv_r.value.to_signed(), int(ok_r.value))

    async def collect(self, count: int, ready: float, rng: random.Random, *, limit: int,
                      check_hold: bool = False) -> tuple[list[tuple], list[int]]:
        """``count`` words with out_ready 1 on a share ``ready`` of the clocks; their clock numbers.

        Sampled at each rising edge: a word moves when out_valid and out_ready are both 1
        there. ``check_hold``: a word offered and not taken must be offered again unchanged.
        """
        d = self.dut
        clk, out_valid, out_ready = d.clk, d.out_valid, d.out_ready
        words: list[tuple] = []
        when: list[int] = []
        held = None
        clocks = 0
        always = ready >= 1.0
        ready_now = 1 if always or rng.random() < ready else 0  # (a write is not read back until it applies)
        out_ready.value = ready_now
        edge = RisingEdge(clk)
        while len(words) < count:
            await edge
            clocks += 1
            if clocks > limit:
                raise AssertionError(f"only {len(words)} of {count} words after {limit} clocks")
            if int(out_valid.value):
                if ready_now or check_hold:
                    word = self.read_word()
                    if check_hold and held is not None and word != held:
                        raise AssertionError(f"word {len(words)} changed while stalled: {held} -> {word}")
                    if ready_now:
                        words.append(word)
                        when.append(clocks)
                        held = None
                    else:
                        held = word
            elif check_hold and held is not None:
                raise AssertionError(f"out_valid dropped while word {len(words)} was stalled")
            if not always:
                ready_now = 1 if rng.random() < ready else 0
                out_ready.value = ready_now
        return words, when

    async def expect_silence(self, clocks: int) -> None:
        self.dut.out_ready.value = 1
        for _ in range(clocks):
            await RisingEdge(self.dut.clk)
            if int(self.dut.out_valid.value):
                raise AssertionError(f"an unexpected word {self.read_word()} after the frame's last one")


def compare(name: str, got: list[tuple], exp: Expected, width: int) -> list[str]:
    """How many of the frame's words differ from the model's and the first few, each named by its pixel
    (the words are (iu_l, iv_l, ok_l, iu_r, iv_r, ok_r))."""
    want = [exp.word(k) for k in range(len(exp))]
    return [f"{name}: {m}" for m in mismatches(got, want, lambda k: f"pixel ({k % width}, {k // width})")]


@cocotb.test()
async def frames(dut: SimHandleBase) -> None:
    """Every case of RC_COORD_CASES, one frame each, random backpressure: 0 differing words."""
    tb = TB(dut)
    await tb.reset()
    problems: list[str] = []
    total_words = 0
    sim_seconds = 0.0
    for case in _settings()["cases"]:
        w, h = case["width"], case["height"]
        rng = random.Random(case.get("seed", 0))
        exp = Expected.frame(case["left"], case["right"], w, h)
        tb.program(case["left"], case["right"], w, h)
        t0 = time.perf_counter()
        await tb.pulse_start()
        limit = FIRST_WORD_LIMIT + 40 * w * h + 1000
        got, _ = await tb.collect(w * h, case.get("ready", 0.6), rng, limit=limit)
        sim_seconds += time.perf_counter() - t0
        total_words += len(got)
        await tb.expect_silence(8)
        found = compare(case["name"], got, exp, w)
        valid = int(exp.ok_l.sum() + exp.ok_r.sum())
        dut._log.info("%s: %dx%d, %d words, %d of %d positions valid, %s", case["name"], w, h, len(got),
                      valid, 2 * w * h, "OK" if not found else f"{len(found)} problem(s)")
        problems += found
    if sim_seconds > 0:
        _report("frames", {"words": total_words, "positions": 2 * total_words, "seconds": sim_seconds,
                           "positions_per_second": 2 * total_words / sim_seconds})
    assert not problems, "\n".join(problems)


@cocotb.test()
async def timing(dut: SimHandleBase) -> None:
    """out_ready always 1: first word within FIRST_WORD_LIMIT clocks of start, then one word per 2 clocks."""
    tb = TB(dut)
    await tb.reset()
    case = _settings()["cases"][0]
    w, h = 37, 5  # rows of odd length: the left camera must still enter on its phase every pixel
    exp = Expected.frame(case["left"], case["right"], w, h)
    results = {}
    for phase in (0, 1):  # start on either phase of the engine (its internal ph: left camera enters at 0)
        await ClockCycles(dut.clk, 3)
        if int(dut.ph.value) != phase:
            await RisingEdge(dut.clk)
        tb.program(case["left"], case["right"], w, h)
        dut.out_ready.value = 1
        await tb.pulse_start()
        got, when = await tb.collect(w * h, 1.0, random.Random(1), limit=FIRST_WORD_LIMIT + 2 * w * h + 10)
        first = when[0]  # clocks after the edge that took start
        gaps = {b - a for a, b in zip(when[:-1], when[1:], strict=True)}
        problems = compare(f"timing phase {phase}", got, exp, w)
        assert not problems, "\n".join(problems)
        assert first <= FIRST_WORD_LIMIT, f"first word {first} clocks after start"
        assert gaps == {2}, f"clocks between words: {sorted(gaps)} (expected always 2)"
        await tb.expect_silence(8)
        results[f"phase{phase}"] = first
    dut._log.info("first word %s clocks after the start edge; then one word per 2 clocks", results)
    _report("timing", {"first_word_clocks": results, "clocks_per_word": 2})


@cocotb.test()
async def stall(dut: SimHandleBase) -> None:
    """Long stalls fill the FIFO: nothing is lost or changes while held, and issue resumes."""
    tb = TB(dut)
    await tb.reset()
    case = _settings()["cases"][0]
    w, h = 23, 11
    exp = Expected.frame(case["left"], case["right"], w, h)
    tb.program(case["left"], case["right"], w, h)
    await tb.pulse_start()
    dut.out_ready.value = 0
    await ClockCycles(dut.clk, 300)  # far longer than the pipeline: the FIFO fills, issue stops
    # Bursts of ready and long stalls, checking that a stalled word holds still.
    rng = random.Random(7)
    got: list[tuple] = []
    while len(got) < w * h:
        n = min(w * h - len(got), rng.randint(1, 40))
        part, _ = await tb.collect(n, rng.choice([1.0, 0.9, 0.5, 0.1]), rng, limit=4000, check_hold=True)
        got += part
        dut.out_ready.value = 0
        await ClockCycles(dut.clk, rng.choice([0, 1, 5, 120]))
    problems = compare("stall", got, exp, w)
    assert not problems, "\n".join(problems)
    await tb.expect_silence(100)


@cocotb.test()
async def restart(dut: SimHandleBase) -> None:
    """Frame boundaries: back-to-back frames, start while busy, size 0, reset mid-frame, 1-pixel frames."""
    tb = TB(dut)
    await tb.reset()
    cases = _settings()["cases"]
    a, b = cases[0], cases[min(1, len(cases) - 1)]
    rng = random.Random(3)
    # 1. start again as soon as every pixel of a frame has entered, its words still in flight:
    #    at out_ready = 1 the 24 pixels of a 6x4 frame enter in 48 clocks, long before the first
    #    word is out. Same parameters (they must hold until a frame's last word), another size.
    wa, ha, wb, hb = 6, 4, 9, 3
    exp_a = Expected.frame(a["left"], a["right"], wa, ha)
    exp_a2 = Expected.frame(a["left"], a["right"], wb, hb)
    exp_b = Expected.frame(b["left"], b["right"], wb, hb)
    tb.program(a["left"], a["right"], wa, ha)
    dut.out_ready.value = 1
    await tb.pulse_start()
    await ClockCycles(dut.clk, 2 * wa * ha + 4)
    assert not int(dut.out_valid.value), "the first word came earlier than the test assumes"
    dut.width.value = wb
    dut.height.value = hb
    await tb.pulse_start()
    got_a, _ = await tb.collect(wa * ha, 1.0, rng, limit=200)
    got_a2, _ = await tb.collect(wb * hb, 0.5, rng, limit=400)
    await tb.expect_silence(80)
    problems = compare("back-to-back 1", got_a, exp_a, wa) + compare("back-to-back 2", got_a2, exp_a2, wb)
    tb.program(b["left"], b["right"], wb, hb)
    await tb.pulse_start()
    # 2. start pulses while busy are ignored (with another size on the inputs).
    await ClockCycles(dut.clk, 3)
    dut.width.value = 2
    dut.height.value = 2
    await tb.pulse_start()
    dut.width.value = wb
    dut.height.value = hb
    got_b, _ = await tb.collect(wb * hb, 0.5, rng, limit=2000)
    await tb.expect_silence(100)
    problems += compare("start while busy", got_b, exp_b, wb)
    # 3. width or height 0: no words.
    dut.width.value = 0
    await tb.pulse_start()
    await tb.expect_silence(100)
    dut.width.value = wb
    # 4. reset in the middle of a frame, then a new frame: only its words come out.
    tb.program(a["left"], a["right"], 40, 20)
    await tb.pulse_start()
    await ClockCycles(dut.clk, 200)
    await tb.reset()
    await tb.expect_silence(100)
    tb.program(b["left"], b["right"], wb, hb)
    await tb.pulse_start()
    got_c, _ = await tb.collect(wb * hb, 0.7, rng, limit=2000)
    await tb.expect_silence(100)
    problems += compare("after reset", got_c, exp_b, wb)
    # 5. a frame of one pixel, one column, one row.
    for w, h in ((1, 1), (1, 7), (7, 1)):
        tb.program(a["left"], a["right"], w, h)
        await tb.pulse_start()
        got, _ = await tb.collect(w * h, 0.5, rng, limit=500)
        await tb.expect_silence(80)
        problems += compare(f"{w}x{h}", got, Expected.frame(a["left"], a["right"], w, h), w)
    assert not problems, "\n".join(problems)



# --------------------------------------------------------------------------- the parts on their own
# Run with rc_div, rc_coord_mul or rc_fifo as the toplevel; RC_COORD_UNIT holds its parameters.
# Inputs change right after a rising edge; a value read just after an edge is the one the
# edge sampled, so a register stage n clocks after an input shows it n + 1 edges later.


def _unit() -> dict:
    return json.loads(os.environ.get("RC_COORD_UNIT", "{}"))


def _wrap(value: int, bits: int) -> int:
    """``value`` as a ``bits``-bit two's complement number."""
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


async def _stream(dut: SimHandleBase, vectors: list[dict], read, latency: int) -> list:
    """Apply one input vector per clock; return what ``read()`` gives ``latency`` clocks after each."""
    out = []
    edge = RisingEdge(dut.clk)
    await ClockCycles(dut.clk, 2)  # the clock is running: a write after an edge is in place by the next
    for k in range(len(vectors) + latency):
        if k < len(vectors):
            drive(dut, **vectors[k])
        await edge  # edge k samples vector k
        if k >= latency:
            out.append(read())
    return out


@cocotb.test()
async def div_exact(dut: SimHandleBase) -> None:
    """rc_div: floor(num * 2**SH / den) for extreme and random operands, latency QB."""
    p = _unit()
    lanes, nw, dw, qb, sh = p["LANES"], p["NW"], p["DW"], p["QB"], p["SH"]
    start_clock(dut.clk)
    rng = random.Random(p.get("seed", 5))
    dens = sorted({d for d in (1, 2, 3, 5, (1 << dw) - 1, 1 << (dw - 1), (1 << (dw - 1)) + 1, (1 << 30) + 7)
                   if d < 1 << dw})
    dens += [rng.randrange(1, 1 << rng.randint(1, dw)) for _ in range(120)]
    cases = []
    for den in dens:
        top = min(den << (qb - sh), 1 << nw) - 1  # largest numerator with quo < 2**QB
        nums = [0, 1, top, max(0, top - 1), min(top, den), min(top, den - 1), min(top, 3 * den)]
        nums += [rng.randint(0, top) for _ in range(6)]
        for i in range(0, len(nums), lanes):
            chunk = (nums[i:i + lanes] + [0] * lanes)[:lanes]
            cases.append((chunk, den))
    vectors = [{"num": sum(n << (nw * i) for i, n in enumerate(nums)), "den": den} for nums, den in cases]
    got = await _stream(dut, vectors, lambda: dut.quo.value.to_unsigned(), qb)
    mask = (1 << qb) - 1
    bad = []
    for (nums, den), q in zip(cases, got, strict=True):
        want = [(n << sh) // den for n in nums]
        have = [(q >> (qb * i)) & mask for i in range(lanes)]
        if have != want:
            bad.append(f"num {nums} den {den}: rtl {have}, expected {want}")
    assert not bad, f"{len(bad)} of {len(cases)} wrong, e.g. " + "; ".join(bad[:4])
    dut._log.info("%d divisions of %d lanes exact", len(cases), lanes)


@cocotb.test()
async def mul_exact(dut: SimHandleBase) -> None:
    """rc_coord_mul: ((a*b >>> LO) + c) >>> SH in OW bits for extreme and random operands, latency 5."""
    p = _unit()
    aw, bw, lo, cw, sh, ow = p["AW"], p["BW"], p["LO"], p["CW"], p["SH"], p["OW"]
    start_clock(dut.clk)
    rng = random.Random(p.get("seed", 6))

    def specials(bits: int) -> list[int]:
        lo_, hi_ = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        out = [lo_, lo_ + 1, hi_, hi_ - 1, 0, 1, -1, (1 << 17) - 1, 1 << 17, -(1 << 17), (1 << 16)]
        return [v for v in out if lo_ <= v <= hi_]

    pairs = [(a, b) for a in specials(aw) for b in specials(bw)]
    pairs += [(rng.randint(-(1 << (aw - 1)), (1 << (aw - 1)) - 1),
               rng.randint(-(1 << (bw - 1)), (1 << (bw - 1)) - 1)) for _ in range(1500)]
    cs = [rng.randint(-(1 << (cw - 1)), (1 << (cw - 1)) - 1) for _ in pairs]
    cs[:4] = [-(1 << (cw - 1)), (1 << (cw - 1)) - 1, 0, -1][:len(cs[:4])]
    # c goes in 4 clocks after its a, b.
    vectors = []
    for k in range(len(pairs) + 4):
        v = {}
        if k < len(pairs):
            v["a"] = pairs[k][0] & ((1 << aw) - 1)
            v["b"] = pairs[k][1] & ((1 << bw) - 1)
        if k >= 4:
            v["c"] = cs[k - 4] & ((1 << cw) - 1)
        vectors.append(v)
    got = await _stream(dut, vectors, lambda: dut.p.value.to_signed(), 5)
    bad = []
    for (a, b), c, have in zip(pairs, cs, got[:len(pairs)], strict=True):
        want = _wrap((((a * b) >> lo) + c) >> sh, ow)
        if have != want:
            bad.append(f"a {a} b {b} c {c}: rtl {have}, expected {want}")
    assert not bad, f"{len(bad)} of {len(pairs)} wrong, e.g. " + "; ".join(bad[:4])
    dut._log.info("%d products exact", len(pairs))


@cocotb.test()
async def fifo_order(dut: SimHandleBase) -> None:
    """rc_fifo: random pushes and pops, words in order, count, s_ready, m_valid, reset empties it."""
    p = _unit()
    depth, show_ahead, width = p["DEPTH"], p["SHOW_AHEAD"], p["WIDTH"]
    start_clock(dut.clk)
    rng = random.Random(p.get("seed", 7))
    dut.s_valid.value = 0
    dut.m_ready.value = 0
    dut.rst.value = 1
    edge = RisingEdge(dut.clk)
    for _ in range(3):
        await edge
    dut.rst.value = 0
    queue: list[int] = []
    pending = None  # SHOW_AHEAD = 0: the word a granted request puts on m_data next clock
    s_valid = m_ready = 0
    data = 0
    moved_in = moved_out = 0
    for cycle in range(4000):
        phase = (cycle // 500) % 4  # fill, drain, both busy, both sparse
        p_in, p_out = ((0.9, 0.2), (0.2, 0.9), (0.9, 0.9), (0.3, 0.3))[phase]
        s_valid = int(rng.random() < p_in)
        m_ready = int(rng.random() < p_out)
        data = rng.getrandbits(width)
        dut.s_valid.value = s_valid
        dut.s_data.value = data
        dut.m_ready.value = m_ready
        await edge
        count = dut.count.value.to_unsigned()
        assert count == len(queue), f"cycle {cycle}: count {count}, holds {len(queue)}"
        s_ready = int(dut.s_ready.value)
        assert s_ready == (len(queue) < depth), f"cycle {cycle}: s_ready {s_ready} with {len(queue)} held"
        m_valid = int(dut.m_valid.value)
        if show_ahead:
            assert m_valid == (len(queue) > 0), f"cycle {cycle}: m_valid {m_valid} with {len(queue)} held"
            if m_valid and m_ready:
                assert dut.m_data.value.to_unsigned() == queue[0], f"cycle {cycle}: wrong word"
                queue.pop(0)
                moved_out += 1
        else:
            assert m_valid == (pending is not None), f"cycle {cycle}: m_valid {m_valid}"
            if pending is not None:
                assert dut.m_data.value.to_unsigned() == pending, f"cycle {cycle}: wrong word"
            pending = None
            if m_ready and queue:
                pending = queue.pop(0)
                moved_out += 1
        if s_valid and count < depth:
            queue.append(data)
            moved_in += 1
    dut.s_valid.value = 0
    dut.rst.value = 1
    await edge
    dut.rst.value = 0
    await edge
    await edge
    assert dut.count.value.to_unsigned() == 0 and not int(dut.m_valid.value), "reset does not empty it"
    dut._log.info("%d words in, %d out", moved_in, moved_out)
