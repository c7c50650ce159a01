"""`pbdyn bench --failures K`: replays of up to K failed tasks per failure mode, in ``OUT/failures/``.

Failure modes are pbdyn.outcome.FAILURES (every outcome of a flown trial but success; an "error" row -- the planner
raised -- has no flight to draw and is listed on the card instead). The tasks are chosen from the task rows
deterministically (choose): per mode, the tasks of that outcome taken level by level, easiest level first, one per
level per round (the first in task order, then the second, ...), so K replays spread over the levels the mode occurs
in. Each chosen task is flown again, alone, with a trace (pbdyn.sim.observers.TraceObserver through
pbdyn.sim.trial.run_trial): a trial is deterministic, so the re-flight is the trial of the row, which is checked
(its deterministic fields against the row's; a difference is a warning and the card entry's ``reflown``) -- then
drawn by pbdyn's replay writer (pbdyn.analysis.replay.write_replay, real time) as ``<mode>-<i>.gif`` (or .mp4).

``failures/replays.json`` records which task and code each file shows; a bench run again with --failures reuses the
files that still show its choice and removes those it no longer chooses (only files it wrote).
"""

from __future__ import annotations

import json
import tempfile
import warnings
from pathlib import Path

from pbdyn.benchmark.card import DETERMINISTIC_FIELDS, task_key, task_row
from pbdyn.benchmark.suite import Suite, flight_scenario
from pbdyn.config import PlannerEntry
from pbdyn.errors import ConfigError, PbdynWarning
from pbdyn.outcome import FAILURES

FOLDER = "failures"
INDEX = "replays.json"
INDEX_FORMAT = "pbdyn-failure-replays/1"
FORMATS = ("gif", "mp4")
"""Replay formats: an animated GIF (default) or an H.264 MP4 (needs imageio-ffmpeg)."""

MAX_FAILURE_REPLAYS = 1_000
"""Most replays per failure mode (--failures): each re-flies a task and draws every step, ~1-10 s. It lives here,
not in pbdyn.limits, which the trial core imports: a bench option must not change the code identity of every
flight (docs/design.md "Code identity")."""


def check_request(failures, failures_format) -> tuple[int | None, str | None]:
    """(K, format) checked: K an integer in [1, MAX_FAILURE_REPLAYS] or None (no replays); the format "gif"
    (default) or "mp4" (imageio-ffmpeg installed), given only with K. ConfigError naming ``failures`` or
    ``failures_format`` otherwise."""
    if failures is None:
        if failures_format is not None:
            raise ConfigError("failures_format", "applies only with failures (replays of K failed tasks per failure "
                              "mode)", failures_format)
        return None, None
    if isinstance(failures, bool) or not isinstance(failures, int) or not 1 <= failures <= MAX_FAILURE_REPLAYS:
        raise ConfigError("failures", f"must be an integer in [1, {MAX_FAILURE_REPLAYS:,}] (replays per failure "
                          "mode; pbdyn.limits)", failures)
    fmt = "gif" if failures_format is None else failures_format
    if fmt not in FORMATS:
        raise ConfigError("failures_format", f"must be {' or '.join(FORMATS)}", fmt)
    if fmt == "mp4":
        from pbdyn.analysis.replay import check_output

        check_output("replay.mp4", "failures_format")
    return failures, fmt


def choose(suite: Suite, rows: list[dict], k: int) -> list[tuple[str, int, dict]]:
    """(outcome, index 1..k, task row) of up to ``k`` tasks per failure mode, in FAILURES order (module doc)."""
    chosen = []
    for mode in FAILURES:
        by_level: dict[int, list[dict]] = {}
        for r in sorted(rows, key=task_key):
            if r["outcome"] == mode.value:
                by_level.setdefault(suite.map_level(r["part"], r["map_id"]), []).append(r)
        queues = [by_level[lv] for lv in sorted(by_level)]
        picked: list[dict] = []
        depth = 0
        while len(picked) < k and any(depth < len(q) for q in queues):
            picked.extend(q[depth] for q in queues if depth < len(q))
            depth += 1
        chosen.extend((mode.value, i + 1, r) for i, r in enumerate(picked[:k]))
    return chosen


def _identity(row: dict, fingerprint: str, entry: PlannerEntry) -> dict:
    """What a replay file shows: the task, its row's deterministic fields and the planner's code and parameters."""
    return {"task": [row["part"], row["map_id"], row["start"], row["goal"], row["mav_speed"]],
            "row": {f: row[f] for f in DETERMINISTIC_FIELDS}, "fingerprint": fingerprint,
            "trajectory_params": dict(entry.trajectory_params), "gaze_params": dict(entry.gaze_params)}


def _read_index(folder: Path) -> dict:
    path = folder / INDEX
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    files = doc.get("files") if isinstance(doc, dict) and doc.get("format") == INDEX_FORMAT else None
    return files if isinstance(files, dict) else {}


def _write_index(folder: Path, files: dict) -> None:
    from pbdyn.files import atomic_write_text

    atomic_write_text(folder / INDEX, json.dumps({"format": INDEX_FORMAT, "files": files}, indent=1, sort_keys=True)
                      + "\n")


class _Trials:
    """Each part's flight scenario and its trials by task key, built once per part."""

    def __init__(self, suite: Suite, entry: PlannerEntry):
        self.suite, self.entry = suite, entry
        self.parts: dict[str, tuple] = {}

    def find(self, row: dict):
        """(scenario, map spec, v_max, start, goal) of the row's trial."""
        from pbdyn.experiments.tasks import enumerate_trials

        name = row["part"]
        if name not in self.parts:
            sc = flight_scenario(self.suite, self.suite.part(name), [self.entry])
            by_key = {}
            for _, m, _, v, s, g in enumerate_trials(sc):
                t = {"part": name, "map_id": self.suite.spec_map_id(m), "start": [float(x) for x in s],
                     "goal": [float(x) for x in g], "mav_speed": float(v)}
                by_key[task_key(t)] = (m, v, s, g)
            self.parts[name] = (sc, by_key)
        sc, by_key = self.parts[name]
        m, v, s, g = by_key[task_key(row)]
        return sc, m, v, s, g


def reflight(trials: _Trials, row: dict, trace_path: Path) -> dict:
    """Fly the row's task again, alone, writing its trace to ``trace_path``; its task row."""
    from pbdyn.experiments.tasks import trial_spec
    from pbdyn.sim.trial import run_trial
    from pbdyn.world.rollout import get_rollout

    sc, m, v, s, g = trials.find(row)
    spec = trial_spec(sc, m, trials.entry, v, s, g)
    result = run_trial(spec, get_rollout(sc, m), trace_path=trace_path)
    return task_row(row["part"], {**result.to_dict(), "map_id": row["map_id"]})


def write_replays(suite: Suite, entry: PlannerEntry, fingerprint: str, rows: list[dict], out: Path, k: int,
                  fmt: str, *, fresh: bool = False, progress: bool = False, done: list | None = None) -> dict:
    """Write the replays of choose(suite, rows, k) into ``out``/failures/ and return the card's "failure_replays":
    {"requested": k, "files": [{"outcome", "part", "map_id", "start", "goal", "mav_speed", "file"}, ...]} ("file"
    relative to ``out``, in choose's order; "reflown": the re-flight's differing fields, only if it differed).
    Files that show the same task, row and code are kept (``fresh``: none is); ``done`` receives the name of each
    replay as its re-flight begins (the cost ledger counts the replays drawn or begun)."""
    import sys

    from pbdyn.analysis.replay import write_replay

    folder = Path(out) / FOLDER
    chosen = choose(suite, rows, k)
    old = _read_index(folder)
    keep = {}
    entries = []
    trials = _Trials(suite, entry)
    for n, (mode, i, row) in enumerate(chosen, 1):
        name = f"{mode}-{i}.{fmt}"
        ident = _identity(row, fingerprint, entry)
        item = {"outcome": mode, "part": row["part"], "map_id": row["map_id"], "start": row["start"],
                "goal": row["goal"], "mav_speed": row["mav_speed"], "file": f"{FOLDER}/{name}"}
        have = old.get(name)
        if not fresh and have is not None and have.get("identity") == ident and (folder / name).is_file():
            if have.get("reflown"):
                item["reflown"] = have["reflown"]
            keep[name] = have
            entries.append(item)
            continue
        folder.mkdir(parents=True, exist_ok=True)
        if done is not None:
            done.append(name)
        with tempfile.TemporaryDirectory(prefix="pbdyn-failure-") as tmp:
            trace = Path(tmp) / "trace.npz"
            try:
                again = reflight(trials, row, trace)
            except Exception as exc:   # the re-flight raised (a planner that fails only sometimes): no replay
                warnings.warn(PbdynWarning("failures", f"the re-flight of task {_shown(row)} raised "
                                           f"{type(exc).__name__}: {exc}; no replay of it"))
                continue
            write_replay(trace, folder / name)
        differs = {f: again[f] for f in DETERMINISTIC_FIELDS if again[f] != row[f]}
        if differs:
            item["reflown"] = differs
            warnings.warn(PbdynWarning("failures", f"the re-flight of task {_shown(row)} differs from its row in "
                                       f"{', '.join(sorted(differs))} (outcome {again['outcome']}, the row's "
                                       f"{row['outcome']}); its replay {name} shows the re-flight"))
        keep[name] = {"identity": ident, **({"reflown": differs} if differs else {})}
        _write_index(folder, {**{f: v for f, v in old.items() if f not in keep and (folder / f).exists()}, **keep})
        entries.append(item)
        if progress:
            sys.stderr.write(f"pbdyn bench: replay {n}/{len(chosen)} {FOLDER}/{name}\n")
            sys.stderr.flush()
    for name in old:                                  # files of an earlier choice that this one no longer makes
        if name not in keep and _is_replay_name(name):
            (folder / name).unlink(missing_ok=True)
    if keep != old and (old or keep):
        _write_index(folder, keep)
    return {"requested": k, "files": entries}


def _is_replay_name(name: str) -> bool:
    """Whether ``name`` is a file name write_replays gives (never a path: the index is read from disk)."""
    stem, _, ext = name.rpartition(".")
    mode, _, index = stem.rpartition("-")
    return ext in FORMATS and index.isdigit() and mode in {m.value for m in FAILURES} and "/" not in name


def _shown(row: dict) -> str:
    return (f"{row['part']}/{row['map_id']} {tuple(row['start'])} -> {tuple(row['goal'])} at "
            f"{row['mav_speed']:g} m/s")
