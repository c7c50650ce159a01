"""Where an environment's episodes come from (docs/gym.md "Maps, tasks and difficulty"): the map and the task of each
reset, chosen by the environment's seeded Generator, and the rollouts and PyBullet worlds kept between episodes.

Two sources of maps:
- a scenario's maps (default "quickstart"; any bundled name, file or Scenario): a map index drawn uniformly, or the
  one ``options["map"]`` names; a task is a start/goal pair of the scenario's candidates and one of its MAV speeds
  (``options["task"]`` = (start, goal) and ``options["v_max"]`` set them);
- a ladder: a shipped benchmark suite's maps (pbdyn-2d-v1 / pbdyn-3d-v1), each with its difficulty on the anchored
  scale (pbdyn.analysis.scale) and its level (1 = easiest); ``options["level"]`` draws a map of that level,
  ``options["difficulty"]`` (logits on the anchored scale) takes the map nearest to it; the tasks are the suite's.

What an environment keeps between episodes is bounded (docs/gym.md "Memory"): the PyBullet worlds of the last
``keep_worlds`` maps (default WORLDS_KEPT; a reset on one of them builds no world) and the rollouts of the last maps
within ROLLOUT_BYTES_KEPT; close() disconnects every world's client and drops the rollouts.
"""

from __future__ import annotations

import ctypes
import math
import numbers
from collections.abc import Mapping
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

WORLDS_KEPT = 4
"""PyBullet worlds an environment keeps by default, one per recently flown map (each ladder level has 3-4 maps).
Each world is one PyBullet DIRECT client: about 29 MiB, nearly all of it the client's fixed cost (measured on the
shipped scenarios and ladders: 28.2-28.5 MiB with their bodies), so about 115 MiB per environment."""

MAX_WORLDS_KEPT = 64
"""The most worlds an environment may be asked to keep (``keep_worlds``)."""

ROLLOUT_BYTES_KEPT = 32 * 2 ** 20
"""Bytes of obstacle rollouts an environment keeps, the most recently flown maps' (the shipped maps' rollouts hold
0.2-1 MiB each); the current map's rollout is kept whatever its size (at most pbdyn.limits.MAX_ROLLOUT_BYTES)."""


@dataclass(frozen=True)
class Episode:
    """One reset's choice: the trial spec, the map's identity (scenario name, index, id, key), its anchored
    difficulty (logits; None off the ladder) and level (None off the ladder); ``difficulty_clamped``: True when
    options["difficulty"] lay outside the ladder's range and was clamped to it."""

    spec: TrialSpec
    map_index: int
    difficulty: float | None
    level: int | None
    difficulty_clamped: bool = False


class EpisodeSource:
    """Maps and tasks for an environment of ``dims`` dimensions whose default scenario is ``scenario``."""

    def __init__(self, scenario, dims: int | None = None, keep_worlds: int = WORLDS_KEPT):
        if isinstance(keep_worlds, bool) or not isinstance(keep_worlds, int) \
                or not 1 <= keep_worlds <= MAX_WORLDS_KEPT:
            raise ConfigError("keep_worlds", f"must be an integer 1..{MAX_WORLDS_KEPT} (PyBullet worlds kept, about "
                              "29 MiB each)", keep_worlds)
        self.keep_worlds = keep_worlds
        self.scenario = self._load(scenario, dims)
        self.dims = self.scenario.world.dims
        self._ladder = None
        self._rollouts: dict = {}        # (scenario id, map key) -> (scenario, rollout, bytes), least recent first
        self.world = None                # the world of the last reset
        self._worlds: dict = {}          # (scenario id, map key) -> (scenario, world, 1), least recent first
        self._given: dict = {}
        self._map_seq = None             # (scenario, its MapSequence) of the last non-ladder reset

    def _maps_of(self, sc: Scenario):
        """The maps of ``sc`` (one MapSequence per scenario kept: its world digest is computed once)."""
        got = self._map_seq
        if got is None or got[0] is not sc:
            got = self._map_seq = (sc, enumerate_maps(sc))
        return got[1]

    @staticmethod
    def _load(scenario, dims: int | None, field: str = "scenario") -> Scenario:
        try:
            sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        except ConfigError as exc:
            if field == exc.field:
                raise
            problem = exc.problem if exc.field == "scenario" else f"{exc.field}: {exc.problem}"
            raise ConfigError(field, problem, scenario) from None
        except OSError as exc:                    # e.g. a name too long for a path
            raise ConfigError(field, f"cannot be read ({exc.strerror or exc})", scenario) from None
        if dims is not None and sc.world.dims != dims:
            raise ConfigError(field, f"is a {sc.world.dims}D scenario; this environment is {dims}D", sc.name)
        return sc

    # ------------------------------------------------------------------------------------------------ choice
    def choose(self, rng: np.random.Generator, options) -> Episode:
        """The episode of a reset with ``options`` (a dict of OPTIONS or None; anything else, an unknown key or a
        bad value is one ConfigError naming the option), drawn from ``rng``. A scenario option holds for later
        resets once its episode was chosen."""
        options = check_options(options)
        self._given = options
        sc = self.scenario
        if options.get("scenario") is not None:
            sc = self._load(options["scenario"], self.dims, "options.scenario")
        ladder = [k for k in ("level", "difficulty") if options.get(k) is not None]
        if ladder and options.get("map") is not None:
            raise ConfigError("options.map", f"cannot be combined with options.{ladder[0]}", options["map"])
        if len(ladder) == 2:
            raise ConfigError("options.level", "cannot be combined with options.difficulty", options["level"])
        if ladder:
            episode = self._from_ladder(rng, ladder[0], options[ladder[0]])
        else:
            maps = self._maps_of(sc)
            index = options.get("map")
            if index is None:
                index = int(rng.integers(len(maps)))
            elif isinstance(index, bool) or not isinstance(index, numbers.Integral) or not 0 <= index < len(maps):
                raise ConfigError("options.map", f"must be a map index 0..{len(maps) - 1} of {sc.name}", index)
            ms = maps[int(index)]
            episode = Episode(self.task(rng, sc, ms, sc.task.pairs(), sc.drone.v_max), int(index), None, None)
        self.scenario = sc
        return episode

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
                start, goal = (tuple(float(x) for x in point) for point in task)
            except (TypeError, ValueError, OverflowError):
                raise ConfigError("options.task", "must be (start, goal), two points in m", task) from None
        if self._given.get("v_max") is not None:
            v = self._given["v_max"]
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise ConfigError("options.v_max", "must be a number (m/s)", v)
            v = float(v)
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
                if suite.spec_map_id(ms) != m["map_id"]:
                    raise ConfigError("ladder", f"map {m['map_index']} of {sc.name} is not the suite's "
                                      f"{m['map_id']}", suite.spec_map_id(ms))
                rows.append((m, sc, ms))
            self._ladder = (suite, rows)
        return self._ladder

    def levels(self) -> tuple[int, ...]:
        """The ladder's levels, easiest first."""
        suite, _ = self.ladder()
        return tuple(int(x["level"]) for x in suite.levels)

    def _from_ladder(self, rng, key: str, value) -> Episode:
        suite, rows = self.ladder()
        clamped = False
        if key == "level":
            levels = self.levels()
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) not in levels:
                raise ConfigError("options.level", f"must be a level of {suite.name} ({levels[0]}..{levels[-1]})",
                                  value)
            pick = [r for r in rows if int(r[0]["level"]) == int(value)]
            m, sc, ms = pick[int(rng.integers(len(pick)))]
        else:
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise ConfigError("options.difficulty", "must be a finite number (logits on the anchored scale)",
                                  value)
            known = np.array([float(r[0]["difficulty"]) for r in rows])
            wanted = min(max(float(value), float(known.min())), float(known.max()))
            clamped = wanted != float(value)
            gaps = np.abs(known - wanted)
            m, sc, ms = rows[int(np.flatnonzero(gaps == gaps.min())[0])]
        spec = self.task(rng, sc, ms, sc.task.pairs(), suite.speeds)
        return Episode(spec, int(m["map_index"]), float(m["difficulty"]), int(m["level"]), clamped)

    def difficulty_range(self) -> tuple[float, float]:
        """(lowest, highest) anchored difficulty (logits) of the ladder's maps: options["difficulty"] is clamped to
        it."""
        _, rows = self.ladder()
        known = [float(r[0]["difficulty"]) for r in rows]
        return min(known), max(known)

    # ------------------------------------------------------------------------------------------------ world
    def rollout(self, spec: TrialSpec):
        """The rollout of the spec's map; the last maps' are kept within ROLLOUT_BYTES_KEPT (the current one
        always)."""
        return _kept(self._rollouts, spec, lambda: get_rollout(spec.scenario, spec.map_spec), ROLLOUT_BYTES_KEPT,
                     size=rollout_bytes)

    def world_for(self, spec: TrialSpec, rollout):
        """The PyBullet world of the spec's map: kept for the last ``keep_worlds`` maps (a reset on one of them
        builds no world; the least recent one is closed), else a new one."""
        self.world = _kept(self._worlds, spec, lambda: make_world(spec, rollout), self.keep_worlds,
                           drop=lambda world: world.close())
        return self.world

    @property
    def worlds_open(self) -> int:
        """PyBullet worlds (one client each) this source keeps open now."""
        return len(self._worlds)

    @property
    def rollouts_kept(self) -> tuple[int, int]:
        """(rollouts, their bytes) this source keeps now."""
        return len(self._rollouts), sum(hit[2] for hit in self._rollouts.values())

    def close(self) -> None:
        """Disconnect every kept PyBullet world, drop the kept rollouts and the ladder, and hand the freed memory
        back to the system (release_memory). The source stays usable: a later choice loads what it needs again."""
        worlds = [hit[1] for hit in self._worlds.values()]
        self._worlds.clear()
        self._rollouts.clear()
        self._ladder = None
        self._map_seq = None
        self._given = {}
        self.world = None
        for world in worlds:
            world.close()
        release_memory()


def check_options(options) -> dict:
    """Reset ``options`` as a dict: None is {}; anything but a mapping of OPTIONS keys is a ConfigError naming
    ``options`` (or ``options.<key>`` for an unknown key)."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ConfigError("options", f"must be a dict of reset options ({', '.join(OPTIONS)}) or None", options)
    for key in options:
        if key not in OPTIONS:
            raise ConfigError(f"options.{key}", f"unknown reset option (known: {', '.join(OPTIONS)})", options[key])
    return dict(options)


def rollout_bytes(rollout) -> int:
    """Bytes of a rollout's arrays (its imported bodies' poses included)."""
    parts = [rollout, rollout.bodies] if rollout.bodies is not None else [rollout]
    return sum(v.nbytes for part in parts for v in vars(part).values() if isinstance(v, np.ndarray))


def release_memory() -> None:
    """Hand the C heap's free pages back to the system (glibc's malloc_trim; nothing elsewhere), so that what a
    closed environment freed leaves the process's resident set instead of staying reserved by malloc."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (AttributeError, OSError, TypeError):
        pass


def _kept(cache: dict, spec: TrialSpec, make, limit: int, drop=None, size=lambda value: 1):
    """The value ``cache`` keeps for the spec's map, else ``make()``'s, kept as the most recent; the least recent
    are let go (``drop`` is called on each) until the values' total ``size`` is at most ``limit`` or one is left. A
    map key names a map within its scenario only (the ladder's parts share keys), so the cache is keyed by the
    scenario as well, and holds the scenario to tell a reused id() apart."""
    key = (id(spec.scenario), spec.map_spec.key)
    hit = cache.pop(key, None)
    if hit is None or hit[0] is not spec.scenario:
        if hit is not None and drop is not None:
            drop(hit[1])
        value = make()
        hit = (spec.scenario, value, size(value))
    cache[key] = hit                             # the most recent last
    while len(cache) > 1 and sum(h[2] for h in cache.values()) > limit:
        old = cache.pop(next(iter(cache)))[1]
        if drop is not None:
            drop(old)
    return hit[1]
