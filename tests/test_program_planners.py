"""The thesis program's settings of the built-in global primitives and MPC planners (PROGRAM_PARAMS, profile
"thesis_program"): the program's acceleration grid, heuristic, node keys and budget; the physical profile's norm
filter; the MPC's quadratically drifting obstacle prediction; and closed-loop trials in program mode."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.perception.grid import FREE, OCCUPIED, OccupancyGrid
from pbdyn.planning import registry
from pbdyn.planning.primitives.global_astar import (GlobalPrimitives, program_accel_values, program_heuristic,
                                              program_keys)
from pbdyn.planning.mpc.planner import MPC
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.view import MAVLimits, Tracks, View
from pbdyn.sim.contract import check_plan
from pbdyn.outcome import Outcome
from pbdyn.sim.trial import make_trial_spec, run_trial
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout
from tests.helpers import make_tracks

DT = 0.1
QUICKSTART = Path(__file__).resolve().parents[1] / "scenarios" / "quickstart.toml"
PROGRAM_GP = GlobalPrimitives.PROGRAM_PARAMS


def _context(v_max=4.0, physical=False, dims=2):
    hi = np.array([50.0, 50.0, 20.0][:dims])
    return PlannerContext(dims, DT, MAVLimits(1.0, v_max, 4.0, 1.4), np.zeros(dims), hi, physical=physical)


def _grid(ctx):
    g = OccupancyGrid(ctx.bounds_lo, ctx.bounds_hi, 1.0)
    g.cells[(slice(1, -1),) * ctx.dims] = FREE
    return g


def _view(ctx, p, goal, v=None, grid=None, tracks=None):
    d = ctx.dims
    v = np.zeros(d) if v is None else np.asarray(v, float)
    return View(t=0.0, dt=DT, position=np.asarray(p, float), velocity=v,
                acceleration=np.zeros(d), yaw=0.0, goal=np.asarray(goal, float), goal_radius=1.0, limits=ctx.limits,
                bounds_lo=ctx.bounds_lo, bounds_hi=ctx.bounds_hi, grid=_grid(ctx) if grid is None else grid,
                tracks=Tracks.empty(d) if tracks is None else tracks, trajectory=None)


# ---------------------------------------------------------------- global primitives: the program's grid

@pytest.mark.parametrize("v_max,step_px,per_axis,children,has_zero", [
    (2.0, 3, 27, 729, False), (4.0, 11, 8, 64, False), (6.0, 4, 20, 400, True)])
def test_program_grid_is_the_programs_arange_sized_by_v_max(v_max, step_px, per_axis, children, has_zero):
    vals = program_accel_values(v_max, 4.0)
    np.testing.assert_allclose(vals, np.arange(-40, 40, step_px) / 10.0, atol=1e-12)    # the program, in pixels
    assert vals.shape == (per_axis,) and bool(np.any(vals == 0.0)) == has_zero
    gp = GlobalPrimitives(_context(v_max), **PROGRAM_GP)
    assert gp.accel_grid == "program" and gp.n_accel == per_axis and gp.accelerations.shape == (children, 2)
    assert np.isclose(np.linalg.norm(gp.accelerations, axis=1).max(), 4.0 * np.sqrt(2.0))   # per axis, no norm
    assert GlobalPrimitives(_context(v_max, dims=3), **PROGRAM_GP).accelerations.shape == (per_axis ** 3, 3)


def test_program_grid_between_and_below_the_programs_speeds():
    assert program_accel_values(3.0, 4.0).shape == (12,)            # the program's rule: step 0.7 m/s^2
    np.testing.assert_array_equal(program_accel_values(1.0, 4.0), program_accel_values(2.0, 4.0))   # clamped
    with pytest.raises(ValueError, match="n_accel applies"):
        GlobalPrimitives(_context(), accel_grid="program", n_accel=7)
    for bad in ({"accel_grid": "linspace"}, {"heuristic": "euclid"}):
        with pytest.raises(ValueError, match="must be one of"):
            GlobalPrimitives(_context(), **bad)


def test_physical_profile_drops_over_norm_children_and_plans_keep_the_contract():
    full = GlobalPrimitives(_context(6.0, physical=False), **PROGRAM_GP).accelerations
    kept = GlobalPrimitives(_context(6.0, physical=True), **PROGRAM_GP).accelerations
    norms = np.linalg.norm(full, axis=1)
    assert kept.shape[0] == int(np.sum(norms <= 4.0 + 1e-12)) < full.shape[0] == 400
    assert np.linalg.norm(kept, axis=1).max() <= 4.0 + 1e-12
    # moving at 4 m/s along +x toward a goal up and to the left: the best turn of the full grid is over a_max
    p0, v0 = [25.0, 25.0], [4.0, 0.0]
    plans = {}
    for physical in (False, True):
        ctx = _context(6.0, physical=physical)
        gp = GlobalPrimitives(ctx, **PROGRAM_GP)
        plans[physical] = gp.plan(_view(ctx, p0, [25.0, 45.0], v=v0))
        assert plans[physical] is not None and gp.last_status == "found"
    assert np.linalg.norm(plans[False].a, axis=1).max() > 4.0 + 1e-6
    kw = dict(t=0.0, dt=DT, position=np.array(p0), velocity=np.array(v0), v_max=6.0, a_max=4.0)
    assert check_plan(plans[False], physical=True, **kw).check == "acceleration"
    assert check_plan(plans[False], physical=False, **kw) is None
    assert check_plan(plans[True], physical=True, **kw) is None


def test_program_heuristic_and_node_keys():
    gp = GlobalPrimitives(_context(), **PROGRAM_GP)
    assert gp.T == 2.0 and gp.epsilon == 1.0 and gp.rho == 10.0
    p = np.array([[10.0, 10.0], [13.0, 14.0]])
    v = np.array([[3.0, 4.0], [0.0, 0.0]])
    goal = np.array([13.0, 14.0])
    np.testing.assert_allclose(gp.heuristic(goal, 1.0, p, v), [2.0 * (5.0 * 5.0 + 5.0), 0.0])   # T (5 d + |v|)
    np.testing.assert_allclose(gp.heuristic(goal, 3.0, p, v), program_heuristic(goal, p, v, 2.0))  # no radius
    # the program's keys: round(x_px) // 10 (1 m cells after rounding to 0.1 m), round(v_px) (0.1 m/s)
    keys = program_keys(np.array([[10.04, 3.0], [10.94, 3.5], [10.96, 3.5]]),
                        np.array([[1.04, 0.0], [0.96, 0.0], [0.96, 0.0]]))
    assert keys[0] == keys[1] == (10, 3, 10, 0) and keys[2] == (11, 3, 10, 0)
    # the lattice mode is untouched
    d = GlobalPrimitives(_context())
    assert (d.accel_grid, d.heuristic_kind, d.n_accel, d.accelerations.shape) == ("norm_lattice", "lqmt", 7, (29, 2))


def test_program_budget_gives_up_where_the_default_budget_finds_the_way_round():
    ctx = _context(4.0)
    grid = _grid(ctx)
    grid.cells[20:22, 8:43] = OCCUPIED                  # a wall across the goal line
    view = _view(ctx, [10.0, 25.0], [40.0, 25.0], grid=grid)
    program = GlobalPrimitives(ctx, **PROGRAM_GP)
    assert program.max_expansions == 98
    assert program.plan(view) is None
    assert program.last_status == "budget" and program.last_expansions == 98 and program.n_budget_hits == 1
    default_budget = GlobalPrimitives(ctx, **{**PROGRAM_GP, "max_expansions": 20000})
    tr = default_budget.plan(view)
    assert tr is not None and default_budget.last_status == "found" and default_budget.last_expansions > 100
    assert np.linalg.norm(tr.p[-1] - [40.0, 25.0]) <= 1.0


def test_program_params_are_accepted_by_the_registry():
    attr = {"heuristic": "heuristic_kind", "duration_s": "T"}
    for cls in (GlobalPrimitives, MPC):
        pl = registry.build_planner(cls, _context(), dict(cls.PROGRAM_PARAMS), "planners[0].trajectory_params")
        for key, value in cls.PROGRAM_PARAMS.items():
            assert getattr(pl, attr.get(key, key)) == value, key


# ---------------------------------------------------------------- MPC: the program's prediction

def test_mpc_program_prediction_is_quadratic_in_the_step():
    ctx = _context()
    tracks = make_tracks([[20.0, 12.0], [30.0, 30.0]], [[1.5, -0.5], [0.0, 2.0]], 1.0)
    k = np.arange(1, 26, dtype=float)
    prog, cv = MPC(ctx, **MPC.PROGRAM_PARAMS), MPC(ctx)
    expect = tracks.position[None] + (0.5 * k * (k + 1.0) * DT)[:, None, None] * tracks.velocity[None]
    np.testing.assert_allclose(prog.obstacle_prediction(tracks), expect, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cv.obstacle_prediction(tracks),
                               tracks.position[None] + (k * DT)[:, None, None] * tracks.velocity[None],
                               rtol=0, atol=1e-12)
    # the track rows are built on it: row centres are the drifted predictions of the selected tracks
    view = _view(ctx, [15.0, 15.0], [45.0, 15.0], v=[2.0, 0.0], tracks=tracks)
    _, centres, _ = prog.track_rows(view, prog.reference_path(view))
    sel = prog.last_track_index
    np.testing.assert_allclose(centres[:sel.shape[0]], np.swapaxes(expect[:, sel], 0, 1), atol=1e-12)
    assert np.linalg.norm(centres[0, -1] - centres[0, 0]) > 10.0 * np.linalg.norm(tracks.velocity[sel[0]]) * 2.4
    assert prog.max_slack >= 1e3 and cv.max_slack == 0.05


# ---------------------------------------------------------------- closed-loop trials in program mode

def _fly_program(trajectory: str, start, goal):
    """One quickstart trial (map 0, 10 obstacles) of ``trajectory`` with its PROGRAM_PARAMS in the scenario's
    trajectory_params, flown under the thesis_program rules (run_trial's one switch: the planner built with
    PlannerContext.physical = False, an Agent that checks continuity only, a guard that checks the form only)."""
    cls = registry.resolve_trajectory_planner(trajectory)
    doc = tomllib.loads(QUICKSTART.read_text())
    doc["planners"] = [{"trajectory": trajectory, "gaze": "fullrange", "trajectory_params": dict(cls.PROGRAM_PARAMS)}]
    sc = parse_scenario(doc)
    map_spec = enumerate_maps(sc)[0]
    spec = make_trial_spec(sc, map_spec, start=start, goal=goal)
    watch = _Planned()
    result = run_trial(spec, build_rollout(sc, map_spec), observers=[watch], execution="thesis_program")
    return Outcome(result.outcome), result.steps, watch.planned, watch.planner


class _Planned:
    """Observer: the plans asked for (every one valid) and the agent's planner."""

    planned, planner = 0, None

    def on_step(self, state, agent, decision, record):
        assert decision.violation is None, decision.violation
        assert not agent.physical and not agent.context.physical
        self.planned += decision.planned
        self.planner = agent.planner

    def on_end(self, state, agent):
        pass


@pytest.mark.parametrize("trajectory", ["global_primitives", "mpc"])
def test_program_mode_trial_completes(trajectory):
    outcome, steps, planned, planner = _fly_program(trajectory, (4.0, 4.0), (46.0, 46.0))
    assert outcome in (Outcome.SUCCESS, Outcome.DYNAMIC_COLLISION, Outcome.STATIC_COLLISION, Outcome.DEADLOCK,
                       Outcome.FREEZING)
    assert steps > 20 and planned >= 1
    if trajectory == "global_primitives":
        assert planner.accel_grid == "program" and planner.accelerations.shape == (64, 2) and planner.n_plans >= 1
        assert outcome == Outcome.SUCCESS            # open start corner, 10 obstacles: the program plans get there
    else:
        assert planner.prediction == "program" and planned == steps     # a new plan every step
