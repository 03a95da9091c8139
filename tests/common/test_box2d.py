"""2D box overlaps shared by the detector, tracker and evaluator (hand-computed values)."""

import numpy as np
import pytest
from vehicle_common.box2d import iou_2d, overlap_over_first


def test_iou_and_overlap_over_first():
    a = np.array([[0.0, 0.0, 10.0, 10.0]])
    b = np.array([[5.0, 0.0, 15.0, 10.0], [20.0, 20.0, 30.0, 30.0], [0.0, 0.0, 10.0, 10.0]])
    np.testing.assert_allclose(iou_2d(a, b), [[50 / 150, 0.0, 1.0]])
    np.testing.assert_allclose(overlap_over_first(a, b), [[0.5, 0.0, 1.0]])
    # a small box inside a large region: overlap over the small box is 1, IoU is its share
    small, big = np.array([[2.0, 2.0, 4.0, 4.0]]), np.array([[0.0, 0.0, 10.0, 10.0]])
    assert overlap_over_first(small, big)[0, 0] == 1.0
    assert iou_2d(small, big)[0, 0] == pytest.approx(4 / 100)


def test_degenerate_and_nan_boxes_overlap_nothing():
    a = np.array([[5.0, 5.0, 5.0, 9.0], [np.nan, 0.0, 1.0, 1.0]])
    b = np.array([[0.0, 0.0, 10.0, 10.0]])
    np.testing.assert_array_equal(iou_2d(a, b), [[0.0], [0.0]])
    np.testing.assert_array_equal(overlap_over_first(a, b), [[0.0], [0.0]])
    assert iou_2d(np.zeros((0, 4)), b).shape == (0, 1)
