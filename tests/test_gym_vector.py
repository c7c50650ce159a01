"""Gymnasium vector environments and the difficulty curriculum (pbdyn.gym.curriculum): the curriculum moves the ladder
level up and down on a scripted policy, counts every ended episode once under vector autoreset, and refuses bad
settings; SyncVectorEnv and AsyncVectorEnv step and autoreset pbdyn's environments."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.gym import AvoidEnv, Curriculum, CurriculumEnv


def _to_goal(obs: np.ndarray, dims: int = 2) -> np.ndarray:
    """A scripted policy: accelerate toward the goal, damp the velocity, no turning."""
    v, g = obs[:dims], obs[dims + 2:2 * dims + 2]
    a = 3.0 * g / max(float(np.linalg.norm(g)), 1e-6) - 2.0 * v
    return np.r_[np.clip(a, -1.0, 1.0), 0.0].astype(np.float32)


def test_the_curriculum_moves_up_above_the_band_down_below_it_and_stays_on_the_ladder():
    cur = Curriculum((1, 2, 3), band=(0.4, 0.7), window=4)
    for ok in (True, True, True, False):          # 0.75 > 0.7: up
        cur.report(ok)
    assert cur.level == 2 and not cur.recent
    for ok in (True, False, True, False):         # 0.5 inside the band: stay, the window slides
        cur.report(ok)
    assert cur.level == 2 and len(cur.recent) == 4
    for ok in (False, False, False):              # window (False, False, False, False) after sliding: down
        cur.report(ok)
    assert cur.level == 1
    for _ in range(4):
        cur.report(False)                         # the easiest level is the floor
    assert cur.level == 1
    for _ in range(12):
        cur.report(True)                          # up to the hardest, and no further
    assert cur.level == 3 and list(cur.recent) == [True] * 4
    assert cur.report(False, level=2) == 3 and list(cur.recent) == [True] * 4     # drawn before the move: not counted
    assert cur.history[-1] == (2, False)
    for kwargs, field in (({"band": (0.8, 0.5)}, "band"), ({"band": "x"}, "band"), ({"window": 0}, "window"),
                          ({"level": 7}, "level")):
        with pytest.raises(ConfigError) as err:
            Curriculum((1, 2, 3), **kwargs)
        assert err.value.field == field


def test_a_shared_curriculum_over_sync_vector_autoreset_moves_both_ways_and_counts_each_episode_once():
    cur = Curriculum(range(1, 10), band=(0.3, 0.6), window=4)
    envs = gymnasium.vector.SyncVectorEnv([lambda: CurriculumEnv(AvoidEnv(), cur) for _ in range(2)])
    try:
        obs, info = envs.reset(seed=0)
        assert list(info["curriculum_level"]) == [1, 1] and list(info["level"]) == [1, 1]
        ended = 0
        for _ in range(4000):
            obs, reward, term, trunc, info = envs.step(np.stack([_to_goal(o) for o in obs]))
            ended += int(np.sum(term | trunc))
            if len(cur.history) >= 32:
                break
    finally:
        envs.close()
    levels = [lv for lv, _ in cur.history]
    assert ended == len(cur.history)                   # every ended episode once; the autoresets not at all
    assert max(levels) >= 2 and any(b < a for a, b in zip(levels, levels[1:]))   # up, and down again
    for lv in set(levels):                             # each move followed the band at the level it left
        assert lv in cur.levels


def test_async_vector_envs_step_and_autoreset_in_their_own_processes():
    envs = gymnasium.vector.AsyncVectorEnv([lambda: AvoidEnv(), lambda: AvoidEnv()])
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs.shape == (2, envs.single_observation_space.shape[0])
        assert info["map_id"][0] and info["map_id"][1]
        resets = 0
        for _ in range(300):
            obs, reward, term, trunc, info = envs.step(np.stack([_to_goal(o) for o in obs]))
            assert np.all(np.abs(obs) <= 1.0) and np.all(np.isfinite(reward))
            resets += int(np.sum(term | trunc))
        assert resets >= 2
    finally:
        envs.close()


# ------------------------------------------------------------------------------------------------ native vector env
def _run_vector(env, steps: int, seed: int = 0):
    """(observations, rewards, terminated, truncated) of ``steps`` steps of the goal-seeking policy."""
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        obs, reward, term, trunc, info = env.step(np.stack([_to_goal(o) for o in obs]))
        out.append((obs.copy(), reward.copy(), term.copy(), trunc.copy()))
    return out


def test_the_native_vector_env_autoresets_on_the_next_step_keeps_episodes_in_phase_and_the_limits():
    from pbdyn.gym import AvoidVectorEnv

    env = gymnasium.make_vec("pbdyn/Avoid2D-v0", num_envs=8, vectorization_mode="vector_entry_point")
    assert isinstance(env.unwrapped, AvoidVectorEnv)
    try:
        obs, info = env.reset(seed=3)
        assert obs.shape == (8, env.single_observation_space.shape[0]) and info["_map_id"].all()
        ended_before = np.zeros(8, dtype=bool)
        autoresets = 0
        for _ in range(400):
            obs, reward, term, trunc, info = env.step(np.stack([_to_goal(o) for o in obs]))
            assert np.all(np.abs(obs) <= 1.0)
            # NEXT_STEP: a sub-environment that ended in the last step starts anew now: reward 0, not ended
            assert np.all(reward[ended_before] == 0.0) and not np.any((term | trunc)[ended_before])
            # every sub-environment's info each step, under AvoidEnv's keys; reward terms after a step only
            assert info["_map_id"].all() and np.array_equal(info["_reward_terms"], ~ended_before)
            assert set(info) >= {"outcome", "reason", "map_index", "level", "start", "goal", "speed", "t"}
            done = term | trunc
            assert all((o is not None) == bool(e) for o, e in zip(info["outcome"], done))
            autoresets += int(ended_before.sum())
            ended_before = term | trunc
            newest = env.unwrapped.epochs[-1]
            phases = {st.k0 + st.k for st in (newest.batch.states[b] for ep, b in env.unwrapped.slots
                                               if ep is newest) if not st.done}
            assert len(phases) <= 1                          # every running trial of a map at the same step
            for ep, b in env.unwrapped.slots:
                st = ep.batch.states[b]
                assert np.linalg.norm(st.velocity) <= st.limits.v_max * (1 + 1e-12)
        assert autoresets >= 4
    finally:
        env.close()


def test_the_native_vector_env_is_deterministic_and_moves_to_a_new_map_when_the_rollout_ends():
    from pbdyn.gym import AvoidVectorEnv

    a = AvoidVectorEnv(4, epoch_s=80.0)
    b = AvoidVectorEnv(4, epoch_s=80.0)
    try:
        ra, rb = _run_vector(a, 900, seed=5), _run_vector(b, 900, seed=5)
        for x, y in zip(ra, rb):
            assert all(np.array_equal(p, q) for p, q in zip(x, y))
        assert a.episodes.world is None                # the maps' worlds belong to the epochs
        assert a.epochs_begun >= 2 and 1 <= len(a.epochs) <= 2       # a second map began; old ones were closed
        assert a.epochs_begun == b.epochs_begun
    finally:
        a.close()
        b.close()
    with pytest.raises(ValueError, match="num_envs"):
        AvoidVectorEnv(0)
    for bad in ({"tracks": -1}, {"rays": 1.5}, {"patch": 2}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            AvoidVectorEnv(2, **bad)


@pytest.mark.parametrize("kind", ["Avoid", "Gaze"])
def test_a_native_vector_episode_flies_alike_in_a_batch_of_three_and_alone(kind):
    """Sub-environment 0 draws its map and task first, so a vector env of 3 and one of 1 give it the same first
    episode; flown with the same actions it is bit for bit the same, though the batch of 3 shares its posing, rays,
    tracker bank and swept checks with two other trials (GazeVectorEnv: each with its own planner)."""
    import pbdyn.gym

    cls = getattr(pbdyn.gym, f"{kind}VectorEnv")
    flights = []
    for n in (3, 1):
        vec = cls(n)
        rng = np.random.default_rng(11)
        try:
            obs, _ = vec.reset(seed=4)
            rows = [obs[0].tobytes()]
            sp = vec.state(0).spec
            key = (sp.map_spec.key, tuple(sp.start), tuple(sp.goal), sp.v_max, sp.planner)
            while True:
                a = rng.uniform(-1.0, 1.0, (3,) + vec.single_action_space.shape).astype(np.float32)
                obs, reward, term, trunc, info = vec.step(a[:n])
                rows.append(obs[0].tobytes() + reward[0].tobytes())
                if term[0] or trunc[0]:
                    rows.append(info["outcome"][0])
                    break
            flights.append((key, rows))
        finally:
            vec.close()
    assert flights[0] == flights[1]
    assert len(flights[0][1]) > 20 and flights[0][1][-1] in ("success", "dynamic_collision", "static_collision",
                                                            "freezing", "deadlock", "invalid_plan")


def test_the_gaze_vector_env_is_made_by_id_and_autoresets():
    from pbdyn.gym import GazeVectorEnv

    env = gymnasium.make_vec("pbdyn/Gaze2D-v0", num_envs=4, vectorization_mode="vector_entry_point")
    assert isinstance(env.unwrapped, GazeVectorEnv) and env.single_action_space.shape == (1,)
    rng = np.random.default_rng(2)
    try:
        obs, _ = env.reset(seed=1)
        ended_before = np.zeros(4, dtype=bool)
        outcomes = []
        for _ in range(500):
            obs, reward, term, trunc, info = env.step(rng.uniform(-1, 1, (4, 1)).astype(np.float32))
            assert np.all(reward[ended_before] == 0.0) and np.all(np.abs(obs) <= 1.0)
            ended = term | trunc
            outcomes += [o for o, m in zip(info.get("outcome", []), ended) if m]
            ended_before = ended
            for ep, b in env.unwrapped.slots:            # the planner flies: within the MAV's limits
                st = ep.batch.states[b]
                assert np.linalg.norm(st.velocity) <= st.limits.v_max * (1 + 1e-9)
                assert st.spec.planner.trajectory == "local_primitives"
        assert len(outcomes) >= 4 and "success" in outcomes
    finally:
        env.close()


def test_stacked_infos_equal_gymnasiums_add_info():
    """pbdyn.gym.glue.stack_infos (one pass per key) gives exactly what Gymnasium's VectorEnv._add_info gives
    sub-environment by sub-environment: keys in order, masks, dtypes and values, nested reward terms included, on
    real infos of a vector run (episodes beginning, running and ended) and on crafted ones."""
    from gymnasium.vector import VectorEnv

    from pbdyn.gym import AvoidVectorEnv
    from pbdyn.gym.glue import info, stack_infos

    def same(a, b):
        assert list(a) == list(b)
        for k in a:
            if isinstance(a[k], dict):
                same(a[k], b[k])
            else:
                assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
                assert all((x is y) or (x == y) for x, y in zip(a[k].tolist(), b[k].tolist())), k

    env = AvoidVectorEnv(3)
    rng = np.random.default_rng(0)
    ref = VectorEnv()
    ref.num_envs = 4
    checked = 0
    try:
        env.reset(seed=9)
        for _ in range(60):
            env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            rows = [info(ep.episode, ep.batch.states[b]) for ep, b in env.slots] + [None]
            rows[1] = {**rows[1], "reward_terms": {"progress": 0.5, "time": -0.01}, "n": np.int64(3),
                       "v": np.arange(2.0)}
            want: dict = {}
            for i, row in enumerate(rows):
                if row is not None:
                    want = ref._add_info(want, row, i)
            same(stack_infos(rows, 4), want)
            checked += 1
    finally:
        env.close()
    assert checked == 60
