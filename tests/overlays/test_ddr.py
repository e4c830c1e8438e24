"""The emulated DDR: page allocator, PynqBuffer-like arrays, and access by physical address."""

from __future__ import annotations

import gc
import threading

import numpy as np
import pytest

from stereocam.overlays.emulated.ddr import (
    PAGE,
    DecodeError,
    EmulatedBuffer,
    EmulatedDDR,
    NotInDDR,
    OutOfDDR,
)

pytestmark = pytest.mark.armhf

BASE = 0x1000_0000


@pytest.fixture
def ddr() -> EmulatedDDR:
    return EmulatedDDR(BASE, 64 * PAGE)


def test_allocations_are_page_aligned_zeroed_and_distinct(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((3, 4, 8))
    b = ddr((100,), np.uint32)  # the driver allocator protocol
    c = ddr.allocate((PAGE + 1,), "u1")  # pynq passes dtype strings
    assert isinstance(a, EmulatedBuffer) and a.shape == (3, 4, 8) and a.dtype == np.uint8
    assert b.dtype == np.uint32
    assert [a.physical_address, b.physical_address, c.physical_address] == [
        BASE,
        BASE + PAGE,
        BASE + 2 * PAGE,
    ]
    assert a.device_address == a.physical_address
    assert not a.any() and not c.any()
    assert ddr.num_buffers == 3
    assert ddr.mem_used == 4 * PAGE  # c needs two pages


def test_views_report_their_own_address_and_computed_arrays_have_none(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((4, 5, 8))
    assert a[1:].physical_address == BASE + 5 * 8
    assert a[2, 3].physical_address == BASE + (2 * 5 + 3) * 8
    with pytest.raises(NotInDDR, match="does not live in an EmulatedDDR"):
        (a + 1).physical_address  # noqa: B018
    with pytest.raises(NotInDDR):
        np.zeros(3).view(EmulatedBuffer).physical_address  # noqa: B018


def test_physical_access_sees_the_same_bytes_as_the_array(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((2, 3, 8))
    a[1, 2] = np.arange(8)
    assert ddr.read(a[1, 2].physical_address, 8) == bytes(range(8))
    ddr.write(a.physical_address, b"\x07" * 8)
    assert (a[0, 0] == 7).all()
    # a 2-D transfer with a stride wider than the line
    lines = ddr.view2d(a.physical_address + 8, 2, 16, 24)
    lines[:] = 9
    assert (a[:, 1:3] == 9).all() and (a[:, 0] != 9).any() and (a[:, 0, :] == [[7] * 8, [0] * 8]).all()


def test_decode_errors_outside_live_allocations(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((100,))
    b = ddr.allocate((PAGE,))
    with pytest.raises(DecodeError, match=r"\[0x10000000, 0x10000065\)"):
        ddr.view(BASE, 101)  # past the bytes asked for, inside the page padding
    with pytest.raises(DecodeError):
        ddr.view(BASE + 200, 4)  # only padding
    with pytest.raises(DecodeError):
        ddr.view(BASE - 4, 4)  # below the window
    with pytest.raises(DecodeError):
        ddr.view2d(b.physical_address, 2, PAGE // 2, PAGE)  # second line runs off the end
    assert ddr.contains(BASE, 100) and not ddr.contains(BASE + 99, 2)
    a.freebuffer()
    with pytest.raises(DecodeError, match="freed buffer or wrong address"):
        ddr.view(BASE, 4)
    assert a.freed and not b.freed


def test_free_merges_ranges_and_first_fit_reuses_them(ddr: EmulatedDDR) -> None:
    a, b, c = (ddr.allocate((PAGE,)) for _ in range(3))
    b.freebuffer()
    a.freebuffer()
    a.freebuffer()  # idempotent
    big = ddr.allocate((2 * PAGE,))  # fits only because a and b merged
    assert big.physical_address == BASE
    small = ddr.allocate((1,))
    assert small.physical_address == BASE + 3 * PAGE
    assert c.physical_address == BASE + 2 * PAGE
    assert ddr.num_buffers == 3


def test_views_keep_memory_alive_and_dropping_everything_frees_it(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((PAGE,))
    view = a[10:20]
    address = view.physical_address
    del a
    gc.collect()
    assert ddr.contains(address, 10) and ddr.num_buffers == 1
    del view
    gc.collect()
    assert not ddr.contains(address, 10)
    assert ddr.num_buffers == 0 and ddr.mem_used == 0
    view2 = ddr.allocate((2, PAGE))[1]
    view2.freebuffer()  # only the array allocate returned owns the memory
    assert ddr.num_buffers == 1


def test_context_manager_and_close_free(ddr: EmulatedDDR) -> None:
    with ddr.allocate((8,)) as buf:
        assert ddr.num_buffers == 1
        address = buf.physical_address
    assert ddr.num_buffers == 0 and not ddr.contains(address, 8)
    other = ddr.allocate((8,))
    other.close()
    assert ddr.num_buffers == 0


def test_out_of_memory_says_how_much_is_free(ddr: EmulatedDDR) -> None:
    keep = ddr.allocate((60 * PAGE,))
    with pytest.raises(
        OutOfDDR, match=f"cannot allocate {5 * PAGE} bytes: {4 * PAGE} of {64 * PAGE} bytes free"
    ):
        ddr.allocate((5 * PAGE,))
    assert isinstance(OutOfDDR("x"), MemoryError)
    keep.freebuffer()
    ddr.allocate((5 * PAGE,))


def test_pynq_frame_cache_protocol(ddr: EmulatedDDR) -> None:
    class Cache:
        def __init__(self) -> None:
            self.pointers: list = []

        def return_pointer(self, pointer: object) -> None:
            self.pointers.append(pointer)

    cache = Cache()
    a = ddr.allocate((4, 8), np.uint8, cacheable=True, cache=cache)
    address = a.physical_address
    a.freebuffer()  # back to the cache, not freed
    assert len(cache.pointers) == 1 and ddr.contains(address, 32)
    b = ddr.allocate((4, 8), "u1", pointer=cache.pointers.pop(), cache=cache)
    assert b.physical_address == address and ddr.num_buffers == 1
    with pytest.raises(ValueError, match="do not fit"):
        ddr.allocate((5, 8), pointer=b.pointer)


def test_flush_and_invalidate_are_counted(ddr: EmulatedDDR) -> None:
    a = ddr.allocate((8,))
    a.flush()
    a[2:].invalidate()
    a.sync_to_device()
    assert (ddr.flushes, ddr.invalidates) == (2, 1)
    assert a.cacheable is False


def test_window_must_be_page_aligned_and_32_bit() -> None:
    with pytest.raises(ValueError, match="multiples of 0x1000"):
        EmulatedDDR(BASE + 1, PAGE)
    with pytest.raises(ValueError, match="below 4 GiB"):
        EmulatedDDR(0xFFFF_F000, 2 * PAGE)


def test_concurrent_allocations_never_overlap(ddr: EmulatedDDR) -> None:
    live: list = []
    lock = threading.Lock()
    errors: list = []

    def worker(seed: int) -> None:
        rng = np.random.default_rng(seed)
        mine = []
        try:
            for _ in range(200):
                if mine and rng.random() < 0.5:
                    mine.pop(int(rng.integers(len(mine)))).freebuffer()
                elif len(mine) < 3:
                    buf = ddr.allocate((int(rng.integers(1, 2 * PAGE)),))
                    buf[:] = seed
                    mine.append(buf)
                for b in mine:
                    assert (b == seed).all(), "another thread's allocation overlapped"
            with lock:
                live.extend(mine)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(s,)) for s in range(1, 5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert ddr.num_buffers == len(live)
    spans = sorted((b.physical_address, b.physical_address + b.nbytes) for b in live)
    assert all(end <= start for (_, end), (start, _) in zip(spans, spans[1:], strict=False))
