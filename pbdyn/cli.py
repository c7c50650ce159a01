"""The ``pbdyn`` command (docs/design.md "Command line").

Bad input exits with status 2 and one line on stderr naming the problem; ``--json`` prints exactly one JSON
document on stdout; progress and logs go to stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
import tempfile
import traceback
import warnings
from pathlib import Path

from pbdyn import __version__, limits
from pbdyn.errors import ConfigError, PbdynError, PbdynWarning, check_writable_file
from pbdyn.experiments import limit_threads

EXIT_USAGE = 2
EXIT_PIPE = 141
"""Exit status when the reader of stdout went away before the output was written (a pager quit early, `| head -c0`):
128 + SIGPIPE, like a command that signal ends, and nothing on stderr."""


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error message and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        if message.startswith("argument "):     # "argument --vmax: ..." -> "--vmax: ...", as pbdyn's own errors
            message = message[len("argument "):]
        sys.stderr.write(f"pbdyn: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


def _parsed(text: str, convert, ok, what: str):
    """``convert(text)`` if it parses and ``ok`` holds for it; argparse's one-line error "must be <what>" else."""
    try:
        v = convert(text)
    except ValueError:
        v = None
    if v is None or not ok(v):
        raise argparse.ArgumentTypeError(f"must be {what} (got {text!r})")
    return v


def _nonneg_int(text: str) -> int:
    return _parsed(text, int, lambda v: 0 <= v <= limits.MAX_INDEX, f"an integer in [0, {limits.MAX_INDEX}]")


def _positive_int(text: str) -> int:
    return _parsed(text, int, lambda v: 1 <= v <= limits.MAX_INDEX, f"an integer in [1, {limits.MAX_INDEX}]")


def _count(text: str) -> int:
    """A count of at most pbdyn.limits.MAX_FLAG_COUNT (0 is refused by the command, naming its flag)."""
    return _parsed(text, int, lambda v: 0 <= v <= limits.MAX_FLAG_COUNT,
                   f"an integer in [0, {limits.MAX_FLAG_COUNT:,}] (pbdyn.limits)")


def _bootstrap(text: str) -> int:
    return _parsed(text, int, lambda v: 0 <= v <= limits.MAX_BOOTSTRAP,
                   f"an integer in [0, {limits.MAX_BOOTSTRAP:,}] (pbdyn.limits)")


def _obstacle_count(text: str) -> int:
    return _parsed(text, int, lambda v: 1 <= v <= limits.MAX_OBSTACLES,
                   f"an integer in [1, {limits.MAX_OBSTACLES:,}] (pbdyn.limits)")


def _positive_float(text: str) -> float:
    return _parsed(text, float, lambda v: math.isfinite(v) and 0 < v <= limits.MAX_MAGNITUDE,
                   f"a positive number <= {limits.MAX_MAGNITUDE:g} (pbdyn.limits)")


def _finite_float(text: str) -> float:
    return _parsed(text, float, lambda v: math.isfinite(v) and abs(v) <= limits.MAX_MAGNITUDE,
                   f"a finite number within +-{limits.MAX_MAGNITUDE:g} (pbdyn.limits)")


def _replays(text: str) -> int:
    from pbdyn.benchmark.failures import MAX_FAILURE_REPLAYS

    return _parsed(text, int, lambda v: 1 <= v <= MAX_FAILURE_REPLAYS,
                   f"an integer in [1, {MAX_FAILURE_REPLAYS:,}] (pbdyn.benchmark.failures)")


def _json_object(text: str) -> dict:
    return _parsed(text, json.loads, lambda v: isinstance(v, dict), "a JSON object, e.g. '{\"tracks\": 8}'")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = _Parser(prog="pbdyn", description="PyBullet testbed for MAV dynamic obstacle avoidance benchmarking.")
    parser.add_argument("--version", action="version", version=f"pbdyn {__version__}",
                        help="print pbdyn's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="fly one trial and print its TrialResult")
    run.add_argument("scenario", help="scenario TOML file")
    run.add_argument("--planner", help="trajectory planner (registry name, entry label, or package.module:Class)")
    run.add_argument("--gaze", help="gaze planner (registry name or package.module:Class)")
    run.add_argument("--map", type=_nonneg_int, default=0, help="map index in the scenario's enumeration (default 0)")
    run.add_argument("--start", help="start X,Y[,Z] in m (default: the first candidate)")
    run.add_argument("--goal", help="goal X,Y[,Z] in m (default: the last candidate)")
    run.add_argument("--vmax", type=_positive_float, help="MAV speed limit in m/s (default: the first drone.v_max)")
    run.add_argument("--gui", action="store_true", help="show the PyBullet GUI (real time, the arena framed; FOV, plan "
                     "and goal drawn)")
    run.add_argument("--follow", action="store_true", help="with --gui: the camera follows the MAV")
    run.add_argument("--gui-snapshot", help="write a .png of the final state, rendered headless (no display needed)")
    run.add_argument("--trace", help="save per-step MAV state, yaw, tracks and plans to this .npz file")
    run.add_argument("--replay", help="also write the trial's replay (.gif, .mp4 or .png; see pbdyn replay)")
    run.add_argument("--json", action="store_true", help="print the result as one JSON document")

    cal = sub.add_parser("calibrate", help="a map's measured difficulty on the anchored scale (the reference panel "
                         "flies its reference tasks)")
    cal.add_argument("scenario", help="scenario TOML file or imported world")
    cal.add_argument("--map", type=_nonneg_int, action="append", help="map index (repeatable; default: every map)")
    cal.add_argument("--store", help="results store of the flights (default: one in the cache; resumable)")
    cal.add_argument("--workers", type=_positive_int, help="local processes (default: CPU count)")
    cal.add_argument("--json", action="store_true", help="print the maps' difficulties as one JSON document")

    bn = sub.add_parser("bench", help="fly a planner on a frozen benchmark suite and write its score card "
                        "(card.json, card.md, card.html)")
    bn.add_argument("planner", nargs="?", help="trajectory planner: a registry name or 'package.module:Class'")
    bn.add_argument("--gaze", help="gaze planner (default: the thesis pairing; lookahead for a plug-in)")
    bn.add_argument("--params", type=_json_object, metavar="JSON", help="the trajectory planner's parameters as a "
                    "JSON object (its trajectory_params table; default: none)")
    bn.add_argument("--gaze-params", type=_json_object, metavar="JSON", help="the gaze planner's parameters as a "
                    "JSON object (its gaze_params table; default: none)")
    bn.add_argument("--suite", default=None, help="suite name or folder (default pbdyn-2d-v2; --list shows them)")
    bgrp = bn.add_mutually_exclusive_group()
    bgrp.add_argument("--workers", type=_positive_int, help="local worker processes (default: CPU count)")
    bgrp.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786")
    bn.add_argument("--out", help="folder of the flights and the card (resumable; with --compare: where to write "
                    "compare.md and compare.html)")
    bn.add_argument("--reproduce", action="store_true",
                    help="a built-in planner: compare the flights with its shipped reference results, field by field")
    bn.add_argument("--rerun-changed", action="store_true", help="re-fly the flights in --out whose planner code or "
                    "world changed since they were flown (else they stop the bench)")
    bn.add_argument("--failures", type=_replays, metavar="K", help="after flying, write replays of up to K failed "
                    "tasks per failure mode into OUT/failures/ (linked from the card)")
    bn.add_argument("--failures-format", choices=("gif", "mp4"), help="the replays' format: gif (default) or mp4 "
                    "(needs imageio-ffmpeg)")
    bn.add_argument("--compare", nargs="+", metavar="CARD", help="put score cards (card.json or bench folders) side "
                    "by side instead of flying")
    bn.add_argument("--list", action="store_true", help="list the bundled suites")
    bn.add_argument("--json", action="store_true", help="print the card (or the comparison) as JSON")

    gen = sub.add_parser("generate", help="maps of a chosen difficulty, written as a scenario file (thesis 5-2-2)")
    gen.add_argument("--metric", help="the metric to hit (e.g. survivability; with --target)")
    gen.add_argument("--target", type=_finite_float, help="the metric's target value (its unit)")
    gen.add_argument("--success", type=_finite_float, help="instead of --metric/--target: the reference panel's "
                     "success rate to hit (0-1): the predictor proposes, the panel's flights decide")
    gen.add_argument("--tolerance", type=_positive_float, required=True, help="keep maps within +- this of it")
    gen.add_argument("--count", type=_positive_int, default=20, help="maps to find (default 20)")
    gen.add_argument("--out", required=True, help="the scenario .toml to write (maps 0..count-1)")
    gen.add_argument("--family", default="uniform", help="generator family: a built-in structure (uniform, "
                     "clustered, crossing, walls, mixed, spread, rvo; default uniform)")
    gen.add_argument("--dims", type=int, choices=(2, 3), default=2, help="2 (default) or 3")
    gen.add_argument("--scenario", help="base scenario: its world, MAV, sensor, task and planners (default: "
                     "pbdyn's defaults, 50 m arena)")
    gen.add_argument("--obstacles", type=_obstacle_count, help="hold the obstacle count fixed")
    gen.add_argument("--radius", type=_positive_float, help="hold the obstacle radius (m) fixed")
    gen.add_argument("--speed", type=_positive_float, help="hold the obstacle speed (m/s) fixed")
    gen.add_argument("--seed", type=_nonneg_int, default=0, help="the file's root_seed and the search's (default 0)")
    gen.add_argument("--workers", type=_positive_int, help="processes measuring candidates (default: CPU count)")
    gen.add_argument("--json", action="store_true", help="print a JSON summary")

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
    met.add_argument("--plot", help="draw the survivability and VO samples as heat maps over the map (.png, .pdf, .svg)")
    met.add_argument("--json", action="store_true")

    bat = sub.add_parser("batch", help="run (or resume) every trial and map metric of a scenario into a results store")
    bat.add_argument("scenario", help="scenario TOML file")
    bat.add_argument("--out", required=True, help="results store (SQLite; keep it on a local disk)")
    grp = bat.add_mutually_exclusive_group()
    grp.add_argument("--workers", type=_nonneg_int, help="local worker processes (default: CPU count; at most 4 x the CPU count)")
    grp.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786 (tls:// only through the Python API, with a "
                     "Client)")
    bat.add_argument("--limit", type=_nonneg_int, help="run only the first N trials of the experiment")
    bat.add_argument("--extend", action="store_true",
                     help="accept a scenario that adds grid values, planners, MAV speeds or maps to the store's")
    bat.add_argument("--no-metrics", action="store_true", help="skip the maps' difficulty metrics")
    bat.add_argument("--rerun-changed", action="store_true",
                     help="re-fly the stored trials whose planner code or world (motion modules, URDFs, meshes) "
                          "changed since they were flown (else they stop the batch)")
    bat.add_argument("--retry-errors", action="store_true", help="re-fly the stored trials whose outcome is error")
    bat.add_argument("--shard", help="run only shard I of N (I/N, 1 <= I <= N; maps split into N contiguous blocks), "
                     "e.g. one SLURM array task; join the shards' stores with `pbdyn merge`")
    bat.add_argument("--lockstep", type=_count, default=None,
                     help="trials of one map flown together per task (default 72; 1: one trial per task)")
    bat.add_argument("--json", action="store_true", help="print a JSON summary")

    rep = sub.add_parser("replay", help="draw a trace (pbdyn run --trace) as an animation or a still")
    rep.add_argument("trace", help="trace .npz written by pbdyn run --trace")
    rep.add_argument("--out", required=True, help="output .gif, .mp4 (H.264) or .png (the final state)")
    rep.add_argument("--fps", type=_positive_float, help="frames per second: 0.1 to 50 for .gif, to 120 for .mp4 "
                     "(default: real time, within those)")
    rep.add_argument("--every", type=_count, default=1, help="one frame every N steps (default 1)")
    rep.add_argument("--json", action="store_true", help="print a JSON summary")

    mrg = sub.add_parser("merge", help="join results stores of one experiment (e.g. `pbdyn batch --shard` shards)")
    mrg.add_argument("results", nargs="+", help="results stores to join")
    mrg.add_argument("--out", required=True, help="the joined store (created, or an existing store of the experiment)")
    mrg.add_argument("--json", action="store_true", help="print a JSON summary")

    ev = sub.add_parser("evaluate", help="success rates and how well each metric ranks maps (table 4-5), figures")
    ev.add_argument("results", nargs="+", help="results store(s); the first is the reference (controlled) set")
    ev.add_argument("--plots", help="write the figures into this folder (.png at 200 dpi, .pdf, .svg)")
    ev.add_argument("--html", help="write one self-contained HTML report (tables, figures inlined, scenario)")
    ev.add_argument("--bootstrap", type=_bootstrap, default=1000,
                    help="bootstrap draws for the SRCC CIs and the paired success differences (1000)")
    ev.add_argument("--json", action="store_true", help="print the whole report as one JSON document")
    ev.add_argument("--pool", action="store_true",
                    help="evaluate every store's maps as one dataset (a heterogeneous set: no reference set)")

    exp = sub.add_parser("export", help="export a results store's trials")
    exp.add_argument("results", help="results store")
    fmt = exp.add_mutually_exclusive_group(required=True)
    fmt.add_argument("--csv", help="CSV file to write")
    fmt.add_argument("--parquet", help="Parquet file to write")

    demo = sub.add_parser("demo", help="fly every planner pair over a few maps and start/goal pairs; print a table")
    demo.add_argument("scenario")
    demo.add_argument("--maps", type=_count, default=4, help="number of maps (default 4)")
    demo.add_argument("--pairs", type=_count, default=3, help="start/goal pairs per map (default 3)")
    demo.add_argument("--json", action="store_true")
    return parser


FLAGS = {"planner": "--planner", "gaze": "--gaze", "map": "--map", "start": "--start", "goal": "--goal",
         "v_max": "--vmax", "trace": "--trace", "horizon": "--horizon", "metric": "--metric", "metrics": "--metric",
         "backend": "--backend", "workers": "--workers", "scheduler": "--scheduler", "limit": "--limit",
         "lockstep": "--lockstep", "replay": "--replay", "fps": "--fps", "every": "--every", "plot": "--plot",
         "gui_snapshot": "--gui-snapshot", "html": "--html", "out": "--out", "plots": "--plots", "csv": "--csv",
         "parquet": "--parquet", "gui": "--gui", "scenario": "SCENARIO", "results": "RESULTS",
         "target": "--target", "tolerance": "--tolerance", "count": "--count", "family": "--family", "dims": "--dims",
         "seed": "--seed", "fixed.count": "--obstacles", "fixed.radius": "--radius", "fixed.speed": "--speed",
         "store": "--store", "maps": "--map", "success": "--success", "suite": "--suite", "card": "CARD",
         "gaze_params": "--gaze-params", "reproduce": "--reproduce", "rerun_changed": "--rerun-changed",
         "failures": "--failures", "failures_format": "--failures-format", "extend": "--extend",
         "retry_errors": "--retry-errors", "shard": "--shard", "params": "--params"}
"""Library parameter names -> the flags (or positional arguments) that set them, for error messages."""


def _command_line(command: str) -> str:
    """The command as typed, for a store's or card's record; bytes that are not UTF-8 (an argument holding b"\\xff")
    are written as escapes, so that the record can be stored."""
    text = " ".join(["pbdyn", command, *sys.argv[2:]])
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def cmd_run(args: argparse.Namespace) -> int:
    from pbdyn import api

    if args.follow and not args.gui:
        raise ConfigError("--follow", "needs --gui (the camera follows the MAV in the GUI)", None, show_value=False)
    if args.replay is not None:
        from pbdyn.analysis.replay import check_output

        check_output(args.replay, "replay")
        check_writable_file("replay", args.replay)
    with contextlib.ExitStack() as stack:
        trace = args.trace
        if args.replay is not None and trace is None:
            trace = str(Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="pbdyn-replay-"))) / "trace.npz")
        result = api.run_trial(args.scenario, planner=args.planner, gaze=args.gaze, map=args.map, start=args.start,
                               goal=args.goal, v_max=args.vmax, trace=trace, gui=args.gui,
                               gui_snapshot=args.gui_snapshot, follow=args.follow)
        if args.replay is not None:
            summary = api.replay(trace, args.replay)
            sys.stderr.write(f"pbdyn run: replay of {summary.frames} frames in {summary.path}\n")
    if args.json:
        sys.stdout.write(json.dumps(result.to_dict(), sort_keys=True) + "\n")
    else:
        for key, value in result.to_dict().items():
            sys.stdout.write(f"{key:>22}: {value}\n")
    return 0


def cmd_rollout(args: argparse.Namespace) -> int:
    from pbdyn import api

    out = Path(args.out)
    if out.suffix != ".npz":
        raise ConfigError("--out", "must name an .npz file", args.out)
    if out.parent and not out.parent.exists():
        raise ConfigError("--out", "folder does not exist", str(out.parent))
    from pbdyn.errors import check_writable_file

    check_writable_file("--out", out)
    scenario = api.load_scenario(args.scenario)
    m = api.map_info(scenario, args.map)
    ro = api.rollout(scenario, args.map, horizon=args.horizon)
    ro.save(out)
    summary = {"out": str(out), "map_index": args.map, "map_id": m["map_id"], "setup": m["setup"],
               "replicate": m["replicate"], "seed": m["seed"], "steps": ro.n_steps,
               "obstacles": ro.n_obstacles, "horizon_s": ro.horizon}
    if args.json:
        sys.stdout.write(json.dumps(summary, sort_keys=True) + "\n")
    else:
        sys.stdout.write(f"wrote {out}: map {args.map} ({summary['map_id']}) {summary['setup']} replicate "
                         f"{summary['replicate']}, {ro.n_obstacles} obstacles x {ro.n_steps} steps\n")
    return 0


def cmd_metrics(args: argparse.Namespace) -> int:
    from pbdyn import api

    scenario = api.load_scenario(args.scenario)
    backend = api.metric_backend(scenario, args.backend)
    if args.plot is not None:
        fig = api.metric_heatmaps(scenario, args.map, args.plot, metrics=args.metric, dense=args.dense,
                                  backend=backend)
        drawn = ", ".join(dict.fromkeys(name for name, _, _ in fig.panels))
        sys.stderr.write(f"pbdyn metrics: heat maps of {drawn} in {fig.path}\n")
    values = api.compute_metrics(scenario, args.map, metrics=args.metric, dense=args.dense, backend=backend)
    ro_meta = api.map_info(scenario, args.map)
    doc = {"scenario": scenario.name, "map_index": args.map, "map_id": ro_meta["map_id"],
           "setup": ro_meta["setup"], "replicate": ro_meta["replicate"], "backend": backend, "metrics": values}
    if scenario.is_world:
        doc["bodies"] = [{"name": b.name, "motion": b.motion} for b in scenario.bodies]
        del doc["setup"], doc["replicate"]
    doc["predicted_reference_success"] = api.predict_success(scenario, args.map, backend=backend)
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
        return 0
    if scenario.is_world:
        moving = sum(b.moving for b in scenario.bodies)
        sys.stdout.write(f"world {scenario.name}: {len(scenario.bodies)} bodies ({moving} moving), backend {backend}\n")
    else:
        sys.stdout.write(f"map {args.map} ({doc['map_id']}) {doc['setup']} replicate {doc['replicate']}, "
                         f"backend {backend}\n")
    from pbdyn.metrics.catalog import INFO

    for name, v in values.items():
        err = f" +- {v['stderr']:.3f}" if v.get("stderr") is not None else ""
        info = INFO.get(name)
        unit = "" if info is None or info.unit == "1" else f" {info.unit}"
        sense = f" [{info.direction}]" if info is not None else ""
        sys.stdout.write(f"{name:>24}: {v['value']:.4f}{err}{unit}{sense}  (n={v['n_samples']}, excluded "
                         f"{v['n_excluded']}, {1000 * v['wall_time_s']:.1f} ms{', cached' if v['cached'] else ''})\n")
    from pbdyn.analysis.predict import format_prediction

    sys.stdout.write(format_prediction(doc["predicted_reference_success"]))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from pbdyn import api

    for flag, value in (("--maps", args.maps), ("--pairs", args.pairs)):
        if value == 0:
            raise ConfigError(flag, "must be >= 1", 0)
    rows = api.run_demo(args.scenario, n_maps=args.maps, n_pairs=args.pairs, json_out=args.json)
    if args.json:
        sys.stdout.write(json.dumps(rows, sort_keys=True) + "\n")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from pbdyn import api

    if args.workers == 0:
        raise ConfigError("--workers", "must be >= 1", 0)
    if args.limit == 0:
        raise ConfigError("--limit", "must be >= 1", 0)
    if args.lockstep == 0:
        raise ConfigError("--lockstep", "must be >= 1", 0)
    s = api.run_batch(args.scenario, args.out, workers=args.workers, scheduler=args.scheduler, limit=args.limit,
                      extend=args.extend, metrics=not args.no_metrics, rerun_changed=args.rerun_changed,
                      retry_errors=args.retry_errors, shard=args.shard, lockstep=args.lockstep,
                      command=_command_line("batch"))
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


def cmd_replay(args: argparse.Namespace) -> int:
    from pbdyn import api

    if args.every == 0:
        raise ConfigError("--every", "must be >= 1", 0)
    s = api.replay(args.trace, args.out, fps=args.fps, every=args.every)
    doc = {"out": s.path, "frames": s.frames, "width": s.width, "height": s.height}
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
    else:
        sys.stdout.write(f"{s.path}: {s.frames} frames of {s.width} x {s.height} px\n")
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    from pbdyn import api

    s = api.merge_results(args.out, args.results)
    doc = {"results": str(args.out), "trials": s.trials, "added": s.added, "duplicates": s.duplicates,
           "conflicts": s.conflicts, "maps": s.maps}
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
    else:
        conflict = f", {s.conflicts} of them with another outcome or planner code (first kept)" if s.conflicts else ""
        sys.stdout.write(f"{args.out}: {s.trials} trials ({s.added} added, {s.duplicates} duplicates skipped"
                         f"{conflict}), {s.maps} maps\n")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from pbdyn import api
    from pbdyn.benchmark import render
    from pbdyn.benchmark.run import DEFAULT_SUITE

    if args.list:
        from pbdyn.benchmark.suite import load_suite, suite_names

        for name in suite_names():
            s = load_suite(name)
            sys.stdout.write(f"{name}: {s.dims}D, {len(s.maps)} maps in {len(s.levels)} levels, {s.n_tasks()} tasks, "
                             f"hash {s.hash[:12]}\n")
        return 0
    if args.compare:
        if args.planner is not None:
            raise ConfigError("--compare", "takes card files only, not a PLANNER", args.planner)
        cards = api.compare_cards(args.compare, out=args.out)
        if args.json:
            sys.stdout.write(json.dumps({"cards": cards}, sort_keys=True) + "\n")
        else:
            sys.stdout.write(render.compare_text(cards))
        return 0
    if args.planner is None:
        raise ConfigError("PLANNER", "is required (or --compare CARD ... / --list)", None, show_value=False)
    if args.out is None:
        raise ConfigError("--out", "is required: the folder of the flights and the card", None, show_value=False)
    if args.failures_format is not None and args.failures is None:
        raise ConfigError("--failures-format", "needs --failures K (the replays it formats)", args.failures_format)
    card = api.bench(args.planner, gaze=args.gaze, params=args.params, gaze_params=args.gaze_params,
                     suite=args.suite or DEFAULT_SUITE, out=args.out, workers=args.workers, scheduler=args.scheduler,
                     progress=not args.json, reproduce=args.reproduce, rerun_changed=args.rerun_changed,
                     failures=args.failures, failures_format=args.failures_format, command=_command_line("bench"))
    rp = card.get("reproduction")
    if args.json:
        sys.stdout.write(json.dumps(card, sort_keys=True) + "\n")
    else:
        sys.stdout.write(card["summary"] + "\n" + f"card: {Path(args.out) / 'card.json'} (.md, .html)\n")
        fr = card.get("failure_replays")
        if fr is not None:
            sys.stdout.write(f"failure replays: {len(fr['files'])} in {Path(args.out) / 'failures'} (up to "
                             f"{fr['requested']} per failure mode)\n")
        if rp is not None:
            sys.stdout.write(f"reproduction of the shipped reference of {rp['reference']}: " +
                             (f"bit for bit on all {rp['tasks']} tasks\n" if rp["identical"] else
                              f"{rp['n_differences']} difference(s), e.g. " + "; ".join(rp["differences"][:3]) + "\n"))
    return 1 if rp is not None and not rp["identical"] else 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from pbdyn import api
    from pbdyn.analysis.scale import format_difficulties, load_anchors
    from pbdyn.planning.registry import pair_fingerprint

    res = api.calibrate(args.scenario, maps=args.map, store=args.store, workers=args.workers,
                        progress=not args.json)
    anchors = load_anchors()
    status = anchors.code_status(pair_fingerprint) if anchors is not None else "no anchors"
    if args.json:
        sys.stdout.write(json.dumps({"maps": [r.to_dict() for r in res], "anchors_code": status},
                                    sort_keys=True) + "\n")
    else:
        sys.stdout.write(format_difficulties(res))
        if status != "same":
            sys.stdout.write(f"note: the shipped anchors' code: {status} (docs/difficulty-scale.md)\n")
    return 0


def cmd_generate(args: argparse.Namespace) -> int:
    from pbdyn import api

    fixed = {k: v for k, v in (("count", args.obstacles), ("radius", args.radius), ("speed", args.speed))
             if v is not None}
    if args.success is not None:
        if args.metric is not None or args.target is not None:
            raise ConfigError("--success", "cannot be combined with --metric/--target (two targets)", args.success)
    elif args.metric is None or args.target is None:
        raise ConfigError("--metric" if args.metric is None else "--target",
                          "is required (or ask for a reference success with --success)", None, show_value=False)
    res = api.generate_maps(args.out, metric=args.metric, target=args.target, success=args.success,
                            tolerance=args.tolerance, count=args.count, family=args.family, dims=args.dims,
                            scenario=args.scenario, fixed=fixed, seed=args.seed, workers=args.workers,
                            progress=not args.json)
    doc = {"out": args.out, **res.summary()}
    if args.json:
        sys.stdout.write(json.dumps(doc, sort_keys=True) + "\n")
    elif args.success is not None:
        lo, hi = res.reachable
        got = doc["measured"]
        sys.stdout.write(f"{args.out}: {len(res.maps)} maps of family {args.family} ({args.dims}D) with reference "
                         f"success {args.success:g} +- {args.tolerance:g} as flown ({min(got):.2f} to {max(got):.2f});"
                         f" {res.flown} candidates flown of {res.candidates} predicted, predicted range {lo:.2f} to "
                         f"{hi:.2f}; {res.wall_time_s:.1f} s ({doc['seconds_per_map']:.1f} s per map)\n")
    else:
        lo, hi = res.reachable
        sys.stdout.write(f"{args.out}: {len(res.maps)} maps of family {args.family} ({args.dims}D) with {args.metric} "
                         f"{args.target:g} +- {args.tolerance:g} ({min(doc['values']):.3g} to "
                         f"{max(doc['values']):.3g}); {res.candidates} candidates measured, pilot range {lo:.3g} to "
                         f"{hi:.3g}; {res.wall_time_s:.1f} s ({doc['seconds_per_map']:.2f} s per map)\n")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from pbdyn import api

    fmt = "csv" if args.csv is not None else "parquet"
    target = args.csv if args.csv is not None else args.parquet
    n = api.export_results(args.results, target, format=fmt)
    sys.stderr.write(f"pbdyn export: {n} trials -> {target}\n")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from pbdyn import api

    report, table, figures = api.evaluate(args.results, plots=args.plots, n_boot=args.bootstrap, pool=args.pool,
                                          html=args.html)
    if args.json:
        sys.stdout.write(json.dumps(report, sort_keys=True, allow_nan=False) + "\n")
    else:
        sys.stdout.write(table.rstrip("\n") + "\n")
    if figures:
        sys.stderr.write(f"pbdyn evaluate: {len(figures)} figures in {args.plots}\n")
    if args.html:
        sys.stderr.write(f"pbdyn evaluate: report in {args.html}\n")
    return 0


COMMANDS = {"run": cmd_run, "rollout": cmd_rollout, "metrics": cmd_metrics, "demo": cmd_demo, "batch": cmd_batch,
            "export": cmd_export, "evaluate": cmd_evaluate, "merge": cmd_merge, "replay": cmd_replay,
            "generate": cmd_generate, "calibrate": cmd_calibrate, "bench": cmd_bench}


COMMAND_FLAGS = {"bench": {"planner": "PLANNER", "card": "--compare"}, "generate": {"scenario": "--scenario"},
                 "calibrate": {"out": "--store", "results": "--store"}}
"""Where a command names an option otherwise than FLAGS does (bench's planner is its positional PLANNER, generate's
base scenario its --scenario, calibrate's results store its --store)."""


def _flag(command: str, field: str) -> str | None:
    """The option the user typed for the library's ``field`` (``params.<key>``: ``--params.<key>``,
    ``gaze_params.<key>``: ``--gaze-params.<key>``), or None."""
    own = COMMAND_FLAGS.get(command, {})
    if field in own:
        return own[field]
    if field.startswith("params."):
        return "--" + field
    if field.startswith("gaze_params."):
        return "--gaze-params" + field[len("gaze_params"):]
    return FLAGS.get(field)


ELSEWHERE = {"rerun_changed": "batch", "retry_errors": "batch", "extend": "batch", "trace": "run", "params": "bench"}
"""The command whose flag a library message may advise where the command that raised it has no such flag."""
_NAMED = re.compile(r"`([a-z][a-z0-9_]*)`")


def _cli_words(command: str, text: str) -> str:
    """A library message in the command line's words: each option it names in backticks (`rerun_changed`,
    pbdyn.errors.ConfigError) becomes the flag that sets it (_flag), "pbdyn OTHER --flag" where only another
    command has it (ELSEWHERE); other backticked text is kept."""
    def word(m: re.Match) -> str:
        flag = _flag(command, m.group(1))
        home = ELSEWHERE.get(m.group(1))
        if flag is None or home in (None, command):
            return flag or m.group(0)
        sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
        return flag if flag in sub.choices[command]._option_string_actions else f"pbdyn {home} {flag}"
    return _NAMED.sub(word, text)


def _warning_line(show):
    """A warnings.showwarning that prints a PbdynWarning as one line ``pbdyn: warning: ...`` on stderr (naming the
    flag where the library names a parameter) and passes any other warning to ``show``."""
    def showwarning(message, category, filename, lineno, file=None, line=None):
        if isinstance(message, PbdynWarning):
            flag = FLAGS.get(message.field)
            sys.stderr.write(f"pbdyn: warning: {message.renamed(flag) if flag else message}\n")
        else:
            show(message, category, filename, lineno, file, line)
    return showwarning


def _stdout_gone() -> bool:
    """True if stdout is a pipe whose reader has closed it."""
    try:
        import select

        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(event & select.POLLERR for _, event in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _discard_stdout() -> None:
    """Point stdout at the null device, so that the interpreter's last flush of what is still buffered for the
    closed pipe prints no "Exception ignored" on stderr."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)
    except (AttributeError, OSError, ValueError):
        pass


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``pbdyn`` console script. ``PBDYN_DEBUG=1`` in the environment: an error also prints its
    full traceback (before its one line), an internal failure its Python traceback."""
    limit_threads()
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = bool(os.environ.get("PBDYN_DEBUG"))
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_line(warnings.showwarning)
            status = COMMANDS[args.command](args)
            sys.stdout.flush()      # here, not at interpreter exit: a reader that went away is handled below
            return status
    except ConfigError as exc:
        if debug:
            traceback.print_exc()
        flag = _flag(args.command, exc.field)
        sys.stderr.write(f"pbdyn: error: {_cli_words(args.command, str(exc.renamed(flag) if flag else exc))}\n")
        return EXIT_USAGE
    except PbdynError as exc:
        if debug:
            traceback.print_exc()
        sys.stderr.write(f"pbdyn: error: {_cli_words(args.command, str(exc))}\n")
        return EXIT_USAGE
    except KeyboardInterrupt as exc:   # pbdyn batch: BatchInterrupted (SIGTERM 143, SIGINT 130)
        sys.stderr.write(f"pbdyn: {str(exc) or 'interrupted'}\n")
        return getattr(exc, "exit_status", 130)
    except Exception as exc:  # an internal failure: one line, details only on request
        if isinstance(exc, BrokenPipeError) and _stdout_gone():
            _discard_stdout()
            return EXIT_PIPE
        if debug:
            raise
        sys.stderr.write(f"pbdyn: internal error: {type(exc).__name__}: {exc} (set PBDYN_DEBUG=1 for details)\n")
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
