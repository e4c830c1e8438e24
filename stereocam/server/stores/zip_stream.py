"""A zip archive of open files, produced as a stream of byte chunks.

So that a capture or a recording downloads without being built in memory or
on disk first: ``zipfile`` writes into an unseekable sink that is emptied
after each chunk.
"""
from __future__ import annotations

import zipfile
from typing import IO, Any, Iterator, List, Tuple


class _Sink:
    """A write-only, unseekable file for ``zipfile``: collects what it is given until taken."""

    def __init__(self) -> None:
        self._parts: List[bytes] = []
        self._pos = 0
        self.pending = 0

    def write(self, data: Any) -> int:
        b = bytes(data)
        self._parts.append(b)
        self._pos += len(b)
        self.pending += len(b)
        return len(b)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    def take(self) -> bytes:
        out = b"".join(self._parts)
        self._parts.clear()
        self.pending = 0
        return out


def close_all(handles: List[IO[bytes]]) -> None:
    for fh in handles:
        fh.close()


def zip_chunks(
    cid: str, date_time: Tuple[int, int, int, int, int, int],
    handles: List[Tuple[str, IO[bytes], int]], chunk_size: int,
) -> Iterator[bytes]:
    """The archive of ``handles`` (name, open file, size) in the folder ``cid/``; closes them at the end."""
    sink = _Sink()
    try:
        with zipfile.ZipFile(sink, "w", allowZip64=True) as zf:
            for name, fh, size in handles:
                zi = zipfile.ZipInfo(f"{cid}/{name}", date_time=date_time)
                zi.compress_type = zipfile.ZIP_STORED if name.endswith(".png") else zipfile.ZIP_DEFLATED
                zi.file_size = size
                zi.external_attr = 0o644 << 16
                with zf.open(zi, "w") as dst:
                    while True:
                        block = fh.read(chunk_size)
                        if not block:
                            break
                        dst.write(block)
                        if sink.pending >= chunk_size:
                            yield sink.take()
                if sink.pending:
                    yield sink.take()
        if sink.pending:
            yield sink.take()
    finally:
        close_all([fh for _, fh, _ in handles])
