"""Compare a pbdyn thesis_program store with the thesis program's own recorded trials, trial by trial.

    .venv/bin/python tools/program_records.py RECORDS_DIR STORE [STORE ...] [--json OUT]

RECORDS_DIR holds the program's result files (CSV, one row per trial, columns Method, Planner, Motion Profile, Map
ID, Agent size, Number of agents, Agent speed, Drone speed, Initial position, Target position, Success, Static
Collision, Dynamic Collision, Freezing, Dead Lock; pixels, 10 px per m, in its frame 1 m outside pbdyn's). The
program's repository deleted them in its commit 3a6e838 ("detele experiment results"); its parent still has them,
e.g. ``git -C gym-Drone2D-ActivePerception archive 3a6e838^ experiment/validation | tar -x``. Trials flown on the
program's own maps (scenarios/thesis/controlled_2d.toml, obstacles.layout = "program") are the program's trials:
same map id, setup, start, goal and MAV speed. Per combo and MAV speed the tool prints how many of the store's trials
the records hold, the share that ended alike, both pooled rates on those trials and their paired difference with a
95% interval (mean and 1.96 sd / sqrt(n) of the per-trial differences). Rows of other motion profiles, of radii
outside the thesis' 0.5 / 1.0 / 1.5 m and the program's repeated runs of a trial (the first one read, in file-name
order, is kept) are left out.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pbdyn.errors import ConfigError  # noqa: E402
from pbdyn.experiments.store import ResultsStore  # noqa: E402
from pbdyn.outcome import Outcome  # noqa: E402
from pbdyn.world.maps import PROGRAM_PX_PER_M, PROGRAM_WALL_M  # noqa: E402

RECORD_OUTCOMES = (("Success", Outcome.SUCCESS.value), ("Dynamic Collision", Outcome.DYNAMIC_COLLISION.value),
                   ("Static Collision", Outcome.STATIC_COLLISION.value), ("Dead Lock", Outcome.DEADLOCK.value))
"""The records' outcome flags -> pbdyn's outcome names, in the order they are read (a row with none: freezing)."""

SETUP_RADII_PX = (5, 10, 15)
"""The thesis' controlled radii (px); the program's other runs (random sizes, -1) are left out."""

KEY = ("combo", "map_id", "count", "radius_px", "speed_px", "mav_px", "start", "goal")
"""A trial's identity in the program's units: combo name, map id, setup, MAV speed, start and goal pixels."""


def _px(value: float) -> int:
    return int(round(float(value) * PROGRAM_PX_PER_M))


def _point_px(point) -> tuple[int, ...]:
    return tuple(_px(float(x) + PROGRAM_WALL_M) for x in point)


def read_records(folder: Path) -> pd.DataFrame:
    """The program's CVM trials in ``folder`` (*.csv, recursively) as a frame with KEY columns and "outcome"."""
    frames = []
    for path in sorted(Path(folder).rglob("*.csv")):
        try:
            head = pd.read_csv(path, nrows=1)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError):
            continue
        if not {"Method", "Planner", "Map ID", "Initial position"} <= set(head.columns):
            continue
        frames.append(pd.read_csv(path))
    if not frames:
        raise ConfigError("RECORDS_DIR", "holds no program result files (*.csv with Method, Planner, Map ID, ...)",
                          str(folder))
    rec = pd.concat(frames, ignore_index=True)
    rec = rec[(rec["Motion Profile"] == "CVM") & rec["Agent size"].isin(SETUP_RADII_PX)]
    outcome = np.full(len(rec), Outcome.FREEZING.value, dtype=object)
    for column, name in reversed(RECORD_OUTCOMES):
        outcome = np.where(rec[column].to_numpy() == 1, name, outcome)
    out = pd.DataFrame({
        "combo": rec["Method"].astype(str) + "+" + rec["Planner"].astype(str),
        "map_id": rec["Map ID"].astype(int), "count": rec["Number of agents"].astype(int),
        "radius_px": rec["Agent size"].astype(int), "speed_px": rec["Agent speed"].astype(int),
        "mav_px": rec["Drone speed"].astype(int),
        "start": [tuple(ast.literal_eval(s)) for s in rec["Initial position"]],
        "goal": [tuple(ast.literal_eval(s)) for s in rec["Target position"]], "outcome": outcome})
    return out.drop_duplicates(list(KEY), keep="first")


def read_store(path: Path) -> pd.DataFrame:
    """A thesis_program store flown on the program's own maps as a frame with KEY columns and "outcome"."""
    st = ResultsStore.open(path)
    try:
        scenario = json.loads(st.get_meta("scenario") or "{}")
        names, rows = st.trial_rows(["planner_label", "mav_speed", "map_key", "start", "goal", "outcome"])
    finally:
        st.close()
    obstacles = scenario.get("obstacles", {})
    if obstacles.get("layout") != "program":
        raise ConfigError("STORE", "was not flown on the program's own maps (obstacles.layout = \"program\")", str(path))
    root = int(obstacles.get("root_seed", 0))
    df = pd.DataFrame(rows, columns=names)
    df = df[df["outcome"] != Outcome.ERROR.value]
    keys = [json.loads(k) for k in df["map_key"]]
    return pd.DataFrame({
        "combo": df["planner_label"].astype(str).to_numpy(),
        "map_id": [root + k["replicate"] for k in keys], "count": [int(k["setup"]["count"]) for k in keys],
        "radius_px": [_px(k["setup"]["radius"]) for k in keys], "speed_px": [_px(k["setup"]["speed"]) for k in keys],
        "mav_px": [_px(v) for v in df["mav_speed"]],
        "start": [_point_px(json.loads(s)) for s in df["start"]],
        "goal": [_point_px(json.loads(g)) for g in df["goal"]], "outcome": df["outcome"].to_numpy()})


def compare(store: pd.DataFrame, records: pd.DataFrame) -> list[dict]:
    """Per (combo, MAV speed): matched trials, share ending alike, recorded and pbdyn success / dynamic-collision /
    deadlock rates on them and the paired differences (pbdyn - record) with 95% half-widths."""
    both = store.merge(records, on=list(KEY), suffixes=("_pbdyn", "_record"))
    out = []
    for (combo, mav), g in both.groupby(["combo", "mav_px"]):
        n_store = int(((store["combo"] == combo) & (store["mav_px"] == mav)).sum())
        row = {"combo": combo, "mav_speed": mav / PROGRAM_PX_PER_M, "trials": n_store, "matched": len(g),
               "alike": float(np.mean(g["outcome_pbdyn"] == g["outcome_record"]))}
        for name in (Outcome.SUCCESS.value, Outcome.DYNAMIC_COLLISION.value, Outcome.DEADLOCK.value):
            a = (g["outcome_pbdyn"] == name).to_numpy(float)
            b = (g["outcome_record"] == name).to_numpy(float)
            d = a - b
            half = 1.96 * d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
            row[name] = {"pbdyn": float(a.mean()), "record": float(b.mean()), "diff": float(d.mean()),
                         "half_width": float(half)}
        out.append(row)
    return out


def format_table(rows: list[dict]) -> str:
    """The comparison as a markdown table."""
    lines = ["| combo | MAV [m/s] | trials (in the records) | ended alike | success pbdyn / record | paired diff "
             "[95% CI] | dyn. coll. pbdyn / record | deadlock pbdyn / record |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s, c, d = (r[o] for o in (Outcome.SUCCESS.value, Outcome.DYNAMIC_COLLISION.value, Outcome.DEADLOCK.value))
        lines.append(f"| {r['combo']} | {r['mav_speed']:g} | {r['trials']} ({r['matched']}) | {r['alike']:.3f} | "
                     f"{s['pbdyn']:.3f} / {s['record']:.3f} | {s['diff']:+.3f} [{s['diff'] - s['half_width']:+.3f}, "
                     f"{s['diff'] + s['half_width']:+.3f}] | {c['pbdyn']:.3f} / {c['record']:.3f} | "
                     f"{d['pbdyn']:.3f} / {d['record']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", help="folder of the program's result CSV files")
    ap.add_argument("stores", nargs="+", help="pbdyn thesis_program stores flown on the program's maps")
    ap.add_argument("--json", help="also write the comparison as JSON here")
    args = ap.parse_args(argv)
    try:
        records = read_records(Path(args.records))
        store = pd.concat([read_store(Path(p)) for p in args.stores], ignore_index=True)
    except ConfigError as exc:
        print(f"program_records: error: {exc}", file=sys.stderr)
        return 2
    rows = compare(store, records)
    print(format_table(rows), end="")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
