"""A small synchronous Python client of the stereocam daemon's HTTP API (for scripts and notebooks).

``Client("http://board:8080", token=None)``: frames of any view as numpy arrays, captures and
recordings, the source, the virtual camera, the camera controls and Verify. It speaks HTTP only
(never imports the daemon), so it runs on a laptop as well as on the board.
"""
from __future__ import annotations

from .client import Client, ClientError, Frame, FrameStream, Recording, decode_image, encode_png

__all__ = ["Client", "ClientError", "Frame", "FrameStream", "Recording", "decode_image", "encode_png"]
