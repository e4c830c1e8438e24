"""The frame path without HTTP: pipeline, feed, latest-wins broadcast, views and encoders."""
from __future__ import annotations

import asyncio
import concurrent.futures
import time
from typing import Callable

import cv2
import numpy as np
import pytest

from stereocam.drivers.vdma import ChannelFault
from stereocam.overlays.model.fast import RectifyModel
from stereocam.overlays.model.stereo import compute
from stereocam.server.frames.depth import stereo_of
from stereocam.server.frames.encoders import EncoderKey, Encoders, encoded_for
from stereocam.server.frames.feed import BroadcastClosed, FrameFeed, Latest
from stereocam.server.frames.pipeline import FrameSet, NoSignal, OnceCache, Pipeline, SourceState
from stereocam.server.frames.views import VIEWS, ViewUnavailable, render, view_size

from .daemon import SMALL, H, W, make_overlay

WAIT_S = 60.0  # last-resort bound of a wait for something that does happen (a busy machine is slow)


def wait_until(condition: Callable[[], bool], what: str) -> None:
    """Poll ``condition()`` (from a test's thread) until true; fail naming ``what`` after WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"no {what} within {WAIT_S} s"
        time.sleep(0.01)


@pytest.fixture
def stepped():
    overlay = make_overlay(clock="stepped")
    overlay.start()
    yield overlay
    overlay.close()


def model_of(overlay) -> RectifyModel:
    config, options = overlay.core_setup()
    return RectifyModel(config.left, config.right, config.width, config.height, options)


def frame_set(processed: np.ndarray, raw=None, n: int = 1) -> FrameSet:
    return FrameSet(seq=n, frame=n, fabric_count=n, timestamp=time.time(), monotonic=time.monotonic(),
                    source="live", processed=processed, raw=raw)


# -- pipeline -------------------------------------------------------------------------------------

def test_grab_copies_a_synchronised_pair_once_per_frame(stepped) -> None:
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    model = model_of(stepped)
    stepped.step(2)
    with pipeline.raw_wanted():
        first = pipeline.grab()
        assert first is not None and first.raw is not None
        assert pipeline.grab() is None, "the same frame must not be published twice"
        stepped.step(1)
        second = pipeline.grab()
    assert second is not None and second.frame > first.frame and second.seq == first.seq + 1
    for fs in (first, second):
        np.testing.assert_array_equal(fs.processed, model.process(fs.raw).frame)
        assert not fs.processed.flags.writeable and not fs.raw.flags.writeable
        assert fs.processed.shape == (H, W, 8) and fs.size == (W, H)
    stepped.step(1)
    plain = pipeline.grab()
    assert plain is not None and plain.raw is None, "no raw copy when nobody wants it"
    assert pipeline.frames == 3 and pipeline.drops == 0


def test_drops_are_counted_from_the_frame_counter(stepped) -> None:
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    stepped.step(2)
    a = pipeline.grab()
    stepped.step(4)
    b = pipeline.grab()
    assert a is not None and b is not None
    assert b.frame - a.frame == 4 and pipeline.drops == 3


def test_a_copy_that_straddles_a_frame_is_retried_then_dropped(stepped, monkeypatch) -> None:
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    stepped.step(2)
    counter = iter(range(100, 200))
    monkeypatch.setattr(pipeline, "frame_count", lambda: next(counter))  # the fabric moves during every copy
    assert pipeline.grab() is None
    assert pipeline.retries == 3 and pipeline.frames == 0
    values = iter([300, 301, 302, 302])  # moves during the first copy only
    monkeypatch.setattr(pipeline, "frame_count", lambda: next(values))
    fs = pipeline.grab()
    assert fs is not None and fs.fabric_count == 302 and pipeline.retries == 4


def test_virtual_input_is_the_raw_pair_from_its_effective_frame(stepped) -> None:
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    stepped.step(2)
    virtual = np.zeros((H, W, 8), np.uint8)
    virtual.flags.writeable = False
    count = pipeline.frame_count()
    pipeline.set_source(SourceState("virtual", virtual, count + 2))
    stepped.step(1)
    early = pipeline.grab()
    assert early is not None and early.raw is not virtual and early.source == "virtual"
    stepped.step(2)
    late = pipeline.grab()
    assert late is not None and late.raw is virtual


def test_thread_publishes_every_frame_and_beats_without_frames() -> None:
    overlay = make_overlay(fps=30)
    published = []
    beats = []
    pipeline = Pipeline(overlay, publish=published.append,
                        heartbeat=lambda: beats.append(time.monotonic()), wait_s=0.05)
    overlay.start()
    try:
        with pipeline:
            pipeline.start()  # idempotent
            wait_until(lambda: len(published) >= 8, "8 published frames")
            numbers = [fs.frame for fs in published]
            assert numbers == sorted(set(numbers))
            # Measured rates (a busy machine lowers them: their size is not the point here).
            assert pipeline.meter.rate() > 0 and pipeline.fabric_fps() > 0
            ticks = overlay.emulation.counters.ticks
            overlay.emulation.cameras_running = False
            # A tick that began after that one sees no camera frame; then the pipeline drains
            # what the fabric still holds (at most a frame or two, each followed by a beat).
            wait_until(lambda: overlay.emulation.counters.ticks > ticks + 1, "a tick without cameras")
            b = len(beats)
            wait_until(lambda: len(beats) >= b + 3, "the pipeline beating after the cameras stopped")
            n, b = len(published), len(beats)
            # Each beat without a frame follows a whole wait_s (0.05 s) of waiting for one.
            wait_until(lambda: len(beats) >= b + 7, "the thread beating while it waits")
            assert len(published) == n, "no frames without cameras"
            assert pipeline.last_frame_age() > 0.25
        assert not pipeline.running
        pipeline.stop()  # idempotent
    finally:
        overlay.close()


def test_a_channel_fault_is_counted_and_left_to_fabric_health(stepped, monkeypatch) -> None:
    """The pipeline thread goes on waiting; it does not restart the channel (a hung reset would stall it)."""
    pipeline = Pipeline(stepped, publish=lambda fs: None, wait_s=0.05)
    s2mm = stepped.fabric.proc_vdma.s2mm
    calls = {"wait": 0, "recover": 0}

    def faulty_wait(timeout=None, fresh=False):
        calls["wait"] += 1
        if calls["wait"] == 1:
            raise ChannelFault("vdma_proc S2MM halted on VDMADecErr; call recover()", ("VDMADecErr",))
        time.sleep(0.01)
        from stereocam.drivers.mmio import RegisterTimeout
        raise RegisterTimeout("vdma_proc", "S2MM_VDMASR", "set FrmCnt_Irq", 0, timeout or 0)

    monkeypatch.setattr(s2mm, "wait_frame", faulty_wait)
    def recover(timeout=None):
        calls["recover"] += 1

    monkeypatch.setattr(s2mm, "recover", recover)
    with pipeline:
        wait_until(lambda: calls["wait"] >= 3, "three waits for a frame")
    assert calls["recover"] == 0 and pipeline.errors == 1 and "VDMADecErr" in pipeline.last_error


def test_once_cache_computes_once_across_threads() -> None:
    cache = OnceCache()
    calls = []

    def compute():
        calls.append(1)
        time.sleep(0.05)
        return object()

    with concurrent.futures.ThreadPoolExecutor(8) as pool:
        results = list(pool.map(lambda _: cache.get("k", compute), range(8)))
    assert len(calls) == 1 and all(r is results[0] for r in results)
    with pytest.raises(ZeroDivisionError):
        cache.get("bad", lambda: 1 / 0)
    assert cache.get("bad", lambda: 2) == 2


# -- latest-wins broadcast and the feed -----------------------------------------------------------

async def test_latest_wakes_every_waiter_with_the_newest_value() -> None:
    latest: Latest[int] = Latest()
    assert latest.current() == (0, None)
    waiters = [asyncio.create_task(latest.wait_newer(0)) for _ in range(5)]
    await asyncio.sleep(0)
    latest.publish(1)
    latest.publish(2)  # 1 is skipped: latest wins
    assert [await w for w in waiters] == [(2, 2)] * 5
    assert await latest.wait_newer(0) == (2, 2)
    slow = asyncio.create_task(latest.wait_newer(2))
    await asyncio.sleep(0)
    latest.close()
    with pytest.raises(BroadcastClosed):
        await slow
    latest.publish(3)
    assert latest.current() == (2, 2)


async def test_feed_keeps_the_newest_set_and_marks_no_signal() -> None:
    feed = FrameFeed(frame_size=SMALL, no_signal_s=0.2)
    feed.attach(asyncio.get_running_loop())
    frame = np.zeros((H, W, 8), np.uint8)
    sets = [frame_set(frame, n=i) for i in range(1, 4)]

    def push_all() -> None:
        for fs in sets:
            feed.push(fs)

    await asyncio.get_running_loop().run_in_executor(None, push_all)
    seq, item = await asyncio.wait_for(feed.frames.wait_newer(0), WAIT_S)
    while feed.frames.current()[1] is not sets[-1]:  # the pushes reach the loop one by one
        seq, item = await asyncio.wait_for(feed.frames.wait_newer(seq), WAIT_S)
    seq, item = feed.frames.current()
    assert item is sets[-1] and feed.signal
    assert seq <= 3 and feed.coalesced + seq >= 3
    watcher = asyncio.create_task(feed.watch())
    try:
        seq, marker = await asyncio.wait_for(feed.frames.wait_newer(seq), WAIT_S)
        assert isinstance(marker, NoSignal) and marker.last_frame == 3 and marker.size == SMALL
        assert not feed.signal
        with pytest.raises(asyncio.TimeoutError):
            await feed.next_frame(timeout=0.3)
    finally:
        watcher.cancel()
        feed.close()


# -- views ------------------------------------------------------------------------------------------

def test_views_are_derived_once_per_frame(stepped) -> None:
    stepped.step(2)
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    with pipeline.raw_wanted(), pipeline.depth_wanted():  # the disparity views need the core's output
        fs = pipeline.grab()
    assert fs is not None and fs.raw is not None and fs.depth is not None
    p, r = fs.processed, fs.raw
    np.testing.assert_array_equal(render(fs, "raw_left"), r[..., [2, 1, 0]])
    np.testing.assert_array_equal(render(fs, "raw_right", gray=True), r[..., 7])
    np.testing.assert_array_equal(render(fs, "rect_right"), p[..., [6, 5, 4]])
    np.testing.assert_array_equal(render(fs, "sbs", gray=True), np.hstack([p[..., 3], p[..., 7]]))
    ana = render(fs, "anaglyph")
    np.testing.assert_array_equal(ana[..., 2], p[..., 3])  # red: left
    np.testing.assert_array_equal(ana[..., 0], p[..., 7])  # blue and green: right
    np.testing.assert_array_equal(ana[..., 1], p[..., 7])
    assert render(fs, "anaglyph", gray=True) is ana, "gray does not apply to the anaglyph"
    disp = render(fs, "disparity")
    assert disp.shape == (H, W, 3) and disp.any()
    for view in VIEWS:
        image = render(fs, view)
        assert image is render(fs, view), "cached per frame"
        assert image.shape[:2][::-1] == view_size(view, SMALL)
        assert image.flags.c_contiguous and not image.flags.writeable
    with pytest.raises(ViewUnavailable):
        render(frame_set(p), "raw_left")
    without_depth = frame_set(p)
    without_depth.stereo = True  # from an overlay with a stereo core, read without its output
    with pytest.raises(ViewUnavailable, match="read without the stereo core's output"):
        render(without_depth, "disparity")
    with pytest.raises(KeyError):
        render(fs, "edges")


def test_disparity_uses_the_papers_block_matcher() -> None:
    """Where the bitstream has no stereo core, the ARM computes the disparity with StereoBM."""
    stepped = make_overlay(clock="stepped", stereo=False)
    stepped.start()
    try:
        stepped.step(2)
        fs = Pipeline(stepped, publish=lambda fs: None).grab()
    finally:
        stepped.close()
    assert fs is not None and not fs.stereo
    bm = cv2.StereoBM.create(numDisparities=128, blockSize=19)
    bm.setUniquenessRatio(15)
    disp = bm.compute(np.ascontiguousarray(fs.processed[..., 3]), np.ascontiguousarray(fs.processed[..., 7]))
    image = render(fs, "disparity")
    assert (image.any(axis=2) == (disp >= 0)).mean() > 0.999  # black exactly where no disparity was found


def test_the_cores_output_is_taken_only_while_wanted(stepped) -> None:
    stepped.step(2)
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    fs = pipeline.grab()
    assert fs is not None and fs.stereo and fs.depth is None and fs.calibration is None
    calibrations = []
    pipeline.set_calibration(lambda count: calibrations.append(count))
    stepped.step(1)
    with pipeline.depth_wanted():
        assert pipeline.wants_depth
        fs = pipeline.grab()
    assert not pipeline.wants_depth
    assert fs is not None and fs.depth is not None and calibrations == [fs.fabric_count]
    core = stereo_of(fs)
    p = fs.processed
    assert core is not None and core.equal(compute(p[..., 3].copy(), p[..., 7].copy()))
    assert stereo_of(fs) is core, "read once per set"


def test_a_frame_the_core_emitted_nothing_for_says_why(stepped) -> None:
    stereo = stepped.stereo
    assert stereo is not None
    stereo.program(stereo.params(), size=(SMALL[0] - 8, SMALL[1]), wait=False)  # latched at the next frame
    stepped.step(3)
    pipeline = Pipeline(stepped, publish=lambda fs: None)
    with pipeline.depth_wanted():
        fs = pipeline.grab()
    assert fs is not None and fs.depth is not None and stereo.status().flags["SIZE_ERROR"]
    with pytest.raises(ValueError, match="emitted no output for frame .*SIZE_ERROR"):
        stereo_of(fs)


def test_without_a_stereo_core_nothing_is_taken() -> None:
    overlay = make_overlay(clock="stepped", stereo=False)
    overlay.start()
    try:
        overlay.step(2)
        pipeline = Pipeline(overlay, publish=lambda fs: None)
        with pipeline.depth_wanted():
            fs = pipeline.grab()
    finally:
        overlay.close()
    assert fs is not None and not fs.stereo and fs.depth is None and stereo_of(fs) is None


# -- encoders -----------------------------------------------------------------------------------------

async def test_encoders_run_only_while_subscribed_and_encode_each_frame_once() -> None:
    feed = FrameFeed(frame_size=SMALL, no_signal_s=5)
    feed.attach(asyncio.get_running_loop())
    overlay = make_overlay(clock="stepped")
    overlay.start()
    pipeline = Pipeline(overlay, publish=feed.push)
    overlay.step(1)  # the first processed frame completes with the second tick
    timings = []
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        encoders = Encoders(feed, pipeline, pool, disparity_fps=5, observe=lambda v, s: timings.append(v))
        key = EncoderKey("raw_left", 70)
        with encoders.subscribe(key, 60) as a, encoders.subscribe(key, 10) as b:
            assert a is b and a.subscribers == 2 and a.fps == 60
            assert pipeline.wants_raw, "a raw view asks the pipeline for the raw pair"
            seq = 0
            for _ in range(4):
                await asyncio.sleep(1 / 50)  # frames at 50 fps: the encoder's rate limit lets all through
                overlay.step(1)
                fs = pipeline.grab()
                assert fs is not None
                feed.push(fs)
                seq, encoded = await asyncio.wait_for(a.output.wait_newer(seq), WAIT_S)
                assert encoded.frame == fs.frame and encoded.signal
                assert encoded.part.startswith(b"--frame\r\nContent-Type: image/jpeg\r\n")
                assert bytes(encoded.jpeg) == encoded.part[encoded.jpeg_start:-2]
                assert encoded_for(key, fs) is encoded, "a snapshot of the same frame shares the encode"
            assert timings.count("raw_left") == 4
        assert not encoders.active() and not pipeline.wants_raw
        with encoders.subscribe(EncoderKey("disparity", 80), 30) as d:
            assert encoders.disparity.running
            overlay.step(1)
            fs = pipeline.grab()
            feed.push(fs)
            seq = 0
            while True:  # the worker starts with the frame set that was current, then takes the new one
                seq, encoded = await asyncio.wait_for(d.output.wait_newer(seq), WAIT_S)
                if encoded.frame == fs.frame:
                    break
        assert not encoders.disparity.running
        await encoders.close()
    overlay.close()
    feed.close()


async def test_an_encoder_skips_frames_nobody_wants() -> None:
    feed = FrameFeed(frame_size=SMALL, no_signal_s=5)
    frame = np.zeros((H, W, 8), np.uint8)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        encoders = Encoders(feed, None, pool, disparity_fps=5)
        with encoders.subscribe(EncoderKey("rect_left", 50), 10) as enc:
            loop = asyncio.get_running_loop()
            t, began = time.monotonic(), loop.time()
            for i in range(1, 13):  # 12 frames at 60 fps for a client that wants 10
                fs = frame_set(frame, n=i)
                fs.monotonic = t + i / 60
                feed.frames.publish(fs)
                await asyncio.sleep(0.01)
            # Latest wins: the encoder ends on the last frame, however busy the machine.
            seq, encoded = enc.output.current()
            while encoded is None or encoded.frame != 12:
                seq, encoded = await asyncio.wait_for(enc.output.wait_newer(seq), WAIT_S)
            took = loop.time() - began
            # At most one encode per 0.75 / 10 s (the encoder's limit for 10 fps) since the first:
            # 2 or 3 of the 12 on an idle machine (about 0.13 s); more only if publishing them took longer.
            assert 2 <= enc.frames <= 1 + int(took / 0.075)
        await encoders.close()


async def test_no_signal_markers_are_encoded_as_no_signal_frames() -> None:
    marker = NoSignal(seq=1, timestamp=time.time(), since=time.time() - 2, last_frame=7, size=SMALL)
    encoded = encoded_for(EncoderKey("sbs", 80), marker)
    assert not encoded.signal and encoded.frame == 7
    assert b"X-Signal: none" in encoded.part[:encoded.jpeg_start]
    image = cv2.imdecode(np.frombuffer(bytes(encoded.jpeg), np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (H, 2 * W, 3)
