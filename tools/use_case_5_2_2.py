"""Reproduce the thesis' use case 5-2-2 (maps with a predefined difficulty) from pbdyn's own data, without trials.

    .venv/bin/python tools/use_case_5_2_2.py [--out results/use_case_5_2_2] [--maps 5] [--count 20] [--workers 2]

1. Survivability of the controlled set's maps (scenarios/datasets/controlled_2d.toml: 27 setups x ``--maps``; the
   same maps `pbdyn batch` flies), measured with pbdyn.compute_metrics.
2. Eq. 5-1 fitted by OLS (statsmodels: coefficients, standard errors, R^2) to the raw survivability s (seconds)
   and to the survivability difficulty of eqs. 4-10, 4-11 (normalised to [0, 10] over these maps; lower
   survivability = harder), beside the thesis' table 5-4; fig_5_11.png: predicted vs measured, both scales.
3. The thesis' two requests of fig. 5-12 (difficulty 5 with n = 10; difficulty 7 with n = 25, r = 1.2 m): the
   difficulty target becomes a survivability target through the fitted normaliser, and pbdyn.generate_maps finds
   ``--count`` maps of the uniform family measured within ``--tolerance`` s of it (fig_5_12X.toml); fig_5_12X.png
   draws two of them (the first found and the one whose setup differs most from it) at t = 0.
4. The thesis' answer to each request, eq. 5-2 under 5-3..5-6 with a fitted f (pbdyn's, and table 5-4's): the setup
   whose prediction is closest to the target (ties: the free values nearest the box centre), and what
   ``--ilp-maps`` maps of that setup measure -- a prediction is not a measurement.

Writes summary.md (also printed) and summary.json into ``--out``. ``--setups corners`` uses only the 8 corner
setups of the grid (a smoke run).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import pbdyn  # noqa: E402
from pbdyn.analysis.normalise import Normaliser  # noqa: E402
from pbdyn.experiments.generate import BOX  # noqa: E402

CONTROLLED = ROOT / "scenarios" / "datasets" / "controlled_2d.toml"
THESIS_COEF = (-6.014, 0.226, 2.646, 1.104)
THESIS_R2 = 0.95
"""Table 5-4 (eq. 5-1 of survivability difficulty) and the R^2 of section 5-2-2."""
REQUESTS = (("a", 5.0, {"count": 10}), ("b", 7.0, {"count": 25, "radius": 1.2}))
"""Fig. 5-12: (panel, difficulty target, fixed setup values)."""
FIELDS = ("count", "radius", "speed")
METRIC = "survivability"


# ------------------------------------------------------------------------------------------------ data
def controlled_document(maps: int, setups: str = "all") -> dict:
    """The controlled set with ``maps`` maps per setup (its first replicates: the same maps as the full set's);
    ``setups`` "corners": only the 8 corners of its grid."""
    doc = tomllib.loads(CONTROLLED.read_text(encoding="utf-8"))
    obst = doc["obstacles"]
    obst["maps_per_setup"] = maps
    if setups == "corners":
        for key in FIELDS:
            obst[key] = [min(obst[key]), max(obst[key])]
    doc["name"] = f"controlled_2d_{maps}maps" + ("_corners" if setups == "corners" else "")
    return doc


def setup_document(base: dict, n: int, r: float, v: float, maps: int, seed: int) -> dict:
    """``base`` with one setup (n, r, v) and ``maps`` maps of it under root_seed ``seed``."""
    doc = json.loads(json.dumps(base))
    doc["obstacles"].update(count=[int(n)], radius=[float(r)], speed=[float(v)], maps_per_setup=maps,
                            root_seed=seed)
    doc["name"] = "ilp_setup"
    return doc


def measure_maps(doc: dict) -> list[dict]:
    """One row per map of ``doc``: map index, setup values, replicate, survivability s."""
    sc = pbdyn.load_scenario(doc)
    total = len(sc.obstacles.count) * len(sc.obstacles.radius) * len(sc.obstacles.speed) * \
        sc.obstacles.maps_per_setup
    rows = []
    for i in range(total):
        info = pbdyn.map_info(sc, i)
        s = pbdyn.compute_metrics(sc, i, metrics=[METRIC])[METRIC]["value"]
        rows.append({"map": i, **info["setup"], "replicate": info["replicate"], "s": float(s)})
    return rows


# ------------------------------------------------------------------------------------------------ eq. 5-1
def fit_eq_5_1(rows: list[dict], y: np.ndarray):
    """statsmodels OLS of y on (1, n, r, v) (thesis eq. 5-1)."""
    import statsmodels.api as sm

    x = np.array([[row["count"], row["radius"], row["speed"]] for row in rows], float)
    return sm.OLS(np.asarray(y, float), sm.add_constant(x, has_constant="add")).fit()


def fit_summary(fit) -> dict:
    """Coefficients, standard errors, 95% intervals and R^2 of an OLS fit, JSON-able."""
    ci = np.asarray(fit.conf_int(0.05))
    return {"coef": [float(c) for c in fit.params], "se": [float(s) for s in fit.bse],
            "ci95": [[float(a), float(b)] for a, b in ci], "r2": float(fit.rsquared), "n": int(fit.nobs)}


def predict(coef, n, r, v) -> np.ndarray:
    """b0 + b1 n + b2 r + b3 v."""
    return coef[0] + coef[1] * np.asarray(n, float) + coef[2] * np.asarray(r, float) + coef[3] * np.asarray(v, float)


def ilp_setup(coef, target: float, fixed: dict) -> dict:
    """Thesis eq. 5-2 under 5-3..5-6: the setup (n integer) minimising |f(n, r, v) - target|; the last free value
    of (speed, radius) is solved exactly, the others searched (n over integers, r on a 0.01 m grid); among equal
    optima the free values nearest the box centre (in box widths). Returns {count, radius, speed, predicted}."""
    grids = {"count": np.arange(BOX["count"][0], BOX["count"][1] + 1, dtype=float),
             "radius": np.round(np.arange(BOX["radius"][0], BOX["radius"][1] + 1e-9, 0.01), 2),
             "speed": np.round(np.arange(BOX["speed"][0], BOX["speed"][1] + 1e-9, 0.01), 2)}
    solved = next((k for k in ("speed", "radius") if k not in fixed), None)
    axes = [np.array([float(fixed[k])]) if k in fixed else (np.array([np.nan]) if k == solved else grids[k])
            for k in FIELDS]
    n, r, v = (a.ravel() for a in np.meshgrid(*axes, indexing="ij"))
    idx = {"count": 1, "radius": 2, "speed": 3}
    if solved is not None:
        vals = {"count": n, "radius": r, "speed": v}
        rest = coef[0] + sum(coef[idx[k]] * np.nan_to_num(vals[k]) for k in FIELDS if k != solved)
        lo, hi = BOX[solved]
        vals[solved][:] = np.clip((target - rest) / coef[idx[solved]], lo, hi)
    resid = np.abs(predict(coef, n, r, v) - target)
    dist = sum(((a - 0.5 * sum(BOX[k])) / (BOX[k][1] - BOX[k][0])) ** 2
               for k, a in zip(FIELDS, (n, r, v)) if k not in fixed)
    best = np.lexsort((dist, np.round(resid, 9)))[0]
    return {"count": int(n[best]), "radius": float(r[best]), "speed": float(v[best]),
            "predicted": float(predict(coef, n[best], r[best], v[best]))}


# ------------------------------------------------------------------------------------------------ figures
def draw_fig_5_11(path: Path, rows: list[dict], fits: dict, ys: dict, dpi: int) -> None:
    """Predicted vs measured per map, raw survivability (left) and difficulty (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([row["count"] for row in rows])
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.6), layout="constrained")
    for ax, key, label in zip(axes, ("raw", "difficulty"), ("survivability s [s]", "survivability difficulty [0, 10]")):
        y, fit = ys[key], fits[key]
        pred = fit.fittedvalues
        sc = ax.scatter(pred, y, c=n, cmap="viridis", s=14, alpha=0.85, edgecolors="none")
        lo, hi = float(min(pred.min(), y.min())), float(max(pred.max(), y.max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=1)
        ax.set_title(f"{fmt_eq(fit.params)}\nR$^2$ {fit.rsquared:.3f}, {int(fit.nobs)} maps", fontsize=9)
        ax.set_xlabel(f"predicted {label} (eq. 5-1)")
        ax.set_ylabel(f"measured {label}")
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=axes, label="obstacle count n", shrink=0.85)
    fig.suptitle("Eq. 5-1 on the controlled maps (cf. thesis fig. 5-11)", fontsize=10)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def draw_map(ax, scenario, index: int, title: str) -> None:
    """A 2D map at t = 0: arena, obstacle discs, velocity arrows (1 s of motion), start/goal candidates with the
    MAV disc."""
    from matplotlib.patches import Circle, Rectangle

    sc = pbdyn.load_scenario(scenario)
    ro = pbdyn.rollout(sc, index, horizon=1.0)
    size = ro.arena_size
    ax.add_patch(Rectangle((0, 0), size[0], size[1], fill=False, ec="k", lw=2))
    p, vel = ro.positions[0], ro.velocities[0]
    for i in range(ro.n_obstacles):
        ax.add_patch(Circle(p[i], ro.radii[i], fc="tab:red", ec="darkred", alpha=0.6))
    ax.quiver(p[:, 0], p[:, 1], vel[:, 0], vel[:, 1], angles="xy", scale_units="xy", scale=1.0, width=0.004,
              color="k")
    for c in sc.task.candidates:
        ax.add_patch(Circle(c[:2], sc.drone.radius, fc="tab:blue", ec="none", alpha=0.5))
    ax.set_xlim(-1, size[0] + 1)
    ax.set_ylim(-1, size[1] + 1)
    ax.set_aspect("equal")
    ax.set_xticks([0, size[0] / 2, size[0]])
    ax.set_yticks([0, size[1] / 2, size[1]])
    ax.set_title(title, fontsize=9)


def two_maps(maps) -> tuple[int, int]:
    """The first map and the one whose setup differs most from it (box widths)."""
    first = maps[0]

    def dist(c):
        return sum(((getattr(c, k) - getattr(first, k)) / (BOX[k][1] - BOX[k][0])) ** 2 for k in FIELDS)

    return 0, max(range(1, len(maps)), key=lambda i: (dist(maps[i]), -i))


def draw_fig_5_12(path: Path, scenario, picks: list[tuple[int, str]], suptitle: str, dpi: int) -> None:
    """The (map index, title) ``picks`` of ``scenario`` side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(picks), figsize=(4.2 * len(picks), 4.8), layout="constrained")
    for ax, (index, title) in zip(np.atleast_1d(axes), picks):
        draw_map(ax, scenario, index, title)
    fig.suptitle(suptitle, fontsize=10)
    fig.supxlabel("t = 0; arrows: 1 s of motion; blue: start/goal candidates (MAV disc); x, y in m", fontsize=8)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------ the run
def fmt_eq(coef) -> str:
    """b0 + b1 n + b2 r + b3 v as text."""
    return f"{coef[0]:.3f}" + "".join(f" {'-' if c < 0 else '+'} {abs(c):.3f} {nm}"
                                      for c, nm in zip(coef[1:], ("n", "r", "v")))


def run(args) -> dict:
    """The whole use case (module doc) into ``args.out``; returns what summary.json holds."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    base = controlled_document(args.maps, args.setups)
    rows = measure_maps(base)
    s = np.array([row["s"] for row in rows])
    norm = Normaliser(float(s.min()), float(s.max()), True)
    diff = norm.difficulty(s)
    fits = {"raw": fit_eq_5_1(rows, s), "difficulty": fit_eq_5_1(rows, diff)}
    draw_fig_5_11(out / "fig_5_11.png", rows, fits, {"raw": s, "difficulty": diff}, args.dpi)
    t_fit = time.perf_counter() - t0
    result = {"maps": len(rows), "setups": args.setups, "maps_per_setup": args.maps,
              "normaliser": norm.as_dict(), "fit": {k: fit_summary(f) for k, f in fits.items()},
              "thesis": {"coef": list(THESIS_COEF), "r2": THESIS_R2}, "tolerance_s": args.tolerance,
              "requests": [], "measure_and_fit_wall_s": t_fit}
    coef_sets = {"pbdyn": result["fit"]["difficulty"]["coef"], "table 5-4": list(THESIS_COEF)}
    for panel, target, fixed in REQUESTS:
        result["requests"].append(fig_5_12_request(panel, target, fixed, base, norm, coef_sets, out, args))
    result["wall_s"] = time.perf_counter() - t0
    (out / "summary.json").write_text(json.dumps(result, indent=1), encoding="utf-8")
    (out / "summary.md").write_text(summary_markdown(result), encoding="utf-8")
    return result


def fig_5_12_request(panel: str, target: float, fixed: dict, base: dict, norm: Normaliser, coef_sets: dict,
                     out: Path, args) -> dict:
    """One request of fig. 5-12: maps generated at the difficulty ``target`` (converted to seconds by ``norm``)
    with ``fixed`` setup values, measured again and two of them drawn; and eq. 5-2's setup for each f of
    ``coef_sets`` with what its maps measure."""
    span = norm.hi - norm.lo
    s_target = round(norm.hi - target / 10.0 * span, 4)
    t1 = time.perf_counter()
    gen = pbdyn.generate_maps(out / f"fig_5_12{panel}.toml", metric=METRIC, target=s_target,
                              tolerance=args.tolerance, count=args.count, family="uniform", dims=2,
                              scenario={k: v for k, v in base.items() if k != "name"}, fixed=fixed, seed=args.seed,
                              workers=args.workers)
    gen_wall = time.perf_counter() - t1
    gsc = pbdyn.load_scenario(tomllib.loads((out / f"fig_5_12{panel}.toml").read_text(encoding="utf-8")))
    gvals = np.array([pbdyn.compute_metrics(gsc, i, metrics=[METRIC])[METRIC]["value"]
                      for i in range(len(gen.maps))])
    picks = []
    for i in two_maps(gen.maps):
        c = gen.maps[i]
        picks.append((i, f"map {i}: n = {c.count}, r = {c.radius:.2f} m, v = {c.speed:.2f} m/s\n"
                         f"survivability {gvals[i]:.2f} s = difficulty {float(norm.difficulty(gvals[i])):.2f}"))
    fixed_text = ", ".join(f"{'n' if k == 'count' else 'r'} = {v:g}{' m' if k == 'radius' else ''}"
                           for k, v in fixed.items())
    draw_fig_5_12(out / f"fig_5_12{panel}.png", gsc, picks,
                  f"Difficulty {target:g} ({fixed_text}): survivability {s_target:.2f} +- {args.tolerance:g} s "
                  f"(cf. thesis fig. 5-12{panel})", args.dpi)
    within = np.abs(gvals - s_target) <= args.tolerance + 1e-9
    req = {"panel": panel, "difficulty_target": target, "fixed": fixed, "survivability_target_s": s_target,
           "difficulty_tolerance": args.tolerance * 10.0 / span,
           "generated": {"maps": len(gen.maps), "candidates": gen.candidates, "wall_s": gen_wall,
                         "reachable_s": list(gen.reachable), "setups": [[c.count, c.radius, c.speed] for c in gen.maps],
                         "survivability_s": [float(x) for x in gvals],
                         "difficulty": [float(x) for x in norm.difficulty(gvals)],
                         "within_tolerance_again": float(np.mean(within)), "drawn": [p[0] for p in picks]},
           "ilp": []}
    for label, coef in coef_sets.items():
        best = ilp_setup(coef, target, fixed)
        vals = np.array([row["s"] for row in measure_maps(setup_document(
            base, best["count"], best["radius"], best["speed"], args.ilp_maps, args.seed))])
        d = norm.difficulty(vals)
        req["ilp"].append({"f": label, **best, "maps": len(vals), "survivability_s": [float(x) for x in vals],
                           "difficulty_mean": float(d.mean()),
                           "difficulty_std": float(d.std(ddof=1)) if len(d) > 1 else 0.0,
                           "difficulty_min": float(d.min()), "difficulty_max": float(d.max()),
                           "within_tolerance": float(np.mean(np.abs(vals - s_target) <= args.tolerance + 1e-9))})
    return req


def summary_markdown(res: dict) -> str:
    """The run's results as markdown."""
    fd, fr = res["fit"]["difficulty"], res["fit"]["raw"]
    nm = res["normaliser"]
    lines = [f"# Thesis use case 5-2-2 with pbdyn ({res['maps']} controlled maps, {res['setups']} setups x "
             f"{res['maps_per_setup']})", "",
             f"Survivability difficulty = 10 - 10 (s - {nm['min']:.3f}) / ({nm['max']:.3f} - {nm['min']:.3f}) "
             "(eqs. 4-10, 4-11 over these maps).", "",
             "## Table 5-4 (eq. 5-1, OLS; standard errors in brackets)", "",
             "| | b0 | b1 (n) | b2 (r, m) | b3 (v, m/s) | R^2 |", "|---|---|---|---|---|---|",
             "| thesis, difficulty | " + " | ".join(f"{c:.3f}" for c in res["thesis"]["coef"])
             + f" | {res['thesis']['r2']:.2f} |",
             "| pbdyn, difficulty | " + " | ".join(f"{c:.3f} ({e:.3f})" for c, e in zip(fd["coef"], fd["se"]))
             + f" | {fd['r2']:.3f} |",
             "| pbdyn, raw s [s] | " + " | ".join(f"{c:.3f} ({e:.3f})" for c, e in zip(fr["coef"], fr["se"]))
             + f" | {fr['r2']:.3f} |", "",
             "Thesis coefficient inside pbdyn's 95% interval: " + ", ".join(
                 f"b{i} {'yes' if lo <= t <= hi else 'no'}"
                 for i, (t, (lo, hi)) in enumerate(zip(res["thesis"]["coef"], fd["ci95"]))) + ".", "",
             f"## Fig. 5-12: generated maps (uniform family, tolerance {res['tolerance_s']:g} s)", ""]
    for req in res["requests"]:
        g = req["generated"]
        fixed = ", ".join(f"{k} {v:g}" for k, v in req["fixed"].items())
        setups = np.array(g["setups"], float)
        lines += [f"### 5-12{req['panel']}: difficulty {req['difficulty_target']:g} with {fixed}", "",
                  f"- target survivability {req['survivability_target_s']:.3f} +- {res['tolerance_s']:g} s "
                  f"(difficulty +- {req['difficulty_tolerance']:.2f})",
                  f"- generated: {g['maps']} maps from {g['candidates']} candidates in {g['wall_s']:.1f} s; "
                  f"setups n {setups[:, 0].min():g}-{setups[:, 0].max():g}, r {setups[:, 1].min():.2f}-"
                  f"{setups[:, 1].max():.2f} m, v {setups[:, 2].min():.2f}-{setups[:, 2].max():.2f} m/s; measured "
                  f"again: difficulty {min(g['difficulty']):.2f}-{max(g['difficulty']):.2f}, "
                  f"{100 * g['within_tolerance_again']:.0f}% within tolerance",
                  "- eq. 5-2 (closed form) and what its setup's maps measure:", "",
                  "| f | setup (n, r, v) | predicted | measured mean +- std [min, max] | within tolerance |",
                  "|---|---|---|---|---|"]
        for q in req["ilp"]:
            lines.append(f"| {q['f']} | {q['count']}, {q['radius']:.2f} m, {q['speed']:.2f} m/s | "
                         f"{q['predicted']:.2f} | {q['difficulty_mean']:.2f} +- {q['difficulty_std']:.2f} "
                         f"[{q['difficulty_min']:.2f}, {q['difficulty_max']:.2f}] ({q['maps']} maps) | "
                         f"{100 * q['within_tolerance']:.0f}% |")
        lines.append("")
    lines.append(f"Wall time {res['wall_s']:.1f} s.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results/use_case_5_2_2", help="output folder")
    ap.add_argument("--maps", type=int, default=5, help="maps per controlled setup (default 5)")
    ap.add_argument("--setups", choices=("all", "corners"), default="all", help="all 27 setups or the 8 corners")
    ap.add_argument("--count", type=int, default=20, help="maps to generate per request (default 20)")
    ap.add_argument("--tolerance", type=float, default=0.2, help="survivability tolerance, s (default 0.2)")
    ap.add_argument("--ilp-maps", type=int, default=20, help="maps measured on each eq. 5-2 setup (default 20)")
    ap.add_argument("--workers", type=int, default=2, help="processes measuring candidates (default 2)")
    ap.add_argument("--seed", type=int, default=0, help="root seed of generated and eq. 5-2 maps (default 0)")
    ap.add_argument("--dpi", type=int, default=100, help="figure resolution (default 100)")
    args = ap.parse_args(argv)
    if args.maps < 1 or args.count < 2 or args.ilp_maps < 1 or not args.tolerance > 0:
        ap.error("--maps, --ilp-maps >= 1, --count >= 2, --tolerance > 0")
    res = run(args)
    print(summary_markdown(res), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
