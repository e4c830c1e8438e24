"""The emulated DDR takes the memory its buffers use, not its 256 MiB window, and gives it back.

A 32-bit process (the armhf test env, a board's 3G/1G kernel) has about 3 GiB of address
space: an emulated overlay that held a 256 MiB array for its window allowed about a dozen
overlays alive at once. Measured two ways: what :class:`EmulatedDDR` says its
allocations hold, and what the process allocated (tracemalloc, which numpy reports its
array memory to), so that neither the DDR's bookkeeping nor the measure alone decides.
"""
from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

from stereocam.overlays.emulated.ddr import DEFAULT_SIZE, PAGE, EmulatedDDR
from stereocam.overlays.emulated.overlay import EmulatedOverlay

pytestmark = pytest.mark.armhf

MIB = 1 << 20


class FlatSource:
    """A camera source of one flat stream frame (cheap to make, unlike the synthetic rig's scene)."""

    frame_size = (160, 120)

    def __init__(self) -> None:
        self.frame = np.full((120, 160, 8), 64, np.uint8)

    def read(self, index: int, t: float) -> np.ndarray:
        return self.frame

    def close(self) -> None:
        pass


def test_a_ddr_takes_no_memory_until_it_allocates_and_only_what_it_allocates() -> None:
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        ddrs = [EmulatedDDR() for _ in range(8)]  # eight 256 MiB windows: 2 GiB of address space
        assert all(d.size == DEFAULT_SIZE and d.held_bytes == 0 for d in ddrs)
        # Loose bounds (another thread of the process may allocate meanwhile): the window was 2 GiB.
        assert tracemalloc.get_traced_memory()[0] - before < 8 * MIB
        bufs = [d.allocate((3, PAGE + 1)) for d in ddrs]  # 3 pages and 3 bytes: 4 pages each
        assert all(d.held_bytes == 4 * PAGE for d in ddrs)
        assert tracemalloc.get_traced_memory()[0] - before < 8 * 4 * PAGE + 8 * MIB
    finally:
        tracemalloc.stop()
    # Physical addresses, DMA access and freeing behave as before.
    assert bufs[0].physical_address == ddrs[0].base
    ddrs[0].write(bufs[0][1].physical_address, b"\x05" * 4)
    assert (bufs[0][1, :4] == 5).all() and not bufs[0][0].any()
    bufs[0].freebuffer()
    assert ddrs[0].num_buffers == 0 and ddrs[0].held_bytes == 4 * PAGE  # bufs[0] still refers to it
    del bufs
    gc.collect()
    assert all(d.held_bytes == 0 for d in ddrs)


def test_freed_range_reused_gets_fresh_zeroed_memory() -> None:
    ddr = EmulatedDDR(0x1000_0000, 16 * PAGE)
    a = ddr.allocate((PAGE,))
    a[:] = 7
    address = a.physical_address
    a.freebuffer()
    b = ddr.allocate((PAGE,))
    assert b.physical_address == address and not b.any()  # first fit: the same range, new memory
    ddr.write(address, b"\x01")
    assert b[0] == 1 and a[0] == 7  # DMA reaches the live allocation only


def test_overlays_opened_and_closed_in_sequence_give_their_memory_back() -> None:
    """Closed overlays that something still holds (as aiohttp's middleware cache held every
    test's application) keep no DDR memory: four of them held 1 GiB before."""
    kept = []
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for _ in range(4):
            ov = EmulatedOverlay(clock="stepped", source=FlatSource())
            ov.start()
            ov.step(2)
            ddr = ov.emulation.ddr
            assert 0 < ddr.held_bytes < 16 * MIB, "an open overlay holds its frame buffers only"
            ov.close()
            kept.append(ov)
        gc.collect()
        assert [ov.emulation.ddr.held_bytes for ov in kept] == [0] * 4
        assert [ov.emulation.ddr.num_buffers for ov in kept] == [0] * 4
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 16 * MIB, f"four closed overlays still hold {grown / MIB:.0f} MiB"
