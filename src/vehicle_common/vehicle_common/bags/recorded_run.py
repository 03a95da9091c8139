"""Reading a recorded run (rosbag2/MCAP bag) back into per-frame KITTI-style objects.

:func:`read_run` returns a :class:`RecordedRun`: one :class:`RecordedFrame` per recorded
``/kitti/ground_truth`` message (frame index, stamp, camera offset, ground truth) holding the
2D detections, 3D detections and tracks with the same stamp, converted to
:class:`vehicle_common.kitti.KittiObject` in camera-0 coordinates (KITTI label convention):
through :mod:`vehicle_common.camera_frames` (size from the message or the KITTI mean car, alpha
from the orientation bin (folded, so ambiguous by pi) or from the track's yaw; rows that are not
finite are dropped). The raw 3D detections (left optical frame) are kept too, for re-running
the tracker offline. Tracks published in another frame than the camera's (the tracker's
``tracks_frame``, e.g. ``odom``) are brought back into the camera's frame with the recorded
/tf and /tf_static (:func:`tracks_in_camera_frame`). Pure core: rosbags only, no rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .. import topics
from ..camera_frames import kitti_row_from_centre
from ..frame_messages import bbox_to_xyxy, kitti_objects_from_message, stamp_ns
from ..kitti import KittiObject
from ..odometry import Pose
from ..odometry_messages import TransformTree
from ..orientation_bins import bin_to_alpha
from .reader import BagError, bag_messages, open_reader
from .repeated_stamps import mixed_runs_hint

#: the graph's topics as recorded without a namespace (see :func:`bag_namespace`)
GT_TOPIC = topics.resolve(topics.GROUND_TRUTH)
DET2D_TOPIC = topics.resolve(topics.DETECTIONS_2D)
DET3D_TOPIC = topics.resolve(topics.DETECTIONS_3D)
TRACKS_TOPIC = topics.resolve(topics.TRACKS)
LEFT_IMAGE_TOPIC = topics.resolve(topics.LEFT_IMAGE)
LEFT_INFO_TOPIC = topics.resolve(topics.LEFT_INFO)
TF_TOPIC = topics.resolve(topics.TF)
TF_STATIC_TOPIC = topics.resolve(topics.TF_STATIC)
#: Track states reported as tracker output (confirmed and coasting; tentative ones are not).
OUTPUT_STATES = (1, 2)
#: Track states ranked by the tracks' 3D AP: the output plus tentative tracks (state 0), whose
#: score the tracker lowers by their progress toward confirmation (tracker_node.lifecycle), so
#: they rank after confirmed ones. CLEAR-MOT / HOTA take the output states only.
RANKED_STATES = (0, 1, 2)


class BagReadError(BagError):
    """A bag is missing, unreadable or lacks what the evaluation needs (message names it)."""


@dataclass(frozen=True)
class FrameGrid:
    """Where a run without ``/kitti/ground_truth`` puts each stamp: frame
    ``round((stamp - start_s) / period_s)``, the KITTI player's stamps (its ``start_time``,
    default 1.0 s, and 10 Hz dataset time: kitti_player_node.playback.stamp_ns). Scoring such a
    run against label files by stamp order shifted every frame after a missing one (issue #42:
    13 of 16 frames, MOTA 0.0)."""

    start_s: float = 1.0
    period_s: float = 0.1
    #: largest distance of a stamp from its grid point [s] (the player's stamps are exact)
    tolerance_s: float = 0.001

    def frame(self, stamp: int, path) -> int:
        """The frame of ``stamp`` [ns]; BagReadError (one line) when it is off the grid."""
        offset = stamp * 1e-9 - self.start_s
        k = round(offset / self.period_s)
        if k < 0 or abs(offset - k * self.period_s) > self.tolerance_s:
            raise BagReadError(
                f"{path}: stamp {stamp * 1e-9:.6f} s is not on the KITTI player's frame grid "
                f"(frame 0 at {self.start_s:g} s, {self.period_s:g} s a frame), and the bag has "
                f"no {GT_TOPIC} to number the frames: give the player's start_time with "
                "--start-time, or record the ground truth"
            )
        return int(k)


@dataclass
class RecordedFrame:
    """Everything recorded for one frame (one stamp)."""

    frame: int
    stamp_ns: int
    offset: np.ndarray  # left_camera_offset (3,)
    gt: list[KittiObject] = field(default_factory=list)
    det2d: list[KittiObject] = field(default_factory=list)
    det3d: list[KittiObject] = field(default_factory=list)
    det3d_msg: object | None = None  # the recorded VehicleDetection3DArray (tracker input)
    tracks: list[KittiObject] = field(default_factory=list)
    tentative: list[KittiObject] = field(default_factory=list)  # state-0 tracks (AP only)
    track_velocities: list[np.ndarray] = field(default_factory=list)  # (3,) per track [m/s]
    # (3,) per track: velocity over the ground [m/s] (TrackedVehicle.velocity_over_ground), NaN
    # when unknown or recorded before the field existed
    track_ground_velocities: list[np.ndarray] = field(default_factory=list)
    receive_ns: dict[str, int] = field(default_factory=dict)  # topic -> receive time [ns]


@dataclass
class RecordedRun:
    """A recorded run: frames in frame order plus what was seen in the bag."""

    path: Path
    sequence: str
    frames: list[RecordedFrame]
    topics: dict[str, int]  # topic -> message count
    P_left: np.ndarray | None  # 3x4 projection of camera-0 points into the left image
    image_size: tuple[int, int] | None  # (width, height)
    unmatched_stamps: int = 0  # messages whose stamp has no ground-truth frame


def det3d_to_object(det, offset: np.ndarray, frame: int) -> KittiObject | None:
    """A VehicleDetection3D as a KITTI result row (camera 0, bottom centre, mean car size: the
    message carries no size; alpha from the orientation bin); None when not finite."""
    return kitti_row_from_centre(
        (det.position.x, det.position.y, det.position.z),
        None,
        bbox_to_xyxy(det.bbox),
        offset,
        alpha=bin_to_alpha(det.orientation_bin),
        frame=frame,
        score=float(det.score),
    )


def _track_object(v, offset: np.ndarray, frame: int) -> KittiObject | None:
    """A TrackedVehicle as a KITTI result row (mean car size when it has none); None when not
    finite."""
    return kitti_row_from_centre(
        (v.position.x, v.position.y, v.position.z),
        (v.size.x, v.size.y, v.size.z),
        bbox_to_xyxy(v.bbox),
        offset,
        yaw=float(v.yaw),
        frame=frame,
        track_id=int(v.track_id),
        score=float(v.confidence),
    )


def _ground_velocity(v) -> np.ndarray:
    """A TrackedVehicle's velocity over the ground (3,), NaN when unknown (covariance[0] < 0) or
    absent (recorded before the field existed)."""
    g = getattr(v, "velocity_over_ground", None)
    cov = getattr(v, "velocity_over_ground_covariance", None)
    if g is None or cov is None or not cov[0] >= 0:
        return np.full(3, np.nan)
    return np.array([g.x, g.y, g.z], dtype=float)


def _vector(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


def _xyz(a) -> SimpleNamespace:
    return SimpleNamespace(x=float(a[0]), y=float(a[1]), z=float(a[2]))


def tracks_in_camera_frame(msg, camera_pose: Pose) -> list:
    """The vehicles of a TrackedVehicleArray published in another frame, as seen from the
    camera whose pose in that frame is ``camera_pose``: position and velocities moved and
    rotated back, the yaw (about that frame's z axis) back to KITTI's rotation about the
    camera's y axis (the inverse of tracker_node.conversions.TrackGeometry); other fields as
    they are."""
    inv = camera_pose.inverse()
    out = []
    for v in msg.vehicles:
        heading = inv.rotation @ np.array([np.cos(v.yaw), np.sin(v.yaw), 0.0])
        out.append(
            SimpleNamespace(
                track_id=v.track_id,
                state=v.state,
                confidence=v.confidence,
                size=v.size,
                bbox=v.bbox,
                position=_xyz(inv.apply(_vector(v.position))),
                yaw=float(np.arctan2(-heading[2], heading[0])),
                velocity=_xyz(inv.rotation @ _vector(v.velocity)),
                velocity_over_ground=_xyz(inv.rotation @ _vector(v.velocity_over_ground)),
                velocity_over_ground_covariance=v.velocity_over_ground_covariance,
            )
        )
    return out


def bag_namespace(topic_names) -> str:
    """The namespace the recorded graph ran in, from a bag's topic names: the one in which
    ``kitti/ground_truth`` (else ``vehicles/tracks``) appears; ``""`` when none or ambiguous."""
    for topic in (topics.GROUND_TRUTH, topics.TRACKS):
        ns = topics.namespace_of(topic_names, topic)
        if ns is not None:
            return ns
    return ""


#: the topics :func:`read_run` reads (as recorded without a namespace)
_RUN_TOPICS = (
    GT_TOPIC,
    DET2D_TOPIC,
    DET3D_TOPIC,
    TRACKS_TOPIC,
    LEFT_INFO_TOPIC,
    TF_TOPIC,
    TF_STATIC_TOPIC,
)
#: the pipeline's per-frame outputs, attached to the frames by stamp
_OUTPUT_TOPICS = (DET2D_TOPIC, DET3D_TOPIC, TRACKS_TOPIC)


@dataclass
class _RunMessages:
    """What :func:`read_run` takes from a bag before building frames: per topic (its name
    without namespace) ``stamp -> (message, receive time [ns])``, the last left camera_info and
    every recorded transform."""

    name: dict[str, str]  # topic -> its name in the bag (namespaced)
    msgs: dict[str, dict[int, tuple[object, int]]]
    info: object | None = None
    transforms: TransformTree = field(default_factory=lambda: TransformTree(history=10**9))
    repeated: dict[str, int] = field(default_factory=dict)  # topic -> stamps seen again

    def add(self, topic: str, msg, t_ns: int, path) -> None:
        """Note one deserialised message of ``topic``."""
        if topic == LEFT_INFO_TOPIC:
            self.info = msg
            return
        if topic in (TF_TOPIC, TF_STATIC_TOPIC):
            try:
                self.transforms.add_message(msg, static=topic == TF_STATIC_TOPIC)
            except ValueError as exc:
                raise BagReadError(f"{path}: {self.name[topic]}: {exc}") from None
            return
        stamp = stamp_ns(msg.header)
        if stamp in self.msgs[topic]:
            self.repeated[topic] = self.repeated.get(topic, 0) + 1
        self.msgs[topic][stamp] = (msg, t_ns)


def read_run(
    path: str | Path,
    track_states: tuple[int, ...] = OUTPUT_STATES,
    progress: bool = False,
    namespace: str | None = None,
    frame_grid: FrameGrid | None = None,
) -> RecordedRun:
    """Read a recorded run. Frames come from ``/kitti/ground_truth``; without it, every stamp
    of the pipeline's topics becomes a frame (no ground truth): numbered by its stamp on
    ``frame_grid`` when given (frames between the first and the last with no output at all
    are kept, empty: scored as missed), else in stamp order.
    Tracks whose state is not in ``track_states`` are dropped (tentative ones go to
    ``RecordedFrame.tentative``, for the tracks' AP). ``namespace``: the namespace
    the graph ran in (``/rig2``); None: detected from the bag's topics (:func:`bag_namespace`)."""
    reader = open_reader(path)
    counts = {c.topic: c.msgcount for c in reader.connections}
    if namespace is None:
        namespace = bag_namespace(counts)
    run = _read_messages(reader, path, namespace, progress)
    _refuse_mixed_runs(run, path)
    if run.msgs[GT_TOPIC]:
        frames, sequence = _ground_truth_frames(run.msgs[GT_TOPIC])
    else:
        frames, sequence = _output_frames(run.msgs, path, frame_grid), ""
    P_left, image_size = _left_camera(run.info, bool(run.msgs[GT_TOPIC]), frames)
    unmatched = _attach_outputs(frames, run, path, track_states)
    ordered = sorted(frames.values(), key=lambda f: (f.frame, f.stamp_ns))
    return RecordedRun(
        path=Path(path),
        sequence=sequence,
        frames=ordered,
        topics=counts,
        P_left=P_left,
        image_size=image_size,
        unmatched_stamps=unmatched,
    )


def _read_messages(reader, path, namespace: str, progress: bool) -> _RunMessages:
    """Every message of ``_RUN_TOPICS`` (in ``namespace``) of the opened ``reader``, which
    is closed; BagReadError when the bag holds none of them or one cannot be read."""
    name = {t: topics.resolve(t.lstrip("/"), namespace) for t in _RUN_TOPICS}
    recorded = {v: k for k, v in name.items()}  # namespaced name -> the name used below
    wanted = set(name.values())
    conns = [c for c in reader.connections if c.topic in wanted]
    if not conns:
        reader.close()
        raise BagReadError(f"{path}: none of the pipeline's topics ({', '.join(sorted(wanted))})")
    run = _RunMessages(name=name, msgs={t: {} for t in name})
    try:
        it = bag_messages(reader, path, conns)  # a damaged chunk: one line naming it
        if progress:
            from tqdm import tqdm

            total = sum(c.msgcount for c in conns)
            it = tqdm(it, total=total, desc="reading bag", unit="msg")
        for conn, t_ns, raw in it:
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise BagReadError(f"{path}: {conn.topic}: cannot deserialise ({exc})") from None
            run.add(recorded[conn.topic], msg, int(t_ns), path)
    finally:
        reader.close()
    return run


def _refuse_mixed_runs(run: _RunMessages, path) -> None:
    """BagReadError when a per-frame topic holds a stamp twice: the bag mixes two runs."""
    if run.repeated:
        topic, n = max(run.repeated.items(), key=lambda kv: kv[1])
        raise BagReadError(
            f"{path}: mixes more than one run: {run.name[topic]} holds {n} stamp(s) more than "
            f"once (one message per frame and stamp in a run); {mixed_runs_hint()}"
        )


def _ground_truth_frames(gts: dict[int, tuple]) -> tuple[dict[int, RecordedFrame], str]:
    """One frame per recorded ground-truth message (stamp -> frame), and the sequence."""
    sequence = ""
    frames: dict[int, RecordedFrame] = {}
    for stamp, (m, t_ns) in gts.items():
        sequence = sequence or str(m.sequence)
        off = np.array(m.left_camera_offset, dtype=float).reshape(3)
        f = RecordedFrame(frame=int(m.frame_index), stamp_ns=stamp, offset=off)
        f.gt = kitti_objects_from_message(m)
        f.receive_ns[GT_TOPIC] = t_ns
        frames[stamp] = f
    return frames, sequence


def _output_frames(msgs, path, frame_grid: FrameGrid | None) -> dict[int, RecordedFrame]:
    """Without ground truth: one frame per stamp of the pipeline's outputs, numbered on
    ``frame_grid`` (the frames between with no output at all kept, empty) or in stamp order."""
    frames: dict[int, RecordedFrame] = {}
    stamps = sorted({s for t in _OUTPUT_TOPICS for s in msgs[t]})
    for i, s in enumerate(stamps):
        k = i if frame_grid is None else frame_grid.frame(s, path)
        frames[s] = RecordedFrame(frame=k, stamp_ns=s, offset=np.zeros(3))
    if frame_grid is not None and stamps:  # a frame with no output at all: nothing tracked
        seen = {f.frame for f in frames.values()}
        for k in range(min(seen), max(seen) + 1):
            if k not in seen:
                s = int(round((frame_grid.start_s + k * frame_grid.period_s) * 1e9))
                frames[s] = RecordedFrame(frame=k, stamp_ns=s, offset=np.zeros(3))
    return frames


def _left_camera(info, has_gt: bool, frames: dict[int, RecordedFrame]):
    """(P_left, image size) from the recorded left camera_info: P_left (camera-0 points into
    the left image) only with ground truth, which gives the camera offset; Nones without it."""
    if info is None:
        return None, None
    K = np.array(info.k, dtype=float).reshape(3, 3)
    image_size = (int(info.width), int(info.height))
    P_left = None
    if has_gt:
        off = next(iter(frames.values())).offset
        P_left = K @ np.hstack([np.eye(3), off[:, None]])
    return P_left, image_size


def _attach_outputs(frames, run: _RunMessages, path, track_states) -> int:
    """The 2D detections, 3D detections and tracks attached to their frames by stamp; returns
    how many messages have a stamp without a frame."""
    camera_frame = run.info.header.frame_id if run.info is not None else None
    unmatched = 0
    for topic in _OUTPUT_TOPICS:
        for stamp, (m, t_ns) in run.msgs[topic].items():
            f = frames.get(stamp)
            if f is None:
                unmatched += 1
                continue
            f.receive_ns[topic] = t_ns
            if topic == DET2D_TOPIC:
                f.det2d.extend(_det2d_object(d, f.frame) for d in m.detections)
            elif topic == DET3D_TOPIC:
                f.det3d_msg = m
                rows = (det3d_to_object(d, f.offset, f.frame) for d in m.detections)
                f.det3d = [r for r in rows if r is not None]
            else:
                camera = f.det3d_msg.header.frame_id if f.det3d_msg is not None else camera_frame
                _add_tracks(f, _tracks_in_camera(m, camera, stamp, run, path), track_states)
    return unmatched


def _det2d_object(d, frame: int) -> KittiObject:
    """A VehicleDetection2D as a KITTI result row (alpha from the orientation bin)."""
    return KittiObject(
        type="Car",
        alpha=bin_to_alpha(int(d.orientation_bin)),
        bbox=bbox_to_xyxy(d.bbox),
        frame=frame,
        score=float(d.score),
    )


def _tracks_in_camera(m, camera: str | None, stamp: int, run: _RunMessages, path) -> list:
    """The vehicles of a TrackedVehicleArray as seen from the camera: as they are when
    published in the camera's frame, else moved with the recorded transforms."""
    if not (camera and m.header.frame_id and m.header.frame_id != camera):
        return m.vehicles
    pose = run.transforms.lookup(m.header.frame_id, camera, stamp)
    if pose is None:
        raise BagReadError(
            f"{path}: {run.name[TRACKS_TOPIC]}: tracks in {m.header.frame_id!r} at "
            f"stamp {stamp} ns and no recorded transform to {camera!r} "
            f"({run.name[TF_TOPIC]}, {run.name[TF_STATIC_TOPIC]})"
        )
    return tracks_in_camera_frame(m, pose)


def _add_tracks(f: RecordedFrame, vehicles, track_states) -> None:
    """The tracks of one frame: those in ``track_states`` as output (with their velocities),
    the other ranked ones (tentative) for the tracks' AP only."""
    for v in vehicles:
        output = int(v.state) in track_states
        if not output and int(v.state) not in RANKED_STATES:
            continue
        row = _track_object(v, f.offset, f.frame)
        if row is None:
            continue
        if not output:
            f.tentative.append(row)
            continue
        f.tracks.append(row)
        f.track_velocities.append(_vector(v.velocity))
        f.track_ground_velocities.append(_ground_velocity(v))


def read_left_images(
    path: str | Path, stamps: set[int] | None = None, namespace: str | None = None
) -> dict[int, np.ndarray]:
    """Left images of a bag as RGB arrays, keyed by stamp [ns] (only ``stamps`` when given;
    ``namespace`` as in :func:`read_run`)."""
    from ..image_conversion import image_to_rgb

    reader = open_reader(path)
    out: dict[int, np.ndarray] = {}
    try:
        if namespace is None:
            namespace = bag_namespace([c.topic for c in reader.connections])
        left = topics.resolve(topics.LEFT_IMAGE, namespace)
        conns = [c for c in reader.connections if c.topic == left]
        if not conns:  # (rosbags reads every connection when given none)
            return out
        for conn, _t, raw in bag_messages(reader, path, conns):
            msg = reader.deserialize(raw, conn.msgtype)
            s = stamp_ns(msg.header)
            if stamps is None or s in stamps:
                out[s] = image_to_rgb(msg)
    finally:
        reader.close()
    return out
