"""pynq binds our drivers to the stereocam overlay, and one process owns the fabric.

Everything runs pynq's own code (``Overlay``, its ``.hwh`` parser, ``DefaultIP``,
``MMIO``, ``allocate``) on :class:`EmulatedPynqDevice`, a ``pynq.Device`` whose
PL is the emulated fabric and whose "programming" records pynq's PL state as
the board's ``EmbeddedDevice`` does. The overlay's ``.hwh`` is written by
:mod:`tests.pynq_hwh` from the block design the Vivado scripts build (run in the
stubbed Vivado of :mod:`tests.vivado_stub`); other designs from a list of IP.

Gating as in ``test_pynq_vdma.py`` (CI forbids skipped tests, so nothing here is
ever skipped): with ``STEREOCAM_TEST_ENV=board`` pynq must import; elsewhere the
tests exist only if pynq imports (but for the one that reads the ``.hwh`` alone).
"""
from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any, Iterator, List, Optional
from xml.etree import ElementTree

import numpy as np
import pytest

from stereocam.drivers.mmio import UnsupportedIP
from stereocam.drivers.rectify import RectifyCore
from stereocam.drivers.switch import AxisSwitch
from stereocam.drivers.vdma import VDMA
from stereocam.overlays.emulated.logic import EmulatedFabric
from stereocam.overlays.emulated.render import SyntheticRig
from stereocam.overlays.spec.axis_switch import LIVE, NUM_INPUTS, VIRTUAL
from stereocam.overlays.spec.overlay import (
    ADDRESS_MAP,
    DEPTH_VDMA,
    FABRIC_CLOCK_HZ,
    INSTANCES,
    INTERRUPTS,
    NUM_FSTORES,
    OPTIONAL_ADDRESS_MAP,
    OPTIONAL_INTERRUPTS,
    STEREO,
    VDMA_VLNVS,
    WINDOW_SIZE,
)
from stereocam.overlays.spec.rectify import CORE_ID, DEFAULT_BUILD, RECTIFY_MAP
from stereocam.overlays.spec.regs import Access
from stereocam.overlays.spec.stereo import STEREO_MAP

from .. import pynq_device as pd
from ..pynq_hwh import Ip, pynq_for_tests, rectify_parameters, stereocam_ips, write_overlay

pynq: Optional[Any] = pynq_for_tests()

W, H = 752, 480  # the core's WIDTH/HEIGHT at reset: frames pass in BYPASS without a calibration

# A second process that opens the overlay on its own emulated fabric with the same lock, says so, and waits.
OWNER = textwrap.dedent("""
    import sys
    from pathlib import Path
    from stereocam.overlays.emulated.logic import EmulatedFabric
    from tests import pynq_device as pd
    from stereocam.overlays.spec.overlay import ADDRESS_MAP
    from stereocam.overlays.pynq.overlay import PynqPLState, StereocamOverlay
    hw = EmulatedFabric(clock="stepped")
    windows = {{n: (ADDRESS_MAP[n], b) for n, b in hw.blocks.items()}}
    dev = pd.EmulatedPynqDevice(hw.ddr, windows, tick=hw.step, programmed=False, state_dir=Path({state!r}))
    ov = StereocamOverlay(Path({bit!r}), device=dev, lock=Path({lock!r}),
                          pl_state=PynqPLState(dev.state_file, fpga_manager=dev.fpga_manager))
    print("bound", flush=True)
    sys.stdin.readline()
    ov.close()
""")



@pytest.mark.parametrize("build", ["colour", "depth"])
def test_the_hwh_names_address_blocks_and_interrupts_as_the_design_does(tmp_path: Path, build: str) -> None:
    """What pynq reads but does not report (it lists interrupts only behind an AXI interrupt
    controller; this design wires the VDMAs to IRQ_F2P through an xlconcat). Runs without pynq too.
    The depth build adds the stereo core's window and vdma_depth's, and its interrupt last."""
    root = ElementTree.parse(write_overlay(tmp_path, build=build).with_suffix(".hwh")).getroot()
    ranges = {r.get("INSTANCE"): (r.get("ADDRESSBLOCK"), int(r.get("BASEVALUE"), 0))
              for r in root.iter("MEMRANGE") if r.get("MASTERBUSINTERFACE") == "M_AXI_GP0"}
    blocks = {"vdma_raw": "Reg", "vdma_proc": "Reg", "rectify": "reg0", "mux": "Reg"}
    addresses = dict(ADDRESS_MAP)
    if build == "depth":
        blocks.update({STEREO: "reg0", DEPTH_VDMA: "Reg"})
        addresses.update(OPTIONAL_ADDRESS_MAP)
    assert ranges == {name: (blocks[name], addresses[name]) for name in blocks}
    found = {m.get("INSTANCE"): [(b.get("INTERFACE"), b.get("NAME"), int(b.get("RANGE")))
                                 for b in m.iter("ADDRESSBLOCK")] for m in root.iter("MODULE")}
    sizes = {"rectify": RECTIFY_MAP.size, **({STEREO: STEREO_MAP.size} if build == "depth" else {})}
    assert {name: blocks for name, blocks in found.items() if blocks} == {
        name: [("s_axil", "reg0", size)] for name, size in sizes.items()}
    modules = {m.get("INSTANCE"): m for m in root.iter("MODULE")}
    irq = modules["processing_system7_0"].find("./PORTS/PORT[@NAME='IRQ_F2P']")
    assert irq is not None
    (source,) = irq.findall("./CONNECTIONS/CONNECTION")
    concat = modules[source.get("INSTANCE")]
    assert concat.get("MODTYPE") == "xlconcat" and source.get("PORT") == "dout"
    lines = []
    for i in range(int(concat.find("./PARAMETERS/PARAMETER[@NAME='NUM_PORTS']").get("VALUE"))):
        (driver,) = concat.findall(f"./PORTS/PORT[@NAME='In{i}']/CONNECTIONS/CONNECTION")
        lines.append((driver.get("INSTANCE"), driver.get("PORT")))
        port = modules[driver.get("INSTANCE")].find(f"./PORTS/PORT[@NAME='{driver.get('PORT')}']")
        assert port is not None and port.get("SIGIS") == "INTERRUPT"
    expected = INTERRUPTS + (OPTIONAL_INTERRUPTS if build == "depth" else ())
    assert tuple(lines) == expected
    assert int(irq.get("LEFT")) == len(expected) - 1


if pynq is not None:
    from stereocam.overlays.backend import BackendError
    from stereocam.overlays.pynq.drivers import (
        FabricLost,
        GuardedWindow,
        PynqAxisSwitch,
        PynqRectifyCore,
        PynqVDMA,
    )
    from stereocam.overlays.pynq.overlay import FabricBusy, FabricLock, PynqPLState, StereocamOverlay

    class Board:
        """An emulated board: the fabric, the pynq device over it (PL cold unless ``programmed``), files."""

        def __init__(self, tmp: Path, *, programmed: bool = False) -> None:
            self.tmp = tmp
            self.hw = EmulatedFabric(clock="stepped", source=SyntheticRig(size=(W, H), motion=False))
            blocks = {name: (ADDRESS_MAP[name], block) for name, block in self.hw.blocks.items()}
            self.dev = pd.EmulatedPynqDevice(self.hw.ddr, blocks, tick=self.hw.step, programmed=programmed,
                                             state_dir=tmp / "pl")
            self.bit = write_overlay(tmp / "overlays")
            self.lock = tmp / "run" / "fabric.lock"

        def pl_state(self) -> PynqPLState:
            return PynqPLState(self.dev.state_file, fpga_manager=self.dev.fpga_manager)

        def open(self, bit: Optional[Path] = None, **kwargs: Any) -> StereocamOverlay:
            """What the daemon does: StereocamOverlay on this board's device, lock and PL state."""
            return StereocamOverlay(bit or self.bit, device=self.dev, frame_size=(W, H), lock=self.lock,
                                    pl_state=self.pl_state(), **kwargs)

        def foreign(self, name: str = "base", ips: Optional[List[Ip]] = None) -> Path:
            """Another design (by default one with no IP where ours are)."""
            return write_overlay(self.tmp / name, name, ips or [])

        def close(self) -> None:
            self.hw.close()

    @pytest.fixture
    def board(tmp_path: Path) -> Iterator[Board]:
        b = Board(tmp_path)
        yield b
        b.close()

    def test_the_hwh_reads_as_the_spec_through_pynqs_parser(board: Board) -> None:
        ov = pynq.Overlay(str(board.bit), device=board.dev, download=False)
        assert set(ov.ip_dict) == set(INSTANCES) | {"processing_system7_0"}, "the addressable cells, no more"
        for name, vlnvs in INSTANCES.items():
            desc = ov.ip_dict[name]
            assert (desc["type"], desc["phys_addr"], desc["addr_range"]) == (
                vlnvs[-1], ADDRESS_MAP[name], WINDOW_SIZE)
        assert {n: ov.ip_dict[n]["mem_id"] for n in INSTANCES} == {
            "vdma_raw": "S_AXI_LITE", "vdma_proc": "S_AXI_LITE", "rectify": "s_axil", "mux": "S_AXI_CTRL"}
        raw, proc = ov.ip_dict["vdma_raw"]["parameters"], ov.ip_dict["vdma_proc"]["parameters"]
        assert raw["C_NUM_FSTORES"] == proc["C_NUM_FSTORES"] == str(NUM_FSTORES)
        # as block_design.tcl builds them: vdma_raw S2MM only, 512-deep line buffers
        assert (raw["C_INCLUDE_MM2S"], raw["C_INCLUDE_S2MM"], proc["C_INCLUDE_MM2S"]) == ("0", "1", "1")
        assert raw["C_S2MM_LINEBUFFER_DEPTH"] == proc["C_MM2S_LINEBUFFER_DEPTH"] == "512"
        rect = ov.ip_dict["rectify"]["parameters"]
        assert {k: rect[k] for k in rectify_parameters(DEFAULT_BUILD)} == rectify_parameters(DEFAULT_BUILD)
        registers = ov.ip_dict["rectify"]["registers"]
        assert {n: (r["address_offset"], r["access"]) for n, r in registers.items()} == {
            reg.name: (reg.offset, "read-only" if reg.access is Access.RO else
                       "write-only" if reg.access is Access.WO else "read-write") for reg in RECTIFY_MAP}
        mux = ov.ip_dict["mux"]["parameters"]
        assert (mux["NUM_SI"], mux["ROUTING_MODE"]) == (str(NUM_INPUTS), "1")
        ps7 = ov.ip_dict["processing_system7_0"]["parameters"]
        assert float(ps7["PCW_FPGA0_PERIPHERAL_FREQMHZ"]) * 1e6 == FABRIC_CLOCK_HZ
        assert board.dev.downloads == [] and board.dev.bus_accesses == 0

    def test_pynq_reads_the_depth_builds_stereo_core_and_its_vdma(board: Board) -> None:
        """build.tcl -build depth: pynq's ip_dict has the optional instances where the spec puts them,
        and the VLNVs our drivers register for."""
        from stereocam.overlays.pynq.drivers import PynqStereoCore
        from stereocam.overlays.spec.stereo import VLNV as STEREO_VLNV

        bit = write_overlay(board.tmp / "depth", build="depth")
        ov = pynq.Overlay(str(bit), device=board.dev, download=False)
        assert set(ov.ip_dict) == set(INSTANCES) | {STEREO, DEPTH_VDMA, "processing_system7_0"}
        stereo, depth = ov.ip_dict[STEREO], ov.ip_dict[DEPTH_VDMA]
        assert (stereo["type"], stereo["phys_addr"], stereo["addr_range"]) == (
            STEREO_VLNV, OPTIONAL_ADDRESS_MAP[STEREO], WINDOW_SIZE)
        assert (depth["type"] in VDMA_VLNVS, depth["phys_addr"]) == (True, OPTIONAL_ADDRESS_MAP[DEPTH_VDMA])
        params = depth["parameters"]
        assert (params["C_INCLUDE_MM2S"], params["C_INCLUDE_S2MM"], params["C_NUM_FSTORES"]) == (
            "0", "1", str(NUM_FSTORES))
        assert ov.ip_dict[STEREO]["registers"]["CONTROL"]["address_offset"] == STEREO_MAP["CONTROL"].offset
        assert pynq.overlay._ip_drivers[STEREO_VLNV] is PynqStereoCore

    def test_the_hwh_follows_the_block_design_script(board: Board) -> None:
        """A VDMA the script builds with MM2S gets it in the .hwh, its interrupt too: nothing typed twice."""
        edit = ("block_design.tcl", "CONFIG.c_include_mm2s {0}", "CONFIG.c_include_mm2s {1}")
        bit = write_overlay(board.tmp / "mm2s", edits=(edit,))
        ov = pynq.Overlay(str(bit), device=board.dev, download=False)
        assert ov.ip_dict["vdma_raw"]["parameters"]["C_INCLUDE_MM2S"] == "1"
        default = pynq.Overlay(str(board.bit), device=board.dev, download=False)
        assert default.ip_dict["vdma_raw"]["parameters"]["C_INCLUDE_MM2S"] == "0"
        text = bit.with_suffix(".hwh").read_text()
        assert 'NAME="mm2s_introut" SENSITIVITY="LEVEL_HIGH" SIGIS="INTERRUPT"' in text
        moved = ("block_design.tcl", "-offset 0x43C10000", "-offset 0x43C20000")
        ov = pynq.Overlay(str(write_overlay(board.tmp / "moved", edits=(moved,))), device=board.dev,
                          download=False)
        assert ov.ip_dict["mux"]["phys_addr"] == 0x43C2_0000

    def test_a_plain_pynq_overlay_gives_our_drivers(board: Board) -> None:
        """The notebook way: ``pynq.Overlay("stereocam.bit")`` after our driver module was imported."""
        registry = pynq.overlay._ip_drivers
        assert set(VDMA_VLNVS) <= set(pynq.lib.video.dma.AxiVDMA.bindto), "pynq binds its own VDMA driver too"
        assert all(registry[v] is PynqVDMA for v in VDMA_VLNVS), "ours were registered after pynq's"
        ov = pynq.Overlay(str(board.bit), device=board.dev)  # downloads, as a notebook does
        assert board.dev.downloads == [str(board.bit)]
        assert isinstance(ov.rectify, PynqRectifyCore) and isinstance(ov.rectify, RectifyCore)
        assert isinstance(ov.vdma_raw, PynqVDMA) and isinstance(ov.vdma_proc, VDMA)
        assert isinstance(ov.mux, PynqAxisSwitch) and isinstance(ov.mux, AxisSwitch)
        assert ov.vdma_raw.num_fstores == 3 and ov.mux.inputs == 2
        assert (ov.rectify.lb_rows, ov.rectify.max_width, ov.rectify.colour) == (80, 752, True)
        assert type(ov.rectify.regs.window).__module__ == "pynq.mmio"  # no guard without StereocamOverlay
        ov.mux.select(VIRTUAL)
        assert board.hw.mux.selected == VIRTUAL
        assert ov.rectify.read(RECTIFY_MAP["ID"].offset) == CORE_ID  # still a DefaultIP

    def test_the_overlay_programs_a_cold_fabric_and_its_fabric_is_its_drivers(board: Board) -> None:
        with board.open() as ov:
            assert board.dev.downloads == [str(board.bit)]
            fabric = ov.fabric
            assert (fabric.rectify, fabric.raw_vdma, fabric.proc_vdma, fabric.mux) == (
                ov.rectify, ov.vdma_raw, ov.vdma_proc, ov.mux)
            assert isinstance(ov.rectify.regs.window, GuardedWindow)
            assert type(ov.rectify.regs.window.window).__module__ == "pynq.mmio"
            ov.rectify.set_mode(bypass=True)
            fabric.select("virtual")
            frame = np.random.default_rng(5).integers(0, 256, (H, W, 8), dtype=np.uint8)
            fabric.send_virtual(frame)
            board.hw.step(2)
            _, proc = fabric.latest_processed()
            np.testing.assert_array_equal(proc, frame)
            assert fabric.status()["backend"] == "pynq"
        assert board.hw.mux.selected == LIVE, "close() returned the mux to the cameras"

    def test_a_restart_binds_without_reprogramming_where_pynqs_own_check_cannot_tell(board: Board) -> None:
        cold = pynq.Overlay(str(board.bit), device=board.dev, download=False)
        assert cold.is_loaded(), "pynq's is_loaded() is true for any overlay made with download=False"
        ov = board.open()
        ov.close()
        again = board.open()
        try:
            assert board.dev.downloads == [str(board.bit)], "the second daemon found the bitstream loaded"
            assert again.is_loaded()
        finally:
            again.close()

    def test_a_state_file_left_from_the_last_boot_is_not_trusted(board: Board) -> None:
        board.open().close()
        (board.dev.fpga_manager / "state").write_text("unknown\n")  # power cycle: the PL is empty again
        board.dev.mapped = False
        ov = board.open()
        try:
            assert board.dev.downloads == [str(board.bit)] * 2
            assert not board.dev.state_file.exists(), (
                "pynq cleared the stale record; its metadata cached, wrote none")
            ov.fabric.status()
            board.foreign()
            pynq.Overlay(str(board.tmp / "base" / "base.bit"), device=board.dev)
            with pytest.raises(FabricLost, match="pynq records .*base.bit since .*, not nothing"):
                ov.fabric.status()
        finally:
            ov.close()

    def test_an_hwh_that_disagrees_with_the_core_is_refused(board: Board) -> None:
        edit = ("block_design.tcl", "CONFIG.LB_ROWS {80}", "CONFIG.LB_ROWS {64}")
        wrong = write_overlay(board.tmp / "lb64", "stereocam", edits=(edit,))
        with pytest.raises(UnsupportedIP,
                           match=r"rectify: LB_ROWS=64 in the \.hwh but 80 in the core's register"):
            board.open(wrong)
        board.open().close()  # the refused overlay let go of the fabric

    def test_an_overlay_without_our_ip_is_refused_before_programming(board: Board) -> None:
        other = board.foreign("base", [ip for ip in stereocam_ips() if ip.name != "mux"])
        with pytest.raises(UnsupportedIP, match="the overlay has no IP named 'mux'"):
            board.open(other)
        switch = [ip if ip.name != "mux"
                  else Ip("mux", ip.vlnv, ip.base, {"NUM_SI": "2", "ROUTING_MODE": "0"})
                  for ip in stereocam_ips()]
        with pytest.raises(UnsupportedIP,
                           match=r"mux: ROUTING_MODE=0 \(TDEST routing\) has no control registers"):
            board.open(board.foreign("tdest", switch))
        assert board.dev.downloads == [str(board.tmp / "tdest" / "tdest.bit")], (
            "the first was refused unloaded")
        board.open().close()

    def test_our_overlay_binds_our_drivers_whatever_pynq_has_registered(board: Board, monkeypatch) -> None:
        AxiVDMA = pynq.lib.video.dma.AxiVDMA
        for vlnv in VDMA_VLNVS:
            monkeypatch.setitem(pynq.overlay._ip_drivers, vlnv, AxiVDMA)
        ov = board.open()
        try:
            assert type(ov.vdma_raw) is PynqVDMA and type(ov.vdma_proc) is PynqVDMA
            assert ov.ip_dict["vdma_raw"]["driver"] is AxiVDMA, "pynq would have bound its own"
        finally:
            ov.close()

    def test_a_second_owner_in_this_process_is_refused_before_touching_anything(board: Board) -> None:
        ov = board.open()
        downloads, accesses = list(board.dev.downloads), board.dev.bus_accesses
        with pytest.raises(FabricBusy) as err:
            board.open()
        message = str(err.value)
        cmdline = FabricLock(board.lock).holder()["cmdline"]
        assert message.startswith(f"the fabric is in use by `{cmdline[:50]}")
        assert f"(pid {os.getpid()}) since " in message
        assert f": close its overlay or end process {os.getpid()} first (lock: {board.lock})" in message
        assert (board.dev.downloads, board.dev.bus_accesses) == (downloads, accesses)
        ov.close()
        board.open().close()

    def test_a_second_daemon_is_refused_and_a_killed_owner_frees_the_fabric(board: Board) -> None:
        script = OWNER.format(state=str(board.tmp / "other-pl"), bit=str(board.bit),
                              lock=str(board.lock))
        env = {**os.environ, "INVOCATION_ID": "0123456789abcdef"}  # what systemd gives a service
        with subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              env=env, text=True, cwd=Path(__file__).resolve().parents[2]) as owner:
            try:
                assert owner.stdout is not None and owner.stdout.readline() == "bound\n"
                busy = (rf"^the fabric is in use by the stereocam service \(pid "
                        rf"{owner.pid}: `{re.escape(sys.executable)} -c .*`\) since "
                        r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d: stop it with "
                        r"`systemctl stop stereocam` first")
                with pytest.raises(FabricBusy, match=busy):
                    board.open()
                assert board.dev.downloads == []
                owner.send_signal(signal.SIGKILL)  # a crash: no close(), no cleanup
                assert owner.wait() == -signal.SIGKILL
            finally:
                if owner.poll() is None:
                    owner.kill()
        board.open().close()

    def test_another_overlay_downloaded_underneath_stops_the_daemon_off_the_bus(board: Board, caplog) -> None:
        ov = board.open()
        ov.start()
        ov.fabric.select("virtual")
        notebook = pynq.Overlay(str(board.foreign()), device=board.dev)  # pynq has no lock: this downloads
        assert notebook.is_loaded() and not board.dev.mapped
        accesses = board.dev.bus_accesses
        caplog.set_level(logging.ERROR, logger="stereocam.overlays.pynq.overlay")
        lost = (r"^the fabric was re-programmed underneath stereocam: "
                r"pynq records .*/base\.bit since .*, not .*/stereocam\.bit")
        with pytest.raises(FabricLost, match=lost):
            ov.fabric.status()
        calls = (lambda: ov.fabric.select("live"), ov.fabric.latest_processed, ov.rectify.status, ov.stop)
        for call in calls:
            with pytest.raises(FabricLost, match="restart stereocam"):
                call()
        ov.close()  # no DMA stop: it would touch the bus
        assert board.dev.bus_accesses == accesses, "nothing touched the bus after the foreign download"
        assert [r.getMessage()[:60] for r in caplog.records] == [
            "the fabric was re-programmed underneath stereocam: pynq reco"]
        with pytest.raises(pd.BusHang, match="on the board this hangs the AXI bus"):
            pynq.MMIO(ADDRESS_MAP["rectify"], 4, device=board.dev).read(0)
        successor = FabricLock(board.lock)
        successor.acquire("next")  # the closed overlay let go of the fabric
        successor.release()

    def test_a_design_loaded_behind_pynqs_back_is_caught_by_the_identity_probe(board: Board) -> None:
        ov = board.open(probe_interval=0.0)
        try:
            ov.fabric.status()
            # Another design answers at our address; pynq recorded nothing.
            board.hw.core.set("ID", 0x12345678)
            gone = ("the rectify core's ID register reads 0x12345678, not 0x52454354: "
                    "the PL no longer holds the stereocam overlay")
            with pytest.raises(FabricLost, match=gone):
                ov.fabric.status()
            accesses = board.dev.bus_accesses
            with pytest.raises(FabricLost):
                ov.vdma_raw.s2mm.errors()
            assert board.dev.bus_accesses == accesses
        finally:
            ov.close()

    def test_a_closed_or_bound_overlay_does_not_reprogram(board: Board) -> None:
        ov = board.open()
        with pytest.raises(BackendError, match="the overlay's drivers are bound: re-programming would pull"):
            ov.download()
        ov.close()
        ov.close()
        with pytest.raises(FabricBusy, match="this overlay was closed and no longer owns the fabric"):
            ov.download()
        with pytest.raises(FabricLost, match="the stereocam overlay was closed"):
            ov.rectify.status()
        assert board.dev.downloads == [str(board.bit)]

