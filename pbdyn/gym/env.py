"""Gymnasium environments over the trial core (docs/gym.md): an episode is a trial of pbdyn, flown by
pbdyn.sim.batch.TrialBatch (a batch of one) with the same world, sensing, tracking, MAV limits and outcomes as
``pbdyn run``.

``AvoidEnv``: the policy flies the MAV. Action: Box [-1, 1]^(d + 1), float32: an acceleration command
(action[:d] * a_max, m/s^2, world frame; the core clips its norm to a_max and integrates it within v_max,
pbdyn.sim.guard.Accel) and a yaw rate (action[d] * the yaw-rate limit, rad/s); actions outside [-1, 1] are clipped
to it, and a non-finite action is refused (ValueError).
``GazeEnv``: a built-in trajectory planner flies (default local primitives, with its plan contract and braking) and
the policy only turns the gaze: Box [-1, 1]^1, the yaw rate as a fraction of its limit (the thesis' gaze-planning
problem).

Both observe pbdyn.gym.observation (what the MAV knows), are rewarded by pbdyn.gym.reward, end an episode when the
trial ends (``terminated``: success, a collision, invalid_plan or deadlock; ``truncated``: the time limit, i.e.
the outcome "freezing"), and put in ``info`` the outcome and its reason (once ended), the map's identity, its
anchored difficulty and level (on the ladder), the reward's terms, and the MAV's speed and acceleration: all built
by pbdyn.gym.glue, as the vector environments' are. ``watch(observer)`` attaches an observer (e.g.
pbdyn.sim.observers.TraceObserver: a trace ``pbdyn replay`` draws) to the running episode.
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium
import numpy as np
from gymnasium import spaces

from pbdyn.gym.episodes import WORLDS_KEPT, Episode, EpisodeSource
from pbdyn.gym.glue import Glue
from pbdyn.sim.agent import Agent
from pbdyn.sim.batch import TrialBatch
from pbdyn.sim.guard import Accel
from pbdyn.sim.spec import make_trial_spec


def command(action: np.ndarray, limits) -> Accel:
    """The Accel a normalised action means (AvoidEnv's Box [-1, 1]^(d + 1), already clipped): action[:d] * a_max
    (m/s^2, world frame) and action[d] * the yaw-rate limit (rad/s); ``limits``: the MAV's MAVLimits. The one
    definition the environments and the policy adapter (pbdyn.gym.policy_planner) share."""
    d = action.shape[0] - 1
    return Accel(action[:d] * limits.a_max, float(action[d]) * limits.yaw_rate)


class _CoreEnv(gymnasium.Env):
    """The part both environments share: episodes, the trial batch of one, observation, reward and info."""

    metadata = {"render_modes": []}

    def __init__(self, scenario="quickstart", *, dims: int | None = None, tracks: int = 8, rays: int = 0,
                 patch: int = 0, reward=None, keep_worlds: int = WORLDS_KEPT):
        super().__init__()
        self.episodes = EpisodeSource(scenario, dims, keep_worlds)
        self.dims = self.episodes.dims
        self.glue = Glue.of(self.dims, tracks, rays, patch, reward)
        self.observation_space = spaces.Box(-1.0, 1.0, (self.glue.size(self.dims),), np.float32)
        self.batch: TrialBatch | None = None
        self.episode: Episode | None = None

    # ------------------------------------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode: a map and task drawn by the environment's Generator (seeded by ``seed``), or chosen by
        ``options`` (a dict of pbdyn.gym.episodes.OPTIONS or None; a bad one is a ConfigError naming it). Returns
        (observation, info)."""
        super().reset(seed=seed)
        episode = self.episodes.choose(self.np_random, options)
        spec = episode.spec
        rollout = self.episodes.rollout(spec)
        world = self.episodes.world_for(spec, rollout)
        report = self._start(episode, rollout, world)
        if 0 in report.errors:
            raise report.errors[0]
        obs, info, self._dist = self.glue.first(self.episode, self.batch.states[0])
        return obs, info

    def step(self, action):
        """One step of the trial with ``action``. Returns (observation, reward, terminated, truncated, info)."""
        if self.batch is None or self.batch.done:
            raise RuntimeError("step() before reset() or after the episode ended; call reset()")
        st = self.batch.states[0]
        accel0 = st.acceleration
        report = self._act(self._checked(action))
        if 0 in report.errors:
            raise report.errors[0]
        *out, self._dist = self.glue.after(self.episode, st, self._dist, accel0)
        return tuple(out)

    def watch(self, observer) -> None:
        """Attach ``observer`` (pbdyn.sim.observers.Observer; its ``agent`` is None under AvoidEnv) to the running
        episode: it sees each of its steps and its end (TraceObserver writes a trace that ``pbdyn replay`` draws)."""
        if self.batch is None or self.batch.done:
            raise RuntimeError("watch() needs a running episode; call reset() first")
        self.batch.watch(0, [observer])

    def close(self) -> None:
        """Release what the environment keeps: its trial, every PyBullet world (their clients disconnected) and
        rollout (EpisodeSource.close). A later reset builds them again."""
        self.batch = None
        self.episodes.close()

    # ------------------------------------------------------------------------------------------------ parts
    def _checked(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=float)
        if a.shape != self.action_space.shape or not np.isfinite(a).all():
            raise ValueError(f"action must be {self.action_space.shape[0]} finite numbers (got {action!r})")
        return np.clip(a, -1.0, 1.0)


class AvoidEnv(_CoreEnv):
    """The policy flies the MAV: acceleration command and yaw rate (see the module docstring).

    scenario: a bundled scenario name, a file or a Scenario (default "quickstart"; its maps, tasks and MAV speeds
    are the episodes' unless a reset asks for the ladder); dims: 2 or 3 (checked against the scenario); tracks: K,
    the nearest tracks observed; rays: B, depth bins observed (0: none); patch: P, the cells per side of the
    occupancy patch observed (0: none; odd); reward: a RewardConfig or dict of weights; keep_worlds: the PyBullet
    worlds kept for the last maps flown (about 29 MiB each; docs/gym.md "Memory")."""

    def __init__(self, scenario="quickstart", *, dims: int | None = None, tracks: int = 8, rays: int = 0,
                 patch: int = 0, reward=None, keep_worlds: int = WORLDS_KEPT):
        super().__init__(scenario, dims=dims, tracks=tracks, rays=rays, patch=patch, reward=reward,
                         keep_worlds=keep_worlds)
        self.action_space = spaces.Box(-1.0, 1.0, (self.dims + 1,), np.float32)

    def _start(self, episode: Episode, rollout, world):
        self.episode = episode
        self.batch = TrialBatch([episode.spec], rollout, world=world)
        return self.batch.start()

    def _act(self, a: np.ndarray):
        return self.batch.step({0: command(a, self.batch.states[0].limits)})


class PolicyYaw:
    """A gaze planner whose yaw rate is the policy's last action (rad/s): GazeEnv's and GazeVectorEnv's."""

    fov_deg = None

    def __init__(self):
        self.rate = 0.0

    def yaw_rate(self, view, trajectory) -> float:
        return self.rate


def gaze_spec(spec, planner: str):
    """The trial spec of a gaze episode: ``spec``'s map, task and speed flown by the trajectory planner ``planner``
    (a registry name) beside the scenario's gaze entry (whose yaw rate the policy replaces)."""
    return make_trial_spec(spec.scenario, spec.map_spec, planner=planner, gaze=spec.planner.gaze,
                           start=tuple(spec.start), goal=tuple(spec.goal), v_max=spec.v_max)


class GazeEnv(_CoreEnv):
    """A built-in trajectory planner flies; the policy turns the gaze (see the module docstring). ``planner``: the
    trajectory planner's registry name (default "local_primitives"); other arguments as AvoidEnv."""

    def __init__(self, scenario="quickstart", *, dims: int | None = None, tracks: int = 8, rays: int = 0,
                 patch: int = 0, reward=None, planner: str = "local_primitives", keep_worlds: int = WORLDS_KEPT):
        super().__init__(scenario, dims=dims, tracks=tracks, rays=rays, patch=patch, reward=reward,
                         keep_worlds=keep_worlds)
        self.planner = planner
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.agent: Agent | None = None

    def _start(self, episode: Episode, rollout, world):
        spec = gaze_spec(episode.spec, self.planner)
        self.episode = replace(episode, spec=spec)
        self.gaze = PolicyYaw()
        self.agent = Agent(spec, None, self.gaze)
        self.batch = TrialBatch([spec], rollout, world=world, agents=[self.agent])
        return self.batch.start()

    def _act(self, a: np.ndarray):
        self.gaze.rate = float(a[0]) * self.batch.states[0].limits.yaw_rate
        return self.batch.step()
