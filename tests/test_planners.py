"""Trajectory planners, gaze planners, the shared trajectory check and the registry, on synthetic Views."""

import math
import struct

import numpy as np
import pytest
import ruckig

from pbdyn.errors import ConfigError
from pbdyn.perception.grid import FREE, OCCUPIED, OccupancyGrid
from pbdyn.planning import registry
from pbdyn.planning.checks import WALL_MARGIN_CAP, first_conflict, trajectory_clear, within_limits
from pbdyn.planning.gaze.rules import FullRange, LookAhead, LookGoal
from pbdyn.planning.primitives.local import LocalPrimitives
from pbdyn.planning.protocols import GazePlanner, PlannerContext, TrajectoryPlanner
from pbdyn.planning.straight_line import StraightLine
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, Tracks, View
from pbdyn.world.geometry import wrap_angle
from tests.helpers import make_tracks

DT = 0.1
SIZE = 50.0


def _context(dims=2, v_max=4.0, a_max=4.0):
    hi = np.array([SIZE, SIZE, 20.0][:dims])
    return PlannerContext(dims, DT, MAVLimits(1.0, v_max, a_max, 1.4), np.zeros(dims), hi)


def _grid(ctx, free=True):
    g = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    if free:
        g.cells[(slice(1, -1),) * ctx.dims] = FREE
    return g


def _view(ctx, p, goal, v=None, a=None, grid=None, tracks=None, t=0.0, yaw=0.0, trajectory=None):
    d = ctx.dims
    return View(t=t, dt=ctx.dt, position=np.asarray(p, float), velocity=np.zeros(d) if v is None else v,
                acceleration=np.zeros(d) if a is None else a, yaw=yaw, goal=np.asarray(goal, float),
                goal_radius=1.0, limits=ctx.limits, bounds_lo=ctx.bounds_lo, bounds_hi=ctx.bounds_hi,
                grid=_grid(ctx) if grid is None else grid, tracks=Tracks.empty(d) if tracks is None else tracks,
                trajectory=trajectory)


_tracks = make_tracks


def _fly(planner, ctx, start, goal, steps=800, grid=None, tracks=None):
    """Execute sample 1 of every plan; returns (reached, executed speeds, executed accelerations, n steps)."""
    d = ctx.dims
    p, v, a = np.asarray(start, float), np.zeros(d), np.zeros(d)
    grid = _grid(ctx) if grid is None else grid
    speeds, accs = [], []
    for k in range(steps):
        view = _view(ctx, p, goal, v, a, grid=grid, tracks=tracks, t=k * DT)
        tr = planner.plan(view)
        assert tr is not None, f"planning failed at step {k}"
        assert tr.t0 == pytest.approx(view.t) and tr.dt == DT and tr.n_samples >= 2
        np.testing.assert_allclose(tr.p[0], p, atol=1e-12)
        np.testing.assert_allclose(tr.v[0], v, atol=1e-12)
        p, v, a = tr.p[1].copy(), tr.v[1].copy(), tr.a[1].copy()
        speeds.append(np.linalg.norm(v))
        accs.append(np.linalg.norm(a))
        if np.linalg.norm(p - goal) <= 1.0:
            return True, np.array(speeds), np.array(accs), k + 1
    return False, np.array(speeds), np.array(accs), steps


# ---------------------------------------------------------------- checks

def test_checks_walls_use_capped_margin_and_unknown_cells_are_free():
    ctx = _context()
    view = _view(ctx, [10, 10], [40, 10], grid=_grid(ctx, free=False))  # every cell UNKNOWN
    wall_r = 1.0 + WALL_MARGIN_CAP
    assert trajectory_clear(view, np.array([[wall_r + 0.01, 25.0], [25.0, SIZE - wall_r - 0.01]]), [0.1, 0.2])
    assert not trajectory_clear(view, np.array([[25.0, 25.0], [wall_r - 0.01, 25.0]]), [0.1, 0.2])
    assert first_conflict(view, np.array([[25.0, 25.0], [25.0, 25.0], [25.0, SIZE - wall_r + 0.01]]),
                          [0.1, 0.2, 0.3]) == 2


def test_checks_occupied_cells_with_margin():
    ctx = _context()
    grid = _grid(ctx)
    grid.mark_occupied(np.array([[20.5, 25.5]]))  # the cell [20, 21) x [25, 26)
    view = _view(ctx, [10, 10], [40, 10], grid=grid)
    pts = np.array([[18.45, 25.5], [18.55, 25.5]])  # 1.55 m and 1.45 m from the cell's face at x = 20
    assert first_conflict(view, pts, [0.1, 0.2], margin=0.5) == 1
    assert trajectory_clear(view, pts[:1], [0.1], margin=0.5)
    assert not trajectory_clear(view, pts[1:], [0.1], margin=0.5)
    assert trajectory_clear(view, pts[1:], [0.1], margin=0.4)


def test_checks_tracks_are_predicted_to_the_sample_time():
    ctx = _context()
    # track at view.t = 5 s is at (20, 10) moving +y at 2 m/s: at absolute time 7 s it is at (20, 14)
    tracks = _tracks([[20.0, 10.0]], [[0.0, 2.0]], 0.5)
    view = _view(ctx, [10, 10], [40, 10], tracks=tracks, t=5.0)
    p = np.array([[20.0, 14.0]])
    assert not trajectory_clear(view, p, [7.0])
    assert first_conflict(view, p, [7.0]) == 0
    assert trajectory_clear(view, p, [5.0])           # it is still 4 m away at 5 s
    # the distance threshold is MAV radius + margin + track radius = 2.0 m
    assert trajectory_clear(view, np.array([[22.01, 14.0]]), [7.0])
    assert not trajectory_clear(view, np.array([[21.99, 14.0]]), [7.0])


def test_within_limits_uses_norms():
    v = np.array([[3.0, 3.0]])  # |v| = 4.24 although each axis is below 4
    assert not within_limits(v, np.zeros((1, 2)), 4.0, 4.0)
    assert within_limits(v, np.zeros((1, 2)), 4.25, 4.0)
    assert not within_limits(np.zeros((1, 2)), np.array([[0.0, 4.0 + 1e-6]]), 4.0, 4.0)


# ---------------------------------------------------------------- local primitives

@pytest.mark.parametrize("v_max", [2.0, 4.0, 6.0])
def test_local_primitives_reach_goals_in_empty_arena_within_limits(v_max):
    ctx = _context(v_max=v_max)
    pairs = [((4, 4), (46, 25)), ((46, 46), (4, 4)), ((25, 4), (25, 46)), ((4, 46), (46, 4)), ((46, 25), (4, 25))]
    builds = []
    for start, goal in pairs:
        planner = LocalPrimitives(ctx)
        reached, speeds, accs, steps = _fly(planner, ctx, start, goal)
        assert reached, (start, goal)
        assert speeds.max() <= v_max + 1e-9 and accs.max() <= 4.0 + 1e-9
        assert speeds.max() > 0.75 * v_max  # it really cruises, not creeps
        builds.append(planner.last_candidates_built)
    assert max(builds) <= 4


def test_local_primitives_reach_goal_in_3d():
    ctx = _context(dims=3)
    planner = LocalPrimitives(ctx)
    assert planner.directions.shape == (412, 3)  # rings every 10 deg
    np.testing.assert_allclose(np.linalg.norm(planner.directions, axis=1), 1.0)
    reached, speeds, accs, _ = _fly(planner, ctx, (4, 4, 10), np.array([46.0, 25.0, 10.0]))
    assert reached
    assert speeds.max() <= 4.0 + 1e-9 and accs.max() <= 4.0 + 1e-9


def test_local_primitives_ranking_and_first_candidate_points_at_goal():
    ctx = _context()
    planner = LocalPrimitives(ctx)
    view = _view(ctx, [10, 10], [10 + 30 * math.cos(math.radians(35)), 10 + 30 * math.sin(math.radians(35))])
    order = planner.ranked_candidates(view)
    assert order[0] == 7 and set(order[1:3]) == {6, 8}
    tr = planner.plan(view)
    assert tr is not None and planner.last_rank == 0 and planner.last_candidates_built >= 1
    np.testing.assert_allclose(planner.last_target, [10 + 3 * math.cos(math.radians(35)),
                                                     10 + 3 * math.sin(math.radians(35))], atol=1e-12)
    # ties (goal half way between candidates 7 and 8) go to the lower index
    tie = _view(ctx, [10, 10], [10 + 30 * math.cos(math.radians(37.5)), 10 + 30 * math.sin(math.radians(37.5))])
    assert list(planner.ranked_candidates(tie)[:2]) == [7, 8]


def test_local_primitives_primitive_ends_at_candidate_with_end_velocity():
    ctx = _context()
    planner = LocalPrimitives(ctx)
    tr = planner.plan(_view(ctx, [10, 10], [40, 10]))
    # the reference: ruckig itself, from rest to the candidate 3 m along +x (a straight primitive: per-axis limits
    # are the norm limits, so the first build is kept)
    otg, traj, inp = ruckig.Ruckig(2), ruckig.Trajectory(2), ruckig.InputParameter(2)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [3.0, 0.0], [2.0, 0.0], [0.0, 0.0]
    inp.max_velocity, inp.max_acceleration = [ctx.limits.v_max] * 2, [ctx.limits.a_max] * 2
    inp.max_jerk, inp.minimum_duration = [planner.jerk_max] * 2, planner.min_duration
    assert otg.calculate(inp, traj) in (ruckig.Result.Working, ruckig.Result.Finished)
    duration = traj.duration
    assert duration >= planner.min_duration - 1e-12 and planner.min_duration == pytest.approx(0.9)
    assert tr.n_samples == math.ceil(duration / DT - 1e-9) + 1
    t_last = (tr.n_samples - 1) * DT  # past the duration the end velocity is held
    np.testing.assert_allclose(tr.p[-1], [13.0 + 2.0 * (t_last - duration), 10.0], atol=1e-9)
    np.testing.assert_allclose(tr.v[-1], [2.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(tr.a[-1], [0.0, 0.0], atol=1e-9)
    # samples are the ruckig trajectory at k dt
    for k in (1, 4):
        p, v, a = traj.at_time(k * DT)
        # planned in a frame whose first axis points at the candidate (+x here), origin at the MAV
        np.testing.assert_allclose(tr.p[k], np.add(p, [10.0, 10.0])), np.testing.assert_allclose(tr.v[k], v)


@pytest.mark.parametrize("minjerk", [False, True], ids=["ruckig", "minjerk"])
def test_local_primitives_goal_within_step_is_first_candidate_at_rest(minjerk):
    from dataclasses import replace

    from pbdyn.planning.primitives.minjerk import LocalPrimitivesMinJerk

    ctx = replace(_context(), physical=not minjerk)
    planner = (LocalPrimitivesMinJerk if minjerk else LocalPrimitives)(ctx)
    goal = np.array([12.0, 11.0])
    tr = planner.plan(_view(ctx, [10, 10], goal))
    assert planner.last_rank == 0
    np.testing.assert_allclose(planner.last_target, goal)
    np.testing.assert_allclose(tr.p[-1], goal, atol=1e-9)
    np.testing.assert_allclose(tr.v[-1], 0.0, atol=1e-9)
    if minjerk:   # blocked goal: the fan follows, its ranks counted after the goal's
        tr = planner.plan(_view(ctx, [10, 10], goal, tracks=make_tracks([goal], [[0.0, 0.0]], 0.5)))
        assert tr is not None and planner.last_rank >= 1 and planner.last_candidates_tried >= 2


def test_local_primitives_avoid_occupied_wall():
    ctx = _context()
    grid = _grid(ctx)
    for y in range(22, 29):
        grid.mark_occupied(np.array([[13.5, y + 0.5]]))  # a wall segment x in [13, 14), y in [22, 29)
    planner = LocalPrimitives(ctx)
    view = _view(ctx, [10.5, 25.5], [40.5, 25.5], grid=grid)
    tr = planner.plan(view)
    assert tr is not None and planner.last_rank > 0
    assert planner.last_candidates_tried >= 2
    assert not np.any(grid.collides(tr.p[1:], 1.5))
    # the straight candidate really is blocked, and an executed flight gets around the wall
    assert grid.collides(np.array([[13.5, 25.5]]), 1.5)[0]
    reached, speeds, _, _ = _fly(LocalPrimitives(ctx), ctx, (10.5, 25.5), np.array([40.5, 25.5]), grid=grid)
    assert reached and speeds.max() <= 4.0 + 1e-9


def test_local_primitives_avoid_predicted_track():
    ctx = _context()
    tracks = _tracks([[14.0, 25.0]], [[0.0, 0.0]], 1.0)  # a hovering obstacle on the straight path
    planner = LocalPrimitives(ctx)
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0], tracks=tracks)
    tr = planner.plan(view)
    assert tr is not None and planner.last_rank > 0
    dist = np.linalg.norm(tr.p[1:] - [14.0, 25.0], axis=1)
    assert dist.min() >= 1.0 + 1.0 + 0.5
    # an obstacle crossing the straight path when the MAV would be there: coming down from y = 29 at 4 m/s
    crossing = _tracks([[12.0, 29.0]], [[0.0, -4.0]], 1.0)
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0], tracks=crossing, t=3.0)
    tr = planner.plan(view)
    assert tr is not None and planner.last_rank > 0
    centres = crossing.predict(tr.times[1:] - view.t)[:, 0, :]
    assert np.linalg.norm(tr.p[1:] - centres, axis=1).min() >= 2.5


def test_local_primitives_all_blocked_returns_none():
    ctx = _context()
    grid = _grid(ctx)
    grid.cells[1:-1, 1:-1] = OCCUPIED
    grid.cells[10:13, 10:13] = FREE  # a 3 x 3 m free pocket around (10, 10)
    planner = LocalPrimitives(ctx)
    assert planner.plan(_view(ctx, [10.0, 10.0], [40.0, 10.0], grid=grid)) is None
    assert planner.last_rank is None
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ring = _tracks(np.c_[10 + 3 * np.cos(ang), 10 + 3 * np.sin(ang)], np.zeros((12, 2)), 1.0)  # hovering ring
    assert planner.plan(_view(ctx, [10.0, 10.0], [40.0, 10.0], tracks=ring)) is None
    assert planner.last_candidates_tried == 72


def test_local_primitives_limits_from_random_moving_states():
    rng = np.random.default_rng(3)
    for dims in (2, 3):
        ctx = _context(dims=dims, v_max=6.0)
        planner = LocalPrimitives(ctx)
        n_ok = 0
        for _ in range(60):
            v = rng.normal(size=dims)
            v *= rng.uniform(0, 6.0) / np.linalg.norm(v)
            a = rng.normal(size=dims)
            a *= rng.uniform(0, 4.0) / np.linalg.norm(a)
            p = rng.uniform(10, [40, 40, 10][:dims])
            goal = rng.uniform(5, [45, 45, 15][:dims])
            tr = planner.plan(_view(ctx, p, goal, v=v, a=a))
            assert planner.last_candidates_built <= 4 * planner.last_candidates_tried
            if tr is None:
                continue
            n_ok += 1
            np.testing.assert_allclose(tr.a[0], a)
            assert within_limits(tr.v[1:], tr.a[1:], 6.0, 4.0)
        assert n_ok >= 50


def test_local_primitives_rejects_bad_parameters():
    with pytest.raises(ValueError):
        LocalPrimitives(_context(), n_candidates=0)
    with pytest.raises(ValueError):
        LocalPrimitives(_context(), step_m=-1.0)


# ---------------------------------------------------------------- straight line

def test_straight_line_reaches_goal_ignoring_tracks_and_respects_limits():
    ctx = _context(v_max=6.0)
    planner = StraightLine(ctx)
    assert isinstance(planner, TrajectoryPlanner)
    tracks = _tracks([[20.0, 20.0]], [[0.0, 0.0]], 1.5)  # right on the line
    view_free = _view(ctx, [5.0, 5.0], [45.0, 45.0], v=np.array([0.0, 3.0]))
    view_obst = _view(ctx, [5.0, 5.0], [45.0, 45.0], v=np.array([0.0, 3.0]), tracks=tracks)
    a, b = planner.plan(view_free), planner.plan(view_obst)
    np.testing.assert_array_equal(a.p, b.p)
    reached, speeds, accs, _ = _fly(planner, ctx, (5.0, 5.0), np.array([45.0, 45.0]), tracks=tracks)
    assert reached
    assert speeds.max() <= 6.0 + 1e-9 and accs.max() <= 4.0 + 1e-9 and speeds.max() > 5.9


def test_straight_line_corrects_misaligned_velocity_and_stops_at_goal():
    ctx = _context(v_max=4.0)
    planner = StraightLine(ctx)
    p, v, a = np.array([25.0, 25.0]), np.array([-4.0, 0.0]), np.zeros(2)
    goal = np.array([30.0, 25.0])
    for k in range(300):
        tr = planner.plan(_view(ctx, p, goal, v=v, a=a, t=k * DT))
        assert tr.n_samples >= 2
        assert within_limits(tr.v, tr.a, 4.0, 4.0)
        # the plan is a consistent double integrator
        np.testing.assert_allclose(tr.p[1:], tr.p[:-1] + tr.v[:-1] * DT + 0.5 * tr.a[:-1] * DT ** 2, atol=1e-12)
        p, v, a = tr.p[1], tr.v[1], tr.a[1]
    np.testing.assert_allclose(p, goal, atol=1e-3)
    assert np.linalg.norm(v) < 1e-3


def test_straight_line_and_lookahead_in_3d():
    ctx = _context(dims=3)
    reached, speeds, accs, _ = _fly(StraightLine(ctx), ctx, (4.0, 4.0, 5.0), np.array([46.0, 25.0, 15.0]))
    assert reached and speeds.max() <= 4.0 + 1e-9 and accs.max() <= 4.0 + 1e-9
    view = _view(ctx, [25, 25, 10], [40, 25, 10], v=np.array([0.0, 0.05, 3.0]), yaw=0.0)
    assert LookAhead(ctx).yaw_rate(view, None) == pytest.approx(ctx.limits.yaw_rate)  # x-y part points at +y


# ---------------------------------------------------------------- gaze

def test_lookahead_turns_toward_velocity_at_most_the_limit_the_shortest_way():
    ctx = _context()
    gaze = LookAhead(ctx)
    assert isinstance(gaze, GazePlanner)
    limit = ctx.limits.yaw_rate

    def rate(v, yaw, **kw):
        return gaze.yaw_rate(_view(ctx, [25, 25], [40, 25], v=np.asarray(v, float), yaw=yaw, **kw), None)

    assert rate([0, 2], 0.0) == pytest.approx(limit)                      # 90 deg left: full rate
    assert rate([math.cos(3.0), math.sin(3.0)], -3.0) == pytest.approx(-limit)  # across +-pi: the short way
    small = math.radians(5)
    assert rate([math.cos(small), math.sin(small)], 0.0) == pytest.approx(small / DT)  # reached in one step
    assert rate([-1, 0], math.pi - 0.05) == pytest.approx(0.05 / DT)
    assert rate([1, 0], 0.0) == 0.0
    # the yaw after one step never passes the target
    yaw, target = 0.0, 2.0
    for _ in range(30):
        yaw += rate([math.cos(target), math.sin(target)], yaw) * DT
    assert yaw == pytest.approx(target)


def test_lookahead_fallbacks_when_hovering():
    ctx = _context()
    gaze = LookAhead(ctx)
    n = 5
    p = np.tile([25.0, 25.0], (n, 1))
    v = np.zeros((n, 2))
    v[1:] = [0.0, -1.0]
    tr = Trajectory(0.0, DT, p, v, np.zeros((n, 2)))
    view = _view(ctx, [25, 25], [40, 25], yaw=0.0)
    assert gaze.yaw_rate(view, tr) == pytest.approx(-ctx.limits.yaw_rate)  # next sample's velocity: -90 deg
    still = Trajectory(0.0, DT, np.array([[25.0, 25.0], [24.0, 25.0]]), np.zeros((2, 2)), np.zeros((2, 2)))
    assert gaze.yaw_rate(_view(ctx, [25, 25], [40, 25], yaw=math.pi - 0.01), still) == pytest.approx(0.01 / DT)
    assert gaze.yaw_rate(_view(ctx, [25, 25], [25, 26], yaw=0.0), None) == pytest.approx(ctx.limits.yaw_rate)


def test_wrap_angle_range():
    assert wrap_angle(math.pi) == -math.pi and wrap_angle(-math.pi) == -math.pi
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-6.0) == pytest.approx(-6.0 + 2 * math.pi)
    assert np.array_equal(wrap_angle(np.array([math.pi, 0.5, -7.0])), [wrap_angle(math.pi), 0.5, wrap_angle(-7.0)])


def test_the_gaze_rules_wrap_into_minus_pi_pi_as_they_did_bit_for_bit():
    """The rule gaze planners' heading error, 0.0 - wrap_angle(yaw - heading), is the (-pi, pi] wrap they had
    (pi - (pi - x) mod 2 pi) bit for bit: signed zeros and the boundaries too."""
    def before(x):
        return math.pi - (math.pi - x) % (2.0 * math.pi)

    edges = [0.0, -0.0, math.pi, -math.pi, 2 * math.pi, math.nextafter(math.pi, 0), math.nextafter(-math.pi, 0),
             math.nextafter(math.pi, 4), 5e-324, 1e16, math.atan2(0.0, -1.0), math.atan2(-0.0, -1.0)]
    rng = np.random.default_rng(3)
    pairs = [(h, y) for h in edges for y in edges] + list(zip(rng.uniform(-4, 4, 20_000), rng.uniform(-4, 4, 20_000)))
    for h, y in pairs:
        h, y = float(h), float(y)
        assert struct.pack("<d", 0.0 - wrap_angle(y - h)) == struct.pack("<d", before(h - y)), (h, y)
    ctx = _context()
    behind = LookGoal(ctx).yaw_rate(_view(ctx, [25, 25], [20, 25], yaw=0.0), None)
    assert behind == ctx.limits.yaw_rate                   # the goal exactly behind: counter-clockwise


def test_fullrange_has_360_fov_and_no_yaw_control():
    ctx = _context()
    g = FullRange(ctx)
    assert g.fov_deg == 360.0 and FullRange.fov_deg == 360.0
    assert g.yaw_rate(_view(ctx, [25, 25], [40, 25], v=np.array([0.0, 3.0])), None) == 0.0


# ---------------------------------------------------------------- registry

class PluginPlanner:
    """A user plug-in: hovers in place."""

    def __init__(self, context, *, hold_s=0.5):
        self.context = context
        self.hold_s = hold_s

    def replan_check(self, view):
        return True

    def plan(self, view):
        n = int(round(self.hold_s / view.dt)) + 1
        p = np.tile(view.position, (n, 1))
        return Trajectory(view.t, view.dt, p, np.zeros_like(p), np.zeros_like(p))


class PluginGaze:
    def __init__(self, context):
        pass

    def yaw_rate(self, view, trajectory):
        return 0.3


class NotAPlanner:
    def __init__(self, context):
        pass

    def plan(self, view):
        return None


def test_registry_builtins_resolve():
    assert registry.resolve_trajectory_planner("local_primitives", "planners[0].trajectory") is LocalPrimitives
    assert registry.resolve_trajectory_planner("straight_line") is StraightLine
    assert registry.resolve_gaze_planner("lookahead") is LookAhead
    assert registry.resolve_gaze_planner("fullrange") is FullRange
    ctx = _context()
    lp = registry.build_planner(LocalPrimitives, ctx, {"n_candidates": 36, "margin": 0.3}, "planners[0].params")
    assert lp.n_candidates == 36 and lp.margin == 0.3 and lp.directions.shape == (36, 2)


def test_registry_plugins_resolve_and_build():
    ctx = _context()
    cls = registry.resolve_trajectory_planner(f"{__name__}:PluginPlanner", "planners[2].trajectory")
    assert cls is PluginPlanner
    planner = registry.build_planner(cls, ctx, {"hold_s": 0.3}, "planners[2].params")
    tr = planner.plan(_view(ctx, [5, 5], [40, 5]))
    assert tr.n_samples == 4
    gaze_cls = registry.resolve_gaze_planner(f"{__name__}:PluginGaze", "planners[2].gaze")
    assert registry.build_planner(gaze_cls, ctx, {}, "planners[2].params").yaw_rate(None, None) == 0.3


@pytest.mark.parametrize("name,fragment", [
    ("rrt_star", "unknown trajectory planner"),
    ("no_such_pkg_xyz.module:Planner", "cannot import module"),
    (f"{__name__}:Missing", "has no attribute"),
    (f"{__name__}:NotAPlanner", "missing method(s) replan_check"),
    (f"{__name__}:PluginGaze", "missing method(s) replan_check, plan"),
    (":Planner", "package.module:Class"),
    (3, "planner name"),
])
def test_registry_errors_name_the_field(name, fragment):
    with pytest.raises(ConfigError) as err:
        registry.resolve_trajectory_planner(name, "planners[1].trajectory")
    msg = str(err.value)
    assert msg.startswith("planners[1].trajectory: ") and fragment in msg and repr(name) in msg
    assert "\n" not in msg


def test_registry_gaze_errors_and_bad_params():
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.gaze: unknown gaze planner"):
        registry.resolve_gaze_planner("owl_v2", "planners[0].gaze")
    with pytest.raises(ConfigError, match=r"missing method\(s\) yaw_rate"):
        registry.resolve_gaze_planner(f"{__name__}:PluginPlanner", "planners[0].gaze")
    ctx = _context()
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params\.n_candidate: unknown parameter"):
        registry.build_planner(LocalPrimitives, ctx, {"n_candidate": 10}, "planners[0].params")
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params: invalid parameters for LocalPrimitives"):
        registry.build_planner(LocalPrimitives, ctx, {"n_candidates": 0}, "planners[0].params")
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params\.gain: unknown parameter of FullRange"):
        registry.build_planner(FullRange, ctx, {"gain": 1.0}, "planners[0].params")


def test_local_primitives_are_invariant_to_the_arena_orientation():
    """Planning in the candidate's own frame: a scene rotated by 90 deg gives the same plan, rotated."""
    ctx = _context()
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])
    centre = np.array([25.0, 25.0])
    p, goal = np.array([20.0, 22.0]), np.array([33.0, 30.0])
    v, a = np.array([1.5, -2.0]), np.array([0.5, 1.0])
    plan_a = LocalPrimitives(ctx).plan(_view(ctx, p, goal, v=v, a=a))
    plan_b = LocalPrimitives(ctx).plan(_view(ctx, centre + rot @ (p - centre), centre + rot @ (goal - centre),
                                             v=rot @ v, a=rot @ a))
    assert plan_a is not None and plan_b is not None and plan_a.n_samples == plan_b.n_samples
    np.testing.assert_allclose(plan_b.p, centre + (plan_a.p - centre) @ rot.T, atol=1e-9)
    np.testing.assert_allclose(plan_b.v, plan_a.v @ rot.T, atol=1e-9)


# ---------------------------------------------------------------- chunked candidates and the no-candidate proof

def _random_views(ctx, rng, n):
    """Views from random moving states among random tracks and occupied cells: many with no clear candidate."""
    d = ctx.dims
    grid = _grid(ctx)
    occupied = rng.integers(1, np.array(grid.shape) - 1, size=(40, d))
    grid.cells[tuple(occupied.T)] = OCCUPIED
    hi = np.array([SIZE, SIZE, 20.0][:d])
    for _ in range(n):
        p = rng.uniform(2.0, hi - 2.0)
        speed = rng.uniform(0.0, ctx.limits.v_max)
        u = rng.normal(size=d)
        v = speed * u / np.linalg.norm(u)
        a = rng.uniform(-1.0, 1.0, size=d)
        m = int(rng.integers(0, 12))
        centres = p + rng.uniform(-6.0, 6.0, size=(m, d))
        vel = rng.uniform(-4.0, 4.0, size=(m, d))
        tracks = make_tracks(centres, vel, rng.uniform(0.5, 1.5)) if m else None
        goal = rng.uniform(2.0, hi - 2.0)
        yield _view(ctx, p, goal, v, a, grid=grid, tracks=tracks, t=float(rng.integers(0, 100)) * DT)


@pytest.mark.parametrize("dims", [2, 3])
def test_local_primitives_chunked_plan_equals_one_by_one_bit_for_bit(dims):
    """plan() (chunked, vectorised checks, the no-candidate proof) returns exactly the trajectory of the reference
    that builds and checks the candidates one at a time, on clear, partly blocked and fully blocked views."""
    ctx = _context(dims)
    rng = np.random.default_rng(5)
    planner = LocalPrimitives(ctx, sphere_spacing_deg=30.0)
    outcomes = {"first": 0, "later": 0, "none": 0, "proven": 0}
    for view in _random_views(ctx, rng, 150 if dims == 2 else 80):
        got = planner.plan(view)
        tried, rank = planner.last_candidates_tried, planner.last_rank
        proven = planner.none_can_be_clear(view)
        ref = planner.plan_reference(view)
        assert (got is None) == (ref is None)
        if ref is None:
            outcomes["proven" if proven else "none"] += 1
            continue
        assert not proven                         # the proof never fires where a candidate is clear
        for x, y in ((got.p, ref.p), (got.v, ref.v), (got.a, ref.a)):
            assert np.array_equal(x, y)
        assert (tried, rank) == (planner.last_candidates_tried, planner.last_rank)
        outcomes["first" if rank == 0 else "later"] += 1
    assert all(n > 0 for n in outcomes.values()), outcomes


def test_local_primitives_proof_of_no_candidate():
    """An obstacle predicted on top of the MAV's next position: no primitive can be clear, proven once the best
    candidate has failed, without building another; the same obstacle 2 m further away proves nothing (and a
    candidate is found)."""
    ctx = _context()
    planner = LocalPrimitives(ctx)
    v = np.array([3.0, 0.0])
    near = make_tracks(np.array([[26.0, 25.0]]), np.zeros((1, 2)), 1.0)
    view = _view(ctx, [25.0, 25.0], [45.0, 25.0], v, tracks=near)
    assert planner.none_can_be_clear(view)
    assert planner.plan(view) is None and planner.last_candidates_tried == 1
    assert planner.last_candidates_built <= 1 + 3                         # the best one (and its rebuilds) only
    assert planner.plan_reference(view) is None and planner.last_candidates_built > 0
    far = make_tracks(np.array([[25.0, 30.0]]), np.zeros((1, 2)), 1.0)
    view = _view(ctx, [25.0, 25.0], [45.0, 25.0], v, tracks=far)
    assert not planner.none_can_be_clear(view)
    assert planner.plan(view) is not None
    wall = _view(ctx, [1.05, 25.0], [45.0, 25.0], np.array([-2.0, 0.0]))   # flying into the wall at 2 m/s
    assert planner.none_can_be_clear(wall) and planner.plan_reference(wall) is None


@pytest.mark.parametrize("dims", [2, 3])
def test_local_primitives_compiled_proof_decides_as_numpy(dims):
    """none_can_be_clear (compiled) and its numpy evaluation agree on random views, and on views whose obstacle or
    wall lies just inside and just outside the proof's reach (the decisive comparisons on their bounds)."""
    ctx = _context(dims)
    planner = LocalPrimitives(ctx)
    rng = np.random.default_rng(23)
    fired = 0
    for view in _random_views(ctx, rng, 300):
        got = planner.none_can_be_clear(view)
        assert got == planner._none_can_be_clear_reference(view)
        fired += got
    assert 0 < fired < 300
    # an obstacle straight ahead at the decisive distance of sample 1 (gap + ball = reach), nudged both ways
    dt, a_max = DT, ctx.limits.a_max + 1e-9
    ball = a_max * dt * dt * 0.75 + 1e-6
    v = np.zeros(dims)
    v[0] = 2.0
    p = np.full(dims, 10.0)
    for radius in (0.5, 1.0):
        reach = radius + ctx.limits.radius + planner.margin
        for nudge in (-1e-9, 0.0, 1e-9):
            centre = p + v * dt
            centre[0] += reach - ball + nudge
            tracks = make_tracks(centre[None], np.zeros((1, dims)), radius)
            view = _view(ctx, p, np.full(dims, 30.0), v, tracks=tracks)
            assert planner.none_can_be_clear(view) == planner._none_can_be_clear_reference(view)


def goal_angles_reference(directions, to_goal):
    """The reference twin of goal_angles_argmin's angles (rad): numpy's np.round(np.arccos(np.clip(cos, -1, 1)), 12)
    of the cosines between unit ``directions`` [n, d] and ``to_goal`` [d]."""
    x = directions @ (to_goal / math.sqrt(float(to_goal @ to_goal)))
    return np.round(np.arccos(np.clip(x, -1.0, 1.0)), 12)


@pytest.mark.parametrize("dims", [2, 3])
def test_goal_angles_are_numpys_rounded_arccos_of_the_clipped_cosines(dims):
    """goal_angles computes np.round(np.arccos(np.clip(cos, -1, 1)), 12) in place: the same floats, including the
    clip's edges, exact ties after rounding and directions straight at or away from the goal."""
    from pbdyn.planning.primitives.local import candidate_directions, goal_angles, goal_angles_argmin

    rng = np.random.default_rng(7)
    dirs = candidate_directions(dims, 72, 15.0)
    goals = [rng.normal(size=dims) * 10.0 ** rng.integers(-6, 3) for _ in range(3000)]
    goals += [dirs[5] * 3.0, -dirs[9] * 0.5, dirs[0] + 1e-15, np.zeros(dims) + 1e-9]
    goals += [np.full(dims, np.nan)]
    for g in goals:
        got = goal_angles(dirs, g)
        want = goal_angles_reference(dirs, g)
        assert np.array_equal(got, want, equal_nan=True)
        angles, i = goal_angles_argmin(dirs, g)
        assert np.array_equal(angles, want, equal_nan=True) and i == int(np.argmin(want))
    ties = dirs.copy()
    ties[[3, 40]] = ties[[40, 3]]                         # equal angles: the first index wins, as in np.argmin
    g = dirs[3] + dirs[40]
    assert goal_angles_argmin(ties, g)[1] == int(np.argmin(goal_angles(ties, g)))
    assert goal_angles(dirs, np.zeros(dims)) is None and goal_angles_argmin(dirs, np.zeros(dims)) is None


def test_clip_rate_is_numpys_clip_of_a_float():
    """The gaze planners' scalar clip gives np.clip's value bit for bit, signed zeros, limits and NaN included."""
    from pbdyn.planning.gaze.yaw import clip_rate

    rng = np.random.default_rng(3)
    values = list(rng.normal(size=2000) * 3.0) + [0.0, -0.0, 1.4, -1.4, 1.4 + 1e-16, math.inf, -math.inf, math.nan]
    for limit in (1.4, 0.5, 1e-300):
        for x in values:
            want = float(np.clip(x, -limit, limit))
            got = clip_rate(float(x), limit)
            assert type(got) is float
            assert (math.isnan(want) and math.isnan(got)) or (got == want and math.copysign(1, got) ==
                                                               math.copysign(1, want))


def test_the_environments_views_equal_views_built_field_by_field():
    """TrialState.view (View.of_owned: no dataclass __init__, shared read-only goal and bounds) gives what View(...)
    gives for the same values: every field equal, arrays read-only, and the state arrays copies of the env's."""
    import dataclasses

    from pbdyn.sim.batch import TrialBatch
    from pbdyn.sim.spec import make_trial_spec
    from tests.helpers import first_map, handmade_rollout, open_scenario

    sc = open_scenario(obstacles={"count": 1})
    batch = TrialBatch([make_trial_spec(sc, first_map(sc), start=(4.0, 4.0), goal=(46.0, 40.0))],
                       handmade_rollout(sc, [[20.0, 20.0]], [[0.0, 1.0]], [1.0]))
    batch.start()
    env = batch.states[0]
    traj = Trajectory(0.0, env.dt, np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)))
    got = env.view(traj)
    sensor = sc.sensor
    want = View(env.t, env.dt, env.position, env.velocity, env.acceleration, env.yaw, env.goal, env.goal_radius,
                env.limits, env.bounds[0], env.bounds[1], env.grid, env.tracks, traj, env.fov_deg, sensor.range,
                sensor.vfov_deg)
    assert type(got) is View and got.extras == {} and got.extras is not env.view().extras
    for f in dataclasses.fields(View):
        a, b = getattr(got, f.name), getattr(want, f.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b) and not a.flags.writeable
        else:
            assert a is b or a == b, f.name
    assert not np.shares_memory(got.position, env.position) and not np.shares_memory(got.goal, env.goal)
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.t = 1.0
    batch.close()


def test_trajectory_of_owned_equals_the_checked_constructor():
    """Trajectory.of_owned (planners' fresh samples made read-only in place) gives what Trajectory(...) gives."""
    rng = np.random.default_rng(5)
    p, v, a = (rng.normal(size=(7, 2)) for _ in range(3))
    got = Trajectory.of_owned(0.3, DT, p.copy(), v.copy(), a.copy())
    want = Trajectory(0.3, DT, p, v, a)
    assert type(got) is Trajectory and (got.t0, got.dt) == (want.t0, want.dt)
    for name in ("p", "v", "a"):
        x, y = getattr(got, name), getattr(want, name)
        assert x.dtype == y.dtype and np.array_equal(x, y) and not x.flags.writeable
    assert got.state_at(0.5)[0].tolist() == want.state_at(0.5)[0].tolist() and got.t_end == want.t_end
