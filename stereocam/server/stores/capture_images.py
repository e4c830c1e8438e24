"""A capture's frames as PNG files: encoded losslessly, decoded bit for bit.

A frame is an ``(H, W, 4)`` RGBY view of the stream (or ``(H, W, 3)``
RGB, or ``(H, W)`` gray) and is stored losslessly as PNG:

- ``"color": "gray"``: R == G == B == Y at every pixel (a gray camera): an
  8-bit gray PNG.
- ``"color": "rgb"``: an RGB PNG. Y is not stored when it equals
  :func:`...overlays.spec.pixel.gray_of` of the RGB pixels, which is what the
  demosaic stage computes for raw frames. Otherwise (rectified frames: the
  core interpolates Y on its own) Y goes to a gray PNG ``<frame>_y.png``,
  named by ``"y_file"``, so every stored frame comes back bit for bit.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import cv2
import numpy as np

from ...calibration.image_files import (
    CAPTURE_FILES,
    RAW_FRAMES,
    ImageTooLarge,
    capture_file,
    check_image_header,
)
from ...overlays.spec import pixel
from .errors import Damaged, StoreError
from .files import MAX_IMAGE_FILE_BYTES, read_member

__all__ = ["FRAME_NAMES", "read_raw_pair", "encode_pixels", "CAPTURE_PNG", "FAST_PNG"]

FRAME_NAMES = RAW_FRAMES + ("rect_left", "rect_right")
CAPTURE_PNG = (cv2.IMWRITE_PNG_COMPRESSION, 3)
# Recordings: a camera's frames carry sensor noise, so deflate's string matching finds little in
# them; the Paeth filter with run-length matches only (deflate level 1) makes files as small or
# smaller at about a third of the CPU (API.md, "Recordings", has the figures). An OpenCV without
# the filter choice (before 4.11) lets libpng pick filters per row: the same size, a little slower.
FAST_PNG = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE) + (
    (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH) if hasattr(cv2, "IMWRITE_PNG_FILTER") else ())


def _png(name: str, image: np.ndarray, params: Sequence[int] = CAPTURE_PNG) -> bytes:
    if image.ndim == 3:  # RGB to OpenCV's BGR, in one copy
        image = image[..., 2::-1]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), list(params))
    if not ok:
        raise StoreError(f"cannot encode {name} as PNG (OpenCV refused it): nothing was stored")
    return buf.tobytes()


def _as_rgby(name: str, frame: Any) -> np.ndarray:
    a = np.asarray(frame)
    if a.dtype != np.uint8:
        raise TypeError(f"frame {name} must be uint8, got {a.dtype}")
    if a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3):
        a = pixel.rgby(a)
    elif not (a.ndim == 3 and a.shape[2] == 4):
        raise ValueError(f"frame {name} must be (H, W, 4) RGBY, (H, W, 3) RGB or (H, W) gray; got {a.shape}")
    h, w = a.shape[:2]
    if h == 0 or w == 0:
        raise ValueError(f"frame {name} is empty: {a.shape}")
    return a


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """``a == b`` everywhere; a colour frame most often differs in its first row already (cheap)."""
    return np.array_equal(a[:1], b[:1]) and np.array_equal(a, b)


def encode_pixels(name: str, frame: Any, params: Sequence[int] = CAPTURE_PNG
                  ) -> Tuple[str, bytes, Optional[bytes]]:
    """``(color, png, y_png)`` of one frame: gray or RGB PNG, and its Y plane's where it is needed.

    ``y_png`` is None unless Y differs from what gray or :func:`pixel.gray_of` of RGB gives back
    (see the module doc); ``params`` are OpenCV's PNG options (:data:`CAPTURE_PNG`, :data:`FAST_PNG`).
    Any of them reads back bit for bit. ``name`` names the frame in errors.
    """
    a = _as_rgby(name, frame)
    r, g, b, y = (a[..., i] for i in range(4))
    if _same(r, g) and _same(r, b) and _same(r, y):
        return "gray", _png(name, r, params), None
    rgb = a[..., :3]
    y_png = None if np.array_equal(y, pixel.gray_of(rgb)) else _png(f"{name}_y", np.ascontiguousarray(y),
                                                                     params)
    return "rgb", _png(name, rgb, params), y_png


def encode_frame(name: str, frame: Any) -> Tuple[Dict[str, Any], List[Tuple[str, bytes]]]:
    """The image entry of meta.json and the PNG files of one frame (see the module doc)."""
    a = _as_rgby(name, frame)
    h, w = a.shape[:2]
    color, png, y_png = encode_pixels(name, a)
    file, y_file = capture_file(name), capture_file(name, y_plane=True)
    entry: Dict[str, Any] = {"file": file, "width": int(w), "height": int(h), "color": color,
                             "y_file": None if y_png is None else y_file}
    files = [(file, png)]
    if y_png is not None:
        files.append((y_file, y_png))
    return entry, files


def encode_frames(frames: Mapping[str, np.ndarray]) -> Tuple[Dict[str, Any], List[Tuple[str, bytes]]]:
    """meta.json's ``images`` and the PNG files of a capture's :data:`FRAME_NAMES` frames.

    ``ValueError`` unless ``frames`` has exactly those keys and each pair's
    left and right frames have the same size.
    """
    missing = [n for n in FRAME_NAMES if n not in frames]
    extra = sorted(str(n) for n in frames if n not in FRAME_NAMES)
    if missing or extra:
        raise ValueError(
            f"frames must have exactly the keys {', '.join(FRAME_NAMES)}"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(extra)}" if extra else "")
        )
    images: Dict[str, Any] = {}
    files: List[Tuple[str, bytes]] = []
    for name in FRAME_NAMES:
        entry, pngs = encode_frame(name, frames[name])
        images[name] = entry
        files.extend(pngs)
    for a, b in (("raw_left", "raw_right"), ("rect_left", "rect_right")):
        sa = (images[a]["width"], images[a]["height"])
        sb = (images[b]["width"], images[b]["height"])
        if sa != sb:
            raise ValueError(
                f"frames {a} ({sa[0]}x{sa[1]}) and {b} ({sb[0]}x{sb[1]}) must have the same size"
            )
    return images, files


def _decode_png(data: bytes) -> Optional[np.ndarray]:
    if not data:
        return None
    try:
        check_image_header(data, "a capture's image")
    except ImageTooLarge:  # no capture of ours: treated as unreadable
        return None
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint8:
        return None
    if img.ndim == 3:
        if img.shape[2] == 3:
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        return None
    return img


def read_raw_pair(cid: str, folder: Path) -> Tuple[np.ndarray, np.ndarray]:
    """The raw left and right frames of the capture ``cid`` in ``folder``, as RGBY arrays.

    :class:`Damaged` if a raw image is missing or corrupt, or the two differ in size.
    """
    out = []
    for name in RAW_FRAMES:
        file, y_file = capture_file(name), capture_file(name, y_plane=True)
        try:
            data = read_member(folder, file, MAX_IMAGE_FILE_BYTES)
        except FileNotFoundError:
            raise Damaged(f"capture {cid} cannot be replayed: {file} is missing") from None
        except ValueError as exc:  # larger than any frame
            raise Damaged(f"capture {cid} cannot be replayed: {exc}") from None
        except OSError as exc:
            raise Damaged(
                f"capture {cid} cannot be replayed: {file} cannot be read ({exc.strerror or exc})"
            ) from exc
        image = _decode_png(data)
        if image is None:
            raise Damaged(
                f"capture {cid} cannot be replayed: {file} is not a valid 8-bit image"
            )
        frame = pixel.rgby(image)
        try:
            y_data: Optional[bytes] = read_member(folder, y_file, MAX_IMAGE_FILE_BYTES)
        except FileNotFoundError:
            y_data = None
        except ValueError as exc:
            raise Damaged(f"capture {cid} cannot be replayed: {exc}") from None
        except OSError as exc:
            raise Damaged(
                f"capture {cid} cannot be replayed: {y_file} cannot be read ({exc.strerror or exc})"
            ) from exc
        if y_data is not None:
            y = _decode_png(y_data)
            if y is None or y.shape != frame.shape[:2]:
                raise Damaged(
                    f"capture {cid} cannot be replayed: {y_file} is not a gray image of the "
                    f"frame's size"
                )
            frame[..., pixel.Y] = y
        out.append(frame)
    left, right = out
    if left.shape != right.shape:
        raise Damaged(
            f"capture {cid} cannot be replayed: {CAPTURE_FILES[0]} is {left.shape[1]}x{left.shape[0]} "
            f"but {CAPTURE_FILES[1]} is {right.shape[1]}x{right.shape[0]}"
        )
    return left, right
