"""The graph's topic names, written once, RELATIVE (no leading "/").

A node resolves them in its namespace, so ``--ros-args -r __ns:=/rig2`` (or the launchers'
``namespace``) moves a whole graph to ``/rig2/stereo/left/image_rect``, ...; without a namespace
they resolve to ``/stereo/left/image_rect``, .... Tools that read recorded bags (which store
resolved names) use :func:`resolve` and :func:`namespace_of`.
"""

from __future__ import annotations

LEFT_IMAGE = "stereo/left/image_rect"
RIGHT_IMAGE = "stereo/right/image_rect"
LEFT_INFO = "stereo/left/camera_info"
RIGHT_INFO = "stereo/right/camera_info"
GROUND_TRUTH = "kitti/ground_truth"
CLOCK = "clock"
DETECTIONS_2D = "vehicles/detections_2d"
#: the detector's note that it started a frame (the image's header), before its 2D array: the
#: stereo node begins that frame's work that needs no boxes meanwhile (its early_start module)
DETECTIONS_2D_STARTED = "vehicles/detections_2d/started"
DETECTIONS_3D = "vehicles/detections_3d"
TRACKS = "vehicles/tracks"
TRACK_MARKERS = "vehicles/track_markers"
DISPARITY = "stereo/disparity"
POINTS = "stereo/points"
#: the visual odometry (nav_msgs/Odometry) and the transforms (REP-105): relative like the rest,
#: so "tf" is tf2's /tf without a namespace and /rig2/tf in one (a second rig's frames must not
#: mix into the first's tree; remap tf:=/tf and set frame names apart to share one tree)
ODOMETRY = "stereo/odometry"
TF = "tf"
TF_STATIC = "tf_static"
#: vision_msgs (4.x) beside the project's messages: the 2D detections and the tracks
VISION_DETECTIONS_2D = "vehicles/vision/detections_2d"
VISION_TRACKS = "vehicles/vision/tracks"
#: image_transport's convention: sensor_msgs/CompressedImage on ``<image topic>/compressed``
COMPRESSED_SUFFIX = "/compressed"
LEFT_IMAGE_COMPRESSED = LEFT_IMAGE + COMPRESSED_SUFFIX
RIGHT_IMAGE_COMPRESSED = RIGHT_IMAGE + COMPRESSED_SUFFIX

#: every topic of the graph
ALL = (
    LEFT_IMAGE,
    RIGHT_IMAGE,
    LEFT_INFO,
    RIGHT_INFO,
    GROUND_TRUTH,
    CLOCK,
    DETECTIONS_2D,
    DETECTIONS_2D_STARTED,
    DETECTIONS_3D,
    TRACKS,
    TRACK_MARKERS,
    DISPARITY,
    POINTS,
    LEFT_IMAGE_COMPRESSED,
    RIGHT_IMAGE_COMPRESSED,
    ODOMETRY,
    TF,
    TF_STATIC,
    VISION_DETECTIONS_2D,
    VISION_TRACKS,
)

#: the message type of every topic (``package/msg/Type``)
TYPES = {
    LEFT_IMAGE: "sensor_msgs/msg/Image",
    RIGHT_IMAGE: "sensor_msgs/msg/Image",
    LEFT_INFO: "sensor_msgs/msg/CameraInfo",
    RIGHT_INFO: "sensor_msgs/msg/CameraInfo",
    GROUND_TRUTH: "stereo_vehicle_msgs/msg/KittiFrameLabels",
    CLOCK: "rosgraph_msgs/msg/Clock",
    DETECTIONS_2D: "stereo_vehicle_msgs/msg/VehicleDetection2DArray",
    DETECTIONS_2D_STARTED: "std_msgs/msg/Header",
    DETECTIONS_3D: "stereo_vehicle_msgs/msg/VehicleDetection3DArray",
    TRACKS: "stereo_vehicle_msgs/msg/TrackedVehicleArray",
    TRACK_MARKERS: "visualization_msgs/msg/MarkerArray",
    DISPARITY: "stereo_msgs/msg/DisparityImage",
    POINTS: "sensor_msgs/msg/PointCloud2",
    LEFT_IMAGE_COMPRESSED: "sensor_msgs/msg/CompressedImage",
    RIGHT_IMAGE_COMPRESSED: "sensor_msgs/msg/CompressedImage",
    ODOMETRY: "nav_msgs/msg/Odometry",
    TF: "tf2_msgs/msg/TFMessage",
    TF_STATIC: "tf2_msgs/msg/TFMessage",
    VISION_DETECTIONS_2D: "vision_msgs/msg/Detection2DArray",
    VISION_TRACKS: "vision_msgs/msg/Detection3DArray",
}
#: topics whose publishers keep their last message for late subscribers (TRANSIENT_LOCAL, as
#: tf2's static broadcaster); their subscribers (the recorder) ask for it too
TRANSIENT_LOCAL = (TF_STATIC,)
#: KEEP_LAST depth of a processing node's frame inputs (images, 2D detection arrays): a burst
#: of this many frames that its executor takes late is still seen, dropped and counted by the
#: node itself (only the newest frame is processed); older ones are never taken (0.5 s at
#: 10 Hz). docs/ARCHITECTURE.md, "Topics".
INPUT_DEPTH = 5
#: what the bag recorder records by default (the graph's recorder node subscribes to these)
RECORDED = (
    LEFT_INFO,
    RIGHT_INFO,
    GROUND_TRUTH,
    CLOCK,
    DETECTIONS_2D,
    DETECTIONS_3D,
    TRACKS,
    TRACK_MARKERS,
    ODOMETRY,
    TF,
    TF_STATIC,
    VISION_DETECTIONS_2D,  # the vision_msgs copies too (issue #42: the README said every
    VISION_TRACKS,  # output is recorded; the detector builds them only for a subscriber)
)
#: large image-like topics, recorded only on request (the recorder's ``include_images``)
RECORDED_IMAGES = (LEFT_IMAGE, RIGHT_IMAGE, DISPARITY, POINTS)
#: the camera images (raw here; ``image_topic`` gives where another transport sends them)
CAMERA_IMAGES = (LEFT_IMAGE, RIGHT_IMAGE)


def image_topic(topic: str, transport: str) -> str:
    """The topic an image travels on: ``topic`` for "raw", ``topic/compressed`` otherwise."""
    return topic if transport == "raw" else topic + COMPRESSED_SUFFIX


def normalise_namespace(namespace: str | None) -> str:
    """``"rig2"``, ``"/rig2/"`` -> ``"/rig2"``; ``""``, ``"/"``, None -> ``""``."""
    ns = (namespace or "").strip().strip("/")
    return f"/{ns}" if ns else ""


def resolve(topic: str, namespace: str | None = "") -> str:
    """The absolute name of ``topic`` in ``namespace`` (absolute topics are kept)."""
    if topic.startswith("/"):
        return topic
    return f"{normalise_namespace(namespace)}/{topic}"


def namespace_of(names, topic: str = GROUND_TRUTH) -> str | None:
    """The namespace in which ``topic`` appears among the absolute ``names`` (e.g. a bag's
    topics): ``""`` for ``/topic``, ``"/rig2"`` for ``/rig2/topic``, None when absent or when it
    appears in several namespaces (ambiguous)."""
    suffix = "/" + topic
    found = sorted({n[: -len(suffix)] for n in names if n.endswith(suffix)})
    return found[0] if len(found) == 1 else None
