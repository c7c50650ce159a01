"""Gymnasium environments (pbdyn.gym): every id passes gymnasium's env checker; the same seed gives the same episode
in two processes; actions beyond the limits are clipped and the MAV never leaves its limits; replayed accelerations of
a built-in planner reach that trial's outcome; maps are chosen by index, ladder level or anchored difficulty; bad
options and actions are clear errors."""

from __future__ import annotations

import hashlib
import itertools
import os
import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pbdyn.gym
from pbdyn.errors import ConfigError
from pbdyn.gym import AvoidEnv, GazeEnv
from tests.conftest import ROOT


@pytest.mark.parametrize("env_id", sorted(pbdyn.gym.ENV_IDS))
def test_every_registered_environment_passes_gymnasiums_checker(env_id):
    env = gymnasium.make(env_id)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, info = env.reset(seed=1)
        assert env.observation_space.contains(obs) and info["outcome"] is None and info["map_id"]
    finally:
        env.close()


MAKE_WITHOUT_IMPORT = r"""
import sys
assert "gymnasium" not in sys.modules and "numpy" not in sys.modules and "pbdyn" not in sys.modules
import gymnasium
env = gymnasium.make(sys.argv[1])
obs, info = env.reset(seed=0)
assert env.observation_space.contains(obs) and info["map_id"]
env.close()
print(sorted(i for i in gymnasium.registry if i.startswith("pbdyn/")))
"""


def _fresh_python(code: str, *args: str, **env: str) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PBDYN_GYM_AUTOREGISTER")}
    return subprocess.run([sys.executable, "-W", "error", "-c", code, *args], capture_output=True, text=True,
                          cwd=ROOT.parent, env={**full, **env}, timeout=300)


@pytest.mark.parametrize("env_id", ["pbdyn/Avoid2D-v0", "pbdyn/Gaze3D-v0"])
def test_an_installed_pbdyn_is_made_by_id_with_no_pbdyn_import(env_id):
    """The installed pbdyn-gym.pth registers the ids when gymnasium is imported; quietly, even under -W error."""
    done = _fresh_python(MAKE_WITHOUT_IMPORT, env_id)
    assert done.returncode == 0 and not done.stderr, done.stderr[-3000:]
    assert eval(done.stdout) == sorted(pbdyn.gym.ENV_IDS)


def test_the_start_up_hook_loads_nothing_heavy_and_can_be_switched_off():
    """At start-up the hook imports neither pbdyn (the path decides later which pbdyn a process gets) nor Gymnasium."""
    probe = "import sys; print([m for m in ('numpy', 'gymnasium', 'pbdyn') if m in sys.modules])"
    done = _fresh_python(probe)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stderr
    off = _fresh_python(MAKE_WITHOUT_IMPORT, "pbdyn/Avoid2D-v0", PBDYN_GYM_AUTOREGISTER="0")
    assert off.returncode != 0 and "pbdyn" in off.stderr.strip().splitlines()[-1]
    explicit = _fresh_python("import gymnasium, pbdyn.gym; gymnasium.make('pbdyn/Avoid3D-v0').close()",
                             PBDYN_GYM_AUTOREGISTER="0")
    assert explicit.returncode == 0 and not explicit.stderr, explicit.stderr[-3000:]


def test_the_hook_registers_once_whatever_the_order():
    """pbdyn.gym imported after the hook registered (or the hook installed after gymnasium) adds nothing twice."""
    code = ("import gymnasium, pbdyn_gym_hook as g\n"
            "before = dict(gymnasium.registry)\n"
            "import pbdyn.gym\n"
            "g.install()\n"
            "assert dict(gymnasium.registry) == before\n"
            "spec = gymnasium.spec('pbdyn/Avoid2D-v0')\n"
            "assert spec.entry_point == 'pbdyn.gym.env:AvoidEnv'\n"
            "assert spec.kwargs == {'scenario': 'quickstart', 'dims': 2}\n"
            "assert spec.vector_entry_point == 'pbdyn.gym.vector:AvoidVectorEnv'\n")
    done = _fresh_python(code)
    assert done.returncode == 0 and not done.stderr, done.stderr[-3000:]


EPISODE = r'''
import hashlib, sys
import numpy as np
import gymnasium
import pbdyn.gym
env = gymnasium.make(sys.argv[1])
h = hashlib.sha256()
rng = np.random.default_rng(7)
for seed in (3, 4):
    obs, info = env.reset(seed=seed)
    h.update(obs.tobytes() + info["map_id"].encode())
    done = False
    while not done:
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        h.update(obs.tobytes() + np.float64(r).tobytes())
        done = term or trunc
    h.update(info["outcome"].encode())
env.close()
print(h.hexdigest())
'''


def test_the_same_seed_gives_the_same_episode_in_two_processes():
    digests = []
    for hashseed in ("0", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=hashseed)
        out = subprocess.run([sys.executable, "-c", EPISODE, "pbdyn/Avoid2D-v0"], capture_output=True, text=True,
                             cwd=ROOT, env=env, timeout=300)
        assert out.returncode == 0 and out.stderr == "", out.stderr
        digests.append(out.stdout.strip())
    assert digests[0] == digests[1] and len(digests[0]) == 64


@pytest.mark.parametrize("dims", [2, 3])
def test_actions_beyond_the_limits_are_clipped_and_the_mav_never_leaves_its_limits(dims):
    env = AvoidEnv("quickstart" if dims == 2 else "spheres_3d", dims=dims)
    rng = np.random.default_rng(dims)
    try:
        obs, info = env.reset(seed=11)
        lim = env.batch.states[0].limits
        done, n = False, 0
        while not done:
            action = rng.normal(0.0, 20.0, dims + 1)          # far outside [-1, 1]
            v0 = env.batch.states[0].velocity
            obs, r, term, trunc, info = env.step(action)
            st = env.batch.states[0]
            assert env.observation_space.contains(obs)
            assert info["speed"] <= lim.v_max * (1 + 1e-12) and info["acceleration"] <= lim.a_max * (1 + 1e-12)
            assert np.linalg.norm(st.velocity - v0) <= lim.a_max * st.dt * (1 + 1e-12)
            done, n = term or trunc, n + 1
        assert info["outcome"] != "invalid_plan" and n > 3
        with pytest.raises(RuntimeError, match="reset"):
            env.step(np.zeros(dims + 1))
        env.reset(seed=11)
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([np.nan] + [0.0] * dims))
        with pytest.raises(ValueError, match="finite"):
            env.step(np.zeros(dims + 2))
    finally:
        env.close()


def test_replayed_accelerations_of_a_built_in_planner_reach_its_outcome(tmp_path):
    """A local-primitives trial flown by pbdyn, replayed through AvoidEnv as its executed velocity changes (the
    acceleration the core integrates) and its yaw rates: the same outcome, positions within a few centimetres."""
    import pbdyn
    from tests.helpers import open_scenario

    sc = open_scenario(obstacles={"count": 0})
    res = pbdyn.run_trial(sc, planner="local_primitives", start=(4.0, 4.0), goal=(46.0, 25.0),
                          trace=tmp_path / "trace.npz")
    trace = np.load(tmp_path / "trace.npz")
    env = AvoidEnv(sc)
    try:
        env.reset(seed=0, options={"map": 0, "task": ((4.0, 4.0), (46.0, 25.0)), "v_max": res.mav_speed})
        st = env.batch.states[0]
        lim = st.limits
        v = np.vstack([trace["v"], trace["final_v"][None]])
        for k in range(len(trace["t"])):
            accel = (v[k + 1] - v[k]) / st.dt
            _, _, term, trunc, info = env.step(np.r_[accel / lim.a_max, trace["yaw_rate"][k] / lim.yaw_rate])
            assert np.linalg.norm(st.position - (trace["p"][k + 1] if k + 1 < len(trace["t"])
                                                 else trace["final_p"])) < 0.05
            if term or trunc:
                break
        assert info["outcome"] == res.outcome == "success" and st.steps == res.steps
    finally:
        env.close()


def _patch_reference(grid, position, patch: int) -> np.ndarray:
    """The occupancy patch cell by cell: 1 occupied or outside the grid, 0.5 unknown, 0 free (C order)."""
    centre = np.floor((position - grid.origin) / grid.res).astype(int)
    h = patch // 2
    out = []
    for off in itertools.product(range(-h, h + 1), repeat=grid.dims):
        idx = centre + np.array(off)
        if np.any(idx < 0) or np.any(idx >= np.array(grid.shape)):
            out.append(1.0)
        else:
            out.append({1: 1.0, -1: 0.5, 0: 0.0}[int(grid.cells[tuple(idx)])])
    return np.array(out)


@pytest.mark.parametrize("scenario, patch", [("worlds/warehouse_2d", 9), ("worlds/warehouse_2d", 105),
                                             ("spheres_3d", 5)])
def test_the_occupancy_patch_is_the_mavs_grid_around_it(scenario, patch):
    env = AvoidEnv(scenario, patch=patch)
    d = env.dims
    seen = set()
    try:
        assert env.observation_space.shape == (2 * d + 2 + 8 * (2 * d + 3) + patch ** d,)
        obs, _ = env.reset(seed=2)
        for k in range(40):
            st = env.batch.states[0]
            tail = obs[-patch ** d:]
            assert np.array_equal(tail, _patch_reference(st.grid, st.position, patch).astype(np.float32))
            seen |= set(np.unique(tail).tolist())
            action = np.zeros(d + 1, np.float32)
            action[-1] = 1.0                                     # turn in place: the sensor sweeps the walls
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
    if patch > 52:                                               # larger than the grid: walls, unknown and beyond
        assert seen == {0.0, 0.5, 1.0}
    for bad in (2, -1, True, 1.5):
        with pytest.raises(ValueError, match="patch"):
            AvoidEnv(scenario, patch=bad)


def test_every_ladder_map_flies_with_its_own_rollout():
    """The ladder's parts share map keys (a key names a map within its scenario): each map still gets its own
    rollout and world, whatever the order of the resets."""
    env = AvoidEnv()
    try:
        _, rows = env.episodes.ladder()
        for level in env.episodes.levels() + env.episodes.levels()[::-1]:
            for seed in range(2):
                env.reset(seed=seed, options={"level": level})
                st = env.batch.states[0]
                assert env.batch.rollout.n_obstacles == st.world.obstacle_ids.shape[0]
                assert env.batch.rollout is env.episodes.rollout(env.episode.spec)
                env.step(np.zeros(3, np.float32))
    finally:
        env.close()


def test_maps_by_index_level_and_difficulty_and_a_kept_world():
    env = AvoidEnv()
    try:
        _, info = env.reset(seed=5, options={"map": 3})
        assert info["map_index"] == 3 and info["difficulty"] is None and info["level"] is None
        world = env.episodes.world
        env.reset(seed=6, options={"map": 3})
        assert env.episodes.world is world                     # the map stayed: no new PyBullet world
        _, info = env.reset(seed=5, options={"level": 1})
        assert info["level"] == 1 and info["difficulty"] is not None and info["scenario"].startswith("pbdyn-2d-v1")
        _, hard = env.reset(seed=5, options={"difficulty": 3.0})
        _, easy = env.reset(seed=5, options={"difficulty": -3.0})
        assert hard["difficulty"] > easy["difficulty"] and hard["level"] > easy["level"]
        for options, field in (({"map": 99}, "options.map"), ({"level": 0}, "options.level"),
                               ({"difficulty": float("nan")}, "options.difficulty"), ({"colour": 1}, "options.colour"),
                               ({"map": 1, "level": 2}, "options.map")):
            with pytest.raises(ConfigError) as err:
                env.reset(seed=1, options=options)
            assert err.value.field == field
    finally:
        env.close()


def test_the_gaze_environment_flies_the_planner_and_turns_the_gaze():
    env = GazeEnv()
    try:
        obs, info = env.reset(seed=2, options={"map": 0})
        yaws = []
        done = False
        while not done:
            obs, r, term, trunc, info = env.step(np.array([1.0], dtype=np.float32))
            yaws.append(env.batch.states[0].yaw)
            done = term or trunc
        assert info["outcome"] in ("success", "dynamic_collision", "static_collision", "deadlock", "freezing")
        assert len(set(np.round(yaws, 6))) > 5                  # the policy's yaw rate turned the MAV
    finally:
        env.close()


def test_reward_weights_are_validated_and_reported():
    env = AvoidEnv(reward={"progress": 2.0, "time": 0.0})
    try:
        env.reset(seed=1)
        _, r, _, _, info = env.step(np.zeros(3, dtype=np.float32))
        assert r == pytest.approx(sum(info["reward_terms"].values())) and info["reward_terms"]["time"] == 0.0
    finally:
        env.close()
    with pytest.raises(ConfigError, match="reward.speed"):
        AvoidEnv(reward={"speed": 1.0})
    with pytest.raises(ConfigError, match="reward.time"):
        AvoidEnv(reward={"time": -1.0})


def test_a_gym_episode_is_traced_through_its_batch_and_replayed(tmp_path):
    """An observer attached to the running episode (AvoidEnv.watch: the trial batch's observers) records the policy's
    flight: a trace with one row per step, the episode's end, which pbdyn replay draws."""
    import pbdyn
    from pbdyn.analysis.replay import load_trace
    from pbdyn.sim.observers import TraceObserver
    from tests.gym_policies import goal_seeker

    env = AvoidEnv("quickstart", dims=2)
    policy = goal_seeker(2)
    path = tmp_path / "episode.npz"
    try:
        obs, _ = env.reset(seed=2)
        env.watch(TraceObserver(path))
        steps, done = 0, False
        while not done:
            obs, _, term, trunc, info = env.step(policy(obs))
            steps, done = steps + 1, term or trunc
    finally:
        env.close()
    tr = load_trace(path)
    assert tr["t"].shape == (steps,) and str(tr["outcome"]) == info["outcome"]
    assert np.isnan(tr["plan"]).all()                 # a policy flies: no plan in execution
    summary = pbdyn.replay(path, tmp_path / "episode.gif", every=10)
    assert (tmp_path / "episode.gif").stat().st_size > 0 and summary.frames >= 2
    with pytest.raises(RuntimeError, match="reset"):
        AvoidEnv("quickstart").watch(TraceObserver(tmp_path / "x.npz"))
