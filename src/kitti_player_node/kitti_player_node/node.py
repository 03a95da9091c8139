"""``kitti_player`` node: plays a KITTI tracking sequence as a rectified stereo camera.

Per frame, with one shared dataset stamp: ``/clock``, ``/kitti/ground_truth``, left/right
``camera_info`` and left/right ``image_rect`` (rgb8). Pacing, lockstep, drops and noise are
decided by :mod:`kitti_player_node.playback`; KITTI files are read through :mod:`.kitti`.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from stereo_vehicle_msgs.msg import KittiFrameLabels, TrackedVehicleArray
from vehicle_common.frame_accounting import FrameCounter
from vehicle_common.frame_messages import (
    LEFT_FRAME,
    RIGHT_FRAME,
    ground_truth_message,
    header,
    stamp_ns,
    stereo_camera_infos,
)
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.graph_readiness import NodeReport, unready_topics
from vehicle_common.kitti import KittiFormatError, TrackingSequence, check_stereo_calibration
from vehicle_common.node_parameters import (
    EXIT_BAD_PARAMETER,
    ParameterError,
    check_overrides,
    declare_config,
    parameter_error_line,
)
from vehicle_common.node_runtime import (
    DIAGNOSTICS_TOPIC,
    NodeHealth,
    StopRequest,
    apply_process_settings,
    init_rclpy,
    reports_from_message,
    spin_until_stopped,
)

from vehicle_common import topics

from .parameters import PlayerParameters
from .playback import (
    FrameEvent,
    FramePrefetcher,
    LockstepAnswers,
    PreloadWatch,
    StartGate,
    expected_topics,
    image_message,
    mixed_runs_line,
    noisy_pair,
    plan_playback,
    playing_line,
    progress_line,
    summary_line,
)

NODE_NAME = "kitti_player"


class PlayerError(RuntimeError):
    """A parameter or the dataset is unusable; the message names the field or file."""


class KittiPlayerNode(Node):
    """Publishes a KITTI tracking sequence frame by frame (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        self.params = p = dataclasses.asdict(declare_config(self, PlayerParameters))
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        if not p["dataset_root"]:
            raise ParameterError("dataset_root", "not set")
        self.sequence = TrackingSequence.open(p["dataset_root"], p["sequence"])
        # a pair the graph cannot range (no baseline) is refused here, not frame by frame later
        check_stereo_calibration(self.sequence.calib, self.sequence.calib_path)
        try:
            frames, self.scheduler, period, tick = plan_playback(p, self.sequence.frame_ids)
        except ValueError as exc:
            raise PlayerError(str(exc)) from None

        transport = p["image_transport"]
        image_type = Image if transport == "raw" else CompressedImage
        self.pub_left = self.create_publisher(
            image_type, topics.image_topic(topics.LEFT_IMAGE, transport), 5
        )
        self.pub_right = self.create_publisher(
            image_type, topics.image_topic(topics.RIGHT_IMAGE, transport), 5
        )
        self.pub_left_info = self.create_publisher(CameraInfo, topics.LEFT_INFO, 5)
        self.pub_right_info = self.create_publisher(CameraInfo, topics.RIGHT_INFO, 5)
        self.pub_gt = self.create_publisher(KittiFrameLabels, topics.GROUND_TRUTH, 10)
        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, 10)
        self.publishers_list = [self.pub_clock, self.pub_gt, self.pub_left_info]
        self.publishers_list += [self.pub_right_info, self.pub_left, self.pub_right]
        if p["lockstep"]:
            self.create_subscription(
                TrackedVehicleArray, p["lockstep_topic"], self._on_lockstep, 10
            )
        self.done = False
        self.error: str | None = None
        #: the run cannot go on (another graph on the lockstep topic): main() exits 1
        self.fatal: str | None = None
        self.answers = LockstepAnswers()  # one answer per published frame
        self._started = False
        self._summary_logged = False
        self.gate = StartGate(float(p["match_settle_time"]))
        wait, external = p["wait_for_topics"], p["external_subscribers"]
        try:
            self._expected = expected_topics(wait, external, self.resolve_topic_name)
        except ValueError as exc:
            raise PlayerError(str(exc)) from None
        self.reader = FramePrefetcher(self.sequence.read_stereo)
        self.preload = PreloadWatch(self.reader, p["preload_mib"], frames, self.scheduler)
        self.frames = FrameCounter()  # frames scheduled, published, dropped (drop_probability)
        self.health = NodeHealth(self, self.frames)
        # the other nodes' reports: matched subscriptions of the topics they publish
        self._reports: dict[str, NodeReport] = {}
        self._report_sub = None
        if set(self._expected) - {pub.topic_name for pub in self.publishers_list}:
            self._report_sub = self.create_subscription(
                DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_reports, 50
            )
        self.timer = self.create_timer(tick, self._tick)
        self.get_logger().info(playing_line(self.sequence, frames, period, p))

    def _on_reports(self, msg: DiagnosticArray) -> None:
        for report in reports_from_message(msg):
            self._reports[report.node] = report

    def _unready(self) -> list[str]:
        """Topics of the graph not yet matched as expected (own publishers: also every
        subscription the ROS graph already knows of)."""
        own = {p.topic_name: p.get_subscription_count() for p in self.publishers_list}
        expected = dict(self._expected)
        for topic in own:  # a subscriber the ROS graph knows of must have matched too
            expected[topic] = max(expected.get(topic, 0), self.count_subscribers(topic))
        return unready_topics(expected, own, self._reports.values())

    def _on_lockstep(self, msg: TrackedVehicleArray) -> None:
        stamp = stamp_ns(msg.header)
        problem = self.answers.answer(stamp)
        if problem is not None and self.fatal is None:
            topic = self.resolve_topic_name(self.params["lockstep_topic"])
            self.fatal = mixed_runs_line(NODE_NAME, topic, problem, self.count_publishers(topic))
            self.done = True
            return
        if self.scheduler.acknowledge(stamp):
            self._tick()

    def _tick(self) -> None:
        if self.done or self._summary_logged:
            return
        now = time.monotonic()
        if not self._started:
            if not self._preload_done():
                return
            want = int(self.params["wait_for_subscribers"])
            have = self.pub_left.get_subscription_count()
            start, line = self.gate.check(now, have, want, self._unready())
            if line is not None:
                self.get_logger().info(line)
            if not start:
                return
            self._started = True
            if self._report_sub is not None:
                self.destroy_subscription(self._report_sub)
                self._report_sub = None
            if self._expected:
                self.get_logger().info("every edge of the graph matched: playing")
        # in lockstep every frame the window has room for goes out now; else one per tick
        while self._next_frame(now) and self.params["lockstep"]:
            pass
        if self.done:
            return
        if self.scheduler.finished:
            self._log_summary()
            if self.params["exit_when_done"]:
                self.done = True

    def _next_frame(self, now: float) -> bool:
        """Publish (or drop) the frame due at ``now``; False when none is due or on an error."""
        timeouts = self.scheduler.stats.lockstep_timeouts
        event = self.scheduler.poll(now)
        if self.scheduler.stats.lockstep_timeouts > timeouts:
            self.get_logger().warning(
                f"lockstep: no message on {self.params['lockstep_topic']} within "
                f"{self.params['lockstep_timeout']} s, going on"
            )
        if event is None:
            return False
        self.frames.received()
        if event.dropped:
            self.frames.dropped()
            self.reader.prefetch(self.scheduler.next_frame)  # the next one is read ahead too
        else:
            try:
                self._publish(event)
                self.answers.published(event.stamp_ns)
            except KittiFormatError as exc:
                self.error = str(exc)  # main() prints it as the one error line
                self.done = True
                return False
            self.frames.published()
        line = progress_line(self.scheduler.stats, event.frame)
        if line is not None:
            self.get_logger().info(line)
        return True

    def _publish(self, event: FrameEvent) -> None:
        left, right = self.reader.get(event.frame)
        self.reader.prefetch(self.scheduler.next_frame)  # read while the graph works
        left, right = noisy_pair(
            left, right, float(self.params["snr_db"]), self.params["seed"], event
        )
        calib, stamp = self.sequence.calib, event.stamp_ns
        clock = Clock()
        clock.clock = header(stamp, "").stamp
        self.trace("clock", stamp)  # the frame's time 0 (VEHICLE_TRACE_DIR)
        self.pub_clock.publish(clock)
        objects = self.sequence.objects(event.frame)
        self.pub_gt.publish(
            ground_truth_message(self.sequence.sequence, event.frame, calib, objects, stamp)
        )
        h, w = left.shape[:2]
        left_info, right_info = stereo_camera_infos(calib, w, h, stamp)
        self.pub_left_info.publish(left_info)
        self.pub_right_info.publish(right_info)
        transport, quality = self.params["image_transport"], self.params["jpeg_quality"]
        self.pub_left.publish(image_message(left, header(stamp, LEFT_FRAME), transport, quality))
        self.trace("left_published", stamp)
        self.pub_right.publish(image_message(right, header(stamp, RIGHT_FRAME), transport, quality))
        self.trace("right_published", stamp)

    def _preload_done(self) -> bool:
        """False while the frames are being read into memory; logs the preload once."""
        done, line = self.preload.done(self.scheduler)
        if line is not None:
            self.get_logger().info(line)
        return done

    def _log_summary(self) -> None:
        if self._summary_logged:
            return
        self._summary_logged = True
        line = summary_line(self.scheduler.stats)
        if self.scheduler.stats.lockstep_timeouts:
            self.get_logger().warning(line)
        else:
            self.get_logger().info(line)

    def flush(self, timeout_s: float = 2.0) -> None:
        """Wait until subscribers acknowledged everything published (reliable QoS), at most
        ``timeout_s`` in all (a frozen subscriber acknowledges nothing: waiting that long for
        each publisher made the player's stop take 4 x 2 s)."""
        deadline = time.monotonic() + timeout_s
        for pub in self.publishers_list:
            left = max(0.0, deadline - time.monotonic())
            pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))


def main(args: list[str] | None = None) -> int:
    """Console script ``kitti_player``; returns the exit code (2 for a bad dataset/parameter).
    SIGINT/SIGTERM: no frame is published after the signal, the frames already published are
    flushed to their subscribers, and the process exits with 0."""
    if not init_rclpy(args, NODE_NAME):
        return EXIT_BAD_PARAMETER
    stop = StopRequest.install()
    node = None
    try:
        try:
            node = KittiPlayerNode()
        except ParameterError as exc:
            print(parameter_error_line(NODE_NAME, exc), file=sys.stderr)
            return EXIT_BAD_PARAMETER
        except (KittiFormatError, PlayerError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        spin_until_stopped(node, stop, node.health, on_stop=[node.flush], done=lambda: node.done)
        if node.fatal is not None:
            print(f"error: {node.fatal}", file=sys.stderr)
            return 1
        if node.error is not None:
            print(f"error: {node.error}", file=sys.stderr)
            return 2
        return 0
    except KeyboardInterrupt:  # stopped during start-up
        return 0
    finally:
        if node is not None:
            node.reader.close()
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
