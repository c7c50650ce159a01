"""The start rule's effect (issue 13, item 3): the same trials under start_rule = "immediate" and "first_clear".

    .venv/bin/python tools/bench/start_rule_effect.py [--maps 1] [--vmax 4] [--workers 2] [--out results/start-rule]

Flies the controlled dataset (scenarios/datasets/controlled_2d.toml: 27 setups x ``--maps`` maps, 72 start/goal
pairs, MAV speed ``--vmax``) with FullRange + local primitives and LookAhead + local primitives (physical profile)
once per rule, each into its own store (resumable), and prints per rule and pair: trials, success rate, collision
rate, early collisions (a collision within the first ``--early`` s of flight), the share of trials whose start was
delayed and the median delay. Every trial is the same map, pair and speed under both rules.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.experiments.runner import BatchOptions, run_batch  # noqa: E402
from pbdyn.experiments.store import ResultsStore  # noqa: E402
from pbdyn.outcome import Outcome  # noqa: E402

PAIRS = ({"trajectory": "local_primitives", "gaze": "fullrange"},
         {"trajectory": "local_primitives", "gaze": "lookahead"})
RULES = ("immediate", "first_clear")


def scenario(rule: str, maps: int, vmax: float):
    """The controlled dataset reduced to ``maps`` maps per setup, one MAV speed and PAIRS, under ``rule``."""
    doc = tomllib.loads((ROOT / "scenarios" / "datasets" / "controlled_2d.toml").read_text())
    doc["name"] = f"start_rule_{rule}"
    doc["obstacles"]["maps_per_setup"] = maps
    doc["drone"]["v_max"] = [vmax]
    doc["planners"] = list(PAIRS)
    doc["task"] = {"start_rule": rule}
    return parse_scenario(doc, f"{doc['name']}.toml")


def summarise(rows: list[dict], early: float) -> dict[str, dict]:
    """Per planner label: n, success, collision, early collision rates, delayed share, median delay (s)."""
    out: dict[str, dict] = {}
    for label in sorted({r["planner_label"] for r in rows}):
        sel = [r for r in rows if r["planner_label"] == label and r["outcome"] not in (None, "error")]
        n = len(sel)
        coll = [r for r in sel if r["outcome"] in (Outcome.DYNAMIC_COLLISION.value, Outcome.STATIC_COLLISION.value)]
        delays = sorted(r.get("start_delay_s") or 0.0 for r in sel)
        delayed = [d for d in delays if d > 0]
        out[label] = {"n": n, "success": sum(r["outcome"] == Outcome.SUCCESS.value for r in sel) / n,
                      "collision": len(coll) / n,
                      "early_collisions": sum(r["flight_time_s"] <= early + 1e-9 for r in coll),
                      "delayed": len(delayed) / n,
                      "median_delay_s": delayed[len(delayed) // 2] if delayed else 0.0}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", type=int, default=1)
    ap.add_argument("--vmax", type=float, default=4.0)
    ap.add_argument("--workers", type=int)
    ap.add_argument("--early", type=float, default=1.0, help="s: a collision this early counts as early")
    ap.add_argument("--out", default=str(ROOT / "results" / "start-rule"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    results = {}
    for rule in RULES:
        sc = scenario(rule, args.maps, args.vmax)
        store = out / f"{sc.name}.sqlite"
        s = run_batch(sc, store, BatchOptions(workers=args.workers, metrics=False),
                      command="tools/bench/start_rule_effect.py")
        sys.stderr.write(f"start_rule_effect: {rule}: {s.total} trials in {s.wall_time_s:.0f} s\n")
        st = ResultsStore.open(store)
        try:
            results[rule] = summarise(st.results(), args.early)
        finally:
            st.close()
    lines = [f"start rule effect: controlled_2d, 27 setups x {args.maps} map(s), 72 pairs, v_max {args.vmax:g} m/s",
             "| rule | pair | trials | success | collisions | collisions within "
             f"{args.early:g} s | delayed starts | median delay [s] |", "|---|---|---|---|---|---|---|---|"]
    for rule, per in results.items():
        for label, s in per.items():
            lines.append(f"| {rule} | {label} | {s['n']} | {s['success']:.3f} | {s['collision']:.3f} | "
                         f"{s['early_collisions']} | {s['delayed']:.3f} | {s['median_delay_s']:.1f} |")
    text = "\n".join(lines) + "\n"
    (out / "start_rule.md").write_text(text)
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
