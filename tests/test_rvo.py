"""RVO (ORCA) obstacle motion: constraint geometry against brute force, no overlaps, CVM when alone, head-on passes."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.motion.cvm import cvm_fold
from pbdyn.motion.rvo import RVOParams, orca_halfspaces, rvo_rollout
from pbdyn.world.maps import enumerate_maps, spawn_obstacles
from pbdyn.world.rollout import build_rollout


def _in_vo(v, p, big_r, tau):
    """Brute force: does relative velocity v [K, d] bring the pair within big_r during (0, tau]?"""
    t = np.linspace(1e-4, tau, 4001)
    d = np.linalg.norm(t[None, :, None] * v[:, None, :] - p[None, None, :], axis=-1)
    return d.min(axis=1) < big_r


@pytest.mark.parametrize("dims", [2, 3])
def test_orca_u_is_the_shortest_way_out_of_the_velocity_obstacle(dims):
    rng = np.random.default_rng(4)
    tau, dt = 2.0, 0.1
    for _ in range(6):
        pos = np.zeros((2, dims))
        pos[1] = rng.uniform(-8, 8, dims)
        radii = np.array([1.0, 1.2])
        if np.linalg.norm(pos[1]) < 3.0:
            continue
        vel = rng.uniform(-4, 4, (2, dims))
        normal, offset = orca_halfspaces(pos, vel, radii, tau, dt)
        v_rel = vel[0] - vel[1]
        # recover u from the constraint: offset = n . (v_0 + u / 2); u is parallel to n
        n = normal[0, 1]
        u_len = 2.0 * (offset[0, 1] - n @ vel[0])
        boundary = v_rel + u_len * n
        p = pos[1] - pos[0]
        # the boundary point is on the edge of the VO: just inside on one side, just outside on the other
        inside = _in_vo(np.array([boundary - 1e-3 * n, boundary + 1e-3 * n]), p, radii.sum(), tau)
        assert list(inside) == [True, False]
        # and no boundary point is nearer: sample velocities around v_rel, find the nearest one of the other kind
        own = _in_vo(v_rel[None], p, radii.sum(), tau)[0]
        dirs = rng.standard_normal((1500, dims))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        radius = abs(u_len) * 0.995
        probe = v_rel + radius * dirs
        assert np.all(_in_vo(probe, p, radii.sum(), tau) == own)
        # reciprocity: the pair's constraints mirror each other
        np.testing.assert_allclose(normal[1, 0], -normal[0, 1], atol=1e-12)


def test_a_lone_obstacle_keeps_its_cvm_path_exactly():
    p0, v0, r = np.array([[10.0, 20.0]]), np.array([[5.0, 3.0]]), np.array([1.0])
    size = np.array([50.0, 50.0])
    pos, vel = rvo_rollout(p0, v0, r, size, 0.1, 801)
    ref_p, ref_v = cvm_fold(p0, v0, r, size, np.arange(801) * 0.1)
    np.testing.assert_allclose(pos, ref_p, atol=1e-9)
    np.testing.assert_allclose(vel, ref_v, atol=1e-9)


def test_head_on_obstacles_pass_each_other():
    pos, _ = rvo_rollout(np.array([[10.0, 25.0], [40.0, 25.0]]), np.array([[4.0, 0.0], [-4.0, 0.0]]),
                         np.array([1.5, 1.5]), np.array([50.0, 50.0]), 0.1, 100)
    gap = np.linalg.norm(pos[:, 0] - pos[:, 1], axis=1)
    assert gap.min() >= 3.0 - 1e-9
    assert pos[-1, 0, 0] > 40.0 and pos[-1, 1, 0] < 10.0   # both got past
    assert abs(pos[-1, 0, 1] - pos[-1, 1, 1]) > 0.1          # by sidestepping


@pytest.mark.parametrize("dims", [2, 3])
def test_dense_fast_crowd_never_overlaps_and_stays_inside(dims):
    sc = parse_scenario({"world": {"dims": dims, "time_limit": 80.0},
                         "obstacles": {"count": 30, "radius": 1.5, "speed": 6.0, "motion": "rvo", "root_seed": 1}})
    ro = build_rollout(sc, enumerate_maps(sc)[0])
    pos, r = ro.positions, ro.radii
    reach = r[:, None] + r[None, :]
    dist = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=-1)
    overlap = (reach[None] - dist) / reach[None]
    overlap[:, np.arange(30), np.arange(30)] = -np.inf
    assert overlap.max() <= 0.05
    size = np.asarray(sc.world.size)
    assert np.all(pos >= r[None, :, None] - 1e-9) and np.all(pos <= size - r[None, :, None] + 1e-9)
    # they do move (nobody is frozen) and they deviate from CVM
    assert np.linalg.norm(ro.velocities, axis=-1).mean() > 3.0
    p0, v0, _ = spawn_obstacles(sc, enumerate_maps(sc)[0])
    cvm, _ = cvm_fold(p0, v0, r, size, ro.times)
    assert np.abs(cvm - pos).max() > 1.0


def test_rvo_scenario_fields_are_validated():
    from pbdyn.errors import ConfigError
    with pytest.raises(ConfigError, match="obstacles.rvo: is only used"):
        parse_scenario({"obstacles": {"rvo": {"time_horizon": 2.0}}})
    with pytest.raises(ConfigError, match="obstacles.rvo.time_horizon"):
        parse_scenario({"obstacles": {"motion": "rvo", "rvo": {"time_horizon": -1.0}}})
    sc = parse_scenario({"obstacles": {"motion": "rvo", "rvo": {"n_headings": 16, "n_speeds": 3}}})
    assert sc.obstacles.rvo == RVOParams(n_headings=16, n_speeds=3)
