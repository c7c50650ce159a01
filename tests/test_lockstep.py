"""Lockstep trials (pbdyn.sim.lockstep) give exactly the rows of trials flown one by one (run_trial), for every
built-in planner pair, in 2D and 3D, under the thesis_program profile, on walled and imported worlds; a trial that
raises ends only itself."""

from __future__ import annotations

import json

import pytest

from pbdyn.config import load_scenario
from pbdyn.planning.local_primitives import LocalPrimitives
from pbdyn.sim.lockstep import run_lockstep
from pbdyn.sim.trial import make_trial_spec, make_world, run_trial
from pbdyn.world.maps import get_map
from pbdyn.world.rollout import get_rollout
from tests.conftest import SCENARIOS

TRAJECTORY = ("local_primitives", "global_primitives", "mpc", "straight_line", "local_primitives_minjerk")
GAZE = ("lookahead", "fullrange", "lookgoal", "lookgoal_unexplored", "rotating", "finean", "owl")


def _row(result) -> str:
    row = result.without_wall_times()
    row.pop("planner_fingerprint", None)
    return json.dumps(row, sort_keys=True)


def _specs(sc, ms, combos, speeds, n_pairs):
    """TrialSpecs of (trajectory, gaze) combos x speeds x n_pairs start/goal pairs spread over the scenario's."""
    pairs = sc.task.pairs()
    cands = sc.task.candidates
    out = []
    for c, (traj, gaze) in enumerate(combos):
        for v in speeds:
            for i, j in pairs[c % 5::max(1, len(pairs) // n_pairs)][:n_pairs]:
                out.append(make_trial_spec(sc, ms, planner=traj, gaze=gaze, v_max=v, start=tuple(cands[i]),
                                           goal=tuple(cands[j])))
    return out


def _same_as_one_by_one(sc, map_index, specs):
    ms = get_map(sc, map_index)
    ro = get_rollout(sc, ms)
    world = make_world(specs[0], ro)
    try:
        single = [run_trial(s, ro, world=world) for s in specs]
        together = run_lockstep(specs, ro, world)
    finally:
        world.close()
    assert len(together) == len(single)
    for a, b in zip(single, together):
        assert not isinstance(b, BaseException), b
        assert _row(b) == _row(a)
        assert b.wall_time_s > 0 and set(b.wall_timings) == set(a.wall_timings)
    return single


@pytest.mark.parametrize("scenario, map_index", [("quickstart.toml", 4), ("spheres_3d.toml", 1)])
def test_lockstep_rows_are_bit_identical_to_one_by_one_for_every_built_in_planner(scenario, map_index):
    sc = load_scenario(SCENARIOS / scenario)
    ms = get_map(sc, map_index)
    combos = [(t, GAZE[k % len(GAZE)]) for k, t in enumerate(TRAJECTORY)] + \
             [("local_primitives", g) for g in GAZE]
    speeds = (2.0, 6.0) if sc.world.dims == 2 else (4.0,)
    specs = _specs(sc, ms, combos, speeds, 3 if sc.world.dims == 2 else 2)
    single = _same_as_one_by_one(sc, map_index, specs)
    outcomes = {r.outcome for r in single}
    assert "success" in outcomes and len(outcomes) >= 2, outcomes     # trials end at different ticks


def test_lockstep_under_the_thesis_program_profile():
    """Marching sensor, the program's start-dependent obstacle layouts (one rollout per start), program planners."""
    sc = load_scenario(SCENARIOS / "thesis" / "controlled_2d.toml")
    ms = get_map(sc, 13)
    combos = [(e.label, None) for e in sc.planners if "MPC" not in e.label][:4]
    specs = []
    pairs = sc.task.pairs()
    for c, (label, _) in enumerate(combos):
        for v in (2.0, 6.0):
            for i, j in pairs[c::17]:
                specs.append(make_trial_spec(sc, ms, planner=label, v_max=v, start=tuple(sc.task.candidates[i]),
                                             goal=tuple(sc.task.candidates[j])))
    _same_as_one_by_one(sc, 13, specs)


def test_lockstep_on_walled_and_imported_worlds():
    """Static walls (a structured map) and an imported world whose moving bodies are posed by their real shapes."""
    sc = load_scenario(SCENARIOS / "datasets" / "structured_2d.toml")
    walled = next(i for i in range(60) if get_map(sc, i).setup.get("structure") == "walls")
    ms = get_map(sc, walled)
    _same_as_one_by_one(sc, walled, _specs(sc, ms, [("local_primitives", "lookahead")], (4.0,), 6))
    world = load_scenario(SCENARIOS / "worlds" / "warehouse_2d.toml")
    ms = get_map(world, 0)
    _same_as_one_by_one(world, 0, _specs(world, ms, [("local_primitives", "lookahead"), ("straight_line", "owl")],
                                         (4.0,), 4))


class _RaisesFromTheRight(LocalPrimitives):
    """Local primitives that raise at the first plan of a trial that starts right of x = 40 m."""

    def plan(self, view):
        if view.t == 0.0 and view.position[0] > 40.0:
            raise RuntimeError("start x > 40")
        return super().plan(view)


def _quickstart_local_primitives(n_pairs):
    """(rollout, specs of local primitives + LookAhead at 4 m/s on n_pairs start/goal pairs, world) of quickstart
    map 0; the caller closes the world."""
    sc = load_scenario(SCENARIOS / "quickstart.toml")
    ms = get_map(sc, 0)
    ro = get_rollout(sc, ms)
    specs = _specs(sc, ms, [("local_primitives", "lookahead")], (4.0,), n_pairs)
    return ro, specs, make_world(specs[0], ro)


def test_a_trial_that_raises_ends_only_itself():
    ro, specs, world = _quickstart_local_primitives(12)
    try:
        single = [run_trial(s, ro, world=world) for s in specs if s.start[0] < 40.0]
        from pbdyn.sim.spec import with_planner_objects

        odd = [with_planner_objects(s, trajectory=_RaisesFromTheRight) for s in specs]
        together = run_lockstep(odd, ro, world)
    finally:
        world.close()
    raised = [r for s, r in zip(specs, together) if s.start[0] > 40.0]
    assert raised and all(isinstance(r, Exception) and "start x > 40" in str(r) for r in raised)
    flown = [r for s, r in zip(specs, together) if s.start[0] < 40.0]
    assert [r.outcome for r in flown] == [r.outcome for r in single]
    assert [r.steps for r in flown] == [r.steps for r in single]


def test_share_rest_spreads_a_ticks_unmeasured_time_over_the_trials_that_stepped():
    from pbdyn.sim.lockstep import _share_rest, _Trial

    a, b = _Trial(0, None, 0.0), _Trial(1, None, 0.0)
    a.step_walls, b.step_walls = [5.0, 1.0], [3.0]
    _share_rest([a, b], 10.0)                     # 10 s tick, 4 s measured: 3 s more each
    assert a.step_walls == [5.0, 4.0] and b.step_walls == [6.0]
    _share_rest([a], 1.0)                         # measured more than the tick (clock granularity): unchanged
    assert a.step_walls == [5.0, 4.0]
    _share_rest([], 1.0)


def test_step_times_account_for_the_loop_in_lockstep_and_one_by_one():
    """A trial's wall_time_s is its setup plus its steps, and the steps hold all of the loop's work: the trials'
    times add up to the run's (less the results made at their ends), where the measured step parts alone left
    about a fifth of it out."""
    import time

    from pbdyn.sim.observers import SPLITS

    ro, specs, world = _quickstart_local_primitives(8)
    try:
        run_lockstep(specs[:1], ro, world)        # imports and compiled code in place before timing
        t0 = time.perf_counter()
        together = run_lockstep(specs, ro, world)
        elapsed = time.perf_counter() - t0
        t0 = time.perf_counter()
        single = [run_trial(s, ro, world=world) for s in specs]
        elapsed_single = time.perf_counter() - t0
    finally:
        world.close()
    for results, total in ((together, elapsed), (single, elapsed_single)):
        covered = sum(r.wall_time_s for r in results)
        assert 0.9 * total < covered <= total, (covered, total)
        for r in results:       # 3% for the scheduler: a step's sensing split is the previous step's, timed apart
            steps = r.wall_timings["wall_step_mean_s"] * r.steps
            assert steps > 0.97 * sum(r.wall_timings[k] for k in SPLITS)
