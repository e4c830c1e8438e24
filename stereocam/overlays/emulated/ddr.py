"""Emulated DDR: physically addressed frame memory shared by the processor and the emulated DMAs.

:class:`EmulatedDDR` stands in for the board's contiguous (CMA) memory. It
hands out :class:`EmulatedBuffer` arrays, which behave like
``pynq.buffer.PynqBuffer``: a numpy array with a ``physical_address``, and
``flush()``/``invalidate()``/``freebuffer()``. The emulated VDMA reaches the
same bytes by physical address (:meth:`EmulatedDDR.view2d`), so a frame
written by the S2MM channel appears in the buffer, exactly as on the board.

Rules, as on the board:

* Allocations are page aligned (4 KiB) and come from one window
  ``[base, base + size)`` below 4 GiB (the Zynq-7000 VDMA has 32-bit
  addresses). First fit; freed ranges merge with their neighbours.
* A DMA access must lie inside one live allocation (the bytes asked for,
  not the page padding). Anything else raises :class:`DecodeError`, which
  the emulated VDMA turns into ``VDMASR.VDMADecErr``.
* An allocation lives while any array (the buffer, or a view of it) refers
  to it, or until ``freebuffer()``. Dropping every reference frees it, as
  ``PynqBuffer.__del__`` does; a DMA still pointed at it then gets DecErr.
* Memory is coherent: ``flush``/``invalidate`` only count calls, so tests
  can check that a driver makes them.

Only what is allocated takes memory: the window is address space, and each
allocation has a zeroed array of its own (page rounded), which lives as long
as an array refers to it. So an overlay costs its frame buffers, not the
window (a 32-bit process, the armhf test env and the board's, holds few
256 MiB windows), and when an overlay closes and its drivers free their
buffers, the memory goes back. A range freed and allocated again gets fresh,
zeroed memory; arrays still holding the old allocation keep the old bytes
(no longer reachable by DMA). :attr:`EmulatedDDR.held_bytes` says how much
memory this DDR's allocations hold, freed ones still referenced included.

Thread-safe: the frame clock thread and driver threads may allocate, free
and access at once.
"""

from __future__ import annotations

import bisect
import threading
import weakref
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

PAGE = 4096
DEFAULT_BASE = 0x1000_0000
DEFAULT_SIZE = 256 << 20


class DDRError(Exception):
    """Base of the emulated DDR's errors."""


class OutOfDDR(DDRError, MemoryError):
    """No free range is large enough for an allocation."""


class DecodeError(DDRError):
    """An access at a physical address that no live allocation covers (a DMA gets DecErr)."""

    def __init__(self, address: int, nbytes: int) -> None:
        super().__init__(
            f"no live DDR allocation covers [{address:#010x}, {address + nbytes:#010x}) "
            f"({nbytes} bytes): freed buffer or wrong address"
        )
        self.address = address
        self.nbytes = nbytes


class NotInDDR(DDRError, ValueError):
    """An array that does not live in the emulated DDR has no physical address."""


class _Allocation:
    """One allocated range; the ``pointer`` pynq's frame caches pass back to ``allocate``.

    ``mem`` is its memory (``size`` bytes, zeroed), ``origin`` that memory's virtual address.
    """

    __slots__ = ("start", "nbytes", "size", "serial", "freed", "mem", "origin", "_finalizer", "__weakref__")

    def __init__(self, start: int, nbytes: int, size: int, serial: int, mem: np.ndarray) -> None:
        self.start = start
        self.nbytes = nbytes
        self.size = size
        self.serial = serial
        self.freed = False
        self.mem = mem
        self.origin = int(mem.__array_interface__["data"][0])
        self._finalizer: Optional[weakref.finalize] = None

    def offset_of(self, array: np.ndarray) -> Optional[int]:
        """Byte offset of ``array``'s first element in this allocation's memory, None if outside."""
        offset = int(array.__array_interface__["data"][0]) - self.origin
        return offset if 0 <= offset < self.size else None

    def __repr__(self) -> str:
        return f"<DDR allocation {self.start:#010x}+{self.nbytes}{' freed' if self.freed else ''}>"


class EmulatedBuffer(np.ndarray):
    """A numpy array in emulated DDR, with the ``pynq.buffer.PynqBuffer`` interface we use.

    Views (slices, reshapes) keep the allocation alive and report their own
    physical address. Create buffers with :meth:`EmulatedDDR.allocate` only.
    Arrays computed *from* a buffer (``buf + 1``) are not in DDR; asking
    them for a physical address raises :class:`NotInDDR`.
    """

    _ddr: Optional["EmulatedDDR"]
    _allocation: Optional[_Allocation]

    def __array_finalize__(self, obj: Any) -> None:
        ddr = getattr(obj, "_ddr", None)
        alloc: Optional[_Allocation] = getattr(obj, "_allocation", None)
        if ddr is None or alloc is None or alloc.offset_of(self) is None:
            ddr, alloc = None, None  # a computed result (buf + 1) has memory of its own
        self._ddr = ddr
        self._allocation = alloc
        self._root = False
        self.pointer: Optional[_Allocation] = None
        self.return_to: Any = None
        self.coherent = True

    # -- addresses ----------------------------------------------------------------------
    @property
    def physical_address(self) -> int:
        if self._ddr is None:
            raise NotInDDR(
                "this array does not live in an EmulatedDDR (allocate it there; "
                "results computed from a buffer are ordinary memory)"
            )
        return self._ddr.address_of(self, self._allocation)

    @property
    def device_address(self) -> int:
        return self.physical_address

    @property
    def virtual_address(self) -> int:
        return int(self.__array_interface__["data"][0])

    @property
    def cacheable(self) -> bool:
        return not self.coherent

    @property
    def freed(self) -> bool:
        return self._allocation is None or self._allocation.freed

    # -- cache maintenance (coherent: counted only) -------------------------------------
    def flush(self) -> None:
        """Make CPU writes visible to the DMA (counted; emulated memory is coherent)."""
        if self._ddr is not None:
            self._ddr._count("flushes")

    def invalidate(self) -> None:
        """Make DMA writes visible to the CPU (counted; emulated memory is coherent)."""
        if self._ddr is not None:
            self._ddr._count("invalidates")

    def sync_to_device(self) -> None:
        self.flush()

    def sync_from_device(self) -> None:
        self.invalidate()

    # -- lifetime -----------------------------------------------------------------------
    def freebuffer(self) -> None:
        """Free the memory (idempotent), or hand it back to the pynq frame cache it came from.

        Like ``PynqBuffer.freebuffer``, only the buffer ``allocate`` returned
        owns the memory: on a view this does nothing. Views still in use
        afterwards point at freed memory.
        """
        if not self._root:
            return
        if self.return_to is not None and self.pointer is not None:
            pointer, self.pointer = self.pointer, None
            self.return_to.return_pointer(pointer)
            return
        if self._ddr is not None and self._allocation is not None:
            self._ddr._release(self._allocation)

    def close(self) -> None:
        """Same as :meth:`freebuffer`."""
        self.freebuffer()

    def __enter__(self) -> "EmulatedBuffer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.freebuffer()


class EmulatedDDR:
    """Physically addressed memory ``[base, base + size)`` with a page allocator.

    ``allocate(shape, dtype)`` (also available as ``ddr(shape, dtype)``, the
    driver allocator protocol, and as ``pynq.allocate(..., target=ddr)``)
    returns an :class:`EmulatedBuffer`.
    """

    def __init__(self, base: int = DEFAULT_BASE, size: int = DEFAULT_SIZE) -> None:
        if base % PAGE or size % PAGE or size <= 0:
            raise ValueError(f"DDR base {base:#x} and size {size:#x} must be positive multiples of {PAGE:#x}")
        if base < 0 or base + size > 1 << 32:
            raise ValueError(
                f"DDR window [{base:#x}, {base + size:#x}) must lie below 4 GiB (32-bit DMA addresses)"
            )
        self.base = base
        self.size = size
        self._lock = threading.RLock()
        self._free: List[Tuple[int, int]] = [(base, size)]  # sorted (start, size)
        self._starts: List[int] = []  # sorted starts of live allocations
        # start -> (serial, nbytes, size, weak reference): an allocation lives while arrays refer to it
        self._live: Dict[int, Tuple[int, int, int, "weakref.ref[_Allocation]"]] = {}
        self._dead: List[Tuple[int, int]] = []  # (start, serial) of collected allocations, see _reap
        self._held: Dict[int, int] = {}  # serial -> bytes of allocation memory still alive
        self._gone: List[int] = []  # serials whose memory was collected, see _reap
        self._serial = 0
        self.flushes = 0
        self.invalidates = 0

    # -- allocation ---------------------------------------------------------------------
    def allocate(
        self,
        shape: Any,
        dtype: Any = np.uint8,
        *,
        pointer: Optional[_Allocation] = None,
        cache: Any = None,
        **ignored: Any,
    ) -> EmulatedBuffer:
        """A zero-initialised-at-first-use array of ``shape``/``dtype`` in DDR.

        ``pointer``/``cache`` follow pynq's frame-cache protocol: ``pointer``
        reuses an allocation handed back by an earlier buffer's
        ``freebuffer()``, and ``cache.return_pointer(pointer)`` is called
        instead of freeing when a buffer made with ``cache`` is freed.
        Other pynq keywords (``cacheable``, ...) are accepted and ignored.
        """
        dt = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64)) if np.ndim(shape) else int(shape)
        nbytes = count * dt.itemsize
        if pointer is not None:
            if not isinstance(pointer, _Allocation) or pointer.freed:
                raise ValueError(f"pointer {pointer!r} is not a live allocation of this DDR")
            if nbytes > pointer.nbytes:
                raise ValueError(
                    f"{nbytes} bytes do not fit the {pointer.nbytes}-byte allocation being reused"
                )
            alloc = pointer
        else:
            alloc = self._take(nbytes)
        buf = np.ndarray.__new__(EmulatedBuffer, shape, dtype=dt, buffer=alloc.mem, offset=0)
        buf._ddr = self
        buf._allocation = alloc
        buf._root = True
        if cache is not None:
            buf.pointer = alloc
            buf.return_to = cache
        return buf

    __call__ = allocate

    def _take(self, nbytes: int) -> _Allocation:
        size = max(PAGE, -(-nbytes // PAGE) * PAGE)
        with self._lock:
            self._reap()
            for i, (start, free) in enumerate(self._free):
                if free >= size:
                    if free == size:
                        del self._free[i]
                    else:
                        self._free[i] = (start + size, free - size)
                    self._serial += 1
                    try:
                        mem = np.zeros(size, np.uint8)  # calloc: pages are committed when touched
                    except MemoryError:
                        self._give_back_range(start, size)
                        raise
                    alloc = _Allocation(start, nbytes, size, self._serial, mem)
                    alloc._finalizer = weakref.finalize(alloc, self._dead.append, (start, self._serial))
                    self._held[self._serial] = size
                    weakref.finalize(mem, self._gone.append, self._serial)
                    self._live[start] = (self._serial, nbytes, size, weakref.ref(alloc))
                    bisect.insort(self._starts, start)
                    return alloc
            raise OutOfDDR(
                f"cannot allocate {nbytes} bytes: {self.size - self.mem_used} of {self.size} bytes free "
                f"in {len(self._free)} ranges (free unused buffers, or give EmulatedDDR a larger size)"
            )

    def _release(self, alloc: _Allocation) -> None:
        with self._lock:
            if alloc.freed:
                return
            if alloc._finalizer is not None:
                alloc._finalizer.detach()
            alloc.freed = True
            self._give_back(alloc.start)

    def _give_back(self, start: int) -> None:
        size = self._live.pop(start)[2]
        self._starts.pop(bisect.bisect_left(self._starts, start))
        self._give_back_range(start, size)

    def _give_back_range(self, start: int, size: int) -> None:
        i = bisect.bisect_left(self._free, (start, 0))
        self._free.insert(i, (start, size))
        # merge with the next and the previous free range
        if i + 1 < len(self._free) and start + size == self._free[i + 1][0]:
            self._free[i] = (start, size + self._free[i + 1][1])
            del self._free[i + 1]
        if i > 0 and self._free[i - 1][0] + self._free[i - 1][1] == start:
            self._free[i - 1] = (self._free[i - 1][0], self._free[i - 1][1] + self._free[i][1])
            del self._free[i]

    def _reap(self) -> None:
        """Free allocations whose last array was garbage collected.

        The collector only appends to ``_dead`` (it may run inside any
        allocation, even one holding the lock); the ranges go back to the
        free list here, under the lock.
        """
        while self._dead:
            start, serial = self._dead.pop()
            entry = self._live.get(start)
            if entry is not None and entry[0] == serial:
                self._give_back(start)
        while self._gone:
            self._held.pop(self._gone.pop(), None)

    # -- statistics (pynq memory names) -------------------------------------------------
    @property
    def mem_used(self) -> int:
        with self._lock:
            self._reap()
            return self.size - sum(size for _, size in self._free)

    @property
    def num_buffers(self) -> int:
        with self._lock:
            self._reap()
            return len(self._starts)

    @property
    def held_bytes(self) -> int:
        """Bytes of memory this DDR's allocations hold now: live ones, and freed ones an array still uses."""
        with self._lock:
            self._reap()
            return sum(self._held.values())

    def _count(self, what: str) -> None:
        with self._lock:
            setattr(self, what, getattr(self, what) + 1)

    # -- access by physical address (the DMA side) --------------------------------------
    def address_of(self, array: np.ndarray, allocation: Optional[_Allocation] = None) -> int:
        """Physical address of the first element of an array that lives in this DDR.

        ``allocation``, when known (a buffer knows its own), saves the search among
        the live allocations.
        """
        if allocation is not None:
            offset = allocation.offset_of(array)
            if offset is not None:
                return allocation.start + offset
        with self._lock:
            for _, _, _, ref in self._live.values():
                alloc = ref()
                offset = alloc.offset_of(array) if alloc is not None else None
                if alloc is not None and offset is not None:
                    return alloc.start + offset
        raise NotInDDR("this array does not live in the emulated DDR (a computed result, not a buffer)")

    def _lookup(self, address: int, nbytes: int) -> _Allocation:
        with self._lock:
            self._reap()
            i = bisect.bisect_right(self._starts, address) - 1
            if i >= 0:
                start = self._starts[i]
                _, live_bytes, _, ref = self._live[start]
                alloc = ref()
                if alloc is not None and not alloc.freed and address + nbytes <= start + live_bytes:
                    return alloc
        raise DecodeError(address, nbytes)

    def contains(self, address: int, nbytes: int) -> bool:
        """True if ``[address, address + nbytes)`` lies inside one live allocation."""
        try:
            self._lookup(address, nbytes)
        except DecodeError:
            return False
        return True

    def view(self, address: int, nbytes: int) -> np.ndarray:
        """Writable ``uint8`` view of ``nbytes`` at ``address``; :class:`DecodeError` outside allocations."""
        alloc = self._lookup(address, nbytes)
        off = address - alloc.start
        return alloc.mem[off : off + nbytes]

    def view2d(self, address: int, lines: int, line_bytes: int, stride: int) -> np.ndarray:
        """Writable ``(lines, line_bytes)`` uint8 view of a 2-D transfer, as a VDMA addresses it.

        Line ``y`` starts at ``address + y * stride``. The whole extent
        ``[address, address + (lines - 1) * stride + line_bytes)`` must lie
        inside one live allocation, else :class:`DecodeError`.
        """
        if lines < 1 or line_bytes < 1 or stride < 1:
            raise ValueError(
                f"a 2-D transfer needs lines, line_bytes and stride >= 1, got {lines}, {line_bytes}, {stride}"
            )
        extent = (lines - 1) * stride + line_bytes
        flat = self.view(address, extent)
        return np.lib.stride_tricks.as_strided(flat, shape=(lines, line_bytes), strides=(stride, 1))

    def read(self, address: int, nbytes: int) -> bytes:
        return self.view(address, nbytes).tobytes()

    def write(self, address: int, data: Any) -> None:
        """Copy bytes (or an array's bytes, C order) to ``address``; :class:`DecodeError` outside."""
        if isinstance(data, np.ndarray):
            raw = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
        else:
            raw = np.frombuffer(bytes(data), np.uint8)
        self.view(address, raw.size)[:] = raw
