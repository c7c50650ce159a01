"""`pbdyn bench`: fly a planner on a frozen suite and write its score card (docs/benchmark.md).

The suite's parts are flown by the batch runner (pbdyn.experiments.runner: lockstep, resumable, local processes or
a Dask scheduler) into ``OUT/flights/<part>.sqlite``; then the card (pbdyn.benchmark.card) is written as
``OUT/card.json``, ``OUT/card.md`` and ``OUT/card.html`` (pbdyn.benchmark.render), each atomically. ``OUT/bench.json``
records which planner (with its parameters) and suite the folder holds, so a folder never mixes two benches. One
progress line with one ETA covers every part (Flights). The runner's refusals of a folder's flight stores are put in
bench's terms (bench_error: the flags bench has, a folder rather than a file). ``OUT/cost.json`` sums what the
invocations cost (pbdyn.benchmark.cost, the card's "cost"); ``failures=K`` writes replays of failed tasks into
``OUT/failures/`` (pbdyn.benchmark.failures, the card's "failure_replays").

The suite's reference results (REFERENCE_FILE in the suite folder) hold every built-in trajectory planner flown with
its thesis gaze pairing (THESIS_GAZE); ``reproduce=True`` compares the planner's flights with its shipped reference
rows field by field (DETERMINISTIC_FIELDS: everything but wall times) and reports every difference.
"""

from __future__ import annotations

import contextlib
import gzip
import hashlib
import json
import math
import re
import signal
from collections.abc import Mapping
from pathlib import Path

from pbdyn.benchmark.card import DETERMINISTIC_FIELDS, TASK_FIELDS, make_card, task_key, task_row
from pbdyn.benchmark.suite import Suite, flight_scenario, load_suite, read_versioned_json
from pbdyn.config import PlannerEntry
from pbdyn.errors import ConfigError, check_writable_folder
from pbdyn.files import atomic_write_text

REFERENCE_FILE = "reference.json.gz"
REFERENCE_FORMAT = "pbdyn-reference/1"
THESIS_GAZE = {"local_primitives": "lookahead", "global_primitives": "fullrange", "mpc": "lookahead",
               "straight_line": "lookahead", "local_primitives_minjerk": "lookahead"}
"""The gaze each built-in trajectory planner flies with by default (the thesis' pairings: FullRange with the global
planner, LookAhead with the local ones)."""
DEFAULT_SUITE = "pbdyn-2d-v2"
MARKER = "bench.json"


def planner_entry(planner: str, gaze: str | None = None, params: Mapping | None = None,
                  gaze_params: Mapping | None = None) -> PlannerEntry:
    """The (trajectory, gaze) pair benched: ``gaze`` or the planner's THESIS_GAZE (LookAhead for a plug-in);
    ``params``, ``gaze_params``: the trajectory and the gaze planner's parameters (tables with string keys; default
    none)."""
    from pbdyn.planning.registry import pair_fingerprint, resolve_gaze_planner, resolve_trajectory_planner

    if not isinstance(planner, str) or not planner:
        raise ConfigError("planner", "must be a registry name or 'package.module:Class'", planner)
    if gaze is not None and (not isinstance(gaze, str) or not gaze):
        raise ConfigError("gaze", "must be a gaze planner name or 'package.module:Class'", gaze)
    for name, value, whose in (("params", params, "trajectory"), ("gaze_params", gaze_params, "gaze")):
        if value is not None and (not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value)):
            raise ConfigError(name, f"must be a table of the {whose} planner's parameters (string keys)", value)
    entry = PlannerEntry(planner, gaze or THESIS_GAZE.get(planner, "lookahead"), dict(params or {}),
                         dict(gaze_params or {}))
    resolve_trajectory_planner(entry.trajectory, "planner")   # each name's error names its own option
    resolve_gaze_planner(entry.gaze, "gaze")
    pair_fingerprint(entry.trajectory, entry.gaze)         # unknown names fail here, before anything is written
    return entry


def _check_entry(suite: Suite, entry: PlannerEntry) -> None:
    """Build the pair once on the suite's first part (names, imports, parameters), so that bad parameters fail
    before the bench folder is made; ConfigError naming ``params.<key>`` for a bad trajectory parameter,
    ``gaze_params.<key>`` for a bad gaze parameter."""
    from pbdyn.experiments.runner import check_planners

    try:
        check_planners(flight_scenario(suite, suite.parts[0], [entry]))
    except ConfigError as exc:
        for head, name in (("planners[0].trajectory_params", "params"), ("planners[0].gaze_params", "gaze_params")):
            if exc.field.startswith(head):
                raise exc.renamed(name + exc.field[len(head):]) from None
        raise


def parameter_files(params) -> dict[str, str]:
    """{value: sha256 of the file} for every string among ``params`` (nested tables and lists included) that names an
    existing file, e.g. a policy's weights: a planner's identity includes what its files hold, so a bench folder
    never mixes flights of two versions of one file."""
    found: dict[str, str] = {}

    def walk(value) -> None:
        if isinstance(value, Mapping):
            for v in value.values():
                walk(v)
        elif isinstance(value, (list, tuple)):
            for v in value:
                walk(v)
        elif isinstance(value, str) and value and Path(value).is_file():
            digest = hashlib.sha256()
            with open(value, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    digest.update(block)
            found[value] = digest.hexdigest()

    walk(params)
    return found


def parameter_record(entry: PlannerEntry) -> dict:
    """The entry's parameters as the bench folder's marker and the card record them: "trajectory_params" and
    "gaze_params" (each only if given) and "parameter_files" (parameter_files of both, only if a parameter names
    a file)."""
    rec = {}
    if entry.trajectory_params:
        rec["trajectory_params"] = dict(entry.trajectory_params)
    if entry.gaze_params:
        rec["gaze_params"] = dict(entry.gaze_params)
    files = parameter_files([entry.trajectory_params, entry.gaze_params])
    if files:
        rec["parameter_files"] = files
    return rec


def _check_marker(out: Path, suite: Suite, entry: PlannerEntry) -> None:
    marker = out / MARKER
    mine = {"suite": suite.name, "suite_hash": suite.hash, "trajectory": entry.trajectory, "gaze": entry.gaze,
            **parameter_record(entry)}
    if marker.is_file():
        try:
            have = json.loads(marker.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            have = None
        if have != mine:
            what = f"{have.get('gaze')}+{have.get('trajectory')} on {have.get('suite')}" if isinstance(have, dict) \
                else "something else"
            if isinstance(have, dict) and have.get("trajectory_params", {}) != mine.get("trajectory_params", {}):
                what += f" with other parameters ({json.dumps(have.get('trajectory_params', {}), sort_keys=True)})"
            elif isinstance(have, dict) and have.get("gaze_params", {}) != mine.get("gaze_params", {}):
                what += f" with other gaze parameters ({json.dumps(have.get('gaze_params', {}), sort_keys=True)})"
            elif isinstance(have, dict) and have.get("parameter_files", {}) != mine.get("parameter_files", {}):
                changed = sorted(k for k in set(have.get("parameter_files", {})) | set(mine.get("parameter_files", {}))
                                 if have.get("parameter_files", {}).get(k) != mine.get("parameter_files", {}).get(k))
                what += f" whose parameter file {changed[0]} held other content then"
            raise ConfigError("out", f"holds the bench of {what}; use another `out` folder", str(out))
        return
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError("out", "exists and is not an empty folder or a bench folder; use another `out` folder",
                          str(out))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(marker, json.dumps(mine, indent=1, sort_keys=True) + "\n")


class Flights:
    """The batches of a bench: one per suite part into out/flights/<part>.sqlite (pbdyn.experiments.runner), with
    one progress line and one ETA over every part ("pbdyn bench: done/total trials"; total: the tasks the parts'
    batches will fly, counted from their stores before any is flown). Every part's store is checked before the
    first is flown; a refusal is put in bench's terms (bench_error). ``flown``: the trials flown so far; ``rerun``:
    those of them that replaced stored rows (rerun_changed)."""

    def __init__(self, suite: Suite, entry: PlannerEntry, out: Path, *, workers=None, scheduler=None,
                 progress: bool = False, rerun_changed: bool = False, command: str = ""):
        from pbdyn.experiments.progress import Progress
        from pbdyn.experiments.runner import BatchOptions, pending_trials_of

        self.suite, self.out, self.command = suite, Path(out), command
        self.folder = self.out / "flights"
        self.jobs = [(part, flight_scenario(suite, part, [entry]), self.folder / f"{part.name}.sqlite")
                     for part in suite.parts]
        self.options = BatchOptions(workers=workers, scheduler=scheduler, metrics=False,
                                    rerun_changed=rerun_changed)
        pending = 0
        for part, scenario, store in self.jobs:
            with bench_terms(self.out, part.name):
                pending += pending_trials_of(scenario, store, self.options)
        self.progress = Progress(pending, progress, "pbdyn bench")
        self.rerun = 0

    @property
    def flown(self) -> int:
        return self.progress.done

    def run(self) -> None:
        """Fly every part (resuming what the stores hold). SIGTERM/SIGINT: BatchInterrupted in bench's words."""
        from dataclasses import replace

        from pbdyn.experiments.runner import run_batch
        from pbdyn.experiments.signals import BatchInterrupted

        self.folder.mkdir(parents=True, exist_ok=True)
        options = replace(self.options, progress=self.progress)
        try:
            for part, scenario, store in self.jobs:
                with bench_terms(self.out, part.name):
                    self.rerun += run_batch(scenario, store, options, command=self.command).rerun
        except BatchInterrupted as exc:
            stored = len(read_rows(self.suite, self.out))
            raise BatchInterrupted(exc.signum, f"bench stopped by {signal.Signals(exc.signum).name}: {stored} of "
                                   f"{self.suite.n_tasks()} tasks stored in {self.out} (re-run the same command to "
                                   "resume)") from None


def fly_suite(suite: Suite, entry: PlannerEntry, out: Path, *, workers=None, scheduler=None, progress: bool = False,
        command: str = "", rerun_changed: bool = False) -> list[dict]:
    """Fly ``entry`` on every part of ``suite`` into out/flights/ (resuming what is there; Flights) and return its
    task rows (read_rows)."""
    Flights(suite, entry, out, workers=workers, scheduler=scheduler, progress=progress, rerun_changed=rerun_changed,
            command=command).run()
    return read_rows(suite, out)


_OUT_FILE = re.compile(r"(?:a new|another) `out` file|another file")
"""The runner's advice to write elsewhere: for a bench, another `out` folder."""
_CHANGED_PLANNER = re.compile(r"planners\[\d+\] \((.*)\): (\d+) stored trials (flown with .*)")
"""The runner's note on rows flown by other planner code (pbdyn.experiments.extend.changed_planners)."""


@contextlib.contextmanager
def bench_terms(out: Path, part: str):
    """A context in which the batch runner's ConfigError about the flight store of ``part`` in the bench folder
    ``out`` is raised in bench's terms (bench_error)."""
    try:
        yield
    except ConfigError as exc:
        raise bench_error(exc, out, part) from None


def bench_error(exc: ConfigError, out: Path, part: str) -> ConfigError:
    """The runner's refusal ``exc`` of the flight store of ``part`` in the bench folder ``out``, in bench's terms,
    naming --out and the folder: the store is named by its place in the folder; the advice names what bench
    accepts (another --out folder, not a file; --rerun-changed, which bench has); a store that differs from the
    suite's scenario (the runner's SCENARIO, with its --extend advice) is the folder's problem; what changed
    (planner code, a world), which the runner names in place of a field, is said of the store."""
    store = f"flights/{part}.sqlite"
    problem = _OUT_FILE.sub("another `out` folder", exc.problem).replace(
        "give a file name for the results store", "use another `out` folder")
    if exc.field == "SCENARIO":
        return ConfigError("out", f"{store} holds flights of another scenario than the suite's part {part} (made by "
                           "another pbdyn, or edited); use another `out` folder", str(out))
    if exc.field == "out":
        return ConfigError("out", f"{store}: {problem}", str(out))
    if exc.show_value:
        return ConfigError(exc.field, problem, exc.value)
    m = _CHANGED_PLANNER.fullmatch(exc.field)
    what = f" holds {m[2]} trials of {m[1]} {m[3]}" if m else f": {exc.field}"
    return ConfigError("out", f"{store}{what}: {problem}", str(out))


def read_rows(suite: Suite, out: Path, label: str | None = None) -> list[dict]:
    """The task rows (card.task_row) of the suite's maps in the bench folder ``out`` (its flights/<part>.sqlite
    stores; the rows of planner label ``label`` only, if given), ordered by task."""
    from pbdyn.experiments.store import ResultsStore

    rows = []
    for part in suite.parts:
        path = Path(out) / "flights" / f"{part.name}.sqlite"
        if not path.is_file():
            continue
        st = ResultsStore.open(path)
        try:
            results = st.results()
        finally:
            st.close()
        wanted = {m["map_id"] for m in suite.maps if m["part"] == part.name}
        rows.extend(task_row(part.name, {**r, "map_id": suite.row_map_id(r)}) for r in results
                    if suite.row_map_id(r) in wanted and (label is None or r.get("planner_label") == label))
    return sorted(rows, key=task_key)


def load_references(suite: Suite) -> dict:
    """The suite's shipped reference results: label -> {"meta": {...}, "rows": [task rows]} ({} if none). The file
    must be whole, a reference document of this suite, and match the digest its manifest records
    (pbdyn.benchmark.suite.references_digest); else one ConfigError naming "reference" and the file."""
    from pbdyn.benchmark.suite import REFERENCES_DIGEST, references_digest

    path = suite.folder / REFERENCE_FILE
    recorded = suite.doc.get(REFERENCES_DIGEST)
    if not path.is_file():
        if recorded:
            raise ConfigError("reference", f"is missing: suite {suite.name} records reference results "
                              f"({REFERENCE_FILE}, sha256 {recorded[:12]})", str(path))
        return {}
    try:
        doc = json.loads(gzip.decompress(path.read_bytes()).decode("utf-8"))
    except (OSError, EOFError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError("reference", f"is damaged: not a gzip-compressed JSON document ({exc.__class__.__name__})",
                          str(path)) from None
    if not isinstance(doc, dict) or doc.get("format") != REFERENCE_FORMAT:
        raise ConfigError("reference", f"is not a {REFERENCE_FORMAT} file", str(path))
    if doc.get("suite") != suite.name or doc.get("suite_hash") != suite.hash:
        raise ConfigError("reference", f"was flown on another suite or version of suite {suite.name} (suite "
                          f"{str(doc.get('suite'))[:40]!r}, hash {str(doc.get('suite_hash'))[:12]}, the suite's is "
                          f"{suite.hash[:12]})", str(path))
    if recorded is not None:
        got = references_digest(doc)
        if got != recorded:
            raise ConfigError("reference", f"does not match the digest suite {suite.name} records (sha256 "
                              f"{got[:12]}, the manifest's {str(recorded)[:12]}): the reference results were "
                              "altered or replaced", str(path))
    cols, planners, rows = doc.get("columns"), doc.get("planners"), doc.get("rows")
    if (not isinstance(cols, list) or cols != ["label", *TASK_FIELDS] or not isinstance(planners, dict)
            or not isinstance(rows, list)
            or not all(isinstance(m, dict) for m in planners.values())
            or not all(isinstance(v, list) and len(v) == len(cols) and v[0] in planners for v in rows)):
        raise ConfigError("reference", "is malformed: its columns, planners or rows are not those of a "
                          f"{REFERENCE_FORMAT} document", str(path))
    out = {label: {"meta": meta, "rows": []} for label, meta in planners.items()}
    for values in rows:
        r = dict(zip(cols, values))
        out[r.pop("label")]["rows"].append(r)
    return out


def reference_document(suite: Suite, flown: dict) -> dict:
    """The reference file's document from ``flown``: label -> {"meta": {...}, "rows": [task rows]}."""
    cols = ["label", *TASK_FIELDS]
    rows = []
    for label in sorted(flown):
        for r in sorted(flown[label]["rows"], key=task_key):
            rows.append([label, *(r[c] for c in TASK_FIELDS)])
    return {"format": REFERENCE_FORMAT, "suite": suite.name, "suite_hash": suite.hash, "columns": cols,
            "planners": {k: flown[k]["meta"] for k in sorted(flown)}, "rows": rows}


def reproduction_differences(mine: list[dict], reference: list[dict]) -> list[str]:
    """The differences between flown task rows and reference rows (DETERMINISTIC_FIELDS), one line each; [] when
    they reproduce bit for bit."""
    ref = {task_key(r): r for r in reference}
    got = {task_key(r): r for r in mine}
    out = [f"task {k} missing from the flights" for k in sorted(set(ref) - set(got))]
    out += [f"task {k} not in the reference" for k in sorted(set(got) - set(ref))]
    for k in sorted(set(ref) & set(got)):
        for f in DETERMINISTIC_FIELDS:
            if ref[k][f] != got[k][f]:
                out.append(f"task {k}: {f} {got[k][f]!r} (reference {ref[k][f]!r})")
    return out


def bench(planner: str, *, gaze: str | None = None, params=None, gaze_params=None, suite=DEFAULT_SUITE, out,
          workers=None, scheduler=None, progress: bool = False, reproduce: bool = False, rerun_changed: bool = False,
          failures: int | None = None, failures_format: str | None = None, command: str = "") -> dict:
    """Fly ``planner`` (with ``gaze``; ``params``, ``gaze_params``: the trajectory and the gaze planner's
    parameters) on ``suite`` into the folder ``out`` and write its score card there (card.json, card.md, card.html);
    returns the card. ``reproduce``: the card gains "reproduction", the comparison of the flights with the
    planner's shipped reference rows (a built-in planner only). ``rerun_changed``: re-fly the stored flights whose
    planner code or world changed (else they are refused). ``failures``: K, write replays of up to K failed tasks
    per failure mode into out/failures/ (``failures_format`` "gif", the default, or "mp4"; the card's
    "failure_replays"). The card's "cost" sums the wall and CPU seconds of the invocations that flew into ``out``."""
    from pbdyn.benchmark.cost import Meter, totals
    from pbdyn.benchmark.failures import check_request
    from pbdyn.benchmark.render import card_html, card_markdown
    from pbdyn.planning.registry import pair_fingerprint

    given_scheduler = scheduler
    s = suite if isinstance(suite, Suite) else load_suite(suite)
    if any(m.get("difficulty") is None or m.get("level") is None for m in s.maps):
        raise ConfigError("suite", "is a draft: its maps have no measured difficulty yet (tools/make_suites.py "
                          "freeze)", s.name)
    entry = planner_entry(planner, gaze, params, gaze_params)
    failures, failures_format = check_request(failures, failures_format)
    if not isinstance(rerun_changed, bool):
        raise ConfigError("rerun_changed", "must be True or False", rerun_changed)
    refs = load_references(s)
    if reproduce and (entry.trajectory_params or entry.gaze_params):
        raise ConfigError("reproduce", "compares the flights with the shipped references, which were flown with "
                          "the planners' default parameters: bench without parameters to reproduce them", None,
                          show_value=False)
    if reproduce and entry.label not in refs:
        raise ConfigError("planner", f"has no shipped reference results on {s.name} to reproduce (references: "
                          + (", ".join(sorted(refs)) or "none") + ")", entry.label)
    _check_entry(s, entry)
    out = check_writable_folder("out", out)
    workers, scheduler = _checked_executor(workers, scheduler)
    fingerprint = pair_fingerprint(entry.trajectory, entry.gaze)
    rendered: list = []
    try:
        _check_marker(out, s, entry)
        meter = Meter(out)
        flights = None
        try:
            flights = Flights(s, entry, out, workers=workers, scheduler=scheduler, progress=progress,
                              rerun_changed=rerun_changed, command=command)
            flights.run()
            rows = read_rows(s, out)
            replays = None
            if failures is not None:
                replays = _failure_replays(s, entry, fingerprint, rows, out, failures, failures_format,
                                           fresh=flights.rerun > 0, progress=progress, done=rendered)
        finally:
            runs = meter.record(flights.flown if flights is not None else 0, len(rendered))
    finally:
        if scheduler is not None and not isinstance(scheduler, str) and scheduler is not given_scheduler:
            scheduler.close()
    info = {"label": entry.label, "trajectory": entry.trajectory, "gaze": entry.gaze, "fingerprint": fingerprint,
            **parameter_record(entry)}
    card = make_card(s, info, rows, refs)
    if reproduce:
        diffs = reproduction_differences(rows, refs[entry.label]["rows"])
        card["reproduction"] = {"reference": entry.label, "tasks": len(refs[entry.label]["rows"]),
                                "identical": not diffs, "differences": diffs[:50], "n_differences": len(diffs)}
    if replays is not None:
        card["failure_replays"] = replays
    card["cost"] = totals(runs)
    card = clean(card)
    atomic_write_text(out / "card.json", json.dumps(card, indent=1, sort_keys=True, allow_nan=False) + "\n")
    atomic_write_text(out / "card.md", card_markdown(card))
    atomic_write_text(out / "card.html", card_html(card))
    return card


def _failure_replays(suite: Suite, entry: PlannerEntry, fingerprint: str, rows: list[dict], out: Path, k: int,
                     fmt: str, *, fresh: bool, progress: bool, done: list) -> dict:
    """pbdyn.benchmark.failures.write_replays under stop_on_signals: SIGTERM or SIGINT stops it with
    BatchInterrupted saying what was kept (the flights, the replays written)."""
    from pbdyn.benchmark.failures import FOLDER, write_replays
    from pbdyn.experiments.signals import BatchInterrupted, stop_on_signals

    try:
        with stop_on_signals():
            return write_replays(suite, entry, fingerprint, rows, out, k, fmt, fresh=fresh, progress=progress,
                                 done=done)
    except BatchInterrupted as exc:
        raise BatchInterrupted(exc.signum, f"bench stopped by {signal.Signals(exc.signum).name} while writing the "
                               f"failure replays into {out / FOLDER}: the flights and the finished replays are kept "
                               "(re-run the same command to resume)") from None


def _checked_executor(workers, scheduler):
    """(workers, scheduler) checked as a batch checks them, before the bench folder is made: a scheduler address is
    reached now (its Client is returned; the caller closes it); ConfigError naming the option otherwise."""
    from pbdyn.experiments.cluster import connect
    from pbdyn.experiments.runner import BatchOptions, _checked_options

    if scheduler is None:
        _checked_options(BatchOptions(workers=workers))
    elif isinstance(scheduler, str):
        scheduler = connect(scheduler)
    return workers, scheduler


def read_card(path) -> dict:
    """A card.json (or a bench folder holding one); ConfigError naming the file if it is not a score card."""
    from pbdyn.benchmark.card import CARD_SCHEMA
    from pbdyn.benchmark.schema import card_errors

    p = Path(path)
    if p.is_dir():
        p = p / "card.json"
    if p.exists() and not p.is_file():
        raise ConfigError("card", "is not a file", str(path))
    if p.is_file() and p.stat().st_size > MAX_CARD_BYTES:
        raise ConfigError("card", f"is larger than a score card can be ({MAX_CARD_BYTES >> 20} MiB)", str(path))
    try:
        doc = read_versioned_json(p, "card", "schema", CARD_SCHEMA, "score card", shown=str(path))
    except RecursionError:
        raise ConfigError("card", "cannot be read (nested too deeply)", str(path)) from None
    problems = card_errors(doc)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise ConfigError("card", f"is not a valid {CARD_SCHEMA} score card: {problems[0]}{more}", str(path))
    return doc


MAX_CARD_BYTES = 64 << 20
"""Largest card.json read (a card of the largest suite is well under 1 MiB)."""


def clean(value):
    """``value`` with every NaN or infinite float replaced by None (cards are strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    return value
