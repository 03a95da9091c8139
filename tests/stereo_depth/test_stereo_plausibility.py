"""Stereo plausibility check: road plane per frame (pitch, roll, grade, fallbacks) and the
per-box check (floating, sunk, too short / tall, flat on the road), synthetic and real."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from stereo_depth_node.plausibility import (
    GroundEstimator,
    GroundPlane,
    PlausibilityParams,
    check_boxes,
)
from stereo_depth_node.reprojection import StereoGeometry

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5371)
FB = GEO.fx * GEO.baseline
H, W = 375, 1242


def plane_normal(pitch_deg: float, roll_deg: float) -> np.ndarray:
    n = np.array([math.tan(math.radians(roll_deg)), 1.0, math.tan(math.radians(pitch_deg))])
    return n / np.linalg.norm(n)


def render(normal, height, car=None):
    """Disparity map of a road plane n.P = height (+ a car: a fronto-parallel face at depth z
    spanning x in [x0, x1], from the road up to 1.5 m); invalid (sky) = -1."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    rays = np.stack([(u - GEO.cx) / GEO.fx, (v - GEO.cy) / GEO.fy, np.ones_like(u)], -1)
    nr = rays @ normal
    with np.errstate(divide="ignore"):
        z = np.where(nr > 1e-6, height / nr, np.inf)
    if car is not None:
        zc, x0, x1 = car
        p = rays * zc
        above = height - p @ normal
        hit = (above >= 0) & (above <= 1.5) & (p[..., 0] >= x0) & (p[..., 0] <= x1) & (zc < z)
        z = np.where(hit, zc, z)
    d = np.where(np.isfinite(z) & (z < 200), FB / z, -1.0)
    return d.astype(np.float32)


def car_box(normal, height, zc, x0, x1):
    """The car's 2D box (rows from its top edge to its contact row with the road)."""
    corners = []
    for x in (x0, x1):
        # a point on the road under (x, ., zc): solve n.(x, y, zc) = height for y
        y_road = (height - normal[0] * x - normal[2] * zc) / normal[1]
        for y in (y_road, y_road - 1.5 / normal[1]):
            corners.append((GEO.fx * x / zc + GEO.cx, GEO.fy * y / zc + GEO.cy))
    c = np.array(corners)
    return (c[:, 0].min(), c[:, 1].min(), c[:, 0].max(), c[:, 1].max())


def angle_deg(a, b) -> float:
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


@pytest.mark.parametrize(
    ("pitch", "roll", "height"),
    [(0.0, 0.0, 1.65), (3.0, 0.0, 1.65), (-3.0, 1.5, 1.5), (2.0, -2.0, 1.8), (-5.0, 0.0, 1.65)],
)
def test_road_plane_is_recovered_under_pitch_roll_and_grade(pitch, roll, height):
    """The camera's pitch and roll and a constant grade all tilt the road plane in the camera
    frame: the per-frame fit follows them (a car in view does not pull it)."""
    n = plane_normal(pitch, roll)
    disp = render(n, height, car=(15.0, -2.0, 1.0))
    plane = GroundEstimator().update(disp, GEO)
    assert plane.source == "fit"
    assert plane.offset == pytest.approx(height, abs=0.02)
    assert angle_deg(plane.normal, n) < 0.2
    assert plane.pitch_deg == pytest.approx(pitch, abs=0.2)
    assert plane.roll_deg == pytest.approx(roll, abs=0.2)


def test_car_on_a_sloping_road_is_plausible_only_with_the_fitted_plane():
    """Road rising ahead at 4 % relative to the camera (a grade or the camera pitched up): the
    level prior puts a car standing 30 m ahead 1.2 m above its road, the fitted plane on it."""
    n = plane_normal(math.degrees(math.atan(0.04)), 0.0)
    car = (30.0, -1.0, 0.8)
    disp = render(n, 1.65, car)
    box = car_box(n, 1.65, *car)
    fitted = GroundEstimator().update(disp, GEO)
    prior = GroundEstimator(replace(PlausibilityParams(), ground_fit=False)).update(disp, GEO)
    assert prior.source == "prior"
    (ok,) = check_boxes(disp, [box], [30.0], GEO, fitted)
    (bad,) = check_boxes(disp, [box], [30.0], GEO, prior)
    assert ok.plausible and abs(ok.measures.bottom_height) < 0.1
    assert ok.measures.height == pytest.approx(1.5, abs=0.1)
    assert not bad.plausible and bad.measures.bottom_height > 1.0


def test_boxes_that_cannot_be_a_vehicle_are_rejected():
    """Level road, a car 20 m ahead; boxes with the car's depth that float above it or sink
    below the road, boxes 0.3 m and 6 m tall standing on the road, and a box on the empty
    road surface (at the road's own depth)."""
    n = plane_normal(0.0, 0.0)
    car = (20.0, -1.0, 0.8)
    disp = render(n, 1.65, car)
    plane = GroundEstimator().update(disp, GEO)
    x1, y1, x2, y2 = car_box(n, 1.65, *car)
    px_per_m = GEO.fy / 20.0
    boxes = {
        "car": ((x1, y1, x2, y2), 20.0),
        "floating": ((x1, y1 - 40, x2, y2 - 40), 20.0),  # 1.1 m above the road
        "sunk": ((x1, y1 + 30, x2, y2 + 30), 20.0),
        "0.3 m tall": ((x1, y2 - 0.3 * px_per_m, x2, y2), 20.0),
        "6 m tall": ((x1, y2 - 6.0 * px_per_m, x2, y2), 20.0),
        # 4 m wide, 0.6 m of road rows at 11-14 m, ranged at the road's depth mid-box
        "flat on the road": ((400.0, 260.0, 600.0, 280.0), FB / float(disp[270, 500])),
    }
    checks = dict(
        zip(
            boxes,
            check_boxes(
                disp, [b for b, _ in boxes.values()], [z for _, z in boxes.values()], GEO, plane
            ),
            strict=True,
        )
    )
    assert checks["car"].plausible and checks["car"].plausibility == 1.0
    m = checks["car"].measures
    assert m.height == pytest.approx(1.5, abs=0.05) and m.width == pytest.approx(1.8, abs=0.05)
    assert (
        abs(m.bottom_height) < 0.05 and m.ground_fraction < PlausibilityParams().max_ground_fraction
    )
    for name in ("floating", "sunk", "0.3 m tall", "6 m tall", "flat on the road"):
        assert not checks[name].plausible, name
        assert checks[name].plausibility < 0.5, name
    assert checks["floating"].measures.bottom_height == pytest.approx(40 / px_per_m, abs=0.05)
    assert checks["sunk"].measures.bottom_height < -0.6
    assert checks["flat on the road"].measures.ground_fraction > 0.9


def test_cut_edges_switch_off_the_checks_they_falsify():
    """A car cut by the bottom border has no bottom edge and may look short; one cut at the
    side may look narrow: neither is rejected for it."""
    plane = GroundPlane.level(1.65)
    disp = np.full((H, W), FB / 8.0, np.float32)
    params = replace(PlausibilityParams(), min_width=1.4, max_ground_fraction=1.0)
    bottom_cut, side_cut, short = check_boxes(
        disp,
        [(500, 300, 700, H - 1), (0, 200, 40, 290), (500, 300, 700, 320)],
        [8.0, 8.0, 8.0],
        GEO,
        plane,
        params,
    )
    assert math.isnan(bottom_cut.measures.bottom_height) and bottom_cut.measures.cut_vertical
    assert bottom_cut.plausible  # 0.83 m tall, but its lower part is out of the image
    assert side_cut.measures.cut_side and side_cut.measures.width < 1.4
    assert not short.plausible  # the same 0.22 m tall box inside the image is not a car


def test_road_not_visible_falls_back_to_the_previous_fit_then_the_prior():
    params = replace(PlausibilityParams(), ground_keep_frames=2)
    est = GroundEstimator(params, camera_height=1.6)
    n = plane_normal(2.0, 1.0)
    first = est.update(render(n, 1.7), GEO)
    assert first.source == "fit"
    # a truck fills the view: a fronto-parallel surface 6 m ahead, no road
    wall = np.full((H, W), FB / 6.0, np.float32)
    for _ in range(2):
        kept = est.update(wall, GEO)
        assert kept.source == "previous"
        assert np.allclose(kept.normal, first.normal) and kept.offset == first.offset
    prior = est.update(wall, GEO)
    assert prior.source == "prior" and prior.offset == 1.6
    assert np.allclose(prior.normal, [0.0, 1.0, 0.0])
    assert est.update(np.full((H, W), -1.0, np.float32), GEO).source == "prior"
    assert est.update(render(n, 1.7), GEO).source == "fit"


def test_bad_settings_are_refused():
    for changes in (
        {"plausibility_action": "drop"},
        {"min_height": 3.0, "max_height": 2.0},
        {"ground_height_range": (2.0, 1.0)},
        {"height_softness": 0.0},
    ):
        with pytest.raises(ValueError, match=next(iter(changes))[:10]):
            GroundEstimator(replace(PlausibilityParams(), **changes))


def test_real_0005_labelled_cars_pass_and_a_box_on_the_empty_road_does_not(kitti_tracking_root):
    """Real KITTI 0005, frame 0, the default SGBM map: the road plane is where the camera is
    mounted (1.65 m), the labelled cars stand on it and pass; a car-sized box on the empty
    road in front of the ego car is rejected."""
    from stereo_depth_node.disparity import DisparityParams, compute_disparity
    from stereo_depth_node.ranging import RangingParams, disparity_bias_at, range_boxes
    from stereo_depth_node.region_matching import to_gray
    from vehicle_common.kitti import TrackingSequence

    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    left, right = seq.read_stereo(0)
    disp = compute_disparity(left, right, DisparityParams())
    bias = disparity_bias_at(np.arange(disp.shape[1]), geo, RangingParams())
    plane = GroundEstimator().update(disp, geo, bias)
    assert plane.source == "fit" and plane.offset == pytest.approx(1.65, abs=0.1)
    cars = [o for o in seq.objects(0) if o.type == "Car"]
    boxes = [o.bbox for o in cars] + [(560.0, 290.0, 680.0, 340.0)]
    res = range_boxes(disp, boxes, geo, RangingParams(), None, (to_gray(left), to_gray(right)))
    depths = [geo.fx * geo.baseline / r.disparity for r in res]
    checks = check_boxes(disp, boxes, depths, geo, plane)
    assert len(cars) >= 2 and all(c.plausible for c in checks[:-1])
    assert not checks[-1].plausible


def test_camera_height_is_checked_against_the_fitted_road_plane():
    """ground_height (assumed: not in CameraInfo) is compared once with the median of the
    fitted road planes; a difference names the value to set; no fit at all is reported."""
    import numpy as np
    from stereo_depth_node.plausibility import GroundHeightCheck, GroundPlane

    def plane(h, source="fit"):
        return GroundPlane(np.array([0.0, 1.0, 0.0]), h, source, 500)

    agree = GroundHeightCheck(1.65, True, (1.0, 2.5), fits=3)
    reports = [agree.add(plane(h)) for h in (1.60, 1.70, 1.62, 1.7)]
    assert reports[:2] == [None, None] and reports[3] is None  # one report only
    level, line = reports[2]
    assert level == "info" and "camera 1.62 m above the road" in line
    assert "ground_height 1.65 m (assumed) agrees" in line
    low = GroundHeightCheck(1.65, True, (1.0, 2.5), fits=3)
    reports = [low.add(plane(h)) for h in (1.2, 1.25, 1.3)]
    level, line = reports[-1]
    assert level == "warning" and "stereo_depth.ground_height:=1.25" in line
    none = GroundHeightCheck(1.65, False, (1.0, 2.5), fits=3, frames=4)
    reports = [none.add(plane(1.65, "prior")) for _ in range(5)]
    level, line = reports[3]
    assert level == "warning" and "none found in 4 frames" in line and reports[4] is None
    assert "(parameter)" in line


def _car_box(z: float, bottom_above_road: float, height_m: float = 1.5, u: float = 700.0):
    """A 1.7 m wide box at depth z whose bottom edge is ``bottom_above_road`` above a level
    road 1.65 m below the camera."""
    y2 = GEO.cy + GEO.fy * (1.65 - bottom_above_road) / z
    y1 = y2 - GEO.fy * height_m / z
    half = 0.5 * GEO.fx * 1.7 / z
    return (u - half, y1, u + half, y2)


def test_limits_widen_with_the_depth_uncertainty():
    """Issue #34: a far car's bottom 0.5 m above (or 0.7 m below) the road plane, extrapolated
    from the road nearer than 30 m, is within what the plane's tilt and the stereo depth noise
    allow at 50 m, not at 10 m; with fixed limits (noise_sigmas 0) it is rejected at both, as
    before."""
    plane = GroundPlane.level(1.65)
    disp = np.full((H, W), -1.0, np.float32)  # no road pixels: ground fraction 0
    scaled = PlausibilityParams()
    fixed = replace(scaled, noise_sigmas=0.0)
    for bottom in (0.5, -0.7):
        boxes = [_car_box(10.0, bottom), _car_box(50.0, bottom)]
        depths = [10.0, 50.0]
        stds = [0.3, 0.18]  # the ranging's disparity stds (map / refined far box)
        near, far = check_boxes(disp, boxes, depths, GEO, plane, scaled, stds)
        assert not near.plausible and far.plausible, bottom
        assert far.measures.bottom_std > 3 * near.measures.bottom_std
        assert not any(c.plausible for c in check_boxes(disp, boxes, depths, GEO, plane, fixed))
    # a box that is no car at any range stays out: floating 1 m at 50 m, 0.8 m tall
    boxes = [_car_box(50.0, 1.0), _car_box(50.0, 0.0, 0.8)]
    assert not any(c.plausible for c in check_boxes(disp, boxes, [50.0] * 2, GEO, plane, scaled))


def test_the_depth_std_comes_from_the_disparity_std():
    plane = GroundPlane.level(1.65)
    disp = np.full((H, W), -1.0, np.float32)
    p = replace(PlausibilityParams(), road_tilt_std=0.0, box_edge_std=0.0)
    box = _car_box(40.0, 0.0)
    (exact,) = check_boxes(disp, [box], [40.0], GEO, plane, p)
    (noisy,) = check_boxes(disp, [box], [40.0], GEO, plane, p, [0.3])
    assert exact.measures.height_std == 0.0
    # dh / h = dz / z = z sigma_d / (f B)
    assert noisy.measures.height_std == pytest.approx(
        noisy.measures.height * 40.0 * 0.3 / FB, rel=1e-6
    )
