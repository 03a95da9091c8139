"""Issue #41 item 3: true cars the plausibility check used to drop (a parked car seen from the
side with the road visible under it, an uphill grade beyond the fitted road, a car in a row
ranged at the one before it) are kept at a lowered score; what is clearly no car is still
dropped. Scenes: plausibility_scenes (ray-cast road + cuboid cars, full-extent label boxes)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from plausibility_scenes import GEO, Car, Road, corners, label_box, render
from stereo_depth_node.plausibility import (
    GroundEstimator,
    GroundPlane,
    PlausibilityParams,
    check_boxes,
    published_score,
)
from stereo_depth_node.ranging import range_boxes

DEFAULTS = PlausibilityParams()
BEFORE = replace(DEFAULTS, reject_below=1.0)  # issue #34's reject: every implausible box
BIRTH = 0.35  # the stereo graph's tracker birth_score


def check_car(road: Road, cars: list[Car], depth=None, grow: float = 0.0, std: float = 0.15):
    """The check of cars[0]'s full-extent box (grown by ``grow`` px: a detector's looser box)
    at ``depth`` (None: its nearest corner + 0.5 m, ranged right) in the rendered scene."""
    box = np.add(label_box(cars[0], road), [-grow, -grow, grow, grow])
    disp = render(road, cars, [box])
    plane = GroundEstimator(DEFAULTS).update(disp, GEO)
    z = float(corners(cars[0], road)[:, 2].min()) + 0.5 if depth is None else depth
    (c,) = check_boxes(disp, [box], [z], GEO, plane, DEFAULTS, [std])
    return c, disp, box


def kept_unsure(c) -> float:
    """Dropped before, kept now at a lowered score; returns the published score of a 0.9."""
    assert not c.plausible
    assert published_score(c, 0.9, BEFORE) is None
    score = published_score(c, 0.9, DEFAULTS)
    assert score is not None and score < 0.9
    return score


def test_parked_car_seen_from_the_side_with_road_under_it_is_kept():
    """A car 45 m away, side on (yaw 1.2 rad), 0.3 m ground clearance: the road seen under its
    body and beside it fills a third of a slightly loose box: the road-share test fails."""
    c, _, _ = check_car(Road(), [Car(5.0, 45.0, yaw=1.2, clearance=0.3)], grow=3.0)
    assert c.measures.ground_fraction > DEFAULTS.max_ground_fraction
    assert kept_unsure(c) >= BIRTH  # a confident detection still starts a track


def test_car_on_an_uphill_grade_beyond_the_fitted_road_is_kept():
    """The road rises 3 % beyond 30 m (the plane is fitted nearer): a car at 50 m stands
    0.6 m above the extrapolated plane, beyond the depth-scaled limit: 'floating'."""
    c, _, _ = check_car(Road(grade=0.03), [Car(3.5, 50.0)])
    assert c.measures.bottom_height > DEFAULTS.max_bottom_height + c.measures.bottom_std
    assert kept_unsure(c) >= BIRTH


def test_car_in_a_row_ranged_at_the_car_before_it_is_kept():
    """Two cars parked in a row at 20 and 14 m: the far one's full-extent box holds the near
    one's rear, the ranging takes that depth, and the far box looks short and floating."""
    road, cars = Road(), [Car(3.5, 20.0), Car(2.9, 14.0)]
    box = label_box(cars[0], road)
    disp = render(road, cars, [box])
    (r,) = range_boxes(disp, [box], GEO)
    z = GEO.fx * GEO.baseline / r.disparity
    assert z < 15.0  # the nearer car's depth
    c, _, _ = check_car(road, cars, depth=z, std=r.disparity_std)
    assert c.measures.height < DEFAULTS.min_height
    kept_unsure(c)


@pytest.mark.parametrize(
    ("box", "depth", "what"),
    [
        ((600.0, 40.0, 640.0, 70.0), 40.0, "in the sky, 4 m above the road"),
        ((560.0, 60.0, 700.0, 200.0), 40.0, "7.8 m tall"),
        ((500.0, 200.0, 700.0, 240.0), 20.0, "flat on the road"),
    ],
)
def test_what_is_clearly_no_car_is_still_dropped(box, depth, what):
    disp = render(Road(), [], [box])
    plane = GroundPlane.level(1.65)
    (c,) = check_boxes(disp, [box], [depth], GEO, plane, DEFAULTS, [0.15])
    assert published_score(c, 0.9, DEFAULTS) is None, (what, c)


def test_published_score_per_action():
    disp = np.full((375, 1242), -1.0, np.float32)
    plane = GroundPlane.level(1.65)
    ok_box = (580.0, 178.0, 641.0, 232.4)  # 1.7 m wide, 1.5 m tall at 20 m, on the road
    unsure = (580.0, 180.0, 641.0, 216.1)  # 1.0 m tall, floating 0.45 m
    ok, mid = check_boxes(disp, [ok_box, unsure], [20.0, 20.0], GEO, plane, DEFAULTS)
    assert ok.plausible and not mid.plausible and mid.plausibility >= DEFAULTS.reject_below
    for action, want in (("flag", 0.8), ("score", 0.8 * mid.plausibility)):
        p = replace(DEFAULTS, plausibility_action=action)
        assert published_score(ok, 0.8, p) == 0.8
        assert published_score(mid, 0.8, p) == pytest.approx(want)
    assert published_score(mid, 0.8, DEFAULTS) == pytest.approx(0.8 * mid.plausibility)
    assert published_score(mid, 0.8, BEFORE) is None
    with pytest.raises(ValueError, match="reject_below"):
        replace(DEFAULTS, reject_below=1.5).validate()
