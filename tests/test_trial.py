"""The trial loop end to end in real PyBullet worlds: outcomes, the avoidance benchmark, limits and traces."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout
from tests.helpers import PLANNERS, first_map, fly, handmade_rollout, open_scenario


def _scenario(**extra):
    if "world" in extra:
        extra["world"] = {"dims": 2, "time_limit": 40.0, **extra["world"]}
    return open_scenario(2, **extra)


_fly = fly


def test_side_crossing_obstacle_straight_line_collides_lookahead_local_avoids(tmp_path):
    sc = _scenario()
    start, goal = (4.0, 25.0), (46.0, 25.0)
    # An obstacle 20 m to the side, unseen at t = 0, timed to cross the straight path when the MAV gets there.
    rollout = handmade_rollout(sc, [[25.0, 13.5]], [[0.0, 2.0]], [1.5])
    sl = _fly(sc, rollout, "lookahead+straight_line", start, goal)
    assert sl.outcome == "dynamic_collision", sl
    empty = handmade_rollout(sc, np.zeros((0, 2)), np.zeros((0, 2)), [])
    sl_time = _fly(sc, empty, "lookahead+straight_line", start, goal).flight_time_s
    trace = tmp_path / "cross.npz"
    res = _fly(sc, rollout, "lookahead+local_primitives", start, goal, trace_path=trace)
    assert res.outcome == "success", res
    with np.load(trace) as z:
        assert not z["seen"][0].any() and z["seen"].any()  # unseen at t = 0, seen later
    assert res.min_clearance_m >= 0.0
    assert res.flight_time_s <= 1.5 * sl_time
    assert res.obstacles_tracked == 1 and res.tracked_time_s > 0


def test_all_72_pairs_succeed_in_an_empty_arena():
    sc = _scenario()
    rollout = build_rollout(sc, first_map(sc))
    assert rollout.n_obstacles == 0
    cands = sc.task.candidates
    bad = []
    for i, j in sc.task.pairs():
        res = _fly(sc, rollout, "lookahead+local_primitives", cands[i], cands[j])
        if res.outcome != "success":
            bad.append((cands[i], cands[j], res.outcome))
    assert not bad


def test_executed_states_respect_norm_limits(tmp_path):
    sc = parse_scenario({"world": {"time_limit": 30.0},
                         "obstacles": {"count": 20, "radius": 1.0, "speed": 4.0, "root_seed": 3},
                         "drone": {"v_max": 6.0}, "planners": PLANNERS})
    spec_map = first_map(sc)
    rollout = build_rollout(sc, spec_map)
    for planner in ("lookahead+local_primitives", "lookahead+straight_line"):
        path = tmp_path / f"{planner}.npz"
        _fly(sc, rollout, planner, (4.0, 4.0), (46.0, 46.0), trace_path=path)
        with np.load(path) as z:
            v, a, rate = z["v"], z["a"], z["yaw_rate"]
            speeds = np.linalg.norm(np.vstack([v, z["final_v"]]), axis=1)
            accs = np.linalg.norm(np.vstack([a, z["final_a"]]), axis=1)
        assert speeds.max() <= 6.0 + 1e-9
        assert accs.max() <= 4.0 + 1e-9
        assert np.abs(rate).max() <= 1.4 + 1e-12
        assert speeds.max() > 3.0  # it really flew


def test_static_collision_with_a_pillar():
    sc = _scenario(static_obstacles=[{"kind": "pillar", "center": [25.0, 25.0], "radius": 2.0}],
                   task={"candidates": [[4.0, 25.0], [46.0, 25.0]]})   # no candidate on the pillar
    rollout = build_rollout(sc, first_map(sc))
    res = _fly(sc, rollout, "lookahead+straight_line", (4.0, 25.0), (46.0, 25.0))
    assert res.outcome == "static_collision"
    assert res.min_clearance_m <= 1e-3
    ok = _fly(sc, rollout, "lookahead+local_primitives", (4.0, 25.0), (46.0, 25.0))
    assert ok.outcome == "success" and ok.min_clearance_m > 0


def test_deadlock_when_boxed_in():
    walls = [{"kind": "box", "center": c, "size": s} for c, s in
             (([25.0, 28.5], [8.0, 1.0]), ([25.0, 21.5], [8.0, 1.0]), ([28.5, 25.0], [1.0, 8.0]),
              ([21.5, 25.0], [1.0, 8.0]))]
    sc = _scenario(static_obstacles=walls, task={"candidates": [[25.0, 25.0], [46.0, 46.0]]})
    rollout = build_rollout(sc, first_map(sc))
    res = _fly(sc, rollout, "fullrange+local_primitives", (25.0, 25.0), (46.0, 46.0))
    assert res.outcome == "deadlock", res
    assert res.planning_failures >= 10 and res.final_state == "PLANNING"


def test_freezing_at_the_time_limit():
    sc = _scenario(world={"time_limit": 2.0})
    rollout = build_rollout(sc, first_map(sc))
    res = _fly(sc, rollout, "lookahead+local_primitives", (4.0, 4.0), (46.0, 46.0))
    assert res.outcome == "freezing" and res.steps == 20 and res.flight_time_s == pytest.approx(2.0)


def test_fullrange_sees_behind_and_lookahead_does_not():
    sc = _scenario()
    # obstacle right behind the start, moving away from the MAV's path
    rollout = handmade_rollout(sc, [[0.0 + 1.6, 25.0]], [[0.0, 0.0]], [0.5])
    fr = _fly(sc, rollout, "fullrange+local_primitives", (6.0, 25.0), (46.0, 25.0))
    la = _fly(sc, rollout, "lookahead+local_primitives", (6.0, 25.0), (46.0, 25.0))
    assert fr.obstacles_tracked == 1
    assert la.obstacles_tracked == 0
    assert fr.grid_discovered > la.grid_discovered


def test_trace_contents(tmp_path):
    sc = _scenario(obstacles={"count": 10, "radius": 1.0, "speed": 2.0})
    spec_map = enumerate_maps(sc)[0]
    rollout = build_rollout(sc, spec_map)
    path = tmp_path / "trace.npz"
    res = _fly(sc, rollout, "lookahead+local_primitives", (4.0, 4.0), (46.0, 46.0), trace_path=path)
    with np.load(path) as z:
        assert z["p"].shape == (res.steps, 2) and z["track_mean"].shape == (res.steps, 10, 2)
        assert str(z["outcome"]) == res.outcome
        assert np.allclose(z["p"][0], [4.0, 4.0])
        assert np.isfinite(z["plan"][0]).any()
        assert z["seen"].any() == (res.obstacles_tracked > 0)


def test_the_config_hash_is_computed_once_per_trial(monkeypatch):
    """The spec is resolved once: run_trial hashes the resolved trial spec a single time (imported worlds pay ~7 ms
    per hash for their bodies' fingerprints)."""
    from pbdyn.sim.spec import TrialSpec
    from pbdyn.sim.trial import make_trial_spec, run_trial
    from pbdyn.world.rollout import get_rollout
    from tests.conftest import SCENARIOS

    from pbdyn.config import load_scenario
    from pbdyn.world.maps import get_map

    calls = []
    original = TrialSpec.resolved
    monkeypatch.setattr(TrialSpec, "resolved", lambda self: calls.append(1) or original(self))
    sc = load_scenario(SCENARIOS / "worlds" / "warehouse_2d.toml")
    ms = get_map(sc, 0)
    spec = make_trial_spec(sc, ms)
    res = run_trial(spec, get_rollout(sc, ms))
    assert res.config_hash == spec.config_hash and len(calls) == 1
