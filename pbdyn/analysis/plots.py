"""Figures of an evaluation (matplotlib, Agg canvas; no pyplot state), each as PNG (DPI dots per inch), PDF and SVG:
metric vs success per planner pair with 1-sigma bands (thesis figs 4-5..4-12), success/deadlock vs survivability
per trajectory and per gaze planner (figs 5-9, 5-10), success vs the velocity ratio v_obs / v_max (fig 5-14).
Controlled-dataset maps only. Axis labels are words with units; the thesis' figure and equation numbers are in
the README, not on the figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pbdyn.analysis.bands import band_curve
from pbdyn.analysis.cv import LEVELS, difficulty_level, level_stats
from pbdyn.analysis.figure_tables import figure_tables
from pbdyn.analysis.regression import setup_features
from pbdyn.analysis.report import difficulty_table
from pbdyn.analysis.success import grouped_rate, success_table, trial_arrays
from pbdyn.errors import ConfigError
from pbdyn.outcome import Outcome

_CENTRES = np.arange(LEVELS) + 0.5


DPI = 200
"""Resolution of the PNG figures (dots per inch)."""
FORMATS = ("png", "pdf", "svg")
_NO_TOOL_STAMP = {"png": {"Software": None}, "pdf": {"Creator": None}, "svg": {"Creator": None}}
"""savefig metadata leaving out matplotlib's version stamp (the files depend on the data only)."""


def _figure(w: float = 7.0, h: float = 4.5, ncols: int = 1) -> tuple[Figure, list]:
    fig = Figure(figsize=(w, h), layout="constrained")
    fig.set_dpi(DPI)
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(1, ncols, i + 1) for i in range(ncols)]
    return fig, axes


_SAFE = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")


def figure_name(stem: str) -> str:
    """``stem`` + ".png" as a safe file name: characters other than [A-Za-z0-9._-] become "_", no leading dots
    (scenario and metric names come from stores: "../../x" or "a/b" must not leave the plots folder), at most
    200 characters."""
    text = "".join(c if c in _SAFE else "_" for c in str(stem)).lstrip(".")
    return (text[:200] or "figure") + ".png"


def _save(fig: Figure, out_dir: Path, stem: str, out: list[Path]) -> None:
    """Save ``fig`` as out_dir/figure_name(stem) (PNG at DPI) and beside it as .pdf and .svg, never outside
    ``out_dir``; the PNG's path goes to ``out``."""
    path = out_dir / figure_name(stem)
    if path.resolve().parent != out_dir.resolve():   # pragma: no cover - figure_name cannot produce such a name
        raise ConfigError("plots", "a figure would be written outside the folder (a symbolic link there?)", str(path))
    for fmt in FORMATS:
        fig.savefig(path.with_suffix(f".{fmt}"), dpi=DPI, format=fmt, metadata=_NO_TOOL_STAMP[fmt])
    out.append(path)


def metric_label(name: str) -> str:
    """A metric's name in words (pbdyn.metrics.catalog; the setup model and other report names made readable)."""
    from pbdyn.metrics.catalog import INFO

    info = INFO.get(name)
    if info is not None:
        return info.label
    return str(name).replace("_", " ")


def _colours(n: int) -> list:
    from matplotlib import colormaps
    cmap = colormaps["tab20" if n > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(n)]


def _legend(ax, n: int) -> None:
    if n and ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7 if n > 8 else 8, ncol=2 if n > 8 else 1, loc="best")


def _metric_figure(name: str, d: np.ndarray, rate: np.ndarray, pairs: tuple[str, ...], out_dir: Path,
                   out: list[Path]) -> None:
    fig, (ax,) = _figure()
    cnt, mu, sd = level_stats(d, rate)
    for j, (pair, col) in enumerate(zip(pairs, _colours(len(pairs)))):
        ok = cnt[:, j] > 0
        if not ok.any():
            continue
        ax.scatter(d, rate[:, j], s=16, color=col, alpha=0.6, linewidths=0.3, edgecolors="white")
        ax.plot(_CENTRES[ok], mu[ok, j], "-o", ms=4, color=col, label=pair)
        ax.fill_between(_CENTRES[ok], (mu - sd)[ok, j], (mu + sd)[ok, j], color=col, alpha=0.15, linewidth=0)
    label = metric_label(name)
    ax.set(xlabel=f"difficulty by {label} (0 easiest to {LEVELS} hardest)", ylabel="success rate (share of trials)",
           xlim=(0, LEVELS), ylim=(-0.05, 1.05),
           title=f"Success rate of each map against its {label} difficulty\n(dots: maps; lines: mean +- 1 standard "
                 "deviation per level)")
    _legend(ax, len(pairs))
    _save(fig, out_dir, f"metric_{name}", out)


def _group_lines(ax, group: np.ndarray, n_groups: int, labels: tuple[str, ...], hit: np.ndarray, lev: np.ndarray,
                 keep: np.ndarray, ylabel: str) -> None:
    g = np.where(keep & (lev >= 0), group * LEVELS + lev, -1)
    p, se, n = grouped_rate(g, hit, n_groups * LEVELS)
    p, se, n = (a.reshape(n_groups, LEVELS) for a in (p, se, n))
    for i, (lab, col) in enumerate(zip(labels, _colours(n_groups))):
        ok = n[i] > 0
        if ok.any():
            ax.errorbar(_CENTRES[ok], p[i, ok], yerr=se[i, ok], fmt="-o", ms=3, capsize=2, color=col, label=lab)
    ax.set(xlabel=f"difficulty by survivability (0 easiest to {LEVELS} hardest)", ylabel=ylabel, xlim=(0, LEVELS),
           ylim=(-0.05, 1.05))
    _legend(ax, n_groups)


def _uncontrolled_figures(report: dict, band: str, d: np.ndarray, st, map_ids, maps: dict, out_dir: Path,
                          out: list[Path]) -> None:
    """uncontrolled_<dataset>.png per non-controlled dataset (figs 4-14..4-16): its (difficulty, success) points per
    pair over the controlled fit mu_j(D) +- 1 and 2 sigma_j(D) (the curves the sigma-band shares are counted
    against)."""
    fit = report["sigma_bands"]["fit"]
    mu = np.array(fit["mean"], dtype=float)
    sig = np.array(fit["sigma"], dtype=float)
    grid = np.linspace(0.0, float(LEVELS), 101)
    m_curve, s_curve = band_curve(mu, sig, grid)
    datasets = np.array([str(maps[m].get("dataset", "")) for m in map_ids])
    cols = _colours(len(st.pairs))
    for name in sorted(set(datasets.tolist()) - {report["controlled_dataset"]}):
        sel = datasets == name
        fig, axes = _figure(4.5 * len(st.pairs), 4.0, len(st.pairs))
        for j, (ax, pair) in enumerate(zip(axes, st.pairs)):
            ax.fill_between(grid, m_curve[:, j] - 2 * s_curve[:, j], m_curve[:, j] + 2 * s_curve[:, j],
                            color=cols[j], alpha=0.12, label="controlled fit +- 2 sigma")
            ax.fill_between(grid, m_curve[:, j] - s_curve[:, j], m_curve[:, j] + s_curve[:, j], color=cols[j],
                            alpha=0.25, label="+- 1 sigma")
            ax.plot(grid, m_curve[:, j], color=cols[j], label="controlled mean")
            ok = sel & np.isfinite(st.rate[:, j]) & np.isfinite(d)
            ax.scatter(d[ok], st.rate[ok, j], s=18, color="k", label=f"{name} maps")
            ax.set(xlabel=f"difficulty by {metric_label(band)} (0 easiest to {LEVELS} hardest)",
                   ylabel="success rate (share of trials)", xlim=(0, LEVELS), ylim=(-0.05, 1.05), title=pair)
            _legend(ax, 4)
        fig.suptitle(f"Maps of {name} against the controlled dataset's mean and spread")
        _save(fig, out_dir, f"uncontrolled_{name}", out)


def _rates(cells: list[dict]) -> list[float]:
    """The rates of figure_tables cells, NaN where a cell has no trials."""
    return [np.nan if c["rate"] is None else c["rate"] for c in cells]


def write_plots(trials: list[dict], maps: dict, report: dict, out_dir) -> list[Path]:
    """Write the evaluation figures into ``out_dir`` (created; each as .png at DPI, .pdf and .svg) and return the
    PNG paths:
    metric_<name>.png per report metric (figs 4-5..4-12), survivability_trajectory.png (fig 5-9),
    survivability_gaze.png (fig 5-10) and uncontrolled_<dataset>.png per non-controlled dataset (figs 4-14..4-16)
    when the report has a sigma-band metric, velocity_ratio.png (fig 5-14). File names are figure_name()s: only
    [A-Za-z0-9._-], never outside ``out_dir``.
    ``report`` is the dict from pbdyn.analysis.report.evaluate on the same trials and maps; the bars of fig 5-9
    and the ratio panel of fig 5-14 draw report["figures"] (pbdyn.analysis.figure_tables; computed here if absent)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tables = report.get("figures") or figure_tables(trials, maps, report)
    map_ids, diff = difficulty_table(maps, report)
    ta = trial_arrays(trials, map_ids)
    st = success_table(ta)
    c = np.array([str(maps[m].get("dataset", "")) == report["controlled_dataset"] for m in map_ids])
    out: list[Path] = []

    for name, d in diff.items():
        _metric_figure(name, d[c], st.rate[c], st.pairs, out_dir, out)

    on_c = c[ta.map_idx] & ta.flown
    success = ta.is_outcome(Outcome.SUCCESS)
    band = (report.get("sigma_bands") or {}).get("metric")
    if band in diff:
        lev = np.where(c, difficulty_level(diff[band]), -1)[ta.map_idx]
        nt = len(ta.trajectories)
        fig, (a1, a2) = _figure(12.0, 4.5, 2)
        _group_lines(a1, ta.trajectory_idx, nt, ta.trajectories, success, lev, on_c, "success rate (share of trials)")
        a1.set_title("success rate per trajectory planner")
        fig_5_9 = tables["fig_5_9"]
        ps = np.array([_rates(fig_5_9[lab][Outcome.SUCCESS.value]) for lab in ta.trajectories])
        pdl = np.array([_rates(fig_5_9[lab][Outcome.DEADLOCK.value]) for lab in ta.trajectories])
        n = np.array([[c["n"] for c in fig_5_9[lab][Outcome.SUCCESS.value]] for lab in ta.trajectories])
        width = 0.8 / max(nt, 1)
        for i, (lab, col) in enumerate(zip(ta.trajectories, _colours(nt))):
            ok = n[i] > 0
            x = np.arange(LEVELS)[ok] + (i + 0.5) * width + 0.1
            a2.bar(x, ps[i, ok], width, color=col, label=f"{lab} success")
            a2.bar(x, pdl[i, ok], width, bottom=ps[i, ok], color=col, alpha=0.4, hatch="//",
                   label=f"{lab} deadlock")
        a2.set(xlabel=f"difficulty by survivability (0 easiest to {LEVELS} hardest)",
               ylabel="share of trials", xlim=(0, LEVELS), ylim=(0, 1.05),
               title="success (solid) and deadlock (hatched) rates")
        _legend(a2, 2 * nt)
        fig.suptitle(f"Trajectory planners against difficulty by {metric_label(band)}")
        _save(fig, out_dir, "survivability_trajectory", out)

        fig, axes = _figure(4.5 * nt, 4.0, nt)
        for i, (ax, traj) in enumerate(zip(axes, ta.trajectories)):
            _group_lines(ax, ta.gaze_idx, len(ta.gazes), ta.gazes, success, lev, on_c & (ta.trajectory_idx == i),
                         "success rate (share of trials)")
            ax.set_title(traj)
        fig.suptitle(f"Gaze planners against difficulty by {metric_label(band)}")
        _save(fig, out_dir, "survivability_gaze", out)

    if band in diff:
        _uncontrolled_figures(report, band, diff[band], st, map_ids, maps, out_dir, out)

    v_obs = np.array([setup_features(maps[m])[2] for m in map_ids])[ta.map_idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.round(v_obs / ta.mav_speed, 3)
    keep = on_c & np.isfinite(ratio)
    fig, (a1, a2) = _figure(12.0, 4.5, 2)
    cols = _colours(len(ta.pairs))
    fig_5_14 = tables["fig_5_14"]
    for a, x, sel, xl in ((a1, ratio, None, "obstacle speed / MAV speed limit"),
                          (a2, v_obs, keep & (np.abs(ratio - 1.0) < 1e-6), "obstacle speed (m/s), where it equals "
                                                                           "the MAV's speed limit")):
        if sel is None:      # success per ratio: the numbers of pbdyn.analysis.figure_tables
            xs = np.array(fig_5_14["ratios"], dtype=float)
            rows = [fig_5_14["success"][pair] for pair in ta.pairs]
            p = np.array([_rates(r) for r in rows]).reshape(len(ta.pairs), len(xs))
            se = np.array([[np.nan if c["se"] is None else c["se"] for c in r] for r in rows]).reshape(p.shape)
            n = np.array([[c["n"] for c in r] for r in rows], dtype=np.int64).reshape(p.shape)
        else:
            xs, xi = np.unique(np.where(sel, x, np.inf), return_inverse=True)
            grp = np.where(sel, ta.pair_idx * len(xs) + xi.reshape(-1), -1)
            p, se, n = (v.reshape(len(ta.pairs), len(xs))
                        for v in grouped_rate(grp, success, len(ta.pairs) * len(xs)))
        for j, pair in enumerate(ta.pairs):
            ok = n[j] > 0
            if ok.any():
                a.errorbar(xs[ok], p[j, ok], yerr=se[j, ok], fmt="-o", ms=3, capsize=2, color=cols[j], label=pair)
        if not (n > 0).any():
            a.text(0.5, 0.5, "no trials", ha="center", va="center", transform=a.transAxes)
        a.set(xlabel=xl, ylabel="success rate (share of trials)", ylim=(-0.05, 1.05))
        _legend(a, len(ta.pairs))
    a1.set_title("success vs velocity ratio")
    a2.set_title("same ratio (1), different obstacle speeds")
    fig.suptitle("Success against the ratio of obstacle speed to MAV speed limit")
    _save(fig, out_dir, "velocity_ratio", out)
    return out
