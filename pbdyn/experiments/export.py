"""A results store's trials as one table (pandas), and `pbdyn export` of it as CSV or Parquet.

The table: one row per trial ordered by trial key; trial_key, then the store's trial columns in TrialResult field
order (Table 2-2 first) with start and goal as numeric columns (start_x, start_y[, start_z], goal_x, ...), then
error, then one ``metric_<name>`` column per map metric in the store (joined on map_id; NaN where a map has no
value). Integer columns are int64 (nullable Int64 where error rows leave them empty), real columns float64;
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
from pbdyn.experiments.store import TRIAL_COLUMNS, ResultsStore

_AXES = "xyz"


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


def trials_frame(store: ResultsStore | str | Path):
    """Every trial of ``store`` (a ResultsStore or a store path) as a pandas DataFrame (see the module docstring)."""
    import pandas as pd

    if not isinstance(store, ResultsStore):
        opened = ResultsStore.open(store)
        try:
            return trials_frame(opened)
        finally:
            opened.close()
    names, rows = store.trial_rows()
    columns = {n: [r[i] for r in rows] for i, n in enumerate(names)}
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
    maps = store.maps()
    metric_names = sorted({k for m in maps.values() for k in m["metrics"]})
    for metric in metric_names:
        per_map = {mid: m["metrics"].get(metric) for mid, m in maps.items()}
        data[f"metric_{metric}"] = pd.array([math.nan if per_map.get(mid) is None else float(per_map[mid])
                                             for mid in columns["map_id"]], dtype="float64")
    return pd.DataFrame(data)


def _atomic(path: Path, write) -> None:
    """Write ``path`` through a temporary file in its folder (pbdyn.files.atomic_write): a failed export leaves no
    partial file."""
    atomic_write(path, write, make_parents=True)


def export_csv(store: ResultsStore, path: str | Path) -> int:
    """Write trials_frame(store) to a CSV file (header = column names; empty cells for missing values); returns
    the number of rows. Written atomically."""
    df = trials_frame(store)
    _atomic(Path(path), lambda tmp: df.to_csv(tmp, index=False))
    return len(df)


def export_parquet(store: ResultsStore, path: str | Path) -> int:
    """Write trials_frame(store) to a Parquet file (pyarrow); returns the number of rows. Written atomically."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        raise ConfigError("parquet", "needs pyarrow (pip install pyarrow)", str(path)) from None
    df = trials_frame(store)
    _atomic(Path(path), lambda tmp: df.to_parquet(tmp, index=False, engine="pyarrow"))
    return len(df)
