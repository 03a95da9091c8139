"""The stereo node's parameters, defined once (no rclpy): :class:`StereoNodeParameters` (the
node's own) and the rules of the core settings it declares (:class:`.disparity.DisparityParams`,
:class:`.ranging.RangingParams`, :class:`.plausibility.PlausibilityParams`). The node declares
them (:func:`vehicle_common.node_parameters.declare_config`); the offline tool reads them from a
parameter file (:func:`vehicle_common.node_parameters.config_from_values`).
"""

from __future__ import annotations

import dataclasses

from vehicle_common.camera_settings import DERIVED_ROWS
from vehicle_common.image_transport import ImageTransportParameters
from vehicle_common.node_parameters import (
    PROCESS_PARAMETERS,
    ParameterError,
    config_from_values,
    defaults_of,
    param,
)

from .disparity import DisparityParams, check_match_rows
from .odometry_output import OdometryOutputParameters
from .plausibility import PlausibilityParams
from .ranging import RangingParams

#: Parameter names that differ from the core dataclass field names.
RANGING_RENAMED = {"method": "ranging_method"}
#: Ranges of the core settings beyond what their validate() checks (type and finiteness are
#: checked for every parameter).
DISPARITY_RULES = {
    "min_disparity": {"low": 0},
    "p1_factor": {"low": 0},
    "p2_factor": {"low": 0},
    "pre_filter_cap": {"low": 1, "high": 63},
    "uniqueness_ratio": {"low": 0},
    "speckle_window_size": {"low": 0},
    "speckle_range": {"low": 0},
    "wls_lambda": {"low": 0},
    "wls_sigma": {"low": 0},
    "wls_lrc_thresh": {"low": 0},
    "wls_min_confidence": {"low": 0},
}
RANGING_RULES = {
    "sigma_d": {"low": 0, "low_open": True},
    "sigma_d_far": {"low": 0, "low_open": True},
    "far_disparity": {"low": 0},
    "sigma_pixel": {"low": 0},
    "depth_offset_std": {"low": 0},
    "min_valid_pixels": {"low": 0},
    "min_valid_fraction": {"low": 0.0, "high": 1.0},
    "core_fraction": {"low": 0.0, "high": 1.0, "low_open": True},
    "ground_margin": {"low": 0},
    "mode_bin": {"low": 0, "low_open": True},
    "min_mode_fraction": {"low": 0.0, "high": 1.0},
    "prior_height": {"low": 0, "low_open": True},
    "prior_log_sigma": {"low": 0},
    "correction_bin_spread": {"low": 0.0, "high": 1.0},
    "surface_blend": {"low": 0.0, "high": 1.0},
    "occluder_strip": {"low": 0, "low_open": True},
    "occluder_margin": {"low": 0},
    "occluder_share": {"low": 0.0, "high": 1.0},
}
PLAUSIBILITY_RULES = {
    "max_ground_fraction": {"low": 0.0, "high": 1.0},
    "ground_max_depth": {"low": 0, "low_open": True},
    "ground_max_tilt": {"low": 0.0, "high": 45.0},
    "ground_min_inliers": {"low": 3},
    "ground_keep_frames": {"low": 0},
}


@dataclasses.dataclass
class StereoNodeParameters:
    """The node's own parameters (the core's are DisparityParams' and RangingParams' fields)."""

    publish_disparity: bool = True  # stereo/disparity (the band's map, built while subscribed)
    publish_points: bool = False  # stereo/points, the point cloud (built while subscribed)
    points_decimation: int = param(4, low=1)  # point cloud: every n-th pixel in each direction
    points_max_depth: float = param(80.0, low=0, low_open=True)  # [m] point cloud: farther left out
    points_rgb: bool = False  # point cloud: with the left image's colour
    sync_cache_size: int = param(10, low=1)  # stamps of incomplete frames kept
    # [s] how far apart a left and a right image's stamps may be to pair (two drivers not
    # hardware synced); -1: a quarter of the camera's frame period (measured on the left
    # stamps; stamp_sync.StereoPairing); 0: equal stamps only. Equal stamps always pair.
    stereo_sync_tolerance: float = param(-1.0, low=-1.0)
    num_threads: int = param(2, low=1)  # OpenCV threads of the matcher (cv2.setNumThreads)
    frame_queue: int = param(1, low=1)  # newest complete frames kept waiting (1: latest frame)
    # where the ranging's disparity map is computed: "boxes" (the 2D boxes with their matching
    # context; the odometry and the road plane take a block-matching map of the band) or
    # "band" (the whole band for everything, as before issue #33)
    map_area: str = param("boxes", choices=("boxes", "band"))
    # the road plane's map with map_area "boxes": "own" (the map's algorithm at half its
    # resolution over the band, computed for it in the helper thread) or "shared" (the
    # odometry's block matching of the band, its speckle filter read in pixels: no map of its
    # own, about a quarter less CPU per frame; not the default: on KITTI 2015 its plane
    # differs from own's by more than own's noise, docs/stereo_depth.md section 13). With
    # "band" the road plane always takes the band's map.
    road_map: str = param("own", choices=("own", "shared"))
    # the camera-dependent settings: 0 / [-1, -1] = derived from the CameraInfo pair at run
    # time (vehicle_common.camera_settings); a value given wins
    # [px] disparity range (>= 16, the DisparityParams field); 0: fx * baseline / 4.05 m
    num_disparities: int = param(0, low=0)
    # [top, bottom) rows to match; bottom <= top means all rows; [-1, -1]: derived (KITTI's
    # camera: below the detector's region of interest; another camera: all)
    match_rows: list = param([-1, -1], low=-1, length=2)
    # [m] camera height above the road (the RangingParams field); 0: KITTI's 1.65 m assumed
    # and checked against the fitted road plane
    ground_height: float = param(0.0, low=0.0)
    # stereo visual odometry between successive frames (camera_motion of the 3D arrays)
    visual_odometry: bool = True
    # begin a frame's work that needs no boxes (the scene's map, the odometry, the road
    # plane's map) in the helper thread when the detector announces that it started that
    # frame (vehicles/detections_2d/started), while its CNN runs; the same outputs. Off: on
    # this 2-vCPU machine the CNN slowed as much as the stereo span shortened in half the runs
    # (docs/stereo_depth.md section 17); never on one CPU
    early_start: bool = False

    def validate(self) -> None:
        if 0 < self.num_disparities < 16:
            raise ValueError(
                f"num_disparities: {self.num_disparities} must be >= 16 (0: derived from the "
                "camera)"
            )
        if tuple(self.match_rows) != DERIVED_ROWS:
            check_match_rows(self.match_rows)  # against the image: match_band, at the first pair


@dataclasses.dataclass
class StereoConfig:
    """Every parameter of the stereo node, by the dataclass that holds it."""

    node: StereoNodeParameters
    disparity: DisparityParams  # num_disparities and row_band: from the node's and the camera
    ranging: RangingParams  # ground_height: the node's
    plausibility: PlausibilityParams
    image_transport: ImageTransportParameters  # read by vehicle_common.image_transport
    odometry_output: OdometryOutputParameters


#: (field of StereoConfig, dataclass, keyword arguments of its reading: skipped fields, renames,
#: rules), in the order the node declares them
SECTIONS = (
    (
        "disparity",
        DisparityParams,
        {"skip": ("row_band", "num_disparities"), "rules": DISPARITY_RULES},
    ),
    (
        "ranging",
        RangingParams,
        {"skip": ("ground_height",), "rename": RANGING_RENAMED, "rules": RANGING_RULES},
    ),
    ("node", StereoNodeParameters, {}),
    ("plausibility", PlausibilityParams, {"rules": PLAUSIBILITY_RULES}),
    ("image_transport", ImageTransportParameters, {}),
    ("odometry_output", OdometryOutputParameters, {}),
)


def read_stereo_config(read) -> StereoConfig:
    """The node's parameters, each dataclass read by ``read(cls, skip=(), rename=None,
    rules=None)``: the node's :func:`~vehicle_common.node_parameters.declare_config`, or
    :func:`stereo_config_from_values` for a parameter file's section."""
    return StereoConfig(**{name: read(cls, **kw) for name, cls, kw in SECTIONS})


def stereo_config_from_values(values: dict, source: str | None = None) -> StereoConfig:
    """The node's parameters from parameter name -> value (a parameter file's ``stereo_depth``
    section; missing names keep their defaults). A name no dataclass holds is refused, except
    the process's own (ParameterError naming it)."""
    known = set(PROCESS_PARAMETERS)
    by_class = {}
    for _, cls, kw in SECTIONS:
        rename = kw.get("rename") or {}
        names = {rename.get(f, f): f for f in defaults_of(cls) if f not in kw.get("skip", ())}
        by_class[cls] = {names[k]: v for k, v in values.items() if k in names}
        known |= set(names)
    for name in values:
        if name not in known:
            prefix = f"{source}: " if source else ""
            raise ParameterError(prefix + name, "unknown parameter of stereo_depth")

    def read(cls, skip=(), rename=None, rules=None):
        return config_from_values(cls, by_class[cls], source, rules=rules, rename=rename)

    return read_stereo_config(read)
