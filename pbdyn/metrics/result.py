"""The value a metric returns: its number, its parameters and the per-sample data behind it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class MetricResult:
    """One metric on one map.

    Attributes:
        name: metric name (e.g. "survivability").
        value: the metric (units per metric: s for survivability, m for traversability, 1 for density and VO).
        params: every parameter used (JSON-able).
        n_samples: samples that entered the value; n_excluded: samples left out (e.g. overlapping static geometry).
        per_sample: the per-sample values behind the mean (read-only array; shape per metric, documented there).
        stderr: std / sqrt(n) of the per-sample values (NaN where meaningless).
        extra: further JSON-able results (e.g. the jittered-grid estimate {"values": [...], "mean", "std"}).
        wall_time_s: compute time.
    """

    name: str
    value: float
    params: dict
    n_samples: int
    n_excluded: int = 0
    per_sample: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stderr: float = float("nan")
    extra: dict = field(default_factory=dict)
    wall_time_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (per-sample data omitted)."""
        return {"name": self.name, "value": float(self.value), "params": self.params, "n_samples": int(self.n_samples),
                "n_excluded": int(self.n_excluded), "stderr": None if np.isnan(self.stderr) else float(self.stderr),
                **({"extra": self.extra} if self.extra else {}), "wall_time_s": float(self.wall_time_s)}
