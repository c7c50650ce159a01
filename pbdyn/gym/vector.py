"""Native vector environments (docs/gym.md "Vector environments"): N episodes stepped in one trial batch, so that
their sensing, tracking and collision checks are shared (pbdyn.sim.batch.TrialBatch). AvoidVectorEnv steps N
AvoidEnv episodes (the policy flies), GazeVectorEnv N GazeEnv episodes (a planner flies, the policy turns the gaze).

The N sub-environments fly on one map at a time and stay in phase: every episode starts at the batch's next rollout
step, so at any tick all running trials sense the same obstacle poses (one posing, one Bullet ray batch, one
tracker-bank step and one swept check for all). A new episode's task is drawn as AvoidEnv draws it, among the pairs
whose start is clear at that step by the start rule's test (start_clearance for start_window_s; the first of up to
16 draws that passes, else the clearest) -- where AvoidEnv would wait for a clear start, the vector environment picks
a start that is clear now. The map's rollout covers ``epoch_s`` s (default five time limits); once a new episode
would not fit in it, the next episodes start an epoch on a new map (drawn as reset draws it, with the last reset's
options) while the old map's running episodes finish.

Spaces, observation, reward, outcomes and info are AvoidEnv's (GazeEnv's), built by the same pbdyn.gym.glue.
Autoreset: Gymnasium 1.x's NEXT_STEP mode (the step after an episode ended resets that sub-environment: its action
is ignored, it returns the new episode's first observation with reward 0 and that episode's first info). ``infos``
hold every sub-environment's info under AvoidEnv's keys, stacked as Gymnasium stacks them (with "_key" masks). A
map's world and rollout are held while episodes run on it (the current epoch's, and an older one's until its last
episode ends); close() disconnects every map's PyBullet client.

With num_envs = 1 the steps are built exactly as AvoidEnv's, but the episodes differ, by design (docs/gym.md
"Vector environments"): a sub-environment's episodes follow one another on one map for an epoch (AvoidEnv draws a
map at every reset), each begins at the batch's next tick with a start that is clear then (AvoidEnv's start rule
may wait for one), and the map's rollout covers ``epoch_s``.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from pbdyn.gym.env import PolicyYaw, command, gaze_spec
from pbdyn.gym.episodes import Episode, EpisodeSource, check_options
from pbdyn.gym.glue import Glue, stack_infos
from pbdyn.sim.agent import Agent
from pbdyn.sim.batch import TrialBatch
from pbdyn.sim.state import make_world
from pbdyn.world.rollout import get_rollout

START_DRAWS = 16
"""Task draws tried for a start that is clear now, before the clearest of them is taken."""


class _Epoch:
    """One map of the vector environment: its episode template, rollout, world and trial batch."""

    def __init__(self, episode: Episode, rollout, batch: TrialBatch):
        self.episode = episode
        self.rollout = rollout
        self.batch = batch


class _VectorCore(VectorEnv):
    """What both vector environments share: epochs, joining, autoreset, observation, reward and infos. A subclass
    says what an action is (_action_size, _spec_of, _joined, _move)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int, scenario="quickstart", *, dims: int | None = None, tracks: int = 8,
                 rays: int = 0, patch: int = 0, reward=None, epoch_s: float | None = None):
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1 (got {num_envs!r})")
        self.num_envs = num_envs
        self.episodes = EpisodeSource(scenario, dims)
        self.dims = d = self.episodes.dims
        self.glue = Glue.of(d, tracks, rays, patch, reward)
        self.single_observation_space = spaces.Box(-1.0, 1.0, (self.glue.size(d),), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (self._action_size(d),), np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.epoch_s = epoch_s
        self.epochs: list[_Epoch] = []
        self.epochs_begun = 0                    # maps flown since the environment was made
        self.slots: list[tuple[_Epoch, int] | None] = [None] * num_envs
        self._pending = np.zeros(num_envs, dtype=bool)
        self._dist = np.zeros(num_envs)
        self._options: dict = {}

    # ------------------------------------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start N episodes on a map drawn (or chosen by ``options``, as AvoidEnv.reset) for all of them; bad
        options are one ConfigError naming the option."""
        options = check_options(options)
        super().reset(seed=seed, options=options)
        self._close_epochs()
        self._options = options
        epoch = self._new_epoch()
        obs = np.zeros(self.observation_space.shape, np.float32)
        infos = [None] * self.num_envs
        for i in range(self.num_envs):
            b = self._join(epoch, i)
            self.slots[i] = (epoch, b)
        epoch.batch.step({})                     # the joined trials begin and sense together
        for i, (ep, b) in enumerate(self.slots):
            obs[i], infos[i], self._dist[i] = self.glue.first(ep.episode, ep.batch.states[b])
        self._pending[:] = False
        return obs, stack_infos(infos, self.num_envs)

    def step(self, actions):
        """Step every sub-environment: see the module docstring for autoreset."""
        a = np.asarray(actions, dtype=float)
        if a.shape != self.action_space.shape or not np.isfinite(a).all():
            raise ValueError(f"actions must be a finite array of shape {self.action_space.shape}")
        a = np.clip(a, -1.0, 1.0)
        if not self.epochs:
            raise RuntimeError("step() before reset()")
        starting = np.flatnonzero(self._pending)
        for i in starting:                                  # NEXT_STEP autoreset: a new episode, at the next tick
            epoch = self._epoch_for_new()
            self.slots[i] = (epoch, self._join(epoch, int(i)))
        accel0 = {}
        moves: dict = {}
        for i, slot in enumerate(self.slots):
            if self._pending[i]:
                continue
            epoch, b = slot
            st = epoch.batch.states[b]
            accel0[i] = st.acceleration
            move = self._move(i, epoch.batch, b, a[i])
            if move is not None:
                moves.setdefault(id(epoch), (epoch, {}))[1][b] = move
        for epoch in self.epochs:                           # every map steps once (joined trials begin there)
            got = moves.get(id(epoch))
            report = epoch.batch.step(got[1] if got else {})
            if report.errors:
                raise next(iter(report.errors.values()))
        obs = np.zeros(self.observation_space.shape, np.float32)
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos = [None] * self.num_envs
        for i, (epoch, b) in enumerate(self.slots):
            st = epoch.batch.states[b]
            if self._pending[i]:
                self._pending[i] = False
                obs[i], infos[i], self._dist[i] = self.glue.first(epoch.episode, st)
            else:
                obs[i], rewards[i], terminated[i], truncated[i], infos[i], self._dist[i] = \
                    self.glue.after(epoch.episode, st, self._dist[i], accel0[i])
                if st.outcome is not None:
                    self._pending[i] = True
                    epoch.batch.release(b)
        self._drop_finished_epochs()
        return obs, rewards, terminated, truncated, stack_infos(infos, self.num_envs)

    def close_extras(self, **kwargs) -> None:
        """Release every map's PyBullet world (their clients disconnected) and rollout."""
        self._close_epochs()
        self.episodes.close()

    # ------------------------------------------------------------------------------------------------ the subclass's
    def _action_size(self, dims: int) -> int:
        """The length of one sub-environment's action."""
        raise NotImplementedError

    def _spec_of(self, spec):
        """The trial spec a drawn task (AvoidEnv's spec) is flown as."""
        return spec

    def _joined(self, i: int, spec):
        """Sub-environment i begins an episode of ``spec``: the Agent that decides its steps (None: the policy's
        actions)."""
        return None

    def _move(self, i: int, batch: TrialBatch, b: int, action: np.ndarray):
        """The batch action of sub-environment i (trial b of ``batch``) for its clipped ``action``, or None when
        the trial's agent decides (the policy's action has been handed to it)."""
        raise NotImplementedError

    # ------------------------------------------------------------------------------------------------ parts
    def state(self, i: int):
        """The trial state (pbdyn.sim.state.TrialState) of sub-environment i's episode."""
        epoch, b = self.slots[i]
        return epoch.batch.states[b]

    def watch(self, i: int, observer) -> None:
        """Attach ``observer`` (pbdyn.sim.observers.Observer) to sub-environment i's running episode (its agent is
        None in AvoidVectorEnv): it sees each of the episode's steps and its end."""
        slot = self.slots[i] if 0 <= i < self.num_envs else None
        if slot is None or self._pending[i]:
            raise RuntimeError(f"watch(): sub-environment {i} has no running episode")
        slot[0].batch.watch(slot[1], [observer])

    def _new_epoch(self) -> _Epoch:
        """A new map (drawn with the last reset's options), its rollout over epoch_s, world and empty batch."""
        episode = self.episodes.choose(self.np_random, dict(self._options))
        spec = episode.spec
        sc = spec.scenario
        horizon = self.epoch_s if self.epoch_s is not None else 5.0 * sc.world.time_limit
        rollout = get_rollout(sc, spec.map_spec, max(horizon, 2.0 * sc.world.time_limit))
        world = make_world(spec, rollout)
        batch = TrialBatch([], rollout, world=world, capacity=self.num_envs)
        batch.owns_world = True                  # this map's world: closed with the batch
        batch.start()
        epoch = _Epoch(episode, rollout, batch)
        self.epochs.append(epoch)
        self.epochs_begun += 1
        return epoch

    def _epoch_for_new(self) -> _Epoch:
        """The epoch a new episode joins: the newest, unless its rollout cannot hold one more episode."""
        epoch = self.epochs[-1]
        st_need = epoch.batch.tick + 1 + epoch.episode.spec.scenario.world.n_steps + 3
        if st_need >= epoch.rollout.n_steps:
            epoch = self._new_epoch()
        return epoch

    def _join(self, epoch: _Epoch, i: int) -> int:
        """Add sub-environment i's next episode to ``epoch``'s batch, starting at its next tick; its index there."""
        ep = epoch.episode
        sc, ms = ep.spec.scenario, ep.spec.map_spec
        at = epoch.batch.tick + 1
        task = sc.task
        window = int(round(task.start_window_s / sc.world.dt))
        pairs, speeds = sc.task.pairs(), sc.drone.v_max   # (a ladder map's scenario holds its suite's tasks)
        best, best_gap = None, -math.inf
        for _ in range(START_DRAWS):
            spec = self.episodes.task(self.np_random, sc, ms, pairs, speeds)
            gap = _start_gap(epoch.rollout, spec.start, sc.drone.radius, at, window)
            if gap > best_gap:
                best, best_gap = spec, gap
            if gap >= task.start_clearance:
                break
        best = self._spec_of(best)
        return epoch.batch.add(best, at, agent=self._joined(i, best))

    def _drop_finished_epochs(self) -> None:
        """Close the worlds of older maps whose episodes have all ended."""
        keep = []
        for epoch in self.epochs[:-1]:
            if any(slot is not None and slot[0] is epoch for slot in self.slots):
                keep.append(epoch)
            else:
                epoch.batch.close()
        self.epochs = keep + self.epochs[-1:]

    def _close_epochs(self) -> None:
        for epoch in self.epochs:
            epoch.batch.close()
        self.epochs = []
        self.slots = [None] * self.num_envs


class AvoidVectorEnv(_VectorCore):
    """``num_envs`` AvoidEnv episodes in one trial batch (see the module docstring): the policy flies the MAV. Other
    arguments as AvoidEnv; ``epoch_s``: the time (s) one map's rollout covers."""

    def _action_size(self, dims: int) -> int:
        return dims + 1

    def _move(self, i: int, batch: TrialBatch, b: int, action: np.ndarray):
        return command(action, batch.states[b].limits)


class GazeVectorEnv(_VectorCore):
    """``num_envs`` GazeEnv episodes in one trial batch (see the module docstring): a built-in trajectory planner
    (``planner``, default local primitives, with its plan contract and braking) flies each MAV and the policy turns
    its gaze (action: Box [-1, 1]^1, the yaw rate as a fraction of its limit). Other arguments as AvoidVectorEnv."""

    def __init__(self, num_envs: int, scenario="quickstart", *, dims: int | None = None, tracks: int = 8,
                 rays: int = 0, patch: int = 0, reward=None, epoch_s: float | None = None,
                 planner: str = "local_primitives"):
        super().__init__(num_envs, scenario, dims=dims, tracks=tracks, rays=rays, patch=patch, reward=reward,
                         epoch_s=epoch_s)
        self.planner = planner
        self.agents: list = [None] * self.num_envs          # (Agent, PolicyYaw) of each sub-environment's episode

    def _action_size(self, dims: int) -> int:
        return 1

    def _spec_of(self, spec):
        return gaze_spec(spec, self.planner)

    def _joined(self, i: int, spec):
        gaze = PolicyYaw()
        self.agents[i] = (Agent(spec, None, gaze), gaze)
        return self.agents[i][0]

    def _move(self, i: int, batch: TrialBatch, b: int, action: np.ndarray):
        self.agents[i][1].rate = float(action[0]) * batch.states[b].limits.yaw_rate
        return None


def _start_gap(rollout, start, mav_radius: float, at: int, window: int) -> float:
    """The smallest gap (m) between the MAV at ``start`` and any obstacle over rollout steps at..at + window."""
    if rollout.n_obstacles == 0:
        return math.inf
    rel = rollout.positions[at:at + window + 1] - np.asarray(start, dtype=float)[None, None, :]
    dist = np.sqrt(np.einsum("knd,knd->kn", rel, rel))
    return float(np.min(dist - rollout.radii[None, :])) - mav_radius
