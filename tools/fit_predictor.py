"""The predictor of reference success (pbdyn.analysis.predict): its features, its validation study and its fit.

    .venv/bin/python tools/fit_predictor.py --features   # data/calibration_features.csv from the calibration maps
    .venv/bin/python tools/fit_predictor.py --study      # leave-one-family-out study of every candidate model
    .venv/bin/python tools/fit_predictor.py              # fit the chosen model -> data/predictor.json

The calibration maps are those whose panel outcomes were exported by tools/fit_anchors.py --export
(data/calibration_<dims>d.csv.gz and, for imported worlds, data/calibration_worlds.csv.gz). A map counts once every
one of its panel trials is in (3 planners x 3 speeds x 20 tasks = 180).

Study: for every candidate feature set (CANDIDATES), each family is held out in turn (the 7 generator families
of each dims, and each kind of imported world: office, orbits, plaza, warehouse), the model is fitted on the rest and predicts the held-out
maps. Reported: pooled SRCC and mean absolute error (MAE) of predicted vs measured success, and per held-out
family its SRCC, MAE (95% intervals from resampling the family's maps) and the reliability ceiling of its SRCC
(sqrt of the split-half reliability of the measured successes), plus the share of maps inside their 95% interval.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbdyn.analysis.predict import (PREDICTOR_FILE, fit_predictor, leave_one_group_out,  # noqa: E402
                                    split_half_reliability)
from pbdyn.metrics.features import FEATURES  # noqa: E402

DATA = ROOT / "pbdyn" / "analysis" / "data"
FEATURES_FILE = DATA / "calibration_features.csv"
PANEL_TRIALS = 180
def _candidates() -> dict[str, tuple]:
    """Every feature set the study compares, declared before looking at any result: the constant, each feature
    alone, each pair, the three route metrics together, and all features."""
    import itertools

    out = {"constant": ()}
    out.update({f: (f,) for f in FEATURES})
    out.update({f"{a} + {b}": (a, b) for a, b in itertools.combinations(FEATURES, 2)})
    out["route_survivability + route_detour + log_route_flux"] = ("route_survivability", "route_detour",
                                                                 "log_route_flux")
    out["all"] = FEATURES
    return out


CANDIDATES = _candidates()
CLOSED_FORMS = ("log_flux", "log_density", "log_flux + log_density")
"""The candidates that are closed forms of (n, r, v) and the arena (no simulation of the movers)."""
CHOSEN = {2: "log_flux + static_share", 3: "log_density + static_share"}
"""The shipped models' feature sets per dims: what choose() picks on every calibration map of those dims
(docs/difficulty-scale.md)."""
MAE_MARGIN = 0.005
"""choose(): a simpler model is preferred while its pooled MAE is within this of the best one's."""
OUTCOME_FILES = {"calibration_2d.csv.gz": "2d", "calibration_3d.csv.gz": "3d", "calibration_worlds.csv.gz": "worlds"}


def read_csv_gz(path: Path) -> list[dict]:
    """Rows of a gzip CSV."""
    with gzip.open(path, "rt") as f:
        return list(csv.DictReader(f))


def calibration_maps() -> list[dict]:
    """Every exported calibration map with its complete panel trials: {"map_id", "dims", "family", "k", "n",
    "tasks": [T, 2] (successes, trials per task), "source"}."""
    out = []
    for name, kind in OUTCOME_FILES.items():
        path = DATA / name
        if not path.is_file():
            continue
        per: dict[str, dict] = {}
        for r in read_csv_gz(path):
            m = per.setdefault(r["map_id"], {"map_id": r["map_id"], "family": r["family"] or "imported",
                                             "dims": 2 if kind == "worlds" else int(kind[0]), "tasks": {},
                                             "source": name, "map_index": int(r["map_index"])})
            if kind == "worlds":                     # the world's kind: office_0 -> office
                m["family"] = "imported " + r["family"].rsplit("_", 1)[0]
                m["dims"] = len(r["start"].split())
            t = m["tasks"].setdefault((r["start"], r["goal"]), [0, 0])
            t[0] += int(r["success"])
            t[1] += 1
        for m in per.values():
            tasks = np.array([m["tasks"][t] for t in sorted(m["tasks"])], float)
            m["tasks"] = tasks
            m["k"], m["n"] = float(tasks[:, 0].sum()), float(tasks[:, 1].sum())
            if m["n"] == PANEL_TRIALS:
                out.append(m)
    return sorted(out, key=lambda m: (m["source"], m["map_index"]))


def scenario_of(source: str) -> list[str]:
    """The scenario file(s) behind an outcomes file."""
    if source == "calibration_worlds.csv.gz":
        return sorted(str(p.relative_to(ROOT)) for p in (ROOT / "scenarios/worlds/imported_2d").glob("*.toml"))
    return [f"scenarios/calibration/{source.split('.')[0]}.toml"]


def compute_features(maps: list[dict]) -> Path:
    """Compute FEATURES of every calibration map (pbdyn.metrics.features.map_features) into FEATURES_FILE."""
    from pbdyn.analysis.scale import reference_pairs
    from pbdyn.config import load_scenario
    from pbdyn.metrics.cached import resolve_backend
    from pbdyn.metrics.features import map_features
    from pbdyn.world.maps import enumerate_maps

    want = {m["map_id"] for m in maps}
    rows = []
    seen_sources = sorted({m["source"] for m in maps})
    for source in seen_sources:
        for path in scenario_of(source):
            sc = load_scenario(ROOT / path)
            for spec in enumerate_maps(sc):
                key = f"{sc.name}/{spec.map_id}" if sc.is_world else spec.map_id
                if key not in want:
                    continue
                f = map_features(sc, spec.index, reference_pairs(sc.task.candidates),
                                 backend=resolve_backend(sc, "auto"))
                rows.append({"map_id": key, "scenario": path, "map_index": spec.index,
                             **{k: repr(float(f[k])) for k in FEATURES}})
                print(f"{path} map {spec.index}: " + ", ".join(f"{k} {f[k]:.3f}" for k in FEATURES), flush=True)
    rows.sort(key=lambda r: (r["scenario"], r["map_index"]))
    with FEATURES_FILE.open("w", newline="") as fh:
        w = csv.DictWriter(fh, ["map_id", "scenario", "map_index", *FEATURES], lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return FEATURES_FILE


def table() -> list[dict]:
    """The calibration maps joined with their features (maps without features are left out, with a note)."""
    feats = {}
    if FEATURES_FILE.is_file():
        with FEATURES_FILE.open() as fh:
            feats = {r["map_id"]: r for r in csv.DictReader(fh)}
    out = []
    for m in calibration_maps():
        f = feats.get(m["map_id"])
        if f is None:
            print(f"note: no features for {m['map_id']} ({m['source']}); run --features", file=sys.stderr)
            continue
        out.append({**m, **{k: float(f[k]) for k in FEATURES}})
    return out


def _boot(values_fn, idx: np.ndarray, rng: np.random.Generator, n_boot: int = 2000) -> tuple[float, float]:
    draws = np.array([values_fn(rng.choice(idx, idx.size)) for _ in range(n_boot)])
    draws = draws[np.isfinite(draws)]
    return (float(np.quantile(draws, 0.025)), float(np.quantile(draws, 0.975))) if draws.size else (np.nan, np.nan)


def _agreement(pred: np.ndarray, y: np.ndarray, idx: np.ndarray, rng: np.random.Generator | None = None) -> dict:
    """SRCC and mean absolute error of predicted vs measured success over the maps ``idx``; with ``rng`` also
    their 95% intervals from resampling those maps."""
    from pbdyn.analysis.srcc import spearman

    out = {"srcc": float(spearman(pred[idx], y[idx])), "mae": float(np.mean(np.abs(pred[idx] - y[idx])))}
    if rng is not None:
        out["srcc_ci"] = _boot(lambda j: float(spearman(pred[j], y[j])), idx, rng)
        out["mae_ci"] = _boot(lambda j: float(np.mean(np.abs(pred[j] - y[j]))), idx, rng)
    return out


def study(rows: list[dict], seed: int = 0, dims: int = 2) -> dict:
    """The leave-one-family-out study (module doc) of every candidate on ``rows`` (maps of one dims)."""
    fam = [r["family"] if r["family"].startswith("imported") else f"{r['dims']}D {r['family']}" for r in rows]
    y = np.array([r["k"] / r["n"] for r in rows])
    fams = sorted(set(fam))
    rel = {}
    for g in fams:
        rng = np.random.default_rng([seed, 1, fams.index(g)])
        ts = [r["tasks"] for r, h in zip(rows, fam) if h == g]
        rel[g] = split_half_reliability(ts, rng)
    res = {"maps": len(rows), "families": {g: fam.count(g) for g in fams}, "reliability": rel, "models": {},
           "dims": dims}
    res["nested"] = nested(rows, fam, y, seed)
    for name, feats in CANDIDATES.items():
        pred = leave_one_group_out(rows, feats, fam)
        rng = np.random.default_rng([seed, 2])
        idx = np.arange(len(rows))
        pooled = _agreement(pred, y, idx, rng)
        per = {g: _agreement(pred, y, np.array([k for k, h in enumerate(fam) if h == g]), rng) for g in fams}
        i = np.array([k for k, h in enumerate(fam) if h.startswith("imported")], dtype=int)
        if i.size:
            per["imported worlds (all kinds)"] = _agreement(pred, y, i, rng)
        full = fit_predictor(rows, feats)
        _, lo, hi = full.predict(rows)
        res["models"][name] = {"features": list(feats), "pooled": pooled, "per_family": per,
                               "in_sample_coverage": float(np.mean((y >= lo) & (y <= hi)))}
    return res


def _scores(rows: list[dict], fam: list[str], y: np.ndarray) -> dict:
    """Leave-one-family-out pooled SRCC and MAE of every candidate on ``rows``."""
    out = {}
    for name, feats in CANDIDATES.items():
        pred = leave_one_group_out(rows, feats, fam)
        out[name] = {"features": list(feats), "pooled": _agreement(pred, y, np.arange(len(rows)))}
    return out


def nested(rows: list[dict], fam: list[str], y: np.ndarray, seed: int = 0) -> dict:
    """The honest estimate of the whole procedure (choosing the features, then fitting): for each held-out family,
    choose() runs on a leave-one-family-out study of the other families only, the chosen model is fitted on them
    and predicts the held-out maps. Returns pooled SRCC/MAE with 95% intervals, per family MAE/SRCC and the
    choice made in each fold."""
    fam_a = np.asarray(fam)
    pred = np.full(len(rows), np.nan)
    picked = {}
    for g in sorted(set(fam)):
        train = [i for i, h in enumerate(fam) if h != g]
        test = [i for i, h in enumerate(fam) if h == g]
        inner = _scores([rows[i] for i in train], [fam[i] for i in train], y[train])
        name = choose({"models": inner})
        picked[g] = name
        model = fit_predictor([rows[i] for i in train], CANDIDATES[name])
        pred[test] = model.predict([rows[i] for i in test])[0]
    rng = np.random.default_rng([seed, 3])
    idx = np.arange(len(rows))
    per = {}
    for g in sorted(set(fam)):
        i = np.flatnonzero(fam_a == g)
        per[g] = _agreement(pred, y, i)
    return {**_agreement(pred, y, idx, rng), "per_family": per, "picked": picked, "predictions": pred.tolist(),
            "measured": y.tolist()}


def choose(res: dict) -> str:
    """The model the study picks: the fewest features among those whose pooled MAE is within MAE_MARGIN of the
    lowest and whose pooled SRCC is within 0.01 of that model's (a closed form that predicts as well wins)."""
    models = res["models"]
    best = min(models, key=lambda m: models[m]["pooled"]["mae"])
    ok = [m for m in models if models[m]["pooled"]["mae"] <= models[best]["pooled"]["mae"] + MAE_MARGIN
          and models[m]["pooled"]["srcc"] >= models[best]["pooled"]["srcc"] - 0.01]
    return min(ok, key=lambda m: (len(models[m]["features"]), models[m]["pooled"]["mae"]))


def format_study(res: dict) -> str:
    """The study as markdown tables."""
    nest = res["nested"]
    lines = [f"{res['maps']} calibration maps: " + ", ".join(f"{g} {n}" for g, n in res["families"].items()), "",
             f"Nested (features chosen without the held-out family): pooled SRCC {nest['srcc']:.3f} "
             f"[{nest['srcc_ci'][0]:.2f}, {nest['srcc_ci'][1]:.2f}], MAE {nest['mae']:.3f} [{nest['mae_ci'][0]:.3f}, "
             f"{nest['mae_ci'][1]:.3f}]; worst family MAE "
             + "{1:.3f} ({0})".format(*max(((g, v["mae"]) for g, v in nest["per_family"].items()), key=lambda kv: kv[1]))
             + "; choices: " + ", ".join(f"{g}: {n}" for g, n in nest["picked"].items()), "",
             "| model | pooled SRCC [95% CI] | pooled MAE [95% CI] | worst family MAE | 95% interval coverage |",
             "|---|---|---|---|---|"]
    ranked = sorted(res["models"], key=lambda m: res["models"][m]["pooled"]["mae"])
    show = list(dict.fromkeys(ranked[:8] + ["constant", "survivability", "route_survivability", *CLOSED_FORMS,
                                            "all"]))
    for name in show:
        m = res["models"][name]
        p = m["pooled"]
        worst = max(((g, v) for g, v in m["per_family"].items() if g in res["families"]), key=lambda kv: kv[1]["mae"])
        lines.append(f"| {name} | {p['srcc']:.3f} [{p['srcc_ci'][0]:.2f}, {p['srcc_ci'][1]:.2f}] | {p['mae']:.3f} "
                     f"[{p['mae_ci'][0]:.3f}, {p['mae_ci'][1]:.3f}] | {worst[1]['mae']:.3f} ({worst[0]}) | "
                     f"{m['in_sample_coverage']:.2f} |")
    shipped = CHOSEN.get(res["dims"], choose(res))
    lines += ["", f"The study picks \"{choose(res)}\" (choose()); shipped: \"{CHOSEN.get(res['dims'])}\".", "",
              f"Per held-out family, model \"{shipped}\":", "",
              "| held-out family | maps | SRCC [95% CI] | reliability ceiling | MAE [95% CI] |", "|---|---|---|---|---|"]
    for g, v in res["models"][shipped]["per_family"].items():
        ceil = float(np.sqrt(max(res["reliability"].get(g, np.nan), 0.0))) if g in res["reliability"] else np.nan
        lines.append(f"| {g} | {res['families'].get(g, sum(n for h, n in res['families'].items() if h.startswith('imported')))} | {v['srcc']:.2f} [{v['srcc_ci'][0]:.2f}, {v['srcc_ci'][1]:.2f}] | "
                     f"{ceil:.2f} | {v['mae']:.3f} [{v['mae_ci'][0]:.3f}, {v['mae_ci'][1]:.3f}] |")
    return "\n".join(lines) + "\n"


def fit_chosen(rows: list[dict]) -> dict:
    """The shipped predictors' document: per dims in CHOSEN, its feature set fitted on every calibration map of
    those dims."""
    models = {}
    for dims, name in sorted(CHOSEN.items()):
        sub = [r for r in rows if r["dims"] == dims]
        src = f"tools/fit_predictor.py: statsmodels binomial GLM on {len(sub)} {dims}D calibration maps " \
              f"({', '.join(sorted({r['source'] for r in sub}))}), features: {name}"
        models[str(dims)] = fit_predictor(sub, CANDIDATES[name], source=src).to_dict()
    return {"version": models[str(min(CHOSEN))]["version"], "models": models}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--features", action="store_true", help="compute the calibration maps' features")
    ap.add_argument("--study", action="store_true", help="run the leave-one-family-out study")
    ap.add_argument("--json", type=Path, help="with --study: also write the study as JSON here")
    ap.add_argument("--dims", type=int, choices=(2, 3), help="with --study: only the maps of these dims")
    args = ap.parse_args(argv)
    if args.features:
        print(f"wrote {compute_features(calibration_maps()).relative_to(ROOT)}")
        return 0
    rows = table()
    if args.study:
        out = {}
        for dims in sorted({r["dims"] for r in rows} if args.dims is None else {args.dims}):
            print(f"## {dims}D\n")
            res = out[dims] = study([r for r in rows if r["dims"] == dims], dims=dims)
            sys.stdout.write(format_study(res) + "\n")
        if args.json:
            args.json.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
        return 0
    doc = fit_chosen(rows)
    (DATA / PREDICTOR_FILE).write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    print(json.dumps({d: {k: m[k] for k in ("features", "coef", "sigma")} for d, m in doc["models"].items()},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
