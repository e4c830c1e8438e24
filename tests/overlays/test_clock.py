"""The emulated cameras' frame clock: exact stepped ticks; a realtime thread that starts and stops cleanly.

Realtime assertions are deliberately loose (the machine is 2 shared cores):
they wait for frames to happen (bounded only as a last resort), never check their timing.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable, List, Tuple

import pytest

from stereocam.overlays.emulated.clock import ClockError, ClockStopTimeout, FrameClock

pytestmark = pytest.mark.armhf


def wait_for(condition: Callable[[], bool], timeout: float = 60.0) -> bool:
    """Wait until ``condition()``; ``timeout`` is a last-resort bound, not a measure of speed."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.005)
    return condition()


def test_stepped_clock_ticks_exactly() -> None:
    ticks: List[Tuple[int, float]] = []
    clock = FrameClock(30, lambda i, t: ticks.append((i, t)), mode="stepped")
    with clock:  # start/stop are accepted and do nothing
        clock.step()
        clock.step(2)
    clock.step(0)
    assert ticks == [(0, 0.0), (1, 1 / 30), (2, 2 / 30)]
    assert clock.frames == 3 and clock.index == 3 and clock.skipped == 0 and clock.errors == 0
    assert clock.fps == 30 and not clock.running


def test_stepped_clock_lets_exceptions_through() -> None:
    def tick(index: int, t: float) -> None:
        raise KeyError(index)

    clock = FrameClock(10, tick, mode="stepped")
    with pytest.raises(KeyError):
        clock.step()
    assert clock.index == 1


@pytest.mark.parametrize("fps", [0, -5, float("nan"), float("inf"), "fast", None])
def test_bad_rates_are_refused(fps: object) -> None:
    with pytest.raises(ClockError, match="fps"):
        FrameClock(fps, lambda i, t: None)


def test_bad_mode_and_misuse_are_refused() -> None:
    with pytest.raises(ClockError, match="mode must be one of realtime, stepped"):
        FrameClock(30, lambda i, t: None, mode="fast")
    with pytest.raises(ClockError, match="callable"):
        FrameClock(30, None)
    with pytest.raises(ClockError, match="realtime"):
        FrameClock(30, lambda i, t: None).step()
    with pytest.raises(ClockError, match="n >= 0"):
        FrameClock(30, lambda i, t: None, mode="stepped").step(-1)


def test_realtime_clock_runs_and_stops_promptly() -> None:
    ticks: List[Tuple[int, float, str]] = []
    clock = FrameClock(200, lambda i, t: ticks.append((i, t, threading.current_thread().name)),
                       name="cam-clock")
    with clock:
        assert clock.start() is clock  # idempotent
        assert clock.running
        assert wait_for(lambda: clock.frames >= 5)
    assert not clock.running
    clock.stop()  # idempotent
    indexes = [i for i, _, _ in ticks]
    assert indexes == sorted(set(indexes)) and indexes[0] == 0
    assert all(t == i / 200 for i, t, _ in ticks)
    assert {name for _, _, name in ticks} == {"cam-clock"}
    assert clock.frames == len(ticks) and clock.fps > 0
    assert indexes[-1] + 1 == len(ticks) + clock.skipped
    # a restart carries on from the next index
    before, count = clock.index, len(ticks)
    with clock:
        assert wait_for(lambda: clock.frames >= count + 2)
    assert ticks[count][0] >= before


def test_stop_wakes_a_clock_waiting_for_its_next_frame() -> None:
    """stop() does not wait out the frame period: a 20 s clock stops long before its second tick."""
    clock = FrameClock(0.05, lambda i, t: None)
    with clock:
        assert wait_for(lambda: clock.frames >= 1)
        began = time.monotonic()
    assert time.monotonic() - began < 10.0, "stop() waited for the next frame instead of waking the thread"
    assert not clock.running and clock.frames == 1


def test_a_late_clock_skips_frames_instead_of_bursting() -> None:
    seen: List[int] = []

    def tick(index: int, t: float) -> None:
        seen.append(index)
        if index == 0:
            time.sleep(0.06)  # six frame periods

    with FrameClock(100, tick) as clock:
        assert wait_for(lambda: len(seen) >= 3)
    assert clock.skipped >= 4
    assert seen[1] >= 5  # frames 1..4 were skipped, not run back to back


def test_tick_errors_are_logged_and_counted(caplog: pytest.LogCaptureFixture) -> None:
    def tick(index: int, t: float) -> None:
        raise ValueError(f"bad frame {index}")

    with caplog.at_level(logging.ERROR, logger="stereocam.overlays.emulated.clock"):
        with FrameClock(200, tick) as clock:
            assert wait_for(lambda: clock.errors >= 5)
            assert clock.running
    assert clock.errors == clock.frames
    records = [r for r in caplog.records if "raised" in r.getMessage()]
    assert 1 <= len(records) <= 3 + clock.errors // 100
    assert "bad frame 0" in caplog.text


def test_tick_may_stop_its_own_clock() -> None:
    clock: FrameClock
    calls: List[int] = []

    def tick(index: int, t: float) -> None:
        calls.append(index)
        if len(calls) == 3:  # the third tick (a late clock skips indices: do not wait for index 2)
            clock.stop()

    clock = FrameClock(200, tick)
    clock.start()
    assert wait_for(lambda: not clock.running)
    assert clock.frames == 3
    clock.stop()


def test_stop_times_out_on_a_blocked_tick_and_can_wait_again() -> None:
    release = threading.Event()
    entered = threading.Event()

    def tick(index: int, t: float) -> None:
        entered.set()
        release.wait(60.0)  # released by the test below; the bound only ends a failed test's thread

    clock = FrameClock(100, tick).start()
    assert entered.wait(60.0)
    with pytest.raises(ClockStopTimeout, match="blocking call in the tick callback"):
        clock.stop(timeout=0.05)
    with pytest.raises(ClockStopTimeout, match="still inside tick"):
        clock.start()
    release.set()
    clock.stop()
    assert not clock.running and clock.frames == 1


def test_stop_waits_as_long_as_the_clocks_ticks_take() -> None:
    """A tick is a whole emulated frame: on a slow or busy CPU (qemu, an A9) it can take longer than
    the least wait (2 s), and stopping then must wait for it (four times the longest tick so far),
    not call it a hang: the daemon's shutdown raised ClockStopTimeout in the armhf env."""
    second = threading.Event()
    release = threading.Event()

    def tick(index: int, t: float) -> None:
        if index == 0:
            time.sleep(1.5)  # the longest tick: stop() then waits 6 s for one
        else:
            second.set()
            release.wait(60.0)

    clock = FrameClock(100, tick).start()
    assert second.wait(60.0)
    releaser = threading.Timer(2.5, release.set)  # the tick in progress ends 2.5 s into the stop
    releaser.start()
    try:
        clock.stop()  # before: ClockStopTimeout after 2 s
    finally:
        release.set()
        releaser.cancel()
    assert not clock.running


def test_stop_waits_for_a_first_tick_that_computes_longer_than_the_least_wait() -> None:
    """The first tick has no longest tick before it: on a starved CPU (qemu beside other work) it took
    longer than 2 s and the daemon's shutdown raised. A tick that uses CPU is working: stop waits."""
    entered = threading.Event()

    def tick(index: int, t: float) -> None:
        entered.set()
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            sum(range(1000))  # CPU, not a blocking call

    clock = FrameClock(100, tick).start()
    assert entered.wait(60.0)
    clock.stop()  # before: ClockStopTimeout after 2 s
    assert not clock.running and clock.frames == 1


def test_a_first_tick_blocked_without_using_cpu_is_still_called_a_hang() -> None:
    release = threading.Event()
    entered = threading.Event()

    def tick(index: int, t: float) -> None:
        entered.set()
        release.wait(60.0)

    clock = FrameClock(100, tick).start()
    assert entered.wait(60.0)
    try:
        with pytest.raises(ClockStopTimeout, match="blocking call in the tick callback"):
            clock.stop()
    finally:
        release.set()
    clock.stop()
    assert not clock.running
