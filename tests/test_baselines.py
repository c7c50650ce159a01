"""Closed-form baselines (pbdyn.metrics.baselines): flux and static share by hand on tiny maps, on imported worlds'
real shapes, and in the batch's per-map metrics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbdyn.metrics.baselines import flux, projected_area, static_share, swept_width
from pbdyn.metrics.catalog import BASELINES, BATCH, TABLE_ORDER
from pbdyn.metrics.registry import compute
from pbdyn.world.geometry import StaticBody
from tests.test_metrics import make_rollout
from tests.test_worlds import BOX, rollout_of, world

SPHERE = BOX.replace("box.urdf", "sphere.urdf")


def test_flux_by_hand_2d_and_3d():
    # two discs: r 0.5 at 2 m/s and r 1.5 at 3 m/s (diagonal), MAV radius 1: (2*1.5*2 + 2*2.5*3) / 2500
    ro = make_rollout([[10.0, 10.0], [30.0, 30.0]], [[2.0, 0.0], [3.0 / math.sqrt(2), 3.0 / math.sqrt(2)]],
                      [0.5, 1.5])
    res = flux(ro)
    assert res.value == pytest.approx((6.0 + 15.0) / 2500.0, rel=1e-12)
    np.testing.assert_allclose(res.per_sample, [6.0, 15.0], rtol=1e-12)
    assert flux(ro, mav_radius=0.5).value == pytest.approx((2 * 1.0 * 2 + 2 * 2.0 * 3) / 2500.0, rel=1e-12)
    # a still obstacle sweeps nothing
    assert flux(make_rollout([[10.0, 10.0]], [[0.0, 0.0]], [1.0])).value == 0.0
    # 3D balls: pi (r + R)^2 |v| / volume
    ro3 = make_rollout([[10.0, 10.0, 5.0]], [[0.0, 0.0, 2.0]], [1.0], (50.0, 50.0, 20.0))
    assert flux(ro3).value == pytest.approx(math.pi * 4.0 * 2.0 / 50000.0, rel=1e-12)


def test_static_share_by_hand():
    # a pillar of radius 2 inflated by the MAV radius 1: pi 3^2 of 2500 m^2 (cells of 0.05 m: within 0.5%)
    ro = make_rollout([[40.0, 40.0]], [[1.0, 0.0]], [1.0], static=(StaticBody("pillar", (20.0, 20.0), radius=2.0),))
    res = static_share(ro, cell=0.05)
    assert res.value == pytest.approx(math.pi * 9.0 / 2500.0, rel=5e-3)
    # a 4 x 2 box: its Minkowski sum with the unit disc, (4 + 2)(2 + 2) - (4 - pi)
    box = StaticBody("box", (10.0, 30.0), size=(4.0, 2.0), yaw=0.4)
    ro2 = make_rollout([[40.0, 40.0]], [[1.0, 0.0]], [1.0], static=(box,))
    assert static_share(ro2, cell=0.05).value == pytest.approx((24.0 - 4.0 + math.pi) / 2500.0, rel=5e-3)
    # overlaps count once: two coincident pillars block what one does; per_sample is each body alone
    two = make_rollout([[40.0, 40.0]], [[1.0, 0.0]], [1.0],
                       static=(StaticBody("pillar", (20.0, 20.0), radius=2.0),) * 2)
    both = static_share(two, cell=0.05)
    assert both.value == pytest.approx(res.value, rel=1e-12)
    np.testing.assert_allclose(both.per_sample, [res.value, res.value], rtol=1e-12)
    assert static_share(make_rollout([[40.0, 40.0]], [[1.0, 0.0]], [1.0])).value == 0.0


def test_swept_width_and_projected_area_of_point_sets():
    xs = np.arange(-1.0 + 0.005, 1.0, 0.01)
    g = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    disc = g[np.sum(g * g, axis=1) < 1.0]
    assert swept_width(disc, np.array([1.0, 2.0]), 0.01) == pytest.approx(2.0, abs=0.02)
    rect = g[np.abs(g[:, 1]) < 0.25]                                        # 2 x 0.5
    assert swept_width(rect, np.array([1.0, 0.0]), 0.01) == pytest.approx(0.5, abs=0.011)
    assert swept_width(rect, np.array([0.0, 1.0]), 0.01) == pytest.approx(2.0, abs=0.011)
    xs3 = np.arange(-1.0 + 0.025, 1.0, 0.05)
    g3 = np.stack(np.meshgrid(xs3, xs3, xs3, indexing="ij"), -1).reshape(-1, 3)
    ball = g3[np.sum(g3 * g3, axis=1) < 1.0]
    assert projected_area(ball, np.array([0.3, -0.2, 1.0]), 0.05) == pytest.approx(math.pi, rel=0.08)


def test_imported_bodies_use_their_real_shapes():
    # a moving sphere body of radius 1 sweeps like a generated disc of radius 1 (not its x-y bounding box)
    sc = world([{"name": "ball", "urdf": SPHERE, "position": [10.0, 25.0, 2.0], "motion": "constant_velocity",
                 "velocity": [3.0, 0.0]}])
    got = compute(rollout_of(sc), "flux").value
    assert got == pytest.approx(2.0 * (1.0 + 1.0) * 3.0 / 2500.0, rel=0.02)
    # a moving 2 x 1 box: 1 m across its motion along x, 2 m across motion along y
    for vel, width in (([4.0, 0.0], 1.0), ([0.0, 4.0], 2.0)):
        sc = world([{"name": "cart", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [25.0, 25.0, 1.5],
                     "motion": "constant_velocity", "velocity": vel}])
        assert compute(rollout_of(sc), "flux").value == pytest.approx((width + 2.0) * 4.0 / 2500.0, rel=0.02)
    # a still box is a static share, not a flux
    sc = world([{"name": "shelf", "urdf": BOX, "scale": [2.0, 12.0, 3.0], "position": [15.0, 15.0, 1.5]},
                {"name": "cart", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [35.0, 10.0, 1.5],
                 "motion": "constant_velocity", "velocity": [1.0, 0.0]}])
    ro = rollout_of(sc)
    assert compute(ro, "static_share", cell=0.05).value == pytest.approx((4.0 * 14.0 - 4.0 + math.pi) / 2500.0,
                                                                        rel=0.01)


def test_baselines_are_batch_metrics_but_not_table_rows():
    assert set(BASELINES) == {"flux", "static_share"}
    assert set(BASELINES) <= set(BATCH) and not set(BASELINES) & set(TABLE_ORDER)
