"""The 3D core end to end: spheres in a volume, depth camera, voxel grid, 3D local primitives, RVO in trials."""

from __future__ import annotations

import numpy as np

from pbdyn.config import load_scenario, parse_scenario
from pbdyn.sim.trial import make_trial_spec, run_trial
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout
from tests.conftest import SCENARIOS
from tests.helpers import first_map, fly, handmade_rollout, open_scenario


def _scenario(**extra):
    if "world" in extra:
        extra["world"] = {"dims": 3, "time_limit": 40.0, **extra["world"]}
    return open_scenario(3, **extra)


_fly = fly


def test_3d_crossing_sphere_straight_line_collides_local_primitives_avoid(tmp_path):
    sc = _scenario()
    start, goal = (4.0, 25.0, 10.0), (46.0, 25.0, 10.0)
    rollout = handmade_rollout(sc, [[25.0, 13.5, 10.0]], [[0.0, 2.0, 0.0]], [1.5])
    sl = _fly(sc, rollout, "lookahead+straight_line", start, goal)
    assert sl.outcome == "dynamic_collision"
    empty = handmade_rollout(sc, np.zeros((0, 3)), np.zeros((0, 3)), [])
    sl_time = _fly(sc, empty, "lookahead+straight_line", start, goal).flight_time_s
    trace = tmp_path / "t3.npz"
    res = _fly(sc, rollout, "lookahead+local_primitives", start, goal, trace_path=trace)
    assert res.outcome == "success" and res.min_clearance_m >= 0.0
    assert res.flight_time_s <= 1.5 * sl_time
    with np.load(trace) as z:
        assert z["p"].shape[1] == 3 and not z["seen"][0].any() and z["seen"].any()
        assert np.linalg.norm(z["v"], axis=1).max() <= 4.0 + 1e-9
        assert np.linalg.norm(z["a"], axis=1).max() <= 4.0 + 1e-9


def test_sampled_3d_pairs_succeed_in_an_empty_volume():
    sc = _scenario(task={"candidates": [[x, y, z] for x in (4.0, 25.0, 46.0) for y in (4.0, 46.0)
                                        for z in (4.0, 16.0)]})
    rollout = build_rollout(sc, first_map(sc))
    pairs = sc.task.pairs()
    rng = np.random.default_rng(0)
    cands = sc.task.candidates
    for k in rng.choice(len(pairs), size=10, replace=False):
        i, j = pairs[k]
        res = _fly(sc, rollout, "lookahead+local_primitives", cands[i], cands[j])
        assert res.outcome == "success", (cands[i], cands[j], res.outcome)


def test_3d_static_geometry_is_three_dimensional():
    # a low wall on the floor (z in [0, 6]) across the arena: blocks flight at z = 3, not at z = 15
    sc = _scenario(static_obstacles=[{"kind": "box", "center": [25.0, 25.0, 3.0], "size": [2.0, 50.0, 6.0]}])
    rollout = build_rollout(sc, first_map(sc))
    low = _fly(sc, rollout, "lookahead+straight_line", (4.0, 25.0, 3.0), (46.0, 25.0, 3.0))
    assert low.outcome == "static_collision"
    high = _fly(sc, rollout, "lookahead+straight_line", (4.0, 25.0, 15.0), (46.0, 25.0, 15.0))
    assert high.outcome == "success" and high.min_clearance_m > 2.9  # the start is 3 m from the x = 0 wall
    # the greedy local planner stops in front of the wall (a local minimum) but never touches it
    stuck = _fly(sc, rollout, "lookahead+local_primitives", (4.0, 25.0, 3.0), (46.0, 25.0, 3.0))
    assert stuck.outcome == "freezing" and stuck.min_clearance_m >= 0.0


def test_bundled_3d_scenarios_fly_with_cvm_and_rvo():
    sc = load_scenario(SCENARIOS / "spheres_3d.toml")
    spec_map = enumerate_maps(sc)[0]
    rollout = build_rollout(sc, spec_map)
    res = run_trial(make_trial_spec(sc, spec_map), rollout)
    assert res.outcome in ("success", "dynamic_collision", "static_collision", "freezing", "deadlock")
    assert res.grid_discovered > 1000  # a voxel map, not a plane
    rvo = parse_scenario({"world": {"dims": 3, "time_limit": 20.0},
                          "obstacles": {"count": 15, "motion": "rvo", "speed": 3.0}, "drone": {"v_max": 4.0}})
    spec_rvo = enumerate_maps(rvo)[0]
    res = run_trial(make_trial_spec(rvo, spec_rvo), build_rollout(rvo, spec_rvo))
    assert res.motion_profile == "rvo" and res.steps > 10
