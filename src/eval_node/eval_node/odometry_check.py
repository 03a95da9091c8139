"""Checks of the graph's odometry on real KITTI: its path against reference camera poses
(``poses_orbslam3``) and against the motion of the labelled parked cars, and how still parked
cars stand in ``odom`` (the tracker's ``tracks_frame: odom``). Pure core (numpy, rosbags); the
odometry bench (bench/bench_odometry.py) and the tests call it.

- **Reference path.** ``poses_orbslam3/SSSS.txt`` holds ORB-SLAM3's left-camera poses in the
  first frame's camera coordinates (KITTI odometry format). An estimate: on 0005 it steps
  1.87 m per frame over frames 0-15, while the labelled parked cars move 1.78 m per frame
  relative to the camera (the LiDAR-labelled boxes of two or three cars at 25-70 m, agreeing
  with each other within a few cm per step). :func:`label_scale` measures that ratio from the
  labels of the frames checked, and :func:`path_agreement` compares the odometry with the
  reference as it is and rescaled by it.
- **Path agreement.** Both paths start at the first checked frame; the error at a frame is the
  distance between the two camera positions there; ``max_error_pct`` is its largest value over
  the run in percent of the reference's distance travelled (KITTI's odometry benchmark uses
  the same kind of ratio over segments), ``length_ratio`` the ratio of the distances travelled.
- **Parked cars in odom.** A labelled car (Car, Van, Truck) is parked when its centre, taken to
  ``odom`` with the odometry, moves less than ``parked_span`` over the frames it is labelled in;
  the confirmed and coasting tracks nearest to it (within ``match_distance``) are its track;
  their positions' largest distance from each other over the run is the car's spread, compared
  with its labelled length.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from vehicle_common.bags.reader import bag_messages, open_reader
from vehicle_common.camera_frames import centre_from_kitti
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.frame_messages import kitti_objects_from_message, read_transform, stamp_ns
from vehicle_common.odometry import Pose
from vehicle_common.odometry_messages import TransformTree

from vehicle_common import topics

VEHICLE_TYPES = ("Car", "Van", "Truck")
OUTPUT_STATES = (1, 2)  # confirmed, coasting


def read_reference_poses(path: str | Path) -> list[Pose]:
    """Camera poses of a KITTI-odometry-format file (one row-major 3x4 ``[R | t]`` per frame:
    ``X_first = R X_k + t``) as the camera's pose in the first frame's camera."""
    rows = np.loadtxt(path, ndmin=2).reshape(-1, 3, 4)
    return [Pose(m[:, :3], m[:, 3]) for m in rows]


@dataclass
class OdometryFrame:
    """One recorded frame: its index, stamp, the camera's pose in odom (None: no /tf), the
    camera motion its 3D array carried (None: not measured), its odometry message's position
    and 6x6 pose covariance (None: none recorded), the labelled vehicles (type, centre in the
    left optical frame, length) and the tracks as published (id, state, position in the
    tracks' frame)."""

    frame: int
    stamp_ns: int
    camera_pose: Pose | None = None
    motion: CameraMotion | None = None
    odometry: tuple[np.ndarray, np.ndarray] | None = None
    labels: list[tuple[int, str, np.ndarray, float]] = field(default_factory=list)
    tracks_frame: str = ""
    tracks: list[tuple[int, int, np.ndarray]] = field(default_factory=list)


def read_odometry_run(bag: str | Path, odom_frame: str = "odom", namespace: str = "") -> list:
    """The frames of a recorded run (ground truth, /tf, /tf_static, tracks), in frame order."""
    name = {
        t: topics.resolve(t, namespace)
        for t in (topics.GROUND_TRUTH, topics.TRACKS, topics.DETECTIONS_3D, topics.ODOMETRY)
    }
    tf_topics = {topics.resolve(topics.TF, namespace): False}
    tf_topics[topics.resolve(topics.TF_STATIC, namespace)] = True
    reader = open_reader(bag)
    tree = TransformTree(history=10**9)
    frames: dict[int, OdometryFrame] = {}
    tracks: dict[int, object] = {}
    motions: dict[int, CameraMotion | None] = {}
    odometry: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    camera = ""
    try:
        wanted = {*name.values(), *tf_topics}
        conns = [c for c in reader.connections if c.topic in wanted]
        for conn, _, raw in bag_messages(reader, bag, conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic in tf_topics:
                tree.add_message(msg, static=tf_topics[conn.topic])
            elif conn.topic == name[topics.GROUND_TRUTH]:
                s = stamp_ns(msg.header)
                camera = camera or msg.header.frame_id
                f = frames.setdefault(s, OdometryFrame(int(msg.frame_index), s))
                offset = np.array(msg.left_camera_offset, float)
                for o in kitti_objects_from_message(msg):
                    if o.type in VEHICLE_TYPES:
                        h, _, length = o.dimensions
                        centre = centre_from_kitti(np.asarray(o.location, float), h, offset)
                        f.labels.append((int(o.track_id), o.type, centre, float(length)))
            elif conn.topic == name[topics.DETECTIONS_3D]:
                dt = float(msg.camera_motion_dt)
                motion = None
                if dt > 0:
                    motion = CameraMotion(*read_transform(msg.camera_motion), dt)
                motions[stamp_ns(msg.header)] = motion
            elif conn.topic == name[topics.ODOMETRY]:
                p = msg.pose.pose.position
                cov = np.array(msg.pose.covariance, float).reshape(6, 6)
                odometry[stamp_ns(msg.header)] = (np.array([p.x, p.y, p.z]), cov)
            else:
                tracks[stamp_ns(msg.header)] = msg
    finally:
        reader.close()
    for s, f in frames.items():
        f.camera_pose = tree.lookup(odom_frame, camera, s) if camera else None
        f.motion = motions.get(s)
        f.odometry = odometry.get(s)
        msg = tracks.get(s)
        if msg is not None:
            f.tracks_frame = msg.header.frame_id
            f.tracks = [
                (
                    int(v.track_id),
                    int(v.state),
                    np.array([v.position.x, v.position.y, v.position.z]),
                )
                for v in msg.vehicles
            ]
    return sorted(frames.values(), key=lambda f: f.frame)


def label_centres(frames: list[OdometryFrame]) -> dict[int, list[tuple[int, np.ndarray]]]:
    """Frame -> [(label id, centre in the left optical frame)] of the labelled vehicles."""
    return {f.frame: [(i, c) for i, _, c, _ in f.labels] for f in frames}


def label_scale(
    labels: dict[int, list[tuple[int, np.ndarray]]],
    reference: list[Pose],
    agree: float = 0.3,
) -> tuple[float, int]:
    """How far the camera moves by the labelled parked cars, as a ratio of the reference's
    steps: for each pair of consecutive frames ``k-1, k`` in ``labels`` (frame -> [(label id,
    centre in the left optical frame)]), each car labelled in both gives the camera's step
    ``t_i = q_i - R p_i`` (``R``: the reference's rotation between the frames); the cars within
    ``agree`` m of the median step are taken as parked (two at least); their mean step's length
    over the reference step's, summed over the pairs. Returns (ratio, pairs used)."""
    num = den = 0.0
    used = 0
    for k in sorted(labels):
        if k - 1 not in labels or k >= len(reference):
            continue
        rel = reference[k].inverse().compose(reference[k - 1])  # X_k = R X_k-1 + t
        before = dict(labels[k - 1])
        steps = np.array(
            [q - rel.rotation @ before[i] for i, q in labels[k] if i in before], dtype=float
        ).reshape(-1, 3)
        if len(steps) < 2:
            continue
        median = np.median(steps, axis=0)
        parked = steps[np.linalg.norm(steps - median, axis=1) <= agree]
        if len(parked) < 2:
            continue
        num += float(np.linalg.norm(parked.mean(axis=0)))
        den += float(np.linalg.norm(rel.translation))
        used += 1
    return (num / den if den > 0 else float("nan")), used


def path_agreement(
    odom_positions: dict[int, np.ndarray],
    first_pose: Pose,
    reference: list[Pose],
    scale: float = 1.0,
) -> dict:
    """The odometry's camera positions in odom (frame -> (3,)) against the reference poses
    (their translations times ``scale``), both from the first frame of ``odom_positions``, the
    reference taken into odom with the camera's pose there (``first_pose``)."""
    ks = sorted(k for k in odom_positions if k < len(reference))
    if len(ks) < 2:
        raise ValueError("fewer than two frames with both an odometry and a reference pose")
    k0 = ks[0]
    ref0 = reference[k0].inverse()
    ref = {}
    for k in ks:
        rel = ref0.compose(reference[k])
        ref[k] = first_pose.apply(scale * rel.translation)
    odo = {k: np.asarray(odom_positions[k], float) for k in ks}
    dist_ref = sum(np.linalg.norm(ref[b] - ref[a]) for a, b in zip(ks, ks[1:], strict=False))
    dist_odo = sum(np.linalg.norm(odo[b] - odo[a]) for a, b in zip(ks, ks[1:], strict=False))
    errors = np.array([np.linalg.norm(odo[k] - ref[k]) for k in ks])
    return {
        "frames": len(ks),
        "distance_m": float(dist_ref),
        "odometry_distance_m": float(dist_odo),
        "length_ratio": float(dist_odo / dist_ref),
        "max_error_m": float(errors.max()),
        "end_error_m": float(errors[-1]),
        "max_error_pct": float(100.0 * errors.max() / dist_ref),
        "step_m": float(dist_ref / (len(ks) - 1)),
        "odometry_step_m": float(dist_odo / (len(ks) - 1)),
    }


def parked_car_spreads(
    frames: list[OdometryFrame],
    parked_span: float = 2.0,
    match_distance: float = 4.0,
    odom_frame: str = "odom",
) -> list[dict]:
    """Per parked labelled car (module docstring): its frames, the ids of the tracks matched to
    it, their positions' spread in odom [m] and the car's labelled length [m], and how much the
    track's position jumps from frame to frame over the ground: ``jitter_xy_m``, the RMS second
    difference (x-y of odom, over three consecutive matched frames) of the track, beside
    ``label_jitter_xy_m``, the same of the car's labels taken to odom by the odometry (a parked
    car's labels move there by the odometry's error and their own noise only: what of the
    track's jitter the odometry can explain); NaN with fewer than three consecutive frames. The
    tracks must have been published in odom (``tracks_frame``); frames without a camera pose are
    left out."""
    seen: dict[int, dict[int, np.ndarray]] = {}
    length: dict[int, float] = {}
    for f in frames:
        if f.camera_pose is None:
            continue
        for i, _, centre, car_length in f.labels:
            seen.setdefault(i, {})[f.frame] = f.camera_pose.apply(centre)
            length[i] = car_length
    parked = {
        i: np.mean(list(p.values()), axis=0)
        for i, p in seen.items()
        if len(p) >= 2 and np.ptp(np.array(list(p.values())), axis=0).max() < parked_span
    }
    matched: dict[int, dict[int, tuple[int, np.ndarray]]] = {i: {} for i in parked}
    for f in frames:
        if f.camera_pose is None or not f.tracks:
            continue
        if f.tracks_frame != odom_frame:
            raise ValueError(f"frame {f.frame}: tracks in {f.tracks_frame!r}, not {odom_frame!r}")
        labelled = {i: f.camera_pose.apply(c) for i, _, c, _ in f.labels if i in parked}
        for i, where in labelled.items():
            best = None
            for tid, state, p in f.tracks:
                d = float(np.linalg.norm(p - where))
                if state in OUTPUT_STATES and d <= match_distance and (best is None or d < best[0]):
                    best = (d, tid, p)
            if best is not None:
                matched[i][f.frame] = (best[1], best[2])
    out = []
    for i, hits in sorted(matched.items()):
        if not hits:
            out.append({"label": i, "frames": 0, "tracks": [], "length_m": length[i]})
            continue
        pts = np.array([p for _, p in hits.values()])
        spread = max(float(np.linalg.norm(a - b)) for a in pts for b in pts)
        out.append(
            {
                "label": i,
                "frames": len(hits),
                "tracks": sorted({t for t, _ in hits.values()}),
                "spread_m": spread,
                "spread_xy_m": max(float(np.linalg.norm((a - b)[:2])) for a in pts for b in pts),
                "length_m": length[i],
                "jitter_xy_m": _rms_second_difference({k: p for k, (_, p) in hits.items()}),
                "label_jitter_xy_m": _rms_second_difference(
                    {k: p for k, p in seen[i].items() if k in hits}
                ),
            }
        )
    return out


def _rms_second_difference(points: dict[int, np.ndarray]) -> float:
    """RMS over frames k with k-1 and k+1 present of ``|p[k+1] - 2 p[k] + p[k-1]|`` in x-y
    (the ground plane of odom, REP-103) [m]; NaN without such a frame."""
    d2 = [
        float(np.linalg.norm((points[k + 1] - 2.0 * p + points[k - 1])[:2]))
        for k, p in points.items()
        if k - 1 in points and k + 1 in points
    ]
    return float(np.sqrt(np.mean(np.square(d2)))) if d2 else float("nan")
