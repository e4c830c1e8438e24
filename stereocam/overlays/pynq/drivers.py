"""Our drivers as pynq drivers: ``pynq.Overlay("stereocam.bit").rectify`` is a :class:`RectifyCore`.

pynq binds a driver to an IP through ``DefaultIP`` subclasses: the metaclass
(``pynq.overlay.RegisterIP``) records each class under every VLNV in its
``bindto`` list, and an overlay built afterwards gives its IP of that type
to the class (``Overlay.__getattr__`` -> ``_IPMap`` -> ``driver(description)``).
The registry is a plain dict, so the class registered last wins: pynq's own
``AxiVDMA`` and ``StreamSwitch`` bind to the same VLNVs as our VDMA and
switch. This module imports ``pynq.lib`` (where those are defined) before
defining its classes, so in a process that imports it, ours are the ones
pynq picks, for every overlay of that process: load pynq's base overlay
(whose HDMI hierarchy needs ``AxiVDMA``) in another process.
:class:`~.overlay.StereocamOverlay` does not depend on that order: it
binds these classes to its instances by name.

Each class *is* our driver (a subclass of it) on the ``pynq.MMIO`` that
``DefaultIP`` opens, sized from the ``.hwh`` (``description["parameters"]``):
``C_NUM_FSTORES`` and the address widths for a VDMA, ``NUM_SI`` for the
switch, and, for the rectify core, ``MAX_WIDTH``/``MAX_HEIGHT``/``LB_ROWS``/
``COLOUR`` cross-checked against the registers that report them. A mismatch
raises :class:`~stereocam.drivers.mmio.UnsupportedIP` (not pynq's
``UnsupportedConfiguration``, which pynq turns into a warning and a bare
``DefaultIP``).

Imported only where pynq is installed (the board, the board-like test env).
"""
from __future__ import annotations

import importlib
from typing import Any, Callable, Dict, List, Mapping, Optional, Protocol

import numpy as np

from ...drivers.mmio import Allocator, DriverError, RegisterWindow, UnsupportedIP
from ...drivers.rectify import RectifyCore
from ...drivers.stereo import StereoCore
from ...drivers.switch import AxisSwitch
from ...drivers.vdma import VDMA
from ..spec.axis_switch import NUM_INPUTS
from ..spec.overlay import SWITCH_VLNVS, VDMA_VLNVS
from ..spec.rectify import VLNV as RECTIFY_VLNV
from ..spec.stereo import VLNV as STEREO_VLNV
from . import import_pynq

__all__ = ["BusGuard", "FabricLost", "GuardedWindow", "PynqAxisSwitch", "PynqRectifyCore", "PynqVDMA",
           "pynq_allocator"]

pynq = import_pynq()
importlib.import_module("pynq.lib")  # pynq's drivers register first, so that ours (below) win the VLNVs
DefaultIP: Any = pynq.DefaultIP

DEFAULT_TIMEOUT = 1.0


class FabricLost(DriverError):
    """The fabric may no longer hold our IP (or the overlay was closed): no register is touched any more."""


class BusGuard(Protocol):
    """Asked before every register access; ``check`` raises :class:`FabricLost` to stop it."""

    def check(self) -> None: ...


class GuardedWindow:
    """A register window that calls ``guard.check()`` before each access (``window``: a ``pynq.MMIO``)."""

    def __init__(self, window: RegisterWindow, guard: BusGuard) -> None:
        self.window = window
        self.guard = guard

    def read(self, offset: int) -> int:
        self.guard.check()
        return int(self.window.read(offset))

    def write(self, offset: int, value: int) -> None:
        self.guard.check()
        self.window.write(offset, value)


def pynq_allocator(device: Any) -> Allocator:
    """``pynq.allocate`` in ``device``'s default memory (the DDR the VDMAs reach)."""

    def allocate(shape: Any, dtype: Any = np.uint8) -> Any:
        return pynq.allocate(shape, dtype, target=device.default_memory)

    return allocate


def _parameter(description: Mapping[str, Any], name: str) -> Optional[int]:
    """An integer parameter of the IP from the ``.hwh`` (``None`` where it is not recorded)."""
    value = description.get("parameters", {}).get(name)
    if value is None or value == "":
        return None
    try:
        return int(str(value), 0)
    except ValueError:
        raise UnsupportedIP(
            f"{description.get('fullpath', '?')}: parameter {name}={value!r} in the .hwh is not a number"
        ) from None


def _window(ip: Any, guard: Optional[BusGuard]) -> RegisterWindow:
    mmio: RegisterWindow = ip.mmio
    return mmio if guard is None else GuardedWindow(mmio, guard)


class PynqRectifyCore(RectifyCore, DefaultIP):
    """The rectify core bound by pynq; the ``.hwh`` build parameters must match what the core reports.

    ``guard`` (see :class:`BusGuard`) is asked before every register access;
    pynq passes only ``description`` (no guard, default timeout).
    """

    bindto: List[str] = [RECTIFY_VLNV]

    def __init__(self, description: Mapping[str, Any], *, guard: Optional[BusGuard] = None,
                 timeout: float = DEFAULT_TIMEOUT) -> None:
        DefaultIP.__init__(self, description)
        RectifyCore.__init__(self, _window(self, guard), timeout=timeout)
        name = description.get("fullpath", "rectify")
        reported: Dict[str, int] = {"MAX_WIDTH": self.max_width, "MAX_HEIGHT": self.max_height,
                                    "LB_ROWS": self.lb_rows, "COLOUR": int(self.colour)}
        wrong = [f"{param}={hwh} in the .hwh but {reg} in the core's register"
                 for param, reg in reported.items()
                 if (hwh := _parameter(description, param)) is not None and hwh != reg]
        if wrong:
            raise UnsupportedIP(
                f"{name}: {'; '.join(wrong)}: the .hwh beside the bitstream does not describe the core it "
                "holds; copy the .hwh that Vivado wrote with this bitstream"
            )


class PynqStereoCore(StereoCore, DefaultIP):
    """The stereo core bound by pynq (a ``depth`` bitstream's; see ``spec/overlay.py`` OPTIONAL_INSTANCES)."""

    bindto: List[str] = [STEREO_VLNV]

    def __init__(self, description: Mapping[str, Any], *, guard: Optional[BusGuard] = None,
                 timeout: float = DEFAULT_TIMEOUT) -> None:
        DefaultIP.__init__(self, description)
        StereoCore.__init__(self, _window(self, guard), timeout=timeout)


class PynqVDMA(VDMA, DefaultIP):
    """An AXI VDMA bound by pynq; frame stores and address width from the ``.hwh``.

    Frame buffers come from ``pynq.allocate`` in the device's default memory.
    """

    bindto: List[str] = list(VDMA_VLNVS)

    def __init__(self, description: Mapping[str, Any], *, guard: Optional[BusGuard] = None,
                 timeout: float = DEFAULT_TIMEOUT) -> None:
        DefaultIP.__init__(self, description)
        name = str(description.get("fullpath", "vdma"))
        fstores = _parameter(description, "C_NUM_FSTORES")
        if fstores is None:
            raise UnsupportedIP(f"{name}: the .hwh records no C_NUM_FSTORES; cannot size the frame stores")
        widths = [w for ch in ("S2MM", "MM2S")
                  if _parameter(description, f"C_INCLUDE_{ch}") != 0
                  and (w := _parameter(description, f"C_M_AXI_{ch}_ADDR_WIDTH")) is not None]
        VDMA.__init__(self, _window(self, guard), pynq_allocator(self.device), num_fstores=fstores, name=name,
                      timeout=timeout, addr_width=max(widths, default=32))


class PynqAxisSwitch(AxisSwitch, DefaultIP):
    """An AXI4-Stream switch bound by pynq; its inputs from ``NUM_SI`` in the ``.hwh``.

    Refuses a switch built without control-register routing (``ROUTING_MODE=0``
    has no ``MI_MUX`` registers to write).
    """

    bindto: List[str] = list(SWITCH_VLNVS)

    def __init__(self, description: Mapping[str, Any], *, guard: Optional[BusGuard] = None,
                 timeout: float = DEFAULT_TIMEOUT) -> None:
        DefaultIP.__init__(self, description)
        name = str(description.get("fullpath", "mux"))
        if _parameter(description, "ROUTING_MODE") == 0:
            raise UnsupportedIP(f"{name}: ROUTING_MODE=0 (TDEST routing) has no control registers to select "
                                "an input; build the switch with control register routing")
        inputs = _parameter(description, "NUM_SI")
        AxisSwitch.__init__(self, _window(self, guard), inputs=NUM_INPUTS if inputs is None else inputs,
                            name=name, timeout=timeout)


# instance name (stereocam/overlays/spec/overlay.py INSTANCES) -> the driver class StereocamOverlay binds to
# it
DRIVERS: Dict[str, Callable[..., Any]] = {
    "vdma_raw": PynqVDMA,
    "vdma_proc": PynqVDMA,
    "mux": PynqAxisSwitch,
    "rectify": PynqRectifyCore,
    "stereo": PynqStereoCore,  # optional instances: bound where the .hwh has them
    "vdma_depth": PynqVDMA,
}
