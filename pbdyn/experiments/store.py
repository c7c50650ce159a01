"""The results store: one SQLite file (WAL mode) written by the batch coordinator only (DESIGN.md data flow).

Tables:
    meta   (key, value)       schema version, the resolved scenario (canonical JSON) and its name
    runs   (id, started, ended, version, scenario_json, command, workers)   one row per `pbdyn batch` invocation
    maps   (map_id, ...)      each map's setup, seed, rollout key and its metrics (computed once, JSON)
    trials (trial_key, ...)   one row per trial, unique key (the trial's config hash); INSERT OR IGNORE (OR REPLACE
                              when a trial is re-flown: --rerun-changed, --retry-errors)

A trial row holds every TrialResult field as a real column (TRIAL_COLUMNS, derived from the dataclass: int ->
INTEGER, float -> REAL, str -> TEXT, anything else -> TEXT holding JSON; wall_timings only in result_json) and the
whole TrialResult as JSON. Keep the file on a local disk: SQLite's locking is unreliable on network file systems.

Schema versions: 2 added trials.planner_fingerprint. Older stores are read as they are (a column they lack reads as
NULL) and upgraded in place when `pbdyn batch` writes to them (ResultsStore.create adds the missing columns); a
store from a newer schema is refused.
"""

from __future__ import annotations

import dataclasses
import json
import sqlite3
import time
import typing
from collections.abc import Iterable, Sequence
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.sim.result import TrialResult

SCHEMA_VERSION = 2

_SQL_TYPES = {bool: "INTEGER", int: "INTEGER", float: "REAL", str: "TEXT"}


def trial_columns(result_type: type = TrialResult) -> tuple[tuple[str, str], ...]:
    """(name, SQL type) of every field of ``result_type`` in field order, wall_timings excluded; fields that are
    not int, float or str (tuples, dicts, unions) are "JSON" (stored as TEXT)."""
    hints = typing.get_type_hints(result_type)
    return tuple((f.name, _SQL_TYPES.get(hints[f.name], "JSON")) for f in dataclasses.fields(result_type)
                 if f.name != "wall_timings")


TRIAL_COLUMNS = trial_columns()
"""Trial columns in TrialResult field order (Table 2-2 first, then pbdyn's own)."""

_JSON_COLUMNS = frozenset(n for n, t in TRIAL_COLUMNS if t == "JSON")


def _column_sql(name: str, sql_type: str) -> str:
    return f"{name} {'TEXT' if sql_type == 'JSON' else sql_type}"


_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (id INTEGER PRIMARY KEY AUTOINCREMENT, started REAL, ended REAL, version TEXT,
    scenario_json TEXT, command TEXT, workers TEXT);
CREATE TABLE IF NOT EXISTS maps (map_id TEXT PRIMARY KEY, map_index INTEGER, map_key TEXT, setup_json TEXT,
    seed INTEGER, rollout_key TEXT, dataset TEXT, mean_obstacle_speed REAL, mean_obstacle_radius REAL,
    metrics_json TEXT, metric_times_json TEXT, backend TEXT);
CREATE TABLE IF NOT EXISTS trials (trial_key TEXT PRIMARY KEY, {", ".join(_column_sql(*c) for c in TRIAL_COLUMNS)},
    error TEXT, result_json TEXT NOT NULL, finished REAL);
CREATE INDEX IF NOT EXISTS trials_map ON trials (map_id);
"""


def _cell(value, as_json: bool = False):
    if value is not None and (as_json or isinstance(value, (list, tuple, dict))):
        return json.dumps(value, sort_keys=True)
    return value


class ResultsStore:
    """A results store (see the module docstring). Open with ResultsStore.create or ResultsStore.open."""

    def __init__(self, path: Path, conn: sqlite3.Connection):
        self.path = path
        self.conn = conn

    # ------------------------------------------------------------------------------------------- opening
    @classmethod
    def create(cls, path: str | Path) -> "ResultsStore":
        """Open ``path`` for writing, creating the file and tables if needed (WAL journal, synchronous NORMAL)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(str(p), timeout=30.0)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        store = cls(p, conn)
        version = store._schema_version()
        if version is not None and version > SCHEMA_VERSION:
            conn.close()
            raise ConfigError("RESULTS", f"was written by schema version {version}; this pbdyn reads versions up to "
                              f"{SCHEMA_VERSION} (use a newer pbdyn or a new --out file)", str(path))
        conn.executescript(_SCHEMA)
        have = store._trial_table_columns()
        with conn:   # upgrade an older store in one transaction: add the columns it lacks, then the version
            for name, sql_type in TRIAL_COLUMNS:
                if name not in have:
                    conn.execute(f"ALTER TABLE trials ADD COLUMN {_column_sql(name, sql_type)}")
            conn.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
        return store

    @classmethod
    def open(cls, path: str | Path) -> "ResultsStore":
        """Open an existing store read-only; ConfigError naming RESULTS if it is missing, not a store, or from a
        newer schema."""
        p = Path(path)
        if not p.is_file():
            raise ConfigError("RESULTS", "file not found", str(path))
        try:
            conn = sqlite3.connect(f"file:{p}?mode=ro", uri=True, timeout=30.0)
            store = cls(p, conn)
            version = store._schema_version()
        except sqlite3.DatabaseError:
            raise ConfigError("RESULTS", "is not a pbdyn results store (SQLite)", str(path)) from None
        if version is None:
            conn.close()
            raise ConfigError("RESULTS", "is not a pbdyn results store (no schema version)", str(path))
        if version > SCHEMA_VERSION:
            conn.close()
            raise ConfigError("RESULTS", f"was written by schema version {version}; this pbdyn reads versions up to "
                              f"{SCHEMA_VERSION}", str(path))
        return store

    def _trial_table_columns(self) -> set[str]:
        return {r[1] for r in self.conn.execute("PRAGMA table_info(trials)")}

    def _schema_version(self) -> int | None:
        try:
            row = self.conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        except sqlite3.OperationalError:
            return None
        return int(row[0]) if row else None

    def close(self) -> None:
        """Commit and close."""
        try:
            self.conn.commit()
        finally:
            self.conn.close()

    # ------------------------------------------------------------------------------------------- meta and runs
    def get_meta(self, key: str) -> str | None:
        """A meta value, or None."""
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else None

    def set_meta(self, key: str, value: str) -> None:
        """Set a meta value (committed)."""
        self.conn.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))
        self.conn.commit()

    def start_run(self, version: str, scenario_json: str, command: str, workers: str) -> int:
        """Record the start of a batch run; returns its id."""
        cur = self.conn.execute("INSERT INTO runs (started, version, scenario_json, command, workers) "
                                "VALUES (?, ?, ?, ?, ?)", (time.time(), version, scenario_json, command, workers))
        self.conn.commit()
        return int(cur.lastrowid)

    def end_run(self, run_id: int) -> None:
        """Record the end of a batch run."""
        self.conn.execute("UPDATE runs SET ended = ? WHERE id = ?", (time.time(), run_id))
        self.conn.commit()

    # ------------------------------------------------------------------------------------------- rows
    def finished_keys(self) -> set[str]:
        """Keys of every stored trial."""
        return {r[0] for r in self.conn.execute("SELECT trial_key FROM trials")}

    def trial_states(self) -> dict[str, tuple[str | None, str | None, str | None]]:
        """trial key -> (planner_label, planner_fingerprint, outcome) of every stored trial (None: not recorded)."""
        fp = "planner_fingerprint" if "planner_fingerprint" in self._trial_table_columns() else "NULL"
        return {r[0]: (r[1], r[2], r[3])
                for r in self.conn.execute(f"SELECT trial_key, planner_label, {fp}, outcome FROM trials")}

    def error_count(self) -> int:
        """Number of stored trials whose outcome is "error"."""
        return int(self.conn.execute("SELECT COUNT(*) FROM trials WHERE outcome = 'error'").fetchone()[0])

    def maps_with_metrics(self) -> set[str]:
        """Map ids whose metrics are stored."""
        return {r[0] for r in self.conn.execute("SELECT map_id FROM maps WHERE metrics_json IS NOT NULL")}

    def add_trials(self, rows: Iterable[tuple[str, dict, str | None]], replace: bool = False) -> int:
        """Insert (trial_key, TrialResult dict, error message or None) rows; keys already stored are kept
        (INSERT OR IGNORE), or with ``replace`` replaced row by row (INSERT OR REPLACE: re-flown trials). No
        commit (the coordinator batches commits). Returns the number of rows given."""
        names = [n for n, _ in TRIAL_COLUMNS]
        sql = (f"INSERT OR {'REPLACE' if replace else 'IGNORE'} INTO trials (trial_key, {', '.join(names)}, error, "
               f"result_json, finished) VALUES ({', '.join('?' * (len(names) + 4))})")
        batch = [(key, *[_cell(res.get(n), n in _JSON_COLUMNS) for n in names], err,
                  json.dumps(res, sort_keys=True), time.time()) for key, res, err in rows]
        self.conn.executemany(sql, batch)
        return len(batch)

    def add_map(self, row: dict) -> None:
        """Insert or replace a map row (keys as the maps table's columns; dicts/lists stored as JSON); no commit."""
        cols = ("map_id", "map_index", "map_key", "setup_json", "seed", "rollout_key", "dataset",
                "mean_obstacle_speed", "mean_obstacle_radius", "metrics_json", "metric_times_json", "backend")
        self.conn.execute(f"INSERT OR REPLACE INTO maps ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                          tuple(_cell(row.get(c)) for c in cols))

    def commit(self) -> None:
        """Commit pending rows."""
        self.conn.commit()

    def trial_rows(self, columns: Sequence[str] | None = None) -> tuple[list[str], list[tuple]]:
        """(column names, rows) of the trials table, ordered by trial key (trial_key, TRIAL_COLUMNS, error by
        default); a column an older store lacks reads as None."""
        names = list(columns) if columns else ["trial_key"] + [n for n, _ in TRIAL_COLUMNS] + ["error"]
        have = self._trial_table_columns()
        select = ", ".join(n if n in have else f"NULL AS {n}" for n in names)
        rows = self.conn.execute(f"SELECT {select} FROM trials ORDER BY trial_key").fetchall()
        return names, rows

    def results(self) -> list[dict]:
        """Every stored TrialResult dict (with "trial_key" and "error"), ordered by trial key."""
        out = []
        for key, res, err in self.conn.execute("SELECT trial_key, result_json, error FROM trials "
                                               "ORDER BY trial_key"):
            d = json.loads(res)
            d["trial_key"], d["error"] = key, err
            out.append(d)
        return out

    def maps(self) -> dict[str, dict]:
        """map_id -> map row (JSON columns decoded)."""
        cur = self.conn.execute("SELECT map_id, map_index, map_key, setup_json, seed, rollout_key, dataset, "
                                "mean_obstacle_speed, mean_obstacle_radius, metrics_json, metric_times_json, "
                                "backend FROM maps ORDER BY map_id")
        out = {}
        for r in cur:
            out[r[0]] = {"map_index": r[1], "map_key": r[2], "setup": json.loads(r[3]) if r[3] else {},
                         "seed": r[4], "rollout_key": r[5], "dataset": r[6], "mean_obstacle_speed": r[7],
                         "mean_obstacle_radius": r[8], "metrics": json.loads(r[9]) if r[9] else {},
                         "metric_times": json.loads(r[10]) if r[10] else {}, "backend": r[11]}
        return out

    def count(self) -> int:
        """Number of stored trials."""
        return int(self.conn.execute("SELECT COUNT(*) FROM trials").fetchone()[0])
