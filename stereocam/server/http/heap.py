"""The daemon's heap on a small board: few malloc arenas, freed memory handed back.

glibc gives every thread that allocates its own arena (up to 8 per core) and keeps what is freed
in them. A burst of large uploads handled on the executor threads then leaves tens of MB resident
that a 512 MB board needs back. Two arenas and a periodic ``malloc_trim`` hold the daemon near
its working set (measured in ``tests/server/test_hostile_clients.py``: about 40 MB less after 2,000
malformed requests). Where the C library is not glibc, both do nothing.
"""
from __future__ import annotations

import asyncio
import ctypes
import functools
from typing import Any, Optional

ARENAS = 2  # the executor threads share them: a burst of uploads no longer leaves one heap per thread
TRIM_S = 2.0
_M_ARENA_MAX = -8  # glibc's malloc.h


@functools.lru_cache(maxsize=None)
def _libc() -> Optional[Any]:
    """The C library the process runs with (its own symbols: no library search, no ``ldconfig``)."""
    try:
        return ctypes.CDLL(None)
    except OSError:
        return None


def limit_arenas(arenas: int = ARENAS) -> bool:
    """Cap glibc's malloc arenas; call before the daemon starts its threads. True if it took."""
    libc = _libc()
    mallopt = getattr(libc, "mallopt", None)
    if mallopt is None:
        return False
    return bool(mallopt(_M_ARENA_MAX, arenas))


async def give_back_memory(period_s: float = TRIM_S) -> None:
    """Return freed heap to the system every ``period_s`` (glibc keeps it after large requests).

    A fixed mmap threshold would do it too, but doubles the CPU per frame.
    """
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is None:
        return
    loop = asyncio.get_running_loop()
    while True:
        await asyncio.sleep(period_s)
        await loop.run_in_executor(None, trim, 0)  # a heap walk: off the loop (ctypes drops the GIL)
