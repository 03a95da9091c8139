"""The tracker's parameters: ONE definition shared by the node and the offline CLI.

The node declares every field of :class:`TrackerConfig` as a ROS parameter with the default and
allowed values given here (:func:`vehicle_common.node_parameters.declare_config`);
``tracker_offline --params FILE.yaml`` reads the same names from the
``vehicle_tracker: ros__parameters:`` section of a ROS parameter file, with the same checks.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from vehicle_common.kitti import MEAN_CAR_DIMENSIONS
from vehicle_common.node_parameters import (
    ParameterError,
    check_value,
    config_from_values,
    defaults_of,
    param,
)

from .parameters import TrackerNodeParameters
from .particle import PROPOSALS
from .scene_motion import INIT_VELOCITIES

FILTERS = ("kalman", "particle", "none")
COAST_BOXES = ("projection", "shifted")
MATCHED_BOXES = ("detection", "projection")
ASSOCIATIONS = ("hungarian", "nearest")
COSTS = ("mahalanobis", "euclidean", "iou2d", "giou3d")
NODE_NAME = "vehicle_tracker"


#: a parameter has an invalid value or type; the message names the parameter
TrackerConfigError = ParameterError


#: Parameters of the ``vehicle_tracker`` node beside TrackerConfig's
#: (:class:`.parameters.TrackerNodeParameters`): the camera matrix of coasting tracks' boxes and
#: the frame the tracks are published in
NODE_PARAMETERS = tuple(defaults_of(TrackerNodeParameters))


@dataclass
class TrackerConfig:
    """Tracker parameters (units in the field comments; allowed values in ``param``). Defaults
    tuned on KITTI val seqs 1, 6 (see docs/tracker.md)."""

    filter: str = param("kalman", choices=FILTERS)  # kalman | particle | none
    # nearest (the paper's greedy) | hungarian. Nearest is the default because it measured best
    # on the KITTI validation sequences (MOTA 84.94 vs 84.85, IDSW 0 vs 1, FRAG 8 vs 10 with
    # Kalman, docs/tracker.md); Hungarian + Mahalanobis keeps ids better in crossing scenes.
    association: str = param("nearest", choices=ASSOCIATIONS)
    cost: str = param("mahalanobis", choices=COSTS)  # mahalanobis | euclidean | iou2d | giou3d
    dist_cap: float = param(4.0, low=0, low_open=True)  # [m] gate on the centre distance
    # gate on the squared Mahalanobis distance (3 dof)
    mahalanobis_gate: float = param(25.0, low=0, low_open=True)
    # gate of the iou2d cost: minimum IoU x shape similarity
    min_iou: float = param(0.1, low=0.0, high=1.0)
    min_giou: float = param(-0.2, low=-1.0, high=1.0)  # gate of the giou3d cost: minimum 3D GIoU
    # [m^2/s^3] white-acceleration spectral density (velocities relative to the camera)
    process_noise: float = param(8.0, low=0, low_open=True)
    # [m^2/s^3] the same once tracking in the world frame (the input carries the camera's
    # motion): a car's own acceleration only, without the camera's (docs/tracker.md)
    world_process_noise: float = param(0.5, low=0, low_open=True)
    # [m] position std used when a detection has no covariance
    measurement_noise: float = param(0.3, low=0, low_open=True)
    init_position_var: float = param(1.0, low=0, low_open=True)  # [m^2] (paper)
    init_velocity_var: float = param(50.0, low=0, low_open=True)  # [(m/s)^2] (paper)
    # initial velocity of a new track: zero (paper) | scene (median velocity of the established
    # tracks: the apparent motion of parked cars seen from the moving camera; scene_motion.py)
    init_velocity: str = param("scene", choices=INIT_VELOCITIES)
    # initial position covariance: the detection's covariance (true) or init_position_var I
    init_position_from_detection: bool = param(True)
    # Kalman, world frame: a new track starts with a bank of velocity hypotheses over the
    # ground (birth_hypotheses.py, docs/tracker.md): parked, and moving both ways along its
    # heading at birth_max_speed j / birth_speed_steps, j = 1..steps; 0: off (one prior, the
    # parked one). [m/s]
    birth_max_speed: float = param(0.0, low=0.0)
    birth_speed_steps: int = param(3, low=1)  # moving speeds per direction
    # prior probability of moving (shared equally by the moving hypotheses): the fraction of
    # labelled cars moving (> 3 m/s over the ground) when first labelled, tuning sequences
    birth_moving_prior: float = param(0.18, low=0.0, high=1.0, low_open=True, high_open=True)
    # [(m/s)^2] each hypothesis' velocity variance (z; x, y as known_scene_var)
    birth_hypothesis_var: float = param(4.0, low=0, low_open=True)
    # corrections after which a track keeps its most probable hypothesis (before: the
    # mixture's moments)
    birth_resolve_updates: int = param(10, low=1)
    # tracks seen once when the camera's motion first arrives take the hypotheses too
    world_entry_hypotheses: bool = param(False)
    # world frame: probability that a new track is a parked car, for the stationary model
    # beside the motion filter (stationary.py, issue #41; the reported position is the two
    # models' mixture); 0: off
    stationary_prior: float = param(0.0, low=0.0, high=1.0, high_open=True)
    # probability per frame that a car switches between parked and moving (tuning: 0.003)
    stationary_switch: float = param(0.003, low=0.0, high=0.5, low_open=True)
    # [m^2/s] random walk of a parked car's position in the world frame (odometry drift)
    stationary_process_noise: float = param(0.01, low=0, low_open=True)
    # the two models interact (IMM mixing; Kalman filter, tracks without birth hypotheses)
    stationary_mixing: bool = param(True)
    # detections a parked estimate must have taken before it is blended into the reported
    # position (before, mu is mostly the prior: a young moving car is taken for parked)
    stationary_min_updates: int = param(0, low=0)
    # the most the parked estimate's weight in the reported position changes per frame (it
    # follows mu; 1: it is mu): a car first taken for parked is then not reported metres
    # further on in one frame when mu collapses
    stationary_report_rate: float = param(1.0, low=0.0, high=1.0, low_open=True)
    # robust measurement update: a detection whose innovation is d > k standard deviations
    # (Mahalanobis) is taken with its covariance times d / k (Huber); 0: off, the plain Kalman
    # update (the LiDAR profile's; the graph takes 3 with the wider gate, docs/tracker.md)
    robust_update_k: float = param(0.0, low=0.0)
    # where the robust update applies: both = the Kalman filter and the parked estimate;
    # parked = the parked estimate only (the filter's velocity untouched)
    robust_update_models: str = param("both", choices=("both", "parked"))
    max_staleness: int = param(2, low=0)  # [frames] a track unmatched for more is deleted
    decay_rate: float = param(0.8, low=0.0, high=1.0)  # confidence factor per unmatched frame
    # coasting tracks are reported while conf >= this
    restoration_conf_threshold: float = param(0.5, low=0.0, high=1.0)
    min_hits: int = param(2, low=1)  # matched frames before a track is confirmed
    # [s] a tentative track is also confirmed once matched twice over at least this long: the
    # confirmation in time when fewer frames are processed (a camera faster than the graph:
    # issue #39); 0: off (min_hits frames only)
    min_hits_span: float = param(0.0, low=0.0)
    # smoothing gain of the box size (0..1, 1 = take the detection)
    size_gain: float = param(0.3, low=0.0, high=1.0)
    yaw_gain: float = param(0.5, low=0.0, high=1.0)  # smoothing gain of the yaw (0..1)
    # [m/s] above this the velocity resolves the 180 deg yaw
    min_heading_speed: float = param(2.0, low=0.0)
    # the heading of travel over the ground in the yaw (world frame, bin yaws; issue #34): once
    # a track's direction of travel is known within this std [deg] (0: never), its reported yaw
    # is the inverse-variance mean of it and the detector's yaw, whose std is bin_yaw_std [deg]
    motion_heading_max_std: float = param(0.0, low=0.0, high=180.0)
    bin_yaw_std: float = param(20.0, low=0.0, low_open=True)  # [deg] std of the detector's yaw
    # [m] car size used when detections have none (KITTI means)
    mean_length: float = param(MEAN_CAR_DIMENSIONS[2], low=0, low_open=True)
    mean_width: float = param(MEAN_CAR_DIMENSIONS[1], low=0, low_open=True)  # [m]
    mean_height: float = param(MEAN_CAR_DIMENSIONS[0], low=0, low_open=True)  # [m]
    # particle filter: particles per track (the paper's 100 are too few for the 6D state on real
    # trajectories: AP easy @1.5 m 58.6 with 100, 83.2 with 1000, 86.3 with 2000 on the real-motion
    # tuning sequences against 86.7 for Kalman, docs/tracker.md)
    num_particles: int = param(2000, low=1)
    # regularisation kernel after resampling (Liu & West shrinkage: mean and covariance kept),
    # bandwidth h x the posterior spread (0..1; 0 = plain resampling, 1 = a fresh draw from the
    # fitted Gaussian). 0.5: the smallest h of {0, 0.2, 0.5, 0.7, 1} that keeps a simulated far
    # fast car's start-up within 0.5 std of the exact (Kalman) posterior (docs/tracker.md)
    particle_roughening: float = param(0.5, low=0.0, high=1.0)
    # particle filter proposal: "optimal" (each particle drawn from p(x | its predicted state,
    # detection), weights by the detection's density given the predicted state) or "prior"
    # (bootstrap: particles moved with the process noise, weights N(z; p, R)); docs/tracker.md
    particle_proposal: str = param("optimal", choices=PROPOSALS)
    seed: int = param(0, low=0)  # random seed of the particle filter
    # [s] used for the first frame or non-increasing stamps
    default_dt: float = param(0.1, low=0, low_open=True)
    # 2D box of a coasting track: "projection" of its filtered 3D box (mean size, yaw), or
    # "shifted": its last detection box moved with its predicted centre's pixel and scaled by
    # the depth ratio (keeps the detector's box shape; issue #34, docs/tracker.md)
    coast_box: str = param("projection", choices=COAST_BOXES)
    # 2D box of a track matched this frame: its "detection"'s box (the visible part of an
    # occluded car) or the "projection" of its filtered 3D box (size, yaw, position through the
    # camera matrix: a full-extent box, as KITTI labels occluded cars; issue #41, docs/tracker.md)
    matched_box: str = param("detection", choices=MATCHED_BOXES)
    # 2D box of a matched track ("detection" above): gain x its detection's box + (1 - gain) x
    # its previous box carried to this frame the "shifted" way (moved with the filtered centre's
    # pixel, scaled by the depth ratio); a track's first box is its detection's. 1: the
    # detection's box (issue #41, docs/tracker.md "The 2D box smoothed over frames")
    box_gain: float = param(1.0, low=0.0, low_open=True, high=1.0)
    # [px] for clipping projected boxes (camera_info overrides)
    image_width: int = param(1242, low=1)
    image_height: int = param(375, low=1)  # [px]
    output_tentative: bool = False  # offline CLI: also write tentative tracks

    # Score-aware lifecycle and two-stage association (docs/tracker.md; the defaults leave it
    # off for detections scoring in [0, 1], i.e. the stereo graph's):
    birth_score: float = param(
        0.0, finite=False
    )  # -inf: no threshold; detections scoring below this start no track; they are
    # matched only in a second stage, to the tracks the first stage (>= birth_score) left
    confirm_score: float = param(float("inf"), finite=False)  # a track whose detection scores
    # sum to >= this is confirmed (also before min_hits matches)
    coast_min_hits: int = param(0, low=0)  # coasting tracks are reported only after this many
    # matches
    score_ramp_hits: int = param(1, low=1)  # reported score x min(1, hits / this)
    # detections whose stereo plausibility (VehicleDetection3D, when the stereo node gives it)
    # is below this start no track (second association stage only, as below birth_score);
    # 0: off. Detections without the field are never held back by it.
    birth_plausibility: float = param(0.0, low=0.0, high=1.0)
    # a detection whose 2D box overlaps a track's (predicted) box by a 2D IoU above this starts
    # no track: a duplicate on a car a track holds (issue #41; 0.5 chosen on the camera
    # benchmark's tuning trajectories, docs/tracker.md); 1: off
    birth_max_iou: float = param(0.5, low=0.0, high=1.0)
    # a coasting track whose projected box has less than this share of its area inside the
    # image ends (its car has left the view; issue #41: tracks that outlived their car; 0.5
    # chosen on the camera benchmark's tuning trajectories, docs/tracker.md); 0: off
    coast_min_visible: float = param(0.5, low=0.0, high=1.0)
    # [m] a coasting track whose centre is nearer than this over the ground to a track matched
    # this frame is not reported that frame (hidden, not deleted): a second track on a car
    # another track holds (issue #41, precision; docs/tracker.md); 0: off
    coast_min_distance: float = param(0.0, low=0.0)
    # a coasting track is reported only while the mean score of the detections it was matched
    # to is at least this: a track held up by weak false detections is not reported once they
    # stop (issue #41, precision: ghosts; docs/tracker.md); 0: off
    coast_min_score: float = param(0.0, low=0.0)

    def validate(self) -> TrackerConfig:
        """Check every field's type, range and choices (see ``param``); raises
        TrackerConfigError (ParameterError) naming the parameter."""
        for f in fields(self):
            check_value(f.name, getattr(self, f.name), f.default, dict(f.metadata))
        return self

    @property
    def mean_size(self) -> tuple[float, float, float]:
        """(length, width, height) in metres."""
        return (self.mean_length, self.mean_width, self.mean_height)

    @classmethod
    def from_dict(cls, values: dict, source: str | None = None) -> TrackerConfig:
        """Build from a name -> value mapping; unknown names, wrong types or values raise
        TrackerConfigError naming ``source`` and the parameter. The node's own parameters
        (:data:`NODE_PARAMETERS`: how it publishes, not how it tracks) are passed over."""
        values = {k: v for k, v in values.items() if k not in NODE_PARAMETERS}
        return config_from_values(cls, values, source)

    @classmethod
    def from_yaml(cls, path: str | Path, node_name: str = NODE_NAME) -> TrackerConfig:
        """Read ``node_name: ros__parameters: {...}`` from a ROS parameter file."""
        import yaml

        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise TrackerConfigError(str(path), f"cannot read ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise TrackerConfigError(
                str(path),
                f"not a text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start} is "
                "not UTF-8)",
            ) from None
        except yaml.YAMLError as exc:
            raise TrackerConfigError(
                str(path), f"not valid YAML ({str(exc).splitlines()[0]})"
            ) from None
        section = None
        if isinstance(data, dict):
            for key in (node_name, "/" + node_name, "/**"):
                if isinstance(data.get(key), dict) and "ros__parameters" in data[key]:
                    section = data[key]["ros__parameters"]
                    break
        if not isinstance(section, dict):
            raise TrackerConfigError(str(path), f"no '{node_name}: ros__parameters:' section")
        return cls.from_dict(section, source=str(path))
