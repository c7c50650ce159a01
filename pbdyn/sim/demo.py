"""``pbdyn demo``: fly every planner pair of a scenario over a few maps and start/goal pairs, print a table."""

from __future__ import annotations

import sys
import time
from collections import Counter

from pbdyn.config import Scenario
from pbdyn.outcome import OUTCOMES
from pbdyn.sim.trial import make_trial_spec, run_trial
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import get_rollout


def demo_pairs(scenario: Scenario, n_pairs: int) -> list[tuple[int, int]]:
    """n_pairs (start, goal) index pairs spread evenly over the scenario's ordered pairs (deterministic)."""
    pairs = scenario.task.pairs()
    if n_pairs >= len(pairs):
        return pairs
    step = len(pairs) / max(n_pairs, 1)
    return [pairs[int(i * step + step / 2)] for i in range(n_pairs)]


def run_demo(scenario: Scenario, *, n_maps: int = 4, n_pairs: int = 3, json_out: bool = False) -> list[dict]:
    """Run the demo trials; prints a table (stdout, or stderr with json_out) and returns the result rows."""
    out = sys.stderr if json_out else sys.stdout
    maps = enumerate_maps(scenario)[:n_maps]
    cands = scenario.task.candidates
    pairs = demo_pairs(scenario, n_pairs)
    rows = []
    header = f"{'planner pair':<32} {'map':>3} {'setup':<28} {'start':>11} {'goal':>11} {'vmax':>4} " \
             f"{'outcome':<18} {'time s':>6} {'clear m':>7} {'ms/step':>7}"
    out.write(header + "\n" + "-" * len(header) + "\n")
    t0 = time.perf_counter()
    for spec_map in maps:
        rollout = get_rollout(scenario, spec_map)
        setup = f"n={spec_map.setup['count']} r={spec_map.setup['radius']} v={spec_map.setup['speed']}"
        for entry in scenario.planners:
            for i, j in pairs:
                for vmax in scenario.drone.v_max:
                    spec = make_trial_spec(scenario, spec_map, planner=entry.label, v_max=vmax,
                                           start=cands[i], goal=cands[j])
                    res = run_trial(spec, rollout)
                    rows.append(res.to_dict())
                    s = ",".join(f"{x:g}" for x in cands[i])
                    g = ",".join(f"{x:g}" for x in cands[j])
                    out.write(f"{entry.label:<32} {spec_map.index:>3} {setup:<28} {s:>11} {g:>11} {vmax:>4g} "
                              f"{res.outcome:<18} {res.flight_time_s:>6.1f} {res.min_clearance_m:>7.2f} "
                              f"{1000 * res.wall_timings['wall_step_mean_s']:>7.2f}\n")
                    out.flush()
    counts = Counter((r["planner_label"], r["outcome"]) for r in rows)
    out.write(f"\n{len(rows)} trials in {time.perf_counter() - t0:.1f} s. Outcomes per planner pair:\n")
    for entry in scenario.planners:
        parts = [f"{o}={counts[(entry.label, o)]}" for o in OUTCOMES if counts[(entry.label, o)]]
        out.write(f"  {entry.label:<32} {' '.join(parts)}\n")
    return rows
