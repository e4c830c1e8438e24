"""cocotb bench for the whole stereo core (stereocam/overlays/rtl/stereo/stereo_core.v) against the model.

Run by ``tests/hdl/test_stereo_core_rtl.py`` through ``run_cocotb``; not a pytest module. The case
(``STEREOCAM_STEREO_CASE``, JSON) names an ``.npz`` of frames (``left``, ``right``: (N, H, W) uint8)
and the model's beats for each (``beats``: (N, H, W) uint32), the register writes that program
the core and the pause probabilities of the two streams. Every output beat (TDATA, TUSER, TLAST)
of every frame must equal the model's, in order, and nothing else; then FRAME_COUNT must count
the frames and FLAGS be clear.
"""
from __future__ import annotations

import json
import os
import random
from typing import List, Tuple

import cocotb
import numpy as np
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles
from cocotbext.axi import AxiLiteBus, AxiLiteMaster

from stereocam.overlays.spec import stereo as spec
from tests.hdl.tb_rc_datapath import StreamBench
from tests.hdl.unit_bench import add_to_report

Beat = Tuple[int, int, int]


def frame_beats(left: np.ndarray, right: np.ndarray) -> List[Beat]:
    """The rectify core's 64-bit pixels carrying the pair's gray bytes (the other bytes: noise)."""
    h, w = left.shape
    rng = np.random.default_rng(int(left.sum()) + 7)
    noise = rng.integers(0, 1 << 62, (h, w), dtype=np.uint64)
    keep = ~((np.uint64(0xFF) << np.uint64(8 * spec.IN_LEFT_GRAY_BYTE))
             | (np.uint64(0xFF) << np.uint64(8 * spec.IN_RIGHT_GRAY_BYTE)))
    words = ((noise & keep) | (left.astype(np.uint64) << np.uint64(8 * spec.IN_LEFT_GRAY_BYTE))
             | (right.astype(np.uint64) << np.uint64(8 * spec.IN_RIGHT_GRAY_BYTE)))
    return [(int(words[y, x]), int(x == 0 and y == 0), int(x == w - 1)) for y in range(h) for x in range(w)]


@cocotb.test()
async def frames(dut: SimHandleBase) -> None:
    case = json.loads(open(os.environ["STEREOCAM_STEREO_CASE"]).read())
    data = np.load(case["npz"])
    lefts, rights, want = data["left"], data["right"], data["beats"]
    n, h, w = lefts.shape
    rng = random.Random(case["seed"])
    bench = StreamBench(dut, dut.aclk, dut.aresetn, reset_active_level=False)
    axil = AxiLiteMaster(AxiLiteBus.from_prefix(dut, "s_axil"), dut.aclk, dut.aresetn,
                         reset_active_level=False)
    bench.set_pauses(case["p_in"], case["p_out"], rng)
    dut.aresetn.value = 0
    await ClockCycles(dut.aclk, 8)
    dut.aresetn.value = 1
    await ClockCycles(dut.aclk, 4)
    assert await axil.read_dword(spec.STEREO_MAP.offset("ID")) == spec.CORE_ID
    for offset, value in case["writes"]:
        await axil.write_dword(offset, value)

    async def send() -> None:
        for i in range(n):
            await bench.send(frame_beats(lefts[i], rights[i]))

    sender = cocotb.start_soon(send())
    start = bench.cycle
    differing = 0
    for i in range(n):
        words, users, lengths = await bench.receive_frame(h, case["timeout_us"])
        assert lengths == [w] * h, f"frame {i}: rows of {sorted(set(lengths))} beats, not {w}"
        got = words.astype(np.uint32)
        bad = got != want[i]
        differing += int(bad.sum())
        if bad.any():
            np.save(f"got{i}.npy", got)  # beside the results, for a look at the difference
            y, x = (int(v) for v in np.argwhere(bad)[0])
            raise AssertionError(f"frame {i}: {int(bad.sum())} of {h * w} beats differ; first at x={x} "
                                 f"y={y}: RTL {int(got[y, x]):#010x}, model {int(want[i][y, x]):#010x}")
        assert users[0][0] == 1 and sum(sum(u) for u in users) == 1, f"frame {i}: TUSER misplaced"
    await sender
    cycles = bench.cycle - start
    await ClockCycles(dut.aclk, 8)
    assert await axil.read_dword(spec.STEREO_MAP.offset("FRAME_COUNT")) == n
    assert await axil.read_dword(spec.STEREO_MAP.offset("FLAGS")) == 0
    assert not bench.stall_violations, bench.stall_violations[:3]
    add_to_report("STEREOCAM_STEREO_REPORT", case["name"],
                  {"frames": n, "beats": n * h * w, "differing": differing, "cycles": cycles,
                   "clocks_per_beat": cycles / (n * h * w)})
