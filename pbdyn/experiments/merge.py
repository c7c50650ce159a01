"""Join results stores of one experiment into one (`pbdyn merge`): the shards of `pbdyn batch --shard I/N`, e.g. the
tasks of a SLURM array, or stores flown on different machines.

Every input must hold the same scenario (canonical JSON) and schema-compatible tables, and every planner label and
map must have been flown with one code: a planner label whose rows carry two planner fingerprints, or a map whose
rows or metrics carry two world fingerprints, across the inputs (and an existing output) is refused before anything
is written. Trials are keyed by their config hash, so a trial held by several inputs is stored once (the first
input's row; a duplicate whose outcome differs is counted as a conflict and reported). Maps are joined by map id, a row with metrics
winning over one without. A new output store is written beside its final name and renamed into place only when
complete; into an existing store (same scenario) each input's rows are added in one transaction.
"""

from __future__ import annotations

import os
import signal
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.experiments.signals import BatchInterrupted, stop_on_signals
from pbdyn.experiments.store import MAP_COLUMNS, TRIAL_COLUMNS, ResultsStore, check_store_path, read_only_uri, store_error

_RUN_COLUMNS = ("started", "ended", "version", "scenario_json", "command", "workers")


@dataclass(frozen=True)
class MergeSummary:
    """What a merge did: trials in the output afterwards, trials added, duplicates skipped (of which conflicts:
    the same key with another outcome or planner fingerprint), maps in the output."""

    trials: int
    added: int
    duplicates: int
    conflicts: int
    maps: int


def merge_stores(out: str | Path, inputs: list[str | Path]) -> MergeSummary:
    """Join the results stores ``inputs`` into ``out`` (created, or an existing store of the same scenario)."""
    if not inputs:
        raise ConfigError("RESULTS", "no store to merge", [])
    out_path = check_store_path(out, "out")
    scenario = None
    rules: dict = {}
    for path in inputs:
        if Path(path).resolve() == out_path.resolve():
            raise ConfigError("RESULTS", "lists the output store as an input", str(path))
        st = ResultsStore.open(path)
        try:
            doc = st.get_meta("scenario")
            rules.setdefault(st.get_meta("map_ids") or "setup-1", Path(path))
        finally:
            st.conn.close()
        if doc is None:
            raise ConfigError("RESULTS", "holds no scenario (not written by a batch)", str(path))
        if scenario is None:
            scenario, first = doc, path
        elif doc != scenario:
            raise ConfigError("RESULTS", f"holds another scenario than {Path(first).name}; only stores of one "
                              "experiment merge", str(path))
    existed = out_path.exists() and out_path.stat().st_size > 0
    if existed:
        st = ResultsStore.open(out_path, field="out")
        try:
            have = st.get_meta("scenario")
        finally:
            st.conn.close()
        if have is not None and have != scenario:
            raise ConfigError("out", "holds another scenario than the stores to merge (use a new `out` file)",
                              str(out))
        if have is not None:
            rules.setdefault(_id_rule(out_path), out_path)
    if len(rules) > 1:
        (r1, p1), (r2, p2) = list(rules.items())[:2]
        raise ConfigError("RESULTS", f"{p1.name} names its maps by the map id rule {r1} and {p2.name} by {r2} (an "
                          "older pbdyn); merged, one map would have two ids (re-fly the older store)",
                          show_value=False)
    check_same_code(([(out_path, "out")] if existed else []) + [(p, "RESULTS") for p in inputs])
    if existed:
        target = out_path
    else:
        remove_stale_temps(out_path)
        target = out_path.with_name(f"{temp_prefix(out_path)}{os.getpid()}")
        _remove(target)
    with stop_on_signals():        # SIGTERM and SIGINT unwind through the clean-up below
        try:
            summary = _merge_into(target, scenario, inputs, next(iter(rules)))
            if not existed:
                os.replace(target, out_path)
            return summary
        except BatchInterrupted as exc:
            raise BatchInterrupted(exc.signum, f"merge stopped by {signal.Signals(exc.signum).name}: "
                                   + (f"{out_path.name} not written" if not existed else
                                      f"the input being added to {out_path.name} was rolled back")) from None
        finally:
            if not existed:
                _remove(target)


def temp_prefix(out: Path) -> str:
    """A new output store is written beside its final name as this prefix + the merging process' id:
    ".NAME.merging-" (a name of over 150 bytes is cut and tagged with its digest, so the temp name stays within
    the file system's limit)."""
    name = out.name
    if len(os.fsencode(name)) > 150:
        import hashlib

        name = os.fsencode(name)[:100].decode("utf-8", "ignore") + "~" + \
            hashlib.sha256(os.fsencode(out.name)).hexdigest()[:8]
    return f".{name}.merging-"


def remove_stale_temps(out: Path) -> list[Path]:
    """Delete the temporary stores (and their -wal/-shm/-journal files) that merges into ``out`` left behind when
    they were killed (SIGKILL, power loss): those whose process no longer runs. Returns the temp stores removed."""
    prefix = temp_prefix(out)
    gone = []
    try:
        names = [p.name for p in out.parent.iterdir() if p.name.startswith(prefix)]
    except OSError:
        return gone
    for name in names:
        pid = name[len(prefix):].split("-")[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        base = out.parent / (prefix + pid)
        _remove(base)
        gone.append(base)
    return gone


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:          # another user's process
        return True
    return True


def check_same_code(stores: list[tuple]) -> None:
    """ConfigError unless every (path, field) store flew each planner label with one planner fingerprint and each
    map in one world (world fingerprint): a merged store never holds two versions of a planner or a world under
    one key. Rows without a recorded fingerprint (older schemas) are not compared."""
    planners: dict[str, dict[str, Path]] = {}
    worlds: dict[str, dict[str, Path]] = {}
    metric_codes: dict[str, dict[str, Path]] = {}
    keys: dict[str, int] = {}
    index: dict[str, int] = {}
    for path, field in stores:
        st = ResultsStore.open(path, field=field)
        try:
            for label, fp, _ in st.fingerprint_counts():
                if fp:
                    planners.setdefault(label, {}).setdefault(fp, Path(path))
            for key, fps in st.world_fingerprints(by="map_key").items():   # one map's place, whatever its id
                for fp in fps:
                    if fp:
                        worlds.setdefault(key, {}).setdefault(fp, Path(path))
            keys.update(st.map_keys())
            for map_id, code in st.metric_codes().items():
                metric_codes.setdefault(map_id, {}).setdefault(code, Path(path))
            index.update(st.map_indices())
        finally:
            st.conn.close()
    checks = (
        (metric_codes, index, lambda m, i, a, b: f"the metrics of map {i} ({m}) were computed by code {a[0]} in "
         f"{a[1].name} and {b[0]} in {b[1].name} (a metric's code changed); merged, one map would hold two versions "
         "of its metrics (re-run one store with `rerun_changed`)"),
        (planners, None, lambda label, i, a, b: f"planner {label} was flown with code {a[0]} in {a[1].name} and "
         f"{b[0]} in {b[1].name}; merged, one label would hold two planners (re-fly one store with `rerun_changed`)"),
        (worlds, keys, lambda key, i, a, b: f"map {i} ({key}) was flown in world {a[0]} in {a[1].name} and in world "
         f"{b[0]} in {b[1].name} (its code or files changed); merged, one map would hold two worlds (re-fly one "
         "store with `rerun_changed`)"))
    for found, order, message in checks:      # one version of each map's metrics, each planner, each map's world
        for name, versions in sorted(found.items(), key=lambda kv: str(kv[0]) if order is None else
                                     (order.get(kv[0], -1), kv[0])):
            if len(versions) > 1:
                a, b = list(versions.items())[:2]
                raise ConfigError("RESULTS", message(name, "?" if order is None else order.get(name, "?"), a, b),
                                  show_value=False)


def _id_rule(path: Path) -> str:
    """The map id rule a store's rows were made by (meta "map_ids"; none recorded: "setup-1")."""
    st = ResultsStore.open(path, field="out")
    try:
        return st.get_meta("map_ids") or "setup-1"
    finally:
        st.conn.close()


def _remove(path: Path) -> None:
    for suffix in ("", "-wal", "-shm", "-journal"):
        Path(str(path) + suffix).unlink(missing_ok=True)


def _merge_into(target: Path, scenario: str, inputs: list, rule: str) -> MergeSummary:
    store = ResultsStore.create(target, field="out")
    conn = store.conn
    try:
        if store.get_meta("scenario") is None:
            store.set_meta("scenario", scenario)
            if rule != "setup-1":
                store.set_meta("map_ids", rule)
        before = store.count()
        duplicates = conflicts = 0
        have_cols = store._trial_table_columns()
        for i, path in enumerate(inputs):
            alias = f"src{i}"
            conn.execute(f"ATTACH DATABASE ? AS {alias}", (read_only_uri(Path(path)),))
            try:
                src_cols = {r[1] for r in conn.execute(f"PRAGMA {alias}.table_info(trials)")}
                src_map_cols = {r[1] for r in conn.execute(f"PRAGMA {alias}.table_info(maps)")}
                cols = ["trial_key"] + [n for n, _ in TRIAL_COLUMNS if n in src_cols and n in have_cols] + \
                    ["error", "result_json", "finished"] + (["world_fingerprint"] if "world_fingerprint" in src_cols
                                                            else [])
                dup, bad = conn.execute(
                    f"SELECT COUNT(*), COALESCE(SUM(t.outcome IS NOT s.outcome OR "
                    f"{_same('planner_fingerprint', src_cols)}), 0) FROM {alias}.trials s "
                    f"JOIN main.trials t ON t.trial_key = s.trial_key").fetchone()
                duplicates += int(dup)
                conflicts += int(bad)
                names = ", ".join(cols)
                conn.execute(f"INSERT OR IGNORE INTO main.trials ({names}) SELECT {names} FROM {alias}.trials")
                mcols = ", ".join(c for c in MAP_COLUMNS if c in src_map_cols)
                conn.execute(f"INSERT OR IGNORE INTO main.maps ({mcols}) SELECT {mcols} FROM {alias}.maps")
                rest = [c for c in MAP_COLUMNS[1:] if c in src_map_cols]      # a map row without metrics takes the one with them
                conn.execute(f"UPDATE main.maps SET ({', '.join(rest)}) = (SELECT "
                             f"{', '.join('s.' + c for c in rest)} FROM {alias}.maps s WHERE "
                             f"s.map_id = main.maps.map_id) WHERE metrics_json IS NULL AND map_id IN "
                             f"(SELECT map_id FROM {alias}.maps WHERE metrics_json IS NOT NULL)")
                rcols = ", ".join(_RUN_COLUMNS)
                conn.execute(f"INSERT INTO main.runs ({rcols}) SELECT {rcols} FROM {alias}.runs ORDER BY id")
                conn.commit()
            except BaseException:
                conn.rollback()
                raise
            finally:
                conn.execute(f"DETACH DATABASE {alias}")
        after = store.count()
        maps = int(conn.execute("SELECT COUNT(*) FROM maps").fetchone()[0])
        return MergeSummary(after, after - before, duplicates, conflicts, maps)
    except sqlite3.DatabaseError as exc:
        raise store_error("out", exc, target) from None
    finally:
        store.close()


def _same(column: str, src_cols: set) -> str:
    """SQL: 1 where the source and target rows differ in ``column`` (0 when the source lacks it)."""
    return f"(t.{column} IS NOT s.{column})" if column in src_cols else "0"
