"""From camera parameters to a register set the bitstream can run, or a clear refusal.

Every check a calibration must pass before it reaches the core lives here, so
the CLI, the daemon and the driver refuse the same things with the same
words: values that do not fit a register, a frame larger than the core, and a
calibration that needs more line-buffer rows than the bitstream has.
"""
from __future__ import annotations

from typing import List, Tuple, Union

from ..spec.rectify import RECTIFY_MAP, CameraParams, CameraRegs, CoreConfig, camera_registers
from .linebuffer import LineBufferFit, rows_needed


class CoreParamsError(ValueError):
    """A calibration or frame size the core cannot run; the message says what to change."""


class ParameterOutOfRange(CoreParamsError):
    pass


class FrameSizeError(CoreParamsError):
    pass


class LineBufferTooSmall(CoreParamsError):
    def __init__(self, fit: LineBufferFit, lb_rows: int) -> None:
        super().__init__(
            f"this calibration needs {fit.rows} line-buffer rows but the core buffers {lb_rows}: "
            "recalibrate with the cameras better aligned, use a lens with less distortion, "
            f"lower alpha, or load a bitstream built with at least {fit.rows} rows"
        )
        self.fit = fit
        self.lb_rows = lb_rows


def check_frame_size(width: int, height: int, max_width: int, max_height: int) -> None:
    if not (1 <= width <= max_width and 1 <= height <= max_height):
        raise FrameSizeError(
            f"a {width}x{height} frame does not fit the core (at most {max_width}x{max_height}): "
            "crop or scale the images"
        )


def registers(
    left: Union[CameraParams, CameraRegs], right: Union[CameraParams, CameraRegs], width: int, height: int
) -> Tuple[CameraRegs, CameraRegs]:
    """Both cameras' registers for this frame size.

    :class:`ParameterOutOfRange` says every value that does not fit.
    """
    problems: List[str] = []
    out: List[CameraRegs] = []
    for side, cam in (("left", left), ("right", right)):
        if isinstance(cam, CameraRegs):
            problems += [f"{side} {p}" for p in cam.problems()]
            out.append(cam)
            continue
        try:
            out.append(camera_registers(cam, width, height))
        except ValueError as exc:
            problems += [f"{side} {p}" for p in str(exc).split("; ")]
    if problems:
        raise ParameterOutOfRange(
            "the calibration does not fit the core's registers: " + "; ".join(problems)
            + "; check the calibration file"
        )
    return out[0], out[1]


def check_params(
    left: Union[CameraParams, CameraRegs], right: Union[CameraParams, CameraRegs], width: int, height: int
) -> None:
    registers(left, right, width, height)


def plan(
    left: Union[CameraParams, CameraRegs], right: Union[CameraParams, CameraRegs], width: int, height: int, *,
    lb_rows: int, max_width: int, max_height: int,
) -> "tuple[CoreConfig, LineBufferFit]":
    """The register set for this calibration and frame size, checked against the bitstream.

    Raises a :class:`CoreParamsError` subclass; nothing is written anywhere.
    """
    check_frame_size(width, height, max_width, max_height)
    lregs, rregs = registers(left, right, width, height)
    fit = rows_needed([lregs, rregs], width, height)
    if not fit.fits(lb_rows):
        raise LineBufferTooSmall(fit, lb_rows)
    delay_max = RECTIFY_MAP["LB_DELAY"].field("VALUE").max
    if fit.delay > delay_max:  # pragma: no cover - needs a frame taller than 65535 rows
        raise CoreParamsError(f"line-buffer delay {fit.delay} exceeds the register's {delay_max}")
    return CoreConfig(lregs, rregs, width, height, fit.delay), fit
