"""A ``pynq.Device`` over the emulated fabric, so pynq's own drivers run on our emulated IP.

A test double for the board path: it joins pynq and the emulator, which the
package keeps apart. It also proves the emulation against independent code:
``pynq.lib.video.dma.AxiVDMA`` (with its inline magic numbers and busy-waits)
starts, feeds and reads our :class:`~stereocam.overlays.emulated.vdma.EmulatedVDMA`
exactly as it would the real IP on the board.

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
* Bitstreams: ``pynq.Overlay(bit, device=dev)`` works as on the board's
  ``EmbeddedDevice``: the ``.hwh`` beside the ``.bit`` is read by pynq's own
  metadata parser, and a download records the loaded bitstream in pynq's
  PL state file (``global_pl_state_.json``: name, hash, timestamp), here
  under ``state_dir``, with the FPGA manager's ``state``/``flags`` beside it
  (``state_dir/fpga0``), before "programming". The emulated IP answer only
  while the PL holds a design with them at their addresses: after a
  download of another design every register access raises :class:`BusHang`
  (on the board it would hang the AXI bus), and :attr:`bus_accesses` counts
  every attempt, so tests can show that nothing touched the bus.

pynq is imported lazily, by :func:`stereocam.overlays.pynq.import_pynq`:
importing this module needs no pynq; using :class:`EmulatedPynqDevice` or
:func:`pynq_axi_vdma` does.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

import numpy as np

from stereocam.overlays.emulated.ddr import EmulatedDDR
from stereocam.overlays.emulated.regblock import EmulationError, RegisterBlock
from stereocam.overlays.emulated.vdma import EmulatedVDMA
from stereocam.overlays.pynq import import_pynq
from stereocam.overlays.spec.overlay import INSTANCES
from stereocam.overlays.spec.vdma import VLNV as VDMA_VLNV

__all__ = ["BusHang", "EmulatedInterrupt", "InterruptTimeout", "loopback_tick", "pynq_axi_vdma"]
# ``EmulatedPynqDevice`` is also public; it is made on first access (module ``__getattr__``).


class InterruptTimeout(EmulationError):
    """An interrupt never rose although the frame clock advanced ``max_ticks`` frames."""


class BusHang(EmulationError):
    """A register access while the PL holds no design with IP at that address (the board's bus would hang)."""


STATE_FILE = "global_pl_state_.json"  # pynq's PL state file for device tag "" (pynq.pl_server.global_state)


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
        (``description["device"]``, ``MMIO(..., device=dev)``, ``target=``,
        ``Overlay(..., device=dev)``).

        ``programmed``: the blocks answer from the start, as if their design
        had been loaded before (False: a fresh board, where every access is
        a :class:`BusHang` until a design with them is downloaded).
        ``state_dir``: where pynq's PL state file and the FPGA manager's
        files are kept (None: downloads record nothing).
        """

        def __init__(
            self,
            ddr: EmulatedDDR,
            blocks: Mapping[str, Tuple[int, RegisterBlock]],
            *,
            tick: Callable[[], None],
            max_ticks: int = 64,
            tag: str = "stereocam-emulated",
            programmed: bool = True,
            state_dir: Optional[Path] = None,
        ) -> None:
            super().__init__(tag)
            self.name = tag
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
            self.state_dir = state_dir
            self.mapped = programmed  # the blocks answer at their addresses
            self.pl_design: Optional[str] = "loaded before" if programmed else None
            self.bus_accesses = 0
            self.downloads: List[str] = []
            if state_dir is not None:
                self.fpga_manager.mkdir(parents=True, exist_ok=True)
                self._fpga_manager_files("operating" if programmed else "unknown")

        @property
        def default_memory(self) -> EmulatedDDR:
            return self.ddr

        def allocate(self, shape: Any, dtype: Any, **kwargs: Any) -> Any:
            return self.ddr.allocate(shape, dtype, **kwargs)

        # -- REGISTER_RW capability ---------------------------------------------------------
        def _block_at(self, address: int, length: int) -> Tuple[RegisterBlock, int]:
            self.bus_accesses += 1
            if not self.mapped:
                raise BusHang(f"register access at {address:#010x} while the PL holds "
                              f"{self.pl_design or 'no design'}: on the board this hangs the AXI bus")
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
            if name in INSTANCES:
                desc["type"] = INSTANCES[name][-1]
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

        # -- bitstreams ------------------------------------------------------------------------
        @property
        def state_file(self) -> Path:
            """pynq's record of the loaded bitstream (on the board: in pynq's ``pl_server`` folder)."""
            if self.state_dir is None:
                raise EmulationError("this emulated device keeps no PL state (give state_dir)")
            return self.state_dir / STATE_FILE

        @property
        def fpga_manager(self) -> Path:
            """The stand-in for ``/sys/class/fpga_manager/fpga0`` (files ``state`` and ``flags``)."""
            if self.state_dir is None:
                raise EmulationError("this emulated device has no FPGA manager (give state_dir)")
            return self.state_dir / "fpga0"

        def _fpga_manager_files(self, state: str) -> None:
            (self.fpga_manager / "state").write_text(state + "\n")
            (self.fpga_manager / "flags").write_text("0\n")

        def recorded(self) -> Optional[Dict[str, Any]]:
            """pynq's PL state as the file holds it (None: no file)."""
            if self.state_dir is None or not self.state_file.is_file():
                return None
            record: Dict[str, Any] = json.loads(self.state_file.read_text())
            return record

        def get_bitfile_metadata(self, bitfile_name: str, partial: bool = False) -> Any:
            """pynq's parser of the ``.hwh`` beside ``bitfile_name``, as ``EmbeddedDevice`` makes it.

            The emulated PS has no clock registers: the parser's ``clock_dict``
            is emptied, so ``Overlay.download`` sets no PL clock. As on the
            board, the metadata of the bitstream pynq records as loaded is
            marked as cached, and its download records nothing new.
            """
            # the very parser EmbeddedDevice makes for a .bit with a .hwh (pynqmetadata's, imported there)
            from pynq.pl_server.embedded_device import Metadata, RuntimeMetadataParser, bit2bin
            from pynq.pl_server.global_state import bitstream_hash

            bit = Path(bitfile_name)
            hwh = bit.with_suffix(".hwh")
            if not hwh.is_file():
                raise EmulationError(f"no {hwh.name} beside {bit}: pynq reads the overlay's IP from it")
            parser = RuntimeMetadataParser(Metadata(input=str(hwh)))
            parser.bin_data = bit2bin(bit.read_bytes())  # pynq's .bit header check
            parser.clock_dict = {}
            recorded = self.recorded()
            if recorded is not None and recorded.get("bitfile_hash") == bitstream_hash(str(bit)):
                parser._from_cache = True
            return parser

        def download(self, bitstream: Any, parser: Any = None) -> None:
            """Program the emulated PL with ``bitstream`` as ``EmbeddedDevice.download`` programs the board's.

            Clears a PL state left from before a power cycle (FPGA manager
            state ``unknown``), records the bitstream in pynq's PL state
            (unless pynq took its metadata from the cache: the same bitstream
            as recorded, even if that record was just cleared), then
            maps the blocks if the design has each of them, by name, type
            and address, and unmaps them otherwise. The blocks keep their
            register state across a download (the board's would reset).
            """
            from pynq.pl_server.global_state import GlobalState, bitstream_hash

            if parser is None:
                parser = self.get_bitfile_metadata(bitstream.bitfile_name)
            if self.state_dir is not None and (self.fpga_manager / "state").read_text().startswith("unknown"):
                self.state_file.unlink(missing_ok=True)  # pynq's cold-boot check (in EmbeddedDevice.shutdown)
            if self.state_dir is not None and not getattr(parser, "_from_cache", False):
                t = datetime.datetime.now()  # pynq's timestamp format
                stamp = f"{t.year}/{t.month}/{t.day} {t.hour}:{t.minute}:{t.second} +{t.microsecond}"
                state = GlobalState(bitfile_name=str(bitstream.bitfile_name), active_name=self.name,
                                    timestamp=stamp, bitfile_hash=bitstream_hash(str(bitstream.bitfile_name)))
                dump = getattr(state, "model_dump_json", None) or state.json  # pydantic 2 or 1
                self.state_file.write_text(dump())
            design = parser.ip_dict
            self.mapped = all(
                name in design and design[name].get("phys_addr") == base
                and (name not in INSTANCES or design[name].get("type") in INSTANCES[name])
                for name, (base, _) in self.blocks.items()
            )
            self.pl_design = str(bitstream.bitfile_name)
            self.downloads.append(self.pl_design)
            if self.state_dir is not None:
                self._fpga_manager_files("operating")
            super().post_download(bitstream, parser, self.name)

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
