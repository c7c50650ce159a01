"""The trial core (pbdyn.sim.batch.TrialBatch, pbdyn.sim.trial.fly_trials): trials flown together give exactly the recorded
rows of trials flown one by one, for every built-in planner pair in 2D and 3D, under the thesis_program profile, on
walled and imported worlds, with observers; a trial that raises ends only itself; the guarded step lets no caller
move the MAV outside its limits; the acceleration action is integrated within them."""

from __future__ import annotations

import dataclasses
import gzip
import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from pbdyn.config import load_scenario
from pbdyn.errors import ConfigError
from pbdyn.outcome import Outcome
from pbdyn.planning.primitives.local import LocalPrimitives
from pbdyn.sim.batch import TrialBatch
from pbdyn.sim.guard import Accel, Action, breach, integrate
from pbdyn.sim.observers import SPLITS, TraceObserver
from pbdyn.sim.spec import make_trial_spec, with_planner_objects
from pbdyn.sim.trial import _Log, _share_rest, fly_trials, make_world, run_trial
from pbdyn.world.maps import get_map
from pbdyn.world.rollout import get_rollout
from tests import core_fixture as fx
from tests.conftest import SCENARIOS
from tests.helpers import first_map, handmade_rollout, open_scenario


@pytest.fixture(scope="module")
def recorded() -> dict:
    return json.loads(gzip.decompress(fx.FIXTURE.read_bytes()))


@pytest.mark.parametrize("group", ["all_2d", "all_3d", "walls_2d", "warehouse_2d", "hangar_3d"])
def test_a_batch_flies_the_recorded_one_by_one_rows(recorded, group):
    """Every built-in trajectory x gaze planner (2D, 3D), walls, imported worlds: one batch, the recorded rows of
    the trials flown one by one before the core was made one."""
    assert fx.fly_batch(group) == recorded[group]["rows"]


def test_a_batch_under_the_thesis_program_profile_flies_the_recorded_rows(recorded):
    """Every third case of the thesis_program group (program braking, pixel positions, the program's plans)."""
    _, ro, specs = fx.specs_of("thesis_program")
    got = fly_trials(specs[::3], ro)
    assert [fx.row_of(r) for r in got] == recorded["thesis_program"]["rows"][::3]


def test_observers_watch_every_trial_of_a_batch(recorded):
    """Trace observers on trials in the middle of a batch write the recorded traces of those trials flown alone."""
    _, ro, specs = fx.specs_of("all_2d")
    with tempfile.TemporaryDirectory() as tmp:
        paths = {i: Path(tmp, f"{i}.npz") for i in (0, 17)}
        observers = [[TraceObserver(paths[i])] if i in paths else [] for i in range(len(specs))]
        rows = [fx.row_of(r) for r in fly_trials(specs[:20], ro, observers=observers[:20])]
        assert rows == recorded["all_2d"]["rows"][:20]
        for i, path in paths.items():
            assert fx.trace_digest(path) == recorded["all_2d"]["traces"][str(i)]


def _quickstart_specs(n_pairs: int):
    sc = load_scenario(SCENARIOS / "quickstart.toml")
    ms = get_map(sc, 0)
    ro = get_rollout(sc, ms)
    cands = sc.task.candidates
    pairs = sc.task.pairs()[::max(1, len(sc.task.pairs()) // n_pairs)][:n_pairs]
    specs = [make_trial_spec(sc, ms, planner="local_primitives", gaze="lookahead", v_max=4.0,
                             start=tuple(cands[i]), goal=tuple(cands[j])) for i, j in pairs]
    return ro, specs


class _RaisesFromTheRight(LocalPrimitives):
    """Local primitives that raise at the first plan of a trial that starts right of x = 40 m."""

    def plan(self, view):
        if view.t == 0.0 and view.position[0] > 40.0:
            raise RuntimeError("start x > 40")
        return super().plan(view)


def test_a_trial_that_raises_ends_only_itself():
    ro, specs = _quickstart_specs(12)
    odd = [with_planner_objects(s, trajectory=_RaisesFromTheRight) for s in specs]
    world = make_world(specs[0], ro)
    try:
        single = [run_trial(s, ro, world=world) for s in specs if s.start[0] < 40.0]
        together = fly_trials(odd, ro, world=world)
        with pytest.raises(ConfigError, match="start x > 40"):       # alone, what it raised is raised
            run_trial(next(s for s in odd if s.start[0] > 40.0), ro, world=world)
    finally:
        world.close()
    raised = [r for s, r in zip(specs, together) if s.start[0] > 40.0]
    assert raised and all(isinstance(r, Exception) and "start x > 40" in str(r) for r in raised)
    flown = [r for s, r in zip(specs, together) if s.start[0] < 40.0]
    names = ("planner", "planner_label", "config_hash")        # the plug-in's name, not its flight

    def flight(r):
        return {k: v for k, v in fx.row_of(r).items() if k not in names}
    assert [flight(r) for r in flown] == [flight(r) for r in single]


def test_share_rest_spreads_a_ticks_unmeasured_time_over_the_trials_that_stepped():
    a, b = _Log(0.0), _Log(0.0)
    a.step_walls, b.step_walls = [5.0, 2.0], [2.0]
    _share_rest([a, b], 10.0)                     # 10 s tick, 4 s measured: 3 s more each
    assert a.step_walls == [5.0, 5.0] and b.step_walls == [5.0]
    _share_rest([a], 1.0)                         # measured more than the tick (clock granularity): unchanged
    assert a.step_walls == [5.0, 5.0]
    _share_rest([], 1.0)


def test_step_times_account_for_the_loop_in_a_batch_and_alone():
    """A trial's wall_time_s is its setup plus its steps, and the steps hold all of the loop's work: the trials'
    times add up to the run's (less the results made at their ends)."""
    import time

    ro, specs = _quickstart_specs(8)
    world = make_world(specs[0], ro)
    try:
        fly_trials(specs[:1], ro, world=world)           # imports and compiled code in place before timing
        t0 = time.perf_counter()
        together = fly_trials(specs, ro, world=world)
        elapsed = time.perf_counter() - t0
        t0 = time.perf_counter()
        single = [run_trial(s, ro, world=world) for s in specs]
        elapsed_single = time.perf_counter() - t0
    finally:
        world.close()
    for results, total in ((together, elapsed), (single, elapsed_single)):
        covered = sum(r.wall_time_s for r in results)
        assert 0.85 * total < covered <= total, (covered, total)
        for r in results:       # 3% for the scheduler: a step's sensing split is timed apart from the rest
            steps = r.wall_timings["wall_step_mean_s"] * r.steps
            assert steps > 0.97 * sum(r.wall_timings[k] for k in SPLITS)


# ------------------------------------------------------------------------------------------------ the guarded step
def _open_batch(n: int = 1, dims: int = 2, **extra) -> TrialBatch:
    sc = open_scenario(dims=dims, **extra)
    start, goal = ((4.0, 4.0), (46.0, 46.0)) if dims == 2 else ((4.0, 4.0, 4.0), (46.0, 46.0, 16.0))
    specs = [make_trial_spec(sc, first_map(sc), start=start, goal=goal) for _ in range(n)]
    rollout = handmade_rollout(sc, np.zeros((0, dims)), np.zeros((0, dims)), np.zeros(0))
    batch = TrialBatch(specs, rollout)
    batch.start()
    return batch


def test_a_teleport_to_the_goal_ends_the_trial_as_invalid_plan():
    """The step a new user tried: Action(goal) from the start. Before the guard it ended as success."""
    with _open_batch() as batch:
        st = batch.states[0]
        goal = st.goal.copy()
        report = batch.step({0: Action(goal, np.zeros(2), np.zeros(2), 0.0)})
        assert report.ended == (0,) and report.refused == (0,) and not report.errors and batch.done
        with pytest.raises(dataclasses.FrozenInstanceError):
            report.ended = ()
        assert st.outcome is Outcome.INVALID_PLAN and st.steps == 0 and st.max_speed == 0.0
        assert st.reason.startswith("next state broke position_step:") and "a_max dt^2/4" in st.reason
        np.testing.assert_array_equal(st.position, [4.0, 4.0])


@pytest.mark.parametrize("what, make, check", [
    ("speed", lambda p, v, lim, dt: Action(p, np.array([lim.v_max * 1.01, 0.0]), np.zeros(2), 0.0), "speed"),
    ("acceleration", lambda p, v, lim, dt: Action(p, v, np.array([0.0, lim.a_max * 1.5]), 0.0), "acceleration"),
    ("velocity step", lambda p, v, lim, dt: Action(p + np.array([0.5 * lim.a_max * 1.2 * dt * dt, 0.0]),
                                                   np.array([lim.a_max * 1.2 * dt, 0.0]), np.zeros(2), 0.0),
     "velocity_step"),
    ("nan", lambda p, v, lim, dt: Action(p, np.array([math.nan, 0.0]), np.zeros(2), 0.0), "form"),
    ("shape", lambda p, v, lim, dt: Action(np.zeros(3), np.zeros(3), np.zeros(3), 0.0), "form"),
    ("yaw rate", lambda p, v, lim, dt: Action(p, v, np.zeros(2), math.inf), "form"),
])
def test_every_bound_of_the_guard_refuses_a_breach(what, make, check):
    with _open_batch() as batch:
        st = batch.states[0]
        batch.step({0: make(st.position, st.velocity, st.limits, st.dt)})
        assert st.outcome is Outcome.INVALID_PLAN and st.reason.startswith(f"next state broke {check}"), st.reason


def test_the_guard_lets_a_step_at_its_bounds_through_and_the_thesis_program_checks_the_form_only():
    with _open_batch() as batch:
        st = batch.states[0]
        a = np.array([st.limits.a_max, 0.0])
        v1 = st.velocity + a * st.dt
        at_bound = Action(st.position + 0.5 * (st.velocity + v1) * st.dt, v1, a, 0.0)
        assert breach(at_bound, st.position, st.velocity, st.limits, st.dt, True) is None
        far = Action(st.position + 1.0, np.zeros(2), np.zeros(2), 0.0)
        assert breach(far, st.position, st.velocity, st.limits, st.dt, False) is None
        assert "form" in breach(Action(st.position, np.zeros(2) * math.nan, np.zeros(2), 0.0), st.position,
                                st.velocity, st.limits, st.dt, False)


def test_random_acceleration_commands_never_take_the_mav_outside_its_limits():
    """1,000 steps of random (often far too large) acceleration commands in 2D and 3D: every executed step within
    v_max, a_max and the step bounds; the row reports no exceeded limit."""
    rng = np.random.default_rng(5)
    for dims in (2, 3):
        with _open_batch(dims=dims, world={"dims": dims, "time_limit": 200.0}) as batch:
            st = batch.states[0]
            lim, dt = st.limits, st.dt
            n = 0
            while not batch.done and n < 1000:
                p0, v0 = st.position, st.velocity
                cmd = rng.normal(0.0, 3.0 * lim.a_max, dims) * (1.0 if rng.random() < 0.7 else 10.0)
                batch.step({0: Accel(cmd, float(rng.normal(0.0, 5.0)))})
                if st.k:
                    assert np.linalg.norm(st.velocity) <= lim.v_max * (1 + 1e-12)
                    assert np.linalg.norm(st.acceleration) <= lim.a_max * (1 + 1e-12)
                    assert np.linalg.norm(st.velocity - v0) <= lim.a_max * dt * (1 + 1e-12)
                n += 1
            assert st.outcome is not Outcome.INVALID_PLAN, st.reason
            assert st.max_speed <= lim.v_max * (1 + 1e-9) and st.max_accel <= lim.a_max * (1 + 1e-9)


def test_an_acceleration_command_is_integrated_exactly_within_the_limits():
    with _open_batch() as batch:
        st = batch.states[0]
        lim, dt = st.limits, st.dt
        act = integrate(Accel(np.array([1.0, -2.0]), 0.3), st.position, st.velocity, lim, dt)
        np.testing.assert_array_equal(act.velocity, st.velocity + np.array([1.0, -2.0]) * dt)
        np.testing.assert_array_equal(act.position, st.position + 0.5 * (st.velocity + act.velocity) * dt)
        big = integrate(Accel(np.array([100.0, 0.0])), st.position, st.velocity, lim, dt)
        assert np.linalg.norm(big.acceleration) == pytest.approx(lim.a_max)
        fast = integrate(Accel(np.array([lim.a_max, 0.0])), st.position, np.array([lim.v_max, 0.0]), lim, dt)
        assert np.linalg.norm(fast.velocity) == pytest.approx(lim.v_max)
        with pytest.raises(ValueError, match="acceleration command"):
            integrate(Accel(np.array([1.0, math.nan])), st.position, st.velocity, lim, dt)
        with pytest.raises(ValueError, match="acceleration command"):
            integrate(Accel(np.array([1.0, 0.0, 0.0])), st.position, st.velocity, lim, dt)


def test_step_needs_one_action_per_running_trial_and_the_gui_one_trial():
    with _open_batch(n=2) as batch:
        with pytest.raises(ValueError, match="missing \\[1\\]"):
            batch.step({0: Accel(np.zeros(2))})
        with pytest.raises(ValueError, match="not wanted \\[5\\]"):
            batch.step({0: Accel(np.zeros(2)), 1: Accel(np.zeros(2)), 5: Accel(np.zeros(2))})
        batch.step({0: Accel(np.zeros(2)), 1: Accel(np.array([1.0, 1.0]))})
        assert batch.running == [0, 1] and batch.states[0].k == 1
    ro, specs = _quickstart_specs(2)
    with pytest.raises(ValueError, match="one trial"):
        TrialBatch(specs, ro, gui=True)


def test_one_switch_sets_the_agent_and_the_guard_and_a_bad_one_is_refused():
    """run_trial's execution="thesis_program" on a physical scenario: the agent executes on the program's 0.1 m
    pixels and the guard lets those steps through (the two rules agree: no invalid_plan); a bad value is one line."""
    ro, specs = _quickstart_specs(1)
    pixels = []

    class OnPixels:
        def on_step(self, state, agent, decision, record):
            assert not agent.physical
            pixels.append(np.array_equal(state.position * 10.0, np.round(state.position * 10.0)))

        def on_end(self, state, agent):
            pass

    r = run_trial(specs[0], ro, observers=[OnPixels()], execution="thesis_program")
    assert r.outcome != "invalid_plan" and len(pixels) == r.steps and all(pixels)
    assert not run_trial(specs[0], ro).limits_exceeded
    with pytest.raises(ValueError, match="execution must be one of physical, thesis_program"):
        run_trial(specs[0], ro, execution="program")
