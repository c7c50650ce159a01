"""A results store's trials as one table (pandas), and `pbdyn export` of it as CSV or Parquet.

The table: one row per trial ordered by trial key; trial_key, then the store's trial columns in TrialResult field
order (Table 2-2 first; path_length_m, m, among them) with start and goal as numeric columns (start_x,
start_y[, start_z], goal_x, ...), then error, then the DERIVED columns (path_ratio: path_length_m over the
straight-line distance from the start to the goal ball, |goal - start| - goal radius; wall_planning_median_s, wall_planning_p99_s: the median and 99th percentile
over the trial's steps of the planner's wall time per step, s, from the row's result JSON), then one
``metric_<name>`` column per map metric in the store (joined on map_id; NaN where a map has no value). Integer
columns are int64 (nullable Int64 where error rows leave them empty), real columns float64 (NaN where a value is
missing: error rows, stores written before the field existed, a start inside the goal ball for path_ratio);
obstacle_radius and obstacle_speed are float64 when every value is a number, else JSON text ({"min", "max"}
ranges).
"""

from __future__ import annotations

import json
import math
from numbers import Number
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.files import atomic_write
from pbdyn.experiments.store import TRIAL_COLUMNS, ResultsStore, store_error

_AXES = "xyz"

RESULT_JSON_COLUMNS = ("wall_planning_median_s", "wall_planning_p99_s")
"""Columns read from each row's result JSON (s; NaN where a row lacks them: stores written before them)."""

DERIVED = ("path_ratio", *RESULT_JSON_COLUMNS)
"""The columns after error, in order (see the module docstring)."""


def _store_dims(store: ResultsStore, vectors: list[list]) -> int:
    raw = store.get_meta("scenario")
    dims = (json.loads(raw).get("world") or {}).get("dims") if raw else None
    longest = max((len(v) for v in vectors), default=0)
    return max(int(dims or 2), longest)


def _vectors(values) -> list[list]:
    return [json.loads(v) if isinstance(v, str) and v else [] for v in values]


def _numbers_or_text(values: list):
    """float column values if every non-null JSON value is a number, else the JSON text unchanged."""
    decoded = [json.loads(v) if isinstance(v, str) else v for v in values]
    if all(v is None or (isinstance(v, Number) and not isinstance(v, bool)) for v in decoded):
        return [math.nan if v is None else float(v) for v in decoded], True
    return values, False


def _float_or_nan(v) -> float:
    return float(v) if isinstance(v, Number) and not isinstance(v, bool) else math.nan


def _result_json_columns(store: ResultsStore, raw_rows: list) -> dict[str, list[float]]:
    """RESULT_JSON_COLUMNS from the rows' result JSON texts; an undecodable row is the store's one-line error."""
    out: dict[str, list[float]] = {k: [] for k in RESULT_JSON_COLUMNS}
    for raw in raw_rows:
        try:
            doc = json.loads(raw) if raw else {}
        except (json.JSONDecodeError, UnicodeError) as exc:
            raise store_error(store.field, exc, store.path) from None
        doc = doc if isinstance(doc, dict) else {}
        for k, values in out.items():
            values.append(_float_or_nan(doc.get(k)))
    return out


def _goal_radius(store: ResultsStore) -> float:
    """The goal radius (m) of the store's scenario (task.goal_radius; the default 1 m where it is not recorded)."""
    from pbdyn.config import TaskConfig

    raw = store.get_meta("scenario")
    task = (json.loads(raw).get("task") or {}) if raw else {}
    value = task.get("goal_radius", TaskConfig.goal_radius)
    return float(value) if isinstance(value, Number) and not isinstance(value, bool) else TaskConfig.goal_radius


def _path_ratio(length: list, starts: list[list], goals: list[list], goal_radius: float) -> list[float]:
    """path_length_m over the straight-line distance from the start to the goal ball (|goal - start| - goal_radius)
    per row; NaN where a value is missing or that distance is not positive."""
    out = []
    for n, s, g in zip(length, starts, goals):
        dist = math.dist(s, g) - goal_radius if s and g and len(s) == len(g) else 0.0
        out.append(float(n) / dist if n is not None and dist > 0.0 else math.nan)
    return out


def trials_frame(store: ResultsStore | str | Path):
    """Every trial of ``store`` (a ResultsStore or a store path) as a pandas DataFrame (see the module docstring)."""
    import pandas as pd

    if not isinstance(store, ResultsStore):
        opened = ResultsStore.open(store)
        try:
            return trials_frame(opened)
        finally:
            opened.close()
    names, rows = store.trial_rows(["trial_key", *(n for n, _ in TRIAL_COLUMNS), "error", "result_json"])
    columns = {n: [r[i] for r in rows] for i, n in enumerate(names)}
    names = names[:-1]
    from_json = _result_json_columns(store, columns.pop("result_json"))
    types = dict(TRIAL_COLUMNS)
    vectors = {k: _vectors(columns[k]) for k in ("start", "goal")}
    dims = _store_dims(store, vectors["start"] + vectors["goal"])
    data: dict[str, object] = {}
    for name in names:
        values = columns[name]
        if name in vectors:
            for i in range(dims):
                data[f"{name}_{_AXES[i]}"] = pd.array([float(v[i]) if len(v) > i else math.nan
                                                       for v in vectors[name]], dtype="float64")
        elif types.get(name) == "INTEGER":
            data[name] = pd.array(values, dtype="Int64" if None in values else "int64")
        elif types.get(name) == "REAL":
            data[name] = pd.array([math.nan if v is None else float(v) for v in values], dtype="float64")
        elif types.get(name) == "JSON":
            values, numeric = _numbers_or_text(values)
            data[name] = pd.array(values, dtype="float64" if numeric else object)
        else:
            data[name] = pd.array(values, dtype=object)
    data["path_ratio"] = pd.array(_path_ratio(columns["path_length_m"], vectors["start"], vectors["goal"],
                                                  _goal_radius(store)),
                                  dtype="float64")
    for name, values in from_json.items():
        data[name] = pd.array(values, dtype="float64")
    maps = store.maps()
    metric_names = sorted({k for m in maps.values() for k in m["metrics"]})
    for metric in metric_names:
        per_map = {mid: m["metrics"].get(metric) for mid, m in maps.items()}
        data[f"metric_{metric}"] = pd.array([math.nan if per_map.get(mid) is None else float(per_map[mid])
                                             for mid in columns["map_id"]], dtype="float64")
    return pd.DataFrame(data)


def export_csv(store: ResultsStore, path: str | Path) -> int:
    """Write trials_frame(store) to a CSV file (header = column names; empty cells for missing values); returns
    the number of rows. Written atomically (pbdyn.files.atomic_write: a failed export leaves no partial file)."""
    df = trials_frame(store)
    atomic_write(path, lambda tmp: df.to_csv(tmp, index=False), make_parents=True)
    return len(df)


def export_parquet(store: ResultsStore, path: str | Path) -> int:
    """Write trials_frame(store) to a Parquet file (pyarrow); returns the number of rows. Written atomically."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        raise ConfigError("parquet", "needs pyarrow (pip install pyarrow)", str(path)) from None
    df = trials_frame(store)
    atomic_write(path, lambda tmp: df.to_parquet(tmp, index=False, engine="pyarrow"), make_parents=True)
    return len(df)
