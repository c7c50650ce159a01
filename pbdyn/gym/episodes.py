"""Where an environment's episodes come from (docs/gym.md "Maps, tasks and difficulty"): the map and the task of each
reset, chosen by the environment's seeded Generator, and the rollouts and PyBullet worlds kept between episodes.

Two sources of maps:
- a scenario's maps (default "quickstart"; any bundled name, file or Scenario): a map index drawn uniformly, or the
  one ``options["map"]`` names; a task is a start/goal pair of the scenario's candidates and one of its MAV speeds
  (``options["task"]`` = (start, goal) and ``options["v_max"]`` set them);
- a ladder: a shipped benchmark suite's maps (pbdyn-2d-v1 / pbdyn-3d-v1), each with its difficulty on the anchored
  scale (pbdyn.analysis.scale) and its level (1 = easiest); ``options["level"]`` draws a map of that level,
  ``options["difficulty"]`` (logits on the anchored scale) takes the map nearest to it; the tasks are the suite's.

A world is built once per map and kept for the last WORLDS_KEPT maps (a reset on one of them builds no PyBullet
world).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pbdyn.api import load_scenario
from pbdyn.benchmark.suite import flight_scenario, load_suite
from pbdyn.config import PlannerEntry, Scenario
from pbdyn.errors import ConfigError
from pbdyn.sim.spec import TrialSpec, make_trial_spec
from pbdyn.sim.state import make_world
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import get_rollout

OPTIONS = ("scenario", "map", "level", "difficulty", "task", "v_max")
"""The reset options an environment takes."""

LADDERS = {2: "pbdyn-2d-v1", 3: "pbdyn-3d-v1"}
"""The shipped suite whose maps form the difficulty ladder of each dimension."""

WORLDS_KEPT = 16
"""PyBullet worlds an environment keeps, one per recently flown map (a DIRECT client holds a few MB)."""

ROLLOUTS_KEPT = 8
"""Obstacle rollouts an environment keeps, one per recently flown map."""


@dataclass(frozen=True)
class Episode:
    """One reset's choice: the trial spec, the map's identity (scenario name, index, id, key), its anchored
    difficulty (logits; None off the ladder) and level (None off the ladder)."""

    spec: TrialSpec
    map_index: int
    difficulty: float | None
    level: int | None


class EpisodeSource:
    """Maps and tasks for an environment of ``dims`` dimensions whose default scenario is ``scenario``."""

    def __init__(self, scenario, dims: int | None = None):
        self.scenario = self._load(scenario, dims)
        self.dims = self.scenario.world.dims
        self._ladder = None
        self._rollouts: dict = {}                # (scenario id, map key) -> (scenario, rollout), least recent first
        self.world = None                        # the world of the last reset
        self._worlds: dict = {}                  # (scenario id, map key) -> (scenario, world), least recent first
        self._given: dict = {}

    @staticmethod
    def _load(scenario, dims: int | None) -> Scenario:
        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        if dims is not None and sc.world.dims != dims:
            raise ConfigError("scenario", f"is a {sc.world.dims}D scenario; this environment is {dims}D", sc.name)
        return sc

    # ------------------------------------------------------------------------------------------------ choice
    def choose(self, rng: np.random.Generator, options: dict) -> Episode:
        """The episode of a reset with ``options`` ("scenario", "map", "level", "difficulty"; unknown keys
        refused), drawn from ``rng``."""
        for key in options:
            if key not in OPTIONS:
                raise ConfigError(f"options.{key}", f"unknown reset option (known: {', '.join(OPTIONS)})",
                                  options[key])
        self._given = options
        if "scenario" in options and options["scenario"] is not None:
            self.scenario = self._load(options["scenario"], self.dims)
        ladder = [k for k in ("level", "difficulty") if options.get(k) is not None]
        if ladder and "map" in options and options["map"] is not None:
            raise ConfigError("options.map", f"cannot be combined with options.{ladder[0]}", options["map"])
        if len(ladder) == 2:
            raise ConfigError("options.level", "cannot be combined with options.difficulty", options["level"])
        if ladder:
            return self._from_ladder(rng, ladder[0], options[ladder[0]])
        sc = self.scenario
        maps = enumerate_maps(sc)
        index = options.get("map")
        if index is None:
            index = int(rng.integers(len(maps)))
        elif isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < len(maps):
            raise ConfigError("options.map", f"must be a map index 0..{len(maps) - 1} of {sc.name}", index)
        ms = maps[int(index)]
        return Episode(self.task(rng, sc, ms, sc.task.pairs(), sc.drone.v_max), int(index), None, None)

    def task(self, rng, sc: Scenario, ms, pairs, speeds) -> TrialSpec:
        """A drawn start/goal pair and MAV speed (the draws are made even where options["task"] or
        options["v_max"] replace them, so that an option changes only what it names)."""
        i, j = pairs[int(rng.integers(len(pairs)))]
        v = float(speeds[int(rng.integers(len(speeds)))])
        cands = sc.task.candidates
        start, goal = tuple(cands[i]), tuple(cands[j])
        task = self._given.get("task")
        if task is not None:
            try:
                start, goal = (tuple(float(x) for x in task[0]), tuple(float(x) for x in task[1]))
            except (TypeError, ValueError, IndexError):
                raise ConfigError("options.task", "must be (start, goal), two points in m", task) from None
        if self._given.get("v_max") is not None:
            v = self._given["v_max"]
        try:
            return make_trial_spec(sc, ms, start=start, goal=goal, v_max=v)
        except ConfigError as exc:
            raise ConfigError(f"options.{'task' if exc.field in ('start', 'goal') else exc.field}", exc.problem,
                              exc.value) from None

    def ladder(self):
        """(suite, [(map entry, scenario, MapSpec)]) of this dimension's difficulty ladder, loaded once."""
        if self._ladder is None:
            suite = load_suite(LADDERS[self.dims])
            entry = PlannerEntry("local_primitives", "lookahead")
            scenarios = {p.name: flight_scenario(suite, p, [entry]) for p in suite.parts}
            rows = []
            for m in suite.maps:
                sc = scenarios[m["part"]]
                ms = enumerate_maps(sc)[int(m["map_index"])]
                if ms.map_id != m["map_id"]:
                    raise ConfigError("ladder", f"map {m['map_index']} of {sc.name} is not the suite's "
                                      f"{m['map_id']}", ms.map_id)
                rows.append((m, sc, ms))
            self._ladder = (suite, rows)
        return self._ladder

    def levels(self) -> tuple[int, ...]:
        """The ladder's levels, easiest first."""
        suite, _ = self.ladder()
        return tuple(int(x["level"]) for x in suite.levels)

    def _from_ladder(self, rng, key: str, value) -> Episode:
        suite, rows = self.ladder()
        if key == "level":
            levels = self.levels()
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) not in levels:
                raise ConfigError("options.level", f"must be a level of {suite.name} ({levels[0]}..{levels[-1]})",
                                  value)
            pick = [r for r in rows if int(r[0]["level"]) == int(value)]
            m, sc, ms = pick[int(rng.integers(len(pick)))]
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError("options.difficulty", "must be a finite number (logits on the anchored scale)",
                                  value)
            gaps = np.array([abs(float(r[0]["difficulty"]) - float(value)) for r in rows])
            m, sc, ms = rows[int(np.flatnonzero(gaps == gaps.min())[0])]
        spec = self.task(rng, sc, ms, sc.task.pairs(), suite.speeds)
        return Episode(spec, int(m["map_index"]), float(m["difficulty"]), int(m["level"]))

    # ------------------------------------------------------------------------------------------------ world
    def rollout(self, spec: TrialSpec):
        """The rollout of the spec's map, kept for the last ROLLOUTS_KEPT maps."""
        return _kept(self._rollouts, spec, lambda: get_rollout(spec.scenario, spec.map_spec), ROLLOUTS_KEPT)

    def world_for(self, spec: TrialSpec, rollout):
        """The PyBullet world of the spec's map: kept for the last WORLDS_KEPT maps (a reset on one of them builds
        no world), else a new one."""
        self.world = _kept(self._worlds, spec, lambda: make_world(spec, rollout), WORLDS_KEPT,
                           drop=lambda world: world.close())
        return self.world

    def close(self) -> None:
        """Disconnect every kept PyBullet world."""
        for _, world in self._worlds.values():
            world.close()
        self._worlds.clear()
        self.world = None


def _kept(cache: dict, spec: TrialSpec, make, limit: int, drop=None):
    """The value ``cache`` keeps for the spec's map, else ``make()``'s, kept as the most recent of at most ``limit``
    (``drop`` is called on a value let go). A map key names a map within its scenario only (the ladder's parts share
    keys), so the cache is keyed by the scenario as well, and holds the scenario to tell a reused id() apart."""
    key = (id(spec.scenario), spec.map_spec.key)
    hit = cache.pop(key, None)
    if hit is None or hit[0] is not spec.scenario:
        if hit is not None and drop is not None:
            drop(hit[1])
        hit = (spec.scenario, make())
    cache[key] = hit                             # the most recent last
    while len(cache) > limit:
        old = cache.pop(next(iter(cache)))[1]
        if drop is not None:
            drop(old)
    return hit[1]
