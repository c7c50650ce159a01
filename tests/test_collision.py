"""Swept and sampled collision checks against dynamic obstacles and PyBullet's static geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbdyn.sim.collision import sampled_dynamic, sampled_static, swept_dynamic, swept_static
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import StaticBody

R_MAV = 0.5


@pytest.fixture(scope="module")
def world():
    # Arena 20 x 10; a pillar r=1 at (10, 5); a thin box (0.1 x 6) at x = 15; one dynamic obstacle r=1.
    w = PyBulletWorld(dims=2, arena_size=(20.0, 10.0), mav_radius=R_MAV, obstacle_radii=[1.0],
                      static_bodies=[StaticBody("pillar", (10.0, 5.0), radius=1.0),
                                     StaticBody("box", (15.0, 5.0), size=(0.1, 6.0))])
    w.set_obstacle_positions([[5.0, 5.0]])
    yield w
    w.close()


# ------------------------------------------------------------------------------------------ static
def test_mav_on_a_pillar_is_a_static_collision(world):
    st = swept_static(world, [7.0, 5.0], [8.8, 5.0])          # contact when the centre reaches x = 8.5
    assert st.hit and world.body_kind(st.body_id) == ("static", 0)
    assert math.isclose(st.fraction, 1.5 / 1.8, abs_tol=1e-3)
    assert st.min_clearance <= 1e-4
    sa = sampled_static(world, [8.8, 5.0])
    assert sa.hit and sa.body_id == st.body_id and math.isclose(sa.min_clearance, -0.3, abs_tol=1e-3)
    assert not sampled_static(world, [8.0, 5.0]).hit


def test_mav_at_a_wall_is_a_static_collision(world):
    st = swept_static(world, [1.0, 8.0], [0.2, 8.0])           # wall face at x = 0: contact at x = 0.5
    assert st.hit and world.body_kind(st.body_id)[0] == "wall"
    assert math.isclose(st.fraction, 0.5 / 0.8, abs_tol=1e-3)
    assert sampled_static(world, [0.2, 8.0]).hit
    # Already touching-through at the start: fraction 0.
    st0 = swept_static(world, [0.3, 8.0], [1.0, 8.0])
    assert st0.hit and st0.fraction == 0.0


def test_free_steps_report_exact_clearances(world):
    st = swept_static(world, [4.0, 8.0], [4.5, 8.0])           # nearest: the north wall, 2 m - 0.5
    assert not st.hit and st.fraction == 1.0 and st.body_id == -1
    assert math.isclose(st.min_clearance, 1.5, abs_tol=1e-3)
    # Passing the pillar sideways: the advancement visits the closest approach region; min clearance >= truth.
    st = swept_static(world, [8.0, 7.0], [12.0, 7.0])           # closest: 2 - 1 - 0.5 = 0.5 at x = 10
    assert not st.hit
    assert 0.5 - 1e-3 <= st.min_clearance <= 0.5 + 0.05
    sa = sampled_static(world, [12.0, 7.0])
    assert not sa.hit and sa.min_clearance > st.min_clearance


def test_swept_static_catches_a_thin_box_between_samples(world):
    p0, p1 = [14.0, 5.0], [16.0, 5.0]                           # both ends clear of the 0.1 m box at x = 15
    assert not sampled_static(world, p1).hit
    assert world.static_clearance(p0, 5.0) > 0 and world.static_clearance(p1, 5.0) > 0
    st = swept_static(world, p0, p1)
    assert st.hit and world.body_kind(st.body_id) == ("static", 1)
    assert math.isclose(st.fraction, (14.95 - 0.5 - 14.0) / 2.0, abs_tol=1e-3)


# ------------------------------------------------------------------------------------------ dynamic
def test_mav_on_a_moving_obstacle_is_a_dynamic_collision(world):
    # The obstacle (r = 1) moves from (5, 5) to (5, 6.2); the MAV sits at (5, 7): contact at y = 5.5 -> s = 0.5/1.2.
    obs0, obs1 = np.array([[5.0, 5.0]]), np.array([[5.0, 6.2]])
    dy = swept_dynamic([5.0, 7.0], [5.0, 7.0], obs0, obs1, [1.0], R_MAV)
    assert dy.hit and dy.index == 0 and math.isclose(dy.fraction, 0.5 / 1.2, rel_tol=1e-12)
    assert math.isclose(dy.min_clearance, 0.8 - 1.5, rel_tol=1e-12)
    sa = sampled_dynamic([5.0, 7.0], obs1, [1.0], R_MAV)
    assert sa.hit and sa.index == 0 and math.isclose(sa.min_clearance, -0.7, rel_tol=1e-12)
    # The PyBullet geometry agrees with the analytic clearance at the sample.
    world.set_obstacle_positions(obs1)
    assert math.isclose(world.clearance_to_bodies([5.0, 7.0], world.obstacle_ids, 5.0)[0], -0.7, abs_tol=1e-3)
    world.set_obstacle_positions(obs0)


def test_fast_obstacle_passing_through_is_caught_only_by_the_swept_check():
    # The obstacle crosses the MAV's position entirely within one step: clear at both samples.
    mav = np.array([0.0, 0.0])
    obs0, obs1 = np.array([[-3.0, 0.3]]), np.array([[3.0, 0.3]])
    assert not sampled_dynamic(mav, obs1, [1.0], R_MAV).hit
    dy = swept_dynamic(mav, mav, obs0, obs1, [1.0], R_MAV)
    assert dy.hit and dy.index == 0
    # |(-3 + 6 s, 0.3)| = 1.5  ->  6 s = 3 - sqrt(1.5^2 - 0.3^2)
    assert math.isclose(dy.fraction, (3.0 - math.sqrt(1.5 ** 2 - 0.09)) / 6.0, rel_tol=1e-12)
    assert math.isclose(dy.min_clearance, 0.3 - 1.5, rel_tol=1e-12)


def test_exact_fraction_and_min_clearance_with_both_moving():
    # MAV (0,0) -> (2,0); obstacle 0 (r = 0.5) (4,1) -> (2,1): relative dp(s) = (-4 + 4 s, -1), reach 1.0
    # -> never hits (min distance 1.0 = reach exactly: touching is not a collision); obstacle 1 hits first.
    mav0, mav1 = [0.0, 0.0], [2.0, 0.0]
    obs0 = np.array([[4.0, 1.0], [3.0, -0.2], [10.0, 10.0]])
    obs1 = np.array([[2.0, 1.0], [3.0, -0.2], [10.0, 10.0]])
    radii = [0.5, 0.7, 1.0]
    dy = swept_dynamic(mav0, mav1, obs0, obs1, radii, R_MAV)
    # obstacle 1: dp(s) = (2 s - 3, 0.2), reach 1.2: (2 s - 3)^2 = 1.44 - 0.04 -> s = (3 - sqrt(1.4)) / 2
    assert dy.hit and dy.index == 1
    assert math.isclose(dy.fraction, (3.0 - math.sqrt(1.4)) / 2.0, rel_tol=1e-12)
    # min clearance over the step: obstacle 1 at s = 1: |(-1, 0.2)| - 1.2
    assert math.isclose(dy.min_clearance, math.hypot(1.0, 0.2) - 1.2, rel_tol=1e-12)
    touching = swept_dynamic(mav0, mav1, obs0[:1], obs1[:1], radii[:1], R_MAV)
    assert not touching.hit and math.isclose(touching.min_clearance, 0.0, abs_tol=1e-12)


def test_already_overlapping_has_fraction_zero_and_3d_is_euclidean():
    dy = swept_dynamic([0.0, 0.0], [1.0, 0.0], np.array([[0.5, 0.0]]), np.array([[0.5, 0.0]]), [1.0], R_MAV)
    assert dy.hit and dy.fraction == 0.0
    # 3D: an obstacle 1.4 m above the MAV's path centre-to-centre: reach 1.5, so a hit; in-plane distance alone
    # would be 0.
    dy3 = swept_dynamic([0.0, 0.0, 0.0], [2.0, 0.0, 0.0], np.array([[1.0, 0.0, 1.4]]), np.array([[1.0, 0.0, 1.4]]),
                        [1.0], R_MAV)
    assert dy3.hit and math.isclose(dy3.min_clearance, 1.4 - 1.5, rel_tol=1e-12)
    dy3 = swept_dynamic([0.0, 0.0, 0.0], [2.0, 0.0, 0.0], np.array([[1.0, 0.0, 1.6]]), np.array([[1.0, 0.0, 1.6]]),
                        [1.0], R_MAV)
    assert not dy3.hit


def test_no_obstacles():
    empty = np.zeros((0, 2))
    dy = swept_dynamic([0.0, 0.0], [1.0, 0.0], empty, empty, np.zeros(0), R_MAV)
    assert not dy.hit and dy.index == -1 and dy.min_clearance == math.inf
    assert sampled_dynamic([0.0, 0.0], empty, np.zeros(0), R_MAV).min_clearance == math.inf


def test_swept_dynamic_agrees_with_dense_sampling():
    rng = np.random.default_rng(11)
    n = 40
    for _ in range(30):
        mav0, mav1 = rng.uniform(0, 10, 2), rng.uniform(0, 10, 2)
        obs0, obs1 = rng.uniform(0, 10, (n, 2)), rng.uniform(0, 10, (n, 2))
        radii = rng.uniform(0.3, 1.0, n)
        dy = swept_dynamic(mav0, mav1, obs0, obs1, radii, R_MAV)
        s = np.linspace(0, 1, 20001)[:, None, None]
        rel = (mav0 + s * (mav1 - mav0)) - (obs0 + s * (obs1 - obs0))
        clear = np.linalg.norm(rel, axis=-1) - (radii + R_MAV)           # [S, N]
        assert clear.min() - 1e-3 <= dy.min_clearance <= clear.min() + 1e-12   # exact <= any sample
        if dy.hit:
            k = int(np.argmax((clear < 0).any(axis=1)))                  # first overlapping sample
            assert abs(dy.fraction - s[k, 0, 0]) <= 1e-4
            assert clear[k, dy.index] < 1e-3                             # the reported obstacle is the one hit
        else:
            assert not (clear < 0).any()
