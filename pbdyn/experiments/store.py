"""The results store: one SQLite file written by the batch coordinator only (docs/design.md data flow); WAL mode while
a writer has it open, a rollback journal at rest (so readers create no side files and read it in read-only folders).

Tables:
    meta   (key, value)       schema version, the resolved scenario (canonical JSON) and its name
    runs   (id, started, ended, version, scenario_json, command, workers)   one row per `pbdyn batch` invocation
    maps   (map_id, ...)      each map's setup, seed, rollout key and its metrics (computed once, JSON)
    trials (trial_key, ...)   one row per trial, unique key (the trial's config hash); INSERT OR IGNORE (OR REPLACE
                              when a trial is re-flown: --rerun-changed, --retry-errors)

A trial row holds every TrialResult field as a real column (TRIAL_COLUMNS, derived from the dataclass: int ->
INTEGER, float -> REAL, str -> TEXT, anything else -> TEXT holding JSON; wall_timings only in result_json) and the
whole TrialResult as JSON. Keep the file on a local disk: SQLite's locking is unreliable on network file systems.

Every open runs ``PRAGMA quick_check`` (0.16 s on a 100k-trial, 215 MB store with a warm page cache;
integrity_check, which also cross-checks indexes, took 0.5 s): a damaged page is reported before anything is read
or written. SQLite's failures (damaged or not a database, read-only file or folder, a folder given as the store,
disk I/O errors, locked past the timeout, a full disk) become one-line ConfigErrors naming the store's parameter
("RESULTS" when reading, "out" when a batch writes it) with a hint; a damaged row found while reading (bytes that
are not UTF-8 or not JSON) likewise.

Schema versions: 2 added trials.planner_fingerprint; 3 added profile, start_delay_s, max_speed_mps,
max_accel_mps2 and limits_exceeded (a store holds one profile: pbdyn.experiments.extend.check_scenario); 4 added
trials.world_fingerprint (the first 16 hex digits of the row's map rollout key, which covers the world's code and
files: pbdyn.world.rollout.rollout_key) and the meta key "world" (pbdyn.world.rollout.world_description); 5 added
trials.path_length_m; 6 added maps.metrics_code (the identity of the code that computed the map's metrics,
pbdyn.metrics.cached.metrics_code). Older stores are read as they are (a column they lack reads as
NULL) and upgraded in place when `pbdyn batch` writes to them (ResultsStore.create adds the missing columns); a
store from a newer schema is refused.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import sqlite3
import time
import typing
from collections.abc import Iterable, Sequence
from pathlib import Path

from pbdyn.errors import NAME_MAX, ConfigError, check_path_length
from pbdyn.sim.result import TrialResult

SCHEMA_VERSION = 6

MAP_COLUMNS = ("map_id", "map_index", "map_key", "setup_json", "seed", "rollout_key", "dataset",
               "mean_obstacle_speed", "mean_obstacle_radius", "metrics_json", "metric_times_json", "backend",
               "metrics_code")
"""The maps table's columns (schema 6)."""

WORLD_FINGERPRINT_CHARS = 16
"""A row's world fingerprint: this many leading hex digits of its map's rollout key."""

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
    metrics_json TEXT, metric_times_json TEXT, backend TEXT, metrics_code TEXT);
CREATE TABLE IF NOT EXISTS trials (trial_key TEXT PRIMARY KEY, {", ".join(_column_sql(*c) for c in TRIAL_COLUMNS)},
    error TEXT, result_json TEXT NOT NULL, finished REAL, world_fingerprint TEXT);
CREATE INDEX IF NOT EXISTS trials_map ON trials (map_id);
"""


def _cell(value, as_json: bool = False):
    if value is not None and (as_json or isinstance(value, (list, tuple, dict))):
        return json.dumps(value, sort_keys=True)
    return value


LOCK_TIMEOUT_S = 30.0

_PBDYN_TABLES = {"meta", "runs", "maps", "trials", "sqlite_sequence"}


def store_error(field: str, exc: BaseException, path) -> ConfigError:
    """The one-line ConfigError naming ``field`` for an SQLite (or row decoding) failure on the store ``path``."""
    text = " ".join(str(exc).split())
    low = text.lower()
    if "database or disk is full" in low or "disk is full" in low:
        problem = ("the disk is full (SQLite: database or disk is full); the trials committed so far are kept: free "
                   "space and re-run the same command to resume")
    elif "readonly" in low or "read-only" in low:
        problem = ("is read-only (the file or its folder is not writable; SQLite also writes -wal and -shm files "
                   "beside it); make both writable or use another `out` file")
    elif "locked" in low or "busy" in low:
        problem = (f"is locked by another process for more than {LOCK_TIMEOUT_S:g} s (another batch writing it?); "
                   "wait for it or use another file")
    elif "unable to open" in low:
        problem = "cannot be opened as a file (a folder, or a folder on its path is missing or not accessible)"
    elif "disk i/o" in low:
        problem = "gives disk I/O errors (a failing disk, a removed drive, or a network file system?)"
    elif isinstance(exc, (ValueError, UnicodeError)) or "malformed" in low or "not a database" in low \
            or "decode" in low or "corrupt" in low or "quick_check" in low:
        problem = (f"is damaged ({text[:160]}); restore it from a backup, or `sqlite3 FILE .recover` what is left "
                   "into a new file")
    else:
        problem = f"cannot be used as a results store ({type(exc).__name__}: {text[:160]})"
    return ConfigError(field, problem, str(path))


def _guarded(method):
    """Report SQLite failures and undecodable rows of a store method as store_error (naming the store's field)."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except (sqlite3.DatabaseError, UnicodeError, json.JSONDecodeError) as exc:
            raise store_error(self.field, exc, self.path) from None
    return wrapper


def _quick_check(conn: sqlite3.Connection) -> None:
    row = conn.execute("PRAGMA quick_check(1)").fetchone()
    if not row or row[0] != "ok":
        raise sqlite3.DatabaseError(f"quick_check: {row[0] if row else 'no answer'}")


def read_only_uri(p: Path, field: str = "RESULTS", shown=None) -> str:
    """The SQLite URI that opens the store file ``p`` read-only: mode=ro; in a folder this user cannot write
    (read-only media, another user's folder) and without a -shm file -- which SQLite would have to create to read a
    WAL-mode file -- mode=ro&immutable=1, unless a -wal or -journal file beside it holds changes the file lacks
    (ConfigError naming ``field``: reading the file alone would miss them)."""
    uri = f"{p.absolute().as_uri()}?mode=ro"
    if os.access(p.absolute().parent, os.W_OK) or os.path.exists(f"{p}-shm"):
        return uri
    for side in ("-wal", "-journal"):
        if os.path.exists(f"{p}{side}") and os.path.getsize(f"{p}{side}") > 0:
            raise ConfigError(field, f"is in a folder this user cannot write, beside a {side} file with changes not "
                              f"yet in the store file (SQLite needs a writable folder to apply them); open it once "
                              f"where its folder is writable, or copy it with its {side} file to a writable folder",
                              str(p if shown is None else shown))
    return uri + "&immutable=1"


SIDE_FILE = "-journal"
"""The longest suffix SQLite appends to a store's name for its side files (-journal, -wal, -shm)."""


def check_store_path(path, field: str = "out") -> Path:
    """``path`` as a Path a store can be written at: not a folder, its folder an existing or creatable folder (no
    file on the way), names within the file system's limits; ConfigError naming ``field`` otherwise. Creates
    nothing."""
    p = Path(path)
    check_path_length(field, p)
    if len(os.fsencode(p.name)) + len(SIDE_FILE) > NAME_MAX:
        raise ConfigError(field, f"has a name of {len(os.fsencode(p.name))} bytes; SQLite writes {p.name[:20]}..."
                          f"{SIDE_FILE} beside it, so a store's name may have at most {NAME_MAX - len(SIDE_FILE)}",
                          str(path))
    if p.is_dir():
        raise ConfigError(field, "is a folder; give a file name for the results store", str(path))
    parent = p.absolute().parent
    for anc in (parent, *parent.parents):
        if anc.exists():
            if not anc.is_dir():
                raise ConfigError(field, f"cannot be created: {anc} is a file, not a folder", str(path))
            if not os.access(anc, os.W_OK | os.X_OK) and (anc == parent or not parent.exists()):
                raise ConfigError(field, f"cannot be written: the folder {anc} is not writable", str(path))
            break
    if p.exists() and not os.access(p, os.R_OK | os.W_OK):
        raise ConfigError(field, "is read-only (not writable by this user); make it writable or use another `out` "
                          "file", str(path))
    return p


class ResultsStore:
    """A results store (see the module docstring). Open with ResultsStore.create or ResultsStore.open."""

    def __init__(self, path: Path, conn: sqlite3.Connection, field: str = "RESULTS", writable: bool = False):
        self.path = path
        self.conn = conn
        self.field = field
        self.writable = writable

    # ------------------------------------------------------------------------------------------- opening
    @classmethod
    def create(cls, path: str | Path, field: str = "out") -> "ResultsStore":
        """Open ``path`` for writing, creating the file and tables if needed (WAL journal, synchronous NORMAL);
        the file is checked (quick_check) first. Failures are ConfigErrors naming ``field``."""
        p = check_store_path(path, field)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(field, f"its folder cannot be created ({exc.strerror})", str(path)) from None
        existed = p.exists()
        conn = None
        try:
            conn = sqlite3.connect(p.absolute().as_uri(), uri=True, timeout=LOCK_TIMEOUT_S)
            if existed:
                _quick_check(conn)
            store = cls(p, conn, field, writable=True)
            version = store._schema_version()
            if version is not None and version > SCHEMA_VERSION:
                raise ConfigError(field, f"was written by schema version {version}; this pbdyn reads versions up "
                                  f"to {SCHEMA_VERSION} (use a newer pbdyn or a new `out` file)", str(path))
            if version is None and store._foreign_tables():
                raise ConfigError(field, "is an SQLite file but not a pbdyn results store (use a new `out` file)",
                                  str(path))
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=NORMAL")
            conn.executescript(_SCHEMA)
            have = store._trial_table_columns()
            with conn:   # upgrade an older store in one transaction: add the columns it lacks, then the version
                for name, sql_type in (*TRIAL_COLUMNS, ("world_fingerprint", "TEXT")):
                    if name not in have:
                        conn.execute(f"ALTER TABLE trials ADD COLUMN {_column_sql(name, sql_type)}")
                if "metrics_code" not in store._map_table_columns():
                    conn.execute("ALTER TABLE maps ADD COLUMN metrics_code TEXT")
                conn.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            return store
        except BaseException as exc:
            if conn is not None:
                conn.close()
            if not existed:                     # leave no new (empty) store behind
                for suffix in ("", "-wal", "-shm", "-journal"):
                    Path(str(p) + suffix).unlink(missing_ok=True)
            if isinstance(exc, sqlite3.DatabaseError):
                raise store_error(field, exc, path) from None
            raise

    @classmethod
    def open(cls, path: str | Path, field: str = "RESULTS") -> "ResultsStore":
        """Open an existing store read-only (checked with quick_check); ConfigError naming ``field`` if it is
        missing, not a store, damaged, unreadable, or from a newer schema."""
        p = Path(path)
        check_path_length(field, p)
        if p.is_dir():
            raise ConfigError(field, "is a folder, not a results store file", str(path))
        if not p.is_file():
            raise ConfigError(field, "file not found", str(path))
        conn = None
        try:
            conn = sqlite3.connect(read_only_uri(p, field, path), uri=True, timeout=LOCK_TIMEOUT_S)
            _quick_check(conn)
            store = cls(p, conn, field)
            version = store._schema_version()
        except sqlite3.DatabaseError as exc:
            if conn is not None:
                conn.close()
            if "not a database" in str(exc):
                raise ConfigError(field, "is not a pbdyn results store (SQLite)", str(path)) from None
            raise store_error(field, exc, path) from None
        if version is None:
            conn.close()
            raise ConfigError(field, "is not a pbdyn results store (no schema version)", str(path))
        if version > SCHEMA_VERSION:
            conn.close()
            raise ConfigError(field, f"was written by schema version {version}; this pbdyn reads versions up to "
                              f"{SCHEMA_VERSION}", str(path))
        return store

    def _foreign_tables(self) -> set[str]:
        return {r[0] for r in self.conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")} \
            - _PBDYN_TABLES

    def _trial_table_columns(self) -> set[str]:
        return {r[1] for r in self.conn.execute("PRAGMA table_info(trials)")}

    def _map_table_columns(self) -> set[str]:
        return {r[1] for r in self.conn.execute("PRAGMA table_info(maps)")}

    def _schema_version(self) -> int | None:
        try:
            row = self.conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        except sqlite3.OperationalError:
            return None
        return int(row[0]) if row else None

    def close(self) -> None:
        """Commit and close. A store opened for writing is left in rollback-journal mode (one file at rest: readers
        then create no -wal/-shm files beside it, and can read it from a read-only folder); if another connection
        still has it open, it stays in WAL mode until the last writer closes."""
        try:
            self.conn.commit()
            if self.writable:
                try:
                    self.conn.execute("PRAGMA journal_mode=DELETE")
                except sqlite3.OperationalError:   # another connection holds it: WAL stays, nothing is lost
                    pass
        except sqlite3.DatabaseError as exc:
            raise store_error(self.field, exc, self.path) from None
        finally:
            self.conn.close()

    @_guarded
    def stored_states(self, keys: Sequence[str]) -> dict[str, tuple[str | None, str | None, str | None]]:
        """trial key -> (planner_label, planner_fingerprint, outcome) of those of ``keys`` that are stored."""
        fp = "planner_fingerprint" if "planner_fingerprint" in self._columns() else "NULL"
        out = {}
        for i in range(0, len(keys), 500):
            chunk = list(keys[i:i + 500])
            sql = (f"SELECT trial_key, planner_label, {fp}, outcome FROM trials WHERE trial_key IN "
                   f"({', '.join('?' * len(chunk))})")
            out.update({r[0]: (r[1], r[2], r[3]) for r in self.conn.execute(sql, chunk)})
        return out

    @_guarded
    def fingerprint_counts(self) -> list[tuple[str | None, str | None, int]]:
        """(planner_label, planner_fingerprint, number of stored trials) of every stored combination."""
        fp = "planner_fingerprint" if "planner_fingerprint" in self._columns() else "NULL"
        return [(r[0], r[1], int(r[2])) for r in self.conn.execute(
            f"SELECT planner_label, {fp}, COUNT(*) FROM trials GROUP BY planner_label, {fp} ORDER BY 1, 2")]

    def _columns(self) -> set[str]:
        cols = getattr(self, "_cols", None)
        if cols is None:
            cols = self._cols = self._trial_table_columns()
        return cols

    # ------------------------------------------------------------------------------------------- meta and runs
    @_guarded
    def get_meta(self, key: str) -> str | None:
        """A meta value, or None."""
        row = self.conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return row[0] if row else None

    @_guarded
    def set_meta(self, key: str, value: str) -> None:
        """Set a meta value (committed)."""
        self.conn.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))
        self.conn.commit()

    @_guarded
    def start_run(self, version: str, scenario_json: str, command: str, workers: str) -> int:
        """Record the start of a batch run; returns its id."""
        cur = self.conn.execute("INSERT INTO runs (started, version, scenario_json, command, workers) "
                                "VALUES (?, ?, ?, ?, ?)", (time.time(), version, scenario_json, command, workers))
        self.conn.commit()
        return int(cur.lastrowid)

    @_guarded
    def end_run(self, run_id: int) -> None:
        """Record the end of a batch run."""
        self.conn.execute("UPDATE runs SET ended = ? WHERE id = ?", (time.time(), run_id))
        self.conn.commit()

    # ------------------------------------------------------------------------------------------- rows
    @_guarded
    def error_count(self) -> int:
        """Number of stored trials whose outcome is "error"."""
        return int(self.conn.execute("SELECT COUNT(*) FROM trials WHERE outcome = 'error'").fetchone()[0])

    @_guarded
    def maps_with_metrics(self) -> set[str]:
        """Map ids whose metrics are stored."""
        return {r[0] for r in self.conn.execute("SELECT map_id FROM maps WHERE metrics_json IS NOT NULL")}

    @_guarded
    def add_trials(self, rows: Iterable[tuple[str, dict, str | None]], replace: bool = False,
                   world: str | None = None) -> int:
        """Insert (trial_key, TrialResult dict, error message or None) rows; keys already stored are kept
        (INSERT OR IGNORE), or with ``replace`` replaced row by row (INSERT OR REPLACE: re-flown trials).
        ``world``: the rows' world fingerprint (WORLD_FINGERPRINT_CHARS hex digits of their map's rollout key). No
        commit (the coordinator batches commits). Returns the number of rows given."""
        names = [n for n, _ in TRIAL_COLUMNS]
        sql = (f"INSERT OR {'REPLACE' if replace else 'IGNORE'} INTO trials (trial_key, {', '.join(names)}, error, "
               f"result_json, finished, world_fingerprint) VALUES ({', '.join('?' * (len(names) + 5))})")
        batch = [(key, *[_cell(res.get(n), n in _JSON_COLUMNS) for n in names], err,
                  json.dumps(res, sort_keys=True), time.time(), world) for key, res, err in rows]
        self.conn.executemany(sql, batch)
        return len(batch)

    @_guarded
    def world_fingerprints(self, by: str = "map_id") -> dict[str, dict[str, int]]:
        """map_id (or, ``by`` "map_key", map key: the map's place in its scenario, which an edit of its world keeps
        while its id changes) -> {world fingerprint: stored trials} of every map with trials or a maps row: the
        trials' recorded fingerprints ("" where a row predates schema 4) and the maps row's rollout key (cut to
        WORLD_FINGERPRINT_CHARS; counted 0 trials). Counted in SQL: no trial key is read."""
        if by not in ("map_id", "map_key"):
            raise ValueError(f"by must be map_id or map_key, not {by!r}")
        out: dict[str, dict[str, int]] = {}
        fp = "world_fingerprint" if "world_fingerprint" in self._columns() else "NULL"
        for mid, f, n in self.conn.execute(f"SELECT {by}, {fp}, COUNT(*) FROM trials GROUP BY 1, 2"):
            out.setdefault(mid, {})[f or ""] = int(n)
        for mid, key in self.conn.execute(f"SELECT {by}, rollout_key FROM maps WHERE rollout_key IS NOT NULL"):
            out.setdefault(mid, {}).setdefault(key[:WORLD_FINGERPRINT_CHARS], 0)
        return out

    @_guarded
    def metric_codes(self) -> dict[str, str]:
        """map_id -> the code identity its stored metrics were computed by (maps with metrics and a recorded code:
        stores before schema 6 recorded none)."""
        if "metrics_code" not in self._map_table_columns():
            return {}
        return dict(self.conn.execute("SELECT map_id, metrics_code FROM maps WHERE metrics_json IS NOT NULL "
                                      "AND metrics_code IS NOT NULL"))

    @_guarded
    def map_keys(self) -> dict[str, int]:
        """map key -> map index of every map with trials or a maps row."""
        out = {r[0]: int(r[1]) for r in self.conn.execute("SELECT map_key, map_index FROM maps "
                                                          "WHERE map_index IS NOT NULL AND map_key IS NOT NULL")}
        out.update({r[0]: int(r[1]) for r in self.conn.execute("SELECT map_key, MIN(map_index) FROM trials WHERE "
                                                               "map_index IS NOT NULL AND map_key IS NOT NULL "
                                                               "GROUP BY map_key")})
        return out

    @_guarded
    def map_indices(self) -> dict[str, int]:
        """map_id -> map index of every map with trials or a maps row."""
        out = {r[0]: int(r[1]) for r in self.conn.execute("SELECT map_id, map_index FROM maps "
                                                          "WHERE map_index IS NOT NULL")}
        out.update({r[0]: int(r[1]) for r in self.conn.execute("SELECT map_id, MIN(map_index) FROM trials "
                                                               "WHERE map_index IS NOT NULL GROUP BY map_id")})
        return out

    @_guarded
    def drop_maps(self, map_ids: Iterable[str], by: str = "map_id") -> int:
        """Delete every trial row and the maps row of ``map_ids`` (``by`` "map_key": of those map keys; their world
        changed: `pbdyn batch --rerun-changed` flies them again); no commit. Returns the number of trial rows
        deleted."""
        if by not in ("map_id", "map_key"):
            raise ValueError(f"by must be map_id or map_key, not {by!r}")
        ids = list(map_ids)
        n = 0
        for i in range(0, len(ids), 500):
            chunk = ids[i:i + 500]
            marks = ", ".join("?" * len(chunk))
            n += self.conn.execute(f"DELETE FROM trials WHERE {by} IN ({marks})", chunk).rowcount
            self.conn.execute(f"DELETE FROM maps WHERE {by} IN ({marks})", chunk)
        return n

    @_guarded
    def add_map(self, row: dict) -> None:
        """Insert or replace a map row (keys as the maps table's columns; dicts/lists stored as JSON); no commit."""
        cols = MAP_COLUMNS
        self.conn.execute(f"INSERT OR REPLACE INTO maps ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                          tuple(_cell(row.get(c)) for c in cols))

    @_guarded
    def commit(self) -> None:
        """Commit pending rows."""
        self.conn.commit()

    @_guarded
    def trial_rows(self, columns: Sequence[str] | None = None) -> tuple[list[str], list[tuple]]:
        """(column names, rows) of the trials table, ordered by trial key (trial_key, TRIAL_COLUMNS, error by
        default); a column an older store lacks reads as None."""
        names = list(columns) if columns else ["trial_key"] + [n for n, _ in TRIAL_COLUMNS] + ["error"]
        have = self._trial_table_columns()
        select = ", ".join(n if n in have else f"NULL AS {n}" for n in names)
        rows = self.conn.execute(f"SELECT {select} FROM trials ORDER BY trial_key").fetchall()
        return names, rows

    @_guarded
    def results(self) -> list[dict]:
        """Every stored TrialResult dict (with "trial_key" and "error"), ordered by trial key."""
        out = []
        for key, res, err in self.conn.execute("SELECT trial_key, result_json, error FROM trials "
                                               "ORDER BY trial_key"):
            d = json.loads(res)
            d["trial_key"], d["error"] = key, err
            out.append(d)
        return out

    @_guarded
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

    @_guarded
    def count(self) -> int:
        """Number of stored trials."""
        return int(self.conn.execute("SELECT COUNT(*) FROM trials").fetchone()[0])

    @_guarded
    def is_empty(self) -> bool:
        """True if the store holds no trial and no map."""
        return not any(self.conn.execute(f"SELECT 1 FROM {t} LIMIT 1").fetchone() for t in ("trials", "maps"))
