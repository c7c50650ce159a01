"""Observers of a trial: they watch each step and never change it (trace file, per-step profile; the GUI's are
in pbdyn.sim.gui).

An observer has ``on_step(state, agent, decision, record)``, called after every executed step with ``state`` the
trial's TrialState, ``agent`` its Agent and ``decision`` the agent's Decision of the step (both None for a trial
a caller drives, e.g. a Gymnasium policy), ``record`` the step's StepRecord (what the MAV knew and did at t_k, the
wall-time splits); and ``on_end(state, agent)``, called once when the trial has ended normally (not when it
raised). Observers attach to a trial of a batch (pbdyn.sim.batch.TrialBatch.watch).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from pbdyn.files import atomic_write
from pbdyn.sim.state import SENSE_SPLITS
from pbdyn.world.shapes import still_body_outlines

SPLITS = SENSE_SPLITS + ("wall_planning_s", "wall_gaze_s", "wall_collision_s")
"""Wall-time splits of one step: (1) world, (2) rays, (3) tracking, (4) planning, (5) gaze, (6)-(7) collision."""


@dataclass(frozen=True)
class StepRecord:
    """One executed step: t (s), the MAV state at t_k (p m, v m/s, a m/s^2 [d], yaw rad), the clipped yaw rate
    (rad/s), whether replan_check asked for a plan and whether it succeeded, the tracks (pbdyn Tracks) and the
    detected obstacle ids at t_k, and the step's wall-time splits (s, in SPLITS order)."""

    t: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    yaw: float
    yaw_rate: float
    planned: bool
    plan_ok: bool
    tracks: object
    detected: np.ndarray
    splits: tuple[float, ...]


class Observer(Protocol):
    """Watches a trial (see the module docstring)."""

    def on_step(self, state, agent, decision, record: StepRecord) -> None: ...

    def on_end(self, state, agent) -> None: ...


class ProfileObserver:
    """Per-step lists of each timing split (SPLITS, s), "candidates_built" (the planner's ``last_candidates_built``
    when it has one, else NaN) and "planned", written into the given dict."""

    def __init__(self, profile: dict):
        self.profile = profile
        for name in SPLITS + ("candidates_built", "planned"):
            profile[name] = []

    def on_step(self, state, agent, decision, record: StepRecord) -> None:
        for name, value in zip(SPLITS, record.splits):
            self.profile[name].append(value)
        self.profile["candidates_built"].append(getattr(getattr(agent, "planner", None), "last_candidates_built",
                                                        float("nan")))
        self.profile["planned"].append(bool(record.planned))

    def on_end(self, state, agent) -> None:
        pass


@dataclass
class TraceObserver:
    """Records per-step arrays and writes them to ``path`` (.npz) when the trial ends (``pbdyn run --trace``)."""

    path: str | Path
    t: list = field(default_factory=list)
    p: list = field(default_factory=list)
    v: list = field(default_factory=list)
    a: list = field(default_factory=list)
    yaw: list = field(default_factory=list)
    yaw_rate: list = field(default_factory=list)
    planned: list = field(default_factory=list)
    plan_ok: list = field(default_factory=list)
    track_mean: list = field(default_factory=list)
    track_std: list = field(default_factory=list)
    track_active: list = field(default_factory=list)
    seen: list = field(default_factory=list)

    def on_step(self, state, agent, decision, record: StepRecord) -> None:
        self.t.append(record.t)
        self.p.append(record.position.copy())
        self.v.append(record.velocity.copy())
        self.a.append(record.acceleration.copy())
        self.yaw.append(record.yaw)
        self.yaw_rate.append(record.yaw_rate)
        self.plan_ok.append(record.plan_ok)
        traj = getattr(agent, "trajectory", None)
        self.planned.append(None if traj is None else traj.remaining(record.t).p.copy())
        n, d = state.rollout.n_obstacles, state.dims
        mean = np.full((n, d), np.nan)
        std = np.full((n, d), np.nan)
        tr = record.tracks
        mean[tr.ids] = tr.position
        if len(tr):
            std[tr.ids] = np.sqrt(np.maximum(np.diagonal(tr.covariance[:, :d, :d], axis1=1, axis2=2), 0.0))
        self.track_std.append(std)
        active = np.zeros(n, dtype=bool)
        active[tr.ids] = True
        self.track_mean.append(mean)
        self.track_active.append(active)
        seen = np.zeros(n, dtype=bool)
        seen[np.asarray(record.detected, dtype=np.int64)] = True
        self.seen.append(seen)

    def on_end(self, state, agent) -> None:
        k0, s = state.k0, len(self.t)
        sc = state.spec.scenario
        static = state.rollout.static
        d = state.dims
        extra = {"obstacle_p": np.asarray(state.rollout.positions[k0:k0 + s + 1]),
                 "obstacle_r": np.asarray(state.rollout.radii), "start_step": np.array(k0),
                 "dt": np.array(state.dt), "arena_lo": state.bounds[0], "arena_hi": state.bounds[1],
                 "start": np.asarray(state.spec.start, dtype=float), "goal": state.goal,
                 "goal_radius": np.array(state.goal_radius), "mav_radius": np.array(sc.drone.radius),
                 "fov_deg": np.array(state.fov_deg), "range_m": np.array(sc.sensor.range),
                 "vfov_deg": np.array(sc.sensor.vfov_deg if d == 3 else np.nan),
                 "reason": np.array(state.reason), "label": np.array(trace_label(
                     f"{sc.name} map {state.spec.map_spec.index}, {state.spec.planner.label}, "
                     f"v_max {state.spec.v_max:g} m/s")),
                 "static_kind": np.array([b.kind for b in static], dtype=str),
                 "static_center": np.array([np.asarray(b.center, float)[:d] for b in static]).reshape(len(static), d),
                 "static_radius": np.array([b.radius for b in static], dtype=float),
                 "static_size": np.array([np.asarray(b.size if b.size else (0.0,) * d, float)[:d]
                                          for b in static]).reshape(len(static), d),
                 "static_yaw": np.array([b.yaw for b in static], dtype=float),
                 **still_body_outlines(state.rollout.bodies, d, sc.world.flight_height)}
        save_trace(self, self.path, state.position, state.velocity, state.acceleration, state.yaw, state.outcome,
                   extra)


MAX_LABEL_CHARS = 300
"""Longest label a trace stores (the replay's title); a longer one is cut, its end marked "..."."""


def trace_label(text: str) -> str:
    """``text`` as a trace's label: at most MAX_LABEL_CHARS characters ("..." marks a cut)."""
    return text if len(text) <= MAX_LABEL_CHARS else text[:MAX_LABEL_CHARS - 3] + "..."


def save_trace(trace: TraceObserver, path, p, v, a, yaw, outcome, extra: dict | None = None) -> None:
    """Write the trace .npz atomically: per-step t [S], p/v/a [S, d], yaw [S], yaw_rate [S], plan_ok [S],
    plan [S, Kmax, d] (NaN-padded remaining plan at each step), track_mean [S, N, d] and track_std [S, N, d] (the
    tracks' position means and standard deviations per axis, m; NaN if inactive), track_active [S, N], seen [S, N],
    final_p/v/a [d], final_yaw, outcome; ``extra`` arrays (run_trial: the obstacles' true positions obstacle_p
    [S + 1, N, d] at trial steps 0..S and radii obstacle_r [N], start_step (the rollout step of the trial's t = 0,
    pbdyn.sim.start), dt, arena_lo/arena_hi [d], start/goal [d], goal_radius, mav_radius, fov_deg, range_m,
    vfov_deg (NaN in 2D), reason, label (scenario, map, planner pair, v_max), the static bodies static_kind
    [B], static_center/static_size [B, d], static_radius/static_yaw [B], and an imported world's still bodies
    static_outline [P, V, 2] (2D: cut by the flight plane; 3D: top view) and in 3D static_outline_side [P, V, 2]
    (x-z), NaN-padded polygons (pbdyn.world.shapes.still_body_outlines): what pbdyn replay draws)."""
    kmax = max([0] + [x.shape[0] for x in trace.planned if x is not None])
    d = p.shape[0]
    plans = np.full((len(trace.t), max(kmax, 1), d), np.nan)
    for i, x in enumerate(trace.planned):
        if x is not None:
            plans[i, : x.shape[0]] = x
    n = len(trace.track_active[0]) if trace.track_active else 0
    arrays = {
        "t": np.asarray(trace.t), "p": np.asarray(trace.p).reshape(-1, d), "v": np.asarray(trace.v).reshape(-1, d),
        "a": np.asarray(trace.a).reshape(-1, d), "yaw": np.asarray(trace.yaw), "yaw_rate": np.asarray(trace.yaw_rate),
        "plan_ok": np.asarray(trace.plan_ok, dtype=bool), "plan": plans,
        "track_mean": np.asarray(trace.track_mean, dtype=float).reshape(len(trace.t), n, d),
        "track_std": np.asarray(trace.track_std, dtype=float).reshape(len(trace.t), n, d),
        "track_active": np.asarray(trace.track_active, dtype=bool).reshape(len(trace.t), n),
        "seen": np.asarray(trace.seen, dtype=bool).reshape(len(trace.t), n),
        "final_p": p, "final_v": v, "final_a": a, "final_yaw": np.array(yaw), "outcome": np.array(outcome.value),
        **(extra or {}),
    }
    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    atomic_write(path, write, make_parents=True)
