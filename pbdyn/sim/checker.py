"""``check_planner``: fly a planner on a few maps and report every breach of the plan contract (the analogue of
Gymnasium's ``check_env`` for trajectory planners; docs/design.md "The plan contract")."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from pbdyn.config import Scenario
from pbdyn.errors import ConfigError
from pbdyn.sim.contract import PlanViolation
from pbdyn.outcome import Outcome
from pbdyn.sim.spec import make_trial_spec, plugin_name, with_planner_objects
from pbdyn.sim.trial import run_trial


@dataclass(frozen=True)
class TrialViolation:
    """A trial that ended as invalid_plan: its map index, start and goal (m), the plan's time (s) and every check
    that plan broke."""

    map_index: int
    start: tuple[float, ...]
    goal: tuple[float, ...]
    t: float
    violations: tuple[PlanViolation, ...]


@dataclass(frozen=True)
class PlannerCheck:
    """What check_planner found: the planner's name, the trials flown, their outcomes and every contract breach."""

    planner: str
    trials: int
    outcomes: dict = field(default_factory=dict)
    breaches: tuple[TrialViolation, ...] = ()

    @property
    def ok(self) -> bool:
        """True if no plan broke the contract."""
        return not self.breaches

    def __str__(self) -> str:
        lines = [f"{self.planner}: {self.trials} trials, "
                 + ", ".join(f"{k} {v}" for k, v in sorted(self.outcomes.items()))
                 + (" - plan contract respected" if self.ok else f" - {len(self.breaches)} invalid plans")]
        for b in self.breaches:
            where = ",".join(f"{x:g}" for x in b.start) + " -> " + ",".join(f"{x:g}" for x in b.goal)
            for v in b.violations:
                lines.append(f"  map {b.map_index} {where} t={b.t:.1f} s: {v.reason}")
        return "\n".join(lines)


class _Violations:
    def __init__(self):
        self.found: tuple[PlanViolation, ...] = ()

    def on_step(self, state, agent, decision, record) -> None:
        pass

    def on_end(self, state, agent) -> None:
        self.found = tuple(agent.violations)


def check_planner(planner, scenario: Scenario, *, maps=3, pairs: int = 4, gaze: str | None = None,
                  v_max: float | None = None) -> PlannerCheck:
    """Fly ``planner`` (a registry name, "package.module:Class", a class, or an instance — reused by every trial)
    on ``maps`` maps of ``scenario`` (an int: the first N; or a list of map indices) x ``pairs`` start/goal pairs
    spread over the scenario's candidates (rotated from map to map), with the gaze planner ``gaze`` (default: the first entry's) at ``v_max``
    (default: the first drone.v_max), and report every plan that broke the contract."""
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import get_rollout

    all_maps = enumerate_maps(scenario)
    if isinstance(maps, int) and not isinstance(maps, bool):
        if maps < 1:
            raise ConfigError("maps", "must be a number of maps >= 1 or a list of map indices", maps)
        indices = list(range(min(maps, len(all_maps))))
    elif isinstance(maps, (list, tuple, range)) and len(maps) > 0:
        indices = list(maps)
    else:
        raise ConfigError("maps", "must be a number of maps >= 1 or a non-empty list of map indices", maps)
    for i in indices:
        if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < len(all_maps):
            raise ConfigError("maps", f"must be map indices in 0..{len(all_maps) - 1}", i)
    if not isinstance(pairs, int) or isinstance(pairs, bool) or pairs < 1:
        raise ConfigError("pairs", "must be an integer >= 1", pairs)
    named = isinstance(planner, str)
    name = planner if named else plugin_name(planner)
    cands = scenario.task.candidates
    all_pairs = scenario.task.pairs()
    step = max(1, len(all_pairs) // pairs)
    outcomes: Counter = Counter()
    breaches = []
    for m in indices:
        ms = all_maps[m]
        ro = get_rollout(scenario, ms)
        for i, j in (all_pairs[(7 * m + s * step) % len(all_pairs)] for s in range(min(pairs, len(all_pairs)))):
            spec = make_trial_spec(scenario, ms, planner=planner if named else None, gaze=gaze, v_max=v_max,
                                   start=cands[i], goal=cands[j])
            spec = with_planner_objects(spec, None if named else planner)
            watch = _Violations()
            res = run_trial(spec, ro, trajectory_planner=None if named else planner, observers=[watch])
            outcomes[res.outcome] += 1
            if res.outcome == Outcome.INVALID_PLAN.value:
                breaches.append(TrialViolation(m, cands[i], cands[j], res.flight_time_s, watch.found))
    return PlannerCheck(name, sum(outcomes.values()), dict(outcomes), tuple(breaches))
