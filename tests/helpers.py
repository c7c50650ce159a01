"""Test helpers: hand-built rollouts for scenario-level tests."""

from __future__ import annotations

import numpy as np

from pbdyn.config import Scenario
from pbdyn.motion.cvm import cvm_fold
from pbdyn.world.maps import enumerate_maps, static_bodies
from pbdyn.world.rollout import Rollout, default_horizon


def handmade_rollout(scenario: Scenario, p0, v0, radii) -> Rollout:
    """A CVM rollout of the given obstacles (centres [N, d], velocities [N, d], radii [N]) in the scenario's arena."""
    dt = scenario.world.dt
    n_t = int(round(default_horizon(scenario) / dt)) + 1
    times = np.arange(n_t) * dt
    p0 = np.asarray(p0, float).reshape(-1, scenario.world.dims)
    v0 = np.asarray(v0, float).reshape(-1, scenario.world.dims)
    radii = np.asarray(radii, float).reshape(-1)
    pos, vel = cvm_fold(p0, v0, radii, np.asarray(scenario.world.size), times)
    return Rollout(times, pos, vel, radii, np.asarray(scenario.world.size, float), dt, static_bodies(scenario),
                   {"handmade": True})


def first_map(scenario: Scenario):
    """The scenario's map 0."""
    return enumerate_maps(scenario)[0]


PLANNERS = [{"trajectory": "local_primitives", "gaze": "lookahead"},
            {"trajectory": "straight_line", "gaze": "lookahead"},
            {"trajectory": "local_primitives", "gaze": "fullrange"}]


def open_scenario(dims: int = 2, **extra) -> Scenario:
    """An obstacle-free scenario (40 s, v_max 4 m/s, the three built-in planner pairs); ``extra`` replaces tables."""
    from pbdyn.config import parse_scenario

    doc = {"world": {"dims": dims, "time_limit": 40.0}, "obstacles": {"count": 0}, "drone": {"v_max": 4.0},
           "planners": PLANNERS}
    doc.update(extra)
    return parse_scenario(doc)


def fly(scenario: Scenario, rollout: Rollout, planner: str, start, goal, **kw):
    """Run one trial of ``planner`` (an entry label) from start to goal on map 0's spec with the given rollout."""
    from pbdyn.sim.trial import make_trial_spec, run_trial

    spec = make_trial_spec(scenario, first_map(scenario), planner=planner, start=start, goal=goal)
    return run_trial(spec, rollout, **kw)


def make_tracks(pos, vel, radius):
    """Tracks of M obstacles at centres pos [M, d] (m) with velocities vel [M, d] (m/s), one radius (m), zero
    covariance."""
    from pbdyn.planning.view import Tracks

    pos = np.atleast_2d(np.asarray(pos, float))
    m, d = pos.shape
    return Tracks(np.arange(m), pos, np.atleast_2d(np.asarray(vel, float)), np.zeros((m, 2 * d, 2 * d)),
                  np.full(m, float(radius)))


def failed_pairs(scenario: Scenario, rollout: Rollout, planner: str) -> list:
    """Every ordered start/goal pair of the scenario flown by ``planner`` (an entry label): the ones that did not
    succeed or had planning failures, as (start, goal, outcome, failures)."""
    cands = scenario.task.candidates
    bad = []
    for i, j in scenario.task.pairs():
        res = fly(scenario, rollout, planner, cands[i], cands[j])
        if res.outcome != "success" or res.planning_failures:
            bad.append((cands[i], cands[j], res.outcome, res.planning_failures))
    return bad


def assert_avoids(scenario: Scenario, rollout: Rollout, planner: str, start, goal) -> None:
    """straight_line collides with the rollout's obstacle between start and goal; ``planner`` (an entry label)
    succeeds with min_clearance >= 0 and has tracked the obstacle."""
    sl = fly(scenario, rollout, "lookahead+straight_line", start, goal)
    assert sl.outcome == "dynamic_collision", sl
    res = fly(scenario, rollout, planner, start, goal)
    assert res.outcome == "success", res
    assert res.min_clearance_m >= 0.0 and res.obstacles_tracked == 1


def child_pids(pid: int) -> list[int]:
    """The pids of ``pid``'s child processes (from /proc)."""
    from pathlib import Path

    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(d.name))
    return out


def process_running(pid: int) -> bool:
    """Whether process ``pid`` exists and is neither a zombie nor dead (from /proc)."""
    from pathlib import Path

    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def copy_checkout(dest, *, caches: bool = True):
    """A copy of the checkout (pbdyn/, urdf/, scenarios/, setup.cfg) at ``dest``, for tests that edit or break
    pbdyn's own files; ``caches``: with its __pycache__ folders (numba's compiled functions)."""
    import shutil
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    ignore = None if caches else shutil.ignore_patterns("__pycache__")
    shutil.copytree(root / "pbdyn", dest / "pbdyn", ignore=ignore)
    for name in ("urdf", "scenarios"):
        shutil.copytree(root / name, dest / name)
    shutil.copy2(root / "setup.cfg", dest / "setup.cfg")
    return dest
