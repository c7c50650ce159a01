"""The ``pbdyn`` command (DESIGN.md "Command line").

Bad input exits with status 2 and one line on stderr naming the problem; ``--json`` prints exactly one JSON
document on stdout; progress and logs go to stderr.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from pbdyn.errors import ConfigError, PbdynError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error message and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"pbdyn: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer (got {text!r})") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer (got {text!r})")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number (got {text!r})") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number (got {text!r})")
    return v


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = _Parser(prog="pbdyn", description="PyBullet testbed for MAV dynamic obstacle avoidance benchmarking.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="fly one trial and print its TrialResult")
    run.add_argument("scenario", help="scenario TOML file")
    run.add_argument("--planner", help="trajectory planner (registry name, entry label, or package.module:Class)")
    run.add_argument("--gaze", help="gaze planner (registry name or package.module:Class)")
    run.add_argument("--map", type=_nonneg_int, default=0, help="map index in the scenario's enumeration (default 0)")
    run.add_argument("--start", help="start X,Y[,Z] in m (default: the first candidate)")
    run.add_argument("--goal", help="goal X,Y[,Z] in m (default: the last candidate)")
    run.add_argument("--vmax", type=_positive_float, help="MAV speed limit in m/s (default: the first drone.v_max)")
    run.add_argument("--gui", action="store_true", help="show the PyBullet GUI (real time)")
    run.add_argument("--trace", help="save per-step MAV state, yaw, tracks and plans to this .npz file")
    run.add_argument("--json", action="store_true", help="print the result as one JSON document")

    ro = sub.add_parser("rollout", help="compute a map's rollout and save it as .npz")
    ro.add_argument("scenario")
    ro.add_argument("--map", type=_nonneg_int, default=0)
    ro.add_argument("--out", required=True, help="output .npz file")
    ro.add_argument("--horizon", type=_positive_float, help="seconds to cover (default: time limit + dt)")
    ro.add_argument("--json", action="store_true", help="print a JSON summary")

    met = sub.add_parser("metrics", help="difficulty metrics of a map (values cached per rollout)")
    met.add_argument("scenario", help="scenario TOML file")
    met.add_argument("--map", type=_nonneg_int, default=0)
    met.add_argument("--metric", action="extend", nargs="+", help="metric name (repeatable; default: every sparse metric)")
    met.add_argument("--dense", action="store_true", help="use the dense sample grids where a metric has one")
    met.add_argument("--backend", default="auto",
                     help="survivability backend: analytic, bullet or mesh; auto (default): bullet for imported "
                          "worlds with moving bodies (real shapes), else analytic")
    met.add_argument("--json", action="store_true")

    bat = sub.add_parser("batch", help="run (or resume) every trial and map metric of a scenario into a results store")
    bat.add_argument("scenario", help="scenario TOML file")
    bat.add_argument("--out", required=True, help="results store (SQLite; keep it on a local disk)")
    grp = bat.add_mutually_exclusive_group()
    grp.add_argument("--workers", type=_nonneg_int, help="local worker processes (default: CPU count)")
    grp.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786")
    bat.add_argument("--limit", type=_nonneg_int, help="run only the first N trials of the experiment")
    bat.add_argument("--extend", action="store_true",
                     help="accept a scenario that adds grid values, planners, MAV speeds or maps to the store's")
    bat.add_argument("--no-metrics", action="store_true", help="skip the maps' difficulty metrics")
    bat.add_argument("--rerun-changed", action="store_true",
                     help="re-fly the stored trials whose planner code changed since they were flown (else they stop "
                          "the batch)")
    bat.add_argument("--retry-errors", action="store_true", help="re-fly the stored trials whose outcome is error")
    bat.add_argument("--json", action="store_true", help="print a JSON summary")

    ev = sub.add_parser("evaluate", help="success rates and how well each metric ranks maps (table 4-5), figures")
    ev.add_argument("results", nargs="+", help="results store(s); the first is the reference (controlled) set")
    ev.add_argument("--plots", help="write the PNG figures into this folder")
    ev.add_argument("--bootstrap", type=_nonneg_int, default=1000, help="bootstrap draws for the SRCC CIs (1000)")
    ev.add_argument("--json", action="store_true", help="print the whole report as one JSON document")

    exp = sub.add_parser("export", help="export a results store's trials")
    exp.add_argument("results", help="results store")
    fmt = exp.add_mutually_exclusive_group(required=True)
    fmt.add_argument("--csv", help="CSV file to write")
    fmt.add_argument("--parquet", help="Parquet file to write")

    demo = sub.add_parser("demo", help="fly every planner pair over a few maps and start/goal pairs; print a table")
    demo.add_argument("scenario")
    demo.add_argument("--maps", type=_nonneg_int, default=4, help="number of maps (default 4)")
    demo.add_argument("--pairs", type=_nonneg_int, default=3, help="start/goal pairs per map (default 3)")
    demo.add_argument("--json", action="store_true")
    return parser


def _load(path: str):
    from pbdyn.config import load_scenario
    return load_scenario(path)


def cmd_run(args: argparse.Namespace) -> int:
    from pbdyn.sim.trial import make_trial_spec, run_trial
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import get_rollout

    scenario = _load(args.scenario)
    spec_map = get_map(scenario, args.map)
    spec = make_trial_spec(scenario, spec_map, planner=args.planner, gaze=args.gaze, v_max=args.vmax,
                           start=args.start, goal=args.goal)
    if args.trace is not None and not str(args.trace).endswith(".npz"):
        raise ConfigError("--trace", "must name an .npz file", args.trace)
    rollout = get_rollout(scenario, spec_map)
    result = run_trial(spec, rollout, gui=args.gui, trace_path=args.trace,
                       gui_sleep=scenario.world.dt if args.gui else 0.0)
    if args.json:
        sys.stdout.write(json.dumps(result.to_dict(), sort_keys=True) + "\n")
    else:
        for key, value in result.to_dict().items():
            sys.stdout.write(f"{key:>22}: {value}\n")
    return 0


def cmd_rollout(args: argparse.Namespace) -> int:
    from pbdyn.world.maps import get_map
    from pbdyn.world.rollout import build_rollout

    scenario = _load(args.scenario)
    out = Path(args.out)
    if out.suffix != ".npz":
        raise ConfigError("--out", "must name an .npz file", args.out)
    if out.parent and not out.parent.exists():
        raise ConfigError("--out", "folder does not exist", str(out.parent))
    spec_map = get_map(scenario, args.map)
    ro = build_rollout(scenario, spec_map, args.horizon)
    ro.save(out)
    summary = {"out": str(out), "map_index": spec_map.index, "map_id": spec_map.map_id, "setup": spec_map.setup,
               "replicate": spec_map.replicate, "seed": spec_map.seed, "steps": ro.n_steps,
               "obstacles": ro.n_obstacles, "horizon_s": ro.horizon}
    if args.json:
        sys.stdout.write(json.dumps(summary, sort_keys=True) + "\n")
    else:
        sys.stdout.write(f"wrote {out}: map {spec_map.index} ({spec_map.map_id}) {spec_map.setup} replicate "
                         f"{spec_map.replicate}, {ro.n_obstacles} obstacles x {ro.n_steps} steps\n")
    return 0


def cmd_metrics(args: argparse.Namespace) -> int:
    from pbdyn.metrics.cached import map_metrics, metric_names, resolve_backend
    from pbdyn.world.maps import get_map

    scenario = _load(args.scenario)
    names = metric_names(args.metric, args.dense)
    backend = resolve_backend(scenario, args.backend)
    spec_map = get_map(scenario, args.map)
    values = map_metrics(scenario, spec_map, names, backend=backend)
    doc = {"scenario": scenario.name, "map_index": spec_map.index, "map_id": spec_map.map_id,
           "setup": spec_map.setup, "replicate": spec_map.replicate, "backend": backend, "metrics": values}
    if scenario.is_world:
        doc["bodies"] = [{"name": b.name, "motion": b.motion} for b in scenario.bodies]
        del doc["setup"], doc["replicate"]
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
        return 0
    if scenario.is_world:
        moving = sum(b.moving for b in scenario.bodies)
        sys.stdout.write(f"world {scenario.name}: {len(scenario.bodies)} bodies ({moving} moving), backend {backend}\n")
    else:
        sys.stdout.write(f"map {spec_map.index} ({spec_map.map_id}) {spec_map.setup} replicate {spec_map.replicate}, "
                         f"backend {backend}\n")
    for name, v in values.items():
        err = f" +- {v['stderr']:.3f}" if v.get("stderr") is not None else ""
        sys.stdout.write(f"{name:>24}: {v['value']:.4f}{err}  (n={v['n_samples']}, excluded {v['n_excluded']}, "
                         f"{1000 * v['wall_time_s']:.1f} ms{', cached' if v['cached'] else ''})\n")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from pbdyn.sim.demo import run_demo

    scenario = _load(args.scenario)
    rows = run_demo(scenario, n_maps=args.maps, n_pairs=args.pairs, json_out=args.json)
    if args.json:
        sys.stdout.write(json.dumps(rows, sort_keys=True) + "\n")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from pbdyn.experiments.runner import BatchOptions, run_batch

    scenario = _load(args.scenario)
    if args.workers == 0:
        raise ConfigError("--workers", "must be >= 1", 0)
    if args.limit == 0:
        raise ConfigError("--limit", "must be >= 1", 0)
    opts = BatchOptions(workers=args.workers, scheduler=args.scheduler, limit=args.limit, extend=args.extend,
                        metrics=not args.no_metrics, rerun_changed=args.rerun_changed, retry_errors=args.retry_errors)
    s = run_batch(scenario, args.out, opts, command=" ".join(["pbdyn", "batch", *sys.argv[2:]]))
    doc = {"results": str(args.out), "trials": s.total, "already_stored": s.skipped, "ran": s.ran, "rerun": s.rerun,
           "errors": s.errors, "stored_errors": s.stored_errors, "maps_computed": s.maps_computed,
           "wall_time_s": s.wall_time_s}
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
    else:
        rerun = f" ({s.rerun} replacing stored rows)" if s.rerun else ""
        sys.stdout.write(f"{args.out}: {s.total} trials ({s.skipped} already stored, {s.ran} run now{rerun}, "
                         f"{s.errors} errors; {s.stored_errors} error rows in the store), {s.maps_computed} maps' "
                         f"metrics, {s.wall_time_s:.1f} s\n")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from pbdyn.experiments.export import export_csv, export_parquet
    from pbdyn.experiments.store import ResultsStore

    store = ResultsStore.open(args.results)
    try:
        n = export_csv(store, args.csv) if args.csv else export_parquet(store, args.parquet)
    finally:
        store.close()
    sys.stderr.write(f"pbdyn export: {n} trials -> {args.csv or args.parquet}\n")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from pbdyn.experiments.evaluate import evaluate_stores

    report, table, figures = evaluate_stores(args.results, plots=args.plots, n_boot=args.bootstrap)
    if args.json:
        sys.stdout.write(json.dumps(report, sort_keys=True, allow_nan=False) + "\n")
    else:
        sys.stdout.write(table.rstrip("\n") + "\n")
    if figures:
        sys.stderr.write(f"pbdyn evaluate: {len(figures)} figures in {args.plots}\n")
    return 0


COMMANDS = {"run": cmd_run, "rollout": cmd_rollout, "metrics": cmd_metrics, "demo": cmd_demo, "batch": cmd_batch,
            "export": cmd_export, "evaluate": cmd_evaluate}


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``pbdyn`` console script."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except PbdynError as exc:
        sys.stderr.write(f"pbdyn: error: {exc}\n")
        return EXIT_USAGE
    except KeyboardInterrupt as exc:   # pbdyn batch: BatchInterrupted (SIGTERM 143, SIGINT 130)
        sys.stderr.write(f"pbdyn: {str(exc) or 'interrupted'}\n")
        return getattr(exc, "exit_status", 130)
    except Exception as exc:  # an internal failure: one line, details only on request
        if os.environ.get("PBDYN_DEBUG"):
            raise
        sys.stderr.write(f"pbdyn: internal error: {type(exc).__name__}: {exc} (set PBDYN_DEBUG=1 for details)\n")
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
