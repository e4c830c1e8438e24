"""What the rectify and stereo cores' drivers do alike, over the registers every stereocam core has
in the same place (``overlays/spec/core_common.py``): CONTROL.APPLY, FLAGS.CONFIG_ERROR."""
from __future__ import annotations

from .mmio import DriverError, Registers, UnsupportedIP


def check_identity(regs: Registers, core_id: int, version: int, kind: str) -> None:
    """Refuse (:class:`UnsupportedIP`) a window whose ID is not ``core_id`` or whose major version differs.

    ``kind`` names the core in the message ("rectify", "stereo"), as its register map's name does.
    """
    ident = regs.read("ID")
    if ident != core_id:
        raise UnsupportedIP(
            f"{kind}: ID register reads {ident:#010x}, expected {core_id:#010x}: "
            f"the overlay does not contain a stereocam {kind} core at this address")
    major = regs.field("VERSION", "MAJOR")
    if major != version >> 16:
        raise UnsupportedIP(
            f"{kind}: core version {major}.x is not supported by this driver ({version >> 16}.x): "
            "load a bitstream built from this version of stereocam")


def wait_applied(regs: Registers, refused: str, *, timeout: float) -> None:
    """Wait (at most ``timeout`` s) for APPLY to clear, then raise ``ConfigRefused`` if CONFIG_ERROR is set.

    ``refused`` is the message: which core, and what stays active.
    """
    control = regs.map["CONTROL"]
    regs.wait("CONTROL", lambda v: not control.get(v, "APPLY"),
              expected="cleared APPLY (no frame start reached the core?)", timeout=timeout)
    if regs.field("FLAGS", "CONFIG_ERROR"):
        raise ConfigRefused(refused)


def clear_flags(regs: Registers, *names: str) -> None:
    """Write-1-to-clear the named sticky FLAGS (all of them if none named)."""
    reg = regs.map["FLAGS"]
    names = names or tuple(f.name for f in reg.fields)
    regs.write("FLAGS", reg.encode(**{n: 1 for n in names}))


class ConfigRefused(DriverError):
    """The core raised CONFIG_ERROR on APPLY: it kept its previous parameters."""
