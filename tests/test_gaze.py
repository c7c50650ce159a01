"""Gaze planners (thesis 4-1-2): limits, determinism, behaviour on hand-made Views, and real trials with every
trajectory planner in 2D and 3D; limited FOV matters on side-crossing scenarios."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.perception.grid import FREE, UNKNOWN, OccupancyGrid
from pbdyn.perception.sensor import in_fov
from pbdyn.planning import registry
from pbdyn.planning.gaze.finean import Finean
from pbdyn.planning.gaze.owl import Owl
from pbdyn.planning.gaze.rules import LookGoal, LookGoalUnexplored
from pbdyn.planning.gaze.yaw import rate_candidates
from pbdyn.planning.protocols import GazePlanner, PlannerContext
from pbdyn.planning.straight_line import StraightLine
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import MAVLimits, Tracks, View
from pbdyn.sim.trial import make_trial_spec, run_trial
from pbdyn.world.rollout import build_rollout
from tests.conftest import pbdyn_cmd
from tests.helpers import first_map, fly, handmade_rollout, open_scenario

DT = 0.1
LIMIT = 1.4
GAZES = ("fullrange", "lookahead", "lookgoal", "lookgoal_unexplored", "rotating", "finean", "owl")


def _context(dims=2, v_max=4.0):
    hi = np.array([50.0, 50.0, 20.0][:dims])
    return PlannerContext(dims, DT, MAVLimits(1.0, v_max, 4.0, LIMIT), np.zeros(dims), hi)


def _view(ctx, p, goal, *, yaw=0.0, v=None, t=0.0, grid=None, tracks=None, trajectory=None):
    d = ctx.dims
    if grid is None:
        grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    return View(t=t, dt=DT, position=np.asarray(p, float), velocity=np.zeros(d) if v is None else np.asarray(v, float),
                acceleration=np.zeros(d), yaw=yaw, goal=np.asarray(goal, float), goal_radius=1.0, limits=ctx.limits,
                bounds_lo=ctx.bounds_lo, bounds_hi=ctx.bounds_hi, grid=grid,
                tracks=Tracks.empty(d) if tracks is None else tracks, trajectory=trajectory, fov_deg=90.0,
                range_m=8.0, vfov_deg=60.0 if d == 3 else None)


def _tracks(pos, vel, radius=1.0):
    pos = np.atleast_2d(np.asarray(pos, float))
    m, d = pos.shape
    return Tracks(np.arange(m), pos, np.atleast_2d(np.asarray(vel, float)), np.zeros((m, 2 * d, 2 * d)),
                  np.full(m, radius))


def _line(p0, direction, speed, t0, seconds, hold=0):
    """A Trajectory from p0 along unit ``direction`` at ``speed`` m/s for ``seconds``, after ``hold`` samples at p0."""
    k = np.maximum(np.arange(int(round(seconds / DT)) + 1) - hold, 0)[:, None]
    v = np.asarray(direction, float) * speed
    p = np.asarray(p0, float) + k * DT * v
    return Trajectory(t0, DT, p, np.broadcast_to(v, p.shape), np.zeros_like(p))


def _view_sequence(dims, n=40, seed=5):
    """Deterministic (view, trajectory) pairs of a MAV flying StraightLine plans among moving tracks."""
    rng = np.random.default_rng(seed)
    ctx = _context(dims)
    grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    grid.cells[(slice(5, 20),) * dims] = FREE
    planner = StraightLine(ctx, horizon_s=2.0)
    p = np.array([6.0, 8.0, 10.0][:dims])
    goal = np.array([40.0, 30.0, 12.0][:dims])
    v = np.zeros(dims)
    yaw = 0.3
    out = []
    for k in range(n):
        m = int(rng.integers(0, 4))
        tracks = _tracks(p + rng.uniform(-8, 8, (m, dims)), rng.uniform(-5, 5, (m, dims))) if m else None
        view = _view(ctx, p, goal, yaw=yaw, v=v, t=k * DT, grid=grid, tracks=tracks)
        traj = None if k % 7 == 6 else planner.plan(view)
        out.append((view, traj))
        if traj is not None:
            p, v = traj.p[1].copy(), traj.v[1].copy()
        yaw = float(rng.uniform(-math.pi, math.pi)) if k % 5 == 0 else yaw + 0.1
    return ctx, out


# ---------------------------------------------------------------- registry, limits, determinism

def test_registry_names_and_parameter_errors():
    for name in GAZES:
        cls = registry.resolve_gaze_planner(name)
        assert isinstance(registry.build_planner(cls, _context(), {}, "gaze_params"), GazePlanner)
    for name, params, field in (("rotating", {"rate_fraction": 1.5}, "gaze_params"),
                                ("finean", {"n_rates": 1}, "gaze_params"),
                                ("finean", {"tau_s": -1.0}, "gaze_params"),
                                ("owl", {"bin_deg": 7.0}, "gaze_params"),
                                ("owl", {"lambda_9": 1.0}, "gaze_params.lambda_9")):
        with pytest.raises(ConfigError) as err:
            registry.build_planner(registry.resolve_gaze_planner(name), _context(), params, "gaze_params")
        assert err.value.field == field


def test_rate_candidates_include_both_limits_and_zero():
    r = rate_candidates(LIMIT, 7)
    assert r[0] == -LIMIT and r[-1] == LIMIT and 0.0 in r and r.shape == (7,)
    assert rate_candidates(LIMIT, 6).shape == (7,) and 0.0 in rate_candidates(LIMIT, 6)
    owl = rate_candidates(LIMIT, 20, include_zero=False)
    assert owl.shape == (20,) and owl[0] == -LIMIT and owl[-1] == LIMIT


@pytest.mark.parametrize("dims", [2, 3])
def test_every_gaze_respects_the_rate_limit_and_is_deterministic(dims):
    ctx, seq = _view_sequence(dims)
    for name in GAZES:
        cls = registry.resolve_gaze_planner(name)
        runs = []
        for _ in range(2):
            gaze = cls(ctx)
            runs.append([gaze.yaw_rate(view, traj) for view, traj in seq])
        rates = np.asarray(runs[0])
        assert np.all(np.abs(rates) <= LIMIT), name            # raw output, before the trial's clip
        assert runs[0] == runs[1], name
        if name not in ("fullrange", "rotating"):
            assert np.unique(rates).shape[0] > 1, name          # it reacts to the views


# ---------------------------------------------------------------- full trials with every trajectory planner

@pytest.fixture(scope="module")
def worlds():
    out = {}
    for dims in (2, 3):
        sc = open_scenario(dims, world={"dims": dims, "time_limit": 6.0},
                           obstacles={"count": 8, "radius": 1.0, "speed": 3.0, "root_seed": 4})
        out[dims] = (sc, build_rollout(sc, first_map(sc)))
    return out


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("trajectory", sorted(registry.TRAJECTORY_PLANNERS))
@pytest.mark.parametrize("gaze", GAZES)
def test_every_gaze_flies_with_every_trajectory_planner(worlds, tmp_path, gaze, trajectory, dims):
    sc, rollout = worlds[dims]
    z0 = (10.0,) if dims == 3 else ()
    spec = make_trial_spec(sc, first_map(sc), planner=trajectory, gaze=gaze, start=(4.0, 25.0) + z0,
                           goal=(30.0, 25.0) + z0)
    assert spec.planner.gaze == gaze and spec.planner.trajectory == trajectory
    path = tmp_path / "trace.npz"
    res = run_trial(spec, rollout, trace_path=path)
    assert res.gaze == gaze and res.planner == trajectory and res.steps >= 10
    assert res.outcome in ("success", "dynamic_collision", "static_collision", "freezing", "deadlock")
    with np.load(path) as z:
        rate, yaw = z["yaw_rate"], np.append(z["yaw"], z["final_yaw"])
    assert np.all(np.abs(rate) <= LIMIT + 1e-12)
    step = (np.diff(yaw) - rate * DT + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(step, 0.0, atol=1e-9)             # the executed yaw followed the planner's rate
    if gaze == "rotating":
        np.testing.assert_allclose(rate, LIMIT)


def test_cli_runs_the_new_gazes_in_2d_and_3d(write_scenario):
    import subprocess

    for dims, gaze in ((2, "finean"), (3, "owl")):
        text = f"[world]\ndims = {dims}\ntime_limit = 4.0\n[obstacles]\ncount = 5\n[drone]\nv_max = [4.0]\n"
        path = write_scenario(text, f"s{dims}.toml")
        proc = subprocess.run(pbdyn_cmd() + ["run", str(path), "--gaze", gaze, "--json"], capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        doc = json.loads(proc.stdout)
        assert doc["gaze"] == gaze and len(doc["start"]) == dims and doc["steps"] >= 10


# ---------------------------------------------------------------- LookGoal, Rotating

def test_lookgoal_turns_toward_the_goal_the_shortest_way():
    for dims in (2, 3):
        ctx = _context(dims)
        gaze = LookGoal(ctx)
        p = np.array([25.0, 25.0, 10.0][:dims])
        for bearing_deg, expect in ((30, LIMIT), (170, LIMIT), (-170, -LIMIT), (-30, -LIMIT),
                                    (5, math.radians(5) / DT), (-5, -math.radians(5) / DT), (0, 0.0)):
            b = math.radians(bearing_deg + 40)
            goal = p.copy()
            goal[:2] += 10.0 * np.array([math.cos(b), math.sin(b)])
            if dims == 3:
                goal[2] += 5.0                                   # the height difference does not matter
            rate = gaze.yaw_rate(_view(ctx, p, goal, yaw=math.radians(40), v=np.ones(dims)), None)
            assert rate == pytest.approx(expect, abs=1e-9), (dims, bearing_deg)


def test_lookgoal_unexplored_faces_the_first_unknown_plan_sample_else_the_plan_end():
    ctx = _context()
    grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    grid.cells[1:-1, 1:-1] = FREE
    grid.cells[:, 28:] = UNKNOWN                                  # y >= 27 m unexplored
    gaze = LookGoalUnexplored(ctx)
    traj = _line([20.0, 20.0], [0.0, 1.0], 4.0, 0.0, 3.0)        # north 12 m: first unknown sample at y = 27.2
    view = _view(ctx, [20.0, 20.0], [20.0, 5.0], yaw=0.0, grid=grid)
    # the plan's first unknown sample is straight north (+90 deg): turn left at the limit
    assert gaze.yaw_rate(view, traj) == LIMIT
    off = _line([20.0, 20.0], [math.cos(0.05), math.sin(0.05)], 4.0, 0.0, 2.0)  # all explored: face its end
    assert gaze.yaw_rate(view, off) == pytest.approx(math.atan2(off.p[-1, 1] - 20, off.p[-1, 0] - 20) / DT)
    # no plan: the goal (south, -90 deg): turn right
    assert gaze.yaw_rate(view, None) == -LIMIT


def test_rotating_sweeps_360_degrees_in_2pi_over_limit_seconds(tmp_path):
    limit = 2.0
    sc = open_scenario(2, drone={"v_max": 4.0, "yaw_rate_limit": limit},
                       planners=[{"trajectory": "local_primitives", "gaze": "rotating"}])
    rollout = build_rollout(sc, first_map(sc))
    path = tmp_path / "rot.npz"
    fly(sc, rollout, "rotating+local_primitives", (4.0, 25.0), (46.0, 25.0), trace_path=path)
    with np.load(path) as z:
        turned = np.unwrap(z["yaw"]) - z["yaw"][0]
    n = math.ceil(2 * math.pi / limit / DT - 1e-9)               # steps for a full turn
    assert turned[n] >= 2 * math.pi - 1e-9 and turned[n - 1] < 2 * math.pi
    np.testing.assert_allclose(np.diff(turned), limit * DT, atol=1e-12)


# ---------------------------------------------------------------- Finean et al.

@pytest.mark.parametrize("dims", [2, 3])
def test_finean_age_map_and_future_occupancy_match_brute_force(dims):
    ctx = _context(dims)
    gaze = Finean(ctx)
    grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in grid.shape], indexing="ij"), -1).reshape(-1, dims)
    centres = grid.cell_center(idx)
    poses = [([6.0, 30.0, 10.0], 0.0), ([9.0, 31.0, 10.5], 2.0), ([20.0, 20.0, 9.0], -2.5), ([21.0, 21.0, 9.0], 0.7)]
    last = np.full(centres.shape[0], -5.0)
    for k, (p, yaw) in enumerate(poses):
        p = np.asarray(p[:dims])
        gaze.yaw_rate(_view(ctx, p, p + 5.0, yaw=yaw, t=k * DT, grid=grid), None)
        last[in_fov(yaw, centres - p, 90.0, 8.0, 60.0 if dims == 3 else None)] = k * DT
    t = (len(poses) - 1) * DT
    np.testing.assert_allclose(gaze.age_map(t).reshape(-1), t - last, atol=1e-12)
    assert np.isclose(gaze.age_map(t), 5.0 + t).sum() > 0.9 * centres.shape[0]
    # future occupancy: the earliest time ahead (> 0) a plan sample is within MAV radius + res/2 of a cell centre
    p = np.asarray([20.0, 20.0, 9.0][:dims])
    direction = np.array([0.6, 0.8, 0.0][:dims])
    traj = _line(p, direction, 4.0, t, 4.0)
    cells, taus = gaze.future_cells(_view(ctx, p, p + 5.0, t=t, grid=grid), traj)
    dist = np.linalg.norm(centres[:, None, :] - traj.p[None, 1:, :], axis=-1)      # [cells, samples after t]
    hit = dist <= 1.5
    expect = np.where(hit.any(1), (np.argmax(hit, axis=1) + 1) * DT, 0.0)
    got = np.zeros(centres.shape[0])
    got[cells] = taus
    np.testing.assert_allclose(got, expect, atol=1e-9)
    assert taus.min() == pytest.approx(DT) and taus.max() > 3.0   # both the c1 and the c2 bands exist


def test_finean_reward_follows_eq_4_6_with_the_programs_otherwise_rule():
    gaze = Finean(_context())
    age = np.array([1.0, 1.0, 0.2, 0.2, 3.0, 0.3, 0.5])
    future = np.array([1.0, 4.0, 1.0, 4.0, 0.0, 0.0, 3.0])
    np.testing.assert_allclose(gaze.rewards(age, future), [1e6, 1e3, 0.2, 0.2, 1.0, 0.3, 1e6])


def _finean_after_looking(ctx, grid, looks):
    """A Finean instance that looked along yaw ``looks[k]`` at t = k * 0.1 s from (25.5, 25.5)."""
    gaze = Finean(ctx)
    p = np.array([25.5, 25.5])                                    # a cell centre: the grid is symmetric about y
    for k, yaw in enumerate(looks):
        gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=yaw, t=k * DT, grid=grid), None)
    return gaze, p


def test_finean_turns_toward_the_stale_region_the_plan_enters_soon():
    ctx = _context()
    grid = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    left, right = math.radians(49), math.radians(-49)   # just outside the 45 deg half-FOV
    for path_side, fresh_side, expect_sign in ((left, None, 1), (right, None, -1), (left, right, 1),
                                               (right, left, -1)):
        looks = [0.0] * 5 if fresh_side is None else [fresh_side] * 5 + [0.0] * 5
        gaze, p = _finean_after_looking(ctx, grid, looks)
        t = len(looks) * DT
        # the plan enters that side within 2.5 s; it hovers for its first step, so both next views share one origin
        plan = _line(p, [math.cos(path_side), math.sin(path_side)], 3.0, t, 2.5, hold=1)
        rate = gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=0.0, t=t, grid=grid), plan)
        assert np.sign(rate) == expect_sign and abs(rate) == LIMIT, (path_side, fresh_side)
    # the plan enters a region seen 0.1 s ago (age < tau_c): the stale side without the plan wins
    looks = [0.0] * 5 + [right] * 8
    t = len(looks) * DT
    gaze, p = _finean_after_looking(ctx, grid, looks)
    plan = _line(p, [math.cos(right), math.sin(right)], 3.0, t, 2.5, hold=1)
    assert gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=0.0, t=t, grid=grid), plan) == LIMIT
    # without a plan, too, the never-seen left beats the right seen at 0.5-1.2 s
    assert gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=0.0, t=t + DT, grid=grid), None) == LIMIT


# ---------------------------------------------------------------- Owl

def test_owl_turns_toward_a_fast_closing_track_outside_the_fov():
    ctx = _context()
    p = np.array([25.0, 25.0])
    for side in (1, -1):
        gaze = Owl(ctx)
        # 6 m to the side, closing at 6 m/s; the goal is straight ahead and the MAV hovers
        tracks = _tracks([[25.0, 25.0 + side * 6.0]], [[0.0, -side * 6.0]])
        rate = gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=0.0, tracks=tracks), None)
        assert np.sign(rate) == side and abs(rate) >= 0.8
        # after holding the rate for the period, the track is inside the FOV
        assert in_fov(rate * gaze.period_s, tracks.position - p, 90.0, 8.0)[0]
    # the same track already inside the FOV, or with w_obstacle = 0, does not pull the gaze
    inside = _tracks([[31.0, 27.0]], [[-6.0, -2.0]])
    assert abs(Owl(ctx).yaw_rate(_view(ctx, p, [45.0, 25.0], tracks=inside), None)) < 0.1
    off = Owl(ctx, w_obstacle=0.0)
    assert abs(off.yaw_rate(_view(ctx, p, [45.0, 25.0], tracks=_tracks([[25.0, 31.0]], [[0.0, -6.0]])),
                            None)) < 0.1
    # while the MAV flies at 4 m/s, the velocity term (0.9 * 16 per rad) outweighs the same track
    fast = Owl(ctx)
    rate = fast.yaw_rate(_view(ctx, p, [45.0, 25.0], v=[4.0, 0.0], tracks=_tracks([[25.0, 31.0]], [[0.0, -6.0]])),
                         None)
    assert abs(rate) < 0.1


def test_owl_pairs_each_track_with_its_own_state_and_holds_its_decision():
    ctx = _context()
    p = np.array([25.0, 25.0])
    pos = [[25.0, 31.0], [25.0, 19.0]]                            # left and right, both outside the FOV
    # one track closes fast, the other moves sideways (no threat); swapped states would threaten nothing
    closing_left = _tracks(pos, [[0.0, -6.0], [-6.0, 0.0]])
    closing_right = _tracks(pos, [[6.0, 0.0], [0.0, 6.0]])
    assert Owl(ctx).yaw_rate(_view(ctx, p, [45.0, 25.0], tracks=closing_left), None) > 0.5
    assert Owl(ctx).yaw_rate(_view(ctx, p, [45.0, 25.0], tracks=closing_right), None) < -0.5
    gaze = Owl(ctx)
    first = gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], tracks=closing_left), None)
    yaw = 0.0
    for k in range(1, 8):                                         # held until 0.8 s, whatever the views say
        yaw += first * DT
        assert gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=yaw, t=k * DT, tracks=closing_right), None) == first
    assert gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=yaw, t=0.8, tracks=closing_right), None) < 0


def test_owl_looks_at_directions_not_seen_recently():
    ctx = _context()
    gaze = Owl(ctx, w_goal=0.0)
    p = np.array([25.0, 25.0])
    # having looked left (+90 deg) at t = 0, the right side is the stale one when nothing else matters
    gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=math.pi / 2, t=0.0), None)
    rate = gaze.yaw_rate(_view(ctx, p, [45.0, 25.0], yaw=0.0, t=0.8), None)
    assert rate < -0.5


def _program_g(theta_deg, half=45.0):
    """The program's Owl angle cost G (rad^2), written out for the tests."""
    def between(a, b):
        d = abs((a % 360.0) - (b % 360.0))
        return min(d, 360.0 - d)
    if between(theta_deg, 0.0) <= half:
        return 0.0
    return math.radians(between(theta_deg, half)) * math.radians(between(theta_deg, -half))


def test_owl_program_costs_rates_and_hold_as_the_program_had_them():
    ctx = _context()
    gaze = Owl(ctx, **Owl.PROGRAM_PARAMS)
    # the program's 20 rates: +limit first, 0 among them, -limit missing
    assert gaze.rates[0] == LIMIT and 0.0 in gaze.rates and -LIMIT not in gaze.rates and len(gaze.rates) == 20
    assert gaze.hold_steps == 8
    p = np.array([25.0, 25.0])
    # at rest every program cost was NaN and its argmin took the first candidate; held for 8 steps
    assert gaze.yaw_rate(_view(ctx, p, [25.0, 45.0]), None) == LIMIT
    for k in range(1, 8):
        assert gaze.yaw_rate(_view(ctx, p, [25.0, 45.0], v=[1.0, 0.0], t=k * DT), None) == LIMIT
    # the 9th call decides again: moving along +x at 1 m/s with the goal to the left (+y)
    fresh = Owl(ctx, **Owl.PROGRAM_PARAMS)
    cost = fresh.program_costs(_view(ctx, p, [25.0, 45.0], v=[1.0, 0.0]))
    # beliefs after one update: bin 0 deg (in view) 0.4 - 1 m/s * 0.8 s / 8 m = 0.3; bin 90 deg -0.05 -> 0
    assert fresh.belief[0] == pytest.approx(0.3) and fresh.belief[9] == 0.0
    for i in (0, 5, 10, 19):
        psi = math.degrees(gaze.rates[i] * 0.8)
        nearest = int(np.argmin([min(abs(c - psi % 360.0), 360.0 - abs(c - psi % 360.0))
                                 for c in np.arange(36) * 10.0]))
        expected = (0.2 * _program_g(psi - 90.0) * (1.0 - 0.0) + 0.9 * 1.0 * _program_g(psi) * (1.0 - 0.3)
                    + 0.1 * fresh.belief[nearest])
        assert cost[i] == pytest.approx(expected, rel=1e-12, abs=1e-12)
    # G by hand: 90 deg off a 90-degree FOV is 45 deg x 135 deg
    assert _program_g(90.0) == pytest.approx(math.radians(45) * math.radians(135))


def test_owl_program_pairs_directions_with_the_wrong_tracks_as_the_program_did():
    ctx = _context()
    p = np.array([25.0, 25.0])
    # obstacle 1 at the left, closing fast; obstacle 2 at the right, still; obstacle 0 not tracked. The program
    # weighted the k-th active direction by tracker k: the left one by obstacle 0 (inactive: 0), the right one by
    # obstacle 1 (6 m/s at 6 m: 1/s), so it turns right; pbdyn's own Owl turns left, toward the closing track.
    tracks = Tracks(np.array([1, 2]), np.array([[25.0, 31.0], [25.0, 19.0]]), np.array([[0.0, -6.0], [0.0, 0.0]]),
                    np.zeros((2, 4, 4)), np.ones(2))
    view = _view(ctx, p, [45.0, 25.0], v=[1.0, 0.0], tracks=tracks)
    assert Owl(ctx, **Owl.PROGRAM_PARAMS).yaw_rate(view, None) < -0.5
    assert Owl(ctx).yaw_rate(view, None) > 0.5
    # with obstacle 0 tracked too, every direction is paired with the track before it in id order
    both = Tracks(np.array([0, 1]), np.array([[25.0, 31.0], [25.0, 19.0]]), np.array([[0.0, -6.0], [0.0, 0.0]]),
                  np.zeros((2, 4, 4)), np.ones(2))
    assert Owl(ctx, **Owl.PROGRAM_PARAMS).yaw_rate(_view(ctx, p, [45.0, 25.0], v=[1.0, 0.0], tracks=both),
                                                   None) > 0.5


def test_owl_program_rejects_bad_costs_and_odd_rates():
    with pytest.raises(ValueError, match="costs"):
        Owl(_context(), costs="exact")
    with pytest.raises(ValueError, match="n_rates"):
        Owl(_context(), costs="program", n_rates=7)


# ---------------------------------------------------------------- limited FOV matters

FOV_PLANNERS = [{"trajectory": "local_primitives", "gaze": g} for g in ("fullrange", "lookahead", "rotating")] + [
    {"trajectory": "local_primitives", "gaze": "rotating", "gaze_params": {"rate_fraction": 0.0}, "name": "fixed"}]


def _crossing(sc, side, speed, x_cross, radius):
    """One obstacle crossing y = 25 perpendicularly at x_cross about when a MAV flying from (4, 25) gets there."""
    t_arrive = (x_cross - 4.0) / 4.0 + 0.5
    v = np.array([0.0, side * speed])
    return handmade_rollout(sc, [np.array([x_cross, 25.0]) - v * t_arrive], [v], [radius])


def test_fullrange_avoids_a_side_crossing_that_a_fixed_gaze_sees_too_late(tmp_path):
    sc = open_scenario(2, planners=FOV_PLANNERS)
    rollout = _crossing(sc, 1, 6.0, 25.0, 0.5)                   # closes from ~56 deg off the path: outside 45
    first_seen = {}
    for label in ("fullrange+local_primitives", "fixed"):
        res = fly(sc, rollout, label, (4.0, 25.0), (46.0, 25.0), trace_path=tmp_path / f"{label}.npz")
        with np.load(tmp_path / f"{label}.npz") as z:
            first_seen[label] = (res, int(np.argmax(z["seen"][:, 0])), bool(z["seen"][:, 0].any()))
    full, full_seen, full_any = first_seen["fullrange+local_primitives"]
    fixed, fixed_seen, fixed_any = first_seen["fixed"]
    assert full.outcome == "success" and full_any
    assert fixed.outcome == "dynamic_collision"
    assert not fixed_any or (fixed_seen > full_seen and fixed.steps - fixed_seen <= 5)  # within 0.5 s of impact


def test_lookahead_does_at_least_as_well_as_rotating_on_side_crossings():
    sc = open_scenario(2, planners=FOV_PLANNERS)
    wins = {"lookahead+local_primitives": 0, "rotating+local_primitives": 0}
    for side in (1, -1):
        for speed, x_cross in ((3.0, 20.0), (5.0, 30.0)):
            rollout = _crossing(sc, side, speed, x_cross, 1.0)
            for label in wins:
                wins[label] += fly(sc, rollout, label, (4.0, 25.0), (46.0, 25.0)).outcome == "success"
    assert wins["lookahead+local_primitives"] >= wins["rotating+local_primitives"]
    assert wins["lookahead+local_primitives"] >= 3
