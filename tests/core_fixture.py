"""The trial-core fixture: rows, traces and profiles recorded before the trial loops were made one (issue "One trial
core"), so that the single loop can be proved to fly every trial exactly as the two loops did.

Each group of cases is flown two ways: one by one (``run_trial``) and as one batch on the map's world (the batch
workers' path). tests/data/core_rows.json.gz holds what the code at the recording produced: per case, the row
(without wall times and the planner fingerprint), and per traced case the sha256 of every array of its trace file.
Groups:

- every built-in trajectory planner x every gaze planner, 2D (quickstart map 4) and 3D (spheres_3d map 1);
- the thesis_program profile (thesis/controlled_2d map 13: program braking, pixel rounding);
- a walled map (datasets/structured_2d), an imported 2D world (warehouse_2d) and an imported 3D world (hangar_0);
- batches of 72: local primitives + three gazes x 3 speeds x 8 start/goal pairs on quickstart map 0.

Regenerate only for an intended behaviour change: python -m tests.core_fixture
"""

from __future__ import annotations

import gzip
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = Path(__file__).resolve().parent / "data" / "core_rows.json.gz"

TRAJECTORY = ("local_primitives", "global_primitives", "mpc", "straight_line", "local_primitives_minjerk")
GAZE = ("lookahead", "fullrange", "lookgoal", "lookgoal_unexplored", "rotating", "finean", "owl")


def _pairs(sc, n: int, offset: int = 0) -> list[tuple[tuple, tuple]]:
    """n start/goal pairs spread over the scenario's candidate pairs."""
    pairs = sc.task.pairs()
    cands = sc.task.candidates
    step = max(1, len(pairs) // n)
    return [(tuple(cands[i]), tuple(cands[j])) for i, j in pairs[offset % step::step][:n]]


def groups() -> dict[str, tuple[str, int, list[tuple]]]:
    """name -> (scenario file under scenarios/, map index, [(trajectory, gaze, v_max or None, start, goal)])."""
    from pbdyn.config import load_scenario

    def load(name):
        return load_scenario(ROOT / "scenarios" / name)

    out = {}
    for name, scen, m in (("all_2d", "quickstart.toml", 4), ("all_3d", "spheres_3d.toml", 1)):
        sc = load(scen)
        pairs = _pairs(sc, 7)
        cases = [(traj, gaze, None, *pairs[(t + g) % len(pairs)])
                 for t, traj in enumerate(TRAJECTORY) for g, gaze in enumerate(GAZE)]
        out[name] = (scen, m, cases)
    sc = load("thesis/controlled_2d.toml")
    out["thesis_program"] = ("thesis/controlled_2d.toml", 13, [
        (e.trajectory, e.gaze, v, *pq) for e in sc.planners for v in (2.0, 6.0) for pq in _pairs(sc, 3)])
    sc = load("datasets/structured_2d.toml")
    from pbdyn.world.maps import get_map
    walled = next(i for i in range(60) if get_map(sc, i).setup.get("structure") == "walls")
    out["walls_2d"] = ("datasets/structured_2d.toml", walled, [
        (traj, "lookahead", 4.0, *pq) for traj in ("local_primitives", "global_primitives") for pq in _pairs(sc, 5)])
    for name, scen in (("warehouse_2d", "worlds/warehouse_2d.toml"), ("hangar_3d", "worlds/imported_3d/hangar_0.toml")):
        sc = load(scen)
        out[name] = (scen, 0, [(traj, gaze, None, *pq) for traj, gaze in
                               (("local_primitives", "lookahead"), ("straight_line", "owl"), ("mpc", "finean"))
                               for pq in _pairs(sc, 3)])
    sc = load("quickstart.toml")
    out["batch_72"] = ("quickstart.toml", 0, [
        ("local_primitives", gaze, v, *pq) for gaze in ("lookahead", "fullrange", "owl") for v in (2.0, 4.0, 6.0)
        for pq in _pairs(sc, 8, 1)])
    return out


TRACED = {("all_2d", 0), ("all_2d", 17), ("all_3d", 3), ("hangar_3d", 4), ("thesis_program", 2)}
"""(group, case index) whose trace file is recorded too."""


def row_of(result) -> dict:
    """A TrialResult's row without wall times and the planner fingerprint (provenance, not behaviour)."""
    from pbdyn.world.maps import legacy_map_id

    row = result.without_wall_times()
    row.pop("planner_fingerprint", None)
    row["map_id"] = legacy_map_id(row["map_key"])     # recorded under the map id rule before (setup-1); the key is
    return row                                         # the same, and the id rule is tested on its own


def trace_digest(path: Path) -> dict:
    """sha256 of every array of a trace .npz (key -> hex)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: hashlib.sha256(np.ascontiguousarray(z[k]).tobytes() + str(z[k].dtype).encode()
                                  + str(z[k].shape).encode()).hexdigest() for k in sorted(z.files)}


def specs_of(name: str):
    """(scenario, rollout, [TrialSpec]) of one group."""
    from pbdyn.config import load_scenario
    from pbdyn.sim.trial import make_trial_spec
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import get_rollout

    scen, m, cases = groups()[name]
    sc = load_scenario(ROOT / "scenarios" / scen)
    ms = get_map(sc, m)
    specs = []
    for traj, gaze, v, start, goal in cases:
        kw = {} if v is None else {"v_max": v}
        specs.append(make_trial_spec(sc, ms, planner=traj, gaze=gaze, start=start, goal=goal, **kw))
    return sc, get_rollout(sc, ms), specs


def fly_one_by_one(name: str, *, traces: bool = True) -> dict:
    """{"rows": [row per case], "traces": {case index: trace digest}} of a group flown trial by trial."""
    from pbdyn.sim.trial import run_trial

    _, ro, specs = specs_of(name)
    rows, digests = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, spec in enumerate(specs):
            trace = Path(tmp, f"{i}.npz") if traces and (name, i) in TRACED else None
            rows.append(row_of(run_trial(spec, ro, trace_path=trace)))
            if trace is not None:
                digests[str(i)] = trace_digest(trace)
    return {"rows": rows, "traces": digests}


def fly_batch(name: str) -> list[dict]:
    """The rows of a group flown as one batch on one world (the batch workers' path)."""
    from pbdyn.sim.trial import fly_trials, make_world

    _, ro, specs = specs_of(name)
    world = make_world(specs[0], ro)
    try:
        results = fly_trials(specs, ro, world=world)
    finally:
        world.close()
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return [row_of(r) for r in results]


def record() -> dict:
    return {name: {**fly_one_by_one(name), "batch": fly_batch(name)} for name in groups()}


if __name__ == "__main__":
    data = record()
    for name, got in data.items():
        if got["batch"] != got["rows"]:
            sys.exit(f"{name}: the batch's rows differ from the one-by-one rows; not recorded")
    FIXTURE.write_bytes(gzip.compress((json.dumps(data, sort_keys=True) + "\n").encode(), mtime=0))
    sys.stderr.write(f"wrote {sum(len(g['rows']) for g in data.values())} cases to {FIXTURE}\n")
