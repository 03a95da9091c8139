"""Procedural street scenes for the synthetic KITTI generator: road layout, buildings, vehicles.

World frame = camera-0 frame at frame 0 (x right, y down, z forward, metres); the ground is the
plane ``y = CAMERA_HEIGHT``. The ego car drives straight along +z (no rotation), so at frame k
camera 0 is at ``(0, 0, ego_z(k))`` and a world point ``(x, y, z)`` has camera-0 coordinates
``(x, y, z - ego_z(k))``. Vehicles follow polyline paths at constant speed (lane following,
lane changes, oncoming traffic, crossing and turning at a junction, parked cars); trajectories
that would collide (with each other or the ego car) are rejected when the scene is built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CAMERA_HEIGHT = 1.65  # KITTI camera height above the road, m
FRAME_DT = 0.1  # 10 Hz
LANE_WIDTH = 3.5
LANE_ONCOMING_OUTER, LANE_ONCOMING, LANE_EGO, LANE_RIGHT = -7.0, -3.5, 0.0, 3.5
ROAD_LEFT, ROAD_RIGHT = -8.75, 5.25  # asphalt carriageway edges (x)
PARKING_LEFT, PARKING_RIGHT = -11.5, 9.5  # parking strips end / sidewalks begin (x)
WALL_LEFT, WALL_RIGHT = -14.0, 12.0  # building fronts (x)
FAR_LEFT, FAR_RIGHT = -45.0, 45.0  # second row of buildings / trees (x)
CROSS_HALF_WIDTH = 6.0  # half width of the cross street at the junction (z)

# Segment kinds of the walls along the road.
GAP, BUILDING, VEGETATION = 0, 1, 2

ROLES = ("follow", "lane_change", "oncoming", "crossing", "turning", "parked")


class Path:
    """A polyline in the ground plane (points (x, z)), traversed by arc length ``s``.

    Positions beyond either end are extrapolated along the end segments.
    """

    def __init__(self, points) -> None:
        pts = np.asarray(points, dtype=float)
        seg = np.diff(pts, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        keep = np.concatenate([[True], length > 1e-9])
        pts = pts[keep]
        if len(pts) < 2:
            raise ValueError("a path needs two distinct points")
        self.points = pts
        self.seg = np.diff(pts, axis=0)
        self.length = np.hypot(self.seg[:, 0], self.seg[:, 1])
        self.s = np.concatenate([[0.0], np.cumsum(self.length)])

    def pose(self, s: float) -> tuple[float, float, float, float]:
        """(x, z, dx, dz) at arc length ``s``: position and unit direction of travel."""
        i = int(np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.seg) - 1))
        frac = (s - self.s[i]) / self.length[i]
        p = self.points[i] + frac * self.seg[i]
        d = self.seg[i] / self.length[i]
        return float(p[0]), float(p[1]), float(d[0]), float(d[1])


@dataclass
class VehicleShape:
    """Body and cabin proportions (fractions of the label box) of one vehicle."""

    body_height: float  # fraction of h
    cabin_length: float  # fraction of l
    cabin_offset: float  # cabin centre along the length, fraction of l (+ = towards the front)
    cabin_width: float  # fraction of w


@dataclass
class Vehicle:
    """A vehicle with a KITTI label box and a trajectory ``s(t) = s0 + speed * t`` on ``path``."""

    track_id: int
    type: str  # 'Car' or 'Van'
    dimensions: tuple[float, float, float]  # h, w, l (m)
    colour: tuple[float, float, float]  # body RGB in [0, 1]
    shape: VehicleShape
    path: Path
    s0: float
    speed: float
    role: str = "follow"

    def state(self, t: float) -> tuple[float, float, float]:
        """World (x, z) of the box's bottom centre and KITTI ``rotation_y`` at time ``t``."""
        x, z, dx, dz = self.path.pose(self.s0 + self.speed * t)
        return x, z, math.atan2(-dz, dx)


@dataclass
class WallSegments:
    """Segments of one wall plane along z: ``starts`` ascending, each with kind/height/colour."""

    x: float
    starts: np.ndarray
    kinds: np.ndarray
    heights: np.ndarray
    colours: np.ndarray  # (N, 3)
    window_period: np.ndarray  # m along z; facade window spacing (buildings)

    def index(self, z: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.starts, z, side="right") - 1, 0, len(self.starts) - 1)


@dataclass
class Scene:
    """Everything that defines a synthetic sequence except the camera model and the renderer."""

    frames: int
    seed: int
    ego_speed: float
    junction_z: float
    vehicles: list[Vehicle]
    walls: list[WallSegments] = field(default_factory=list)
    exposure: float = 1.0  # global brightness factor
    sun: tuple[float, float, float] = (0.35, -0.85, -0.40)  # direction towards the sun (y down)

    def ego_z(self, frame: int) -> float:
        return self.ego_speed * frame * FRAME_DT

    def time(self, frame: int) -> float:
        return frame * FRAME_DT


# ----------------------------------------------------------------------------- vehicles

_PALETTE = np.array(
    [
        (0.92, 0.92, 0.90),  # white
        (0.70, 0.71, 0.72),  # silver
        (0.45, 0.46, 0.48),  # grey
        (0.08, 0.08, 0.09),  # black
        (0.60, 0.08, 0.07),  # red
        (0.10, 0.20, 0.50),  # blue
        (0.12, 0.28, 0.18),  # dark green
        (0.75, 0.62, 0.35),  # beige
        (0.85, 0.70, 0.10),  # yellow
        (0.25, 0.15, 0.10),  # brown
    ]
)


def _random_vehicle_body(rng: np.random.Generator, van: bool):
    if van:
        dims = (rng.uniform(1.85, 2.35), rng.uniform(1.80, 2.00), rng.uniform(4.4, 5.5))
        shape = VehicleShape(
            body_height=rng.uniform(0.42, 0.50),
            cabin_length=rng.uniform(0.78, 0.88),
            cabin_offset=-rng.uniform(0.05, 0.10),
            cabin_width=rng.uniform(0.95, 0.99),
        )
    else:
        dims = (rng.uniform(1.40, 1.70), rng.uniform(1.60, 1.85), rng.uniform(3.5, 4.9))
        shape = VehicleShape(
            body_height=rng.uniform(0.50, 0.60),
            cabin_length=rng.uniform(0.45, 0.60),
            cabin_offset=-rng.uniform(0.0, 0.10),
            cabin_width=rng.uniform(0.84, 0.92),
        )
    dims = tuple(round(float(v), 2) for v in dims)
    colour = _PALETTE[rng.integers(len(_PALETTE))] * rng.uniform(0.85, 1.1)
    return dims, tuple(float(c) for c in np.clip(colour, 0.0, 1.0)), shape


def _straight(x0: float, z0: float, dx: float, dz: float) -> Path:
    return Path([(x0 - 2000 * dx, z0 - 2000 * dz), (x0 + 2000 * dx, z0 + 2000 * dz)])


def _lane_change(x_from: float, x_to: float, z_mid: float, length: float) -> Path:
    z_fine = z_mid + np.linspace(-length / 2, length / 2, 41)
    f = np.clip((z_fine - (z_mid - length / 2)) / length, 0.0, 1.0)
    x_fine = x_from + (x_to - x_from) * f * f * (3 - 2 * f)
    pts = [(x_from, z_mid - 3000.0), *zip(x_fine, z_fine, strict=True), (x_to, z_mid + 3000.0)]
    return Path(pts)


def _turn(start, h_in, h_out, radius: float) -> tuple[Path, float]:
    """Straight approach along ``h_in`` to ``start``, a quarter circle to ``h_out``, straight on.

    Returns the path and the arc length of the turn's midpoint.
    """
    S, hi, ho = np.asarray(start, float), np.asarray(h_in, float), np.asarray(h_out, float)
    C = S + radius * ho
    theta = np.linspace(0.0, math.pi / 2, 31)
    arc = C - radius * np.outer(np.cos(theta), ho) + radius * np.outer(np.sin(theta), hi)
    E = arc[-1]
    pts = np.vstack([S - 2000 * hi, arc, E + 2000 * ho])
    return Path(pts), 2000.0 + radius * math.pi / 4


def _collides(a: np.ndarray, b: np.ndarray, ra: float, rb: float) -> bool:
    """a, b: (T, 3, 2) circle centres over time; True if any pair of circles overlaps."""
    d = np.linalg.norm(a[:, :, None, :] - b[:, None, :, :], axis=-1)
    return bool((d < ra + rb).any())


def _footprint_circles(v: Vehicle, times: np.ndarray) -> tuple[np.ndarray, float]:
    h, w, length = v.dimensions
    out = np.empty((len(times), 3, 2))
    for i, t in enumerate(times):
        x, z, dx, dz = v.path.pose(v.s0 + v.speed * t)
        for k, f in enumerate((-1.0, 0.0, 1.0)):
            off = f * (length / 2 - w / 2)
            out[i, k] = (x + off * dx, z + off * dz)
    return out, w / 2 + 0.35


@dataclass
class _Street:
    """The ego car's drive and the junction: what the vehicles are placed around."""

    ego_speed: float
    duration: float  # s
    junction_z: float

    @property
    def ego_end(self) -> float:
        return self.ego_speed * self.duration

    def ego_z(self, t):
        return self.ego_speed * t

    def junction_window(self) -> tuple[float, float]:
        """Times at which the junction is 12..60 m ahead of the ego car."""
        v, zj = self.ego_speed, self.junction_z
        t_lo = max(0.0, (zj - 60.0) / v) if v > 0 else 0.0
        t_hi = min(self.duration, (zj - 12.0) / v) if v > 0 else self.duration
        return t_lo, t_hi


# Each _place_<role>: (path, arc length at time t_m, speed, t_m) of a vehicle of that role;
# t_m is a random time of the sequence, which some roles replace with their own.


def _place_follow(rng: np.random.Generator, street: _Street, t_m: float):
    lane = LANE_RIGHT if rng.random() < 0.55 else LANE_EGO
    dz = rng.uniform(-3.0 if lane == LANE_RIGHT else 9.0, 55.0)
    speed = max(0.0, street.ego_speed + rng.uniform(-3.0, 3.0))
    path, z_m = _straight(lane, 0.0, 0.0, 1.0), street.ego_z(t_m) + dz
    return path, z_m + 2000.0, speed, t_m


def _place_lane_change(rng: np.random.Generator, street: _Street, t_m: float):
    lanes = [LANE_EGO, LANE_RIGHT]
    if rng.random() < 0.5:
        lanes.reverse()
    z_m = street.ego_z(t_m) + rng.uniform(12.0, 40.0)
    speed = street.ego_speed + rng.uniform(1.0, 4.0)
    path = _lane_change(lanes[0], lanes[1], z_m, rng.uniform(20.0, 30.0))
    return path, float(np.interp(z_m, path.points[:, 1], path.s)), speed, t_m


def _place_oncoming(rng: np.random.Generator, street: _Street, t_m: float):
    lane = LANE_ONCOMING if rng.random() < 0.6 else LANE_ONCOMING_OUTER
    z_m = street.ego_z(t_m) + rng.uniform(8.0, 60.0)
    speed = rng.uniform(6.0, 14.0)
    return _straight(lane, 0.0, 0.0, -1.0), 2000.0 - z_m, speed, t_m


def _place_crossing(rng: np.random.Generator, street: _Street, t_m: float):
    t_m = float(rng.uniform(*street.junction_window()))
    east = rng.random() < 0.5
    z_lane = street.junction_z - 3.0 if east else street.junction_z + 3.0
    x_m = rng.uniform(-8.0, 5.0)
    path = _straight(0.0, z_lane, 1.0 if east else -1.0, 0.0)
    s_m = 2000.0 + (x_m if east else -x_m)
    return path, s_m, rng.uniform(4.0, 10.0), t_m


def _place_turning(rng: np.random.Generator, street: _Street, t_m: float):
    t_m = float(rng.uniform(*street.junction_window()))
    kind = int(rng.integers(4))
    zj = street.junction_z
    radius = float(rng.uniform(6.0, 9.0))
    if kind == 0:  # from the right cross street into the oncoming lane
        path, s_m = _turn((LANE_ONCOMING + radius, zj + 3.0), (-1, 0), (0, -1), radius)
    elif kind == 1:  # oncoming car turning right into the cross street
        path, s_m = _turn((LANE_ONCOMING, zj + 3.0 + radius), (0, -1), (-1, 0), radius)
    elif kind == 2:  # car ahead turning right into the cross street
        path, s_m = _turn((LANE_RIGHT, zj - 3.0 - radius), (0, 1), (1, 0), radius)
    else:  # from the left cross street turning left, away from the camera
        path, s_m = _turn((LANE_RIGHT - radius, zj - 3.0), (1, 0), (0, 1), radius)
    return path, s_m, rng.uniform(3.5, 7.0), t_m


def _place_parked(rng: np.random.Generator, street: _Street, t_m: float):
    """Parallel or angled (38-52 degrees, nose to the kerb) on the right, parallel on the left;
    never in the junction."""
    z = float(rng.uniform(3.0, street.ego_end + 60.0))
    if abs(z - street.junction_z) < CROSS_HALF_WIDTH + 4.0:
        z = street.junction_z - CROSS_HALF_WIDTH - 4.0 - rng.uniform(0.0, 10.0)
    r = rng.random()
    if r < 0.4:  # parallel on the right
        x, (hx, hz) = 7.1, (0.0, 1.0 if rng.random() < 0.8 else -1.0)
    elif r < 0.75:  # angled on the right, nose to the kerb
        a = math.radians(rng.uniform(38.0, 52.0)) * (1 if rng.random() < 0.5 else -1)
        x, (hx, hz) = 7.4, (math.sin(abs(a)), math.cos(a))
    else:  # parallel on the left
        x, (hx, hz) = -10.1, (0.0, -1.0 if rng.random() < 0.7 else 1.0)
    return Path([(x, z), (x + hx, z + hz)]), 0.0, 0.0, 0.0


_PLACE = {
    "follow": _place_follow,
    "lane_change": _place_lane_change,
    "oncoming": _place_oncoming,
    "crossing": _place_crossing,
    "turning": _place_turning,
    "parked": _place_parked,
}


def _random_vehicles(rng: np.random.Generator, street: _Street, n_vehicles: int) -> list[Vehicle]:
    """Up to ``n_vehicles`` vehicles whose footprints never overlap each other's or the ego
    car's (a colliding candidate is dropped; at most 6 n + 10 candidates)."""
    times = np.arange(0.0, street.duration + 1e-9, 0.05)
    ego_pts = np.stack(
        [
            np.stack([np.zeros(3), street.ego_z(t) + np.array([-1.0, 0.5, 2.0])], axis=1)
            for t in times
        ]
    )
    accepted: list[tuple[Vehicle, np.ndarray, float]] = []
    vehicles: list[Vehicle] = []
    base_roles = ["follow", "oncoming", "crossing", "turning", "parked", "lane_change", "parked"]
    attempts = 0
    while len(vehicles) < n_vehicles and attempts < 6 * n_vehicles + 10:
        attempts += 1
        if attempts <= len(base_roles):
            role = base_roles[attempts - 1]
        else:
            role = str(rng.choice(ROLES, p=[0.22, 0.1, 0.2, 0.14, 0.14, 0.2]))
        van = rng.random() < 0.2
        dims, colour, shape = _random_vehicle_body(rng, van)
        t_m = float(rng.uniform(0.0, street.duration)) if street.duration > 0 else 0.0
        t_lo, t_hi = street.junction_window()
        if role in ("crossing", "turning") and t_hi < t_lo:
            role = "oncoming"
        path, s_m, speed, t_m = _PLACE[role](rng, street, t_m)
        s0 = s_m - speed * t_m
        vtype = "Van" if van else "Car"
        v = Vehicle(len(vehicles), vtype, dims, colour, shape, path, float(s0), float(speed), role)
        circles, radius = _footprint_circles(v, times)
        if _collides(circles, ego_pts, radius, 1.25):
            continue
        if any(_collides(circles, c, radius, r) for _, c, r in accepted):
            continue
        accepted.append((v, circles, radius))
        vehicles.append(v)
    return vehicles


def random_scene(seed: int, frames: int, n_vehicles: int = 12, sequence_index: int = 0) -> Scene:
    """A random street scene (deterministic for ``seed`` and ``sequence_index``).

    Roles are mixed so that all viewing angles occur: vehicles ahead in both directions, lane
    changes (overtaking), oncoming traffic, crossing and turning at a junction, and parked cars
    (parallel and angled at 45 degrees).
    """
    rng = np.random.default_rng([seed, sequence_index, 0x5EED])
    ego_speed = 0.0 if rng.random() < 0.15 else float(rng.uniform(4.0, 11.0))
    duration = max(frames - 1, 0) * FRAME_DT
    junction_z = ego_speed * duration * 0.55 + float(rng.uniform(28.0, 45.0))
    street = _Street(ego_speed, duration, junction_z)
    vehicles = _random_vehicles(rng, street, n_vehicles)
    walls = _random_walls(rng, junction_z, street.ego_end)
    azimuth, elevation = rng.uniform(-math.pi, math.pi), rng.uniform(0.5, 1.2)
    sun = (
        math.cos(elevation) * math.sin(azimuth),
        -math.sin(elevation),
        math.cos(elevation) * math.cos(azimuth),
    )
    return Scene(
        frames=frames,
        seed=seed,
        ego_speed=ego_speed,
        junction_z=junction_z,
        vehicles=vehicles,
        walls=walls,
        exposure=float(rng.uniform(0.8, 1.15)),
        sun=sun,
    )


# ----------------------------------------------------------------------------- walls


def _random_walls(rng: np.random.Generator, junction_z: float, ego_end: float):
    """Four wall planes (near left/right building fronts, far left/right) with a cross street."""
    walls = []
    z_end = ego_end + 600.0
    j0, j1 = junction_z - CROSS_HALF_WIDTH, junction_z + CROSS_HALF_WIDTH
    for x, near in ((WALL_LEFT, True), (WALL_RIGHT, True), (FAR_LEFT, False), (FAR_RIGHT, False)):
        segs = []  # (start, kind, height, colour, window period)
        z = -60.0
        while z < z_end:
            segs.append((z, *_random_segment(rng, near)))
            z += rng.uniform(8.0, 30.0) if near else rng.uniform(20.0, 70.0)
        # cut the cross street: a gap from j0 to j1, the segment under j1 resumes after it
        resume = next(s for s in reversed(segs) if s[0] <= j1)
        segs = [s for s in segs if s[0] < j0 or s[0] > j1]
        segs += [(j0, GAP, 0.0, (0.0, 0.0, 0.0), 1.0), (j1, *resume[1:])]
        segs.sort(key=lambda s: s[0])
        walls.append(
            WallSegments(
                x=x,
                starts=np.array([s[0] for s in segs]),
                kinds=np.array([s[1] for s in segs], dtype=np.int64),
                heights=np.array([s[2] for s in segs]),
                colours=np.array([s[3] for s in segs], dtype=np.float32),
                window_period=np.array([s[4] for s in segs]),
            )
        )
    return walls


_FACADE_TINTS = np.array(
    [
        (0.78, 0.76, 0.72),  # light grey plaster
        (0.62, 0.60, 0.58),  # concrete
        (0.80, 0.72, 0.58),  # sandstone
        (0.58, 0.33, 0.26),  # brick
        (0.86, 0.82, 0.70),  # cream
        (0.70, 0.66, 0.60),  # stone
    ]
)


def _random_segment(rng: np.random.Generator, near: bool):
    r = rng.random()
    period = float(rng.uniform(2.2, 3.2))
    if near and r < 0.08:
        return GAP, 0.0, (0.0, 0.0, 0.0), period
    if r < (0.3 if near else 0.5):
        height = rng.uniform(1.5, 3.5) if near else rng.uniform(6.0, 14.0)
        colour = rng.uniform([0.12, 0.25, 0.08], [0.25, 0.42, 0.18])
        return VEGETATION, float(height), tuple(float(c) for c in colour), period
    height = rng.uniform(6.0, 18.0) if near else rng.uniform(8.0, 30.0)
    tint = _FACADE_TINTS[rng.integers(len(_FACADE_TINTS))]
    colour = np.clip(tint * rng.uniform(0.75, 1.1) + rng.uniform(-0.03, 0.03, 3), 0.0, 1.0)
    return BUILDING, float(height), tuple(float(c) for c in colour), period
