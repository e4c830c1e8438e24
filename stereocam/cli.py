"""The ``stereocam`` command.

Every failure a user can cause (bad files, sizes, calibrations) ends in one
line on stderr, ``stereocam <command>: error: ...``, and exit code 2: never a
traceback.

Logs go to stderr: ``time LEVEL logger: message``, or, when stderr is the
journal stream systemd names in ``$JOURNAL_STREAM`` (the service), each line
prefixed with its syslog priority (``<3>`` error, ``<4>`` warning, ``<6>``
info, ``<7>`` debug) and no time, which journald adds (:func:`setup_logging`).
"""
from __future__ import annotations

import argparse
import io
import logging
import os
import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Mapping, Optional, Sequence

from . import __version__

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

# Imports are in the functions that need them: `stereocam serve` on the board's A9 starts in seconds
# of imports, and its start-up notifier (main) runs before any of them (tests/cli/test_cli_start.py).

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
JOURNAL_FORMAT = "%(name)s: %(message)s"  # journald stamps the time and keeps the priority itself
_PRIORITIES = ((logging.CRITICAL, 2), (logging.ERROR, 3), (logging.WARNING, 4), (logging.INFO, 6))
ACCESS_LOGGER = "aiohttp.access"  # aiohttp logs every HTTP request there, at INFO


class UserError(Exception):
    """Something the user can fix; printed as one line, exit code 2."""


# -- logging ---------------------------------------------------------------------------------

def on_journal(env: Optional[Mapping[str, str]] = None, stream: Optional[IO[str]] = None) -> bool:
    """True when ``stream`` (default stderr) is the journal stream named by ``$JOURNAL_STREAM``.

    systemd sets ``JOURNAL_STREAM=DEVICE:INODE`` for a service whose output goes
    to the journal. A child whose stderr was redirected elsewhere (a test, a pipe)
    inherits the variable, so the pair must be the stream's own (sd_journal_stream_fd(3)).
    """
    dev, _, ino = (os.environ if env is None else env).get("JOURNAL_STREAM", "").partition(":")
    if not (dev.isdigit() and ino.isdigit()):
        return False
    try:
        st = os.fstat((stream if stream is not None else sys.stderr).fileno())
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


def syslog_priority(levelno: int) -> int:
    """The syslog priority of a logging level: 3 error, 4 warning, 6 info, 7 debug (2 critical)."""
    return next((p for floor, p in _PRIORITIES if levelno >= floor), 7)


class JournalFormatter(logging.Formatter):
    """``<N>logger: message`` on every line (a traceback's too), so ``journalctl -p err`` finds errors."""

    def __init__(self) -> None:
        super().__init__(JOURNAL_FORMAT)

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{syslog_priority(record.levelno)}>"
        return "\n".join(prefix + line for line in (super().format(record).splitlines() or [""]))


class _AccessAtDebug(logging.Filter):
    """aiohttp logs each request at INFO: make it DEBUG (a line per request wears the board's SD card)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


_ACCESS_AT_DEBUG = _AccessAtDebug()


def setup_logging(level: str = "info", *, env: Optional[Mapping[str, str]] = None,
                  stream: Optional[IO[str]] = None, secret: Optional[str] = None) -> bool:
    """Log at ``level`` (one of :data:`LOG_LEVELS`) to ``stream`` (stderr); may be called again.

    HTTP requests (aiohttp's access log) are logged at DEBUG: at any other level
    aiohttp does not even format them. ``secret`` (the daemon's access token, when set)
    never reaches a line, whichever logger writes it, and neither does any ``token=`` value
    (:class:`stereocam.server.http.security.TokenRedactor`). Like ``logging.basicConfig``,
    leaves a logging set up by someone else (pytest, a program embedding us) alone and
    returns False then.
    """
    root = logging.getLogger()
    ours = [h for h in root.handlers if getattr(h, "stereocam", False)]
    if len(ours) != len(root.handlers):
        return False
    for handler in ours:
        root.removeHandler(handler)
    out = stream if stream is not None else sys.stderr
    handler = logging.StreamHandler(out)
    handler.stereocam = True  # type: ignore[attr-defined]  # marks the handler this function owns
    handler.setFormatter(JournalFormatter() if on_journal(env, out) else logging.Formatter(LOG_FORMAT))
    if secret is not None:
        from .server.http.security import TokenRedactor

        handler.addFilter(TokenRedactor(secret))
    numeric = logging.getLevelName(level.upper())
    if not isinstance(numeric, int):
        from .server.http.settings import LOG_LEVELS

        raise UserError(f"log level {level!r} is not one of {', '.join(LOG_LEVELS)}")
    root.setLevel(numeric)
    root.addHandler(handler)
    logging.captureWarnings(True)  # Python's warnings as log lines too (a priority under journald)
    access = logging.getLogger(ACCESS_LOGGER)
    access.setLevel(logging.DEBUG if numeric <= logging.DEBUG else logging.WARNING)
    access.addFilter(_ACCESS_AT_DEBUG)  # filters are a set: adding twice keeps one
    return True


def _read_image(path: Path) -> np.ndarray:
    import cv2
    import numpy as np

    from .calibration.image_files import ImageTooLarge, decode_image_file

    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        image = decode_image_file(path, cv2.IMREAD_UNCHANGED)
    except ImageTooLarge as exc:
        raise UserError(str(exc)) from None
    if image is None:
        raise UserError(f"{path}: not a readable image (PNG, JPEG, BMP, TIFF, PGM/PPM)")
    if image.dtype != np.uint8:
        raise UserError(
            f"{path}: {image.dtype} pixels; the cameras and the core are 8-bit, convert the image first"
        )
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


def _parse_size(text: str) -> "tuple[int, int]":
    import re

    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not an image size WIDTHxHEIGHT, e.g. 752x480")
    return int(m.group(1)), int(m.group(2))


def _alpha(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(
            f"alpha is from 0 (only valid pixels) to 1 (all source pixels), not {text}"
        )
    return value


def _lb_rows(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"line-buffer rows must be at least 1, not {value}")
    from .overlays.spec.rectify import SIZE_BITS

    if value >= 1 << SIZE_BITS:  # no frame the core takes has that many rows; an RTL build would try them
        raise argparse.ArgumentTypeError(
            f"line-buffer rows must be below {1 << SIZE_BITS} (the core counts rows in {SIZE_BITS} bits), "
            f"not {value}")
    return value


def _add_lb_rows(parser: argparse.ArgumentParser, purpose: str) -> None:
    """``--lb-rows N``: the bitstream's line-buffer rows, which a calibration must fit (``purpose``:
    what the command does with them, for the help)."""
    from .overlays.spec.rectify import DEFAULT_LB_ROWS

    parser.add_argument("--lb-rows", type=_lb_rows, default=DEFAULT_LB_ROWS, metavar="N",
                        help=f"line-buffer rows of the bitstream to {purpose} (default {DEFAULT_LB_ROWS})")


def _add_calibration_output(parser: argparse.ArgumentParser, alpha_help: str) -> None:
    """What a command that writes a calibration takes: the rectification's ``--alpha`` (``alpha_help``),
    the ``--lb-rows`` it is checked against, and ``-o/--output FILE``."""
    parser.add_argument("--alpha", type=_alpha, default=0.0, metavar="A", help=alpha_help)
    _add_lb_rows(parser, "check against")
    parser.add_argument("-o", "--output", required=True, metavar="FILE",
                        help="the calibration file to write (YAML)")


def _output_file(path: str) -> Path:
    """Where a file will be written: its folder must exist (checked before any work)."""
    out = Path(path)
    if out.is_dir():
        raise UserError(
            f"{out} is a folder: give the calibration file's name, e.g. {out / 'calibration.yaml'}"
        )
    if not out.parent.is_dir():
        raise UserError(f"cannot write {out}: folder {out.parent} does not exist")
    return out


def cmd_rectify(args: argparse.Namespace) -> int:
    import numpy as np

    from .calibration.file import load_calibration
    from .calibration.pair_depth import rectify_with_model
    from .overlays.spec import pixel

    left, right = _read_image(Path(args.left)), _read_image(Path(args.right))
    if left.shape[:2] != right.shape[:2]:
        raise UserError(
            f"left is {left.shape[1]}x{left.shape[0]} but right is {right.shape[1]}x{right.shape[0]}: "
            "the pair must have the same size"
        )
    fitted = ""
    if args.fit == "exact" and args.size is None:
        h, w = left.shape[:2]
        cal = load_calibration(args.calibration, image_size=(w, h), lb_rows=args.lb_rows)
    else:
        # The frame size: --size, else the one the calibration records (checked against --size).
        cal = load_calibration(args.calibration, image_size=args.size, lb_rows=args.lb_rows)
        cw, ch = cal.image_size
        left, right, fitted = _fit_pair(left, right, (int(cw), int(ch)), args.fit)
        h, w = left.shape[:2]
    gray = left.ndim == 2 and right.ndim == 2
    fit = cal.fit
    if args.core == "rtl":
        frame = pixel.pack(pixel.rgby(left), pixel.rgby(right))
        out = _rectify_rtl(cal, frame, lb_rows=args.lb_rows, gray=gray)
    else:
        out = rectify_with_model(cal, left, right, args.lb_rows)
    outdir = Path(args.output)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create {outdir}: {exc.strerror}") from None
    for name, rgby in (("left", out[..., pixel.LEFT]), ("right", out[..., pixel.RIGHT])):
        plane = rgby[..., pixel.Y] if gray else np.ascontiguousarray(rgby[..., :3])
        _write_png(outdir / f"{name}.png", plane)
    print(
        f"wrote {outdir / 'left.png'} and {outdir / 'right.png'} ({w}x{h} {'gray' if gray else 'colour'}, "
        f"{'the RTL under Verilator' if args.core == 'rtl' else 'the model'}); "
        f"line buffer: {fit.rows} of {args.lb_rows} rows needed (delay {fit.delay})"
    )
    if fitted:
        print(fitted)
    return 0


def _fit_pair(left: np.ndarray, right: np.ndarray, size: "tuple[int, int]", mode: str
              ) -> "tuple[np.ndarray, np.ndarray, str]":
    """The pair made ``size`` by ``--fit`` (the daemon's upload fit) and a line saying what was done."""
    from .server.http.uploads import UploadError, fit_pair

    try:
        left, right, done = fit_pair(left, right, size, mode)
    except UploadError as exc:
        if mode == "exact":
            h, w = left.shape[:2]
            raise UserError(f"the images are {w}x{h}, the calibration is for {size[0]}x{size[1]}: "
                            f"give --fit crop, pad or scale to make them fit") from None
        raise UserError(exc.message) from None
    if not done.changed:
        return left, right, ""
    sw, sh = done.source
    return left, right, f"fit {mode}: {sw}x{sh} -> {size[0]}x{size[1]}: {done.text()}"


RTL_TIMEOUT_S = 60.0  # register waits against the simulated core (a frame takes a large part of a second)


def _rectify_rtl(cal: "Any", frame: np.ndarray, *, lb_rows: int, gray: bool) -> np.ndarray:
    """``frame`` through the core's RTL under Verilator, programmed by the driver as on the board.

    The RTL is built (once, then cached) with the default build's parameters, widened to
    the image and with ``lb_rows`` rows, the bitstream the model stands for.
    """
    import dataclasses

    from .drivers.mmio import DriverError
    from .drivers.rectify import RectifyCore
    from .overlays.model.core_params import CoreParamsError
    from .overlays.rtl.core import RtlCore, RtlError
    from .overlays.rtl.toolchain import ToolMissing
    from .overlays.spec.rectify import DEFAULT_BUILD, SIZE_BITS

    h, w = frame.shape[:2]
    if max(w, h) >= 1 << SIZE_BITS:
        raise UserError(f"{w}x{h}: the core's RTL takes images below {1 << SIZE_BITS} pixels each way")
    build = dataclasses.replace(DEFAULT_BUILD, name="rectify", max_width=max(DEFAULT_BUILD.max_width, w),
                                max_height=max(DEFAULT_BUILD.max_height, h), lb_rows=lb_rows)
    try:
        with RtlCore(build) as core:
            driver = RectifyCore(core, timeout=RTL_TIMEOUT_S)
            driver.program(cal.left, cal.right, w, h)
            driver.set_mode(enable=True, gray=gray)
            out = core.process(frame)
    except ToolMissing as exc:
        raise UserError(f"--core rtl: {exc}") from None
    except (RtlError, DriverError, CoreParamsError) as exc:
        raise UserError(f"--core rtl: {exc}") from None
    if out is None or out.shape != frame.shape:
        raise UserError(f"--core rtl: the RTL core returned {'no frame' if out is None else out.shape} "
                        f"for a {w}x{h} frame; see STATUS and FLAGS (a bug in the RTL)")
    return out


def cmd_disparity(args: argparse.Namespace) -> int:

    from .calibration import pair_depth
    from .calibration.file import load_calibration
    from .overlays.model.stereo import check_pair
    from .overlays.spec.stereo import DEFAULT_PARAMS

    given = {name: getattr(args, name) for name in _stereo_param_names() if getattr(args, name) is not None}
    params = DEFAULT_PARAMS.with_values(**given)
    problems = params.problems()
    if problems:
        raise UserError("; ".join(problems))
    left_path, right_path = Path(args.left), Path(args.right)
    left, right = _read_image(left_path), _read_image(right_path)
    if left.shape[:2] != right.shape[:2]:
        raise UserError(
            f"left is {left.shape[1]}x{left.shape[0]} but right is {right.shape[1]}x{right.shape[0]}: "
            "the pair must have the same size"
        )
    outdir = Path(args.output)
    if outdir.exists() and not outdir.is_dir():
        raise UserError(f"{outdir} is a file: give a folder for the outputs")
    cloud_of = None
    try:
        if args.calibration is not None:
            h, w = left.shape[:2]
            cal = load_calibration(args.calibration, image_size=(w, h), lb_rows=args.lb_rows)
            unit_m = pair_depth.metres_per_unit(args.units or cal.units)
            comment = f"stereocam disparity of {left_path.name} and {right_path.name}, calibration {cal.id}"
            cloud_of = (cal.rect.Q, unit_m, comment)
            stereo = pair_depth.from_calibration(cal, left, right, args.lb_rows)
        else:
            stereo = pair_depth.from_rectified(left, right)
        if args.core == "rtl":
            check_pair(stereo.left, stereo.right, params)  # refused before a build or a simulation
            result = _stereo_rtl(stereo, params)
        else:
            result = pair_depth.run(stereo, params)
        files = pair_depth.depth_files(result, params.num_disp, cloud_of, stereo.colour)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    try:
        pair_depth.write_all(outdir, files)
    except OSError as exc:
        raise UserError(f"cannot write into {outdir}: {exc.strerror or exc}") from None
    valid = int(result.valid.sum())
    h, w = result.disp.shape
    what = "the stereo core's RTL under Verilator" if args.core == "rtl" else "the stereo core's model"
    print(f"wrote {', '.join(str(outdir / n) for n in files)} ({w}x{h}, {valid} of {w * h} pixels with a "
          f"disparity, {what}{'' if cloud_of is None else ', points in metres'})")
    return 0


def _stereo_rtl(stereo: "Any", params: "Any") -> "Any":
    """The pair through the stereo core's RTL (the ``depth`` build) under Verilator: built once, cached."""
    from .calibration import pair_depth
    from .overlays.rtl.stereo_core import RtlError, RtlStereo
    from .overlays.rtl.toolchain import ToolMissing

    try:
        with RtlStereo() as core:
            return pair_depth.run(stereo, params, core.compute)
    except ToolMissing as exc:
        raise UserError(f"--core rtl: {exc}") from None
    except RtlError as exc:
        raise UserError(f"--core rtl: {exc}") from None


def _stereo_param_names() -> "list[str]":
    import dataclasses

    from .overlays.spec.stereo import StereoParams

    return [f.name for f in dataclasses.fields(StereoParams)]


def _add_stereo_params(parser: argparse.ArgumentParser) -> None:
    """``--num-disp N`` ... ``--[no-]median``: the stereo core's registers, each defaulting to the core's."""
    from .overlays.spec.stereo import DEFAULT_PARAMS

    for name in _stereo_param_names():
        default = getattr(DEFAULT_PARAMS, name)
        flag = "--" + name.replace("_", "-")
        if isinstance(default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None,
                                help=f"the core's {name.upper()} switch "
                                     f"(default {'on' if default else 'off'})")
        else:
            parser.add_argument(flag, type=int, default=None, metavar="N",
                                help=f"the core's {name.upper()} register (default {default})")


class _ProgressDisplay:
    """``calibrate_pairs``' progress on stderr: one updating line on a terminal, else a line per step."""

    LABELS = {
        "detect": "finding corners", "calibrate": "calibrating", "check": "measuring rows through the core",
    }

    def __init__(self, *, quiet: bool) -> None:
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.last = ""

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.quiet:
            return
        text = f"{self.LABELS.get(stage, stage)} {done}/{total}"
        if self.tty:
            sys.stderr.write("\r" + text.ljust(len(self.last)))
            sys.stderr.flush()
        elif stage == "detect" and done < total or done == 0:
            sys.stderr.write(text + "\n")
        self.last = text

    def finish(self) -> None:
        if self.tty and self.last and not self.quiet:
            sys.stderr.write("\r" + " " * len(self.last) + "\r")
            sys.stderr.flush()
        self.last = ""


def cmd_calibrate(args: argparse.Namespace) -> int:
    import json

    from .calibration.calibrate import Pattern, calibrate_pairs, find_pairs, pairs_from_files

    pattern = Pattern.parse(args.pattern, args.square)
    if args.left is not None or args.right is not None:
        if args.inputs:
            raise UserError("give capture folders or --left/--right image files, not both")
        pairs = pairs_from_files(args.left or [], args.right or [])
    else:
        pairs = find_pairs(args.inputs)
    out = _output_file(args.output)
    progress = _ProgressDisplay(quiet=args.quiet or False)
    source = (f"stereocam calibrate: {len(pairs)} pairs, pattern {pattern}, "
              f"squares {pattern.square * 1000:g} mm, alpha {args.alpha:g}")
    try:
        report = calibrate_pairs(pairs, pattern, alpha=args.alpha, lb_rows=args.lb_rows, progress=progress,
                                 source=source)
    finally:
        progress.finish()
    written = None
    if report.fits:
        report.calibration.save(out)
        written = out
    if args.json:
        print(json.dumps({**report.to_dict(), "output": str(written) if written else None}))
    else:
        print("\n".join(report.lines()))
        if written:
            print(f"wrote {written} (calibration {report.calibration.id})")
    report.check()  # a calibration the bitstream cannot run: exit 2, nothing written
    return 0


def cmd_calibration_import(args: argparse.Namespace) -> int:
    from .calibration.file import load_calibration

    out = _output_file(args.output)
    sources = [p for src in args.sources for p in src.split(",") if p]
    cal = load_calibration(sources, image_size=args.size, alpha=args.alpha, lb_rows=args.lb_rows,
                           derive_missing=True)
    cal.save(out)
    print(f"wrote {out}: {cal.summary()}")
    return 0


def cmd_calibration_export(args: argparse.Namespace) -> int:
    from .calibration.file import load_calibration

    if args.opencv is None and args.ros is None:
        raise UserError("say what to write: --opencv OUTDIR, --ros OUTDIR or both")
    cal = load_calibration(args.calibration, lb_rows=None)
    if args.opencv is not None:
        intr, extr = cal.to_opencv(Path(args.opencv))
        print(f"wrote {intr} and {extr} (calibration {cal.id})")
    if args.ros is not None:
        left, right = cal.to_ros(Path(args.ros))
        note = "" if cal.ros_units_known else (
            f"; note: the calibration's lengths are in {cal.units!r}, not a known unit, so T is written as "
            "it is, while ROS expects metres")
        print(f"wrote {left} and {right} (ROS camera_info, calibration {cal.id}){note}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from .bench.rectify import run_bench

    return run_bench(args)


def cmd_serve(args: argparse.Namespace) -> int:
    from .overlays.backend import BackendError
    from .server.http.app import ServeError, run
    from .server.http.settings import Settings, SettingsError
    from .server.http.systemd import LATE_DRIVER_EXIT, LateDriver
    from .server.stores.captures import CaptureError

    try:
        config = Settings.load(args.config, host=args.host, port=args.port, backend=args.backend,
                             captures=args.captures, state_dir=args.state_dir, calibration=args.calibration,
                             bitstream=args.bitstream, source=args.source, fps=args.fps,
                             core_build=args.core_build, core=args.core, rtl_dir=args.rtl_dir,
                             cpu_budget=args.cpu_budget, allow_fault_injection=args.allow_fault_injection,
                             board=args.board, log_level=_cli_log_level(args))
        setup_logging(config.log_level, secret=config.access_token)
        config = config.replace(board=_check_board(config.board))
        return run(config)
    except (SettingsError, ServeError, BackendError) as exc:
        raise UserError(str(exc)) from None
    except CaptureError as exc:
        raise UserError(exc.message) from None
    except LateDriver as exc:  # not the user's to fix: the unit restarts on this status
        _error_line(args, exc)
        return LATE_DRIVER_EXIT


def _cli_log_level(args: argparse.Namespace) -> Optional[str]:
    """``--log-level`` (of ``stereocam`` or of the command; the command's wins), ``-v``: debug, else None."""
    level = getattr(args, "log_level", None)
    return str(level) if level is not None else ("debug" if getattr(args, "verbose", False) else None)


def _check_board(board: Optional[str]) -> str:
    """The board profile the daemon will use (``--board``, ``/etc/stereocam/board.yaml``, the packaged one),
    read and checked now, so a wrong one stops ``serve`` with one line before the fabric is touched."""
    from .board.profile import ProfileError, find_profile, load_profile

    try:
        return load_profile(find_profile(board)).source  # the daemon logs it when it loads it again
    except ProfileError as exc:
        raise UserError(str(exc)) from None


def cmd_install_service(args: argparse.Namespace) -> int:
    from .server.http.systemd import ServiceError, install_service, unit_text

    if args.print:
        print(unit_text(venv=args.venv, config=Path(args.config)), end="")
        return 0
    try:
        done = install_service(unit_dir=Path(args.unit_dir), config=Path(args.config), venv=args.venv,
                               host=args.host, port=args.port, captures=args.captures,
                               start=not args.no_start)
    except ServiceError as exc:
        raise UserError(str(exc)) from None
    for line in done:
        print(line)
    return 0


def _add_server_commands(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    from .overlays.backend import CORES
    from .overlays.spec.rectify import BUILDS, DEFAULT_BUILD
    from .server.http import systemd
    from .server.http.settings import BACKENDS, DEFAULT_CAPTURES, LOG_LEVELS

    s = sub.add_parser(
        "serve", help="run the daemon (web page, streams, API)",
        description="Serve live raw and rectified video, captures, the virtual camera and verify over HTTP. "
                    "Off the board it runs on the emulated fabric. Options override the --config file.")
    s.add_argument("--host",
                   help="address to listen on (default 127.0.0.1; the board's service uses 0.0.0.0)")
    s.add_argument("--port", type=int, help="port (default 8080)")
    s.add_argument("--backend", choices=BACKENDS,
                   help=f"fabric: {', '.join(BACKENDS)}; default {BACKENDS[0]} "
                        "(pynq on the board, else emulated)")
    s.add_argument("--config", metavar="FILE",
                   help="settings file (YAML or JSON; keys as in stereocam/server/http/settings.py)")
    s.add_argument("--captures", metavar="DIR", help=f"capture folder (default {DEFAULT_CAPTURES})")
    s.add_argument("--state-dir", metavar="DIR",
                   help="where the page's calibration.yaml and calibration-pairs/ live "
                        "(default: the capture folder's parent)")
    s.add_argument("--calibration", metavar="CAL",
                   help="a stereocam calibration.yaml or any format 'calibration import' reads "
                        "(default on the emulated fabric: the synthetic rig's known calibration)")
    s.add_argument("--bitstream", metavar="FILE", help="the overlay's .bit (pynq backend)")
    s.add_argument("--source", metavar="SRC",
                   help="emulated cameras: synthetic (default), checkerboard (a 9x6 board of 25 mm "
                        "squares held up in a new pose every 1.5 s, to try calibration) or a folder of "
                        "recorded pairs to replay")
    s.add_argument("--fps", type=float, help="emulated camera frame rate (default 60)")
    s.add_argument("--core-build", choices=tuple(BUILDS),
                   help="the rectify core build the emulated fabric has "
                        f"(default {DEFAULT_BUILD.name}; see RECTIFY_CORE.md)")
    s.add_argument("--core", choices=CORES,
                   help="what computes the emulated fabric's rectify core: model (default, numpy) or rtl "
                        "(the core's Verilog under Verilator; slower, a few frames per second)")
    s.add_argument("--rtl-dir", metavar="DIR",
                   help="with --core rtl: build this copy of stereocam/overlays/rtl instead "
                        "(e.g. one being changed)")
    s.add_argument("--cpu-budget", metavar="CORES", type=float,
                   help="cores the daemon may spend on the views; over it, views get lower frame rates "
                        "(default: 1 on the board, all of the machine's off it)")
    s.add_argument("--board", metavar="FILE",
                   help="the board profile (I2C bus and addresses, sensors; default "
                        "/etc/stereocam/board.yaml if it exists, else the packaged zynq-stereo.yaml)")
    s.add_argument("--log-level", choices=LOG_LEVELS, default=argparse.SUPPRESS,
                   help="debug, info (default), warning or error; debug also logs every HTTP request")
    s.add_argument("--allow-fault-injection", action="store_true", default=None,
                   help="emulated fabric only, for testing: /api/faults stalls cameras, faults DMA channels, "
                        "hangs resets, silences sensors, makes the mux refuse (see stereocam/server/API.md)")
    s.set_defaults(func=cmd_serve)

    i = sub.add_parser(
        "install-service", help="install and start the systemd service (on the board, as root)",
        description=f"Write {systemd.DEFAULT_UNIT_DIR / systemd.UNIT_NAME} (Type=notify, watchdog, "
                    f"restart on failure, in the PYNQ venv) and, if missing, the settings file; "
                    f"then systemctl "
                    f"daemon-reload and enable --now.")
    i.add_argument("--port", type=int, default=systemd.DEFAULT_PORT,
                   help=f"port for a new settings file (default {systemd.DEFAULT_PORT}; not 80 or 9090)")
    i.add_argument("--host", default="0.0.0.0", help="address for a new settings file (default 0.0.0.0)")
    i.add_argument("--captures", default=systemd.DEFAULT_CAPTURES, metavar="DIR",
                   help=f"capture folder for a new settings file (default {systemd.DEFAULT_CAPTURES})")
    i.add_argument("--config", default=str(systemd.DEFAULT_CONFIG), metavar="FILE",
                   help=f"the settings file the service reads (default {systemd.DEFAULT_CONFIG})")
    i.add_argument("--venv", default=systemd.PYNQ_VENV, metavar="DIR",
                   help=f"the Python environment stereocam is installed in (default {systemd.PYNQ_VENV})")
    i.add_argument("--unit-dir", default=str(systemd.DEFAULT_UNIT_DIR), metavar="DIR",
                   help=f"where the unit goes (default {systemd.DEFAULT_UNIT_DIR})")
    i.add_argument("--no-start", action="store_true", help="write the files only; no systemctl")
    i.add_argument("--print", action="store_true", help="print the unit and do nothing else")
    i.set_defaults(func=cmd_install_service)


def build_parser(command: Optional[str] = None) -> argparse.ArgumentParser:
    """The ``stereocam`` parser; with ``command`` (what :func:`command_of` found in the arguments) another
    command's suites and actions (``bench ...``, ``hw ...``, modules that take a while to import on the
    board's A9) are left out, since they will not be parsed: ``serve`` imports only what it serves with."""
    from .overlays.backend import CORES
    from .server.http.settings import LOG_LEVELS
    from .server.http.uploads import FIT_MODES

    parser = argparse.ArgumentParser(
        prog="stereocam", description="Zynq stereo camera: rectify core, fabric and daemon"
    )
    parser.add_argument("--version", action="version", version=f"stereocam {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages (--log-level debug)")
    parser.add_argument("--log-level", choices=LOG_LEVELS, default=None,
                        help="debug, info (default), warning or error; debug also logs every HTTP request")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("rectify", help="run the core (its model, or its RTL) on an image pair",
                       description="Rectify and undistort LEFT and RIGHT with the core's bit-exact model "
                                   "(or, with --core rtl, its Verilog under Verilator).")
    p.add_argument("--calibration", required=True, metavar="CAL",
                   help="a stereocam calibration.yaml, a MATLAB stereoParameters .mat, or two files "
                        "separated by a comma: intrinsics.yml,extrinsics.yml (OpenCV stereo_calib) or "
                        "left.yaml,right.yaml (ROS camera_info)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                   help="writes OUTDIR/left.png and OUTDIR/right.png")
    _add_lb_rows(p, "model")
    p.add_argument("--core", choices=CORES, default=CORES[0],
                   help="model (default): the bit-exact numpy model; rtl: the core's Verilog under Verilator "
                        "(built once and cached; the output is the same byte for byte)")
    p.add_argument("--fit", choices=FIT_MODES, default=FIT_MODES[0],
                   help="a pair of another size than the calibration's: exact (default) refuses it; crop "
                        "and pad centre it, cutting what sticks out and padding what is missing with black; "
                        "scale resizes it keeping the aspect ratio (INTER_AREA when shrinking) and pads the "
                        "rest (letterbox); the same fit the daemon's upload takes (fit=...)")
    p.add_argument("--size", type=_parse_size, metavar="WxH",
                   help="the image size the calibration is for, when its files do not record it "
                        "(OpenCV stereo_calib's); with --fit the pair is made this size")
    p.add_argument("left")
    p.add_argument("right")
    p.set_defaults(func=cmd_rectify)

    d = sub.add_parser("disparity", help="run the stereo core (its model or RTL) on an image pair",
                       description="Compute the stereo core's disparity of LEFT and RIGHT with its bit-exact "
                                   "model: OUTDIR/disparity.png (16-bit, disparity x 16, 65535 where "
                                   "invalid), "
                                   "disparity_colour.png, confidence.png and, with --calibration, cloud.ply "
                                   "(binary PLY, metres, coloured by the rectified left image).")
    given = d.add_mutually_exclusive_group(required=True)
    given.add_argument("--calibration", metavar="CAL",
                       help="rectify the pair first as the rectify core does (any format rectify takes)")
    given.add_argument("--rectified", action="store_true",
                       help="the pair is already rectified (up to the stereo core's width)")
    d.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="the folder to write into")
    from .calibration.pair_depth import CORES as STEREO_CORES

    d.add_argument("--core", choices=STEREO_CORES, default=STEREO_CORES[0],
                   help="model (default): the stereo core's bit-exact model; rtl: its Verilog (the depth "
                        "build) under Verilator, built once and cached (tens of seconds), then seconds a "
                        "752x480 pair: the same files")
    d.add_argument("--units", metavar="UNIT",
                   help="the unit of the calibration's T where its file does not say it (m, cm, mm, in)")
    _add_lb_rows(d, "rectify with")
    _add_stereo_params(d)
    d.add_argument("left")
    d.add_argument("right")
    d.set_defaults(func=cmd_disparity)

    c = sub.add_parser(
        "calibrate", help="calibrate the stereo rig from checkerboard pairs",
        description="Find the checkerboard in each pair, calibrate both cameras with the core's lens model "
                    "(k1, k2, p1, p2), rectify, and write the calibration with the core's register values. "
                    "Inputs are capture folders (raw_left.png, raw_right.png), folders of captures or of "
                    "left*/right* images, or image files given with --left ... --right ....",
    )
    c.add_argument("--pattern", required=True, metavar="COLSxROWS",
                   help="inner corners of the checkerboard, e.g. 9x6 (a board of 10x7 squares)")
    c.add_argument("--square", required=True, metavar="LENGTH",
                   help="side of one square with its unit, e.g. 25mm")
    _add_calibration_output(c, "0 keeps only valid pixels (default), 1 keeps every source pixel")
    c.add_argument("--json", action="store_true", help="print the report as one JSON object on stdout")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress display on stderr")
    c.add_argument("--left", nargs="+", metavar="FILE", help="left images, paired in order with --right")
    c.add_argument("--right", nargs="+", metavar="FILE", help="right images, paired in order with --left")
    c.add_argument("inputs", nargs="*", metavar="INPUT", help="capture folders or folders of captures")
    c.set_defaults(func=cmd_calibrate)

    k = sub.add_parser("calibration", help="import or export calibration files",
                       description="Convert calibrations between stereocam's YAML and other tools' formats.")
    ksub = k.add_subparsers(dest="action", metavar="ACTION")
    ksub.required = True
    imp = ksub.add_parser(
        "import", help="write a stereocam calibration from another tool's files",
        description="SRC is a MATLAB stereoParameters .mat (saved with toStruct), two OpenCV "
                    "stereo_calib files (intrinsics.yml extrinsics.yml), two ROS camera_info files "
                    "(left.yaml right.yaml), or a stereocam calibration whose core and id were deleted "
                    "after an edit.",
    )
    imp.add_argument("sources", nargs="+", metavar="SRC")
    imp.add_argument("--size", type=_parse_size, metavar="WxH",
                     help="image size, for files that do not record it (OpenCV stereo_calib)")
    _add_calibration_output(imp,
                            "rectification alpha for sources without a rectification (MATLAB); default 0")
    imp.set_defaults(func=cmd_calibration_import)
    exp = ksub.add_parser("export", help="write another tool's files from a stereocam calibration",
                          description="Write OpenCV stereo_calib files intrinsics.yml and extrinsics.yml, "
                                      "ROS camera_info files left.yaml and right.yaml, or both.")
    exp.add_argument("calibration", metavar="CALIBRATION", help="a stereocam calibration file")
    exp.add_argument("--opencv", metavar="OUTDIR",
                     help="write OUTDIR/intrinsics.yml and OUTDIR/extrinsics.yml")
    exp.add_argument("--ros", metavar="OUTDIR",
                     help="write OUTDIR/left.yaml and OUTDIR/right.yaml (ROS camera_info, plumb_bob, "
                          "lengths in metres), which camera_info_manager and 'calibration import' read")
    exp.set_defaults(func=cmd_calibration_export)

    b = sub.add_parser("bench", help="measure model, fabric and OpenCV throughput",
                       description="Benchmarks on 752x480 stereo pairs, all 8 channels, one process.")
    b.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    b.add_argument("--seconds", type=float, default=2.0, help="time per measurement (default 2)")
    b.add_argument("--serve", action="store_true",
                   help='also run the daemon at 60 fps with 1 and 20 MJPEG clients (key "serve")')
    b.add_argument("--serve-seconds", type=float, default=5.0, metavar="S",
                   help="time per client count of --serve (default 5)")
    b.set_defaults(func=cmd_bench)
    if command in (None, "bench"):
        from .bench.a9.run import add_parser as add_a9_parser  # stereocam bench a9
        from .bench.budget import add_budget_parser  # stereocam bench budget
        from .bench.depth import add_depth_parser  # stereocam bench depth
        from .bench.recording import add_recording_parser  # stereocam bench recording
        from .bench.robustness import add_robustness_parser  # stereocam bench robustness

        suites = b.add_subparsers(dest="suite", metavar="SUITE")
        add_robustness_parser(suites)
        add_budget_parser(suites)
        add_recording_parser(suites)
        add_depth_parser(suites)
        add_a9_parser(suites)

    # stereocam hw ...: the rectify core's RTL (stereocam/overlays/rtl/); each action adds itself to hsub.
    h = sub.add_parser("hw", help="the rectify core's HDL: synthesis and a timing estimate with yosys",
                       description="Tools for the rectify core's Verilog in stereocam/overlays/rtl/.")
    hsub = h.add_subparsers(dest="action", metavar="ACTION")
    hsub.required = True
    if command in (None, "hw"):
        from .overlays.rtl.synth import add_synth_parser
        from .overlays.rtl.timing import add_timing_parser

        add_synth_parser(hsub)
        add_timing_parser(hsub)

    _add_server_commands(sub)
    return parser


def command_of(argv: Sequence[str]) -> Optional[str]:
    """The command ``argv`` (without the program name) runs, read before any parser is built; None: unsure."""
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg == "--log-level":
            skip = True
        elif not arg.startswith("-"):
            return arg
        elif arg in ("-h", "--help", "--version"):
            return None
    return None


def _user_errors() -> "tuple[type[BaseException], ...]":
    """The exceptions that end a command with one line and exit code 2. Imported when one is raised:
    the modules are the calibration tools', which ``serve`` does not import to start."""
    from .calibration.calibrate import CalibrationError
    from .calibration.formats import CalibrationFileError
    from .overlays.model.core_params import CoreParamsError

    return UserError, CalibrationFileError, CalibrationError, CoreParamsError


def _error_line(args: argparse.Namespace, exc: BaseException) -> None:
    command = args.command if args.command != "calibration" else f"calibration {args.action}"
    priority = "<3>" if on_journal() else ""  # under systemd: an error for `journalctl -p err`
    print(f"{priority}stereocam {command}: error: {exc}", file=sys.stderr)


def main(argv: Optional[Sequence[str]] = None) -> int:
    arguments = list(argv) if argv is not None else sys.argv[1:]
    command = command_of(arguments)
    if command == "serve":
        # First, before the imports (seconds on the board's A9): under systemd, keep extending the
        # unit's start timeout and say what is loading until the daemon is READY (systemd.py).
        from .server.http import systemd

        systemd.loading("Python modules")
    parser = build_parser(command)
    args = parser.parse_args(arguments)
    setup_logging(_cli_log_level(args) or "info")
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        if not isinstance(exc, _user_errors()):
            raise
        _error_line(args, exc)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
