"""An experiment's trials and maps as small picklable tasks, and the functions workers run on them.

An experiment = maps x planner pairs x MAV speeds x start/goal pairs (DESIGN.md "Maps and seeds"): the trial key is
the trial's config hash (sha256 of its resolved, value-only description), so adding a grid value, a planner, a
speed or maps never changes an existing key. Workers receive the scenario, the map spec and a rollout reference
(a file path, or the .npz bytes for cluster workers without the coordinator's disk); they keep the last map's
rollout and PyBullet world for the next trial of the same map, and one PyBullet client for their whole life
(reset and refilled when the map changes).
"""

from __future__ import annotations

import dataclasses
import io
import os
import traceback
from dataclasses import dataclass

import numpy as np

from pbdyn.config import PlannerEntry, Scenario
from pbdyn.errors import one_line
from pbdyn.metrics.catalog import BATCH
from pbdyn.sim.outcome import Outcome
from pbdyn.world.maps import MapSpec

METRIC_SET = BATCH
"""The metrics of the thesis' table 4-5, computed once per map (pbdyn.metrics.catalog)."""


@dataclass(frozen=True)
class RolloutRef:
    """Where a worker finds a map's rollout: ``path`` (an .npz file) or ``data`` (its bytes); ``key`` identifies it."""

    key: str
    path: str = ""
    data: bytes = b""


@dataclass(frozen=True)
class TrialTask:
    """One trial to fly: its key (the spec's config hash), its TrialSpec and where its map's rollout is."""

    key: str
    spec: object  # pbdyn.sim.trial.TrialSpec (imported lazily: workers import the trial loop on first use)
    rollout: RolloutRef


@dataclass(frozen=True)
class MapTask:
    """One map's metrics to compute."""

    scenario: Scenario
    map_spec: MapSpec
    rollout: RolloutRef
    metrics: tuple[str, ...] = METRIC_SET
    backend: str = "auto"


def trial_spec(scenario: Scenario, map_spec: MapSpec, planner: PlannerEntry, v_max: float, start, goal):
    """The TrialSpec of one experiment cell."""
    from pbdyn.sim.trial import TrialSpec

    return TrialSpec(scenario, map_spec, planner, float(v_max), tuple(map(float, start)), tuple(map(float, goal)))


def enumerate_trials(scenario: Scenario, maps: list[MapSpec]) -> list[tuple[str, MapSpec, PlannerEntry, float,
                                                                            tuple, tuple]]:
    """Every trial of the experiment as (key, map, planner entry, v_max, start, goal), in the order maps (file
    order) x planner entries x MAV speeds x start/goal pairs."""
    cands = scenario.task.candidates
    out = []
    for m in maps:
        for entry in scenario.planners:
            for v in scenario.drone.v_max:
                for i, j in scenario.task.pairs():
                    spec = trial_spec(scenario, m, entry, v, cands[i], cands[j])
                    out.append((spec.config_hash, m, entry, float(v), tuple(cands[i]), tuple(cands[j])))
    return out


# ------------------------------------------------------------------------------------------------ worker side
_CACHE: dict = {"rollout": (None, None), "world": (None, None), "client": None}


def _limit_threads() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _rollout(ref: RolloutRef, data: bytes | None = None):
    from pbdyn.world.rollout import Rollout

    key, ro = _CACHE["rollout"]
    if key != ref.key:
        ro = Rollout.load(io.BytesIO(data) if data is not None else ref.path if ref.path else io.BytesIO(ref.data))
        _CACHE["rollout"] = (ref.key, ro)
    return ro


def _world(task: TrialTask, spec, ro):
    from pbdyn.sim.trial import make_world

    sc = spec.scenario
    key = (task.rollout.key, sc.world, sc.drone.radius, sc.drone.urdf, sc.source)
    old_key, world = _CACHE["world"]
    if old_key != key:
        if world is not None:
            world.close()                      # leaves the worker's client connected
        _CACHE["world"] = (None, None)
        if _CACHE["client"] is None:
            from pbdyn.world.bullet import new_client

            _CACHE["client"] = new_client()    # one client per worker, reset for every map
        world = make_world(spec, ro, client=_CACHE["client"])
        _CACHE["world"] = (key, world)
    return world


def error_row(task: TrialTask, message: str) -> dict:
    """The result row of a trial that raised: outcome "error" with the message, the task's identifying fields."""
    s = task.spec
    m = s.map_spec
    return {"gaze": s.planner.gaze, "planner": s.planner.trajectory, "map_index": m.index,
            "map_id": m.map_id, "map_seed": m.seed, "map_key": m.key, "mav_speed": s.v_max,
            "obstacle_count": int(m.setup.get("count", 0)), "obstacle_radius": m.setup.get("radius"),
            "obstacle_speed": m.setup.get("speed"), "start": list(s.start), "goal": list(s.goal),
            "outcome": Outcome.ERROR.value, "reason": message, "planner_label": s.planner.label,
            "scenario": s.scenario.name, "config_hash": task.key, "planner_fingerprint": _fingerprint(s.planner)}


def _fingerprint(entry: PlannerEntry) -> str:
    """The entry's planner fingerprint as this worker's code gives it ("" if it cannot be computed)."""
    from pbdyn.planning.registry import pair_fingerprint

    try:
        return pair_fingerprint(entry.trajectory, entry.gaze)
    except Exception:  # an error row is still written; its empty fingerprint makes `pbdyn batch` flag it
        return ""


def run_trial_task(task: TrialTask, data: bytes | None = None) -> tuple[str, dict, str | None]:
    """Fly one trial in this worker: (trial key, TrialResult dict with its planner_fingerprint, None), or an "error"
    row and its message if the trial raised (the batch goes on). ``data``: the rollout's .npz bytes (cluster
    workers), else task.rollout."""
    _limit_threads()
    from pbdyn.sim.trial import run_trial

    try:
        ro = _rollout(task.rollout, data)
        spec = task.spec
        world = _world(task, spec, ro)
        try:
            res = run_trial(spec, ro, world=world)
        except BaseException:
            _CACHE["world"] = (None, None)     # a failed trial may leave the world in any state: rebuild it
            raise
        res = dataclasses.replace(res, planner_fingerprint=_fingerprint(spec.planner))
        return task.key, res.to_dict(), None
    except Exception as exc:  # any failure of a trial is recorded as an "error" row, never stops the batch
        msg = one_line(exc)
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            msg += f" (at {os.path.basename(tb[-1].filename)}:{tb[-1].lineno})"
        return task.key, error_row(task, msg), msg


def run_map_task(task: MapTask, data: bytes | None = None) -> dict:
    """Compute one map's metrics in this worker: a maps-table row (metrics, their compute times, the map's mean
    obstacle speed and radius)."""
    _limit_threads()
    from pbdyn.metrics.cached import metric_params, resolve_backend
    from pbdyn.metrics.registry import compute

    ro = _rollout(task.rollout, data)
    backend = resolve_backend(task.scenario, task.backend)
    metrics, times = {}, {}
    for name in task.metrics:
        res = compute(ro, name, **metric_params(task.scenario, name, backend))
        metrics[name] = res.value
        times[name] = res.wall_time_s
    speeds = np.linalg.norm(ro.velocities[0], axis=-1) if ro.n_obstacles else np.zeros(0)
    m = task.map_spec
    return {"map_id": m.map_id, "map_index": m.index, "map_key": m.key, "setup_json": m.setup, "seed": m.seed,
            "rollout_key": task.rollout.key, "dataset": task.scenario.name,
            "mean_obstacle_speed": float(speeds.mean()) if speeds.size else 0.0,
            "mean_obstacle_radius": float(ro.radii.mean()) if ro.n_obstacles else 0.0,
            "metrics_json": metrics, "metric_times_json": times, "backend": backend}


def worker_init() -> None:
    """Process-pool worker start: ignore SIGINT (a Ctrl-C reaches the whole process group; the coordinator stops
    the workers itself) and limit BLAS/OpenMP threads."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _limit_threads()
