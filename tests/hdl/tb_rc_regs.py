"""cocotb testbench for stereocam/overlays/rtl/rc_regs.v, the rectify core's AXI4-Lite register block.

Run by ``tests/hdl/test_rc_regs.py`` through ``run_cocotb`` under Verilator and Icarus; it
is not a pytest module (cocotb imports it inside the simulator). The build parameters
come in ``RC_REGS_BUILD`` (JSON: MAX_WIDTH, MAX_HEIGHT, LB_ROWS, COLOUR).

Every expectation is derived from the spec (``RECTIFY_MAP``, ``PARAM_RANGE``,
``param_offset``) and the build parameters through :class:`Model`, which knows each
register's access kind, reset value and fields, the shadow and active parameter sets
and the validation rules of RECTIFY_CORE.md ("Behaviour"); no offset or value is
typed here. The bus is driven by ``cocotbext.axi.AxiLiteMaster``; a monitor counts
clock edges, checks the AXI4-Lite handshake rules and records the edge of every write
(the edge on which BVALID rises), so that tests can place input pulses and ``idle``
exactly relative to a write.
"""
from __future__ import annotations

import itertools
import json
import logging
import os
import random
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import cocotb
from cocotb.clock import Clock
from cocotb.handle import SimHandleBase
from cocotb.simtime import get_sim_time
from cocotb.triggers import ClockCycles, Event, FallingEdge, ReadOnly, RisingEdge, with_timeout
from cocotbext.axi import AxiLiteBus, AxiLiteMaster, AxiProt, AxiResp
from cocotbext.axi.axil_master import AxiLiteWriteRespCmd

from stereocam.overlays.spec.rectify import (
    CAMERAS,
    DEFAULT_BUILD,
    PARAM_NAMES,
    PARAM_RANGE,
    RECTIFY_MAP,
    i64_to_words,
    param_offset,
)
from stereocam.overlays.spec.regs import Access

CLOCK_NS = 10
TIMEOUT_US = 500  # bound on any wait: a design that stops answering fails instead of hanging
MASK32 = 0xFFFFFFFF
MASK64 = (1 << 64) - 1

REG = {reg.name: reg for reg in RECTIFY_MAP}
CONTROL = REG["CONTROL"]
STATUS = REG["STATUS"]
FLAGS = REG["FLAGS"]
# Registers whose value is the build's (RECTIFY_MAP's reset value is the default build's).
BUILD_REGISTERS = ("MAX_WIDTH", "MAX_HEIGHT", "LB_ROWS", "CAPS")
# Registers whose value the block computes (not what software wrote).
LIVE_REGISTERS = ("STATUS", "FLAGS", "FRAME_COUNT")
SHADOW_SIZES = ("WIDTH", "HEIGHT", "LB_DELAY")
# Input pulse that raises each FLAGS field (CONFIG_ERROR is raised by a refused APPLY).
FLAG_INPUTS = {"LB_OVERFLOW": "set_lb_overflow", "SIZE_ERROR": "set_size_error"}


@dataclass(frozen=True)
class BuildParams:
    max_width: int
    max_height: int
    lb_rows: int
    colour: int

    @classmethod
    def from_env(cls) -> "BuildParams":
        default = {
            "MAX_WIDTH": DEFAULT_BUILD.max_width,
            "MAX_HEIGHT": DEFAULT_BUILD.max_height,
            "LB_ROWS": DEFAULT_BUILD.lb_rows,
            "COLOUR": int(DEFAULT_BUILD.colour),
        }
        params = {**default, **json.loads(os.environ.get("RC_REGS_BUILD", "{}"))}
        return cls(int(params["MAX_WIDTH"]), int(params["MAX_HEIGHT"]), int(params["LB_ROWS"]),
                   int(params["COLOUR"]))


def byte_mask(strb: int) -> int:
    return sum(0xFF << (8 * b) for b in range(4) if strb >> b & 1)


def value_field(name: str) -> tuple[int, int]:
    """(lsb, width) of the VALUE field of WIDTH, HEIGHT, LB_DELAY, DEBUG_ROW."""
    f = REG[name].field("VALUE")
    return f.lsb, f.width


def param_names() -> Iterator[tuple[str, str]]:
    for cam in CAMERAS:
        for name in PARAM_NAMES:
            yield cam, name


@dataclass
class ActiveSet:
    params: dict[tuple[str, str], int]
    width: int
    height: int
    lb_delay: int


@dataclass
class Model:
    """What the block should hold: every register's value by RECTIFY_MAP's rules, and the active set."""

    build: BuildParams
    values: dict[int, int] = field(default_factory=dict)
    pending: bool = False
    busy: int = 0
    applied: bool = False
    active: ActiveSet | None = None

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.values = {reg.offset: reg.reset for reg in RECTIFY_MAP}
        build = {"MAX_WIDTH": self.build.max_width, "MAX_HEIGHT": self.build.max_height,
                 "LB_ROWS": self.build.lb_rows, "CAPS": REG["CAPS"].encode(COLOUR=self.build.colour)}
        for name in BUILD_REGISTERS:
            self.values[REG[name].offset] = build[name]
        self.pending = False
        self.applied = False
        # Before the first APPLY: zero parameters, the reset WIDTH/HEIGHT/LB_DELAY.
        self.active = ActiveSet({key: 0 for key in param_names()}, *self.sizes())

    # -- the bus -------------------------------------------------------------------------
    def read(self, offset: int) -> int:
        reg = RECTIFY_MAP.at(offset)
        if reg is None:
            return 0
        value = self.values[offset]
        if reg is CONTROL:
            value = CONTROL.encode(value, APPLY=int(self.pending))
        elif reg is STATUS:
            value = STATUS.encode(BUSY=self.busy, APPLY_PENDING=int(self.pending))
        return value & ~reg.unassigned_mask & MASK32

    def write(self, offset: int, data: int, strb: int = 0xF) -> None:
        reg = RECTIFY_MAP.at(offset)
        if reg is None:
            return
        mask = byte_mask(strb)
        old = self.values[offset]
        rw = reg.mask_of(Access.RW) & mask
        new = (old & ~rw) | (data & rw)
        new &= ~(data & mask & reg.mask_of(Access.W1C))
        self.values[offset] = new & MASK32
        if data & mask & reg.mask_of(Access.SC):
            self.pending = True  # CONTROL.APPLY; writing 0 does not cancel

    def get(self, name: str) -> int:
        return self.values[REG[name].offset]

    def raise_flag(self, name: str) -> None:
        self.values[FLAGS.offset] |= FLAGS.bit(name)

    # -- shadow and active sets ------------------------------------------------------------
    def param(self, cam: str, name: str) -> int:
        off = param_offset(cam, name)
        bits = self.values[off + 4] << 32 | self.values[off]
        return bits - (1 << 64) if bits >> 63 else bits

    def sizes(self) -> tuple[int, int, int]:
        return tuple(REG[n].get(self.get(n), "VALUE") for n in SHADOW_SIZES)  # type: ignore[return-value]

    def shadow(self) -> ActiveSet:
        return ActiveSet({key: self.param(*key) for key in param_names()}, *self.sizes())

    def problems(self, s: ActiveSet | None = None) -> list[str]:
        """Why APPLY would refuse the shadow set (RECTIFY_CORE.md, "Validation on APPLY")."""
        s = s or self.shadow()
        out = []
        for (cam, name), value in s.params.items():
            lo, hi = PARAM_RANGE[name]
            if not lo <= value <= hi:
                out.append(f"{cam}_{name} = {value}")
        if not 1 <= s.width <= self.build.max_width:
            out.append(f"WIDTH = {s.width}")
        if not 1 <= s.height <= self.build.max_height:
            out.append(f"HEIGHT = {s.height}")
        if not s.lb_delay < self.build.max_height:
            out.append(f"LB_DELAY = {s.lb_delay}")
        return out

    def latch(self, s: ActiveSet | None = None) -> bool:
        """The APPLY latch on the set ``s`` (default: the shadow now); True when accepted."""
        s = s or self.shadow()
        self.pending = False
        if self.problems(s):
            self.raise_flag("CONFIG_ERROR")
            return False
        self.active = s
        self.applied = True
        return True

    def act_vector(self, cam: str) -> int:
        """``act_l``/``act_r``: parameter i (PARAM_NAMES order) at bits [64*i +: 64], two's complement."""
        assert self.active is not None
        return sum((self.active.params[cam, name] & MASK64) << (64 * i) for i, name in enumerate(PARAM_NAMES))


def random_valid(name: str) -> int:
    lo, hi = PARAM_RANGE[name]
    return random.choice([lo, hi, 0 if lo <= 0 <= hi else lo, random.randint(lo, hi), random.randint(lo, hi)])


@dataclass
class Sample:
    """The bus and block outputs just after one clock edge (what the next edge samples)."""

    rst: int
    awvalid: int
    awready: int
    wvalid: int
    wready: int
    bvalid: int
    bready: int
    arvalid: int
    arready: int
    rvalid: int
    rready: int
    rdata: int
    apply_pending: int


class TB:
    """Clock, bus model, spec model and an edge-counting protocol monitor."""

    def __init__(self, dut: SimHandleBase) -> None:
        self.dut = dut
        self.build = BuildParams.from_env()
        self.model = Model(self.build)
        Clock(dut.clk, CLOCK_NS, unit="ns").start()  # high first: falling edges half a period later
        self.t0 = get_sim_time("ps")
        self.axil = AxiLiteMaster(AxiLiteBus.from_prefix(dut, "s_axil"), dut.clk, dut.rst)
        for interface in (self.axil.write_if, self.axil.read_if):
            interface.log.setLevel(logging.WARNING)  # not a line per access
        for name in ("idle", "busy"):
            getattr(dut, name).value = 1 if name == "idle" else 0
        for name in ("frame_done", *FLAG_INPUTS.values()):
            getattr(dut, name).value = 0
        dut.rst.value = 0
        self.edge = 0  # rising edges so far
        self.write_edges: list[int] = []  # edge of every write (BVALID rises or stays for a new one)
        self.apply_falls: list[int] = []  # edges on which apply_pending fell
        self.violations: list[str] = []
        self.counts = {"aw": 0, "w": 0, "b": 0, "ar": 0, "r": 0}
        cocotb.start_soon(self._monitor())

    # -- clocking and reset ----------------------------------------------------------------
    async def reset(self) -> None:
        await FallingEdge(self.dut.clk)
        self.dut.rst.value = 1
        await ClockCycles(self.dut.clk, 3)
        await FallingEdge(self.dut.clk)
        self.dut.rst.value = 0
        self.model.reset()
        self.model.busy = int(self.dut.busy.value)
        await self.wait_for(lambda: int(self.dut.s_axil_arready.value) == 1, "ARREADY after reset")

    async def wait_for(self, condition, what: str, limit: int = 10_000) -> None:
        """Falling edges until ``condition()`` holds (checked at each falling edge)."""
        for _ in range(limit):
            await FallingEdge(self.dut.clk)
            if condition():
                return
        raise AssertionError(f"timed out waiting for {what}")

    def _at_falling_after(self, edge: int) -> bool:
        period = CLOCK_NS * 1000
        return self.edge == edge and (get_sim_time("ps") - self.t0) % period == period // 2

    async def falling_after(self, edge: int) -> None:
        """Be at the falling edge right after rising edge number ``edge`` (now, or wait for it)."""
        if self._at_falling_after(edge):
            return
        while True:
            await FallingEdge(self.dut.clk)
            if self.edge >= edge:
                assert self.edge == edge, f"wanted to act after edge {edge}, already at {self.edge}"
                return

    async def pulse(self, signal: SimHandleBase, edge: int) -> None:
        """Drive ``signal`` 1 for the one clock edge number ``edge`` samples.

        From an unknown clock phase, ``edge`` must be at least ``self.edge + 2``.
        """
        await self.falling_after(edge - 1)
        signal.value = 1
        await self.falling_after(edge)
        signal.value = 0

    async def set_at(self, signal: SimHandleBase, value: int, edge: int) -> None:
        """Drive ``signal`` to ``value`` from the clock edge number ``edge`` samples on."""
        await self.falling_after(edge - 1)
        signal.value = value

    def sample(self) -> Sample | None:
        """The signals now, or None while any is X or Z (before the first clock)."""
        d = self.dut
        values = [v.value for v in (
            d.rst, d.s_axil_awvalid, d.s_axil_awready, d.s_axil_wvalid, d.s_axil_wready, d.s_axil_bvalid,
            d.s_axil_bready, d.s_axil_arvalid, d.s_axil_arready, d.s_axil_rvalid, d.s_axil_rready,
            d.s_axil_rdata, d.apply_pending,
        )]
        if not all(v.is_resolvable for v in values):
            return None
        return Sample(*(int(v) for v in values))

    async def _monitor(self) -> None:
        """Count edges; check the AXI4-Lite rules; record the edges of writes and of APPLY latches."""
        prev: Sample | None = None
        while True:
            await RisingEdge(self.dut.clk)
            await ReadOnly()
            self.edge += 1
            now = self.sample()
            if prev is not None and now is not None and not prev.rst and not now.rst:
                self._check(prev, now)
            prev = now

    def _check(self, prev: Sample, now: Sample) -> None:
        at = f"edge {self.edge}"
        c = self.counts
        c["aw"] += prev.awvalid and prev.awready
        c["w"] += prev.wvalid and prev.wready
        c["ar"] += prev.arvalid and prev.arready
        b_done = prev.bvalid and prev.bready
        c["b"] += b_done
        c["r"] += prev.rvalid and prev.rready
        if now.bvalid and (not prev.bvalid or b_done):
            self.write_edges.append(self.edge)
            if c["b"] + 1 > min(c["aw"], c["w"]):
                self.violations.append(f"{at}: a write response before its AW and W")
        if now.rvalid and (not prev.rvalid or prev.rready) and c["r"] + 1 > c["ar"]:
            self.violations.append(f"{at}: read data before its AR")
        if prev.bvalid and not prev.bready and not now.bvalid:
            self.violations.append(f"{at}: BVALID dropped before BREADY")
        if prev.rvalid and not prev.rready and (not now.rvalid or now.rdata != prev.rdata):
            self.violations.append(f"{at}: RVALID/RDATA changed while stalled")
        if prev.apply_pending and not now.apply_pending:
            self.apply_falls.append(self.edge)

    def assert_protocol(self) -> None:
        assert not self.violations, f"AXI4-Lite protocol: {self.violations[:5]}"

    # -- bus access ------------------------------------------------------------------------
    async def read(self, offset: int) -> int:
        resp = await with_timeout(self.axil.read(offset, 4), TIMEOUT_US, "us")
        assert resp.resp == AxiResp.OKAY, f"read {offset:#x}: {resp.resp}"
        return int.from_bytes(resp.data, "little")

    async def write(self, offset: int, value: int, strb: int = 0xF, model: bool = True) -> None:
        """Write ``value`` with byte strobes ``strb`` (any pattern) and wait for OKAY; update the model."""
        value &= MASK32
        bytes_on = [b for b in range(4) if strb >> b & 1]
        contiguous = bytes_on == list(range(bytes_on[0], bytes_on[-1] + 1)) if bytes_on else False
        if contiguous:
            data = value.to_bytes(4, "little")[bytes_on[0]:bytes_on[-1] + 1]
            resp = await with_timeout(self.axil.write(offset + bytes_on[0], data), TIMEOUT_US, "us")
            assert resp.resp == AxiResp.OKAY, f"write {offset:#x}: {resp.resp}"
        else:
            await with_timeout(self._write_any_strobe(offset, value, strb), TIMEOUT_US, "us")
        if model:
            self.model.write(offset, value, strb)

    async def _write_any_strobe(self, offset: int, value: int, strb: int) -> None:
        """One write with a strobe AxiLiteMaster.write cannot express (gaps, or none at all).

        Goes through the master's own channels and response queue, as its ``write`` does
        (cocotbext-axi 0.1.28's internals), so it must not overlap other writes.
        """
        wif = self.axil.write_if
        assert wif.in_flight_operations == 0, "a raw-strobe write must not overlap other writes"
        done = Event()
        wif.in_flight_operations += 1
        wif._idle.clear()
        await wif.int_write_resp_command_queue.put(AxiLiteWriteRespCmd(offset, 4, 1, AxiProt.NONSECURE, done))
        aw = wif.aw_channel._transaction_obj()
        aw.awaddr = offset
        aw.awprot = AxiProt.NONSECURE
        w = wif.w_channel._transaction_obj()
        w.wdata = value
        w.wstrb = strb
        await wif.aw_channel.send(aw)
        await wif.w_channel.send(w)
        await done.wait()
        assert done.data.resp == AxiResp.OKAY

    async def write_param(self, cam: str, name: str, value: int) -> None:
        lo, hi = i64_to_words(value)
        off = param_offset(cam, name)
        await self.write(off, lo)
        await self.write(off + 4, hi)

    async def write_set(self, s: ActiveSet) -> None:
        for (cam, name), value in s.params.items():
            await self.write_param(cam, name, value)
        for reg_name, value in zip(SHADOW_SIZES, (s.width, s.height, s.lb_delay), strict=True):
            await self.write(REG[reg_name].offset, REG[reg_name].encode(VALUE=value))

    def random_set(self) -> ActiveSet:
        b = self.build
        return ActiveSet(
            {(cam, name): random_valid(name) for cam, name in param_names()},
            random.choice([1, b.max_width, random.randint(1, b.max_width)]),
            random.choice([1, b.max_height, random.randint(1, b.max_height)]),
            random.choice([0, b.max_height - 1, random.randint(0, b.max_height - 1)]),
        )

    async def apply(self) -> bool:
        """CONTROL.APPLY (other CONTROL bits kept), with ``idle`` as it is; wait for the latch.

        Checks that the latch came on the edge after the write when ``idle`` was 1, and
        updates the model; returns whether the set was accepted.
        """
        falls = len(self.apply_falls)
        await self.write(CONTROL.offset, CONTROL.encode(self.model.get("CONTROL"), APPLY=1))
        written = self.write_edges[-1]
        await self.wait_for(lambda: len(self.apply_falls) > falls, "the APPLY latch")
        assert self.apply_falls[falls] == written + 1, (
            f"APPLY written on edge {written} latched on edge {self.apply_falls[falls]}, want {written + 1}"
        )
        return self.model.latch()

    async def clear_flags(self) -> None:
        await self.write(FLAGS.offset, FLAGS.mask_of(Access.W1C))

    # -- checks ----------------------------------------------------------------------------
    async def check_register(self, offset: int, what: str = "") -> None:
        got = await self.read(offset)
        reg = RECTIFY_MAP.at(offset)
        want = self.model.read(offset)
        name = reg.name if reg else "unmapped"
        assert got == want, f"{what}{name} ({offset:#05x}) reads {got:#010x}, want {want:#010x}"

    async def check_all_registers(self, what: str = "") -> None:
        for reg in RECTIFY_MAP:
            await self.check_register(reg.offset, what)

    async def check_outputs(self, what: str = "") -> None:
        """The active set, ``applied`` and the control outputs against the model."""
        await FallingEdge(self.dut.clk)
        d, m = self.dut, self.model
        assert m.active is not None
        got = {
            "applied": int(d.applied.value),
            "act_l": int(d.act_l.value),
            "act_r": int(d.act_r.value),
            "act_width": int(d.act_width.value),
            "act_height": int(d.act_height.value),
            "act_lb_delay": int(d.act_lb_delay.value),
            "apply_pending": int(d.apply_pending.value),
        }
        want = {
            "applied": int(m.applied),
            "act_l": m.act_vector("L"),
            "act_r": m.act_vector("R"),
            "act_width": m.active.width,
            "act_height": m.active.height,
            "act_lb_delay": m.active.lb_delay,
            "apply_pending": int(m.pending),
        }
        control = CONTROL.decode(m.get("CONTROL"))
        for field_name in ("ENABLE", "BYPASS", "GRAY", "DEBUG_LINE"):
            got[f"ctl_{field_name.lower()}"] = int(getattr(d, f"ctl_{field_name.lower()}").value)
            want[f"ctl_{field_name.lower()}"] = control[field_name]
        got["debug_row"] = int(d.debug_row.value)
        want["debug_row"] = REG["DEBUG_ROW"].get(m.get("DEBUG_ROW"), "VALUE")
        bad = {k: (hex(got[k]), hex(want[k])) for k in got if got[k] != want[k]}
        if "act_l" in bad or "act_r" in bad:
            for cam in CAMERAS:
                vec = int(getattr(d, f"act_{cam.lower()}").value)
                for i, name in enumerate(PARAM_NAMES):
                    g = vec >> (64 * i) & MASK64
                    w = m.active.params[cam, name] & MASK64
                    if g != w:
                        bad[f"{cam}_{name}"] = (hex(g), hex(w))
        assert not bad, f"{what}outputs (got, want): {bad}"


def set_pauses(channels: Iterable, pauses: Callable[[], Iterator[bool]] | None) -> None:
    """A fresh pause generator from ``pauses`` for each channel; None: never pause.

    (cocotbext-axi keeps a channel's last pause state when its generator is removed.)
    """
    for channel in channels:
        channel.set_pause_generator(pauses() if pauses is not None else None)
        if pauses is None:
            channel.pause = False


def every_word() -> Iterable[int]:
    return range(0, RECTIFY_MAP.size, 4)


def writable_offsets() -> list[int]:
    return [reg.offset for reg in RECTIFY_MAP if reg.mask_of(Access.RW)]


def random_word() -> int:
    return random.choice([0, MASK32, 0x80000000, 0x7FFFFFFF, random.getrandbits(32), random.getrandbits(32)])


async def start(dut: SimHandleBase) -> TB:
    tb = TB(dut)
    await tb.reset()
    return tb


# ======================================================================================
# Reset, address map, access kinds
# ======================================================================================


@cocotb.test()
async def reset_values(dut: SimHandleBase) -> None:
    """Every word of the 4 KiB window reads its reset value (0 outside the map), before and after a reset."""
    tb = await start(dut)
    for offset in every_word():
        await tb.check_register(offset, "after reset: ")
    await tb.check_outputs("after reset: ")

    # Change everything that can change, then reset again.
    await tb.write_set(tb.random_set())
    await tb.write(CONTROL.offset, CONTROL.encode(ENABLE=1, BYPASS=1, GRAY=1, DEBUG_LINE=1))
    await tb.write(REG["DEBUG_ROW"].offset, MASK32)
    assert await tb.apply()
    for name in FLAG_INPUTS.values():
        await tb.pulse(getattr(dut, name), tb.edge + 2)
    await tb.pulse(dut.frame_done, tb.edge + 2)
    assert await tb.read(FLAGS.offset) != 0 and await tb.read(REG["FRAME_COUNT"].offset) == 1
    await tb.reset()
    for offset in every_word():
        await tb.check_register(offset, "after a second reset: ")
    await tb.check_outputs("after a second reset: ")
    tb.assert_protocol()


@cocotb.test()
async def unmapped_and_read_only_ignore_writes(dut: SimHandleBase) -> None:
    """Writes outside the map and to read-only registers answer OKAY and change nothing."""
    tb = await start(dut)
    read_only = [reg.offset for reg in RECTIFY_MAP if reg.access is Access.RO]
    unmapped = [off for off in every_word() if RECTIFY_MAP.at(off) is None]
    for offset in [*read_only, *unmapped]:
        await tb.write(offset, random.getrandbits(32) | 1 << random.randrange(32))
        await tb.write(offset, MASK32)
    for offset in every_word():
        await tb.check_register(offset, "after writes to read-only and unmapped words: ")
    await tb.check_outputs()
    tb.assert_protocol()


@cocotb.test()
async def read_write_registers_read_back(dut: SimHandleBase) -> None:
    """Every rw register reads back what was written (its rw bits), and drives its outputs."""
    tb = await start(dut)
    rw = writable_offsets()
    for _ in range(3):
        order = random.sample(rw, len(rw))
        for offset in order:
            value = random_word()
            if offset == CONTROL.offset:
                value = CONTROL.encode(value & ~CONTROL.bit("APPLY") & MASK32)  # APPLY has its own tests
            await tb.write(offset, value)
        for offset in random.sample(rw, len(rw)):
            await tb.check_register(offset)
        await tb.check_outputs("no APPLY: the active set is untouched; ")
    tb.assert_protocol()


@cocotb.test()
async def byte_strobes(dut: SimHandleBase) -> None:
    """WSTRB: every pattern, including none and gaps, on every kind of writable register."""
    tb = await start(dut)
    targets = [CONTROL.offset, REG["WIDTH"].offset, REG["DEBUG_ROW"].offset,
               param_offset("L", PARAM_NAMES[0]), param_offset("R", PARAM_NAMES[-1]) + 4,
               param_offset(random.choice(CAMERAS), random.choice(PARAM_NAMES))]
    for offset in targets:
        for strb in range(16):
            value = random.getrandbits(32)
            if offset == CONTROL.offset:
                value &= ~CONTROL.bit("APPLY")
            await tb.write(offset, value, strb)
            await tb.check_register(offset, f"strobe {strb:04b}: ")
    # FLAGS: a strobe-less byte does not clear
    for name, signal in FLAG_INPUTS.items():
        await tb.pulse(getattr(dut, signal), tb.edge + 2)
        tb.model.raise_flag(name)
    await tb.write(FLAGS.offset, MASK32, strb=0)
    await tb.check_register(FLAGS.offset, "W1C with no strobe: ")
    await tb.check_outputs()
    tb.assert_protocol()


@cocotb.test()
async def channel_order_and_backpressure(dut: SimHandleBase) -> None:
    """AW before W, W before AW (by 0..6 clocks), B and R held off: each write lands once, reads are right."""
    tb = await start(dut)
    wif, rif = tb.axil.write_if, tb.axil.read_if
    offsets = writable_offsets()
    offsets.remove(CONTROL.offset)
    for _lead, late in ((wif.aw_channel, wif.w_channel), (wif.w_channel, wif.aw_channel)):
        for delay in range(7):
            for channel in (late, wif.b_channel, rif.r_channel):
                held = itertools.chain(itertools.repeat(True, delay), itertools.repeat(False))
                channel.set_pause_generator(held)
            offset = random.choice(offsets)
            await tb.write(offset, random.getrandbits(32))
            await tb.check_register(offset, f"{delay} clocks between AW and W: ")
    channels = (wif.aw_channel, wif.w_channel, wif.b_channel, rif.ar_channel, rif.r_channel)
    set_pauses(channels, None)

    # Random pauses on all five channels, reads and writes at once on disjoint registers.
    set_pauses(channels, lambda: (random.random() < 0.4 for _ in itertools.count()))
    random.shuffle(offsets)
    half = len(offsets) // 2
    for writes, reads in ((offsets[:half], offsets[half:]), (offsets[half:], offsets[:half])):
        expected = {off: tb.model.read(off) for off in reads}

        async def writer(writes: list[int]) -> None:
            for off in writes:
                await tb.write(off, random.getrandbits(32))

        async def reader(reads: list[int], expected: dict[int, int]) -> None:
            for off in reads:
                got = await tb.read(off)
                assert got == expected[off], (
                    f"{off:#x} read {got:#x} during writes elsewhere, want {expected[off]:#x}")

        tasks = [cocotb.start_soon(writer(writes)), cocotb.start_soon(reader(reads, expected))]
        for task in tasks:
            await task
    # Many overlapped operations through the master's queues (it keeps one write and one read in flight).
    pending = []
    for off in random.sample(offsets, 20):
        value = random.getrandbits(32)
        pending.append(cocotb.start_soon(tb.axil.write_dword(off, value)))
        tb.model.write(off, value)
    for task in pending:
        await task
    set_pauses(channels, None)
    await tb.check_all_registers("after random backpressure: ")
    await ClockCycles(dut.clk, 2)  # the monitor counts the last handshake
    assert tb.counts["aw"] == tb.counts["w"] == tb.counts["b"], f"handshakes {tb.counts}"
    assert tb.counts["ar"] == tb.counts["r"], f"handshakes {tb.counts}"
    tb.assert_protocol()


# ======================================================================================
# FLAGS, STATUS, FRAME_COUNT
# ======================================================================================


@cocotb.test()
async def flags_are_sticky_and_write_one_to_clear(dut: SimHandleBase) -> None:
    tb = await start(dut)
    for name, signal in FLAG_INPUTS.items():
        await tb.pulse(getattr(dut, signal), tb.edge + 2)
        tb.model.raise_flag(name)
        await ClockCycles(dut.clk, 5)
        await tb.check_register(FLAGS.offset, f"{name} raised by one pulse: ")
    await tb.write(FLAGS.offset, 0)
    await tb.check_register(FLAGS.offset, "writing 0: ")
    for name in FLAG_INPUTS:
        await tb.write(FLAGS.offset, FLAGS.bit(name))
        await tb.check_register(FLAGS.offset, f"cleared {name}: ")
    # CONFIG_ERROR by a refused APPLY, cleared alone
    await tb.write(REG["WIDTH"].offset, REG["WIDTH"].encode(VALUE=0))
    assert not await tb.apply()
    await tb.check_register(FLAGS.offset, "refused APPLY: ")
    await tb.write(FLAGS.offset, FLAGS.bit("CONFIG_ERROR"))
    await tb.check_register(FLAGS.offset, "cleared CONFIG_ERROR: ")
    tb.assert_protocol()


async def _race(tb: TB, write_offset: int, write_value: int, drive, delta: int) -> int:
    """Write, and call ``drive(edge)`` for the edge ``delta`` clocks after the write's edge.

    The write's edge is found by a first, identical, write from the same clock phase
    (the block's timing is deterministic without pauses). Returns the write's edge.
    """
    await FallingEdge(tb.dut.clk)
    start_edge = tb.edge
    await tb.write(write_offset, write_value, model=False)
    latency = tb.write_edges[-1] - start_edge
    await ClockCycles(tb.dut.clk, 4)

    await FallingEdge(tb.dut.clk)
    start_edge = tb.edge
    target = start_edge + latency + delta
    driver = cocotb.start_soon(drive(target))
    await tb.write(write_offset, write_value, model=False)
    await driver
    assert tb.write_edges[-1] == start_edge + latency, "the write's timing was not repeatable"
    return tb.write_edges[-1]


@cocotb.test()
async def flag_raise_wins_over_a_clear(dut: SimHandleBase) -> None:
    """A raise on the very edge of a W1C write leaves the flag set; one edge earlier it is cleared."""
    tb = await start(dut)
    for name, signal in FLAG_INPUTS.items():
        for delta in (-2, -1, 0, 1, 2):
            # Set, so the first write has something to clear.
            await tb.pulse(getattr(dut, signal), tb.edge + 2)

            async def drive(edge: int, signal: str = signal) -> None:
                await tb.pulse(getattr(dut, signal), edge)

            await _race(tb, FLAGS.offset, FLAGS.bit(name), drive, delta)
            got = FLAGS.get(await tb.read(FLAGS.offset), name)
            assert got == int(delta >= 0), f"{name} raised {delta:+d} clocks from its clear: reads {got}"
            await tb.write(FLAGS.offset, FLAGS.mask_of(Access.W1C), model=False)

    # CONFIG_ERROR: a refused APPLY latching (idle rising) on the edge of the clear
    await tb.write(REG["HEIGHT"].offset, REG["HEIGHT"].encode(VALUE=0))
    for delta in (-2, -1, 0, 1, 2):
        dut.idle.value = 1
        assert not await tb.apply()  # refused: CONFIG_ERROR set, to be cleared
        dut.idle.value = 0
        await tb.write(CONTROL.offset, CONTROL.encode(APPLY=1))  # pending until idle

        async def drive_idle(edge: int) -> None:
            await tb.set_at(dut.idle, 1, edge)

        edge = await _race(tb, FLAGS.offset, FLAGS.bit("CONFIG_ERROR"), drive_idle, delta)
        await tb.wait_for(lambda: not int(dut.apply_pending.value), "the APPLY latch")
        latch = tb.apply_falls[-1]
        assert latch == edge + delta, f"latch on edge {latch}, idle from {edge + delta}"
        got = FLAGS.get(await tb.read(FLAGS.offset), "CONFIG_ERROR")
        want = int(latch >= edge)
        assert got == want, f"refused APPLY {latch - edge:+d} clocks from the CONFIG_ERROR clear: reads {got}"
        tb.model.pending = False
        await tb.clear_flags()
    dut.idle.value = 1
    tb.assert_protocol()


@cocotb.test()
async def status_follows_busy_and_apply(dut: SimHandleBase) -> None:
    tb = await start(dut)
    for busy in (1, 0, 1):
        dut.busy.value = busy
        tb.model.busy = busy
        await tb.check_register(STATUS.offset, f"busy {busy}: ")
    dut.idle.value = 0
    await tb.write(CONTROL.offset, CONTROL.encode(APPLY=1))
    await tb.check_register(STATUS.offset, "APPLY pending: ")
    await tb.check_register(CONTROL.offset, "APPLY pending: ")
    dut.idle.value = 1
    await tb.wait_for(lambda: not int(dut.apply_pending.value), "the APPLY latch")
    tb.model.latch()
    await tb.check_register(STATUS.offset, "APPLY done: ")
    await tb.check_register(CONTROL.offset, "APPLY done: ")
    tb.assert_protocol()


@cocotb.test()
async def frame_count_counts_and_wraps(dut: SimHandleBase) -> None:
    tb = await start(dut)
    count = REG["FRAME_COUNT"].offset
    # back-to-back pulses (frame_done high for n clocks), then spaced ones
    await tb.falling_after(tb.edge + 1)
    dut.frame_done.value = 1
    await ClockCycles(dut.clk, 7, rising=False)
    dut.frame_done.value = 0
    assert await tb.read(count) == 7
    for _ in range(5):
        await tb.pulse(dut.frame_done, tb.edge + random.randint(2, 5))
    assert await tb.read(count) == 12
    # wrap at 2^32: start the counter 3 below (a deposit into the register), then 5 pulses
    await FallingEdge(dut.clk)
    dut.frame_count_reg.value = MASK32 - 2
    await FallingEdge(dut.clk)
    assert await tb.read(count) == MASK32 - 2
    for _ in range(5):
        await tb.pulse(dut.frame_done, tb.edge + 2)
    assert await tb.read(count) == 2, "FRAME_COUNT does not wrap at 2^32"
    await tb.write(count, 0)  # read-only
    assert await tb.read(count) == 2
    tb.assert_protocol()


# ======================================================================================
# APPLY: latching, waiting for idle, validation
# ======================================================================================


@cocotb.test()
async def apply_when_idle_latches_on_the_next_clock(dut: SimHandleBase) -> None:
    """A valid shadow set becomes the active set one clock after the APPLY write, with no other change."""
    tb = await start(dut)
    for trial in range(4):
        await tb.write_set(tb.random_set())
        await tb.check_outputs("before APPLY: ")  # the active set waits for APPLY
        before = (int(dut.act_l.value), int(dut.act_r.value))
        other = random.getrandbits(4)
        control = CONTROL.encode(ENABLE=other & 1, BYPASS=other >> 1 & 1, GRAY=other >> 2 & 1,
                                 DEBUG_LINE=other >> 3 & 1, APPLY=1)
        seen: list[tuple[int, int, tuple[int, int]]] = []

        async def watch(seen: list[tuple[int, int, tuple[int, int]]]) -> None:
            while True:
                await FallingEdge(dut.clk)
                act = (int(dut.act_l.value), int(dut.act_r.value))
                seen.append((tb.edge, int(dut.apply_pending.value), act))

        watcher = cocotb.start_soon(watch(seen))
        await tb.write(CONTROL.offset, control)
        edge = tb.write_edges[-1]
        await ClockCycles(dut.clk, 3)
        watcher.cancel()
        assert tb.model.latch(), tb.model.problems()
        after = (tb.model.act_vector("L"), tb.model.act_vector("R"))
        history = {e: (pending, act) for e, pending, act in seen}
        assert history[edge] == (1, before), f"trial {trial}: after the APPLY write: pending, old set"
        assert history[edge + 1] == (0, after), f"trial {trial}: one clock later: latched"
        await tb.check_outputs(f"trial {trial}: ")
        await tb.check_all_registers(f"trial {trial}: ")
    tb.assert_protocol()


@cocotb.test()
async def apply_waits_for_idle(dut: SimHandleBase) -> None:
    """While the datapath is not idle APPLY stays pending (CONTROL.APPLY, STATUS, apply_pending)."""
    tb = await start(dut)
    first = tb.random_set()
    await tb.write_set(first)
    assert await tb.apply()
    for trial in range(3):
        dut.idle.value = 0
        await tb.write_set(tb.random_set())
        await tb.write(CONTROL.offset, CONTROL.encode(tb.model.get("CONTROL"), APPLY=1))
        await ClockCycles(dut.clk, random.randint(5, 40))
        await tb.check_outputs("pending: the old set stays active; ")
        await tb.check_register(CONTROL.offset, "pending: ")
        await tb.check_register(STATUS.offset, "pending: ")
        # other CONTROL writes (APPLY = 0, then 1 again) neither cancel nor double it
        await tb.write(CONTROL.offset, CONTROL.encode(GRAY=1, ENABLE=1))
        await tb.write(CONTROL.offset, CONTROL.encode(GRAY=1, ENABLE=1, APPLY=1))
        await tb.write(CONTROL.offset, CONTROL.encode(ENABLE=1))
        await tb.check_register(CONTROL.offset, "still pending after APPLY = 0: ")
        # a late shadow write counts: the latch takes the shadow as it is when idle comes
        await tb.write_param("R", "CX", random_valid("CX"))
        await tb.check_outputs("still pending: ")
        await ClockCycles(dut.clk, 3)
        await FallingEdge(dut.clk)
        idle_from = tb.edge + 1
        dut.idle.value = 1
        await tb.wait_for(lambda: not int(dut.apply_pending.value), "the APPLY latch")
        assert tb.apply_falls[-1] == idle_from, f"latched on edge {tb.apply_falls[-1]}, idle from {idle_from}"
        assert tb.model.latch()
        await tb.check_outputs(f"trial {trial}, after idle: ")
        await tb.check_all_registers(f"trial {trial}, after idle: ")
    tb.assert_protocol()


async def _try(tb: TB, what: str) -> None:
    """APPLY the shadow as it is; check acceptance or refusal against the model, then clear FLAGS."""
    want_ok = not tb.model.problems()
    before = (tb.model.active, tb.model.applied)
    ok = await tb.apply()
    assert ok == want_ok
    got_flag = FLAGS.get(await tb.read(FLAGS.offset), "CONFIG_ERROR")
    assert got_flag == int(not want_ok), f"{what}: CONFIG_ERROR reads {got_flag}, want {int(not want_ok)}"
    if not want_ok:
        assert (tb.model.active, tb.model.applied) == before
    await tb.check_outputs(f"{what} ({'accepted' if want_ok else 'refused'}): ")
    await tb.clear_flags()
    tb.model.values[FLAGS.offset] = 0


@cocotb.test()
async def validation_of_each_parameter(dut: SimHandleBase) -> None:
    """Every parameter at lo-1, lo, hi, hi+1 of PARAM_RANGE (and far outside): refused outside, kept
    inside."""
    tb = await start(dut)
    await tb.write_set(tb.random_set())
    assert await tb.apply()
    for cam, name in param_names():
        lo, hi = PARAM_RANGE[name]
        values = [lo - 1, lo, hi, hi + 1, -(1 << 63), (1 << 63) - 1,
                  random.randint(hi + 1, (1 << 63) - 1), random.randint(-(1 << 63), lo - 1)]
        for value in values:
            await tb.write_param(cam, name, value)
            await _try(tb, f"{cam}_{name} = {value}")
        await tb.write_param(cam, name, random_valid(name))
        await _try(tb, f"{cam}_{name} back in range")
    tb.assert_protocol()


@cocotb.test()
async def validation_of_frame_size(dut: SimHandleBase) -> None:
    """WIDTH and HEIGHT 0 / 1 / MAX / MAX+1 / all ones, LB_DELAY MAX_HEIGHT-1 / MAX_HEIGHT / all ones."""
    tb = await start(dut)
    await tb.write_set(tb.random_set())
    assert await tb.apply()
    b = tb.build
    cases = {
        "WIDTH": (0, 1, b.max_width, b.max_width + 1, 0xFFFF),
        "HEIGHT": (0, 1, b.max_height, b.max_height + 1, 0xFFFF),
        "LB_DELAY": (b.max_height, 0xFFFF, b.max_height - 1, 0),
    }
    for reg_name, values in cases.items():
        reg = REG[reg_name]
        lsb, width = value_field(reg_name)
        good = tb.model.get(reg_name)
        for value in values:
            await tb.write(reg.offset, reg.encode(VALUE=value & ((1 << width) - 1)))
            await _try(tb, f"{reg_name} = {value}")
        await tb.write(reg.offset, good)
        await _try(tb, f"{reg_name} restored")
    tb.assert_protocol()


@cocotb.test()
async def apply_while_the_shadow_is_being_written(dut: SimHandleBase) -> None:
    """idle rising at random moments during back-to-back shadow writes that make the set valid and invalid.

    The latch must take exactly the shadow of its own clock edge and accept it if and
    only if that set is valid: the check pipeline may never pair one set's verdict with
    another set's values.
    """
    tb = await start(dut)
    await tb.write_set(tb.random_set())
    assert await tb.apply()
    wif = tb.axil.write_if
    targets = [("L", "FX"), ("R", "N00"), ("L", "P2"), ("R", "K1")]
    for trial in range(30):
        dut.idle.value = 0
        await tb.write(CONTROL.offset, CONTROL.encode(APPLY=1))
        base = tb.model.values.copy()
        writes: list[tuple[int, int]] = []
        first_edge = len(tb.write_edges)
        pauses = random.choice([None, 0.3])
        set_pauses((wif.aw_channel, wif.w_channel),
                   None if pauses is None
                   else lambda p=pauses: (random.random() < p for _ in itertools.count()))
        stop = Event()

        def random_write() -> tuple[int, int]:
            if random.random() < 0.2:
                width = random.choice([0, 1, tb.build.max_width])
                return REG["WIDTH"].offset, REG["WIDTH"].encode(VALUE=width)
            cam, name = random.choice(targets)
            lo, hi = PARAM_RANGE[name]
            value = random.choice([lo, hi, lo - 1, hi + 1, random.randint(lo, hi)])
            half = random.randrange(2)
            return param_offset(cam, name) + 4 * half, i64_to_words(value)[half]

        async def writer(stop: Event, writes: list[tuple[int, int]]) -> None:
            while not stop.is_set():
                # 1 to 4 writes in flight at once: commits as close as every other clock
                batch = [random_write() for _ in range(random.randint(1, 4))]
                writes.extend(batch)
                tasks = [cocotb.start_soon(tb.write(offset, word, model=False)) for offset, word in batch]
                for t in tasks:
                    await t

        task = cocotb.start_soon(writer(stop, writes))
        await ClockCycles(dut.clk, random.randint(0, 30))
        await FallingEdge(dut.clk)
        dut.idle.value = 1
        await tb.wait_for(lambda: not int(dut.apply_pending.value), "the APPLY latch")
        await ClockCycles(dut.clk, random.randint(0, 12))
        stop.set()
        await task
        latch = tb.apply_falls[-1]
        # the shadow at the latch: the writes done on edges before it
        edges = tb.write_edges[first_edge:]
        assert len(edges) == len(writes)
        tb.model.values = base
        for (offset, word), edge in zip(writes, edges, strict=True):
            if edge < latch:
                tb.model.write(offset, word)
        at_latch = tb.model.shadow()
        for (offset, word), edge in zip(writes, edges, strict=True):
            if edge >= latch:
                tb.model.write(offset, word)
        accepted = tb.model.latch(at_latch)
        got_flag = FLAGS.get(await tb.read(FLAGS.offset), "CONFIG_ERROR")
        assert got_flag == int(not accepted), (
            f"trial {trial}: set at the latch {'valid' if accepted else 'invalid'} "
            f"({tb.model.problems(at_latch)}), CONFIG_ERROR reads {got_flag}"
        )
        await tb.check_outputs(f"trial {trial}: ")
        await tb.clear_flags()
        tb.model.values[FLAGS.offset] = 0
        # back to a valid shadow for the next trial
        for cam, name in targets:
            await tb.write_param(cam, name, random_valid(name))
        await tb.write(REG["WIDTH"].offset, REG["WIDTH"].encode(VALUE=tb.build.max_width))
    set_pauses((wif.aw_channel, wif.w_channel), None)
    await tb.check_all_registers()
    tb.assert_protocol()
