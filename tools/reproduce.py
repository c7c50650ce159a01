"""Reproduce the thesis' table 4-5 (and tables 4-6..4-8, 5-4, figures 4-5..4-12, 5-9, 5-10, 5-14).

    .venv/bin/python tools/reproduce.py --scale quick [--out results/reproduce-quick] [--workers N]
    .venv/bin/python tools/reproduce.py --scale full  [--out results/reproduce-full] [--scheduler tcp://HOST:8786]

``--dims 3`` uses the 3D counterparts (scenarios/datasets/*_3d.toml) the same way.
``full`` flies the thesis' datasets as shipped (scenarios/datasets/*_2d.toml: the controlled set, 540 maps x 18
pairs x 216 trials, and the three uncontrolled sets, 45 maps x 3 pairs x 216 trials). ``quick`` flies a reduced
grid written next to the results (scenarios/ in the output folder), derived from the same files:

- controlled: all 27 setups x QUICK_MAPS maps (>= 3, so the within-setup SRCC exists), the pairs QUICK_PAIRS, MAV
  speed QUICK_VMAX, start/goal candidates QUICK_CANDIDATES (20 ordered pairs): 8100 trials;
- each uncontrolled set: its 9 setups x QUICK_UNCONTROLLED_MAPS maps, its pairs that are in QUICK_PAIRS, the same
  speed and candidates: 1080 trials each.

Every run is a `pbdyn batch` (resumable: re-run the same command after an interruption) followed by `pbdyn
evaluate` of the controlled store with the uncontrolled stores; the folder receives table.txt, report.json and
figures/, and the table is printed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.experiments.evaluate import evaluate_stores  # noqa: E402
from pbdyn.experiments.runner import BatchOptions, run_batch  # noqa: E402

DATASETS = ROOT / "scenarios" / "datasets"
SETS = ("controlled", "uncontrolled_speed", "uncontrolled_size", "uncontrolled_rvo")

QUICK_MAPS = 5
QUICK_UNCONTROLLED_MAPS = 2
QUICK_PAIRS = (("fullrange", "local_primitives"), ("finean", "global_primitives"), ("lookahead", "mpc"))
"""The thesis' three pairs of the uncontrolled sets: one per trajectory planner (best, worst and a third)."""
QUICK_VMAX = (4.0,)
QUICK_CANDIDATES = ((4.0, 4.0), (4.0, 46.0), (46.0, 4.0), (46.0, 46.0), (25.0, 25.0))
"""The four corner candidates and the centre: 20 ordered start/goal pairs, every flight crossing the arena (3D: at
z = 10 m, the default candidates' height)."""


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def to_toml(doc: dict) -> str:
    """A small TOML writer for scenario documents (tables, arrays of tables, scalars, arrays, inline tables)."""
    lines = []
    for k, v in doc.items():
        if not isinstance(v, (dict, list)) or (isinstance(v, list) and not any(isinstance(x, dict) for x in v)):
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"\n[{k}]")
            lines += [f"{a} = {_toml_value(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines.append(f"\n[[{k}]]")
                lines += [f"{a} = {_toml_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


def quick_doc(name: str) -> dict:
    """The reduced scenario document of dataset ``name`` (see the module docstring)."""
    doc = tomllib.loads((DATASETS / f"{name}.toml").read_text())
    controlled = name.startswith("controlled")
    doc["name"] = f"{name}_quick"
    doc["obstacles"]["maps_per_setup"] = QUICK_MAPS if controlled else QUICK_UNCONTROLLED_MAPS
    doc["drone"]["v_max"] = list(QUICK_VMAX)
    z = [] if doc["world"].get("dims", 2) == 2 else [doc["world"]["size"][2] / 2.0]
    doc["task"] = {"candidates": [list(c) + z for c in QUICK_CANDIDATES]}
    if controlled:
        doc["planners"] = [{"trajectory": t, "gaze": g} for g, t in QUICK_PAIRS]
    else:
        keep = [p for p in doc["planners"] if (p["gaze"], p["trajectory"]) in QUICK_PAIRS]
        doc["planners"] = keep or [{"trajectory": QUICK_PAIRS[0][1], "gaze": QUICK_PAIRS[0][0]}]
    return doc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", choices=("quick", "full"), default="quick")
    ap.add_argument("--dims", type=int, choices=(2, 3), default=2, help="the 2D datasets (default) or their 3D counterparts")
    ap.add_argument("--out", help="output folder (default results/reproduce-SCALE)")
    ap.add_argument("--workers", type=int, help="local worker processes (default: CPU count)")
    ap.add_argument("--scheduler", help="Dask scheduler address")
    ap.add_argument("--bootstrap", type=int, default=1000)
    ap.add_argument("--extend", action="store_true", help="accept grown grids in existing stores (pbdyn batch --extend)")
    args = ap.parse_args(argv)
    out = Path(args.out or ROOT / "results" / f"reproduce-{args.scale}{'' if args.dims == 2 else '-3d'}")
    out.mkdir(parents=True, exist_ok=True)
    stores = []
    t0 = time.perf_counter()
    for name in (f"{s}_{args.dims}d" for s in SETS):
        if args.scale == "quick":
            doc = quick_doc(name)
            path = out / "scenarios" / f"{doc['name']}.toml"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(to_toml(doc))
        else:
            path = DATASETS / f"{name}.toml"
        scenario = parse_scenario(tomllib.loads(path.read_text()), str(path))
        store = out / f"{scenario.name}.sqlite"
        sys.stderr.write(f"reproduce: {scenario.name} -> {store}\n")
        s = run_batch(scenario, store, BatchOptions(workers=args.workers, scheduler=args.scheduler,
                                                         extend=args.extend),
                      command=f"tools/reproduce.py --scale {args.scale}")
        sys.stderr.write(f"reproduce: {scenario.name}: {s.total} trials ({s.ran} run now, {s.errors} errors) in "
                         f"{s.wall_time_s:.0f} s\n")
        stores.append(store)
    report, table, figures = evaluate_stores(stores, plots=out / "figures", n_boot=args.bootstrap)
    (out / "report.json").write_text(json.dumps(report, sort_keys=True, indent=1, allow_nan=False))
    header = (f"pbdyn reproduction of thesis table 4-5, scale {args.scale}: {', '.join(p.stem for p in stores)}; "
              f"{time.perf_counter() - t0:.0f} s wall for this invocation\n")
    (out / "table.txt").write_text(header + table)
    sys.stdout.write(header + table.rstrip("\n") + "\n")
    sys.stderr.write(f"reproduce: table.txt, report.json and {len(figures)} figures in {out}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
