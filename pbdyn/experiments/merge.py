"""Join results stores of one experiment into one (`pbdyn merge`): the shards of `pbdyn batch --shard I/N`, e.g. the
tasks of a SLURM array, or stores flown on different machines.

Every input must hold the same scenario (canonical JSON) and schema-compatible tables. Trials are keyed by their
config hash, so a trial held by several inputs is stored once (the first input's row; a duplicate whose outcome or
planner fingerprint differs is counted as a conflict and reported). Maps are joined by map id, a row with metrics
winning over one without. A new output store is written beside its final name and renamed into place only when
complete; into an existing store (same scenario) each input's rows are added in one transaction.
"""

from __future__ import annotations

import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.experiments.store import TRIAL_COLUMNS, ResultsStore, check_store_path, store_error

_MAP_COLUMNS = ("map_id", "map_index", "map_key", "setup_json", "seed", "rollout_key", "dataset",
                "mean_obstacle_speed", "mean_obstacle_radius", "metrics_json", "metric_times_json", "backend")
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
    for path in inputs:
        if Path(path).resolve() == out_path.resolve():
            raise ConfigError("RESULTS", "lists the output store as an input", str(path))
        st = ResultsStore.open(path)
        try:
            doc = st.get_meta("scenario")
        finally:
            st.conn.close()
        if doc is None:
            raise ConfigError("RESULTS", "holds no scenario (not written by pbdyn batch)", str(path))
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
            raise ConfigError("out", "holds another scenario than the stores to merge (use a new --out file)",
                              str(out))
        target = out_path
    else:
        target = out_path.with_name(f".{out_path.name}.merging-{os.getpid()}")
        _remove(target)
    try:
        summary = _merge_into(target, scenario, inputs)
        if not existed:
            os.replace(target, out_path)
        return summary
    except BaseException:
        if not existed:
            _remove(target)
        raise


def _remove(path: Path) -> None:
    for suffix in ("", "-wal", "-shm", "-journal"):
        Path(str(path) + suffix).unlink(missing_ok=True)


def _merge_into(target: Path, scenario: str, inputs: list) -> MergeSummary:
    store = ResultsStore.create(target, field="out")
    conn = store.conn
    try:
        if store.get_meta("scenario") is None:
            store.set_meta("scenario", scenario)
        before = store.count()
        duplicates = conflicts = 0
        have_cols = store._trial_table_columns()
        for i, path in enumerate(inputs):
            alias = f"src{i}"
            conn.execute(f"ATTACH DATABASE ? AS {alias}", (str(Path(path).absolute()),))
            try:
                src_cols = {r[1] for r in conn.execute(f"PRAGMA {alias}.table_info(trials)")}
                cols = ["trial_key"] + [n for n, _ in TRIAL_COLUMNS if n in src_cols and n in have_cols] + \
                    ["error", "result_json", "finished"]
                dup, bad = conn.execute(
                    f"SELECT COUNT(*), COALESCE(SUM(t.outcome IS NOT s.outcome OR "
                    f"{_same('planner_fingerprint', src_cols)}), 0) FROM {alias}.trials s "
                    f"JOIN main.trials t ON t.trial_key = s.trial_key").fetchone()
                duplicates += int(dup)
                conflicts += int(bad)
                names = ", ".join(cols)
                conn.execute(f"INSERT OR IGNORE INTO main.trials ({names}) SELECT {names} FROM {alias}.trials")
                mcols = ", ".join(_MAP_COLUMNS)
                conn.execute(f"INSERT OR IGNORE INTO main.maps ({mcols}) SELECT {mcols} FROM {alias}.maps")
                rest = _MAP_COLUMNS[1:]      # a map row without metrics takes the one with them
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
