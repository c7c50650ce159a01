"""The policy-to-planner adapter (pbdyn.gym.policy_planner; docs/gym.md "Scoring a policy with pbdyn bench"): a
View observes like the TrialState it was taken of; the adapter's plans keep the plan contract for any action; a
scripted policy flies the same trial through the adapter (pbdyn.run_trial) as in AvoidEnv, with one policy call per
step; `pbdyn bench` scores a policy named in --params."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import subprocess

import numpy as np
import pytest

import pbdyn
import pbdyn.sim.agent
from pbdyn.api import load_scenario
from pbdyn.config import PlannerEntry
from pbdyn.errors import ConfigError
from pbdyn.gym import AvoidEnv
from pbdyn.gym.observation import observe, observe_view
from pbdyn.gym.policy_planner import PolicyGaze, PolicyPlanner, load_policy, policy_pair
from pbdyn.perception.tracks import Tracks
from pbdyn.planning.view import MAVLimits, View
from pbdyn.sim.contract import check_plan
from pbdyn.sim.guard import Accel, integrate
from tests.conftest import ROOT, pbdyn_cmd
from tests.gym_policies import goal_seeker, wall_shy

PP = "pbdyn.gym.policy_planner"


# ------------------------------------------------------------------------------------------------ observation
@pytest.mark.parametrize("scenario", ["quickstart", "spheres_3d"])
def test_a_view_observes_like_the_trial_state_it_was_taken_of(scenario):
    env = AvoidEnv(scenario)
    policy = goal_seeker(env.dims)
    steps = tracked = 0
    try:
        for seed in range(2):
            obs, _ = env.reset(seed=seed)
            done = False
            while not done:
                st = env.batch.states[0]
                view = st.view()
                assert observe_view(view, 8).tobytes() == obs.tobytes() == observe(st, 8, 0).tobytes()
                for k in (0, 3, 12):
                    assert observe_view(view, k).tobytes() == observe(st, k, 0).tobytes()
                for p in (1, 5):
                    assert observe_view(view, 8, 0, p).tobytes() == observe(st, 8, 0, p).tobytes()
                steps += 1
                tracked += st.tracks is not None and len(st.tracks.ids) > 0
                obs, _, terminated, truncated, _ = env.step(policy(obs))
                done = terminated or truncated
        with pytest.raises(ValueError, match="rays = 0"):
            observe_view(view, 8, 4)
    finally:
        env.close()
    assert steps > 50 and tracked > 10           # the tracks' rows were compared too


# ------------------------------------------------------------------------------------------------ the plan
def _view(rng, dims: int, t: float = 1.3) -> View:
    lim = MAVLimits(0.3, float(rng.uniform(1.0, 8.0)), float(rng.uniform(1.0, 10.0)), 2.0)
    v = rng.normal(size=dims)
    v *= lim.v_max * rng.uniform(0.0, 1.0) ** 0.3 / np.linalg.norm(v)        # many near the speed limit
    a = rng.normal(size=dims)
    a *= lim.a_max * rng.uniform(0.0, 1.0) / np.linalg.norm(a)
    size = np.full(dims, 50.0)
    tracks = Tracks(np.array([1]), rng.uniform(0, 50, (1, dims)), rng.normal(size=(1, dims)),
                    np.eye(2 * dims)[None] * 0.1, np.array([1.0]))
    return View(t, 0.1, rng.uniform(1, 49, dims), v, a, 0.4, size - 5.0, 0.5, lim, np.zeros(dims), size, None, tracks)


@pytest.mark.parametrize("dims", [2, 3])
def test_the_plan_keeps_the_contract_and_executes_the_action_as_the_environment_does(dims):
    rng = np.random.default_rng(dims)
    for _ in range(500):
        view = _view(rng, dims)
        raw = rng.normal(size=dims + 1) * 2.0            # often outside [-1, 1]: clipped as AvoidEnv clips
        planner = PolicyPlanner(None, lambda obs: raw)
        traj = planner.plan(view)
        lim = view.limits
        assert check_plan(traj, t=view.t, dt=view.dt, position=view.position, velocity=view.velocity,
                          v_max=lim.v_max, a_max=lim.a_max) is None
        a = np.clip(raw, -1.0, 1.0)
        step = integrate(Accel(a[:dims] * lim.a_max), view.position, view.velocity, lim, view.dt)
        assert traj.t0 == view.t and traj.dt == view.dt and traj.n_samples == 2
        for got, want in ((traj.p, (view.position, step.position)), (traj.v, (view.velocity, step.velocity)),
                          (traj.a, (view.acceleration, step.acceleration))):
            assert got.tobytes() == np.array(want).tobytes()
        assert PolicyGaze(planner=planner).yaw_rate(view, traj) == float(a[dims]) * lim.yaw_rate


def test_bad_policies_and_parameters_are_clear_errors():
    view = _view(np.random.default_rng(0), 2)
    with pytest.raises(ConfigError, match="policy: must return 3 finite numbers"):
        PolicyPlanner(None, lambda obs: np.zeros(2)).plan(view)
    with pytest.raises(ConfigError, match="policy: must return 3 finite numbers"):
        PolicyPlanner(None, lambda obs: np.array([0.0, np.nan, 0.0])).plan(view)
    with pytest.raises(ConfigError, match=r"policy: raised ZeroDivisionError.* at t = 1.3 s"):
        PolicyPlanner(None, lambda obs: 1 / 0).plan(view)
    with pytest.raises(ConfigError, match="policy: is required"):
        PolicyPlanner(None)
    with pytest.raises(ConfigError, match="policy: must be a callable"):
        PolicyPlanner(None, "no_colon")
    with pytest.raises(ConfigError, match="policy: cannot import module"):
        PolicyPlanner(None, "no_such_module_xyz:f")
    with pytest.raises(ConfigError, match="policy_args"):
        PolicyPlanner(None, lambda obs: obs, policy_args={"x": 1})
    with pytest.raises(ConfigError, match="tracks: must be an integer >= 0"):
        PolicyPlanner(None, lambda obs: obs, tracks=-1)
    with pytest.raises(ConfigError, match="PolicyGaze without a policy flies only with PolicyPlanner"):
        PolicyGaze(None).yaw_rate(view, None)
    assert load_policy("tests.gym_policies:goal_seeker") is load_policy("tests.gym_policies:goal_seeker")
    assert load_policy("tests.gym_policies:goal_seeker", {"gain": 2.0}) is not \
        load_policy("tests.gym_policies:goal_seeker")


# ------------------------------------------------------------------------------------------------ the same flight
TASKS = [(0, 0, 8), (0, 3, 5), (1, 8, 0), (1, 1, 7), (2, 2, 6)]
"""(map, start candidate, goal candidate) of quickstart: successes and collisions for both policies."""


def _env_flight(env, policy, m, start, goal, v_max):
    obs, info = env.reset(seed=0, options={"map": m, "task": (start, goal), "v_max": v_max})
    st = env.batch.states[0]
    rows = [(st.position.copy(), st.velocity.copy(), st.acceleration.copy(), st.yaw)]
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(policy(obs))
        rows.append((st.position.copy(), st.velocity.copy(), st.acceleration.copy(), st.yaw))
        done = terminated or truncated
    p, v, a, yaw = (np.array(x) for x in zip(*rows))
    return info["outcome"], len(rows) - 1, p, v, a, yaw


def _adapter_flight(policy, m, start, goal, v_max, trace, scenario="quickstart", patch: int = 0):
    calls = []

    def counted(obs):
        calls.append(1)
        return policy(obs)

    if policy is None:          # the pair named in the scenario's planner entry, as pbdyn bench builds it
        res = pbdyn.run_trial(scenario, map=m, start=start, goal=goal, v_max=v_max, trace=trace)
    else:
        planner, gaze = policy_pair(counted, patch=patch)
        res = pbdyn.run_trial(scenario, planner=planner, gaze=gaze, map=m, start=start, goal=goal, v_max=v_max,
                              trace=trace)
    tr = np.load(trace)
    p, v, a, yaw = (np.concatenate([tr[k], tr["final_" + k][None]]) for k in ("p", "v", "a", "yaw"))
    assert policy is None or len(calls) == res.steps                # one policy call per step
    return res.outcome, res.steps, p, v, a, yaw


@pytest.mark.parametrize("gain", [3.0, 50.0], ids=["gentle", "saturating"])
def test_a_policy_flies_the_same_trial_through_the_adapter_as_in_the_environment(gain, tmp_path, monkeypatch):
    sc = load_scenario("quickstart")
    cands = sc.task.candidates
    policy = goal_seeker(2, gain)
    env = AvoidEnv("quickstart")
    outcomes = set()
    try:
        for m, i, j in TASKS:
            env_run = _env_flight(env, policy, m, cands[i], cands[j], 4.0)
            ada = _adapter_flight(policy, m, cands[i], cands[j], 4.0, tmp_path / "t.npz")
            assert ada[:2] == env_run[:2], (m, i, j)                     # outcome and steps
            assert ada[5].tobytes() == env_run[5].tobytes()            # yaw: the same start (facing the goal) and turns
            assert np.abs(ada[2] - env_run[2]).max() <= 1e-9            # positions (m)
            assert np.abs(ada[3] - env_run[3]).max() <= 1e-9
            outcomes.add(ada[0])
        assert {"success", "dynamic_collision"} <= outcomes
        # The only difference: the agent projects the executed sample's v and a onto |v| <= v_max, |a| <= a_max
        # (pbdyn.sim.agent._project), which rescales a vector that integrate() left an ulp above its limit;
        # AvoidEnv executes integrate()'s state as it is. Without that projection the flights are bit-identical.
        monkeypatch.setattr(pbdyn.sim.agent, "_project", lambda x, limit: x)
        for m, i, j in TASKS:
            env_run = _env_flight(env, policy, m, cands[i], cands[j], 4.0)
            ada = _adapter_flight(policy, m, cands[i], cands[j], 4.0, tmp_path / "t.npz")
            assert ada[:2] == env_run[:2]
            assert all(x.tobytes() == y.tobytes() for x, y in zip(ada[2:], env_run[2:]))
    finally:
        env.close()


def test_a_policy_that_reads_the_occupancy_patch_flies_the_same_trial_through_the_adapter(tmp_path):
    """Among shelves (warehouse_2d), a policy steering by the occupancy patch (P = 5) flies through the adapter as
    in AvoidEnv(patch=5): the View's grid is the trial's."""
    sc = load_scenario("worlds/warehouse_2d")
    cands = sc.task.candidates
    shy = wall_shy(2, patch=5)
    pushed = []

    def policy(obs):
        pushed.append(bool(np.any(obs[-25:] == 1.0)))
        return shy(obs)

    env = AvoidEnv(sc, patch=5)
    try:
        for i, j in ((0, 1), (1, 0), (2, 3)):
            env_run = _env_flight(env, policy, 0, cands[i], cands[j], 4.0)
            ada = _adapter_flight(policy, 0, cands[i], cands[j], 4.0, tmp_path / "t.npz", sc, patch=5)
            assert ada[:2] == env_run[:2], (i, j)
            assert ada[5].tobytes() == env_run[5].tobytes()
            assert np.abs(ada[2] - env_run[2]).max() <= 1e-9
    finally:
        env.close()
    assert sum(pushed) > 20                       # steps on which the patch showed a shelf and the policy swerved
    with pytest.raises(ConfigError, match="patch"):
        policy_pair(policy, patch=4)


def test_the_pair_named_in_a_scenario_flies_as_the_pair_of_a_callable(tmp_path):
    entry = PlannerEntry(f"{PP}:PolicyPlanner", f"{PP}:PolicyGaze", {"policy": "tests.gym_policies:goal_seeker"})
    sc = dataclasses.replace(load_scenario("quickstart"), planners=(entry,))
    cands = sc.task.candidates
    named = _adapter_flight(None, 0, cands[3], cands[5], 4.0, tmp_path / "named.npz", sc)
    given = _adapter_flight(goal_seeker(), 0, cands[3], cands[5], 4.0, tmp_path / "given.npz", sc)
    assert named[:2] == given[:2]
    assert all(x.tobytes() == y.tobytes() for x, y in zip(named[2:], given[2:]))


# ------------------------------------------------------------------------------------------------ pbdyn bench
def test_pbdyn_bench_scores_a_policy(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    out = tmp_path / "bench"
    args = [f"{PP}:PolicyPlanner", "--gaze", f"{PP}:PolicyGaze", "--suite", "pbdyn-2d-mini", "--out", str(out),
            "--workers", "1"]
    res = subprocess.run(pbdyn_cmd() + ["bench", *args, "--params", '{"policy": "tests.gym_policies:goal_seeker"}'],
                         capture_output=True, text=True, timeout=600, env=env)
    assert res.returncode == 0, res.stderr
    card = json.loads((out / "card.json").read_text())
    assert card["trials"] == {"flown": 12, "expected": 12, "errors": 0}
    assert card["success"]["trials"] == 12 and sum(card["outcomes"].values()) == 12
    assert card["success"]["successes"] == card["outcomes"]["success"] > 0
    assert card["planner"]["trajectory_params"] == {"policy": "tests.gym_policies:goal_seeker"}
    assert card["planner"]["fingerprint"].startswith("sha256:")
    # another policy never lands in the same folder
    res = subprocess.run(pbdyn_cmd() + ["bench", *args, "--params", '{"policy": "tests.gym_policies:hover"}'],
                         capture_output=True, text=True, timeout=600, env=env)
    assert res.returncode == 2 and "with other parameters" in res.stderr and res.stderr.count("\n") == 1


def test_a_bench_folder_refuses_a_policy_file_whose_content_changed(tmp_path, monkeypatch):
    """The card and the bench folder record the sha256 of every file a parameter names (e.g. a policy's weights):
    the same path with other content is another planner, refused in the same folder."""
    from pbdyn.benchmark.run import _check_marker, parameter_files, planner_entry
    from pbdyn.benchmark.suite import load_suite
    from pbdyn.errors import ConfigError

    monkeypatch.chdir(tmp_path)
    weights = tmp_path / "policy.bin"
    weights.write_bytes(b"version 1")
    params = {"policy": "tests.gym_policies:goal_seeker", "policy_args": {"path": "policy.bin"}, "tracks": 8}
    assert parameter_files(params) == {"policy.bin": hashlib.sha256(b"version 1").hexdigest()}
    assert parameter_files({"policy": "tests.gym_policies:goal_seeker", "x": ["nope.bin", 3]}) == {}
    suite = load_suite("pbdyn-2d-mini")
    entry = planner_entry("pbdyn.gym.policy_planner:PolicyPlanner", "pbdyn.gym.policy_planner:PolicyGaze", params)
    out = tmp_path / "bench"
    _check_marker(out, suite, entry)
    _check_marker(out, suite, entry)                   # the same file: the folder resumes
    weights.write_bytes(b"version 2")
    with pytest.raises(ConfigError) as err:
        _check_marker(out, suite, entry)
    assert err.value.field == "out" and "parameter file policy.bin held other content" in str(err.value)
