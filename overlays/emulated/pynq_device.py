"""A ``pynq.Device`` over the emulated fabric, so pynq's own drivers run on our emulated IP.

This proves the emulation against independent code: ``pynq.lib.video.dma.AxiVDMA``
(with its inline magic numbers and busy-waits) starts, feeds and reads our
:class:`~stereocam.overlays.emulated.vdma.EmulatedVDMA` exactly as it would
the real IP on the board.

* Register access: the device has pynq's ``REGISTER_RW`` capability, so a
  ``pynq.MMIO`` on it calls :meth:`read_registers`/:meth:`write_registers`,
  which route by physical address to the register block mapped there.
* Memory: ``default_memory`` is the :class:`EmulatedDDR`, so
  ``pynq.allocate(shape, dtype, target=device.default_memory)`` and pynq's
  frame caches allocate :class:`EmulatedBuffer` arrays.
* Interrupts: :meth:`interrupt` gives objects with pynq's ``async wait()``;
  each wait advances the emulated frame clock (the ``tick`` callable) until
  the IP's interrupt line is high, at most ``max_ticks`` frames, then raises
  :class:`InterruptTimeout` instead of hanging.

pynq is imported lazily, here only: importing this module needs no pynq;
using :class:`EmulatedPynqDevice` or :func:`pynq_axi_vdma` does. pynq's
import-time warnings off the board (``pkg_resources`` deprecation, "does
not support the CPU Architecture") are silenced for that import only.
"""

from __future__ import annotations

import warnings
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

import numpy as np

from ..spec.vdma import VLNV as VDMA_VLNV
from .ddr import EmulatedDDR
from .regblock import EmulationError, RegisterBlock
from .vdma import EmulatedVDMA

__all__ = ["EmulatedInterrupt", "InterruptTimeout", "loopback_tick", "pynq_axi_vdma", "import_pynq"]
# ``EmulatedPynqDevice`` is also public; it is made on first access (module ``__getattr__``).


class InterruptTimeout(EmulationError):
    """An interrupt never rose although the frame clock advanced ``max_ticks`` frames."""


def import_pynq() -> Any:
    """Import and return the ``pynq`` package (raises ImportError where it is not installed)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="pkg_resources is deprecated", category=DeprecationWarning)
        warnings.filterwarnings(
            "ignore", message="Pynq does not support the CPU Architecture", category=ResourceWarning
        )
        import pynq
        import pynq.lib.video.dma  # noqa: F401  (the driver under test)
        import pynq.pl_server.device  # noqa: F401
    return pynq


class EmulatedInterrupt:
    """pynq ``Interrupt`` look-alike: ``await wait()`` runs the frame clock until ``line()`` is high."""

    def __init__(self, name: str, tick: Callable[[], None], line: Callable[[], bool], max_ticks: int) -> None:
        self.name = name
        self._tick = tick
        self._line = line
        self.max_ticks = max_ticks
        self.waits = 0

    async def wait(self) -> None:
        self.waits += 1
        for _ in range(self.max_ticks):
            self._tick()
            if self._line():
                return
        raise InterruptTimeout(f"interrupt {self.name} stayed low for {self.max_ticks} emulated frames")


def loopback_tick(
    vdma: EmulatedVDMA, source: Optional[Callable[[], np.ndarray]] = None
) -> Callable[[], None]:
    """A frame clock for one VDMA: each tick its MM2S output (or ``source()``) goes into its S2MM."""

    def tick() -> None:
        frame = vdma.mm2s_fetch()
        if frame is None and source is not None:
            frame = source()
        if frame is not None:
            vdma.s2mm_accept(frame)

    return tick


_classes: Dict[str, type] = {}


def _device_class() -> type:
    cls = _classes.get("EmulatedPynqDevice")
    if cls is not None:
        return cls
    Device = import_pynq().pl_server.device.Device

    class EmulatedPynqDevice(Device):  # type: ignore[misc, valid-type]
        """``pynq.Device`` whose registers are emulated blocks and whose memory is an EmulatedDDR.

        ``blocks`` maps an IP name to ``(physical base address, block)``;
        each block occupies its register map's size. ``tick`` advances the
        emulated fabric by one frame (see :func:`loopback_tick`). Not
        registered with pynq's device probing: pass it explicitly
        (``description["device"]``, ``MMIO(..., device=dev)``, ``target=``).
        """

        def __init__(
            self,
            ddr: EmulatedDDR,
            blocks: Mapping[str, Tuple[int, RegisterBlock]],
            *,
            tick: Callable[[], None],
            max_ticks: int = 64,
            tag: str = "stereocam-emulated",
        ) -> None:
            super().__init__(tag)
            self.capabilities = {"REGISTER_RW": True, "MEMORY_MAPPED": False, "CALLABLE": False}
            self.ddr = ddr
            self.tick = tick
            self.max_ticks = max_ticks
            self.blocks = dict(blocks)
            self._windows: List[Tuple[int, int, str, RegisterBlock]] = sorted(
                (base, block.map.size, name, block) for name, (base, block) in self.blocks.items()
            )
            for (b0, s0, n0, _), (b1, _, n1, _) in zip(self._windows, self._windows[1:], strict=False):
                if b0 + s0 > b1:
                    raise ValueError(f"register windows of {n0} and {n1} overlap")
            self.ip_dict = {name: self.ip_description(name) for name in self.blocks}
            self.mem_dict: Dict[str, Any] = {}
            self.gpio_dict: Dict[str, Any] = {}
            self.interrupt_pins: Dict[str, Any] = {}
            self.interrupt_controllers: Dict[str, Any] = {}
            self.hierarchy_dict: Dict[str, Any] = {}

        @property
        def default_memory(self) -> EmulatedDDR:
            return self.ddr

        def allocate(self, shape: Any, dtype: Any, **kwargs: Any) -> Any:
            return self.ddr.allocate(shape, dtype, **kwargs)

        # -- REGISTER_RW capability ---------------------------------------------------------
        def _block_at(self, address: int, length: int) -> Tuple[RegisterBlock, int]:
            for base, size, _, block in self._windows:
                if base <= address and address + length <= base + size:
                    return block, address - base
            raise EmulationError(f"no emulated IP at {address:#010x} ({length} bytes)")

        def read_registers(self, address: int, length: int) -> bytes:
            if address % 4 or length % 4 or length <= 0:
                raise EmulationError(
                    f"register read of {length} bytes at {address:#x}: whole aligned words only"
                )
            block, offset = self._block_at(address, length)
            words = [block.read(offset + 4 * i) for i in range(length // 4)]
            return np.array(words, dtype="<u4").tobytes()

        def write_registers(self, address: int, data: bytes) -> None:
            if address % 4 or len(data) % 4 or not data:
                raise EmulationError(
                    f"register write of {len(data)} bytes at {address:#x}: whole aligned words only"
                )
            block, offset = self._block_at(address, len(data))
            for i, word in enumerate(np.frombuffer(bytes(data), dtype="<u4")):
                block.write(offset + 4 * i, int(word))

        # -- IP descriptions and interrupts ------------------------------------------------
        def ip_description(self, name: str) -> Dict[str, Any]:
            """The ``description`` dict pynq drivers take (what ``Overlay.ip_dict`` would hold)."""
            base, block = self.blocks[name]
            desc: Dict[str, Any] = {
                "phys_addr": base,
                "addr_range": block.map.size,
                "fullpath": name,
                "device": self,
                "type": "",
                "parameters": {},
                "state": None,
            }
            if isinstance(block, EmulatedVDMA):
                desc["type"] = VDMA_VLNV[-1]
                desc["parameters"] = {
                    "C_INCLUDE_S2MM": "1",
                    "C_INCLUDE_MM2S": "1",
                    "C_NUM_FSTORES": str(block.num_fstores),
                    "C_M_AXI_S2MM_ADDR_WIDTH": "32",
                    "C_M_AXI_MM2S_ADDR_WIDTH": "32",
                }
            return desc

        def interrupt(self, name: str, line: Callable[[], bool]) -> EmulatedInterrupt:
            return EmulatedInterrupt(name, self.tick, line, self.max_ticks)

    _classes["EmulatedPynqDevice"] = EmulatedPynqDevice
    return EmulatedPynqDevice


def pynq_axi_vdma(device: Any, name: str) -> Any:
    """pynq's own ``AxiVDMA`` driver bound to the emulated VDMA ``name`` of ``device``.

    ``DefaultIP`` would build real ``pynq.Interrupt`` objects (which need a
    board); instead the instance gets :class:`EmulatedInterrupt` objects
    for ``s2mm_introut``/``mm2s_introut`` before pynq's ``__init__`` runs.
    Everything else is pynq's code.
    """
    AxiVDMA = import_pynq().lib.video.dma.AxiVDMA
    block = device.blocks[name][1]
    if not isinstance(block, EmulatedVDMA):
        raise TypeError(f"{name} is a {type(block).__name__}, not an EmulatedVDMA")
    vdma = AxiVDMA.__new__(AxiVDMA)
    vdma.s2mm_introut = device.interrupt(f"{name}/s2mm_introut", lambda: block.interrupt("S2MM"))
    vdma.mm2s_introut = device.interrupt(f"{name}/mm2s_introut", lambda: block.interrupt("MM2S"))
    vdma.__init__(device.ip_description(name))
    return vdma


def __getattr__(name: str) -> Any:
    """``EmulatedPynqDevice`` is built (and pynq imported) on first access."""
    if name == "EmulatedPynqDevice":
        return _device_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
