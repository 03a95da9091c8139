"""Reading a recorded run (rosbag2/MCAP bag) back into per-frame KITTI-style objects.

:func:`read_run` returns a :class:`RecordedRun`: one :class:`RecordedFrame` per recorded
``/kitti/ground_truth`` message (frame index, stamp, camera offset, ground truth) holding the
2D detections, 3D detections and tracks with the same stamp, converted to
:class:`kitti_player_node.kitti.KittiObject` in camera-0 coordinates (KITTI label convention):
``p_cam0 = p_left - left_camera_offset``, centre of mass -> bottom centre ``y + h/2``, size from
the message or the KITTI mean car, alpha from the orientation bin (folded, so ambiguous by pi)
or from the track's yaw. The raw 3D detections (left optical frame) are kept too, for re-running
the tracker offline. Pure core: rosbags only, no rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from detector_node.orientation import bin_to_alpha
from kitti_player_node.bag_replay import BagError, open_reader
from kitti_player_node.frame_messages import bbox_to_xyxy, kitti_objects_from_message, stamp_ns
from kitti_player_node.kitti import (
    MEAN_CAR_DIMENSIONS,
    KittiObject,
    alpha_from_rotation_y,
    rotation_y_from_alpha,
    wrap_angle,
)

GT_TOPIC = "/kitti/ground_truth"
DET2D_TOPIC = "/vehicles/detections_2d"
DET3D_TOPIC = "/vehicles/detections_3d"
TRACKS_TOPIC = "/vehicles/tracks"
LEFT_IMAGE_TOPIC = "/stereo/left/image_rect"
LEFT_INFO_TOPIC = "/stereo/left/camera_info"
#: Track states reported as tracker output (confirmed and coasting; tentative ones are not).
OUTPUT_STATES = (1, 2)


class BagReadError(BagError):
    """A bag is missing, unreadable or lacks what the evaluation needs (message names it)."""


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
    track_velocities: list[np.ndarray] = field(default_factory=list)  # (3,) per track [m/s]
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


def det3d_to_object(det, offset: np.ndarray, frame: int) -> KittiObject:
    """A VehicleDetection3D as a KITTI result row (camera 0, bottom centre, mean car size)."""
    h, w, length = MEAN_CAR_DIMENSIONS  # message carries no size
    x, y, z = np.array([det.position.x, det.position.y, det.position.z], dtype=float) - offset
    alpha = bin_to_alpha(det.orientation_bin)
    return KittiObject(
        type="Car",
        alpha=alpha,
        bbox=bbox_to_xyxy(det.bbox),
        dimensions=(h, w, length),
        location=(float(x), float(y + h / 2.0), float(z)),
        rotation_y=rotation_y_from_alpha(alpha, x, z),
        frame=frame,
        score=float(det.score),
    )


def _track_object(v, offset: np.ndarray, frame: int) -> KittiObject:
    length, w, h = float(v.size.x), float(v.size.y), float(v.size.z)
    if not (length > 0 and w > 0 and h > 0):
        h, w, length = MEAN_CAR_DIMENSIONS  # message carries no size
    x, y, z = np.array([v.position.x, v.position.y, v.position.z], dtype=float) - offset
    yaw = wrap_angle(float(v.yaw))
    return KittiObject(
        type="Car",
        alpha=alpha_from_rotation_y(yaw, x, z),
        bbox=bbox_to_xyxy(v.bbox),
        dimensions=(h, w, length),
        location=(float(x), float(y + h / 2.0), float(z)),
        rotation_y=yaw,
        frame=frame,
        track_id=int(v.track_id),
        score=float(v.confidence),
    )


def read_run(
    path: str | Path,
    track_states: tuple[int, ...] = OUTPUT_STATES,
    progress: bool = False,
) -> RecordedRun:
    """Read a recorded run. Frames come from ``/kitti/ground_truth``; without it, every stamp
    of the pipeline's topics becomes a frame (index in stamp order, no ground truth).
    Tracks whose state is not in ``track_states`` are dropped."""
    reader = open_reader(path)
    wanted = {GT_TOPIC, DET2D_TOPIC, DET3D_TOPIC, TRACKS_TOPIC, LEFT_INFO_TOPIC}
    topics = {c.topic: c.msgcount for c in reader.connections}
    conns = [c for c in reader.connections if c.topic in wanted]
    gts: dict[int, object] = {}
    msgs: dict[str, dict[int, tuple[object, int]]] = {t: {} for t in wanted}
    P_left, image_size, info_seen = None, None, None
    if not conns:
        reader.close()
        raise BagReadError(f"{path}: none of the pipeline's topics ({', '.join(sorted(wanted))})")
    try:
        it = reader.messages(connections=conns)
        if progress:
            from tqdm import tqdm

            total = sum(c.msgcount for c in conns)
            it = tqdm(it, total=total, desc="reading bag", unit="msg")
        for conn, t_ns, raw in it:
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise BagReadError(f"{path}: {conn.topic}: cannot deserialise ({exc})") from None
            if conn.topic == LEFT_INFO_TOPIC:
                info_seen = msg
                continue
            stamp = stamp_ns(msg.header)
            if conn.topic == GT_TOPIC:
                gts[stamp] = msg
            msgs[conn.topic][stamp] = (msg, int(t_ns))
    finally:
        reader.close()

    sequence = ""
    frames: dict[int, RecordedFrame] = {}
    if gts:
        for stamp, m in gts.items():
            sequence = sequence or str(m.sequence)
            off = np.array(m.left_camera_offset, dtype=float).reshape(3)
            f = RecordedFrame(frame=int(m.frame_index), stamp_ns=stamp, offset=off)
            f.gt = kitti_objects_from_message(m)
            f.receive_ns[GT_TOPIC] = msgs[GT_TOPIC][stamp][1]
            frames[stamp] = f
    else:
        stamps = sorted({s for t in (DET2D_TOPIC, DET3D_TOPIC, TRACKS_TOPIC) for s in msgs[t]})
        for i, s in enumerate(stamps):
            frames[s] = RecordedFrame(frame=i, stamp_ns=s, offset=np.zeros(3))

    if info_seen is not None:
        K = np.array(info_seen.k, dtype=float).reshape(3, 3)
        image_size = (int(info_seen.width), int(info_seen.height))
        if gts:
            off = next(iter(frames.values())).offset
            P_left = K @ np.hstack([np.eye(3), off[:, None]])

    unmatched = 0
    for topic in (DET2D_TOPIC, DET3D_TOPIC, TRACKS_TOPIC):
        for stamp, (m, t_ns) in msgs[topic].items():
            f = frames.get(stamp)
            if f is None:
                unmatched += 1
                continue
            f.receive_ns[topic] = t_ns
            if topic == DET2D_TOPIC:
                for d in m.detections:
                    f.det2d.append(
                        KittiObject(
                            type="Car",
                            alpha=bin_to_alpha(int(d.orientation_bin)),
                            bbox=bbox_to_xyxy(d.bbox),
                            frame=f.frame,
                            score=float(d.score),
                        )
                    )
            elif topic == DET3D_TOPIC:
                f.det3d_msg = m
                f.det3d = [det3d_to_object(d, f.offset, f.frame) for d in m.detections]
            else:
                for v in m.vehicles:
                    if int(v.state) not in track_states:
                        continue
                    f.tracks.append(_track_object(v, f.offset, f.frame))
                    f.track_velocities.append(
                        np.array([v.velocity.x, v.velocity.y, v.velocity.z], dtype=float)
                    )
    ordered = sorted(frames.values(), key=lambda f: (f.frame, f.stamp_ns))
    return RecordedRun(
        path=Path(path),
        sequence=sequence,
        frames=ordered,
        topics=topics,
        P_left=P_left,
        image_size=image_size,
        unmatched_stamps=unmatched,
    )


def read_left_images(path: str | Path, stamps: set[int] | None = None) -> dict[int, np.ndarray]:
    """Left images of a bag as RGB arrays, keyed by stamp [ns] (only ``stamps`` when given)."""
    from kitti_player_node.image_conversion import image_to_rgb

    reader = open_reader(path)
    out: dict[int, np.ndarray] = {}
    try:
        conns = [c for c in reader.connections if c.topic == LEFT_IMAGE_TOPIC]
        if not conns:  # (rosbags reads every connection when given none)
            return out
        for conn, _t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            s = stamp_ns(msg.header)
            if stamps is None or s in stamps:
                out[s] = image_to_rgb(msg)
    finally:
        reader.close()
    return out
