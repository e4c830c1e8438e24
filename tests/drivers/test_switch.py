"""The live/virtual source mux: AXI4-Stream Switch (PG085) table, driver sequence, emulated behaviour."""

from __future__ import annotations

import pytest

from stereocam.drivers.mmio import RegisterRangeError, RegisterTimeout
from stereocam.drivers.switch import LIVE, VIRTUAL, AxisSwitch, SwitchError
from stereocam.overlays.emulated.regblock import EmulationError, UnknownRegister
from stereocam.overlays.emulated.switch import EmulatedAxisSwitch
from stereocam.overlays.spec.axis_switch import AXIS_SWITCH_MAP, axis_switch_map

from ..doubles import RecordingWindow

pytestmark = pytest.mark.armhf


def test_table_follows_pg085() -> None:
    assert AXIS_SWITCH_MAP.offset("CTRL") == 0x00 and AXIS_SWITCH_MAP["CTRL"].bit("REG_UPDATE") == 0x02
    mux = AXIS_SWITCH_MAP["MI0_MUX"]
    assert mux.offset == 0x40 and mux.field("MUX").mask == 0x0F and mux.bit("DISABLE") == 0x8000_0000
    assert axis_switch_map(16)["MI15_MUX"].offset == 0x7C  # PG085: "MI15_MUX register is at 0x7C"
    assert (LIVE, VIRTUAL) == (0, 1)
    with pytest.raises(ValueError, match="1..16 master interfaces"):
        axis_switch_map(17)


def test_select_writes_mux_then_commits_and_polls() -> None:
    win = RecordingWindow(
        [
            ("w", 0x40, 0x1),  # PG085 "Usage": MI0 sourced from SI1
            ("w", 0x00, 0x2),  # commit
            ("r", 0x00, 0x2),  # still updating
            ("r", 0x00, 0x0),
        ]
    )
    AxisSwitch(win).select(VIRTUAL)
    win.assert_done()
    win.expect(("w", 0x40, 0x8000_0000), ("w", 0x00, 0x2), ("r", 0x00, 0x0))
    switch = AxisSwitch(win)
    switch.disable()
    win.expect(("r", 0x40, 0x8000_0000), ("r", 0x40, 0x0))
    assert switch.selected() is None
    assert switch.selected() == LIVE
    win.assert_done()


def test_bad_arguments_touch_no_register() -> None:
    win = RecordingWindow()
    switch = AxisSwitch(win, inputs=2)
    for bad in (2, -1, True, "1"):
        with pytest.raises(RegisterRangeError, match="does not exist"):
            switch.select(bad)  # type: ignore[arg-type]
    with pytest.raises(SwitchError, match="1..16 inputs"):
        AxisSwitch(win, inputs=0)
    win.assert_done()


def test_emulated_switch_routes_only_after_commit() -> None:
    hw = EmulatedAxisSwitch()
    assert hw.selected is None  # our assumed reset state: master disabled
    hw.write(0x40, 1)
    assert hw.read(0x40) == 1 and hw.selected is None  # staged only
    hw.write(0x00, 2)
    reads = [hw.read(0x00) for _ in range(hw.settle_reads)]
    assert reads == [2] * (hw.settle_reads - 1) + [0]  # REG_UPDATE clears itself after a while
    assert hw.selected == VIRTUAL and hw.commits == 1
    hw.write(0x40, 0x8000_0000)
    assert hw.selected == VIRTUAL
    hw.write(0x00, 2)
    while hw.read(0x00):
        pass
    assert hw.selected is None


def test_emulated_switch_refuses_what_the_hardware_would_misroute() -> None:
    hw = EmulatedAxisSwitch(inputs=2)
    with pytest.raises(EmulationError, match="MI0_MUX selects SI2, but the switch has 2 slave interfaces"):
        hw.write(0x40, 2)
    with pytest.raises(EmulationError, match="reserved bits 0x10"):
        hw.write(0x40, 0x11)
    with pytest.raises(EmulationError, match="reserved bits 0x1"):
        hw.write(0x00, 0x3)
    with pytest.raises(UnknownRegister):
        hw.write(0x44, 0)  # one master interface: no MI1_MUX
    hw.write(0x40, 0x8000_0005)  # a disabled master may hold any (ignored) selection


def test_driver_on_the_emulated_switch() -> None:
    hw = EmulatedAxisSwitch()
    switch = AxisSwitch(hw)
    switch.select(LIVE)
    assert hw.selected == LIVE and switch.selected() == LIVE
    switch.select(VIRTUAL)
    assert hw.selected == VIRTUAL and switch.selected() == VIRTUAL
    switch.disable()
    assert hw.selected is None and switch.selected() is None
    assert hw.commits == 3
    hw.hang_update = True
    with pytest.raises(RegisterTimeout, match="axis_switch: CTRL never cleared REG_UPDATE") as err:
        switch.select(LIVE, timeout=0.02)
    assert err.value.register == "CTRL" and hw.selected is None
