"""Difficulty metrics (thesis ch. 3): hand-computed values, independent formulas, geometry, exclusions, horizon,
determinism, 3D/2D consistency and (slow) the meaning of survivability over the controlled setups."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pbdyn import limits
from pbdyn.config import load_scenario, parse_scenario
from pbdyn.errors import ConfigError, HorizonError
from pbdyn.metrics import survivability as surv_mod
from pbdyn.metrics.analytic import survival_times
from pbdyn.metrics.backends import BACKENDS, Backend
from pbdyn.metrics.density import density
from pbdyn.metrics.registry import METRICS, compute, parameters
from pbdyn.metrics.sampling import grid_samples
from pbdyn.metrics.survivability import global_survivability, survivability
from pbdyn.metrics.traversability import dynamic_traversability, neighbour_steps, traversability
from pbdyn.metrics.vo import velocity_set, vo_feasibility
from pbdyn.motion.cvm import cvm_fold
from pbdyn.world.geometry import StaticBody
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import Rollout, build_rollout
from tests.conftest import SCENARIOS

SQ2 = math.sqrt(2.0)


def make_rollout(p0, v0, radii, size=(50.0, 50.0), *, horizon=50.0, dt=0.1, static=(), meta=None) -> Rollout:
    """A CVM rollout of hand-placed obstacles."""
    size = np.asarray(size, float)
    d = size.shape[0]
    times = np.arange(int(round(horizon / dt)) + 1) * dt
    p0 = np.asarray(p0, float).reshape(-1, d)
    v0 = np.asarray(v0, float).reshape(-1, d)
    radii = np.asarray(radii, float).reshape(-1)
    pos, vel = cvm_fold(p0, v0, radii, size, times)
    return Rollout(times, pos, vel, radii, size, dt, tuple(static), meta or {})


def empty(size=(50.0, 50.0), **kw) -> Rollout:
    return make_rollout(np.zeros((0, len(size))), np.zeros((0, len(size))), np.zeros(0), size, **kw)


@pytest.fixture(scope="module")
def map30() -> Rollout:
    sc = load_scenario(SCENARIOS / "controlled_2d.toml")
    spec = next(m for m in enumerate_maps(sc) if m.setup == {"count": 30, "radius": 1.0, "speed": 4.0})
    return build_rollout(sc, spec)


# ------------------------------------------------------------------------------------------------ empty arena
@pytest.mark.parametrize("size", [(50.0, 50.0), (50.0, 50.0, 20.0)])
def test_empty_arena(size):
    ro = empty(size)
    for mode in ("sampled", "exact"):
        s = survivability(ro, mode=mode)
        assert s.value == 12.0 and np.all(s.per_sample == 12.0)
        assert s.extra["jitter"]["values"] == [12.0] * 8
    assert survivability(ro).n_samples == (64 if len(size) == 2 else 192)
    g = global_survivability(ro)
    assert g.value == 24.0 and g.per_sample.tolist() == [24.0] * 6 and g.n_samples == (16 if len(size) == 2 else 32)
    vo = vo_feasibility(ro)
    assert vo.value == 1.0 and vo.extra["n_velocities"] == (630 if len(size) == 2 else 1260)
    assert density(ro).value == 0.0
    tr = traversability(ro, starts=[[25.0, 25.0] + ([10.0] if len(size) == 3 else [])])
    if len(size) == 2:  # walls at r_mav = 1 and L - 1 = 49
        np.testing.assert_allclose(tr.per_sample[0], [24, 24 * SQ2, 24, 24 * SQ2] * 2)
    else:                # 8 horizontal, 9 up (ceiling at 19 m), 9 down (floor at 1 m)
        want = [24, 24 * SQ2, 24, 24 * SQ2] * 2 + [9.0] + [9 * SQ2, 9 * math.sqrt(3)] * 4 + [9.0] \
            + [9 * SQ2, 9 * math.sqrt(3)] * 4
        np.testing.assert_allclose(tr.per_sample[0], want)


# ------------------------------------------------------------------------------------------------ survivability
@pytest.mark.parametrize("dims", [2, 3])
def test_one_obstacle_heading_at_the_sample(dims):
    z = [10.0] if dims == 3 else []
    size = (50.0, 50.0, 20.0) if dims == 3 else (50.0, 50.0)
    ro = make_rollout([[35.05, 25.0] + z], [[-2.0, 0.0] + [0.0] * (dims - 2)], [1.0], size)
    off = [25.0, 25.0, 10.5] if dims == 3 else [25.0, 25.5]          # 0.5 m off the obstacle's line
    pts = np.array([[25.0, 25.0] + z, off, [25.0, 40.0] + z])
    # contact when the centre distance reaches r + r_mav = 2: straight 10.05 - 2t = 2; offset (10.05-2t)^2 + 0.25 = 4
    t_straight = (10.05 - 2.0) / 2.0
    t_offset = (10.05 - math.sqrt(3.75)) / 2.0
    exact = survival_times(ro, pts, mode="exact")
    sampled = survival_times(ro, pts, mode="sampled")
    np.testing.assert_allclose(exact, [t_straight, t_offset, 12.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(sampled, [4.1, 4.1, 12.0], rtol=0, atol=1e-9)
    assert np.all(exact[:2] < sampled[:2])
    # sampled = the first step with overlap: none at step 40 (4.0 s), overlap at step 41
    for p in pts[:2]:
        dist = np.linalg.norm(ro.positions[:, 0] - p, axis=1)
        assert dist[40] >= 2.0 and dist[41] < 2.0 and np.all(dist[:41] >= 2.0)
    res = survivability(ro, points=pts, mode="exact")
    assert res.value == pytest.approx(np.mean([t_straight, t_offset, 12.0]))
    assert res.stderr == pytest.approx(np.std(exact, ddof=1) / math.sqrt(3))
    # a later start sees the obstacle closer: from t = 2 s it arrives after 2.025 s
    assert survival_times(ro, pts[:1], start_time=2.0, mode="exact")[0] == pytest.approx(2.025)


def test_sampled_kernel_matches_brute_force_and_is_chunk_independent(map30, monkeypatch):
    pts = grid_samples(map30.arena_size, 3.0)
    got = survival_times(map30, pts)
    reach = map30.radii + 1.0
    want = np.full(len(pts), 12.0)
    for i, p in enumerate(pts):
        for k in range(121):
            if np.any(np.linalg.norm(map30.positions[k] - p, axis=1) < reach):
                want[i] = k * map30.dt
                break
    np.testing.assert_array_equal(got, want)
    exact = survival_times(map30, pts, mode="exact")
    assert np.all(exact <= got) and np.any(exact < got)
    monkeypatch.setattr(limits, "CHUNK_ELEMENTS", 500)
    np.testing.assert_array_equal(survival_times(map30, pts), got)
    np.testing.assert_array_equal(survival_times(map30, pts, mode="exact"), exact)


def test_jitter_is_seeded_from_the_map_and_stays_in_the_arena(map30):
    a = survivability(map30)
    jit = a.extra["jitter"]
    assert len(jit["values"]) == 8 and jit["mean"] == pytest.approx(np.mean(jit["values"]))
    assert jit["std"] == pytest.approx(np.std(jit["values"], ddof=1)) and jit["std"] > 0
    assert len(set(jit["values"])) > 1 and a.value not in jit["values"]
    offs = surv_mod.jitter_offsets(map30, 6.0, 8)
    assert np.all(np.abs(offs) <= 3.0)
    grids = surv_mod.jittered_grids(map30, grid_samples(map30.arena_size, 6.0), 6.0, 8, 1.0)
    assert all(np.all((g >= 1.0) & (g <= 49.0)) for g in grids)
    other = Rollout(map30.times, map30.positions, map30.velocities, map30.radii, map30.arena_size, map30.dt,
                    map30.static, {"map_key": "another map"})
    assert not np.array_equal(surv_mod.jitter_offsets(other, 6.0, 8), offs)
    assert json.loads(json.dumps(a.to_dict()))["extra"]["jitter"]["values"] == jit["values"]


def test_global_survivability_is_the_earliest_hit_over_points(map30):
    g = global_survivability(map30)
    pts = grid_samples(map30.arena_size, 12.0)
    assert g.n_samples == 16
    for j, start in enumerate(g.params["start_times"]):
        single = survival_times(map30, pts, t_max=24.0, start_time=start)
        assert np.all(g.per_sample[j] <= single)
        assert g.per_sample[j] == single.min()
    assert g.value == pytest.approx(g.per_sample.mean())
    # a sparse map: survival is long, and still the global value never exceeds a single point's
    ro = make_rollout([[10.0, 10.0], [40.0, 30.0]], [[1.0, 0.5], [-0.5, 1.0]], [0.5, 0.5])
    g2 = global_survivability(ro)
    for j, start in enumerate(g2.params["start_times"]):
        assert np.all(g2.per_sample[j] <= survival_times(ro, pts, t_max=24.0, start_time=start))
    assert 0 < g2.value <= 24.0


# ------------------------------------------------------------------------------------------------ density
def test_density_of_known_discs_balls_and_static_bodies():
    ro = make_rollout([[10, 10], [30, 30], [20, 40]], np.zeros((3, 2)), [1.0, 2.0, 0.5])
    assert density(ro).value == pytest.approx(math.pi * (1 + 4 + 0.25) / 2500.0, rel=1e-15)
    st = (StaticBody("pillar", (40.0, 10.0), radius=1.5), StaticBody("box", (5.0, 40.0), size=(4.0, 3.0), yaw=0.3))
    ro2 = make_rollout([[10, 10]], [[0, 0]], [1.0], static=st)
    assert density(ro2).value == pytest.approx((math.pi * (1 + 2.25) + 12.0) / 2500.0, rel=1e-15)
    assert density(ro2, include_static=False).value == pytest.approx(math.pi / 2500.0)
    ro3 = make_rollout([[10, 10, 5], [30, 30, 10]], np.zeros((2, 3)), [1.0, 2.0], (50.0, 50.0, 20.0),
                       static=(StaticBody("box", (25.0, 25.0, 10.0), size=(2.0, 3.0, 4.0)),))
    assert density(ro3).value == pytest.approx((4 / 3 * math.pi * (1 + 8) + 24.0) / 50000.0, rel=1e-15)


# ------------------------------------------------------------------------------------------------ VO
def _cone_fraction_2d(a, p_b, v_b, reach, vels):
    """Independent formula: v is in B's cone iff |angle(v - v_B) - angle(p)| < asin(R / |p|)."""
    p = np.asarray(p_b) - np.asarray(a)
    half = math.asin(reach / np.linalg.norm(p))
    rel = vels - np.asarray(v_b)
    diff = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - math.atan2(p[1], p[0]))))
    inside = (np.abs(diff) < half) & (np.linalg.norm(rel, axis=1) > 0)
    return 1.0 - inside.mean()


def test_vo_single_obstacle_matches_the_cone_angle_formula():
    a = [20.0, 20.0]
    p_b, v_b, r_b = [27.3, 23.1], [-1.7, 2.9], 1.3
    ro = make_rollout([p_b], [v_b], [r_b])
    _, vels = velocity_set(2)
    res = vo_feasibility(ro, points=[a])
    want = _cone_fraction_2d(a, p_b, v_b, r_b + 1.0, vels)
    assert res.per_sample[0] == want and 0.6 < want < 0.99
    # a static pillar behaves like an obstacle with zero velocity at the same place (a different code path)
    ro_static = empty(static=(StaticBody("pillar", tuple(p_b), radius=r_b),))
    ro_still = make_rollout([p_b], [[0.0, 0.0]], [r_b])
    still = _cone_fraction_2d(a, p_b, [0.0, 0.0], r_b + 1.0, vels)
    assert vo_feasibility(ro_static, points=[a]).per_sample[0] == still
    assert vo_feasibility(ro_still, points=[a]).per_sample[0] == still
    # inside the obstacle: 0
    assert vo_feasibility(ro, points=[[27.0, 22.0]]).per_sample[0] == 0.0
    assert vo_feasibility(ro, points=[[27.0, 22.0]]).extra["n_inside"] == 1


def test_vo_3d_single_ball_matches_the_cone_angle_formula():
    a = np.array([20.0, 20.0, 8.0])
    p_b, v_b, r_b = np.array([26.0, 23.0, 11.0]), np.array([-1.0, 2.0, 0.5]), 1.2
    ro = make_rollout([p_b], [v_b], [r_b], (50.0, 50.0, 20.0))
    dirs, vels = velocity_set(3)
    assert dirs.shape == (126, 3) and np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert abs(dirs.mean(axis=0)).max() < 0.02                       # nearly uniform on the sphere
    p = p_b - a
    rel = vels - v_b
    cosang = rel @ p / (np.linalg.norm(rel, axis=1) * np.linalg.norm(p))
    inside = np.arccos(np.clip(cosang, -1, 1)) < math.asin((r_b + 1.0) / np.linalg.norm(p))
    assert vo_feasibility(ro, points=[a]).per_sample[0] == pytest.approx(1.0 - inside.mean(), abs=1e-12)


# ------------------------------------------------------------------------------------------------ traversability
def corridor(dims=2):
    """Two 30 m x 6 m boxes (x 10..40) with a 4 m corridor y 23..27 between them (3D: spanning the height)."""
    if dims == 2:
        return (StaticBody("box", (25.0, 20.0), size=(30.0, 6.0)), StaticBody("box", (25.0, 30.0), size=(30.0, 6.0)))
    return (StaticBody("box", (25.0, 20.0, 10.0), size=(30.0, 6.0, 20.0)),
            StaticBody("box", (25.0, 30.0, 10.0), size=(30.0, 6.0, 20.0)))


def test_traversability_in_a_corridor_equals_its_geometry():
    ro = empty(static=corridor())
    # directions: 0, 45, ..., 315 deg. From the middle the inflated walls are 1 m away (y = 24 and 26).
    tr = traversability(ro, starts=[[25.0, 25.0], [42.0, 25.0], [45.0, 25.0]])
    np.testing.assert_allclose(tr.per_sample[0], [24, SQ2, 1, SQ2, 24, SQ2, 1, SQ2], atol=1e-12)
    # from (42, 25) the 135 deg ray hits the rounded corner (disc of 1 m at (40, 27)): 2 sqrt 2 - 1
    assert tr.per_sample[1, 3] == pytest.approx(2 * SQ2 - 1, abs=1e-12)
    # from (45, 25) it passes the corner and meets the box's grown end face x = 41 at y = 29: 4 sqrt 2
    assert tr.per_sample[2, 3] == pytest.approx(4 * SQ2, abs=1e-12)
    assert tr.value == pytest.approx(tr.per_sample.mean())
    # grid mode: 1 m cells, corridor cells y 23..26 free; walks from cell (25, 25)
    g = traversability(ro, starts=[[25.0, 25.0]], mode="grid")
    np.testing.assert_allclose(g.per_sample[0], [24, SQ2, 1, SQ2, 25, 2 * SQ2, 2, 2 * SQ2], atol=1e-12)


def test_traversability_rays_against_discs_and_rotated_boxes():
    ro = make_rollout([[30.0, 25.0], [30.0, 30.0]], np.zeros((2, 2)), [1.0, 1.5])
    tr = traversability(ro, starts=[[25.0, 25.0]])
    assert tr.per_sample[0, 0] == pytest.approx(3.0)                   # 5 - (1 + 1)
    assert tr.per_sample[0, 1] == pytest.approx(5 * SQ2 - 2.5)         # straight at the second disc
    # a box rotated 45 deg presents a corner: its grown corner disc (radius 1) at distance 5 - sqrt 2 * 1 along +x
    box = StaticBody("box", (30.0, 25.0), size=(2.0, 2.0), yaw=math.pi / 4)
    tr2 = traversability(empty(static=(box,)), starts=[[25.0, 25.0]])
    assert tr2.per_sample[0, 0] == pytest.approx(5 - SQ2 - 1, abs=1e-12)
    assert tr2.per_sample[0, 2] == pytest.approx(24.0)                 # the box is not in the way


def test_traversability_3d_rounded_cuboid_edges_corners_and_pillars():
    box = StaticBody("box", (30.0, 25.0, 10.0), size=(2.0, 2.0, 2.0))
    pillar = StaticBody("pillar", (10.0, 10.0, 0.0), radius=1.0)
    ro = empty((50.0, 50.0, 20.0), static=(box, pillar))
    idx = {tuple(int(c) for c in s): i for i, s in enumerate(neighbour_steps(3))}
    tr = traversability(ro, starts=[[27.0, 25.0, 13.0], [27.0, 22.0, 13.0], [10.0, 12.5, 10.0]])
    # (1, 0, -1): the grown faces are missed, the edge cylinder along y at (x 29, z 11) is met: 2 sqrt 2 - 1
    assert tr.per_sample[0, idx[(1, 0, -1)]] == pytest.approx(2 * SQ2 - 1, abs=1e-12)
    # (1, 1, -1): the corner ball at (29, 24, 11): 2 sqrt 3 - 1
    assert tr.per_sample[1, idx[(1, 1, -1)]] == pytest.approx(2 * math.sqrt(3) - 1, abs=1e-12)
    # pillars are infinite vertical cylinders: up is free to the ceiling, towards the pillar 2.5 - 2
    assert tr.per_sample[2, idx[(0, 0, 1)]] == pytest.approx(9.0)
    assert tr.per_sample[2, idx[(0, -1, 0)]] == pytest.approx(0.5)
    assert tr.per_sample[2, idx[(0, -1, -1)]] == pytest.approx(0.5 * SQ2)


def test_dynamic_traversability_averages_over_time():
    ro = make_rollout([[30.0, 25.0]], [[1.0, 0.0]], [1.0])            # recedes at 1 m/s along +x
    dt = dynamic_traversability(ro, starts=[[25.0, 25.0]])
    assert dt.per_sample.shape == (6, 1, 8)
    np.testing.assert_allclose(dt.per_sample[:, 0, 0], [3, 5, 7, 9, 11, 13], atol=1e-9)
    assert dt.value == pytest.approx(np.mean([traversability(ro, starts=[[25.0, 25.0]], time=t).value
                                              for t in (0, 2, 4, 6, 8, 10)]))


# ------------------------------------------------------------------------------------------------ exclusions, errors
def test_samples_inside_static_bodies_are_excluded_and_counted():
    # the pillar covers the grid point (14, 14); the box (22.5..24.5)^2 comes within 1 m of the candidate (25, 25) only
    st = (StaticBody("pillar", (14.0, 14.0), radius=2.0), StaticBody("box", (23.5, 23.5), size=(2.0, 2.0)))
    ro = make_rollout([[40.0, 40.0]], [[1.0, 1.0]], [1.0], static=st)
    s = survivability(ro)
    assert (s.n_samples, s.n_excluded) == (63, 1) and s.per_sample.shape == (63,)
    one = survivability(ro, points=[[14.0, 14.0], [8.0, 14.0]])
    assert (one.n_samples, one.n_excluded) == (1, 1) and one.params["points"] == [[8.0, 14.0]]
    assert (vo_feasibility(ro).n_samples, vo_feasibility(ro).n_excluded) == (63, 1)
    tr = traversability(ro)                                         # the centre candidate (25, 25) is in the box
    assert (tr.n_samples, tr.n_excluded) == (8, 1)
    g = global_survivability(ro)                                    # (14, 14) is a 12 m grid point too
    assert (g.n_samples, g.n_excluded) == (15, 1)
    # a point whose MAV disc only touches the inflated boundary is kept: distance 3 = 2 + r_mav
    assert survivability(ro, points=[[17.0, 14.0], [16.5, 14.0]]).n_excluded == 1


def test_times_past_the_horizon_raise():
    ro = empty(horizon=30.0)
    with pytest.raises(HorizonError, match="horizon"):
        survivability(ro, start_time=20.0)
    with pytest.raises(HorizonError):
        survival_times(ro, [[25.0, 25.0]], t_max=31.0)
    with pytest.raises(HorizonError):
        global_survivability(ro)                                      # needs 20 + 24 s
    with pytest.raises(HorizonError):
        traversability(ro, time=30.5)
    with pytest.raises(HorizonError):
        vo_feasibility(ro, time=-1.0)
    with pytest.raises(HorizonError):
        dynamic_traversability(ro, times=(0.0, 40.0))
    with pytest.raises(HorizonError):
        density(ro, time=31.0)
    assert survivability(ro, start_time=18.0).value == 12.0         # 18 + 12 = 30 s is covered


def test_registry_names_parameters_and_errors(map30):
    assert set(METRICS) == {"density", "traversability", "traversability_dense", "dynamic_traversability",
                            "vo_feasibility", "vo_feasibility_dense", "survivability", "survivability_dense",
                            "global_survivability", "flux", "static_share"}
    for name in METRICS:
        assert "mav_radius" in parameters(name)
        r = compute(map30, name, mav_radius=1.0)
        assert r.name == name and np.isfinite(r.value)
        json.dumps(r.to_dict())
    assert compute(map30, "survivability_dense").n_samples == 256
    assert compute(map30, "vo_feasibility_dense").n_samples == 256
    assert compute(map30, "traversability_dense").n_samples == 81
    with pytest.raises(ConfigError) as e:
        compute(map30, "survivabilty")
    assert e.value.field == "metric" and e.value.value == "survivabilty" and "survivabilty" in str(e.value)
    with pytest.raises(ConfigError) as e:
        compute(map30, "density", spacing=3.0)
    assert e.value.field == "metric" and "spacing" in str(e.value)
    with pytest.raises(ConfigError) as e:
        compute(map30, "survivability", backend="mesh2")
    assert e.value.field == "backend" and e.value.value == "mesh2"
    with pytest.raises(ConfigError) as e:
        compute(map30, "global_survivability", backend="bullet", mode="exact")
    assert e.value.field == "backend"
    with pytest.raises(ConfigError) as e:
        survivability(map30, mode="swept")
    assert e.value.field == "mode"
    with pytest.raises(ConfigError):
        traversability(map30, mode="cells")
    with pytest.raises(ConfigError):
        survivability(map30, spacing=0.0)


def test_the_bullet_backend_is_dispatched_through_the_registry(map30, monkeypatch):
    calls = []

    def fake(rollout, points, *, mav_radius, t_max, start_time=0.0):
        calls.append((len(points), mav_radius, t_max, start_time))
        return np.full(len(points), 1.5)

    def fake_table(rollout, points, starts, *, mav_radius, t_max):
        return np.stack([fake(rollout, points, mav_radius=mav_radius, t_max=t_max, start_time=s) for s in starts])

    def broken(*a, **k):
        raise AssertionError("the analytic kernel must not run with backend='bullet'")

    monkeypatch.setitem(BACKENDS, "bullet", Backend(fake, fake_table))
    monkeypatch.setitem(BACKENDS, "analytic", Backend(broken, modes=BACKENDS["analytic"].modes))
    r = compute(map30, "survivability", backend="bullet", mav_radius=0.8)
    assert r.value == 1.5 and r.params["backend"] == "bullet" and r.extra["jitter"]["values"] == [1.5] * 8
    assert len(calls) == 1 and calls[0][1:] == (0.8, 12.0, 0.0)      # base grid and 8 jittered grids in one call
    g = compute(map30, "global_survivability", backend="bullet")
    assert g.value == 1.5 and [c[3] for c in calls[1:]] == [0.0, 4.0, 8.0, 12.0, 16.0, 20.0]


def test_determinism(map30):
    sc = load_scenario(SCENARIOS / "controlled_2d.toml")
    spec = next(m for m in enumerate_maps(sc) if m.setup == {"count": 30, "radius": 1.0, "speed": 4.0})
    again = build_rollout(sc, spec)
    for name in METRICS:
        a, b = compute(map30, name), compute(again, name)
        assert a.value == b.value and np.array_equal(a.per_sample, b.per_sample), name
        assert a.params == b.params and a.extra == b.extra, name


# ------------------------------------------------------------------------------------------------ 3D / 2D
def test_3d_extrusion_of_a_2d_map_gives_the_2d_values():
    """A 3D world whose balls move horizontally in the plane z = 10 and whose static bodies span the height.

    Compared: survivability of samples in the plane z = 10 (in-plane ball distance = disc distance), horizontal
    traversability from starts at z = 10 (the plane cuts the balls and the rounded cuboids in the 2D shapes), and
    density of the static geometry alone (extruded footprints: area ratio = volume ratio). Not compared: the density
    of the dynamic obstacles (balls are not extrusions of discs; their volume share is 4 r / (3 L_z) times the
    disc's area share, checked below) and VO (the 3D velocity set is spherical, not the 2D fan).
    """
    sc = parse_scenario({"obstacles": {"count": 20, "radius": 1.0, "speed": 4.0, "radius_jitter": 0.2},
                         "static_obstacles": [{"kind": "pillar", "center": [14.0, 30.0], "radius": 2.0},
                                              {"kind": "box", "center": [36.0, 18.0], "size": [5.0, 3.0],
                                               "yaw_deg": 30.0}]})
    ro2 = build_rollout(sc, enumerate_maps(sc)[0], horizon=15.0)
    p0 = np.column_stack([ro2.positions[0], np.full(ro2.n_obstacles, 10.0)])
    v0 = np.column_stack([ro2.velocities[0], np.zeros(ro2.n_obstacles)])
    static3 = (StaticBody("pillar", (14.0, 30.0, 10.0), radius=2.0),
               StaticBody("box", (36.0, 18.0, 10.0), size=(5.0, 3.0, 20.0), yaw=math.radians(30.0)))
    ro3 = make_rollout(p0, v0, ro2.radii, (50.0, 50.0, 20.0), horizon=15.0, static=static3)
    np.testing.assert_allclose(ro3.positions[:, :, :2], ro2.positions, atol=1e-9)

    pts2 = grid_samples(ro2.arena_size, 3.0)
    pts3 = np.column_stack([pts2, np.full(len(pts2), 10.0)])
    for mode in ("sampled", "exact"):
        s2 = survivability(ro2, points=pts2, mode=mode)
        s3 = survivability(ro3, points=pts3, mode=mode)
        assert s2.n_excluded == s3.n_excluded > 0
        np.testing.assert_allclose(s3.per_sample, s2.per_sample, atol=1e-9)
        assert s2.value < 12.0
    starts2 = grid_samples(ro2.arena_size, 5.0, margin=5.0)
    starts3 = np.column_stack([starts2, np.full(len(starts2), 10.0)])
    for t in (0.0, 6.0):
        t2 = traversability(ro2, starts=starts2, time=t)
        t3 = traversability(ro3, starts=starts3, time=t, horizontal=True)
        np.testing.assert_allclose(t3.per_sample, t2.per_sample, atol=1e-9)
        assert t2.value < 20.0
    d2 = density(ro2).value - np.sum(np.pi * ro2.radii ** 2) / 2500.0     # the static share
    d3 = density(ro3).value - np.sum(4 / 3 * np.pi * ro3.radii ** 3) / 50000.0
    assert d3 == pytest.approx(d2, rel=1e-12) and d2 > 0
    ratio = density(ro3, include_static=False).value / density(ro2, include_static=False).value
    assert ratio == pytest.approx(np.sum(ro2.radii ** 3) * 4 / 3 / 20.0 / np.sum(ro2.radii ** 2), rel=1e-12)


# ------------------------------------------------------------------------------------------------ meaning (slow)
@pytest.mark.slow
def test_survivability_decreases_with_count_radius_and_speed():
    sc = load_scenario(SCENARIOS / "controlled_2d.toml")
    rows = []
    for spec in enumerate_maps(sc):
        if spec.replicate >= 3:
            continue
        ro = build_rollout(sc, spec, horizon=12.1)
        rows.append((spec.setup["count"], spec.setup["radius"], spec.setup["speed"], survivability(ro).value))
    data = np.array(rows)
    assert data.shape == (81, 4)
    for col in range(3):
        levels = np.unique(data[:, col])
        means = [data[data[:, col] == lv, 3].mean() for lv in levels]
        assert np.all(np.diff(means) < 0), (col, means)
    x = np.column_stack([data[:, :3], np.ones(len(data))])
    coef, *_ = np.linalg.lstsq(x, data[:, 3], rcond=None)
    resid = data[:, 3] - x @ coef
    r2 = 1.0 - resid @ resid / np.sum((data[:, 3] - data[:, 3].mean()) ** 2)
    assert np.all(coef[:3] < 0) and r2 >= 0.9, (coef, r2)


@pytest.mark.parametrize("dims", [2, 3])
def test_compiled_sampled_survival_equals_the_numpy_reference(dims):
    """survival_times' "sampled" mode (compiled, first hit per point) gives the numpy floats of its reference twin
    _survival_reference exactly, for points that are hit at once, later, or never, from several start times."""
    from pbdyn.metrics.analytic import _survival_reference
    from tests.helpers import handmade_rollout, open_scenario

    rng = np.random.default_rng(11 + dims)
    sc = open_scenario(dims, obstacles={"count": 12})
    size = np.asarray(sc.world.size, dtype=float)
    ro = handmade_rollout(sc, rng.uniform(0.0, size, (12, dims)), rng.normal(size=(12, dims)) * 2.0,
                          rng.uniform(0.3, 1.5, 12))
    pts = rng.uniform(0.0, size, (300, dims))
    pts[:5] = ro.positions[0, :5]                           # inside obstacles at t = 0
    seen = set()
    for start, t_max in ((0.0, 12.0), (1.3, 6.0), (0.0, 0.05)):
        got = survival_times(ro, pts, start_time=start, t_max=t_max, mav_radius=0.4)
        k0 = ro.step_index(start)
        n = int(round(t_max / ro.dt))
        want = _survival_reference(pts, ro.positions[k0:k0 + n + 1], (ro.radii + 0.4) ** 2, ro.dt, t_max,
                                   "sampled", np.full(pts.shape[0], t_max))
        assert np.array_equal(got, want)
        seen.update({"now" if t == 0 else "never" if t == t_max else "later" for t in got.tolist()})
    assert seen == {"now", "later", "never"}
