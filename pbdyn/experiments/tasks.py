"""An experiment's trials and maps as small picklable tasks, and the functions workers run on them.

An experiment = maps x planner pairs x MAV speeds x start/goal pairs (docs/design.md "Maps and seeds"): the trial key is
the trial's config hash (sha256 of its resolved, value-only description), so adding a grid value, a planner, a
speed or maps never changes an existing key. Workers receive the scenario, the map spec and a rollout reference
(a file path, or the .npz bytes for cluster workers without the coordinator's disk); they keep the last map's
rollout and PyBullet world for the next trial of the same map, and one PyBullet client for their whole life
(reset and refilled when the map changes).
"""

from __future__ import annotations

import atexit
import hashlib
import io
import json
import os
import traceback
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from pbdyn.config import PlannerEntry, Scenario, canonical_json
from pbdyn.errors import one_line
from pbdyn.experiments import limit_threads
from pbdyn.metrics.catalog import BATCH
from pbdyn.outcome import Outcome
from pbdyn.world.maps import MapSpec, enumerate_maps, sequence_index

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
    spec: object  # pbdyn.sim.spec.TrialSpec (imported lazily: workers import the trial loop on first use)
    rollout: RolloutRef


@dataclass(frozen=True)
class TrialGroupTask:
    """Trials of one map flown together as one trial batch (pbdyn.sim.trial.fly_trials): their keys and TrialSpecs, in
    order, and where the map's rollout is."""

    keys: tuple
    specs: tuple
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
    from pbdyn.sim.spec import TrialSpec      # the coordinator needs the spec, not the trial loop

    return TrialSpec(scenario, map_spec, planner, float(v_max), tuple(map(float, start)), tuple(map(float, goal)))


class Trial(NamedTuple):
    """One trial of an experiment's enumeration (TrialSequence)."""

    key: str                # its config hash
    map: MapSpec
    planner: PlannerEntry
    v_max: float            # m/s
    start: tuple            # m
    goal: tuple             # m

_VARYING = ("map", "v_max", "start", "goal", "planner")
"""The parts of TrialSpec.resolved() that differ between the trials of one scenario; each depends on one axis."""


class _ScenarioDict:
    """A Scenario whose to_dict() is computed once (TrialSpec.resolved() calls it on every call; with thousands of
    candidates it costs 0.1 s). Everything else is the scenario's own."""

    def __init__(self, scenario: Scenario):
        self._scenario = scenario
        self._dict = scenario.to_dict()

    def to_dict(self) -> dict:
        return self._dict

    def __getattr__(self, name):
        return getattr(self._scenario, name)


class _TrialKeys:
    """Trial keys (config hashes) without building a TrialSpec per trial: the canonical JSON of resolved() is the
    concatenation, in sorted key order, of each top-level value's canonical JSON, so the scenario's fragments are
    computed once and each axis' fragment (map, planner entry, speed, start, goal) once per value, from resolved()
    itself. The same bits as spec.config_hash (checked against it on the first trial of every map)."""

    def __init__(self, scenario: Scenario, maps):
        self.scenario = _ScenarioDict(scenario)
        self.m0 = maps[0] if len(maps) else None
        c = scenario.task.candidates
        self.e0, self.v0, self.c0 = scenario.planners[0], float(scenario.drone.v_max[0]), tuple(c[0])
        proto = self._resolved(m=self.m0) if self.m0 is not None else {}
        # the canonical JSON as constant text between the varying values, in sorted key order
        self.slots: list[str] = []      # varying names, in order
        self.text: list[str] = [""]     # len(slots) + 1 constant pieces
        for i, k in enumerate(sorted(proto)):
            self.text[-1] += ("{" if i == 0 else ",") + json.dumps(k) + ":"
            if k in _VARYING:
                self.slots.append(k)
                self.text.append("")
            else:
                self.text[-1] += canonical_json(proto[k])
        self.text[-1] += "}"
        self.cache: dict = {}

    def _resolved(self, m=None, e=None, v=None, s=None, g=None) -> dict:
        return trial_spec(self.scenario, m or self.m0, e or self.e0, self.v0 if v is None else v,
                          s or self.c0, g or self.c0).resolved()

    def _frag(self, axis: str, ident, **kw) -> str:
        k = (axis, ident)
        f = self.cache.get(k)
        if f is None:
            f = canonical_json(self._resolved(**kw)[axis])
            if axis != "map":      # maps come and go; the other axes are few
                self.cache[k] = f
        return f

    def key(self, mfrag: str, e_i: int, entry: PlannerEntry, v: float, start: tuple, s_i: int, goal: tuple,
            g_i: int) -> str:
        parts = {"map": mfrag, "planner": self._frag("planner", e_i, e=entry),
                 "v_max": self._frag("v_max", v, v=v), "start": self._frag("start", s_i, s=start),
                 "goal": self._frag("goal", g_i, g=goal)}
        text = self.text[0] + "".join(parts[k] + t for k, t in zip(self.slots, self.text[1:]))
        return hashlib.sha256(text.encode()).hexdigest()

    def map_frag(self, m: MapSpec) -> str:
        return self._frag("map", m.key, m=m)


class TrialSequence(Sequence):
    """Every trial of the experiment as (key, map, planner entry, v_max, start, goal), lazily, in the order maps
    (file order) x planner entries x MAV speeds x start/goal pairs: ``len``, indexing by index arithmetic, slices
    (lists), iteration and ``iter_range(start, stop)`` (streams; --limit N costs O(N))."""

    def __init__(self, scenario: Scenario, maps=None):
        self.scenario = scenario
        self.maps = enumerate_maps(scenario) if maps is None else maps
        self.cands = tuple(tuple(c) for c in scenario.task.candidates)
        self.speeds = tuple(float(v) for v in scenario.drone.v_max)
        self.entries = tuple(scenario.planners)
        self.pairs = tuple(tuple(p) for p in scenario.task.pairs_flown)    # () = every ordered pair, by arithmetic
        n = len(self.cands)
        self.n_pairs = len(self.pairs) if self.pairs else n * (n - 1)
        self.per_map = len(self.entries) * len(self.speeds) * self.n_pairs
        self._keys: _TrialKeys | None = None

    def __len__(self) -> int:
        return len(self.maps) * self.per_map

    def pair(self, p: int) -> tuple[int, int]:
        """The p-th ordered (start, goal) index pair flown, scenario.task.flown_pairs()[p] (without building the
        list of every pair: 10,000 candidates make 99,990,000)."""
        if self.pairs:
            return self.pairs[p]
        n1 = len(self.cands) - 1
        i, r = divmod(p, n1)
        return i, r + (r >= i)

    def _split(self, idx: int) -> tuple[int, int, int, int]:
        m, rem = divmod(idx, self.per_map)
        e, rem = divmod(rem, len(self.speeds) * self.n_pairs)
        v, p = divmod(rem, self.n_pairs)
        return m, e, v, p

    def __getitem__(self, index):
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step == 1:
                return list(self.iter_range(start, stop))
            return [self[i] for i in range(start, stop, step)]
        i = sequence_index(index, len(self), "trial")
        return next(self.iter_range(i, i + 1))

    def __iter__(self) -> Iterator[Trial]:
        return self.iter_range(0, len(self))

    def map_range(self, stop: int) -> range:
        """Indices of the maps the first ``stop`` trials fly on."""
        return range(0, (stop + self.per_map - 1) // self.per_map if self.per_map else 0)

    def iter_range(self, start: int, stop: int) -> Iterator[Trial]:
        """Trials start..stop-1 of the enumeration, one at a time."""
        stop = min(stop, len(self))
        if start >= stop:
            return
        if self._keys is None:
            self._keys = _TrialKeys(self.scenario, self.maps)
        keys = self._keys
        nv, npairs = len(self.speeds), self.n_pairs
        idx = start
        while idx < stop:
            mi, e_i, v_i, p = self._split(idx)
            m = self.maps[mi]
            mfrag = keys.map_frag(m)
            checked = False
            for e_i in range(e_i, len(self.entries)):
                entry = self.entries[e_i]
                for v_i in range(v_i, nv):
                    v = self.speeds[v_i]
                    for p in range(p, npairs):
                        if idx >= stop:
                            return
                        i, j = self.pair(p)
                        s, g = self.cands[i], self.cands[j]
                        key = keys.key(mfrag, e_i, entry, v, s, i, g, j)
                        if not checked:       # the fragments against the spec's own hash, once per map
                            ref = trial_spec(self.scenario, m, entry, v, s, g).config_hash
                            if ref != key:   # pragma: no cover - a change to TrialSpec.resolved() needs _VARYING
                                raise RuntimeError(f"trial key fragments disagree with TrialSpec.config_hash "
                                                   f"({key} != {ref}); update pbdyn.experiments.tasks._VARYING")
                            checked = True
                        yield Trial(key, m, entry, v, s, g)
                        idx += 1
                    p = 0
                v_i = 0


def enumerate_trials(scenario: Scenario, maps=None) -> TrialSequence:
    """Every trial of the experiment as (key, map, planner entry, v_max, start, goal), in the order maps (file
    order) x planner entries x MAV speeds x start/goal pairs -- lazily (a TrialSequence); ``maps``: the maps to
    enumerate (default: all of the scenario's, lazily)."""
    return TrialSequence(scenario, maps)


# ------------------------------------------------------------------------------------------------ worker side
_CACHE: dict = {"rollout": (None, None), "world": (None, None), "client": None, "queue": None}


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
            from pbdyn.world.pybullet_client import new_client

            _CACHE["client"] = new_client()    # one client per worker, reset for every map
            atexit.register(close_worker_world)
        world = make_world(spec, ro, client=_CACHE["client"])
        _CACHE["world"] = (key, world)
    return world


def close_worker_world() -> None:
    """Close this worker's world and disconnect its PyBullet client (registered with atexit when the client is made:
    a client left to BulletClient.__del__ at interpreter shutdown ends the worker with a traceback on stderr)."""
    _, world = _CACHE["world"]
    client = _CACHE["client"]
    _CACHE["world"], _CACHE["client"] = (None, None), None
    if world is not None:
        world.close()
    if client is not None:
        from pbdyn.world.pybullet_client import stdout_to_stderr

        with stdout_to_stderr():
            client.disconnect()


def error_row(task: TrialTask, message: str) -> dict:
    """The result row of a trial that raised: outcome "error" with the message, the task's identifying fields."""
    from pbdyn.planning.registry import recorded_fingerprint

    s = task.spec
    m = s.map_spec
    fp = recorded_fingerprint(s.planner.trajectory, s.planner.gaze)   # "": the batch flags the row's code
    return {"gaze": s.planner.gaze, "planner": s.planner.trajectory, "map_index": m.index,
            "map_id": m.map_id, "map_seed": m.seed, "map_key": m.key, "mav_speed": s.v_max,
            "obstacle_count": int(m.setup.get("count", 0)), "obstacle_radius": m.setup.get("radius"),
            "obstacle_speed": m.setup.get("speed"), "start": list(s.start), "goal": list(s.goal),
            "outcome": Outcome.ERROR.value, "reason": message, "planner_label": s.planner.label,
            "scenario": s.scenario.name, "config_hash": task.key, "planner_fingerprint": fp}


def run_trial_task(task: TrialTask, data: bytes | None = None) -> tuple[str, dict, str | None]:
    """Fly one trial in this worker: (trial key, TrialResult dict with its planner_fingerprint, None), or an "error"
    row and its message if the trial raised (the batch goes on). ``data``: the rollout's .npz bytes (cluster
    workers), else task.rollout."""
    limit_threads()
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
        return task.key, res.to_dict(), None
    except Exception as exc:  # any failure of a trial is recorded as an "error" row, never stops the batch
        msg = _error_message(exc)
        return task.key, error_row(task, msg), msg


def run_trial_group_task(task: TrialGroupTask, data: bytes | None = None) -> list[tuple[str, dict, str | None]]:
    """Fly a group of trials of one map as one trial batch in this worker: per trial, in order, what run_trial_task
    returns for it (its row, or an "error" row and message if that trial raised). Each row is also put on the
    worker's row queue (worker_init) the moment its trial ends, so the coordinator can commit it before the whole
    group is done. If the shared part of the batch's loop fails (world, ray batch), the trials not yet ended are
    flown one by one with run_trial_task instead."""
    limit_threads()
    from pbdyn.sim.trial import fly_trials

    singles = [TrialTask(k, s, task.rollout) for k, s in zip(task.keys, task.specs)]
    queue = _CACHE.get("queue")
    out: list = [None] * len(singles)

    def deliver(i: int, item: tuple) -> None:
        out[i] = item
        if queue is not None:
            queue.put(item)

    def ended(i: int, res) -> None:
        t = singles[i]
        if isinstance(res, BaseException):
            msg = _error_message(res)
            deliver(i, (t.key, error_row(t, msg), msg))
        else:
            deliver(i, (t.key, res.to_dict(), None))

    try:
        ro = _rollout(task.rollout, data)
        world = _world(singles[0], task.specs[0], ro)
        fly_trials(task.specs, ro, world=world, on_result=ended)
    except Exception:
        _CACHE["world"] = (None, None)
        for i, t in enumerate(singles):
            if out[i] is None:
                deliver(i, run_trial_task(t, data))
    if any(err is not None for _, _, err in out):
        _CACHE["world"] = (None, None)     # a failed trial may leave the world in any state: rebuild it
    if _CACHE.pop("settle", False):
        settle_heap()
    return out


def settle_heap() -> None:
    """Collect the cyclic garbage, then freeze every object still alive (gc.freeze): the long-lived heap of a worker
    (modules, compiled planners, the world, rollouts) is no longer scanned by the collector's full passes, which
    otherwise cost a few % of a batch's CPU time and make the slowest steps (tools/bench/bench_throughput.py).
    Called once by each local pool worker after its first trial group (worker_init), when its imports, compiled
    code and first world are in place; never on Dask workers (processes pbdyn does not own)."""
    import gc

    gc.collect()
    gc.freeze()


def _error_message(exc: BaseException) -> str:
    """An error row's message: the exception in one line and where it was raised (a plug-in's error already names
    the user's file and line)."""
    msg = one_line(exc)
    if getattr(exc, "location", None):
        return msg
    tb = traceback.extract_tb(exc.__traceback__)
    if tb:
        msg += f" (at {os.path.basename(tb[-1].filename)}:{tb[-1].lineno})"
    return msg


def run_map_task(task: MapTask, data: bytes | None = None) -> dict:
    """Compute one map's metrics in this worker: a maps-table row (metrics, their compute times, the map's mean
    obstacle speed and radius)."""
    limit_threads()
    from pbdyn.metrics.cached import metrics_code, resolve_backend, run_metric

    ro = _rollout(task.rollout, data)
    backend = resolve_backend(task.scenario, task.backend)
    metrics, times = {}, {}
    for name in task.metrics:
        res = run_metric(task.scenario, ro, name, backend)
        metrics[name] = res.value
        times[name] = res.wall_time_s
    speeds = np.linalg.norm(ro.velocities[0], axis=-1) if ro.n_obstacles else np.zeros(0)
    m = task.map_spec
    return {"map_id": m.map_id, "map_index": m.index, "map_key": m.key, "setup_json": m.setup, "seed": m.seed,
            "rollout_key": task.rollout.key, "dataset": task.scenario.name,
            "mean_obstacle_speed": float(speeds.mean()) if speeds.size else 0.0,
            "mean_obstacle_radius": float(ro.radii.mean()) if ro.n_obstacles else 0.0,
            "metrics_json": metrics, "metric_times_json": times, "backend": backend,
            "metrics_code": metrics_code(task.metrics, backend)}


PARENT_POLL_S = 0.5
"""How often a pool worker checks that the coordinator that started it is still alive."""


def watch_parent(interval: float = PARENT_POLL_S) -> None:
    """Exit this worker process (status 1, at once) when the process that started it is gone: a coordinator killed
    by SIGKILL cannot stop its workers, which would otherwise keep flying trials nobody stores. A daemon thread
    polls the parent's pid every ``interval`` s."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(interval)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="pbdyn-parent-watch", daemon=True).start()


def worker_init(queue=None) -> None:
    """Process-pool worker start: ignore SIGINT (a Ctrl-C reaches the whole process group; the coordinator stops
    the workers itself), limit BLAS/OpenMP threads, exit when the coordinator is gone (watch_parent), and keep
    ``queue`` (a multiprocessing queue of the coordinator) for the rows of lockstep groups, sent as each trial ends;
    after its first trial group the worker settles its heap (settle_heap)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads()
    watch_parent()
    _CACHE["settle"] = True            # settle_heap after the first trial group
    if queue is not None:
        queue.cancel_join_thread()   # rows also travel with each task's result: never hang at exit on a full pipe
    _CACHE["queue"] = queue
