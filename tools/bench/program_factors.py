"""How much each reproduced behaviour of the thesis' program moves the Jerk_Primitive combos' pooled rates.

    .venv/bin/python tools/bench/program_factors.py [--vmax 6] [--maps 1] [--variants all,-timing,...]
                                                    [--combos LookAhead+Jerk_Primitive,NoControl+Jerk_Primitive]
                                                    [--out results/program-factors] [--workers N]

Flies the controlled thesis dataset (scenarios/thesis/controlled_2d.toml: 27 setups x MAPS first replicates x all
72 start/goal pairs) under the thesis_program profile once as shipped ("all") and once per variant with one program
behaviour switched back to pbdyn's own choice, and prints, per variant, combo and MAV speed, the pooled success /
dynamic-collision / deadlock rates, the change against "all" on the same trials (paired over trials: its 95%
interval from the per-trial differences) and the program's reference rates (tools/reproduce.py REFERENCE_RATES).
Each variant is one resumable store under --out (re-running skips finished trials). Variants:

    all             the profile as shipped
    -timing         sensor.obstacles_at = "current" (sense the obstacles at t_k, not t_k+1)
    -march          sensor.march_rule = "ray" (points 0.9 m apart along each ray, a symmetric fan; not the
                    program's 0.9 m along the dominant axis)
    -drop           tracking.drop_rule = "arena" (tracks dropped only when their mean leaves the arena)
    -yaw            task.start_yaw_deg = "goal" (start facing the goal, not +y)
    -headings       obstacles.headings = "uniform" (random headings, not the program's evenly spaced ones)
    -samples        trajectory samples = "all" (check every sample, not the program's floor(T/dt))
    +goal_first     trajectory goal_first = true (try the goal itself first when nearer than 3 m)
    -static         trajectory static_check = "pbdyn" (the MAV ball + 0.5 m against occupied cells, radius + 0.1 m
                    from the walls; not the program's five probes, which keep 2 m from seen walls)
    -arena          the 50 m arena with walls at its border and candidates {4, 25, 46} (not the program's
                    48 m between its wall cells, candidates {3, 24, 45})
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from pbdyn.api import open_results, run_batch  # noqa: E402
from tools.bench.bench_common import machine  # noqa: E402
from pbdyn.outcome import Outcome  # noqa: E402
from tools.reproduce import REFERENCE_OUTCOMES, REFERENCE_RATES, REFERENCE_SPEEDS  # noqa: E402

SCENARIO = ROOT / "scenarios" / "thesis" / "controlled_2d.toml"
JERK_COMBOS = ("LookAhead+Jerk_Primitive", "NoControl+Jerk_Primitive")


def _traj_params(doc: dict, **params) -> None:
    for entry in doc["planners"]:
        entry.setdefault("trajectory_params", {}).update(params)


def _arena_50(doc: dict) -> None:
    doc["world"]["size"] = [50.0, 50.0]
    doc.setdefault("task", {}).pop("candidates", None)


VARIANTS = {
    "all": lambda doc: None,
    "-timing": lambda doc: doc.setdefault("sensor", {}).update(obstacles_at="current"),
    "-march": lambda doc: doc.setdefault("sensor", {}).update(march_rule="ray"),
    "-drop": lambda doc: doc.setdefault("tracking", {}).update(drop_rule="arena"),
    "-yaw": lambda doc: doc.setdefault("task", {}).update(start_yaw_deg="goal"),
    "-headings": lambda doc: doc["obstacles"].update(headings="uniform"),
    "-samples": lambda doc: _traj_params(doc, samples="all"),
    "+goal_first": lambda doc: _traj_params(doc, goal_first=True),
    "-static": lambda doc: _traj_params(doc, static_check="pbdyn"),
    "-arena": _arena_50,
}
"""Variant name -> an edit of the scenario document (see the module doc)."""


def variant_doc(base: dict, variant: str, combos, vmax, maps: int) -> dict:
    """The reduced scenario document of ``variant``: the given combos, MAV speeds and replicates per setup."""
    doc = copy.deepcopy(base)
    doc["name"] = f"program_factors{variant}"
    doc["planners"] = [e for e in doc["planners"] if e["name"] in combos]
    doc["drone"]["v_max"] = list(vmax)
    doc["obstacles"]["maps_per_setup"] = maps
    VARIANTS[variant](doc)
    return doc


def outcomes(store: Path):
    """Per (combo, v_max): a frame of (trial key, outcome), sorted by key."""
    with open_results(store) as r:
        df = r.trials()
    key = ["map_index", "start_x", "start_y", "goal_x", "goal_y"]
    return {k: g.sort_values(key)[key + ["outcome"]].reset_index(drop=True)
            for k, g in df.groupby(["planner_label", "mav_speed"])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vmax", default="6", help="MAV speeds, comma-separated (m/s)")
    ap.add_argument("--maps", type=int, default=1, help="replicates per setup (first ones)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--combos", default=",".join(JERK_COMBOS))
    ap.add_argument("--out", default=str(ROOT / "results" / "program-factors"))
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    vmax = [float(v) for v in args.vmax.split(",")]
    combos = args.combos.split(",")
    variants = args.variants.split(",")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        print(f"program_factors: error: unknown variants {unknown}; choose from {list(VARIANTS)}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = tomllib.loads(SCENARIO.read_text())
    print(f"# {machine()}")
    results = {}
    for variant in ["all"] + [v for v in variants if v != "all"]:
        store = out / f"{variant.replace('+', 'plus_').replace('-', 'minus_')}.sqlite"
        t0 = time.perf_counter()
        s = run_batch(variant_doc(base, variant, combos, vmax, args.maps), store, workers=args.workers,
                      metrics=False, progress=False)
        print(f"# {variant}: {s.total} trials ({s.ran} flown now) in {time.perf_counter() - t0:.0f} s",
              flush=True)
        results[variant] = outcomes(store)
    ref_of = {v: i for i, v in enumerate(REFERENCE_SPEEDS)}
    print("\n| variant | combo | MAV [m/s] | n | success / dyn. collision / deadlock | success - all [95% CI] | "
          "program |")
    print("|---|---|---|---|---|---|---|")
    for variant, per in results.items():
        for (combo, v), df in sorted(per.items()):
            rates = [float(np.mean(df.outcome == o.value)) for o in REFERENCE_OUTCOMES]
            base_df = results["all"].get((combo, v))
            diff = ""
            if variant != "all" and base_df is not None and len(base_df) == len(df):
                ok = Outcome.SUCCESS.value
                d = (df.outcome == ok).to_numpy(float) - (base_df.outcome == ok).to_numpy(float)
                half = 1.96 * d.std(ddof=1) / np.sqrt(d.size)
                diff = f"{d.mean():+.3f} [{d.mean() - half:+.3f}, {d.mean() + half:+.3f}]"
            ref = REFERENCE_RATES.get(combo, ())
            ref_s = " / ".join(f"{x:.3f}" for x in ref[ref_of[v]]) if v in ref_of and ref else "-"
            print(f"| {variant} | {combo} | {v:g} | {len(df)} | {' / '.join(f'{x:.3f}' for x in rates)} | {diff} | "
                  f"{ref_s} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
