"""The 64-bit pixel of the fabric's AXI4-Stream, and of every frame buffer in DDR.

One beat (and one 8-byte word in memory, little-endian) carries the same pixel
position of both synchronised cameras:

    bits  7:0   left  R        byte 0
    bits 15:8   left  G        byte 1
    bits 23:16  left  B        byte 2
    bits 31:24  left  gray (Y) byte 3
    bits 39:32  right R        byte 4
    bits 47:40  right G        byte 5
    bits 55:48  right B        byte 6
    bits 63:56  right gray (Y) byte 7

A frame in memory is therefore a ``(height, width, 8)`` uint8 array (row
stride a multiple of 8 bytes), and ``frame[..., 0:4]`` / ``frame[..., 4:8]``
are the left and right camera's RGBY pixels. Gray is
``(77 R + 150 G + 29 B + 128) >> 8`` (BT.601 in 8-bit fixed point), computed
by the demosaic stage.
"""
from __future__ import annotations

import numpy as np

BYTES_PER_PIXEL = 8
CHANNELS = ("L_R", "L_G", "L_B", "L_Y", "R_R", "R_G", "R_B", "R_Y")
LEFT = slice(0, 4)
RIGHT = slice(4, 8)
R, G, B, Y = 0, 1, 2, 3  # index inside one camera's 4 channels
GRAY_WEIGHTS = (77, 150, 29)  # sum 256


def gray_of(rgb: np.ndarray) -> np.ndarray:
    """8-bit gray of an ``(..., 3)`` uint8 RGB array, exactly as the demosaic stage computes it."""
    r = rgb[..., 0].astype(np.uint16)
    g = rgb[..., 1].astype(np.uint16)
    b = rgb[..., 2].astype(np.uint16)
    return ((GRAY_WEIGHTS[0] * r + GRAY_WEIGHTS[1] * g + GRAY_WEIGHTS[2] * b + 128) >> 8).astype(np.uint8)


def rgby(image: np.ndarray) -> np.ndarray:
    """An ``(H, W, 4)`` RGBY camera image from gray ``(H, W)`` or RGB ``(H, W, 3)`` uint8.

    Gray input fills R, G and B with the gray value, so a gray camera's
    pixels look the same through either path.
    """
    if image.dtype != np.uint8:
        raise TypeError(f"camera images are 8-bit, got {image.dtype}")
    if image.ndim == 2:
        return np.repeat(image[..., None], 4, axis=2)
    if image.ndim == 3 and image.shape[2] == 3:
        return np.concatenate([image, gray_of(image)[..., None]], axis=2)
    raise ValueError(f"expected an (H, W) gray or (H, W, 3) RGB image, got shape {image.shape}")


def pack(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Interleave two ``(H, W, 4)`` RGBY images into one ``(H, W, 8)`` stream frame."""
    if left.shape != right.shape or left.ndim != 3 or left.shape[2] != 4:
        raise ValueError(f"left {left.shape} and right {right.shape} must both be (H, W, 4)")
    return np.concatenate([left, right], axis=2)


def unpack(frame: np.ndarray) -> "tuple[np.ndarray, np.ndarray]":
    """Split an ``(H, W, 8)`` stream frame into left and right ``(H, W, 4)`` RGBY views."""
    if frame.ndim != 3 or frame.shape[2] != BYTES_PER_PIXEL:
        raise ValueError(f"a stream frame is (H, W, 8), got {frame.shape}")
    return frame[..., LEFT], frame[..., RIGHT]
