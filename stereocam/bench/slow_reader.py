"""A slow stream reader, and the daemon's record of how far the frames it was sent lagged."""
from __future__ import annotations

import asyncio
import socket
import time
from typing import Any, Dict, List

from .raw_http import STALL_TIMEOUT_S, RobustnessBenchError, first_line, get_json

FLOOR_LAG_PERIODS = 2.0


async def slow_reader(port: int, *, view: str = "rect_right", reads: int = 12, read_interval_s: float = 0.5,
                      rcvbuf: int = 4096) -> Dict[str, Any]:
    """One client reading ``/stream/<view>`` a part every ``read_interval_s`` through a ``rcvbuf``-byte
    receive buffer: the frames it read, their age on arrival, and the daemon's record of the
    client (``/api/status`` ``streams``) while it was still connected."""
    loop = asyncio.get_running_loop()
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.setblocking(False)
    await loop.sock_connect(sock, ("127.0.0.1", port))
    reader, writer = await asyncio.open_connection(sock=sock, limit=rcvbuf)
    frames: List[int] = []
    ages: List[float] = []
    try:
        writer.write(f"GET /stream/{view} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        await writer.drain()
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
        if not head.startswith(b"HTTP/1.1 200"):
            raise RobustnessBenchError(f"GET /stream/{view}: {first_line(head)!r}")
        for _ in range(reads):
            await asyncio.sleep(read_interval_s)  # the reader's pace: what makes it slow
            await asyncio.wait_for(reader.readuntil(b"--frame\r\n"), STALL_TIMEOUT_S)
            part = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), STALL_TIMEOUT_S)
            headers = dict(line.split(": ", 1) for line in part.decode().strip().split("\r\n"))
            ages.append(time.time() - float(headers["X-Timestamp"]))
            frames.append(int(headers["X-Frame-Number"]))
            await asyncio.wait_for(reader.readexactly(int(headers["Content-Length"]) + 2), STALL_TIMEOUT_S)
        status = await get_json(port, "/api/status")
    finally:
        writer.close()
    mine = [s for s in status.get("streams", []) if s.get("kind") == "mjpeg" and s.get("view") == view]
    if len(mine) != 1:
        raise RobustnessBenchError(f"/api/status lists {len(mine)} clients of /stream/{view}, "
                                   "not the slow reader alone")
    return {"view": view, "reads": reads, "read_interval_s": read_interval_s, "frames": frames,
            "read_age_max_s": round(max(ages), 3), "client": mine[0],
            "camera_fps": status["fps"].get("camera")}
