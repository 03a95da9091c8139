"""bench/real_motion.py's ranging what-if (``bench_tracker.py real --ranging-error-scale S
[--ranging-error-min-depth Z]``): each simulated 3D position's error from the true point is
scaled by S and its reported covariance by S^2, on the same random draws, so the figures of two
scales are paired; scale 1 is the measured stereo model exactly.

Synthetic (no KITTI data): a KITTI-like rectified pair and a stated disparity error model.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))
import real_motion as rm  # noqa: E402

F, CX, CY, B = 721.5, 609.6, 172.9, 0.54
P2 = np.array([[F, 0.0, CX, 44.9], [0.0, F, CY, 0.2], [0.0, 0.0, 1.0, 0.003]])
P3 = np.array([[F, 0.0, CX, 44.9 - F * B], [0.0, F, CY, 0.2], [0.0, 0.0, 1.0, 0.003]])
CALIB = SimpleNamespace(P2=P2, P3=P3, fx=F, fy=F, cx=CX, cy=CY, baseline=B)
MODEL = rm.StereoErrorModel(
    disparity=(5.0, 20.0, 60.0), bias_px=(-0.4, -0.2, 0.0), spread_px=(0.6, 0.3, 0.2)
)
POINTS = [np.array([x, 1.0, z]) for x, z in ((-3.0, 8.0), (2.0, 25.0), (-6.0, 47.0), (4.0, 70.0))]


def _measure(scale: float, min_depth: float = 0.0, seed: int = 7):
    dm = rm.DetectionModel(ranging_error_scale=scale, ranging_error_min_depth=min_depth)
    ranger = rm._Ranger(CALIB, MODEL, dm, np.random.default_rng(seed))
    out = [ranger.measure(c) for c in POINTS for _ in range(3)]
    return out, ranger.errors


@pytest.mark.parametrize("scale", [0.0, 0.25, 0.5, 2.0])
def test_error_and_covariance_scale_on_the_same_draws(scale):
    base, _ = _measure(1.0)
    scaled, errors = _measure(scale)
    truths = [c for c in POINTS for _ in range(3)]
    for (p1, R1), (ps, Rs), c in zip(base, scaled, truths, strict=True):
        assert np.linalg.norm(p1 - c) > 1e-3  # the model does draw an error
        np.testing.assert_allclose(ps - c, scale * (p1 - c), atol=1e-9)
        np.testing.assert_allclose(Rs, max(scale, 0.05) ** 2 * R1, rtol=1e-12)
        assert np.all(np.linalg.eigvalsh(Rs) > 0)  # never a singular covariance, even at 0
    # the covariance check's rows (true depth, depth error, reported std) follow the scaled ones
    for (z, err, std), (ps, Rs), c in zip(errors, scaled, truths, strict=True):
        assert z == pytest.approx(c[2])
        assert err == pytest.approx(ps[2] - c[2])
        assert std == pytest.approx(np.sqrt(Rs[2, 2]))


def test_scale_one_is_the_stereo_model_as_it_is():
    (a, _), (b, _) = _measure(1.0), _measure(1.0, min_depth=30.0)
    for (pa, Ra), (pb, Rb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa, pb)
        np.testing.assert_array_equal(Ra, Rb)


def test_min_depth_scales_only_the_far_points():
    base, _ = _measure(1.0)
    far, _ = _measure(0.0, min_depth=40.0)
    truths = [c for c in POINTS for _ in range(3)]
    for (p1, R1), (pf, Rf), c in zip(base, far, truths, strict=True):
        if c[2] >= 40.0:
            np.testing.assert_allclose(pf, c, atol=1e-9)
        else:
            np.testing.assert_array_equal(pf, p1)
            np.testing.assert_array_equal(Rf, R1)
