"""The thesis program's local primitives ("local_primitives_minjerk"): the minimum-jerk polynomial, the duration
and end-velocity rules, the rank order and the first-clear choice, the two profiles' limits, real trials."""

import math
from dataclasses import replace

import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.perception.grid import OCCUPIED
from pbdyn.planning import registry
from pbdyn.planning.checks import batch_conflicts, grid_conflicts, program_grid_conflicts, trajectory_clear
from pbdyn.planning.primitives.minjerk import (LocalPrimitivesMinJerk, min_jerk_coefficients,
                                                     min_jerk_matrix, min_jerk_states, program_duration,
                                                     program_sample_counts)
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import Tracks
from pbdyn.sim.contract import plan_violations
from tests.helpers import first_map, handmade_rollout, make_tracks, open_scenario
from tests.test_planners import DT, _context, _grid, _view


def _ctx(dims=2, v_max=4.0, physical=False):
    return replace(_context(dims=dims, v_max=v_max), physical=physical)


def _state(rng, d, v_max, a_max):
    v = rng.normal(size=d)
    v *= rng.uniform(0.0, v_max) / np.linalg.norm(v)
    a = rng.normal(size=d)
    a *= rng.uniform(0.0, a_max) / np.linalg.norm(a)
    return v, a


# ---------------------------------------------------------------- the polynomial

def test_min_jerk_polynomial_meets_the_boundary_conditions_and_the_quintic_solve():
    rng = np.random.default_rng(1)
    for _ in range(20):
        t = rng.uniform(0.3, 5.0)
        start = tuple(rng.normal(scale=3.0, size=3) for _ in range(3))
        end = tuple(rng.normal(scale=3.0, size=3) for _ in range(3))
        p, v, a = min_jerk_states(t, start, end, np.array([0.0, t]))
        for got, want in ((p, (start[0], end[0])), (v, (start[1], end[1])), (a, (start[2], end[2]))):
            np.testing.assert_allclose(got, np.stack(want), atol=1e-9, rtol=0)
        # the same quintic from the six boundary equations (monomial basis c0..c5, per axis)
        rows = []
        for tt in (0.0, t):
            rows += [[tt ** k for k in range(6)], [k * tt ** (k - 1) if k else 0.0 for k in range(6)],
                     [k * (k - 1) * tt ** (k - 2) if k > 1 else 0.0 for k in range(6)]]
        rhs = np.stack([start[0], start[1], start[2], end[0], end[1], end[2]])
        mono = np.linalg.solve(np.array(rows), rhs)                            # [6, 3]
        alpha, beta, gamma = min_jerk_coefficients(t, start, end)
        np.testing.assert_allclose([alpha / 120, beta / 24, gamma / 6], mono[[5, 4, 3]], rtol=1e-8, atol=1e-9)


def test_min_jerk_polynomial_has_the_least_jerk_integral_and_the_papers_matrix():
    t = 1.3
    start, end = (0.2, -1.0, 0.5), (3.0, 2.0, 0.0)
    alpha, beta, gamma = min_jerk_coefficients(t, start, end)
    ts = np.linspace(0.0, t, 4001)
    jerk = alpha * ts ** 2 / 2 + beta * ts + gamma
    base = np.trapezoid(jerk ** 2, ts)
    # s(t) = eps t^3 (T - t)^3 keeps p, v, a at both ends; its third derivative adds to the jerk
    bump = np.polynomial.Polynomial([0, 0, 0, 1]) * np.polynomial.Polynomial([t, -1]) ** 3
    bump_jerk = bump.deriv(3)(ts)
    for eps in (1e-3, -1e-2, 0.1, -1.0):
        assert np.trapezoid((jerk + eps * bump_jerk) ** 2, ts) > base
    # the closed form of Mueller, Hehn & D'Andrea (2015), written out for T = 1
    np.testing.assert_allclose(min_jerk_matrix(1.0), [[720, -360, 60], [-360, 168, -24], [60, -24, 3]])
    np.testing.assert_allclose(min_jerk_matrix(2.0), np.array([[720, -720, 240], [-720, 672, -192],
                                                                [240, -192, 48]]) / 32.0)


@pytest.mark.parametrize("v_max, duration", [(2.0, 1.8), (4.0, 0.9), (6.0, 0.6), (12.0, 0.5), (0.05, 72.0)])
def test_duration_rule(v_max, duration):
    assert program_duration(3.0, v_max) == pytest.approx(duration)
    ctx = _ctx(v_max=v_max)
    planner = LocalPrimitivesMinJerk(ctx)
    assert planner.duration == pytest.approx(duration)
    tr = planner.plan(_view(ctx, [25.0, 25.0], [45.0, 25.0]))
    assert tr is not None and tr.n_samples == math.ceil(duration / DT - 1e-9) + 1
    assert LocalPrimitivesMinJerk(ctx, duration=2.0).sample_times(DT)[-1] == pytest.approx(2.0)


def test_a_tiny_v_max_whose_duration_is_beyond_the_plan_horizon_builds_nothing():
    ctx = _ctx(v_max=1e-3)
    planner = LocalPrimitivesMinJerk(ctx)
    assert planner.duration == pytest.approx(3600.0)
    assert planner.plan(_view(ctx, [25.0, 25.0], [45.0, 25.0])) is None
    assert planner.last_candidates_built == 0


def test_plan_samples_are_the_polynomial_then_the_held_end_state():
    ctx = _ctx(v_max=4.0)
    planner = LocalPrimitivesMinJerk(ctx)
    p0, v0, a0 = np.array([20.0, 22.0]), np.array([1.5, -2.0]), np.array([0.5, 1.0])
    goal = np.array([33.0, 40.0])
    tr = planner.plan(_view(ctx, p0, goal, v=v0, a=a0, t=3.0))
    assert tr.t0 == 3.0 and tr.dt == DT and tr.n_samples == 10            # T = 0.9 s: samples at 0..0.9 s
    np.testing.assert_array_equal(tr.p[0], p0)
    np.testing.assert_array_equal(tr.v[0], v0)
    np.testing.assert_array_equal(tr.a[0], a0)
    g = (goal - planner.last_target) / np.linalg.norm(goal - planner.last_target)   # from the END POINT to the goal
    end = (planner.last_target, 2.0 * g, np.zeros(2))
    p, v, a = min_jerk_states(0.9, (p0, v0, a0), end, DT * np.arange(10))
    np.testing.assert_allclose(tr.p, p, atol=1e-9)
    np.testing.assert_allclose(tr.v, v, atol=1e-9)
    np.testing.assert_allclose(tr.a, a, atol=1e-9)
    # T = 0.75 s is not a multiple of dt: samples at 0..0.8 s, the last one extrapolated from the end state
    planner = LocalPrimitivesMinJerk(ctx, duration=0.75)
    tr = planner.plan(_view(ctx, p0, goal, v=v0, a=a0))
    assert tr.n_samples == 9
    g = (goal - planner.last_target) / np.linalg.norm(goal - planner.last_target)
    np.testing.assert_allclose(tr.p[-1], planner.last_target + 2.0 * g * 0.05, atol=1e-9)
    np.testing.assert_allclose(tr.v[-1], 2.0 * g, atol=1e-9)
    np.testing.assert_array_equal(tr.a[-1], 0.0)
    p, v, _ = min_jerk_states(0.75, (p0, v0, a0), (planner.last_target, 2.0 * g, np.zeros(2)), DT * np.arange(8))
    np.testing.assert_allclose(tr.p[:8], p, atol=1e-9)


# ---------------------------------------------------------------- candidates, rank, end velocity

def test_end_velocity_points_at_the_goal_not_along_the_candidate():
    ctx = _ctx(v_max=4.0)
    grid = _grid(ctx)
    for y in range(22, 29):
        grid.mark_occupied(np.array([[13.5, y + 0.5]]))  # a wall segment across the straight line
    planner = LocalPrimitivesMinJerk(ctx)
    p0, goal = np.array([10.5, 25.5]), np.array([40.5, 25.5])
    tr = planner.plan(_view(ctx, p0, goal, grid=grid))
    assert tr is not None and planner.last_rank > 0
    direction = (planner.last_target - p0) / 3.0
    assert abs(direction[1]) > 0.3                          # a candidate well off the goal direction was taken
    t_end = 0.9
    k = int(round(t_end / DT))
    np.testing.assert_allclose(tr.p[k], planner.last_target, atol=1e-9)
    to_goal = (goal - planner.last_target) / np.linalg.norm(goal - planner.last_target)
    np.testing.assert_allclose(tr.v[k], 2.0 * to_goal, atol=1e-9)   # 0.5 v_max from the end point toward the goal
    assert abs(to_goal[1]) > 0.05                           # which is not the goal direction seen from p0
    np.testing.assert_allclose(tr.a[k], 0.0, atol=1e-9)
    assert not np.any(grid.collides(tr.p[1:], 1.5))


def test_rank_order_is_the_angle_to_the_goal():
    ctx = _ctx()
    planner = LocalPrimitivesMinJerk(ctx)
    assert planner.n_candidates == 72
    ang = np.degrees(np.arctan2(planner.directions[:, 1], planner.directions[:, 0])) % 360
    np.testing.assert_allclose(ang, 5.0 * np.arange(72), atol=1e-9)
    view = _view(ctx, [10, 10], [10 + 30 * math.cos(math.radians(35)), 10 + 30 * math.sin(math.radians(35))])
    order = planner.ranked_candidates(view)
    assert list(order[:5]) == [7, 6, 8, 5, 9]
    goal_dir = (view.goal - view.position) / np.linalg.norm(view.goal - view.position)
    angles = np.arccos(np.clip(planner.directions[order] @ goal_dir, -1, 1))
    assert np.all(np.diff(angles) >= -1e-12)
    tr = planner.plan(view)
    assert tr is not None and planner.last_rank == 0 and planner.last_candidates_tried == 1
    np.testing.assert_allclose(planner.last_target, view.position + 3.0 * planner.directions[7], atol=1e-12)
    tie = _view(ctx, [10, 10], [10 + 30 * math.cos(math.radians(37.5)), 10 + 30 * math.sin(math.radians(37.5))])
    assert list(planner.ranked_candidates(tie)[:2]) == [7, 8]


def _program_is_free(view, p, times, margin=0.5):
    """The program's is_free over samples p [K, 2] at absolute times [K], written out probe by probe: five probes
    (centre, +-(r + 1 m) along x and y) outside the map or in an OCCUPIED cell, or a track prediction within
    r + r_track + margin; no wall test of its own."""
    grid, r = view.grid, view.limits.radius
    lo = grid.origin
    hi = grid.origin + np.asarray(grid.shape, float) * grid.res
    for x, t in zip(p, times):
        for off in ((0, 0), (-r - 1.0, 0), (r + 1.0, 0), (0, -r - 1.0), (0, r + 1.0)):
            q = x + np.asarray(off, float)
            if np.any(q < lo) or np.any(q >= hi) or grid.value_at(q[None])[0] == OCCUPIED:
                return False
        for c, vel, rad in zip(view.tracks.position, view.tracks.velocity, view.tracks.radius):
            if np.linalg.norm(x - (c + (t - view.t) * vel)) < r + rad + margin:
                return False
    return True


def _reference_choice(planner, view, physical):
    """The first clear (and, physical, contract-respecting) candidate in rank order, one candidate at a time, with
    min_jerk_states, checks.trajectory_clear (on the samples the planner checks) and contract.plan_violations:
    (rank, target) or None."""
    d, t_end = view.dims, planner.duration
    g = view.goal - view.position
    dist = np.linalg.norm(g)
    times = planner.sample_times(view.dt)
    every = times.size - 1
    cands = []
    for i in planner.ranked_candidates(view):
        target = view.position + 3.0 * planner.directions[i]
        reach = np.linalg.norm(view.goal - target)      # the end velocity points from the end point at the goal
        vel = planner.end_speed * (view.goal - target) / reach if reach > 0 else np.full(d, np.nan)
        cands.append((target, vel, every if planner.checked is None else int(planner.checked[i])))
    if dist < 3.0 and planner.goal_first:
        cands.insert(0, (view.goal, np.zeros(d), every))
    tau = np.minimum(times, t_end)
    for rank, (target, vel, n_checked) in enumerate(cands):
        if np.isnan(vel).any():                          # the program's 0 / 0: never taken
            continue
        p, v, a = min_jerk_states(t_end, (view.position, view.velocity, view.acceleration),
                                  (target, vel, np.zeros(d)), tau)
        past = times > t_end
        p[past] = target + (times[past] - t_end)[:, None] * vel
        v[past], a[past] = vel, 0.0
        clear = _program_is_free if planner.static_check == "program" else trajectory_clear
        if not clear(view, p[1:n_checked + 1], view.t + times[1:n_checked + 1], 0.5):
            continue
        if physical and plan_violations(Trajectory(view.t, view.dt, p, v, a), t=view.t, dt=view.dt,
                                        position=view.position, velocity=view.velocity,
                                        v_max=view.limits.v_max, a_max=view.limits.a_max):
            continue
        return rank, target
    return None


@pytest.mark.parametrize("physical, v_max, program", [(False, 4.0, False), (True, 2.0, False), (False, 6.0, True),
                                                      (False, 2.0, True)])
def test_choice_is_exactly_the_first_clear_candidate_in_rank_order(physical, v_max, program):
    """Cluttered random scenes (tracks near the MAV, occupied cells): the vectorised choice equals a candidate-by-
    candidate search (program: the program's per-candidate sample counts, no goal-first candidate)."""
    rng = np.random.default_rng(7)
    ctx = _ctx(v_max=v_max, physical=physical)
    planner = LocalPrimitivesMinJerk(ctx, **(LocalPrimitivesMinJerk.PROGRAM_PARAMS if program else {}))
    assert (planner.checked is not None) == program
    n_found, ranks = 0, set()
    for _ in range(120 if physical else 40):   # physical: the program's primitives rarely fit the limits
        p0 = rng.uniform(1.5, 48.5, 2) if program and rng.random() < 0.5 else rng.uniform(6.0, 44.0, 2)
        goal = p0 + rng.normal(size=2) * rng.uniform(1.0, 20.0)
        goal = np.clip(goal, 2.0, 48.0)
        to_goal = (goal - p0) / max(np.linalg.norm(goal - p0), 1e-9)
        turn = math.radians(rng.uniform(-25.0, 25.0))      # physical: moving roughly toward the goal
        heading = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]) @ to_goal
        v = rng.uniform(0.75, 1.0) * v_max * heading if physical else _state(rng, 2, v_max, 4.0)[0]
        a = _state(rng, 2, v_max, 0.5 if physical else 4.0)[1]
        m = rng.integers(0, 8)
        tracks = make_tracks(p0 + rng.uniform(-5, 5, (m, 2)), rng.normal(scale=2.0, size=(m, 2)), 1.0) if m \
            else Tracks.empty(2)
        grid = _grid(ctx)
        for c in p0 + rng.uniform(-5, 5, (rng.integers(0, 12), 2)):
            grid.mark_occupied(np.clip(c, 1.5, 48.5)[None])
        if program:                                               # seen wall cells in the grid's border ring
            for c in p0 + rng.uniform(-6, 6, (rng.integers(0, 10), 2)):
                grid.mark_occupied(np.clip(c, -0.5, 50.5)[None])
        view = _view(ctx, p0, goal, v=v, a=a, grid=grid, tracks=tracks, t=float(rng.uniform(0, 10)))
        tr = planner.plan(view)
        want = _reference_choice(planner, view, physical)
        if want is None:
            assert tr is None and planner.last_rank is None
            continue
        n_found += 1
        ranks.add(planner.last_rank)
        assert tr is not None and planner.last_rank == want[0]
        np.testing.assert_allclose(planner.last_target, want[1], atol=1e-12)
        assert planner.last_candidates_tried == want[0] + 1
    assert n_found >= 6 and len(ranks) >= 3      # the scenes really exercised the ranking (deterministic rng)


def test_memory_bounded_chunks_choose_the_same_candidate(monkeypatch):
    """Candidates are evaluated in chunks of at most _MAX_BATCH_FLOATS candidate x sample x track entries: tiny
    chunks give the same choices as one batch."""
    import pbdyn.planning.primitives.minjerk as mod

    ctx = _ctx()
    rng = np.random.default_rng(3)
    scenes = []
    for _ in range(10):
        p0 = rng.uniform(10.0, 40.0, 2)
        tracks = make_tracks(p0 + rng.uniform(-6, 6, (4, 2)), rng.normal(size=(4, 2)), 0.5)
        scenes.append(_view(ctx, p0, rng.uniform(5.0, 45.0, 2), v=_state(rng, 2, 4.0, 4.0)[0], tracks=tracks))
    whole = [LocalPrimitivesMinJerk(ctx).plan(v) for v in scenes]
    monkeypatch.setattr(mod, "_MAX_BATCH_FLOATS", 100)          # 100 // (10 samples x 4 tracks) = 2 per chunk
    ranks = []
    for view, want in zip(scenes, whole):
        planner = LocalPrimitivesMinJerk(ctx)
        got = planner.plan(view)
        assert (got is None) == (want is None)
        if got is not None:
            np.testing.assert_array_equal(got.p, want.p)
            assert planner.last_candidates_built <= planner.last_candidates_tried + 1
            ranks.append(planner.last_rank)
    assert len(ranks) >= 5 and sum(r > 1 for r in ranks) >= 2, ranks


def test_batched_checks_agree_with_trajectory_clear():
    rng = np.random.default_rng(5)
    ctx = _ctx()
    grid = _grid(ctx)
    grid.cells[20:23, 20:30] = OCCUPIED
    tracks = make_tracks([[25.0, 15.0], [15.0, 25.0]], [[0.0, 2.0], [2.0, 0.0]], 1.0)
    view = _view(ctx, [25, 25], [40, 40], grid=grid, tracks=tracks, t=2.0)
    p = rng.uniform(0.5, 49.5, (200, 6, 2))
    times = 2.0 + DT * np.arange(1, 7)
    bad = batch_conflicts(view, p, times) | grid_conflicts(view, p)
    want = np.array([not trajectory_clear(view, p[i], times) for i in range(200)])
    np.testing.assert_array_equal(bad, want)
    assert 20 < want.sum() < 180


def test_program_static_check_probes_five_points_and_counts_walls_once_seen():
    ctx = _ctx()
    grid = _grid(ctx)                           # inside free, the border ring (the program's wall cells) unknown
    view = _view(ctx, [25, 25], [40, 25], grid=grid)
    def blocked(*pts):
        return bool(program_grid_conflicts(view, np.asarray(pts, float)[None])[0])
    assert not blocked([1.5, 25.0])             # the probe at x = -0.5 lies in an unseen wall cell
    assert blocked([0.9, 25.0])                 # a probe beyond the ring (x < -1) always blocks
    grid.mark_occupied(np.array([[-0.5, 25.5]]))  # a ray saw wall cell (0, 26)
    assert blocked([1.5, 25.0]) and blocked([1.99, 25.9]) and not blocked([2.0, 25.5])
    assert not blocked([1.5, 24.9])             # the probe lands in the unseen cell next to it
    # a cell 1.5 m away diagonally lies between the probes: the program passes, pbdyn's ball check does not
    grid.mark_occupied(np.array([[26.5, 26.5]]))
    assert not blocked([25.0, 25.0])
    assert grid_conflicts(view, np.array([[[25.0, 25.0]]]))[0]
    assert blocked([26.5, 24.6])                # the +y probe at (26.5, 26.6) in that cell
    # no wall margin of its own: pbdyn keeps radius + 0.1 m from the walls, the program's check 1 m (unseen)
    assert not blocked([1.05, 10.0]) and batch_conflicts(view, np.array([[[1.05, 10.0]]]), np.array([0.1]))[0]
    assert not batch_conflicts(view, np.array([[[1.05, 10.0]]]), np.array([0.1]), walls=False)[0]


def test_program_static_check_is_the_programs_default():
    assert LocalPrimitivesMinJerk.PROGRAM_PARAMS["static_check"] == "program"
    assert LocalPrimitivesMinJerk(_ctx()).static_check == "pbdyn"
    with pytest.raises(ValueError, match="static_check"):
        LocalPrimitivesMinJerk(_ctx(), static_check="disc")


# ---------------------------------------------------------------- the profiles' limits

def test_physical_profile_never_breaks_the_plan_contract():
    rng = np.random.default_rng(11)
    found = {}
    for dims in (2, 3):
        for v_max in (2.0, 4.0, 6.0):
            ctx = _ctx(dims=dims, v_max=v_max, physical=True)
            planner = LocalPrimitivesMinJerk(ctx)
            hi = np.array([50.0, 50.0, 20.0][:dims])
            n = 0
            for k in range(60 if dims == 2 else 20):
                p0 = rng.uniform(6.0, hi - 6.0)
                goal = rng.uniform(2.0, hi - 2.0)
                to_goal = (goal - p0) / np.linalg.norm(goal - p0)
                if k % 2:   # moving toward the goal near the program's cruise: where its primitives can fit
                    v = rng.uniform(0.6, 1.0) * v_max * to_goal
                    a = _state(rng, dims, v_max, 1.0)[1]
                else:
                    v, a = _state(rng, dims, v_max, 4.0)
                view = _view(ctx, p0, goal, v=v, a=a, t=1.0)
                tr = planner.plan(view)
                if tr is None:
                    continue
                n += 1
                assert plan_violations(tr, t=1.0, dt=DT, position=p0, velocity=v, v_max=v_max, a_max=4.0) == []
            found[dims, v_max] = n
    assert found[2, 2.0] >= 5 and found[3, 2.0] >= 2, found   # not only failures


def test_thesis_program_profile_exceeds_the_limits_at_v_max_6():
    ctx = _ctx(v_max=6.0, physical=False)
    planner = LocalPrimitivesMinJerk(ctx)
    tr = planner.plan(_view(ctx, [10.0, 25.0], [40.0, 25.0]))
    assert tr is not None and planner.last_rank == 0
    assert np.linalg.norm(tr.a, axis=1).max() > 4.0 * 5          # the program's 3 m in 0.6 s from rest
    assert plan_violations(tr, t=0.0, dt=DT, position=[10.0, 25.0], velocity=[0.0, 0.0], v_max=6.0, a_max=4.0)
    assert plan_violations(tr, t=0.0, dt=DT, position=[10.0, 25.0], velocity=[0.0, 0.0], v_max=6.0, a_max=4.0,
                           physical=False) == []
    # the same state under the physical profile: every primitive is out of the limits
    phys = LocalPrimitivesMinJerk(replace(ctx, physical=True))
    assert phys.plan(_view(ctx, [10.0, 25.0], [40.0, 25.0])) is None and phys.last_candidates_tried == 72


# ---------------------------------------------------------------- 3D, parameters, registry

def test_3d_candidates_on_a_sphere_and_end_velocity_toward_the_goal():
    ctx = _ctx(dims=3)
    planner = LocalPrimitivesMinJerk(ctx)
    assert planner.directions.shape == (412, 3) and planner.n_candidates == 412
    p0, goal = np.array([10.0, 10.0, 10.0]), np.array([30.0, 20.0, 14.0])
    tracks = make_tracks([p0 + 2.5 * (goal - p0) / np.linalg.norm(goal - p0)], [[0.0, 0.0, 0.0]], 1.0)
    tr = planner.plan(_view(ctx, p0, goal, tracks=tracks))
    assert tr is not None and planner.last_rank > 0
    g = (goal - planner.last_target) / np.linalg.norm(goal - planner.last_target)
    np.testing.assert_allclose(tr.v[9], 2.0 * g, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(planner.last_target - p0), 3.0)


def test_parameters_are_validated():
    ctx = _ctx()
    for bad in ({"n_candidates": 0}, {"n_candidates": 10 ** 9}, {"step_m": -1.0}, {"end_speed_frac": 1.5},
                {"margin": -0.1}, {"duration": 0.0}, {"duration": 1e5}, {"sphere_spacing_deg": 1e-9},
                {"duration": float("nan")}):
        with pytest.raises(ValueError):
            LocalPrimitivesMinJerk(ctx, **bad)
    cls = registry.resolve_trajectory_planner("local_primitives_minjerk", "planners[0].trajectory")
    assert cls is LocalPrimitivesMinJerk and registry.TRAJECTORY_PLANNERS["local_primitives_minjerk"] is cls
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params: invalid parameters"):
        registry.build_planner(cls, ctx, {"step_m": 0.0}, "planners[0].params")
    with pytest.raises(ConfigError, match=r"^planners\[0\]\.params\.jerk_max: unknown parameter"):
        registry.build_planner(cls, ctx, {"jerk_max": 20.0}, "planners[0].params")
    assert cls.PROGRAM_PARAMS == {"goal_first": False, "samples": "program", "static_check": "program",
                                  "arithmetic": "program"}
    for bad in ({"goal_first": 1}, {"samples": "some"}):
        with pytest.raises(ValueError):
            LocalPrimitivesMinJerk(ctx, **bad)
    planner = LocalPrimitivesMinJerk(ctx, n_candidates=8, step_m=2.0, end_speed_frac=0.25, duration=1.0)
    assert planner.n_candidates == 8 and planner.end_speed == 1.0 and planner.duration == 1.0


# ---------------------------------------------------------------- real trials

def _fly_program(sc, rollout, start, goal, planner_cls=LocalPrimitivesMinJerk, v_max=None, gaze=None):
    """One trial under the thesis_program rules (the one switch: plans checked for form and continuity only, the
    planner's context has physical False, the guard checks the form only): (outcome, min clearance, peak plan
    speeds, peak plan accelerations), the peaks per step over each returned plan (the agent clips the executed v
    and a to the limits)."""
    from pbdyn.sim.agent import planner_context
    from pbdyn.sim.spec import make_trial_spec
    from pbdyn.sim.trial import run_trial

    spec = make_trial_spec(sc, first_map(sc), planner="local_primitives_minjerk", gaze=gaze, start=start, goal=goal,
                           v_max=v_max)
    planner = planner_cls(replace(planner_context(spec), physical=False))
    peaks = _PlanPeaks()
    result = run_trial(spec, rollout, trajectory_planner=planner, observers=[peaks], execution="thesis_program")
    return result.outcome, result.min_clearance_m, np.array(peaks.speeds), np.array(peaks.accs)


class _PlanPeaks:
    """Observer: each step's peak speed and acceleration over the plan in execution (every plan valid)."""

    def __init__(self):
        self.speeds, self.accs = [], []

    def on_step(self, state, agent, decision, record):
        assert decision.violation is None and decision.plan_ok and not agent.physical
        self.speeds.append(np.linalg.norm(agent.trajectory.v, axis=1).max())
        self.accs.append(np.linalg.norm(agent.trajectory.a, axis=1).max())

    def on_end(self, state, agent):
        pass


def test_real_trials_succeed_in_open_space_under_the_thesis_program():
    sc = open_scenario(2)
    rollout = handmade_rollout(sc, np.zeros((0, 2)), np.zeros((0, 2)), [])
    for start, goal, v_max in (((4.0, 4.0), (46.0, 46.0), 4.0), ((46.0, 25.0), (4.0, 25.0), 6.0),
                               ((25.0, 4.0), (25.0, 46.0), 2.0)):
        outcome, _, speeds, accs = _fly_program(sc, rollout, start, goal, v_max=v_max)
        assert outcome == "success", (start, goal, v_max)
        assert speeds.max() > v_max and accs.max() > 4.0 * (v_max / 2.0)   # the program bounds neither


class _Blind(LocalPrimitivesMinJerk):
    """The same planner without the tracks: what it would fly if it ignored the obstacle."""

    def plan(self, view):
        return super().plan(replace(view, tracks=Tracks.empty(view.dims)))


def test_real_trial_avoids_a_crossing_obstacle_under_the_thesis_program():
    sc = open_scenario(2)
    # an obstacle (r 1.5 m) crossing the goal line y = 25 at x = 25 from the side, when the MAV gets there
    rollout = handmade_rollout(sc, [[25.0, 12.0]], [[0.0, 2.5]], [1.5])
    blind, *_ = _fly_program(sc, rollout, (4.0, 25.0), (46.0, 25.0), planner_cls=_Blind, gaze="fullrange")
    assert blind == "dynamic_collision"
    outcome, clearance, *_ = _fly_program(sc, rollout, (4.0, 25.0), (46.0, 25.0), gaze="fullrange")
    assert outcome == "success" and clearance >= 0.0


def test_physical_profile_trial_never_breaks_the_contract():
    """The default profile: the program's primitives do not fit a_max from rest, so the MAV brakes (stays) and the
    trial deadlocks; it never ends as invalid_plan."""
    import pbdyn

    res = pbdyn.run_trial(open_scenario(2, world={"time_limit": 5.0}), planner="local_primitives_minjerk",
                          gaze="lookahead", start=(4.0, 25.0), goal=(46.0, 25.0))
    assert res.outcome == "deadlock" and res.planning_failures >= 10 and res.planner == "local_primitives_minjerk"


@pytest.mark.parametrize("v_max, counts", [(2.0, {18: 42, 17: 30}), (4.0, {9: 42, 8: 30}), (6.0, {5: 65, 6: 7})])
def test_program_sample_counts_reproduce_the_programs_floating_point_floor(v_max, counts):
    """The program checked floor(T / dt) samples with T = 1.2 |d| / v_max in its pixels and |d| numpy 1.23.4's norm
    of the 3 m offset, whose last bit decides the floor: 1.8 / 0.1 and 0.9 / 0.1 floor to 17 and 8 at 30 of the 72
    angles, and at 6 m/s 7 candidates check 6 samples, not 5 (PROGRAM_SAMPLE_COUNTS, tools/program_tables.py)."""
    got = program_sample_counts(72, 3.0, v_max, 0.1)
    assert dict(zip(*np.unique(got, return_counts=True))) == counts
    assert got[0] == max(counts) - (v_max == 6.0)     # along +x |d| is exactly 30 px
    if v_max == 6.0:
        assert np.flatnonzero(got == 6).tolist() == [3, 15, 21, 33, 39, 57, 69]
    # outside the program's setting the floor is computed here (this numpy's norm)
    other = program_sample_counts(72, 3.0, 5.0, 0.1)
    assert set(other.tolist()) <= {7} and other.shape == (72,)


def test_program_samples_leave_the_primitives_end_unchecked_at_6_mps():
    """At v_max 6 m/s the program never checked the sample at T = 0.6 s: a resting track that meets only the end of
    the best candidate blocks it with samples = "all" and not with samples = "program"."""
    ctx = _ctx(v_max=6.0)
    p0, goal = np.array([20.0, 20.0]), np.array([40.0, 20.0])
    every = LocalPrimitivesMinJerk(ctx)
    prog = LocalPrimitivesMinJerk(ctx, samples="program", goal_first=False)
    free = every.plan(_view(ctx, p0, goal))
    assert free.p.shape[0] == 7 and every.last_rank == 0
    obstacle = np.array([24.99, 20.0])              # reach: 0.5 m radius + 1 m MAV + 0.5 m margin = 2 m
    dist = np.linalg.norm(free.p - obstacle, axis=1)
    assert dist[6] < 2.0 and dist[1:6].min() > 2.0
    view = _view(ctx, p0, goal, tracks=make_tracks([obstacle], [[0.0, 0.0]], 0.5))
    assert every.plan(view) is not None and every.last_rank == 1
    assert prog.plan(view) is not None and prog.last_rank == 0


def test_goal_first_is_pbdyns_addition_and_off_in_the_programs_parameters():
    ctx = _ctx(v_max=4.0)
    p0, goal = np.array([20.0, 20.0]), np.array([21.5, 20.0])
    pb = LocalPrimitivesMinJerk(ctx)
    pb.plan(_view(ctx, p0, goal))
    np.testing.assert_allclose(pb.last_target, goal)
    prog = LocalPrimitivesMinJerk(ctx, **LocalPrimitivesMinJerk.PROGRAM_PARAMS)
    prog.plan(_view(ctx, p0, goal))
    np.testing.assert_allclose(prog.last_target, p0 + [3.0, 0.0], atol=1e-12)


def test_end_velocity_points_from_each_end_point_at_the_goal_and_the_goal_itself_is_never_an_end_point():
    """The program's vf = 0.5 v_max (goal - p1) / |goal - p1|: per candidate, from its own end point; an end point
    on the goal has no direction (its 0 / 0 made NaN samples that its check rejected), so the MAV swerves."""
    ctx = _ctx(v_max=4.0)
    planner = LocalPrimitivesMinJerk(ctx, goal_first=False)
    p0, goal = np.array([20.0, 25.0]), np.array([23.0, 25.0])          # the goal exactly step_m ahead on a candidate
    tr = planner.plan(_view(ctx, p0, goal))
    assert tr is not None and planner.last_rank == 1
    assert not np.allclose(planner.last_target, goal)
    np.testing.assert_allclose(np.linalg.norm(planner.last_target - p0), 3.0)
    np.testing.assert_allclose(abs(np.degrees(np.arctan2(*(planner.last_target - p0)[::-1]))), 5.0)
    v_end = 2.0 * (goal - planner.last_target) / np.linalg.norm(goal - planner.last_target)
    _, v, _ = min_jerk_states(planner.duration, (p0, np.zeros(2), np.zeros(2)), (planner.last_target, v_end,
                                                                                 np.zeros(2)), DT * np.arange(10))
    np.testing.assert_allclose(tr.v, v, atol=1e-9)
    # one step further away the straight candidate is fine again
    assert planner.plan(_view(ctx, p0, goal + [0.1, 0.0])) is not None and planner.last_rank == 0


def test_program_rank_is_the_programs_cost_order_with_its_sorts_ties():
    """The program ranked theta = 5k deg by (wrapped theta - phi)^2 with phi = degrees(atan2) of its pixel goal
    vector; where costs tie (phi a multiple of 45 deg) its numpy 1.23.4 argsort fixed the order of each tied pair
    (PROGRAM_TIE_ORDERS, written by tools/program_tables.py)."""
    from pbdyn.planning.primitives.minjerk import PROGRAM_TIE_ORDERS, program_rank
    theta = np.arange(0, 360, 5)

    def costs(phi):
        diff = np.abs(theta - phi % 360)
        return np.where(diff <= 180, diff, 360 - diff) ** 2

    assert set(PROGRAM_TIE_ORDERS) == {0.0, 45.0, 90.0, 135.0, 180.0, -45.0, -90.0, -135.0}
    for phi, order in PROGRAM_TIE_ORDERS.items():
        assert sorted(order) == list(range(72))
        c = costs(phi)[list(order)]
        assert np.all(np.diff(c) >= 0)                      # a sort of the program's costs ...
        assert (np.diff(c) == 0).sum() == 35                 # ... with 35 tied pairs ...
        assert list(order) != list(np.argsort(costs(phi), kind="stable"))   # ... not in index order
    # the goal straight below on the pixel grid (dx = 0, dy = -2.8 m in the metre frame, off by an ulp)
    np.testing.assert_array_equal(program_rank(np.array([24.0 - 24.0, 21.2 - 24.0])), PROGRAM_TIE_ORDERS[-90.0])
    np.testing.assert_array_equal(program_rank(np.array([45.0 - 42.2, 24.0 - 21.2])), PROGRAM_TIE_ORDERS[45.0])
    # no tie: plain cost order, and the planner uses it under arithmetic = "program"
    g = np.array([3.7, -1.3])
    phi = np.degrees(np.arctan2(g[1], g[0]))
    np.testing.assert_array_equal(program_rank(g), np.argsort(costs(phi), kind="stable"))
    ctx = _ctx()
    planner = LocalPrimitivesMinJerk(ctx, arithmetic="program")
    np.testing.assert_allclose(planner.directions, np.c_[np.cos(np.radians(theta)), np.sin(np.radians(theta))],
                               atol=1e-15)
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0])
    np.testing.assert_array_equal(planner.ranked_candidates(view), PROGRAM_TIE_ORDERS[0.0])
    assert list(LocalPrimitivesMinJerk(ctx).ranked_candidates(view))[:3] == [0, 1, 71]
    with pytest.raises(ValueError, match="arithmetic"):
        LocalPrimitivesMinJerk(ctx, arithmetic="random")


def test_program_end_velocities_keep_the_programs_floating_point_residue():
    """In the program's pixels a candidate ending on the goal leaves either exactly 0 (NaN: never taken) or a residue
    of ulps whose direction the end velocity takes: 3 m short of a goal at y = 4 m (40 px) the straight candidate
    (180 deg, 30 sin(pi) = 3.7e-15 px, more than half an ulp of 40) ends pointing along -y; at y = 25 m (250 px) the
    residue vanishes and the candidate is rejected; off the goal both arithmetics agree."""
    from pbdyn.planning.primitives.minjerk import program_end_velocities, program_unit_vectors
    unit = program_unit_vectors()
    np.testing.assert_array_equal(unit[18], [np.cos(np.pi / 2), 1.0])
    v = program_end_velocities(np.array([6.0, 3.0]), np.array([3.0, 3.0]), unit[[36, 35]], 3.0, 3.0)
    np.testing.assert_array_equal(v[0], [0.0, -3.0])
    p1 = np.array([6.0, 3.0]) + 3.0 * unit[35]
    np.testing.assert_allclose(v[1], 3.0 * (np.array([3.0, 3.0]) - p1) / np.linalg.norm([3.0, 3.0] - p1), rtol=1e-12)
    assert np.isnan(program_end_velocities(np.array([6.0, 24.0]), np.array([3.0, 24.0]), unit[[36]], 3.0, 3.0)).all()
    # the planner under arithmetic = "program" takes that straight candidate, under "pbdyn" it swerves
    ctx = _ctx(v_max=6.0)
    view = _view(ctx, [6.0, 3.0], [3.0, 3.0])
    prog = LocalPrimitivesMinJerk(ctx, **LocalPrimitivesMinJerk.PROGRAM_PARAMS)
    tr = prog.plan(view)
    assert prog.last_rank == 0 and tr is not None
    np.testing.assert_allclose(prog.last_target, [3.0, 3.0], atol=1e-12)
    own = LocalPrimitivesMinJerk(ctx, goal_first=False)
    own.plan(view)
    assert own.last_rank == 1
