"""The one table of difficulty metrics (thesis chapter 3): names, meaning, and every derived name list.

The registry (functions), the cache (default set, dense variants, backend parameter), the batch (metrics per map)
and the analysis (table 4-5 row order) all read METRIC_TABLE; nothing else lists metric names. This module
imports nothing heavy, so analysis code can use it without loading the metric implementations.
"""

from __future__ import annotations

from dataclasses import dataclass

HARDER = "higher = harder"
EASIER = "higher = easier"


@dataclass(frozen=True)
class MetricInfo:
    """One metric.

    name: registry name (and the function's name in ``module``). label, unit ("1": dimensionless), direction
    (HARDER or EASIER: how raw values relate to difficulty), equation (thesis eq.), module (implementation).
    dense: its dense-grid variant; sparse: for a dense variant, the metric it densifies. backend: takes the
    survivability ``backend`` parameter. table_row: its row in thesis table 4-5 (None: not in the table; the batch
    computes the table's metrics and the baselines per map). thesis_time_s: the table's compute time per map (s).
    baseline: a closed-form baseline that needs no simulation (pbdyn.metrics.baselines); every metric is judged
    against these (docs/design.md "Difficulty: what counts as evidence"). per_point: its per-sample values belong to
    points of the map (the sample grid), so it can be drawn as a heat map (`pbdyn metrics --plot`). horizon_s:
    the seconds of rollout it reads at its default parameters (0: the state at t = 0 only).
    """

    name: str
    label: str
    unit: str
    direction: str
    equation: str
    module: str
    dense: str | None = None
    sparse: str | None = None
    backend: bool = False
    table_row: int | None = None
    thesis_time_s: float | None = None
    baseline: bool = False
    per_point: bool = False
    horizon_s: float = 0.0


_M = "pbdyn.metrics."
METRIC_TABLE: tuple[MetricInfo, ...] = (
    MetricInfo("density", "obstacle density", "1", HARDER, "3-1", _M + "density", table_row=1, thesis_time_s=2.0),
    MetricInfo("traversability", "traversability", "m", EASIER, "3-2", _M + "traversability",
               dense="traversability_dense", table_row=2, thesis_time_s=7.0),
    MetricInfo("traversability_dense", "traversability (dense)", "m", EASIER, "3-2", _M + "traversability",
               sparse="traversability"),
    MetricInfo("dynamic_traversability", "dynamic traversability", "m", EASIER, "3-3", _M + "traversability",
               table_row=3, thesis_time_s=30.0, horizon_s=10.0),
    MetricInfo("vo_feasibility", "VO feasibility", "1", EASIER, "3-4, 3-5", _M + "vo", dense="vo_feasibility_dense",
               table_row=7, thesis_time_s=7.0, per_point=True),
    MetricInfo("vo_feasibility_dense", "VO feasibility (dense)", "1", EASIER, "3-4, 3-5", _M + "vo",
               sparse="vo_feasibility", table_row=8, thesis_time_s=15.0, per_point=True),
    MetricInfo("survivability", "survivability", "s", EASIER, "3-6", _M + "survivability",
               dense="survivability_dense", backend=True, table_row=4, thesis_time_s=20.0, per_point=True,
               horizon_s=12.0),
    MetricInfo("survivability_dense", "survivability (dense)", "s", EASIER, "3-6", _M + "survivability",
               sparse="survivability", backend=True, table_row=5, thesis_time_s=90.0, per_point=True,
               horizon_s=12.0),
    MetricInfo("global_survivability", "global survivability", "s", EASIER, "3-7", _M + "survivability",
               backend=True, table_row=6, thesis_time_s=20.0, horizon_s=44.0),
    MetricInfo("flux", "swept-area rate (baseline)", "1/s", HARDER, "-", _M + "baselines", baseline=True),
    MetricInfo("static_share", "static share (baseline)", "1", HARDER, "-", _M + "baselines", baseline=True),
)
"""Every metric, in the thesis' chapter 3 order (sparse metric, then its dense variant)."""

INFO: dict[str, MetricInfo] = {m.name: m for m in METRIC_TABLE}
NAMES: tuple[str, ...] = tuple(INFO)
SPARSE: tuple[str, ...] = tuple(m.name for m in METRIC_TABLE if m.sparse is None)
"""What `pbdyn metrics` computes by default."""
DENSE: dict[str, str] = {m.name: m.dense for m in METRIC_TABLE if m.dense}
"""Sparse metric -> its dense variant (`pbdyn metrics --dense`)."""
BACKEND_METRICS: tuple[str, ...] = tuple(m.name for m in METRIC_TABLE if m.backend)
BATCH: tuple[str, ...] = tuple(m.name for m in METRIC_TABLE if m.table_row is not None or m.baseline)
"""The metrics of thesis table 4-5 and the baselines, computed once per map by `pbdyn batch`."""
PER_POINT: tuple[str, ...] = tuple(m.name for m in METRIC_TABLE if m.per_point)
"""Metrics whose per-sample values belong to points of the map (heat maps)."""
BASELINES: tuple[str, ...] = tuple(m.name for m in METRIC_TABLE if m.baseline)
"""The closed-form baselines (pbdyn.metrics.baselines)."""
TABLE_ORDER: tuple[str, ...] = tuple(sorted((n for n in BATCH if INFO[n].table_row is not None),
                                            key=lambda n: INFO[n].table_row))
"""Row order of thesis table 4-5 (the evaluation report's order)."""
