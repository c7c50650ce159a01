"""Heat maps of a map's per-sample metrics (`pbdyn metrics --plot FILE`): where on the map survivability (thesis eq.
3-6) and VO feasibility (eq. 3-4, 3-5) are low.

Each sample of the metric is drawn as a square of the sample spacing centred on its point, coloured by its value
(the metric's own per-sample values, nothing interpolated), over the arena with its static bodies and the obstacles
at the time the metric looks at (survivability: its start time; VO: its snapshot time). 3D maps get one panel per
z layer of the sample grid, obstacles drawn as their cross-sections with that layer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbdyn.errors import ConfigError, check_writable_file
from pbdyn.files import atomic_write

from pbdyn.metrics.catalog import DENSE, PER_POINT, SPARSE
FIGURE_FORMATS = (".png", ".pdf", ".svg")
DPI = 200
CMAP = "viridis"
STATIC_COLOUR = "#4d4d4d"
"""Fill colour of static bodies in the heat maps."""


@dataclass(frozen=True)
class MetricSamples:
    """One metric's samples on a map: name, sample points [n, d] (m), values [n] (the metric's per_sample), the
    metric's value (their mean), its unit, the colour scale (lo, hi) and the time (s) the obstacles are drawn at."""

    name: str
    points: np.ndarray
    values: np.ndarray
    value: float
    unit: str
    scale: tuple[float, float]
    time: float
    spacing: float


def metric_samples(scenario, rollout, name: str, backend: str) -> MetricSamples:
    """Compute ``name`` on ``rollout`` with the parameters of the scenario's map metrics and return its samples."""
    from pbdyn.metrics.cached import run_metric
    from pbdyn.metrics.catalog import INFO
    from pbdyn.metrics.survivability import base_points, split_static

    res = run_metric(scenario, rollout, name, backend)
    p = res.params
    pts, _ = split_static(rollout, base_points(rollout, p.get("points"), p["spacing"], p["margin"]), p["mav_radius"])
    values = np.asarray(res.per_sample, dtype=float)
    if pts.shape[0] != values.shape[0]:    # pragma: no cover - the metric's points and values are built together
        raise RuntimeError(f"{name}: {pts.shape[0]} sample points but {values.shape[0]} values")
    survival = name.startswith("survivability")
    scale = (0.0, float(p["t_max"])) if survival else (0.0, 1.0)
    time = float(p.get("start_time", 0.0)) if survival else float(p.get("time", 0.0))
    unit = INFO[name].unit
    return MetricSamples(name, pts, values, float(res.value), unit, scale, time, float(p["spacing"]))


@dataclass(frozen=True)
class HeatmapFigure:
    """A written heat-map figure: its path, the matplotlib Figure and, per panel, (metric name, z layer or None,
    Axes) -- the axes map data (m) to the figure's pixels."""

    path: Path
    figure: object
    panels: list


def plot_heatmaps(rollout, samples: list[MetricSamples], out: str | Path, *, title: str = "") -> HeatmapFigure:
    """Draw every metric's samples (one row of panels each; 3D: a panel per z layer) into ``out`` (.png at
    DPI dots per inch, .pdf or .svg), atomically."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    out = Path(out)
    suffix = out.suffix.lower()
    d = rollout.dims
    layers = [None] if d == 2 else sorted({round(float(z), 9) for s in samples for z in s.points[:, 2]})
    fig = Figure(figsize=(4.6 * len(layers), 4.2 * len(samples)), dpi=DPI)
    FigureCanvasAgg(fig)
    size = np.asarray(rollout.arena_size, dtype=float)
    axes_out = []
    for row, s in enumerate(samples):
        norm = Normalize(*s.scale)
        pos = rollout.at(rollout.step_index(s.time))[0]
        for col, z in enumerate(layers):
            ax = fig.add_subplot(len(samples), len(layers), row * len(layers) + col + 1)
            axes_out.append((s.name, z, ax))
            keep = np.ones(s.points.shape[0], dtype=bool) if z is None else np.isclose(s.points[:, 2], z)
            h = s.spacing / 2.0
            lo = np.maximum(s.points[keep, :2] - h, 0.0)                  # squares clipped to the arena
            hi = np.minimum(s.points[keep, :2] + h, size[:2])
            rects = [Rectangle((a[0], a[1]), b[0] - a[0], b[1] - a[1]) for a, b in zip(lo, hi)]
            coll = PatchCollection(rects, cmap=CMAP, norm=norm, edgecolors="none", zorder=1)
            coll.set_array(s.values[keep])
            ax.add_collection(coll)
            for body in rollout.static:
                _static_patch(ax, body)
            _imported_statics(ax, rollout, z)
            r = np.asarray(rollout.radii, dtype=float)
            for i in range(pos.shape[0]):
                rad = r[i] if z is None else math.sqrt(max(r[i] ** 2 - (pos[i, 2] - z) ** 2, 0.0))
                if rad > 0:
                    ax.add_patch(Circle((pos[i, 0], pos[i, 1]), rad, fc="none", ec="white", lw=1.4, zorder=3))
            ax.add_patch(Rectangle((0.0, 0.0), size[0], size[1], fill=False, ec="black", lw=1.5, zorder=4))
            ax.set_xlim(-1.0, size[0] + 1.0)
            ax.set_ylim(-1.0, size[1] + 1.0)
            ax.set_aspect("equal")
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
            layer = "" if z is None else f", z = {z:g} m"
            unit = "" if s.unit == "1" else f" {s.unit}"
            ax.set_title(f"{_label(s.name)}{layer}\nmean {s.value:.3g}{unit}, obstacles at t = {s.time:g} s",
                         fontsize=9)
            cb = fig.colorbar(coll, ax=ax, fraction=0.046, pad=0.03)
            cb.set_label(_colour_label(s.name))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    atomic_write(out, lambda tmp: fig.savefig(tmp, dpi=DPI, format=suffix[1:]))
    return HeatmapFigure(out, fig, axes_out)


def _label(name: str) -> str:
    from pbdyn.metrics.catalog import INFO

    return INFO[name].label


def _colour_label(name: str) -> str:
    return "survival time of a static MAV (s)" if name.startswith("survivability") else \
        "share of velocities outside every velocity obstacle"


def _static_patch(ax, body) -> None:
    from matplotlib.patches import Circle, Polygon

    c = np.asarray(body.center, dtype=float)
    if body.kind == "pillar":
        ax.add_patch(Circle((c[0], c[1]), float(body.radius), fc=STATIC_COLOUR, zorder=2))
        return
    sx, sy = np.asarray(body.size, dtype=float)[:2] / 2.0
    rot = np.array([[math.cos(body.yaw), -math.sin(body.yaw)], [math.sin(body.yaw), math.cos(body.yaw)]])
    corners = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) @ rot.T + c[:2]
    ax.add_patch(Polygon(corners, closed=True, fc=STATIC_COLOUR, zorder=2))


IMPORTED_CELL_M = 0.1
"""Resolution (m) at which an imported world's still bodies are drawn (their cut by the panel's plane)."""


def _imported_statics(ax, rollout, z: float | None) -> None:
    """Fill the cut of an imported world's still bodies by the panel's plane (2D: the flight plane; 3D: layer z),
    where their real shapes' signed distance is <= 0 on a IMPORTED_CELL_M grid, in the static bodies' grey."""
    bodies = getattr(rollout, "bodies", None)
    still = [] if bodies is None else np.flatnonzero(~bodies.moving).tolist()
    if not still:
        return
    from matplotlib.colors import ListedColormap

    size = np.asarray(rollout.arena_size, dtype=float)
    xs = np.arange(0.5 * IMPORTED_CELL_M, size[0], IMPORTED_CELL_M)
    ys = np.arange(0.5 * IMPORTED_CELL_M, size[1], IMPORTED_CELL_M)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    height = float(rollout.meta.get("flight_height", 2.0)) if z is None else float(z)
    q = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)], axis=1)
    field = bodies.field()
    inside = np.zeros(gx.size, dtype=bool)
    for b in still:
        inside |= field.body_distance(b, q, 0) <= 0.0
    if inside.any():
        ax.imshow(np.where(inside.reshape(gx.shape), 1.0, np.nan), origin="lower", extent=(0.0, size[0], 0.0, size[1]),
                  cmap=ListedColormap([STATIC_COLOUR]), vmin=0.0, vmax=1.0, interpolation="nearest", zorder=2)


def heatmap_metrics(requested: list[str] | None, dense: bool) -> list[str]:
    """The metrics `pbdyn metrics --plot` draws: the requested ones that have per-point samples (default:
    survivability and VO feasibility, the dense variants with --dense); ConfigError naming --plot if none."""
    if not requested:
        sparse = [n for n in SPARSE if n in PER_POINT]
        return [DENSE.get(n, n) for n in sparse] if dense else sparse
    names = [DENSE.get(n, n) if dense else n for n in requested]
    chosen = [n for n in names if n in PER_POINT]
    if not chosen:
        raise ConfigError("plot", f"draws per-sample maps of {', '.join(PER_POINT)}; none of them was asked "
                          "for with `metric`", ", ".join(requested))
    return chosen


def check_figure_path(out: str | Path, field: str = "plot") -> Path:
    """``out`` as a Path ending in .png, .pdf or .svg that can be written in an existing folder
    (pbdyn.errors.check_writable_file); ConfigError naming ``field``."""
    p = Path(out)
    if p.suffix.lower() not in FIGURE_FORMATS:
        raise ConfigError(field, f"must end in {', '.join(FIGURE_FORMATS)}", str(out))
    return check_writable_file(field, out)
