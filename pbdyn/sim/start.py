"""Where and when a trial starts (TaskConfig.start_rule; docs/profiles.md "Profiles" and "Scenario reference").

Spawning keeps every start/goal candidate's MAV disc plus ``spawn_clearance`` free at t = 0, but an obstacle can
arrive at the start before the MAV can move: such a trial begins next to an obstacle by construction, and its early
collision says nothing about the planner. Three rules:

- "first_clear" (default): the trial begins at the first rollout step t_s at which the MAV disc at the start, at
  rest, stays ``start_clearance`` m clear of every obstacle disc (and of nothing else: static bodies are kept away
  from the candidates by the scenario) for ``start_window_s`` s. The default window, 1 s, is the time the MAV needs
  to move its own diameter (2 m) sideways from rest at a_max = 4 m/s^2 (sqrt(2 * 2 m / 4 m/s^2)). The map (rollout)
  is the one every metric sees; only the trial's clock starts later (rollout step k0 + k is trial step k). If no
  step within ``start_wait_max_s`` is clear, the trial begins at the step whose window keeps the largest gap (the
  earliest of equals) and the row's reason says so.
- "immediate": t_s = 0 (pbdyn before the start rule existed).
- "program": the thesis' program (docs/thesis-program.md "World and obstacles", a defect reproduced by the
  thesis_program profile): the obstacles are spawned with their centres more than the MAV radius +
  ``start_clearance`` m from the flown start only (not from the other candidates; the program's 8 m test), so the flown layout depends on the start and differs from the
  map the metrics were computed on. Radii and velocities are the map's; only the centres are drawn again (same
  seed). t_s = 0.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from pbdyn.world.rollout import Rollout, build_rollout, rollout_key

_VARIANTS: "OrderedDict[tuple, Rollout]" = OrderedDict()
_VARIANT_CACHE = 16   # start variants kept per process (a map has at most a handful of candidate starts in use)


@dataclass(frozen=True)
class TrialStart:
    """The rollout a trial flies in, the rollout step its t = 0 maps to (k0), and whether the start was clear
    (False only when "first_clear" found no clear step within the wait)."""

    rollout: Rollout
    k0: int
    clear: bool = True

    @property
    def time_s(self) -> float:
        """The rollout time of the trial's t = 0 (s)."""
        return float(self.k0 * self.rollout.dt)


def start_gaps(rollout: Rollout, start: np.ndarray, mav_radius: float, n_steps: int) -> np.ndarray:
    """Per rollout step 0..n_steps-1: the smallest gap (m) between the MAV disc/ball at ``start`` and any obstacle
    (centre distance - r_i - mav_radius); +inf without obstacles."""
    n = min(int(n_steps), rollout.n_steps)
    if rollout.n_obstacles == 0:
        return np.full(n, np.inf)
    rel = rollout.positions[:n] - np.asarray(start, dtype=float)[None, None, :]
    dist = np.sqrt(np.einsum("knd,knd->kn", rel, rel))
    return np.min(dist - rollout.radii[None, :], axis=1) - mav_radius


def first_clear_step(gaps: np.ndarray, clearance: float, window: int, max_wait: int) -> tuple[int, bool]:
    """(k0, clear): the first step k <= max_wait whose gaps[k..k+window] all stay >= clearance; without one, the
    step whose window keeps the largest smallest gap (earliest of equals) and clear = False. ``gaps`` must cover
    max_wait + window + 1 steps."""
    need = max_wait + window + 1
    if gaps.shape[0] < need:
        raise ValueError(f"gaps cover {gaps.shape[0]} steps, the start rule needs {need}")
    worst = np.lib.stride_tricks.sliding_window_view(gaps[:need], window + 1).min(axis=1)   # [max_wait + 1]
    ok = np.flatnonzero(worst >= clearance)
    if ok.size:
        return int(ok[0]), True
    return int(np.argmax(worst)), False


def trial_start(spec, rollout: Rollout) -> TrialStart:
    """The TrialStart of ``spec`` (a pbdyn.sim.spec.TrialSpec) on its map's ``rollout`` (see the module doc)."""
    sc = spec.scenario
    task = sc.task
    if task.start_rule == "immediate" or (task.start_rule == "program" and sc.is_world):
        return TrialStart(rollout, 0)
    start = np.asarray(spec.start, dtype=float)
    if task.start_rule == "program":
        return TrialStart(_program_rollout(spec, rollout, start), 0)
    dt = rollout.dt
    window = int(round(task.start_window_s / dt))
    max_wait = int(round(task.start_wait_max_s / dt))
    gaps = start_gaps(rollout, start, sc.drone.radius, max_wait + window + 1)
    k0, clear = first_clear_step(gaps, task.start_clearance, window, max_wait)
    return TrialStart(rollout, k0, clear)


def _program_rollout(spec, rollout: Rollout, start: np.ndarray) -> Rollout:
    """The map re-spawned with start_clearance around ``start`` only, over the given rollout's horizon (cached per
    process: every trial from the same start on the same map shares it)."""
    sc = spec.scenario
    horizon = rollout.horizon
    key = (rollout_key(sc, spec.map_spec, horizon), tuple(start.tolist()), sc.task.start_clearance)
    hit = _VARIANTS.get(key)
    if hit is not None:
        _VARIANTS.move_to_end(key)
        return hit
    variant = build_rollout(sc, spec.map_spec, horizon, keep_out=(start[None, :], sc.task.start_clearance))
    _VARIANTS[key] = variant
    while len(_VARIANTS) > _VARIANT_CACHE:
        _VARIANTS.popitem(last=False)
    return variant
