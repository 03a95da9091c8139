"""Back-pressure (issue #39): a stage starts a frame only when the stage after it can take it."""

import time

import pytest
from vehicle_common.flow_control import InFlightWindow
from vehicle_common.frame_accounting import FrameCounter, LatestFrameWorker


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_window_admits_up_to_its_size_and_an_output_ends_every_older_frame():
    clock = FakeClock()
    w = InFlightWindow(2, 1.0, clock)
    assert w.admit(10) is None and w.admit(20) is None
    clock.t += 0.25
    assert w.admit(30) == pytest.approx(4.75)  # full: ask again when frame 10 expires
    assert w.finish(5) == 0  # an output of a frame not started here ends nothing
    assert w.finish(20) == 2  # frame 10 was dropped downstream: 20's output ends it too
    assert w.in_flight == 0 and w.finished == 2
    assert w.admit(30) is None


def test_window_frees_a_frame_whose_end_never_comes():
    clock = FakeClock()
    w = InFlightWindow(1, 0.5, clock)
    assert w.admit(1) is None
    assert w.admit(2) is not None
    clock.t += 2.0
    assert w.admit(2) is not None  # nothing timed yet: 5 x 0.5 s
    clock.t += 0.5
    assert w.admit(2) is None and w.expired == 1


def test_window_zero_is_no_back_pressure_and_bad_settings_are_refused():
    w = InFlightWindow(0, 1.0)
    assert all(w.admit(s) is None for s in range(10))
    with pytest.raises(ValueError, match="window"):
        InFlightWindow(-1, 1.0)
    with pytest.raises(ValueError, match="timeout_s"):
        InFlightWindow(1, 0.0)


def _two_stages(back_pressure: bool, stereo_s: float = 0.04):
    """A fast detector (its worker) feeding a slow stereo stage (its own latest-frame worker),
    whose output ends the detector's frames in flight (window 1) when ``back_pressure``."""
    det_frames, stereo_frames = FrameCounter(), FrameCounter()
    window = InFlightWindow(1, 5.0)
    detected, ranged = [], []
    holder = {}

    def stereo(stamp):
        time.sleep(stereo_s)  # busy: the newest complete frame waits, older ones are dropped
        ranged.append(stamp)
        stereo_frames.published()
        if window.finish(stamp):
            holder["det"].wake()

    stereo_worker = LatestFrameWorker(stereo, stereo_frames, "stereo")

    def detect(stamp):
        time.sleep(0.005)
        detected.append(stamp)
        det_frames.published()
        stereo_frames.received()
        stereo_worker.submit(stamp)

    det = LatestFrameWorker(
        detect, det_frames, "detector", admit=window.admit if back_pressure else None
    )
    holder["det"] = det
    return det, stereo_worker, det_frames, stereo_frames, detected, ranged


@pytest.mark.parametrize("back_pressure", [True, False])
def test_burst_while_the_stereo_stage_is_busy(back_pressure):
    """A camera at 100 Hz for 30 frames into a detector whose next stage needs 40 ms a frame:
    with back-pressure the detector skips (and counts) the frames the stereo stage cannot
    take, so nothing it detects is thrown away; without, most of its work is wasted."""
    det, stereo, det_frames, stereo_frames, detected, ranged = _two_stages(back_pressure)
    for stamp in range(30):
        det_frames.received()
        det.submit(stamp)
        time.sleep(0.01)
    assert det.wait_idle(10) and stereo.wait_idle(10)
    assert det.wait_idle(10)  # the last frame may have waited for the stereo stage's end
    d, s = det_frames.snapshot(), stereo_frames.snapshot()
    assert d.received == 30 and d.pending == 0 and s.pending == 0
    assert detected[-1] == 29  # the newest frame is always detected
    if back_pressure:
        assert s.dropped == 0 and ranged == detected  # every detection is used
        assert d.dropped == 30 - len(detected) > 10  # the rest skipped where skipped, counted
    else:
        assert s.dropped > 0 and len(ranged) < len(detected)  # detections thrown away


def test_a_held_frame_is_superseded_and_one_whose_end_never_comes_is_let_through():
    counter = FrameCounter()
    window = InFlightWindow(1, 0.06)  # 0.3 s until a frame is timed
    done = []
    worker = LatestFrameWorker(done.append, counter, admit=window.admit)
    t0 = time.monotonic()
    counter.received()
    worker.submit(0)
    assert worker.wait_idle(5) and done == [0]
    for stamp in (1, 2):  # 1 waits for frame 0's end, and is superseded by 2
        counter.received()
        worker.submit(stamp)
    assert worker.wait_idle(5)
    assert done == [0, 2] and counter.snapshot().dropped == 1
    assert time.monotonic() - t0 >= 0.25 and window.expired == 1  # nobody ended frame 0
    worker.stop()


def test_stopping_finishes_a_held_frame():
    window = InFlightWindow(1, 60.0)
    done = []
    worker = LatestFrameWorker(done.append, admit=window.admit)
    worker.submit(0)
    assert worker.wait_idle(5)
    worker.submit(2)
    worker.submit(1, frame=False)  # not a frame: never held back, but in order
    assert not worker.wait_idle(0.2)
    assert done == [0] and window.in_flight == 1  # frame 2 held: frame 0 is still in flight
    assert worker.stop(5) and done == [0, 2, 1]


def test_serialized_image_reads_the_header_now_and_the_image_when_used():
    """Images taken as the middleware's bytes (issue #39): a skipped frame costs no conversion;
    the header is read from the bytes, the image converts when used; bad bytes are refused."""
    import numpy as np
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CompressedImage, Image
    from vehicle_common.frame_messages import header
    from vehicle_common.image_conversion import ImageConversionError, numpy_to_image
    from vehicle_common.image_transport import SerializedImage, as_message, cdr_header

    img = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    msg = numpy_to_image(img, "rgb8", header(1_500_000_007, "left_camera_optical_frame"))
    data = serialize_message(msg)
    lazy = SerializedImage(data, Image)
    assert (lazy.header.stamp.sec, lazy.header.stamp.nanosec) == (1, 500_000_007)
    assert lazy.header.frame_id == "left_camera_optical_frame"
    full = as_message(lazy)
    assert full == msg and as_message(msg) is msg and lazy.message() is full
    comp = CompressedImage(header=msg.header, format="png", data=b"\x89PNG")
    assert cdr_header(serialize_message(comp)) == (1, 500_000_007, "left_camera_optical_frame")
    big = bytes([0, 0, 0, 0]) + (2).to_bytes(4, "big") + (3).to_bytes(4, "big")
    assert cdr_header(big + (2).to_bytes(4, "big") + b"a\x00") == (2, 3, "a")  # big-endian
    for bad in (b"", b"\x00\x01\x00\x00" + b"\xff" * 20, data[:14]):
        with pytest.raises(ValueError):
            SerializedImage(bad, Image)
    broken = SerializedImage(data[:60], Image)  # a readable header, a cut image
    with pytest.raises(ImageConversionError, match="deserialize"):
        broken.message()


def test_window_timeout_follows_a_slow_downstream_stage():
    """On a starved machine a frame takes seconds downstream: the timeout grows to twice the
    longest recent time in flight, so frames do not expire and back-pressure holds."""
    clock = FakeClock()
    w = InFlightWindow(1, 1.0, clock)
    assert w.admit(1) is None
    clock.t += 3.0
    assert w.finish(1) == 1 and w.timeout == pytest.approx(6.0)
    assert w.admit(2) is None
    clock.t += 4.0
    assert w.admit(3) is not None and w.expired == 0  # 4 s: still waiting for frame 2
    clock.t += 2.0
    assert w.admit(3) is None and w.expired == 1


def test_window_learns_a_stage_slower_than_the_timeout_from_an_expired_frame():
    """Every frame takes 5 s downstream and the timeout starts at 1 s: the first frame expires,
    but its output still comes and sets the timeout, so the next frames wait for theirs."""
    clock = FakeClock()
    w = InFlightWindow(1, 0.2, clock)
    assert w.admit(1) is None
    clock.t += 1.0
    assert w.admit(2) is None and w.expired == 1  # frame 1 expired (nothing timed: 5 x 0.2 s)
    clock.t += 4.0
    assert w.finish(1) == 0 and w.timeout == pytest.approx(10.0)  # 5 s in flight, learnt
    clock.t += 5.0
    assert w.admit(3) is not None and w.expired == 1  # frame 2 is still in flight


def test_cadence_waits_for_a_next_image_due_soon_and_never_for_an_overdue_one():
    """Issue #39: at a camera twice the graph's capacity the newest image had waited half a
    period when the window freed; an image due within half a period is waited for instead."""
    from vehicle_common.flow_control import CameraCadence

    clock = FakeClock()
    cam = CameraCadence(clock)
    assert cam.wait_for_next(0.5) is None  # no period yet
    for _ in range(4):  # 10 Hz
        cam.arrived()
        clock.t += 0.1
    clock.t -= 0.1  # now: the 4th image has just arrived
    assert cam.period == pytest.approx(0.1)
    assert cam.wait_for_next(0.5) is None  # the next is a whole period away: take this one
    clock.t += 0.07  # the next is due in 0.03 s (within half a period): wait for it
    assert cam.wait_for_next(0.5) == pytest.approx(0.03 + 0.025)
    assert cam.wait_for_next(0.0) is None  # off
    clock.t += 0.05  # overdue by 0.02 s, within LATE: still worth the wait
    assert cam.wait_for_next(0.5) == pytest.approx(0.005)
    clock.t += 0.5  # the camera stopped: never wait again
    assert cam.wait_for_next(0.5) is None


def test_admission_takes_the_next_image_when_it_is_due_soon():
    """The detector's admission (a worker in front of a free window): the frame that waited
    past half a period is superseded by the next image instead of being detected stale."""
    from types import SimpleNamespace

    from detector_node.admission import DownstreamAdmission

    adm = DownstreamAdmission(1, 1.0, lambda: 1, lambda line: None, next_frame_wait=0.5)
    clock = FakeClock()
    adm.cadence._clock = clock
    for _ in range(4):
        adm.arrived()
        clock.t += 0.05
    msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0)))
    clock.t += 0.0  # the newest image is 0.05 s old: the next is due now (within LATE)
    wait = adm.admit(msg)
    assert wait is not None and adm.waited_for_next == 1 and adm.flow.in_flight == 0
    clock.t -= 0.04  # the newest image is 0.01 s old: detect it
    assert adm.admit(msg) is None and adm.flow.in_flight == 1
    off = DownstreamAdmission(1, 1.0, lambda: 1, lambda line: None, next_frame_wait=0.0)
    for _ in range(4):
        off.arrived()
    assert off.admit(msg) is None


def test_lead_starts_one_more_frame_timed_to_end_as_the_stage_after_frees():
    """``downstream_lead``: with the window full, one more frame may start ``lead_s`` before
    the newest frame in flight is expected to end (its start + the median time in flight), so
    the next frame's CNN runs beside the stereo node's work on this one; never a third."""
    clock = FakeClock()
    w = InFlightWindow(1, 1.0, clock)
    assert w.admit(1, lead_s=0.04) is None
    assert w.admit(2, lead_s=0.04) == pytest.approx(5.0)  # no time in flight known: no lead
    clock.t += 0.1
    assert w.finish(1) == 1  # 0.1 s in flight: learnt
    assert w.admit(2, lead_s=0.04) is None  # frame 2 starts at t = 0.1
    clock.t += 0.02
    assert w.room_in(0.0) == pytest.approx(1.0 - 0.02)  # no lead: the window is full
    assert w.room_in(0.04) == pytest.approx(0.04)  # expected end 0.2: start at 0.16
    assert w.admit(3, lead_s=0.04) == pytest.approx(0.04) and w.in_flight == 1
    clock.t += 0.04
    assert w.room_in(0.04) == 0.0
    assert w.admit(3, lead_s=0.04) is None and w.in_flight == 2
    clock.t += 0.05
    assert w.admit(4, lead_s=0.04) == pytest.approx(1.0 - 0.11)  # two in flight: no third
    assert w.finish(2) == 1 and w.in_flight == 1  # frame 3 is now the newest in flight
    # the median of 0.1 and 0.11 s: frame 3 (started at 0.16) is expected to end at 0.265
    assert w.room_in(0.04) == pytest.approx(0.265 - 0.04 - 0.21)
    clock.t += 0.5
    assert w.admit(4, lead_s=0.04) is None  # long after its expected end: the lead frame starts


def test_lead_zero_is_the_window_as_before():
    clock = FakeClock()
    a, b = InFlightWindow(1, 1.0, clock), InFlightWindow(1, 1.0, clock)
    for s in range(1, 6):
        assert (a.admit(s) is None) == (b.admit(s, lead_s=0.0) is None)
        clock.t += 0.03
        if s % 2:
            a.finish(s)
            b.finish(s)
    assert a.in_flight == b.in_flight


def test_admission_passes_the_cnn_time_as_the_lead():
    """The detector's admission asks the CNN's time per frame each time and passes it to the
    window: unknown (None) is no lead."""
    from types import SimpleNamespace

    from detector_node.admission import DownstreamAdmission

    cnn = {"s": None}
    adm = DownstreamAdmission(1, 1.0, lambda: 1, lambda line: None, lead=lambda: cnn["s"])
    clock = FakeClock()
    adm.flow._clock = clock

    def msg(sec):
        return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=0)))

    assert adm.admit(msg(1)) is None
    clock.t += 0.1
    adm.finish(msg(1), lambda: None)  # 0.1 s in flight
    assert adm.admit(msg(2)) is None
    clock.t += 0.07
    assert adm.admit(msg(3)) is not None  # CNN time unknown: the window of 1 holds
    cnn["s"] = 0.05
    assert adm.admit(msg(3)) is None and adm.flow.in_flight == 2  # expected end 0.2 - 0.05
