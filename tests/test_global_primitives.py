"""Global motion primitives (thesis A-1): lattice, admissible heuristic, A* search, replanning, and closed-loop
trials in real PyBullet worlds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.perception.grid import FREE, OCCUPIED, OccupancyGrid
from pbdyn.planning import registry
from pbdyn.planning.primitives.astar_heuristic import lqmt_lower_bound
from pbdyn.planning.primitives.astar_static import StaticScreen
from pbdyn.planning.checks import static_clear, trajectory_clear, within_limits
from pbdyn.planning.primitives.global_astar import GlobalPrimitives, acceleration_grid
from pbdyn.planning.protocols import PlannerContext, TrajectoryPlanner
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, Tracks, View
from pbdyn.sim.demo import demo_pairs
from pbdyn.world.rollout import build_rollout
from tests.helpers import assert_avoids, failed_pairs, first_map, fly, handmade_rollout, make_tracks, open_scenario

DT = 0.1
GP_PLANNERS = [{"trajectory": "global_primitives", "gaze": "lookahead"},
               {"trajectory": "global_primitives", "gaze": "fullrange"},
               {"trajectory": "straight_line", "gaze": "lookahead"},
               {"trajectory": "straight_line", "gaze": "fullrange"}]


def _context(dims=2, v_max=4.0, a_max=4.0):
    hi = np.array([50.0, 50.0, 20.0][:dims])
    return PlannerContext(dims, DT, MAVLimits(1.0, v_max, a_max, 1.4), np.zeros(dims), hi)


def _grid(ctx):
    g = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    g.cells[(slice(1, -1),) * ctx.dims] = FREE
    return g


def _view(ctx, p, goal, v=None, grid=None, tracks=None, t=0.0, trajectory=None):
    d = ctx.dims
    return View(t=t, dt=ctx.dt, position=np.asarray(p, float), velocity=np.zeros(d) if v is None else v,
                acceleration=np.zeros(d), yaw=0.0, goal=np.asarray(goal, float), goal_radius=1.0,
                limits=ctx.limits, bounds_lo=ctx.bounds_lo, bounds_hi=ctx.bounds_hi,
                grid=_grid(ctx) if grid is None else grid, tracks=Tracks.empty(d) if tracks is None else tracks,
                trajectory=trajectory)


_tracks = make_tracks


def _scenario(dims=2, **extra):
    return open_scenario(dims, **{"planners": GP_PLANNERS, **extra})


# ---------------------------------------------------------------- lattice

def test_registry_parameters_and_defaults():
    assert registry.resolve_trajectory_planner("global_primitives") is GlobalPrimitives
    ctx = _context()
    gp = registry.build_planner(GlobalPrimitives, ctx, {"rho": 5.0, "max_expansions": 500}, "planners[0].params")
    assert isinstance(gp, TrajectoryPlanner) and gp.rho == 5.0 and gp.max_expansions == 500
    d = GlobalPrimitives(ctx)
    assert (d.T, d.n_accel, d.rho, d.horizon_s, d.max_expansions, d.margin) == (1.0, 7, 10.0, 5.0, 20000, 0.5)
    assert d.n_horizon == 5 and d.steps_per_primitive == 10
    for bad in ({"n_accel": 6}, {"n_accel": 1}, {"duration_s": 0.0}, {"rho": -1.0}, {"epsilon": 0.5},
                {"max_expansions": 0}, {"margin": -0.1}):
        with pytest.raises(ConfigError, match=r"^planners\[0\]\.params: invalid parameters for GlobalPrimitives"):
            registry.build_planner(GlobalPrimitives, ctx, bad, "planners[0].params")
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params\.horizon_s: must be finite"):   # the registry's
        registry.build_planner(GlobalPrimitives, ctx, {"horizon_s": float("nan")}, "planners[0].params")
    with pytest.raises(ValueError, match=r"^horizon_s must be a finite number > 0"):         # the planner's own
        GlobalPrimitives(ctx, horizon_s=float("nan"))


@pytest.mark.parametrize("dims,n_accel,count", [(2, 7, 29), (2, 5, 13), (3, 7, 123), (3, 5, 33)])
def test_acceleration_grid_has_zero_and_respects_the_norm(dims, n_accel, count):
    gp = GlobalPrimitives(_context(dims), n_accel=n_accel)
    a = gp.accelerations
    assert a.shape == (count, dims) == acceleration_grid(n_accel, dims).shape
    assert np.any(np.all(a == 0.0, axis=1))
    assert np.linalg.norm(a, axis=1).max() <= 4.0 + 1e-12
    m = (n_accel - 1) // 2
    np.testing.assert_array_equal(np.unique(a), 4.0 * np.arange(-m, m + 1) / m)  # per-axis grid over [-a_max, a_max]
    assert len({tuple(r) for r in a}) == count


def test_root_children_are_the_grid_at_rest_and_end_on_lattice_velocities():
    gp = GlobalPrimitives(_context(v_max=4.0))
    J1, acc = gp.root_children(np.zeros(2))
    assert sorted(map(tuple, acc)) == sorted(map(tuple, gp.accelerations))
    rng = np.random.default_rng(5)
    for _ in range(20):
        v0 = rng.uniform(-2.8, 2.8, size=2)
        J1, acc = gp.root_children(v0)
        v1 = v0 + gp.T * acc
        np.testing.assert_allclose(v1, gp.w * J1, atol=1e-12)          # they end on the velocity lattice
        assert np.all(np.linalg.norm(acc, axis=1) <= 4.0 + 1e-12)
        assert np.all(np.linalg.norm(v1, axis=1) <= 4.0 + 1e-9)
        assert acc.shape[0] >= 10
    # without the speed limit, a shifted grid keeps about as many accelerations as the grid itself (29)
    fast = GlobalPrimitives(_context(v_max=20.0))
    counts = [fast.root_children(rng.uniform(-3.0, 3.0, size=2))[0].shape[0] for _ in range(50)]
    assert 24 <= min(counts) and max(counts) <= 33


@pytest.mark.parametrize("dims", [2, 3])
def test_static_screen_matches_the_grid_collision_test(dims):
    rng = np.random.default_rng(dims)
    hi = np.array([50.0, 50.0, 20.0][:dims])
    grid = OccupancyGrid(np.zeros(dims), hi, 1.0)
    grid.cells[...] = FREE
    grid.mark_occupied(rng.uniform(0, hi, size=(60 if dims == 2 else 300, dims)))
    pts = rng.uniform(-0.5, hi + 0.5, size=(20000 if dims == 2 else 2000, dims))
    for reach in (0.7, 1.5, 2.3):
        screen = StaticScreen(grid, reach)
        expected = grid.collides(pts, reach)
        assert expected.sum() > 50
        np.testing.assert_array_equal(screen.bad(pts), expected)
        assert screen.valid_for(grid)
    grid.cells[(3,) * dims] = FREE
    grid.mark_occupied(np.array([[2.5] * dims]))              # the centre of cell (3, 3[, 3])
    assert not screen.valid_for(grid)


# ---------------------------------------------------------------- heuristic

def _all_paths(gp, p0, v0, depth):
    """Every acceleration sequence of length depth from the exact state (root: shifted grid): sample positions
    [N, depth * S, d], cumulative cost at each sample [N, depth * S], and validity (|v| <= v_max at every primitive
    end reached so far) [N, depth * S]."""
    s = gp.dt * np.arange(1, gp.steps_per_primitive + 1)
    _, acc_root = gp.root_children(v0)
    p, v = p0[None], v0[None]
    cost, ok = np.zeros(1), np.ones(1, bool)
    pos_l, cost_l, ok_l = [], [], []
    for level in range(depth):
        a = acc_root if level == 0 else gp.accelerations
        n, c = p.shape[0], a.shape[0]
        pos = p[:, None, None, :] + s[None, None, :, None] * v[:, None, None, :] \
            + 0.5 * (s * s)[None, None, :, None] * a[None, :, None, :]                    # [n, c, S, d]
        v_end = v[:, None, :] + gp.T * a[None]
        ok = ok[:, None] & (np.linalg.norm(v_end, axis=2) <= gp.limits.v_max + 1e-9)      # [n, c]
        a2 = np.einsum("cd,cd->c", a, a)
        cum = cost[:, None, None] + ((a2 + gp.rho)[None, :, None] * s[None, None, :])      # [n, c, S]
        # expand the history of the previous levels to the new children
        pos_l = [x.repeat(c, axis=0) for x in pos_l] + [pos.reshape(n * c, -1, p.shape[1])]
        cost_l = [x.repeat(c, axis=0) for x in cost_l] + [cum.reshape(n * c, -1)]
        ok_l = [x.repeat(c, axis=0) for x in ok_l] + [np.repeat(ok.reshape(-1, 1), s.shape[0], axis=1)]
        p, v = pos[:, :, -1].reshape(n * c, -1), v_end.reshape(n * c, -1)
        cost, ok = cum[:, :, -1].reshape(-1), ok.reshape(-1)
    return np.concatenate(pos_l, axis=1), np.concatenate(cost_l, axis=1), np.concatenate(ok_l, axis=1)


def _eq_a1(p, v, goal, T, rho):
    """Thesis eq. A-1: the LQMT cost with T fixed and the final state fixed at the goal with zero velocity."""
    e = goal - p
    return 12 * (e @ e) / T ** 3 - 12 * (v @ e) / T ** 2 + 4 * (v @ v) / T + rho * T


@pytest.mark.parametrize("n_accel,depth,v_max", [(5, 3, 4.0), (7, 3, 6.0)])
def test_heuristic_never_exceeds_the_exhaustive_lattice_optimum(n_accel, depth, v_max):
    """100 seeded random states per case (200 in all): h <= the cheapest path to the goal ball among all
    acceleration sequences of the given depth; h is not trivially small; eq. A-1 would overestimate."""
    gp = GlobalPrimitives(_context(v_max=v_max), n_accel=n_accel)
    rng = np.random.default_rng(1234 + n_accel)
    goal_r = 1.0 - 1e-9
    ratios, a1_over = [], 0
    for _ in range(100):
        p0 = rng.uniform(20.0, 30.0, size=2)
        v0 = rng.normal(size=2)
        v0 *= rng.uniform(0.0, v_max) / np.linalg.norm(v0)
        pos, cost, ok = _all_paths(gp, p0, v0, depth)
        # the goal: near a random sample of a random valid path, so a path of this depth reaches it
        i = rng.choice(np.flatnonzero(ok[:, -1]))
        k = rng.integers(0, pos.shape[1])
        off = rng.normal(size=2)
        goal = pos[i, k] + off / np.linalg.norm(off) * rng.uniform(0.0, 0.9)
        inside = ok & (np.linalg.norm(pos - goal, axis=2) <= goal_r)
        opt = cost[inside].min()
        h = gp.heuristic(goal, 1.0, p0[None], v0[None])[0]
        h_cont = lqmt_lower_bound(goal - p0, v0, 1.0, gp.rho, v_max, 4.0)[0]   # without the lattice velocities
        assert 0.0 <= h <= opt + 1e-9 and 0.0 <= h_cont <= opt + 1e-9, (p0, v0, goal, h, h_cont, opt)
        ratios.append(h / opt)
        a1_over += _eq_a1(p0, v0, goal, gp.T * depth, gp.rho) > opt + 1e-9
    assert np.median(ratios) > 0.5
    assert a1_over > 0


def test_astar_with_epsilon_one_is_optimal_and_weighted_is_bounded():
    ctx = _context()
    rng = np.random.default_rng(7)
    exact, weighted = GlobalPrimitives(ctx, n_accel=5, epsilon=1.0), GlobalPrimitives(ctx, n_accel=5)
    for _ in range(12):
        p0 = rng.uniform(20.0, 30.0, size=2)
        v0 = rng.uniform(-2.0, 2.0, size=2)
        pos, cost, ok = _all_paths(exact, p0, v0, 2)
        goal = pos[rng.choice(np.flatnonzero(ok[:, -1])), -1]
        opt2 = cost[ok & (np.linalg.norm(pos - goal, axis=2) <= 1.0 - 1e-9)].min()
        view = _view(ctx, p0, goal, v=v0)
        assert exact.plan(view) is not None and weighted.plan(view) is not None
        assert exact.last_cost <= opt2 + 1e-9          # optimal over all depths, so at most the depth-2 optimum
        assert exact.last_cost <= weighted.last_cost + 1e-9 <= 1.5 * exact.last_cost + 1e-9


# ---------------------------------------------------------------- one plan

def _busy_view(ctx, v=None, t=3.0):
    grid = _grid(ctx)
    for y in range(18, 27):
        grid.mark_occupied(np.array([[24.5, y + 0.5]]))           # a wall segment x in [24, 25), y in [18, 27)
    tracks = _tracks([[17.0, 29.0], [30.0, 14.0], [33.0, 26.0]], [[0.0, -2.0], [-1.0, 2.0], [-3.0, 0.0]], 1.0)
    return _view(ctx, [12.0, 22.0], [42.0, 22.0], v=np.array([2.5, -0.7]) if v is None else v, grid=grid,
                 tracks=tracks, t=t)


def test_plan_is_dynamically_feasible_within_limits_and_clear_of_its_predictions():
    ctx = _context()
    gp = GlobalPrimitives(ctx)
    view = _busy_view(ctx)
    tr = gp.plan(view)
    assert tr is not None and gp.last_status == "found" and gp.last_expansions >= 1
    assert tr.t0 == view.t and tr.dt == DT and tr.n_samples >= 2
    np.testing.assert_array_equal(tr.p[0], view.position)
    np.testing.assert_array_equal(tr.v[0], view.velocity)
    # exact double integrator with piecewise-constant acceleration a[k] on [t_k, t_k+1)
    np.testing.assert_allclose(tr.p[1:], tr.p[:-1] + tr.v[:-1] * DT + 0.5 * tr.a[:-1] * DT ** 2, atol=1e-9)
    np.testing.assert_allclose(tr.v[1:], tr.v[:-1] + tr.a[:-1] * DT, atol=1e-9)
    assert within_limits(tr.v, tr.a, 4.0, 4.0)
    # acceleration changes only at primitive boundaries (every 10 samples)
    changes = np.flatnonzero(np.any(np.diff(tr.a[:-1], axis=0) != 0, axis=1)) + 1
    assert np.all(changes % gp.steps_per_primitive == 0) and changes.size >= 1
    # clear of the predictions within the horizon, of the occupied cells and walls everywhere; ends in the goal
    times = tr.times
    near = times - view.t <= gp.horizon_s + 1e-9
    assert trajectory_clear(view, tr.p[1:][near[1:]], times[1:][near[1:]], gp.margin)
    assert static_clear(view, tr.p[1:], gp.margin).all()
    assert np.linalg.norm(tr.p[-1] - view.goal) <= view.goal_radius
    assert np.all(np.linalg.norm(tr.p[:-1] - view.goal, axis=1) > view.goal_radius - 1e-9)
    # the wall and the tracks really were in the way: the straight line to the goal is not clear
    line = view.position + np.linspace(0, 1, 300)[:, None] * (view.goal - view.position)
    assert not static_clear(view, line, gp.margin).all()


def test_heuristic_never_exceeds_the_remaining_cost_along_returned_paths():
    rng = np.random.default_rng(11)
    checked = plans = 0
    for k in range(6):                                          # 2D: the busy scene at several times
        gp = GlobalPrimitives(_context())
        assert gp.plan(_busy_view(_context(), t=float(k))) is not None
        checked += _check_path_heuristic(gp)
    ctx = _context(3)
    gp = GlobalPrimitives(ctx)
    while plans < 6:                                            # 3D: random scenes whose start is not in conflict
        tracks = _tracks(rng.uniform([10, 10, 4], [40, 40, 16], size=(6, 3)), rng.uniform(-2, 2, size=(6, 3)), 1.0)
        p0 = rng.uniform([5, 5, 4], [15, 45, 16])
        if np.linalg.norm(tracks.position - p0, axis=1).min() < 6.0:
            continue
        view = _view(ctx, p0, rng.uniform([35, 5, 4], [45, 45, 16]), v=rng.uniform(-1.5, 1.5, size=3), tracks=tracks)
        assert gp.plan(view) is not None
        checked += _check_path_heuristic(gp)
        plans += 1
    assert checked > 50


def _check_path_heuristic(gp) -> int:
    total = gp.last_cost
    assert total == pytest.approx(gp.last_path[-1][2])
    for _, _, g, h in gp.last_path:
        assert h <= total - g + 1e-9
    assert gp.last_path[0][3] > 0.5 * total                     # and h is informative at the root
    return len(gp.last_path)


def test_same_inputs_give_identical_trajectories():
    ctx = _context()
    plans = [GlobalPrimitives(ctx).plan(_busy_view(ctx)) for _ in range(2)]
    for name in ("p", "v", "a"):
        np.testing.assert_array_equal(getattr(plans[0], name), getattr(plans[1], name))


def test_exhausted_and_budget_statuses():
    ctx = _context()
    grid = _grid(ctx)
    grid.cells[1:-1, 1:-1] = OCCUPIED
    grid.cells[8:14, 8:14] = FREE                           # a 6 x 6 m pocket around (10, 10)
    gp = GlobalPrimitives(ctx)
    assert gp.plan(_view(ctx, [10.0, 10.0], [40.0, 10.0], grid=grid)) is None
    assert gp.last_status == "exhausted" and gp.n_budget_hits == 0
    small = GlobalPrimitives(ctx, max_expansions=3)
    assert small.plan(_view(ctx, [10.0, 10.0], [40.0, 40.0])) is None
    assert small.last_status == "budget" and small.last_expansions == 3 and small.n_budget_hits == 1
    assert GlobalPrimitives(ctx).plan(_view(ctx, [10.0, 10.0], [40.0, 40.0])) is not None


def test_replan_check_on_new_predictions_new_occupied_cells_and_end_of_plan():
    ctx = _context()
    gp = GlobalPrimitives(ctx)
    grid = _grid(ctx)
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0], grid=grid)
    assert gp.replan_check(view)                                  # no plan yet
    tr = gp.plan(view)
    t1 = DT

    def at(t, tracks=None, trajectory=tr):
        p, v, _ = trajectory.state_at(t)
        return _view(ctx, p, [40.0, 25.0], v=v, grid=grid, tracks=tracks, t=t, trajectory=trajectory)

    assert not gp.replan_check(at(t1))
    # a track whose prediction meets the remaining plan 2 s ahead (within the horizon)
    q = tr.p[tr.index_at(t1 + 2.0)]
    meet = _tracks([q - [0.0, 6.0]], [[0.0, 3.0]], 1.0)
    assert gp.replan_check(at(t1, meet))
    # the same meeting 7 s ahead is beyond the 5 s horizon
    q7 = tr.p[tr.index_at(t1 + 7.0)]
    late = _tracks([q7 - [0.0, 21.0]], [[0.0, 3.0]], 1.0)
    assert not gp.replan_check(at(t1, late))
    # a newly occupied cell on the remaining plan (grid version changes)
    q_far = tr.p[tr.index_at(t1 + 6.0)]
    assert not gp.replan_check(at(t1))
    grid.mark_occupied(np.array([[35.0, 45.0]]))                  # far away: version changes, plan still clear
    assert not gp.replan_check(at(t1))
    grid.mark_occupied(q_far[None])
    assert gp.replan_check(at(t1))
    # the plan runs out
    end = Trajectory(tr.t0, tr.dt, tr.p[:3], tr.v[:3], tr.a[:3])
    assert not gp.replan_check(at(DT, trajectory=end))
    assert gp.replan_check(at(2 * DT, trajectory=end))


# ---------------------------------------------------------------- trials in PyBullet worlds

def test_all_72_pairs_succeed_in_an_empty_arena_2d():
    sc = _scenario()
    assert len(sc.task.pairs()) == 72
    assert failed_pairs(sc, build_rollout(sc, first_map(sc)), "lookahead+global_primitives") == []


def test_sample_of_pairs_succeeds_in_an_empty_volume_3d():
    cands = [[x, y, z] for x in (4.0, 25.0, 46.0) for y in (4.0, 46.0) for z in (4.0, 16.0)]
    sc = _scenario(3, task={"candidates": cands}, drone={"v_max": 2.0})
    rollout = build_rollout(sc, first_map(sc))
    for i, j in demo_pairs(sc, 6):
        res = fly(sc, rollout, "lookahead+global_primitives", sc.task.candidates[i], sc.task.candidates[j])
        assert res.outcome == "success" and res.planning_failures == 0, (i, j, res)


@pytest.mark.parametrize("dims,p0,v0,radius,planner", [
    (2, [40.0, 25.0], [-2.5, 0.0], 1.0, "lookahead+global_primitives"),            # head-on on the goal line
    (2, [25.0, 13.5], [0.0, 2.0], 1.5, "lookahead+global_primitives"),             # crossing, unseen at t = 0
    (2, [25.0, 36.5], [0.0, -2.0], 1.5, "fullrange+global_primitives"),            # crossing from the other side
    (3, [40.0, 25.0, 10.0], [-2.5, 0.0, 0.0], 1.0, "lookahead+global_primitives"),  # head-on sphere in 3D
])
def test_avoids_head_on_and_crossing_obstacles_that_straight_line_hits(dims, p0, v0, radius, planner):
    sc = _scenario(dims)
    z = [10.0] if dims == 3 else []
    start, goal = tuple([4.0, 25.0] + z), tuple([46.0, 25.0] + z)
    assert_avoids(sc, handmade_rollout(sc, [p0], [v0], [radius]), planner, start, goal)


def test_trials_respect_norm_limits_and_are_deterministic(tmp_path):
    sc = parse_scenario({"world": {"time_limit": 30.0},
                         "obstacles": {"count": 20, "radius": 1.0, "speed": 3.0, "root_seed": 3},
                         "drone": {"v_max": 6.0}, "planners": GP_PLANNERS})
    rollout = build_rollout(sc, first_map(sc))
    runs = []
    for name in ("a.npz", "b.npz"):
        res = fly(sc, rollout, "fullrange+global_primitives", (4.0, 4.0), (46.0, 46.0), trace_path=tmp_path / name)
        with np.load(tmp_path / name) as z:
            v, a = np.vstack([z["v"], z["final_v"]]), np.vstack([z["a"], z["final_a"]])
            runs.append((res.outcome, res.steps, res.min_clearance_m, z["p"].copy(), v, a))
    (o1, s1, c1, p1, v1, a1), (o2, s2, c2, p2, v2, a2) = runs
    assert (o1, s1, c1) == (o2, s2, c2) and s1 > 20
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(v1, v2)
    assert np.linalg.norm(v1, axis=1).max() <= 6.0 + 1e-9
    assert np.linalg.norm(a1, axis=1).max() <= 4.0 + 1e-9
    assert np.linalg.norm(v1, axis=1).max() > 4.0                  # it really cruised


def test_boxed_in_is_a_deadlock_of_the_map_not_of_the_budget():
    walls = [{"kind": "box", "center": c, "size": s} for c, s in
             (([25.0, 28.5], [8.0, 1.0]), ([25.0, 21.5], [8.0, 1.0]), ([28.5, 25.0], [1.0, 8.0]),
              ([21.5, 25.0], [1.0, 8.0]))]
    planners = []

    class Recording(GlobalPrimitives):
        def __init__(self, context, **kw):
            super().__init__(context, **kw)
            planners.append(self)

    registry.TRAJECTORY_PLANNERS["_test_recording_gp"] = Recording
    try:
        sc = _scenario(static_obstacles=walls, task={"candidates": [[25.0, 25.0], [46.0, 46.0]]},
                       planners=[{"trajectory": "_test_recording_gp", "gaze": "fullrange"}])
        rollout = build_rollout(sc, first_map(sc))
        res = fly(sc, rollout, "fullrange+_test_recording_gp", (25.0, 25.0), (46.0, 46.0))
    finally:
        del registry.TRAJECTORY_PLANNERS["_test_recording_gp"]
    assert res.outcome == "deadlock", res
    gp = planners[-1]
    assert gp.n_plans >= 10 and gp.n_budget_hits == 0 and gp.last_status == "exhausted"
    assert math.isnan(gp.last_cost)
