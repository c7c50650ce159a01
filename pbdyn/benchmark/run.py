"""`pbdyn bench`: fly a planner on a frozen suite and write its score card (docs/benchmark.md).

The suite's parts are flown by the batch runner (pbdyn.experiments.runner: lockstep, resumable, local processes or
a Dask scheduler) into ``OUT/flights/<part>.sqlite``; then the card (pbdyn.benchmark.card) is written as
``OUT/card.json``, ``OUT/card.md`` and ``OUT/card.html`` (pbdyn.benchmark.render), each atomically. ``OUT/bench.json``
records which planner and suite the folder holds, so a folder never mixes two benches.

The suite's reference results (REFERENCE_FILE in the suite folder) hold every built-in trajectory planner flown with
its thesis gaze pairing (THESIS_GAZE); ``reproduce=True`` compares the planner's flights with its shipped reference
rows field by field (DETERMINISTIC_FIELDS: everything but wall times) and reports every difference.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path

from pbdyn.benchmark.card import DETERMINISTIC_FIELDS, TASK_FIELDS, make_card, task_key, task_row
from pbdyn.benchmark.suite import Suite, flight_scenario, load_suite, read_versioned_json
from pbdyn.config import PlannerEntry
from pbdyn.errors import ConfigError, check_writable_folder

REFERENCE_FILE = "reference.json.gz"
REFERENCE_FORMAT = "pbdyn-reference/1"
THESIS_GAZE = {"local_primitives": "lookahead", "global_primitives": "fullrange", "mpc": "lookahead",
               "straight_line": "lookahead", "local_primitives_minjerk": "lookahead"}
"""The gaze each built-in trajectory planner flies with by default (the thesis' pairings: FullRange with the global
planner, LookAhead with the local ones)."""
DEFAULT_SUITE = "pbdyn-2d-v1"
MARKER = "bench.json"


def planner_entry(planner: str, gaze: str | None = None, params: Mapping | None = None) -> PlannerEntry:
    """The (trajectory, gaze) pair benched: ``gaze`` or the planner's THESIS_GAZE (LookAhead for a plug-in);
    ``params``: the trajectory planner's parameters (a table with string keys; default none)."""
    from pbdyn.planning.registry import pair_fingerprint, resolve_gaze_planner, resolve_trajectory_planner

    if not isinstance(planner, str) or not planner:
        raise ConfigError("planner", "must be a registry name or 'package.module:Class'", planner)
    if gaze is not None and (not isinstance(gaze, str) or not gaze):
        raise ConfigError("gaze", "must be a gaze planner name or 'package.module:Class'", gaze)
    if params is not None and (not isinstance(params, Mapping) or not all(isinstance(k, str) for k in params)):
        raise ConfigError("params", "must be a table of the trajectory planner's parameters (string keys)", params)
    entry = PlannerEntry(planner, gaze or THESIS_GAZE.get(planner, "lookahead"), dict(params or {}))
    resolve_trajectory_planner(entry.trajectory, "planner")   # each name's error names its own option
    resolve_gaze_planner(entry.gaze, "gaze")
    pair_fingerprint(entry.trajectory, entry.gaze)         # unknown names fail here, before anything is written
    return entry


def _check_entry(suite: Suite, entry: PlannerEntry) -> None:
    """Build the pair once on the suite's first part (names, imports, parameters), so that bad parameters fail
    before the bench folder is made; ConfigError naming ``params.<key>`` for a bad trajectory parameter."""
    from pbdyn.experiments.runner import check_planners

    try:
        check_planners(flight_scenario(suite, suite.parts[0], [entry]))
    except ConfigError as exc:
        head = "planners[0].trajectory_params"
        if exc.field.startswith(head):
            raise exc.renamed("params" + exc.field[len(head):]) from None
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


def _check_marker(out: Path, suite: Suite, entry: PlannerEntry) -> None:
    marker = out / MARKER
    mine = {"suite": suite.name, "suite_hash": suite.hash, "trajectory": entry.trajectory, "gaze": entry.gaze}
    if entry.trajectory_params:
        mine["trajectory_params"] = dict(entry.trajectory_params)
        files = parameter_files(entry.trajectory_params)
        if files:
            mine["parameter_files"] = files
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
            elif isinstance(have, dict) and have.get("parameter_files", {}) != mine.get("parameter_files", {}):
                changed = sorted(k for k in set(have.get("parameter_files", {})) | set(mine.get("parameter_files", {}))
                                 if have.get("parameter_files", {}).get(k) != mine.get("parameter_files", {}).get(k))
                what += f" whose parameter file {changed[0]} held other content then"
            raise ConfigError("out", f"holds the bench of {what}; use another --out folder", str(out))
        return
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError("out", "exists and is not an empty folder or a bench folder; use another --out folder",
                          str(out))
    out.mkdir(parents=True, exist_ok=True)
    _write_atomic(marker, json.dumps(mine, indent=1, sort_keys=True) + "\n")


def fly(suite: Suite, entry: PlannerEntry, out: Path, *, workers=None, scheduler=None, progress: bool = False,
        command: str = "") -> list[dict]:
    """Fly ``entry`` on every part of ``suite`` into out/flights/ (resuming what is there) and return its task
    rows (read_rows)."""
    from pbdyn.experiments.runner import BatchOptions, run_batch

    folder = out / "flights"
    folder.mkdir(parents=True, exist_ok=True)
    for part in suite.parts:
        run_batch(flight_scenario(suite, part, [entry]), folder / f"{part.name}.sqlite",
                  BatchOptions(workers=workers, scheduler=scheduler, metrics=False, progress=progress),
                  command=command)
    return read_rows(suite, out)


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


def compare_rows(mine: list[dict], reference: list[dict]) -> list[str]:
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


def bench(planner: str, *, gaze: str | None = None, params=None, suite=DEFAULT_SUITE, out, workers=None,
          scheduler=None, progress: bool = False, reproduce: bool = False, command: str = "") -> dict:
    """Fly ``planner`` (with ``gaze``; ``params``: the trajectory planner's parameters) on ``suite`` into the folder
    ``out`` and write its score card there (card.json, card.md, card.html); returns the card. ``reproduce``: the
    card gains "reproduction", the comparison of the flights with the planner's shipped reference rows (a built-in
    planner only)."""
    from pbdyn.benchmark.render import card_html, card_markdown
    from pbdyn.planning.registry import pair_fingerprint

    given_scheduler = scheduler
    s = suite if isinstance(suite, Suite) else load_suite(suite)
    if any(m.get("difficulty") is None or m.get("level") is None for m in s.maps):
        raise ConfigError("suite", "is a draft: its maps have no measured difficulty yet (tools/make_suites.py "
                          "freeze)", s.name)
    entry = planner_entry(planner, gaze, params)
    refs = load_references(s)
    if reproduce and entry.label not in refs:
        raise ConfigError("planner", f"has no shipped reference results on {s.name} to reproduce (references: "
                          + (", ".join(sorted(refs)) or "none") + ")", entry.label)
    _check_entry(s, entry)
    out = check_writable_folder("out", out)
    workers, scheduler = _checked_executor(workers, scheduler)
    try:
        _check_marker(out, s, entry)
        rows = fly(s, entry, out, workers=workers, scheduler=scheduler, progress=progress, command=command)
    finally:
        if scheduler is not None and not isinstance(scheduler, str) and scheduler is not given_scheduler:
            scheduler.close()
    info = {"label": entry.label, "trajectory": entry.trajectory, "gaze": entry.gaze,
            "fingerprint": pair_fingerprint(entry.trajectory, entry.gaze)}
    if entry.trajectory_params:
        info["trajectory_params"] = dict(entry.trajectory_params)
        files = parameter_files(entry.trajectory_params)
        if files:
            info["parameter_files"] = files
    card = make_card(s, info, rows, refs)
    if reproduce:
        diffs = compare_rows(rows, refs[entry.label]["rows"])
        card["reproduction"] = {"reference": entry.label, "tasks": len(refs[entry.label]["rows"]),
                                "identical": not diffs, "differences": diffs[:50], "n_differences": len(diffs)}
    card = clean(card)
    _write_atomic(out / "card.json", json.dumps(card, indent=1, sort_keys=True, allow_nan=False) + "\n")
    _write_atomic(out / "card.md", card_markdown(card))
    _write_atomic(out / "card.html", card_html(card))
    return card


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


def _write_atomic(path: Path, text: str) -> None:
    from pbdyn.files import atomic_write

    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def clean(value):
    """``value`` with every NaN or infinite float replaced by None (cards are strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    return value
