"""MPC trajectory planner (thesis A-3): closed-loop trials in PyBullet worlds, the two solver paths, limits,
dynamics, constraints and determinism."""

import math

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.perception.grid import FREE, OccupancyGrid
from pbdyn.planning import registry
from pbdyn.planning.checks import trajectory_clear, within_limits
from pbdyn.planning.mpc.planner import MPC
from pbdyn.planning.mpc.problem import INACTIVE_RHS
from pbdyn.planning.protocols import PlannerContext, TrajectoryPlanner
from pbdyn.planning.view import MAVLimits, Tracks, View
from pbdyn.sim.demo import demo_pairs
from pbdyn.world.rollout import build_rollout
from tests.helpers import assert_avoids, failed_pairs, first_map, fly, handmade_rollout, open_scenario

DT = 0.1
MPC_PLANNERS = [{"trajectory": "mpc", "gaze": "lookahead"}, {"trajectory": "straight_line", "gaze": "lookahead"},
                {"trajectory": "mpc", "gaze": "fullrange"}]


def _scenario(dims=2, **extra):
    return open_scenario(dims, planners=MPC_PLANNERS, **extra)


def _context(dims=2, v_max=4.0):
    hi = np.array([50.0, 50.0, 20.0][:dims])
    return PlannerContext(dims, DT, MAVLimits(1.0, v_max, 4.0, 1.4), np.zeros(dims), hi)


def _view(ctx, p, goal, v=None, tracks=None, grid=None, t=0.0, trajectory=None):
    d = ctx.dims
    if grid is None:
        grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
        grid.cells[(slice(1, -1),) * d] = FREE
    return View(t=t, dt=DT, position=np.asarray(p, float), velocity=np.zeros(d) if v is None else np.asarray(v, float),
                acceleration=np.zeros(d), yaw=0.0, goal=np.asarray(goal, float), goal_radius=1.0, limits=ctx.limits,
                bounds_lo=ctx.bounds_lo, bounds_hi=ctx.bounds_hi, grid=grid,
                tracks=Tracks.empty(d) if tracks is None else tracks, trajectory=trajectory)


def _tracks(pos, vel, radius):
    pos = np.atleast_2d(np.asarray(pos, float))
    m, d = pos.shape
    return Tracks(np.arange(m), pos, np.atleast_2d(np.asarray(vel, float)), np.zeros((m, 2 * d, 2 * d)),
                  np.broadcast_to(np.asarray(radius, float), (m,)).copy())


def _cluttered_view(ctx, planner_t=0.0):
    """A moving MAV with five tracks around it and an occupied block ahead (several rows active)."""
    grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    grid.cells[1:-1, 1:-1] = FREE
    grid.mark_occupied(np.array([[x + 0.5, y + 0.5] for x in (22, 23) for y in range(14, 18)]))
    tracks = _tracks([[18.0, 21.0], [21.0, 12.0], [30.0, 17.0], [12.0, 16.0], [40.0, 40.0]],
                     [[0.0, -2.0], [0.0, 2.5], [-3.0, 0.0], [1.0, 1.0], [0.0, 0.0]], [1.0, 0.8, 1.2, 1.0, 1.0])
    return _view(ctx, [15.0, 15.0], [45.0, 18.0], v=[3.0, 0.5], tracks=tracks, grid=grid, t=planner_t)


# ---------------------------------------------------------------- closed loop in the trial

def test_mpc_sample_of_pairs_succeeds_in_an_empty_arena_2d():
    sc = _scenario()
    rollout = build_rollout(sc, first_map(sc))
    cands = sc.task.candidates
    for i, j in demo_pairs(sc, 12):
        res = fly(sc, rollout, "lookahead+mpc", cands[i], cands[j])
        assert res.outcome == "success" and res.planning_failures == 0, (cands[i], cands[j], res)


@pytest.mark.slow
def test_mpc_all_72_pairs_succeed_in_an_empty_arena_2d():
    sc = _scenario()
    assert len(sc.task.pairs()) == 72
    assert failed_pairs(sc, build_rollout(sc, first_map(sc)), "lookahead+mpc") == []


def test_mpc_sample_of_pairs_succeeds_in_an_empty_arena_3d():
    sc = _scenario(3)
    rollout = build_rollout(sc, first_map(sc))
    cands = sc.task.candidates
    for i, j in demo_pairs(sc, 4):
        res = fly(sc, rollout, "lookahead+mpc", cands[i], cands[j])
        assert res.outcome == "success" and res.planning_failures == 0, (cands[i], cands[j], res)


@pytest.mark.parametrize("dims,p0,v0,radius,planner", [
    (2, [40.0, 25.0], [-3.0, 0.0], 1.0, "lookahead+mpc"),             # head-on along the goal line
    (2, [25.0, 13.5], [0.0, 2.0], 1.5, "lookahead+mpc"),              # crossing from the side, unseen at t = 0
    (2, [25.0, 13.5], [0.0, 2.0], 1.5, "fullrange+mpc"),
    (3, [40.0, 25.0, 10.0], [-3.0, 0.0, 0.0], 1.0, "lookahead+mpc"),  # head-on sphere in 3D
])
def test_mpc_avoids_head_on_and_crossing_obstacles_that_straight_line_hits(dims, p0, v0, radius, planner):
    sc = _scenario(dims)
    z = [10.0] if dims == 3 else []
    start, goal = tuple([4.0, 25.0] + z), tuple([46.0, 25.0] + z)
    assert_avoids(sc, handmade_rollout(sc, [p0], [v0], [radius]), planner, start, goal)


@pytest.mark.parametrize("kind", ["hovering_track", "static_pillar"])
def test_mpc_bends_around_an_obstacle_on_the_goal_line(kind, tmp_path):
    start, goal = (4.0, 25.0), (46.0, 25.0)
    if kind == "hovering_track":          # a dynamic obstacle at rest: half-planes from the track
        sc = _scenario()
        radius = 1.5
        rollout = handmade_rollout(sc, [[25.0, 25.0]], [[0.0, 0.0]], [radius])
    else:                                 # static geometry: half-planes from the occupied cells
        radius = 2.0
        sc = _scenario(static_obstacles=[{"kind": "pillar", "center": [25.0, 25.0], "radius": radius}],
                       task={"candidates": [list(start), list(goal)]})   # no candidate on the pillar
        rollout = build_rollout(sc, first_map(sc))
    assert fly(sc, rollout, "lookahead+straight_line", start, goal).outcome != "success"
    trace = tmp_path / "trace.npz"
    res = fly(sc, rollout, "lookahead+mpc", start, goal, trace_path=trace)
    assert res.outcome == "success" and res.min_clearance_m >= 0.0, res
    with np.load(trace) as tr:
        p = tr["p"]
    assert np.abs(p[:, 1] - 25.0).max() >= radius + 1.0       # it went around, not through
    passing = np.abs(p[:, 0] - 25.0) < 0.5
    assert passing.any() and np.all(np.abs(p[passing, 1] - 25.0) >= radius + 1.0)


def test_mpc_trials_are_deterministic(tmp_path):
    sc = parse_scenario({"world": {"time_limit": 20.0},
                         "obstacles": {"count": 20, "radius": 1.0, "speed": 3.0, "root_seed": 4},
                         "drone": {"v_max": 4.0}, "planners": MPC_PLANNERS})
    rollout = build_rollout(sc, first_map(sc))
    runs = []
    for name in ("a.npz", "b.npz"):
        res = fly(sc, rollout, "fullrange+mpc", (4.0, 4.0), (46.0, 46.0), trace_path=tmp_path / name)
        with np.load(tmp_path / name) as z:
            runs.append((res.outcome, res.steps, res.min_clearance_m, z["p"].copy(), z["v"].copy()))
    (o1, s1, c1, p1, v1), (o2, s2, c2, p2, v2) = runs
    assert (o1, s1, c1) == (o2, s2, c2) and s1 > 20
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(v1, v2)
    # a fresh planner on the same view gives bit-identical plans
    ctx = _context()
    view = _cluttered_view(ctx)
    a, b = MPC(ctx).plan(view), MPC(ctx).plan(view)
    np.testing.assert_array_equal(a.p, b.p)
    np.testing.assert_array_equal(a.a, b.a)


# ---------------------------------------------------------------- single plans

def test_mpc_plans_and_executed_states_respect_norm_limits_and_dynamics():
    """A closed loop at v_max 6 among fast crossing tracks, executing sample 1 of every plan exactly."""
    ctx = _context(v_max=6.0)
    planner = MPC(ctx)
    assert isinstance(planner, TrajectoryPlanner)
    obs_p = np.array([[20.0, 5.0], [30.0, 45.0], [38.0, 20.0]])
    obs_v = np.array([[0.0, 4.0], [0.0, -4.0], [-4.0, 0.5]])
    p, v, traj = np.array([4.0, 25.0]), np.zeros(2), None
    goal = np.array([46.0, 25.0])
    speeds, accs, n_plans = [], [], 0
    for k in range(200):
        t = k * DT
        view = _view(ctx, p, goal, v=v, tracks=_tracks(obs_p + t * obs_v, obs_v, 1.0), t=t, trajectory=traj)
        traj = planner.plan(view)
        assert traj is not None, planner.last_fail_reason
        n_plans += 1
        assert traj.t0 == t and traj.dt == DT and traj.n_samples == 26
        np.testing.assert_array_equal(traj.p[0], p)
        np.testing.assert_array_equal(traj.v[0], v)
        assert within_limits(traj.v, traj.a, 6.0, 4.0, tol=1e-9)
        h = 0.5 * DT * DT
        np.testing.assert_allclose(traj.p[1:], traj.p[:-1] + DT * traj.v[:-1] + h * traj.a[:-1], atol=1e-9, rtol=0)
        np.testing.assert_allclose(traj.v[1:], traj.v[:-1] + DT * traj.a[:-1], atol=1e-9, rtol=0)
        p, v = traj.p[1].copy(), traj.v[1].copy()
        speeds.append(np.linalg.norm(v))
        accs.append(np.linalg.norm(traj.a[0]))
        if np.linalg.norm(p - goal) <= 1.0:
            break
    assert np.linalg.norm(p - goal) <= 1.0
    assert max(speeds) <= 6.0 + 1e-9 and max(accs) <= 4.0 + 1e-9
    assert max(speeds) > 5.9 and max(accs) > 3.9            # the limits were really reached


def test_mpc_solution_satisfies_the_dynamics_and_the_constraints_it_was_given():
    ctx = _context()
    planner = MPC(ctx)
    view = _cluttered_view(ctx)
    traj = planner.plan(view)
    assert traj is not None
    data, sol = planner.last_data, planner.last_solution
    assert sol.optimal
    n, d, r = planner.horizon, 2, planner.n_tracks + planner.n_cells
    assert data.normals.shape == (r, n, d) and data.rhs.shape == (r, n)
    h = 0.5 * DT * DT
    p_prev = np.vstack([data.p0, sol.p[:-1]])
    v_prev = np.vstack([data.v0, sol.v[:-1]])
    np.testing.assert_allclose(sol.p, p_prev + DT * v_prev + h * sol.u, atol=1e-6)
    np.testing.assert_allclose(sol.v, v_prev + DT * sol.u, atol=1e-6)
    tol = 1e-6
    assert np.all(sol.s >= -tol) and np.all(sol.b >= -tol) and np.all(sol.b <= data.band + tol)
    assert data.band == pytest.approx(planner.margin - planner.hard_margin)
    lhs = np.einsum("rnd,nd->rn", data.normals, sol.p) + sol.s[None, :] + sol.b[None, :]
    assert np.all(lhs >= data.rhs - tol)
    active = np.abs(lhs - data.rhs) < 1e-4
    assert active[:planner.n_tracks].any() and active[planner.n_tracks:].any()  # both kinds of row bind
    assert np.all(sol.p >= data.wall_lo - sol.s[:, None] - tol) and np.all(sol.p <= data.wall_hi + sol.s[:, None] + tol)
    assert np.all(np.linalg.norm(sol.v, axis=1) <= data.v_lim + tol)
    assert np.all(np.linalg.norm(sol.u, axis=1) <= data.a_lim + tol)
    # the returned trajectory is that solution, and it keeps the hard margin (less the accepted slack) in 1 s
    np.testing.assert_allclose(traj.p[1:], sol.p, atol=1e-6)
    assert planner.last_max_slack <= planner.max_slack
    k1 = planner.slack_steps + 1
    assert trajectory_clear(view, traj.p[1:k1], traj.times[1:k1], margin=planner.hard_margin - planner.max_slack)
    # the rows really are tangent half-planes of the inflated predicted discs
    tracks = view.tracks
    pred = tracks.predict(DT * np.arange(1, n + 1))
    ids = planner.last_track_index
    assert sorted(ids.tolist()) == [0, 1, 2, 3, 4]
    for j, i in enumerate(ids):
        nrm = data.normals[j]
        np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0)
        np.testing.assert_allclose(np.einsum("nd,nd->n", nrm, pred[:, i]) + tracks.radius[i] + 1.5, data.rhs[j])


def test_mpc_keeps_the_structure_with_padding_rows_and_picks_the_nearest_tracks():
    ctx = _context()
    planner = MPC(ctx, n_tracks=3)
    far = _tracks([[45.0, 45.0], [10.0, 20.0], [40.0, 5.0], [16.0, 10.0], [30.0, 30.0]], np.zeros((5, 2)), 1.0)
    views = [_view(ctx, [10.0, 10.0], [40.0, 10.0]),
             _view(ctx, [10.0, 10.0], [40.0, 10.0], tracks=_tracks([[20.0, 10.0]], [[0.0, 0.0]], 1.0)),
             _view(ctx, [10.0, 10.0], [40.0, 10.0], tracks=far)]
    nnz = None
    for view in views:
        assert planner.plan(view) is not None
        data = planner.last_data
        assert data.normals.shape == (3 + planner.n_cells, 25, 2)
        A = planner._solver._A
        nnz = A.nnz if nnz is None else nnz
        assert A.nnz == nnz                                          # the sparsity pattern never changes
    pad = ~np.any(planner.last_data.normals != 0.0, axis=-1)
    assert pad[3:].all() and not pad[:3].any()                       # no occupied cells: all cell rows padding
    assert np.all(planner.last_data.rhs[3:] == INACTIVE_RHS)
    # the three nearest tracks to the (constant-velocity, at rest) reference: (16, 10), (10, 20), (30, 30)
    rhs0 = planner.last_data.rhs[:3, 0]
    nrm0 = planner.last_data.normals[:3, 0]
    centres = far.position[[3, 1, 4]]
    np.testing.assert_allclose(np.einsum("rd,rd->r", nrm0, centres) + 2.5, rhs0)


def test_mpc_degenerate_normal_uses_the_current_direction_and_symmetry_is_broken():
    ctx = _context()
    planner = MPC(ctx, bias_deg=0.0)
    # at rest at (10, 25); a track 4 m ahead coming at 4 m/s reaches the MAV's position at k = 10
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0], tracks=_tracks([[14.0, 25.0]], [[-4.0, 0.0]], 1.0))
    data = planner.problem_data(view)
    np.testing.assert_allclose(data.normals[0, 9], [-1.0, 0.0])     # obstacle -> MAV now, not undefined
    # a hovering obstacle dead ahead: without the bias the normal opposes the goal direction exactly ...
    ahead = _view(ctx, [10.0, 25.0], [40.0, 25.0], tracks=_tracks([[16.0, 25.0]], [[0.0, 0.0]], 1.0))
    np.testing.assert_allclose(planner.problem_data(ahead).normals[0], np.tile([-1.0, 0.0], (25, 1)))
    # ... with it, every step's normal is turned by bias_deg to the left (+y) and the plan leaves the line
    biased = MPC(ctx)
    nrm = biased.problem_data(ahead).normals[0]
    ang = math.radians(biased.bias_deg)
    np.testing.assert_allclose(nrm, np.tile([-math.cos(ang), math.sin(ang)], (25, 1)), atol=1e-12)
    tr = biased.plan(ahead)
    assert tr is not None and tr.p[-1, 1] > 25.5
    # the next step linearises about that plan, read at the same absolute times (constant velocity past its end)
    nxt = _view(ctx, tr.p[1], [40.0, 25.0], v=tr.v[1], tracks=ahead.tracks, t=DT, trajectory=tr)
    ref = biased.reference_path(nxt)
    np.testing.assert_array_equal(ref[:-1], tr.p[2:])
    np.testing.assert_allclose(ref[-1], tr.p[-1] + DT * tr.v[-1])
    np.testing.assert_allclose(biased.reference_path(ahead), np.tile([10.0, 25.0], (25, 1)))  # first: CV guess


def test_mpc_3d_floor_and_ceiling_are_walls():
    ctx = _context(dims=3)
    planner = MPC(ctx)
    p, v, traj = np.array([10.0, 25.0, 10.0]), np.zeros(3), None
    top = 20.0 - 1.0 - planner.wall_margin
    zs = []
    for k in range(60):                       # the goal lies above the ceiling's reach
        traj = planner.plan(_view(ctx, p, [30.0, 25.0, 19.6], v=v, t=k * DT, trajectory=traj))
        assert traj is not None
        assert traj.p[1:, 2].max() <= top + 1e-6
        p, v = traj.p[1], traj.v[1]
        zs.append(p[2])
    assert max(zs) > top - 0.05 and p[0] > 25.0


def test_mpc_fails_when_a_collision_is_unavoidable_within_one_second():
    ctx = _context()
    planner = MPC(ctx, n_tracks=8)
    ang = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    ring = np.c_[20.0 + 5.0 * np.cos(ang), 20.0 + 5.0 * np.sin(ang)]
    closing = _tracks(ring, -4.0 * np.c_[np.cos(ang), np.sin(ang)], 1.0)   # a ring closing in at 4 m/s
    assert planner.plan(_view(ctx, [20.0, 20.0], [40.0, 20.0], tracks=closing)) is None
    assert "slack" in planner.last_fail_reason and planner.last_max_slack > planner.max_slack
    # the same ring standing still is no threat within the horizon's reach: a plan exists
    still = _tracks(ring, np.zeros((8, 2)), 1.0)
    assert planner.plan(_view(ctx, [20.0, 20.0], [40.0, 20.0], tracks=still)) is not None


def test_mpc_direct_clarabel_path_matches_the_cvxpy_path():
    ctx = _context()
    direct, reference = MPC(ctx), MPC(ctx, backend="cvxpy")
    views = [_cluttered_view(ctx),
             _view(ctx, [30.0, 30.0], [5.0, 40.0], v=[-1.0, 2.0],
                   tracks=_tracks([[27.0, 33.0], [20.0, 30.0]], [[1.0, 0.0], [0.0, -1.0]], 1.0))]
    ctx3 = _context(dims=3)
    views3 = [_view(ctx3, [10.0, 10.0, 10.0], [40.0, 20.0, 12.0], v=[2.0, 0.0, 0.5],
                    tracks=_tracks([[16.0, 11.0, 10.0]], [[-1.0, 0.0, 0.0]], 1.0))]
    for (a_pl, b_pl), vs in (((direct, reference), views), ((MPC(ctx3), MPC(ctx3, backend="cvxpy")), views3)):
        for view in vs:
            data = a_pl.problem_data(view)
            sa, sb = a_pl.solve(data), b_pl.solve(data)
            assert sa.optimal and sb.optimal, (sa.status, sb.status)
            np.testing.assert_allclose(sa.p, sb.p, atol=1e-3)
            np.testing.assert_allclose(sa.v, sb.v, atol=5e-3)
            np.testing.assert_allclose(sa.u, sb.u, atol=2e-2)
            np.testing.assert_allclose(sa.s, sb.s, atol=1e-4)
            ta, tb = a_pl.plan(view), b_pl.plan(view)
            np.testing.assert_allclose(ta.p, tb.p, atol=1e-3)


def test_mpc_registry_and_parameter_errors():
    ctx = _context()
    assert registry.resolve_trajectory_planner("mpc") is MPC
    pl = registry.build_planner(MPC, ctx, {"horizon": 20, "n_tracks": 4}, "planners[0].trajectory_params")
    assert pl.horizon == 20 and pl.shape.rows == 4 + pl.n_cells
    assert pl.plan(_view(ctx, [10, 10], [40, 10])).n_samples == 21
    for bad in ({"horizon": 1}, {"n_tracks": -1}, {"w_acc": 0.0}, {"backend": "osqp"}, {"bias_deg": 95.0}):
        with pytest.raises(ConfigError, match=r"^planners\[0\]\.trajectory_params: invalid parameters for MPC"):
            registry.build_planner(MPC, ctx, bad, "planners[0].trajectory_params")
