"""One malformed request and the statuses it may get, and the builder the families of cases share."""
from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Any, FrozenSet, List, Optional, Sequence, Tuple

from .raw_http import http_request


@dataclass(frozen=True)
class Case:
    """One malformed request: ``data`` is every byte sent, ``expect`` the statuses it may get.

    An empty ``expect`` allows any 4xx. ``answered=False`` allows the daemon to close the
    connection without answering (a request cut short has nothing to answer).
    """

    kind: str  # upload | json | yaml | header | line
    name: str
    data: bytes = field(repr=False)
    expect: FrozenSet[int] = frozenset()
    answered: bool = True

    def complaint(self, status: Optional[int]) -> Optional[str]:
        """None when ``status`` (None: no answer) is one this case allows, else what is wrong."""
        if status is None:
            return None if not self.answered else "no answer"
        if status >= 500:
            return f"answered {status}"
        if self.expect:
            return None if status in self.expect else f"answered {status}, not {sorted(self.expect)}"
        return None if 400 <= status < 500 else f"answered {status}, not a 4xx"


ANSWERED = tuple(range(400, 500)) + (200,)  # a request that is odd but valid may be taken


class CaseBuilder:
    """Collects cases; ``token`` goes on every state-changing request unless a case says otherwise."""

    def __init__(self, token: Optional[str]) -> None:
        self.token = token
        self.cases: List[Case] = []

    def add(self, kind: str, name: str, data: bytes, expect: Sequence[int] = (), *,
            answered: bool = True) -> None:
        self.cases.append(Case(kind, name, data, frozenset(expect), answered))

    def request(self, kind: str, name: str, method: bytes, path: bytes, body: bytes = b"",
                expect: Sequence[int] = (), *, headers: Sequence[Tuple[bytes, bytes]] = (),
                auth: bool = True, **kwargs: Any) -> None:
        data = http_request(method, path, body, headers=headers, token=self.token if auth else None, **kwargs)
        self.add(kind, name, data, expect)

    def upload(self, name: str, body: bytes, expect: Sequence[int] = (),
               ctype: bytes = b"multipart/form-data; boundary=hostileBoundary") -> None:
        self.request("upload", name, b"POST", b"/api/virtual-camera", body, expect,
                     headers=[(b"Content-Type", ctype)])


def flip_bits(data: bytes, rng: random.Random, n: int, start: int) -> bytes:
    """``data`` with ``n`` bits flipped at or after byte ``start``."""
    out = bytearray(data)
    for _ in range(n):
        i = rng.randrange(min(start, len(out) - 1), len(out))
        out[i] ^= 1 << rng.randrange(8)
    return bytes(out)
