"""The ``stereocam`` command.

Every failure a user can cause (bad files, sizes, calibrations) ends in one
line on stderr, ``stereocam <command>: error: ...``, and exit code 2: never a
traceback.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np


class UserError(Exception):
    """Something the user can fix; printed as one line, exit code 2."""


def _read_image(path: Path) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise UserError(f"{path}: no such file")
    data = np.fromfile(str(path), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise UserError(f"{path}: not a readable image (PNG, JPEG, BMP, TIFF, PGM/PPM)")
    if image.dtype != np.uint8:
        raise UserError(f"{path}: {image.dtype} pixels; the cameras and the core are 8-bit, convert the image first")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image


def _write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    out = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", out)
    if not ok:
        raise UserError(f"{path}: PNG encoding failed")
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_bytes(buf.tobytes())
        tmp.replace(path)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror}") from None


def cmd_rectify(args: argparse.Namespace) -> int:
    from .calibration_io import load_opencv_pair, parse_calibration_arg
    from .overlays.model.config import plan
    from .overlays.model.fast import RectifyModel
    from .overlays.model.result import CoreOptions
    from .overlays.spec import pixel
    from .overlays.spec.rectify import DEFAULT_MAX_HEIGHT, DEFAULT_MAX_WIDTH
    from .stereo import core_cameras

    left, right = _read_image(Path(args.left)), _read_image(Path(args.right))
    if left.shape[:2] != right.shape[:2]:
        raise UserError(
            f"left is {left.shape[1]}x{left.shape[0]} but right is {right.shape[1]}x{right.shape[0]}: "
            "the pair must have the same size"
        )
    gray = left.ndim == 2 and right.ndim == 2
    h, w = left.shape[:2]
    intr, extr = parse_calibration_arg(args.calibration)
    model, rect = load_opencv_pair(intr, extr, (w, h))
    try:
        cam_l, cam_r = core_cameras(model, rect)
    except np.linalg.LinAlgError:
        raise UserError(f"{extr}: the rectification (P1*R1 or P2*R2) is singular; the file is not a valid calibration") from None
    config, fit = plan(cam_l, cam_r, w, h, lb_rows=args.lb_rows, max_width=DEFAULT_MAX_WIDTH, max_height=DEFAULT_MAX_HEIGHT)
    options = CoreOptions(lb_rows=args.lb_rows, lb_delay=config.lb_delay, gray=gray)
    frame = pixel.pack(pixel.rgby(left), pixel.rgby(right))
    out = RectifyModel(cam_l, cam_r, w, h, options).process(frame).frame
    outdir = Path(args.output)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create {outdir}: {exc.strerror}") from None
    for name, rgby in (("left", out[..., pixel.LEFT]), ("right", out[..., pixel.RIGHT])):
        _write_png(outdir / f"{name}.png", rgby[..., pixel.Y] if gray else np.ascontiguousarray(rgby[..., :3]))
    print(
        f"wrote {outdir / 'left.png'} and {outdir / 'right.png'} ({w}x{h} {'gray' if gray else 'colour'}); "
        f"line buffer: {fit.rows} of {args.lb_rows} rows needed (delay {fit.delay})"
    )
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run_bench

    return run_bench(args)


def build_parser() -> argparse.ArgumentParser:
    from .overlays.spec.rectify import DEFAULT_LB_ROWS

    parser = argparse.ArgumentParser(prog="stereocam", description="Zynq stereo camera: rectify core, fabric and daemon")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("rectify", help="run the core's model on an image pair",
                       description="Rectify and undistort LEFT and RIGHT with the core's bit-exact model.")
    p.add_argument("--calibration", required=True, metavar="CAL",
                   help="OpenCV stereo_calib files: intrinsics.yml,extrinsics.yml")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="writes OUTDIR/left.png and OUTDIR/right.png")
    p.add_argument("--lb-rows", type=int, default=DEFAULT_LB_ROWS, metavar="N",
                   help=f"line-buffer rows of the bitstream to model (default {DEFAULT_LB_ROWS})")
    p.add_argument("left")
    p.add_argument("right")
    p.set_defaults(func=cmd_rectify)

    b = sub.add_parser("bench", help="measure model, fabric and OpenCV throughput",
                       description="Benchmarks on 752x480 stereo pairs, all 8 channels, one process.")
    b.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    b.add_argument("--seconds", type=float, default=2.0, help="time per measurement (default 2)")
    b.set_defaults(func=cmd_bench)
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    from .calibration_io import CalibrationFileError
    from .overlays.model.config import ConfigError

    parser = build_parser()
    args = parser.parse_args(list(argv) if argv is not None else None)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args))
    except (UserError, CalibrationFileError, ConfigError) as exc:
        print(f"stereocam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
