"""`pbdyn export`: a results store's trials as CSV or Parquet, the thesis' Table 2-2 columns first."""

from __future__ import annotations

import csv
import os
import tempfile
from pathlib import Path

from pbdyn.errors import ConfigError
from pbdyn.experiments.store import ResultsStore


def _atomic(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".export-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def export_csv(store: ResultsStore, path: str | Path) -> int:
    """Write every trial row to a CSV file (header = column names; JSON text for tuples and ranges; empty cells
    for NULL); returns the number of rows. Written atomically."""
    names, rows = store.trial_rows()

    def write(tmp: str) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            w.writerows(["" if v is None else v for v in r] for r in rows)
    _atomic(Path(path), write)
    return len(rows)


def export_parquet(store: ResultsStore, path: str | Path) -> int:
    """Write every trial row to a Parquet file (pyarrow; column types from the store); returns the number of rows.
    Written atomically."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        raise ConfigError("--parquet", "needs pyarrow (pip install pyarrow)", str(path)) from None
    names, rows = store.trial_rows()
    columns = {n: [r[i] for r in rows] for i, n in enumerate(names)}
    table = pa.table(columns)
    _atomic(Path(path), lambda tmp: pq.write_table(table, tmp))
    return len(rows)
