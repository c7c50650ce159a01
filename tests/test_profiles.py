"""Profiles (docs/profiles.md "Profiles", docs/design.md "Profiles") and the start rules (pbdyn.sim.start)."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pbdyn.config import PROFILE_DEFAULTS, parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.experiments.evaluate import load_results
from pbdyn.experiments.runner import BatchOptions, run_batch
from pbdyn.experiments.store import ResultsStore
from pbdyn.metrics.cached import PROFILE_METRIC_PARAMS, metric_params
from pbdyn.planning.trajectory import Trajectory
from pbdyn.sim.spec import make_trial_spec
from pbdyn.sim.start import first_clear_step, start_gaps, trial_start
from pbdyn.sim.trial import run_trial
from pbdyn.world.maps import get_map
from pbdyn.world.rollout import build_rollout
from tests.helpers import first_map, handmade_rollout, open_scenario

ROOT = Path(__file__).resolve().parents[1]


def _scenario(profile: str | None = None, **extra):
    doc = {"world": {"time_limit": 20.0}, "obstacles": {"count": 20, "radius": 1.0, "speed": 4.0},
           "drone": {"v_max": 4.0}, "planners": [{"trajectory": "local_primitives", "gaze": "fullrange"}],
           "task": {"candidates": [[4.0, 4.0], [25.0, 25.0], [46.0, 46.0]]}}
    if profile is not None:
        doc["profile"] = profile
    for k, v in extra.items():
        doc[k] = {**doc.get(k, {}), **v}
    return parse_scenario(doc)


def _readme_section(title: str) -> str:
    text = (ROOT / "docs" / "profiles.md").read_text(encoding="utf-8")
    m = re.search(rf"^## {title}\n(.*?)(?=^## )", text, re.S | re.M)
    assert m, f"README has no {title!r} section"
    return m.group(1)


# ---------------------------------------------------------------------------------------------- configuration
def test_profile_defaults_apply_to_omitted_fields_only_and_the_readme_lists_them():
    sc = _scenario("thesis_program")
    assert sc.profile == "thesis_program" and not sc.physical
    for (section, key), value in PROFILE_DEFAULTS["thesis_program"].items():
        assert getattr(getattr(sc, section) if section else sc, key) == value
    given = _scenario("thesis_program", task={"start_rule": "immediate", "start_clearance": 2.0})
    assert (given.task.start_rule, given.task.start_clearance) == ("immediate", 2.0)
    phys = _scenario()
    assert phys.profile == "physical" and phys.physical and phys.task.start_rule == "first_clear"
    rows = re.findall(r"^\| `(\w+)` \| `(?:([a-z_]+)\.)?([a-z_]+)` \| `([^`]+)` \|", _readme_section("Profiles"), re.M)
    listed = {(p, (s, k)): v for p, s, k, v in rows}
    expected = {(p, sk): v for p, table in PROFILE_DEFAULTS.items() for sk, v in table.items()}
    assert set(listed) == set(expected)
    for key, value in expected.items():
        assert tomllib.loads(f"v = {listed[key]}")["v"] == value, key


def test_readme_lists_the_profiles_metric_parameters():
    section = _readme_section("Profiles")
    for profile, table in PROFILE_METRIC_PARAMS.items():
        for name, params in table.items():
            row = next((ln for ln in section.splitlines() if f"`{profile}`" in ln and f"`{name}`" in ln), None)
            assert row, f"README Profiles: no row for {profile} {name}"
            for k, v in params.items():
                assert f"`{k} = {v}`" in row, (row, k, v)
    for traj in ("global_primitives", "mpc"):
        row = next(ln for ln in section.splitlines() if f"trajectory `{traj}`" in ln)
        assert "PROGRAM_PARAMS" in row
    sc = _scenario("thesis_program")
    assert metric_params(sc, "vo_feasibility", "analytic")["mav_radius"] == 0.5
    assert metric_params(sc, "dynamic_traversability", "analytic")["marking"] == "program"
    assert metric_params(_scenario(), "vo_feasibility", "analytic")["mav_radius"] == 1.0


@pytest.mark.parametrize("doc, field", [
    ({"profile": "thesis"}, "profile"),
    ({"profile": 3}, "profile"),
    ({"task": {"start_rule": "later"}}, "task.start_rule"),
    ({"task": {"start_clearance": -1.0}}, "task.start_clearance"),
    ({"task": {"start_window_s": float("nan")}}, "task.start_window_s"),
    ({"task": {"start_wait_max_s": 1e6}}, "task.start_wait_max_s"),
])
def test_bad_profile_and_start_fields_name_the_field(doc, field):
    with pytest.raises(ConfigError) as e:
        parse_scenario(doc)
    assert e.value.field == field


def test_the_config_hash_depends_on_the_profile():
    a = make_trial_spec(_scenario(task={"start_rule": "program", "start_clearance": 7.0}), get_map(_scenario(), 0))
    b = make_trial_spec(_scenario("thesis_program"), get_map(_scenario(), 0))
    assert a.resolved()["profile"] == "physical" and b.resolved()["profile"] == "thesis_program"
    assert a.config_hash != b.config_hash


# ---------------------------------------------------------------------------------------------- the contract
class JumpyPlanner:
    """Plans a straight 1-sample burst toward the goal at 8x a_max (breaks |a| <= a_max, keeps continuity)."""

    def __init__(self, context, **params):
        self.context = context

    def replan_check(self, view):
        return True

    def plan(self, view):
        g = view.goal - view.position
        u = g / np.linalg.norm(g)
        a = 8.0 * view.limits.a_max * u
        v1 = view.velocity + a * view.dt
        speed = np.linalg.norm(v1)
        if speed > view.limits.v_max:
            v1 = v1 * view.limits.v_max / speed
            a = (v1 - view.velocity) / view.dt
        p1 = view.position + 0.5 * (view.velocity + v1) * view.dt
        return Trajectory(view.t, view.dt, np.stack([view.position, p1]), np.stack([view.velocity, v1]),
                          np.stack([a, a]))


def test_thesis_program_executes_over_limit_plans_and_records_the_excess():
    phys = open_scenario(task={"start_rule": "immediate"})
    prog = open_scenario(profile="thesis_program")
    for sc, expect in ((phys, "invalid_plan"), (prog, "success")):
        spec = make_trial_spec(sc, first_map(sc), start=(4.0, 4.0), goal=(46.0, 46.0))
        rollout = handmade_rollout(sc, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        r = run_trial(spec, rollout, trajectory_planner=JumpyPlanner)
        assert r.outcome == expect, r.reason
        assert r.profile == sc.profile
    assert r.max_accel_mps2 > 4.0 * 7.9 and r.max_speed_mps <= 4.0 + 1e-9
    assert r.limits_exceeded.startswith("acceleration") and "a_max 4" in r.limits_exceeded
    ok = run_trial(make_trial_spec(phys, first_map(phys), start=(4.0, 4.0), goal=(46.0, 46.0)),
                   handmade_rollout(phys, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)))
    assert ok.outcome == "success" and ok.limits_exceeded == "" and ok.profile == "physical"
    assert 4.0 - 1e-6 < ok.max_speed_mps <= 4.0 + 1e-9 and 0.0 < ok.max_accel_mps2 <= 4.0 * (1 + 1e-9)


# ---------------------------------------------------------------------------------------------- start rules
def test_first_clear_step_takes_the_first_window_that_stays_clear():
    gaps = np.array([5.0, 0.5, 2.0, 2.0, 0.2, 2.0, 2.0, 2.0, 2.0, 0.0])
    assert first_clear_step(gaps, 1.0, window=1, max_wait=7) == (2, True)
    assert first_clear_step(gaps, 1.0, window=2, max_wait=7) == (5, True)
    assert first_clear_step(gaps, 1.0, window=0, max_wait=7) == (0, True)
    k, clear = first_clear_step(np.array([0.1, 0.3, 0.2, 0.3, 0.3, 0.0]), 1.0, window=1, max_wait=4)
    assert (k, clear) == (3, False)        # the window keeping the largest gap (0.3)
    with pytest.raises(ValueError):
        first_clear_step(gaps, 1.0, window=5, max_wait=7)


def test_first_clear_waits_for_an_obstacle_crossing_the_start():
    sc = open_scenario(obstacles={"count": 1})
    # an obstacle of radius 1 m crossing the start (4, 25) at 4 m/s: it is within 1 m of the MAV disc from t = 0.25 to 1.75 s
    rollout = handmade_rollout(sc, [[4.0, 29.0]], [[0.0, -4.0]], [1.0])
    spec = make_trial_spec(sc, first_map(sc), planner="lookahead+local_primitives", start=(4.0, 25.0),
                           goal=(46.0, 25.0))
    st = trial_start(spec, rollout)
    gaps = start_gaps(rollout, np.array([4.0, 25.0]), 1.0, rollout.n_steps)
    assert st.clear and st.k0 > 0
    assert np.all(gaps[st.k0:st.k0 + 11] >= 1.0) and np.any(gaps[st.k0 - 1:st.k0 + 10] < 1.0)
    r = run_trial(spec, rollout)
    assert r.start_delay_s == pytest.approx(st.time_s) and r.start_delay_s == pytest.approx(1.8)
    assert r.outcome == "success"
    immediate = open_scenario(obstacles={"count": 1}, task={"start_rule": "immediate"})
    spec0 = make_trial_spec(immediate, first_map(immediate), planner="lookahead+local_primitives", start=(4.0, 25.0),
                            goal=(46.0, 25.0))
    assert trial_start(spec0, rollout).k0 == 0 and run_trial(spec0, rollout).start_delay_s == 0.0


def test_the_program_rule_respawns_around_the_flown_start_only():
    sc = _scenario("thesis_program", obstacles={"count": 30, "radius": 1.5})
    ms = get_map(sc, 0)
    base = build_rollout(sc, ms)
    starts = [(4.0, 4.0), (25.0, 25.0)]
    variants, inner = [], 0
    for s in starts:
        spec = make_trial_spec(sc, ms, start=s, goal=(46.0, 46.0))
        st = trial_start(spec, base)
        assert st.k0 == 0 and st.rollout is not base
        centre = np.linalg.norm(st.rollout.positions[0] - np.array(s), axis=1)
        assert centre.min() > 8.0                              # no obstacle CENTRE within 8 m of the start
        inner += int(np.sum(centre - st.rollout.radii < 8.0))  # discs may reach into the circle (the program's rule)
        np.testing.assert_array_equal(st.rollout.radii, base.radii)
        speeds = np.linalg.norm(st.rollout.velocities[0], axis=1)
        np.testing.assert_allclose(speeds, np.linalg.norm(base.velocities[0], axis=1))
        assert trial_start(spec, base).rollout is st.rollout   # cached per process
        variants.append(st.rollout)
    for seed in range(1, 6):    # and over more maps, some disc does reach into the 8 m circle
        other = _scenario("thesis_program", obstacles={"count": 30, "radius": 1.5, "root_seed": seed})
        st = trial_start(make_trial_spec(other, get_map(other, 0), start=(25.0, 25.0), goal=(46.0, 46.0)),
                         build_rollout(other, get_map(other, 0)))
        centre = np.linalg.norm(st.rollout.positions[0] - 25.0, axis=1)
        assert centre.min() > 8.0
        inner += int(np.sum(centre - st.rollout.radii < 8.0))
    assert inner > 0
    assert not np.array_equal(variants[0].positions[0], variants[1].positions[0])
    # the map the metrics see keeps every candidate's 1 m clearance and is not the flown layout
    assert not np.array_equal(variants[0].positions[0], base.positions[0])
    again = build_rollout(sc, ms, keep_out=(np.array([starts[0]]), 7.0))
    np.testing.assert_array_equal(again.positions, variants[0].positions)


def test_start_yaw_faces_the_goal_or_the_given_angle():
    from pbdyn.sim.batch import TrialBatch

    for task, want in (({}, math.atan2(21.0, 42.0)), ({"start_yaw_deg": 90.0}, math.pi / 2),
                       ({"start_yaw_deg": -270.0}, math.pi / 2), ({"start_yaw_deg": "goal"}, math.atan2(21.0, 42.0))):
        sc = open_scenario(task=task)
        spec = make_trial_spec(sc, first_map(sc), start=(4.0, 4.0), goal=(46.0, 25.0))
        with TrialBatch([spec], handmade_rollout(sc, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))) as batch:
            batch.start()
            assert batch.states[0].yaw == pytest.approx(want), task
    assert _scenario("thesis_program").task.start_yaw_deg == 90.0


@pytest.mark.parametrize("where, k", [("current", 0), ("next", 1)])
def test_obstacles_at_next_senses_the_obstacles_one_step_ahead(where, k):
    """The program moved its obstacles before the MAV sensed: with sensor.obstacles_at = "next" the scan at t_k
    measures the centres at t_k+1; the collision check still uses t_k+1 against the MAV at t_k+1."""
    from pbdyn.sim.batch import TrialBatch

    sc = open_scenario(obstacles={"count": 1}, sensor={"obstacles_at": where, "fov_deg": 360.0})
    rollout = handmade_rollout(sc, [[10.0, 4.0]], [[0.0, 3.0]], [1.0])
    spec = make_trial_spec(sc, first_map(sc), start=(4.0, 4.0), goal=(46.0, 4.0))
    with TrialBatch([spec], rollout) as batch:
        batch.start()
        env = batch.states[0]
        np.testing.assert_allclose(env.detections.centers, rollout.at(k)[0])
        np.testing.assert_allclose(env.tracks.position, rollout.at(k)[0])
    assert _scenario("thesis_program").sensor.obstacles_at == "next"


def test_imported_worlds_refuse_the_program_rule():
    with pytest.raises(ConfigError) as e:
        parse_scenario({"bodies": [{"urdf": "sphere.urdf", "position": [20.0, 20.0]}],
                        "task": {"start_rule": "program"}})
    assert e.value.field == "task.start_rule"


def test_the_trace_holds_the_obstacles_of_the_flown_steps(tmp_path):
    sc = open_scenario(obstacles={"count": 1})
    rollout = handmade_rollout(sc, [[4.0, 29.0]], [[0.0, -4.0]], [1.0])
    spec = make_trial_spec(sc, first_map(sc), planner="lookahead+local_primitives", start=(4.0, 25.0),
                           goal=(46.0, 25.0))
    r = run_trial(spec, rollout, trace_path=tmp_path / "t.npz")
    tr = np.load(tmp_path / "t.npz")
    k0 = int(tr["start_step"])
    assert k0 == round(r.start_delay_s / 0.1) > 0
    np.testing.assert_array_equal(tr["obstacle_p"], rollout.positions[k0:k0 + r.steps + 1])


# ---------------------------------------------------------------------------------------------- stores
def test_a_store_holds_one_profile_and_evaluate_refuses_to_pool_profiles(tmp_path):
    doc = {"name": "p1", "world": {"time_limit": 10.0}, "obstacles": {"count": 5},
           "drone": {"v_max": 4.0}, "task": {"candidates": [[4.0, 4.0], [46.0, 46.0]]},
           "planners": [{"trajectory": "straight_line", "gaze": "lookahead"}]}
    phys = parse_scenario(doc)
    prog = parse_scenario({**doc, "name": "p2", "profile": "thesis_program"})
    opts = BatchOptions(workers=1, progress=False, metrics=False)
    run_batch(phys, tmp_path / "a.sqlite", opts)
    with pytest.raises(ConfigError) as e:
        run_batch(parse_scenario({**doc, "profile": "thesis_program"}), tmp_path / "a.sqlite", opts)
    assert "one profile" in str(e.value)
    run_batch(prog, tmp_path / "b.sqlite", opts)
    for path, profile in ((tmp_path / "a.sqlite", "physical"), (tmp_path / "b.sqlite", "thesis_program")):
        store = ResultsStore.open(path)
        try:
            rows = store.results()
        finally:
            store.close()
        assert len(rows) == 2 and {r["profile"] for r in rows} == {profile}
    with pytest.raises(ConfigError) as e:
        load_results([tmp_path / "a.sqlite", tmp_path / "b.sqlite"])
    assert "mixes profiles" in str(e.value)


def test_thesis_program_gives_built_in_planners_their_program_parameters():
    from pbdyn.planning.primitives.global_astar import GlobalPrimitives
    from pbdyn.planning.mpc.planner import MPC
    from pbdyn.sim.agent import Agent

    for profile in ("physical", "thesis_program"):
        for traj, cls in (("global_primitives", GlobalPrimitives), ("mpc", MPC)):
            sc = parse_scenario({
                "profile": profile, "planners": [{"trajectory": traj, "gaze": "fullrange",
                                                  "trajectory_params": {"margin": 0.4}}]})
            agent = Agent(make_trial_spec(sc, get_map(sc, 0)))
            assert agent.context.physical == (profile == "physical") and agent.physical == agent.context.physical
            assert agent.planner.margin == 0.4                       # an explicit parameter wins
            if traj == "global_primitives":
                assert (agent.planner.max_expansions == cls.PROGRAM_PARAMS["max_expansions"]) == \
                    (profile == "thesis_program")
            else:
                assert (agent.planner.prediction == "program") == (profile == "thesis_program")
        sc = parse_scenario({"profile": profile, "task": {"start_yaw_deg": 90.0},
                             "planners": [{"trajectory": "local_primitives_minjerk", "gaze": "lookahead"}]})
        agent = Agent(make_trial_spec(sc, get_map(sc, 0), start=(4.0, 4.0), goal=(46.0, 4.0)))
        assert agent.gaze.at_rest == ("hold" if profile == "thesis_program" else "plan")
        from pbdyn.sim.batch import TrialBatch
        with TrialBatch([agent.spec], build_rollout(sc, get_map(sc, 0)), agents=[agent]) as batch:
            batch.start()                             # at rest facing +y; the goal lies along +x
            d = agent.act(batch.view(0, agent.trajectory))
        assert (d.action.yaw_rate == 0.0) == (profile == "thesis_program")


def test_every_thesis_combo_flies_under_the_thesis_program_profile():
    """scenarios/thesis: each of the 18 program combos flies a trial with the program's sensor and start rule."""
    from pbdyn.config import load_scenario
    from pbdyn.world.rollout import get_rollout

    sc = load_scenario(ROOT / "scenarios" / "thesis" / "controlled_2d.toml")
    assert sc.profile == "thesis_program" and sc.sensor.model == "marching" and sc.sensor.rays == 50
    assert len(sc.planners) == 18 and all("+" in e.name for e in sc.planners)
    ms = get_map(sc, 0)
    rollout = get_rollout(sc, ms)
    outcomes = {}
    for entry in sc.planners:
        spec = make_trial_spec(sc, ms, planner=entry.name, v_max=4.0, start=(4.0, 25.0), goal=(46.0, 25.0))
        assert spec.planner == entry
        r = run_trial(spec, rollout)
        assert r.profile == "thesis_program" and r.planner_label == entry.name and r.start_delay_s == 0.0
        assert r.outcome in ("success", "dynamic_collision", "static_collision", "deadlock", "freezing"), r.reason
        outcomes[entry.name] = r.outcome
    assert sum(o == "success" for o in outcomes.values()) >= 12, outcomes


def test_program_brake_and_pixel_positions():
    """thesis_program executes plans as the program did: positions on its 0.1 m pixels; a failed plan brakes as its
    Drone2D.brake (stop when |v| <= a_max dt, else v -= a_max dt v/|v| and p += v_new dt; a kept)."""
    from pbdyn.sim.agent import Agent, program_brake
    from pbdyn.sim.batch import TrialBatch

    p, a = np.array([10.0, 10.0]), np.array([3.0, -1.0])
    p1, v1, a1 = program_brake(p, np.array([3.0, 4.0]), a, 4.0, 0.1)
    np.testing.assert_allclose(v1, [2.76, 3.68])
    np.testing.assert_allclose(p1, p + 0.1 * v1)
    np.testing.assert_array_equal(a1, a)
    p1, v1, a1 = program_brake(p, np.array([0.3, 0.0]), a, 4.0, 0.1)
    np.testing.assert_array_equal(p1, p) and np.testing.assert_array_equal(v1, [0.0, 0.0])
    np.testing.assert_array_equal(a1, a)

    sc = _scenario("thesis_program", obstacles={"count": 0})
    spec = make_trial_spec(sc, get_map(sc, 0), planner="local_primitives_minjerk", gaze="lookahead",
                           start=(4.0, 4.0), goal=(46.0, 46.0))
    agent = Agent(spec)
    batch = TrialBatch([spec], build_rollout(sc, get_map(sc, 0)), agents=[agent])
    batch.start()
    env = batch.states[0]
    off_grid = 0
    for _ in range(30):
        batch.step()                              # the agent decides inside the core's step
        pix = env.position * 10.0
        np.testing.assert_array_equal(pix, np.round(pix))
        off_grid += int(np.any(np.abs(agent.trajectory.p[1] * 10.0 - np.round(agent.trajectory.p[1] * 10.0)) > 1e-6))
    batch.close()
    assert off_grid > 0          # the plans themselves are not on the pixel grid


def test_even_headings_are_the_programs_and_keep_the_centres():
    uni = _scenario(obstacles={"count": 12})
    even = _scenario(obstacles={"count": 12, "headings": "even"})
    a, b = build_rollout(uni, get_map(uni, 0)), build_rollout(even, get_map(even, 0))
    np.testing.assert_array_equal(a.positions[0], b.positions[0])
    np.testing.assert_array_equal(a.radii, b.radii)
    k = np.arange(12)
    np.testing.assert_allclose(b.velocities[0], -4.0 * np.stack([np.cos(2 * np.pi * k / 12),
                                                                  np.sin(2 * np.pi * k / 12)], axis=1), atol=1e-12)
    assert not np.allclose(a.velocities[0], b.velocities[0])
    assert _scenario("thesis_program").obstacles.headings == "even"
    with pytest.raises(ConfigError) as e:
        _scenario(obstacles={"headings": "random"})
    assert e.value.field == "obstacles.headings"
