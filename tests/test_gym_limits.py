"""What a Gymnasium environment keeps and accepts (pbdyn.gym; docs/gym.md "Memory", "Episodes, maps and
difficulty"): the kept PyBullet worlds and rollouts stay within their budget and close() releases them; the
difficulty option is clamped to the ladder; bad options, observation sizes and policy factories are one clean
ConfigError naming what is wrong; random option dicts never reach an internal error."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pybullet
import pytest
from gymnasium.utils.env_checker import check_env

import pbdyn.gym.episodes as episodes
from pbdyn.errors import ConfigError
from pbdyn.gym import AvoidEnv, AvoidVectorEnv, CurriculumEnv, PolicyPlanner
from tests.conftest import ROOT

MAX_CLIENTS = 1024
"""PyBullet's client slots (MAX_PHYSICS_CLIENTS): the ids a connection can have."""


def _connected() -> int:
    """PyBullet clients connected in this process now."""
    return sum(pybullet.getConnectionInfo(physicsClientId=i)["isConnected"] for i in range(MAX_CLIENTS))


# ------------------------------------------------------------------------------------------------ memory
def test_an_environment_keeps_its_world_and_rollout_budget_and_close_releases_them():
    before = _connected()
    env = AvoidEnv()
    levels = env.episodes.levels()[:6]                     # six maps: more than WORLDS_KEPT
    for k in range(24):
        _, info = env.reset(seed=k, options={"level": levels[k % len(levels)]})
        assert info["level"] == levels[k % len(levels)]
        assert env.episodes.worlds_open <= episodes.WORLDS_KEPT
        assert _connected() - before == env.episodes.worlds_open
        n, size = env.episodes.rollouts_kept
        assert 1 <= n and size <= episodes.ROLLOUT_BYTES_KEPT
        env.step(np.zeros(3, np.float32))
    assert env.episodes.worlds_open == episodes.WORLDS_KEPT == 4
    clients = [hit[1].client for hit in env.episodes._worlds.values()]
    env.close()
    assert _connected() == before and not any(c.isConnected() for c in clients)
    assert env.episodes.worlds_open == 0 and env.episodes.rollouts_kept == (0, 0) and env.batch is None
    _, info = env.reset(seed=0, options={"level": 2})       # still usable: builds what it needs again
    assert info["level"] == 2 and _connected() == before + 1
    env.close()
    assert _connected() == before


def test_keep_worlds_sets_the_world_budget_and_a_small_rollout_budget_keeps_the_current_one(monkeypatch):
    before = _connected()
    monkeypatch.setattr(episodes, "ROLLOUT_BYTES_KEPT", 1)
    env = AvoidEnv(keep_worlds=1)
    try:
        check_env(env, skip_render_check=True)
        for k in range(6):
            env.reset(seed=k, options={"map": k % 3})
            assert _connected() - before == 1 and env.episodes.rollouts_kept[0] == 1
            assert env.batch.rollout is env.episodes.rollout(env.episode.spec)
    finally:
        env.close()
    assert _connected() == before
    for bad in (0, 65, True, 2.0):
        with pytest.raises(ConfigError, match=r"^keep_worlds: must be an integer 1\.\.64 .*\(got "):
            AvoidEnv(keep_worlds=bad)


# ------------------------------------------------------------------------------------------------ options
def test_a_difficulty_outside_the_ladder_is_clamped_and_info_says_so():
    env = AvoidEnv()
    try:
        lo, hi = env.episodes.difficulty_range()
        _, top = env.reset(seed=1, options={"difficulty": hi + 50.0})
        _, bottom = env.reset(seed=1, options={"difficulty": lo - 50.0})
        _, inside = env.reset(seed=1, options={"difficulty": np.float32((lo + hi) / 2)})
        _, plain = env.reset(seed=1)
        assert top["difficulty_clamped"] and top["difficulty"] == hi and top["level"] == max(env.episodes.levels())
        assert bottom["difficulty_clamped"] and bottom["difficulty"] == lo and bottom["level"] == 1
        assert not inside["difficulty_clamped"] and lo < inside["difficulty"] < hi and not plain["difficulty_clamped"]
        with pytest.raises(ConfigError, match="^options.difficulty: must be a finite number"):
            env.reset(options={"difficulty": math.inf})
    finally:
        env.close()
    venv = AvoidVectorEnv(2)
    try:
        _, infos = venv.reset(seed=0, options={"difficulty": 99.0})
        assert infos["difficulty_clamped"].tolist() == [True, True] and infos["difficulty"].tolist() == [hi, hi]
    finally:
        venv.close()


@pytest.mark.parametrize("make", [AvoidEnv, lambda: AvoidVectorEnv(2), lambda: CurriculumEnv(AvoidEnv())],
                         ids=["single", "vector", "curriculum"])
def test_options_that_are_not_a_dict_are_one_clear_error(make):
    env = make()
    try:
        for bad in ([("map", 1)], "map=1", 3, ("level", 2)):
            with pytest.raises(ConfigError) as err:
                env.reset(seed=0, options=bad)
            assert err.value.field == "options"
            assert str(err.value).startswith("options: must be a dict of reset options (scenario, map, level, ")
        env.reset(seed=0, options={"map": 1})              # the environment still works
    finally:
        env.close()


@pytest.mark.parametrize("kwargs, message, largest", [
    (dict(tracks=1001), r"^tracks: must be an integer >= 0 and <= 1000 \(pbdyn.limits.MAX_GYM_TRACKS\) \(got 1001\)",
     dict(tracks=1000)),
    (dict(rays=10_001), r"^rays: must be an integer >= 0 and <= 10000 \(pbdyn.limits.MAX_GYM_RAYS\) \(got 10001\)",
     dict(rays=10_000)),
    (dict(patch=1025), r"^patch: must be 0 or an odd integer >= 1 and <= 1023 in 2D .*MAX_GYM_PATCH_CELLS.*1025",
     dict(patch=1023)),
    (dict(scenario="spheres_3d", patch=103), r"^patch: .* <= 101 in 3D .*\(got 103\)",
     dict(scenario="spheres_3d", patch=101)),
    (dict(patch=np.int64(2 ** 22 + 1)), r"^patch: .*\(got np.int64\(4194305\)\)", dict(patch=np.int64(1))),
], ids=["tracks", "rays", "patch-2d", "patch-3d", "patch-int64"])
def test_observation_sizes_have_upper_bounds_named_in_the_error(kwargs, message, largest):
    for make in (AvoidEnv, lambda **kw: AvoidVectorEnv(1, **kw)):
        with pytest.raises(ConfigError, match=message):
            make(**kwargs)
    if "scenario" not in kwargs and "rays" not in kwargs:     # the policy adapter takes K and P (no depth bins)
        with pytest.raises(ConfigError, match=message):
            PolicyPlanner(None, lambda obs: obs, **kwargs)
    env = AvoidEnv(**largest)                                # the bound itself is accepted
    try:
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


# ------------------------------------------------------------------------------------------------ policy factories
@pytest.mark.parametrize("name, args", [
    ("subprocess:run", "MARKER"),
    ("os:system", "MARKER"),
    ("builtins:eval", None),
    ("tests.gym_policies:math.hypot", None),
    ("pbdyn.gym.policy_planner:load_policy", {"policy": "tests.gym_policies:goal_seeker"}),
], ids=["subprocess", "os", "builtins", "stdlib-through-a-user-module", "pbdyn"])
def test_a_policy_factory_outside_the_users_modules_is_refused_before_it_is_called(name, args, tmp_path):
    marker = tmp_path / "called"
    if args == "MARKER":
        command = f"touch {marker}"
        args = {"args": ["sh", "-c", command]} if name.startswith("subprocess") else {"command": command}
    with pytest.raises(ConfigError) as err:
        PolicyPlanner(None, name, policy_args=args)
    assert err.value.field == "policy" and "must name a factory defined in a module of your own" in str(err.value)
    assert ("standard library" in str(err.value)) != name.startswith("pbdyn")
    assert not marker.exists()
    assert PolicyPlanner(None, "tests.gym_policies:goal_seeker").policy is not None


# ------------------------------------------------------------------------------------------------ fuzz
VALUES = {
    "scenario": ["quickstart", "controlled_2d", "spheres_3d", "no_such_scenario", "x" * 300, 5, ["quickstart"],
                 {"world": 3},
                 ROOT / "scenarios" / "quickstart.toml"],
    "map": [0, 8, 9, -1, 1.5, "1", np.int64(2), True, 10 ** 30, np.array(3), [1]],
    "level": [1, 9, 0, 10, np.int16(3), 2.0, "3", -(10 ** 20), {"level": 1}],
    "difficulty": [0.0, 99, -99, math.nan, math.inf, np.float32(0.3), "1", [1.0], np.array([1.0]), False],
    "task": [((4, 4), (46, 25)), ((4.0, 4.0), (46.0,)), {"a": 1}, "ab", 5, [[1e400, 0], [3, 3]],
             [[4, 4], [46, 25], [1, 1]], np.array([[10.0, 10.0], [40.0, 40.0]]), ((-500, 4), (46, 25)),
             ((math.nan, 4), (46, 25))],
    "v_max": [2.0, 0, -1, math.nan, math.inf, "x", 7.0, np.float32(3.0), 1e-300, [2.0]],
    "seed": [1],
    7: [None],
}
"""Values, good and bad, that the fuzz draws for each option (and two unknown keys)."""


def _random_options(rng: np.random.Generator):
    """A random options value: mostly a dict of one to three keys with values from VALUES, sometimes no dict."""
    if rng.random() < 0.08:
        return [None, [("map", 1)], "level=1", 3.5, ("map",)][int(rng.integers(5))]
    keys = list(VALUES)
    weights = np.array([1.0 if key in episodes.OPTIONS else 0.2 for key in keys])
    chosen = rng.choice(len(keys), size=int(rng.integers(1, 4)), replace=False, p=weights / weights.sum())
    return {keys[i]: VALUES[keys[i]][int(rng.integers(len(VALUES[keys[i]])))] for i in chosen}


def _fuzz(env, rng, n: int, reset) -> tuple[int, int]:
    """Reset ``env`` with n random options: each reset works or is one ConfigError naming an option."""
    worked = refused = 0
    for k in range(n):
        options = _random_options(rng)
        try:
            obs = reset(k, options)
        except ConfigError as exc:
            assert exc.field == "options" or exc.field.startswith("options."), (options, exc)
            assert str(exc).startswith(exc.field + ": ") and "\n" not in str(exc), (options, exc)
            refused += 1
        else:
            assert env.observation_space.contains(obs), options
            worked += 1
    return worked, refused


def test_random_reset_options_work_or_raise_one_error_naming_the_option():
    env = AvoidEnv()
    try:
        def reset(k, options):
            obs, info = env.reset(seed=k, options=options)
            assert info["outcome"] is None and info["map_id"]
            return obs

        worked, refused = _fuzz(env, np.random.default_rng(41), 120, reset)
        assert worked >= 5 and refused >= 50
        again = env.reset(seed=3, options={"scenario": "quickstart"})[0]
    finally:
        env.close()
    fresh = AvoidEnv()
    try:
        assert np.array_equal(fresh.reset(seed=3)[0], again)   # failed resets left nothing behind
    finally:
        fresh.close()


def test_random_vector_reset_options_work_or_raise_one_error_naming_the_option():
    env = AvoidVectorEnv(2)
    try:
        def reset(k, options):
            obs, _ = env.reset(seed=k, options=options)
            env.step(np.zeros(env.action_space.shape, np.float32))
            return obs

        worked, refused = _fuzz(env, np.random.default_rng(8), 40, reset)
        assert worked >= 3 and refused >= 20
    finally:
        env.close()


def test_every_option_key_value_pair_alone_works_or_is_refused_cleanly():
    env = AvoidEnv()
    try:
        for key, values in VALUES.items():
            for value in values:
                try:
                    env.reset(seed=0, options={key: value})
                except ConfigError as exc:
                    assert exc.field == f"options.{key}", (key, value, exc)
    finally:
        env.close()
    assert list(itertools.islice(VALUES, 6)) == list(episodes.OPTIONS)
