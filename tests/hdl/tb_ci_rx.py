"""cocotb testbench for stereocam/overlays/rtl/camera/ci_rx.v, one camera's parallel receiver.

Run by ``tests/hdl/test_rtl_units.py``. The bench drives the MT9V034's DOUT, LINE_VALID and
FRAME_VALID on pclk, plays the line FIFO (a Python memory written through w_en / w_addr / w_data)
and its reader (which takes committed words at random and returns them through w_rptr, so the FIFO
also fills), and parses the records the reader takes (spec/camera_in.py, "Words of the line
FIFOs"): LINE {first, tag, len} and len PIXEL words per line, EOF {err, tag} per frame.

Checked against what the header of ci_rx.v states: a frame without loss gives exactly its lines
(first set on the first one), each pixel's 10 bits, the tag of the frame tag at its start, and an
EOF without err; a line longer than MAX_WIDTH, or one the FIFO has no room for, loses the rest of
its frame, whose records are then its first whole lines and an EOF with err; no word is written
into room the reader has not given back.
"""
from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

import cocotb
from cocotb.triggers import FallingEdge

from stereocam.overlays.spec import camera_in as spec

from .unit_bench import params, start_clock

LEN_BITS = spec.LEN_BITS
TAG_BITS = spec.TAG_BITS
RAW_BITS = spec.RAW_BITS


@dataclass
class Record:
    kind: int
    first: int = 0
    tag: int = 0
    length: int = 0  # LINE
    err: int = 0  # EOF
    pixel: int = 0  # PIXEL


def decode(word: int) -> Record:
    kind = word >> (spec.REC_BITS - spec.REC_KIND_BITS)
    if kind == spec.REC_PIXEL:
        return Record(kind, pixel=word & ((1 << RAW_BITS) - 1))
    flag = (word >> (LEN_BITS + TAG_BITS)) & 1
    tag = (word >> LEN_BITS) & ((1 << TAG_BITS) - 1)
    if kind == spec.REC_LINE:
        return Record(kind, first=flag, tag=tag, length=word & ((1 << LEN_BITS) - 1))
    return Record(kind, err=flag, tag=tag)


Frame = list[list[int]]


class Bench:
    def __init__(self, dut: Any, seed: int) -> None:
        p = params()
        self.dut = dut
        self.max_width, self.aw = p["MAX_WIDTH"], p["AW"]
        self.depth = 1 << self.aw
        self.mod = 2 * self.depth
        self.rng = random.Random(seed)
        self.mem: dict[int, int] = {}
        # the FIFO pointers are never cleared: take over where an earlier test left them (empty)
        self.commit = int(dut.w_commit.value) if dut.w_commit.value.is_resolvable else 0
        self.rptr = self.commit
        self.read_p = 0.5
        self.words: list[int] = []  # committed words the reader took, in order
        self.problems: list[str] = []
        dut.rst.value = 0
        dut.data.value = 0
        dut.line_valid.value = 0
        dut.frame_valid.value = 0
        dut.tag_gray.value = 0
        dut.w_rptr.value = self.rptr
        start_clock(dut.pclk, 37.6)

    async def clock(self, data: int, lv: int, fv: int) -> None:
        """One pclk: drive the camera's pins, then play the FIFO and its reader for the clock."""
        dut = self.dut
        dut.data.value, dut.line_valid.value, dut.frame_valid.value = data, lv, fv
        await FallingEdge(dut.pclk)
        if dut.w_en.value:
            addr = int(dut.w_addr.value)
            used = (self.commit - self.rptr) % self.mod
            # the word is in the reserved room beyond the commit, inside what the reader gave back
            if (addr - self.commit) % self.depth >= self.depth - used:
                self.problems.append(f"write at {addr} over a committed, unread word")
            self.mem[addr] = int(dut.w_data.value)
        self.commit = int(dut.w_commit.value)
        if self.rptr != self.commit and self.rng.random() < self.read_p:
            self.words.append(self.mem[self.rptr % self.depth])
            self.rptr = (self.rptr + 1) % self.mod
            dut.w_rptr.value = self.rptr

    async def frame(self, lines: Frame, tag: int, hblank: tuple[int, int] = (1, 6), vblank: int = 20,
                    cut: bool = False) -> None:
        """One frame: FRAME_VALID up two clocks before the first line, lines of pixels with LINE_VALID
        low between them, FRAME_VALID down two clocks after the last; the tag (gray) set in the blanking.
        ``cut``: FRAME_VALID falls in the last line instead, LINE_VALID one clock later."""
        self.dut.tag_gray.value = tag ^ (tag >> 1)
        for _ in range(vblank):
            await self.clock(0, 0, 0)
        for _ in range(2):
            await self.clock(0, 0, 1)
        for k, line in enumerate(lines):
            for pixel in line:
                await self.clock(pixel, 1, 1)
            if cut and k == len(lines) - 1:
                await self.clock(0, 1, 0)
                await self.clock(0, 0, 0)
                return
            for _ in range(self.rng.randint(*hblank)):
                await self.clock(self.rng.getrandbits(RAW_BITS), 0, 1)
        for _ in range(2):
            await self.clock(0, 0, 1)

    async def idle(self, clocks: int) -> None:
        for _ in range(clocks):
            await self.clock(0, 0, 0)

    def random_frame(self, widths: tuple[int, int], heights: tuple[int, int]) -> Frame:
        width, height = self.rng.randint(*widths), self.rng.randint(*heights)
        return [[self.rng.getrandbits(RAW_BITS) for _ in range(width)] for _ in range(height)]

    def frames_out(self) -> list[tuple[int, int, Frame]]:
        """(tag, err, lines) of each frame in the records taken, checking their framing."""
        out: list[tuple[int, int, Frame]] = []
        lines: Frame = []
        tag = None
        i = 0
        records = [decode(w) for w in self.words]
        while i < len(records):
            r = records[i]
            if r.kind == spec.REC_LINE:
                if r.first != (not lines):
                    self.problems.append(f"record {i}: LINE first={r.first} after {len(lines)} lines")
                if tag is not None and r.tag != tag:
                    self.problems.append(f"record {i}: LINE tag {r.tag} in a frame of tag {tag}")
                tag = r.tag
                pixels = records[i + 1:i + 1 + r.length]
                if len(pixels) < r.length or any(p.kind != spec.REC_PIXEL for p in pixels):
                    self.problems.append(f"record {i}: LINE of {r.length} not followed by as many PIXELs")
                lines.append([p.pixel for p in pixels])
                i += 1 + r.length
            elif r.kind == spec.REC_EOF:
                if tag is not None and r.tag != tag:
                    self.problems.append(f"record {i}: EOF tag {r.tag} in a frame of tag {tag}")
                out.append((r.tag, r.err, lines))
                lines, tag = [], None
                i += 1
            else:
                self.problems.append(f"record {i}: a PIXEL outside a line")
                i += 1
        if lines:
            self.problems.append(f"{len(lines)} lines after the last EOF")
        return out


async def reset(tb: Bench) -> None:
    tb.dut.rst.value = 1
    await tb.idle(3)
    tb.dut.rst.value = 0
    await tb.idle(3)


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def whole_frames(dut: Any) -> None:
    """Random frames (lines of 1 to MAX_WIDTH pixels, random blanking) with a reader that takes words
    at random: every frame arrives whole, in order, with its tag, first flags and an EOF without err."""
    tb = Bench(dut, 1)
    await reset(tb)
    sent = []
    for k in range(24):
        tb.read_p = (1.0, 0.8, 0.6)[k % 3]
        f = tb.random_frame((1, tb.max_width), (1, 5))
        tag = k % (1 << TAG_BITS)
        await tb.frame(f, tag)
        sent.append((tag, 0, f))
    tb.read_p = 1.0
    await tb.idle(4 * tb.depth)
    got = tb.frames_out()
    assert not tb.problems, "\n".join(tb.problems[:10])
    for k, (g, s) in enumerate(zip(got, sent, strict=False)):
        assert g == s, f"frame {k}: (tag, err, line lengths) {g[0], g[1], [len(x) for x in g[2]]}, sent " \
            f"{s[0], s[1], [len(x) for x in s[2]]}{' (pixels differ)' if g[:2] == s[:2] else ''}"
    assert len(got) == len(sent), f"{len(got)} frames out of {len(sent)}"


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def losses_cut_frames_at_a_whole_line(dut: Any) -> None:
    """Lines longer than MAX_WIDTH, FRAME_VALID falling inside a line, and a reader that stalls until
    the FIFO is full: a frame that lost something ends after its first whole lines with an EOF with
    err; the frames after it are whole."""
    tb = Bench(dut, 2)
    await reset(tb)
    sent = []
    for k in range(16):
        tag = k % (1 << TAG_BITS)
        f = tb.random_frame((1, tb.max_width), (2, 5))
        case = k % 4
        if case == 1:  # one line too long
            f[tb.rng.randrange(len(f))] = [tb.rng.getrandbits(RAW_BITS) for _ in range(tb.max_width + 1)]
        tb.read_p = 0.0 if case == 3 else 0.7  # case 3: the reader stalls through the frame
        if case == 3:
            f = [[tb.rng.getrandbits(RAW_BITS) for _ in range(tb.max_width)] for _ in range(4)]
        await tb.frame(f, tag, cut=case == 2)  # case 2: the last line cut
        tb.read_p = 1.0
        await tb.idle(2 * tb.depth)
        sent.append((tag, f, case))
    got = tb.frames_out()
    assert not tb.problems, "\n".join(tb.problems[:10])
    assert len(got) == len(sent), f"{len(got)} frames out of {len(sent)}"
    cut = 0
    for k, ((tag, err, lines), (stag, f, case)) in enumerate(zip(got, sent, strict=True)):
        assert tag == stag, f"frame {k}: tag {tag}, sent {stag}"
        lossy = case in (1, 2) or (case == 3 and 4 * (tb.max_width + 1) + 1 > tb.depth)
        if not lossy:
            assert (err, lines) == (0, f), f"frame {k} (case {case}) not whole: err {err}, {len(lines)} lines"
        else:
            assert err == 1 and lines == f[:len(lines)] and len(lines) < len(f), \
                f"frame {k} (case {case}): err {err}, {len(lines)} of {len(f)} lines, or not its first lines"
            cut += 1
    assert cut == 12, cut
