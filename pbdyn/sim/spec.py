"""A trial's specification, resolved once: scenario, map, planner pair, MAV speed, start and goal.

The config hash (docs/design.md "Outcomes and the record") and the per-trial seed are computed once per TrialSpec and
cached; everything a trial does is a function of its spec and its map's rollout.
"""

from __future__ import annotations

import hashlib
import inspect
import math
from dataclasses import dataclass, replace
from functools import cached_property

from pbdyn.config import PlannerEntry, Scenario, canonical_json, check_v_max, later_fields, warn_stopping
from pbdyn.errors import ConfigError
from pbdyn.motion.registry import other_tables
from pbdyn.planning.registry import resolve_gaze_planner, resolve_trajectory_planner
from pbdyn.world.imported.bodies import bodies_fingerprint
from pbdyn.world.maps import MapSpec, stable_hash64


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial: scenario, map, planner pair, MAV speed, start and goal (m)."""

    scenario: Scenario
    map_spec: MapSpec
    planner: PlannerEntry
    v_max: float
    start: tuple[float, ...]
    goal: tuple[float, ...]

    def resolved(self) -> dict:
        """The canonical, path- and version-free description of the trial (what config_hash hashes)."""
        base = _scenario_part(self.scenario)
        return {
            **base, "map": self._map_dict(), "v_max": float(self.v_max),
            "start": [float(x) for x in self.start], "goal": [float(x) for x in self.goal],
            "planner": {"trajectory": self.planner.trajectory, "gaze": self.planner.gaze,
                        "trajectory_params": dict(self.planner.trajectory_params),
                        "gaze_params": dict(self.planner.gaze_params)},
        }

    def _map_dict(self) -> dict:
        """The map's part of resolved(): its setup and replicate, and its structure's settings when it has one."""
        out = {"setup": self.map_spec.setup, "replicate": self.map_spec.replicate}
        if "structure" in self.map_spec.setup:
            out["structure"] = _structure_dict(self.scenario, self.map_spec)
        return out

    @cached_property
    def config_hash(self) -> str:
        """sha256 of the canonical JSON of resolved() (computed once per spec)."""
        return hashlib.sha256(canonical_json(self.resolved()).encode()).hexdigest()

    @cached_property
    def seed(self) -> int:
        """A per-trial seed (sensor noise, planners that need randomness), derived from config_hash."""
        return stable_hash64(self.config_hash) >> 1


_SCENARIO_PARTS: dict = {}
"""id(scenario) -> (scenario, its part of resolved()): the scenarios last asked about (kept alive while cached, so
that an id is not reused), at most _SCENARIO_PARTS_KEPT."""
_SCENARIO_PARTS_KEPT = 8


def _scenario_part(scenario: Scenario) -> dict:
    """The scenario's part of TrialSpec.resolved() (the same for all its trials; computed once per scenario object,
    since Scenario is frozen). Callers must not modify it."""
    got = _SCENARIO_PARTS.get(id(scenario))
    if got is not None and got[0] is scenario:
        return got[1]
    sc = scenario.to_dict()
    skip = {"count", "radius", "speed", "maps_per_setup", "grid_order", "structure", "structures", "maps"}
    motion = sc["obstacles"]["motion"]
    skip |= other_tables(motion)
    skip |= set(later_fields("obstacles", sc["obstacles"]))       # stores keep resuming across versions
    obstacles = {k: v for k, v in sc["obstacles"].items() if k not in skip}
    drone = {k: v for k, v in sc["drone"].items() if k not in ("urdf", "v_max")}
    task = {k: v for k, v in sc["task"].items() if k not in ("candidates", "pairs_flown")}
    later = later_fields("tracking", sc["tracking"])
    tracking = {k: v for k, v in sc["tracking"].items() if k not in later}
    part = {
        "world": sc["world"], "obstacles": obstacles, "static_obstacles": sc["static_obstacles"], "drone": drone,
        "sensor": sc["sensor"], "tracking": tracking, "task": task, "candidates": sc["task"]["candidates"],
        "collision_check": scenario.collision_check, "profile": scenario.profile,
        **({"bodies": bodies_fingerprint(scenario)} if scenario.is_world else {}),
    }
    if len(_SCENARIO_PARTS) >= _SCENARIO_PARTS_KEPT:
        _SCENARIO_PARTS.pop(next(iter(_SCENARIO_PARTS)))
    _SCENARIO_PARTS[id(scenario)] = (scenario, part)
    return part


def _structure_dict(scenario, map_spec) -> dict:
    """The map's StructureConfig as plain data (what its trials' hashes include)."""
    from dataclasses import asdict

    return asdict(scenario.obstacles.structure_of(map_spec.setup["structure"]))


def _parse_point(text: str | None, field_name: str, dims: int) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(field_name, "must be comma-separated numbers like 4,25", text) from None
    if len(vals) != dims or not all(math.isfinite(v) for v in vals):
        raise ConfigError(field_name, f"must have {dims} finite coordinates", text)
    return vals


def _given_point(value, field_name: str, dims: int) -> tuple[float, ...]:
    """A start or goal given as "x,y[,z]" or a sequence of numbers; ConfigError naming ``field_name`` unless it has
    ``dims`` finite coordinates."""
    if isinstance(value, str):
        return _parse_point(value, field_name, dims)
    try:
        vals = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise ConfigError(field_name, "must be a sequence of numbers like (4, 25)", value) from None
    if len(vals) != dims or not all(math.isfinite(v) for v in vals):
        raise ConfigError(field_name, f"must have {dims} finite coordinates", value)
    return vals


def make_trial_spec(scenario: Scenario, map_spec: MapSpec, *, planner: str | None = None, gaze: str | None = None,
                    v_max: float | None = None, start: str | tuple | None = None,
                    goal: str | tuple | None = None) -> TrialSpec:
    """Resolve CLI-style choices into a TrialSpec (defaults: first planner entry, first v_max, first candidate as
    start, last candidate as goal). ``planner`` picks an entry by label or trajectory name, or names a trajectory
    planner; ``gaze`` overrides the entry's gaze planner. A ``v_max`` outside the scenario's grid that cannot stop
    within the sensor range is a PbdynWarning (pbdyn.config.warn_stopping)."""
    entries = scenario.planners
    entry = entries[0]
    if planner is not None:
        match = [e for e in entries if e.label == planner] or [e for e in entries if e.trajectory == planner]
        if gaze is not None:
            match = [e for e in match if e.gaze == gaze] or match
        entry = match[0] if match else PlannerEntry(planner, gaze or entry.gaze)
    if gaze is not None and entry.gaze != gaze:
        entry = PlannerEntry(entry.trajectory, gaze, entry.trajectory_params, {}, "")
    idx = next((i for i, e in enumerate(entries) if e == entry), None)
    resolve_trajectory_planner(entry.trajectory, "planner" if planner is not None or idx is None
                               else f"planners[{idx}].trajectory")
    resolve_gaze_planner(entry.gaze, "gaze" if gaze is not None or idx is None else f"planners[{idx}].gaze")
    if v_max is None:
        v = scenario.drone.v_max[0]
    else:
        if isinstance(v_max, bool) or not isinstance(v_max, (int, float)) or not math.isfinite(v_max) or v_max <= 0:
            raise ConfigError("v_max", "must be a positive number", v_max)
        v = check_v_max(v_max, "v_max")
    dims = scenario.world.dims
    cands = scenario.task.candidates
    s = cands[0] if start is None else _given_point(start, "start", dims)
    g = cands[-1] if goal is None else _given_point(goal, "goal", dims)
    r = scenario.drone.radius
    for name, pt in (("start", s), ("goal", g)):
        for k, x in enumerate(pt):
            if not r <= x <= scenario.world.size[k] - r:
                raise ConfigError(name, f"must lie inside the arena with the MAV's radius ({r:g} m) to spare",
                                  ",".join(f"{c:g}" for c in pt))
    if v not in scenario.drone.v_max:    # the scenario's own speeds were checked when it was loaded
        warn_stopping(scenario, (v,), "v_max")
    return TrialSpec(scenario, map_spec, entry, v, tuple(map(float, s)), tuple(map(float, g)))


def plugin_name(obj) -> str:
    """The "module:QualName" a planner class or instance is recorded under."""
    cls = obj if inspect.isclass(obj) else type(obj)
    return f"{cls.__module__}:{cls.__qualname__}"


def with_planner_objects(spec: TrialSpec, trajectory=None, gaze=None) -> TrialSpec:
    """``spec`` with its entry's trajectory and/or gaze planner given as a class or instance (not None) instead:
    recorded under plugin_name, without the replaced planner's params table."""
    if trajectory is None and gaze is None:
        return spec
    e = spec.planner
    return replace(spec, planner=PlannerEntry(
        e.trajectory if trajectory is None else plugin_name(trajectory),
        e.gaze if gaze is None else plugin_name(gaze),
        e.trajectory_params if trajectory is None else {}, e.gaze_params if gaze is None else {}))
