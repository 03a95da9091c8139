"""Hand-made street scenes for the plausibility check (issue #41 item 3): a disparity map
ray-cast from a road surface that need not be one plane (a grade change beyond the fitted
range, a crowned road, a kerb) and yawed cuboid cars with ground clearance; each car's 2D box
is the full-extent projection of its 3D box, as KITTI labels it (also when another car hides
part of it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from stereo_depth_node.reprojection import StereoGeometry

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5371)
FB = GEO.fx * GEO.baseline
H, W = 375, 1242
CAMERA_HEIGHT = 1.65


@dataclass(frozen=True)
class Road:
    """Road height [m] above the level plane CAMERA_HEIGHT below the camera at (x, z):
    ``grade`` (rise per metre) beyond ``grade_from`` [m] of depth, a crown falling by
    ``crown`` per metre of |x|, and a kerb: ``kerb`` [m] higher where x >= ``kerb_x``."""

    grade: float = 0.0
    grade_from: float = 30.0
    crown: float = 0.0
    kerb: float = 0.0
    kerb_x: float = 1e9

    def height(self, x, z):
        x, z = np.asarray(x, float), np.asarray(z, float)
        g = self.grade * np.maximum(z - self.grade_from, 0.0) - self.crown * np.abs(x)
        return g + np.where(x >= self.kerb_x, self.kerb, 0.0)


@dataclass(frozen=True)
class Car:
    """A cuboid car: centre of its footprint (x, z) [m], length along its heading, width,
    body height above the road, yaw [rad] (0: heading along +z, seen from behind), and the
    ground clearance under its body (the wheels are not modelled: road is seen under it)."""

    x: float
    z: float
    yaw: float = 0.0
    length: float = 4.2
    width: float = 1.7
    height: float = 1.5
    clearance: float = 0.0


def _pixels(boxes) -> np.ndarray:
    """Mask of the pixels a check reads: the road-plane fit's sparse grid (every 4th row
    below the horizon, every 12th column) and each box with a 4 px margin."""
    mask = np.zeros((H, W), bool)
    mask[int(np.ceil(GEO.cy)) :: 4, ::12] = True
    for x1, y1, x2, y2 in boxes:
        mask[max(int(y1) - 4, 0) : int(y2) + 5, max(int(x1) - 4, 0) : int(x2) + 5] = True
    return mask


def render(road: Road, cars: list[Car], boxes=None, z_max: float = 120.0) -> np.ndarray:
    """Disparity map [px] of the scene (sky and road beyond ``z_max``: -1); ``boxes``: only
    the pixels a check of these boxes reads are rendered (:func:`_pixels`, the rest -1: a
    test's time), None: every pixel."""
    mask = np.ones((H, W), bool) if boxes is None else _pixels(boxes)
    v, u = np.nonzero(mask)
    a, b = (u - GEO.cx) / GEO.fx, (v - GEO.cy) / GEO.fy
    lo, hi = np.full(a.shape, 0.5), np.full(a.shape, 400.0)

    def f(t):  # > 0 below the road surface
        return b * t - (CAMERA_HEIGHT - road.height(a * t, t))

    hit = f(hi) > 0
    for _ in range(32):  # 400 m / 2^32: exact to well under a pixel's depth
        mid = 0.5 * (lo + hi)
        below = f(mid) > 0
        hi = np.where(below, mid, hi)
        lo = np.where(below, lo, mid)
    depth = np.where(hit, hi, np.inf)
    for car in cars:
        depth = np.minimum(depth, _car_hit(car, road, a, b))
    out = np.full((H, W), -1.0, np.float32)
    out[v, u] = np.where(depth < z_max, FB / depth, -1.0)
    return out


def _car_hit(car: Car, road: Road, a, b):
    """Depth (z) where each ray (a, b, 1) enters the car's cuboid (inf: misses)."""
    base = CAMERA_HEIGHT - float(road.height(car.x, car.z))  # y of the road under the car
    c, s = np.cos(car.yaw), np.sin(car.yaw)
    # car frame: along = heading (sin yaw, cos yaw) in (x, z), across, up (-y)
    o = np.array([-car.x, -car.z])
    ox, oz = c * o[0] - s * o[1], s * o[0] + c * o[1]  # origin in (across, along)
    dx, dz = c * a - s * 1.0, s * a + c * 1.0
    t0, t1 = np.zeros(a.shape), np.full(a.shape, np.inf)
    for org, d, half in ((ox, dx, car.width / 2), (oz, dz, car.length / 2)):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (-half - org) / d, (half - org) / d
        tn, tf = np.minimum(ta, tb), np.maximum(ta, tb)
        par = np.abs(d) < 1e-12
        tn = np.where(par, np.where(np.abs(org) <= half, -np.inf, np.inf), tn)
        tf = np.where(par, np.where(np.abs(org) <= half, np.inf, -np.inf), tf)
        t0, t1 = np.maximum(t0, tn), np.minimum(t1, tf)
    # vertical slab: y in [base - height, base - clearance]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (base - car.height) / b, (base - car.clearance) / b
    tn, tf = np.minimum(ta, tb), np.maximum(ta, tb)
    t0, t1 = np.maximum(t0, tn), np.minimum(t1, tf)
    return np.where((t1 >= t0) & (t0 > 0.1), t0, np.inf)


def corners(car: Car, road: Road) -> np.ndarray:
    """The 8 corners (8, 3) of the car's 3D box in the camera frame (y down)."""
    base = CAMERA_HEIGHT - float(road.height(car.x, car.z))
    c, s = np.cos(car.yaw), np.sin(car.yaw)
    out = []
    for al in (-car.length / 2, car.length / 2):
        for ac in (-car.width / 2, car.width / 2):
            x = car.x + c * ac + s * al
            z = car.z - s * ac + c * al
            for y in (base, base - car.height):
                out.append((x, y, z))
    return np.array(out)


def label_box(car: Car, road: Road) -> tuple[float, float, float, float]:
    """The full-extent 2D box: the projection of the car's 3D box."""
    p = corners(car, road)
    u = GEO.fx * p[:, 0] / p[:, 2] + GEO.cx
    v = GEO.fy * p[:, 1] / p[:, 2] + GEO.cy
    return (float(u.min()), float(v.min()), float(u.max()), float(v.max()))
