"""The trial-row fixture: built-in planner pairs on the bundled quickstart (2D) and spheres_3d (3D) maps.

tests/data/trial_rows.json holds the rows these cases produced before the trial loop was split into a steppable
core (main at 145e667), regenerated when the default start rule became "first_clear" (issue 13; with
start_rule = "immediate" the old rows were reproduced bit-identically); test_trial_fixture.py re-flies them and requires bit-identical rows (all fields but wall
times; regenerated once more when rows gained the task metrics task_survivability_s and task_flux_per_s, every other field
bit-identical; and once more when rows gained path_length_m, every other field bit-identical). Regenerate only for an intended behaviour change: python -m tests.trial_fixture
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIXTURE = Path(__file__).resolve().parent / "data" / "trial_rows.json"

TRAJECTORY = ("local_primitives", "global_primitives", "mpc", "straight_line")
GAZE = ("lookahead", "fullrange", "lookgoal", "lookgoal_unexplored", "rotating", "finean", "owl")


def cases() -> list[tuple[str, int, str, str, tuple, tuple]]:
    """(scenario file, map index, trajectory, gaze, start, goal) of every fixture trial."""
    from pbdyn.config import load_scenario

    out = []
    for name, maps in (("quickstart.toml", (0, 4, 8)), ("spheres_3d.toml", (1, 3))):
        sc = load_scenario(ROOT / "scenarios" / name)
        cands = sc.task.candidates
        pairs = sc.task.pairs()
        n = 0
        for m in maps:
            for traj in TRAJECTORY:
                for _ in range(3 if sc.world.dims == 2 else 2):
                    gaze = GAZE[n % len(GAZE)]
                    i, g = pairs[(7 * n + 3) % len(pairs)]
                    out.append((name, m, traj, gaze, cands[i], cands[g]))
                    n += 1
    return out


def fly_cases(every: int = 1) -> list[dict]:
    """Fly every ``every``-th case; each row is TrialResult.without_wall_times() plus the case."""
    from pbdyn.config import load_scenario
    from pbdyn.sim.trial import make_trial_spec, run_trial
    from pbdyn.world.maps import get_map, legacy_map_id
    from pbdyn.world.rollout import get_rollout

    rows = []
    scenarios: dict = {}
    for name, m, traj, gaze, start, goal in cases()[::every]:
        sc = scenarios.setdefault(name, load_scenario(ROOT / "scenarios" / name))
        ms = get_map(sc, m)
        spec = make_trial_spec(sc, ms, planner=traj, gaze=gaze, start=tuple(start), goal=tuple(goal))
        res = run_trial(spec, get_rollout(sc, ms))
        row = res.without_wall_times()
        row.pop("planner_fingerprint", None)   # provenance of the code, not behaviour: not part of the fixture
        row["map_id"] = legacy_map_id(row["map_key"])   # recorded under the id rule before (setup-1); same key
        rows.append({"case": [name, m, traj, gaze, list(start), list(goal)], "row": row})
    return rows


if __name__ == "__main__":
    rows = fly_cases()
    FIXTURE.write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")
    sys.stderr.write(f"wrote {len(rows)} rows to {FIXTURE}\n")
