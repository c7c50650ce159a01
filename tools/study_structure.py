"""The structure study (docs/science.md): does any metric see difficulty beyond the setup?

    .venv/bin/pbdyn batch scenarios/datasets/structured_2d.toml --out results/study/structured_2d.sqlite
    .venv/bin/pbdyn batch scenarios/datasets/heterogeneous_2d.toml --out results/study/heterogeneous_2d.sqlite
    .venv/bin/pbdyn batch scenarios/datasets/structured_3d.toml --out results/study/structured_3d.sqlite
    .venv/bin/python tools/study_structure.py results/study/*.sqlite [--out results/study/summary.md]
    .venv/bin/python tools/study_structure.py --pool heterogeneous_2d.sqlite imported_2d/*.sqlite --out pooled.md

Evaluates each store on its own (pbdyn evaluate, 1000 bootstrap draws) and writes one markdown summary: per metric
its SRCC against per-map success and against the fitted (1PL) difficulty with 95% intervals, the within-family SRCC
(maps of one structure, differing by seed), the paired difference to the flux and setup-only baselines, and the
trial-level log-loss gain; then the reliability of per-map success and the planners' abilities. The full reports
are written beside the summary as <store>.report.json. With --pool the stores are evaluated as one heterogeneous
set (`pbdyn evaluate --pool`: generated maps and imported worlds, no setup label), written as pooled.report.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbdyn.analysis.report import beaters, verdict_mark  # noqa: E402
from pbdyn.experiments.evaluate import evaluate_stores  # noqa: E402


def _f(x, spec=".3f") -> str:
    return "-" if x is None else format(x, spec)


def _ci(ci) -> str:
    return "-" if not ci or ci[0] is None else f"[{ci[0]:.2f}, {ci[1]:.2f}]"


def _cmp(row: dict, base: str, key: str = "vs_baselines") -> str:
    c = (row.get(key) or {}).get(base)
    if c is None:
        return "-"
    return f"{c['diff']:+.3f} {_ci(c['ci95'])}"


def _gain(r: dict | None) -> str:
    """A trial-level log-loss gain with its interval and verdict mark (verdict_mark)."""
    if not r:
        return "-"
    ci = r.get("log_loss_gain_ci95") or [None, None]
    return f"{_f(r['log_loss_gain'], '+.4f')} [{_f(ci[0], '+.3f')}, {_f(ci[1], '+.3f')}]" + verdict_mark(r)


def summarise(name: str, rep: dict) -> list[str]:
    """Markdown lines for one store's report."""
    lines = [f"### {name}", "", f"{rep['datasets'].get(rep['controlled_dataset'], 0)} maps, {rep['n_trials']} trials, "
             f"{len(rep['pairs'])} planner pairs. SRCC: positive = ranks maps as success does; intervals: 95% "
             "bootstrap over maps (comparisons paired over the same draws).", ""]
    bases = rep["baselines"]["rows"]
    lines += ["| metric | SRCC vs success [95% CI] | SRCC vs fitted difficulty [95% CI] | within family | " +
              " | ".join(f"minus {b} [95% CI]" for b in bases) + " | trial log-loss gain |",
              "|---|---|---|---|" + "---|" * len(bases) + "---|"]
    tl = (rep.get("trial_level") or {}).get("predictors", {})
    for m, r in rep["metrics"].items():
        fit = r.get("fitted") or {}
        tag = " (baseline)" if r.get("kind") == "baseline" else verdict_mark(r)
        lines.append(f"| {m}{tag} | {_f(r['srcc_mean'])} {_ci(r['srcc_ci95'])} | {_f(fit.get('srcc'))} "
                     f"{_ci(fit.get('ci95'))} | {_f(r.get('within_family_srcc'))} "
                     f"{_ci(r.get('within_family_ci95'))} | " +
                     " | ".join(_cmp(r, b) for b in bases) + f" | {_gain(tl.get(m))} |")
    for t in ("task_survivability", "task_flux"):
        if t in tl:
            lines.append(f"| {t} (per trial) | - | - | - | " + " | ".join("-" for _ in bases) +
                         f" | {_gain(tl[t])} (AUC {_f(tl[t]['auc'])}) |")
    ref = tl.get("planners only")
    rel = rep.get("within_setup_reliability") or {}
    fam = rep.get("within_family_reliability") or {}
    fd = rep["fitted_difficulty"]
    lines += ["", f"Reliability of per-map success: within setups {_f(rel.get('mean_reliability'), '.2f')}, within "
                  f"families {_f(fam.get('mean_reliability'), '.2f')}. Planners-only trial model: AUC "
                  f"{_f(ref and ref['auc'])}, log-loss {_f(ref and ref['log_loss'], '.4f')}.",
              "'*': beats every baseline (95% interval of each paired difference above 0); '**': still after "
              "Holm's correction for the number of metrics (predictors) tested.",
              "Trial level, beats every baseline predictor (held-out log-loss, 95% interval over maps): " +
              beaters(tl, none="none") + ".",
              "Beats every baseline across maps: " + beaters(rep["metrics"], none="none") +
              "; against the fitted difficulty: " + beaters(rep["metrics"], sub="fitted", none="none") +
              "; within setups: " +
              beaters(rep["metrics"], "beats_baselines_within_setup", "beats_baselines_within_setup_holm",
                      none="none") +
              "; within families: " +
              beaters(rep["metrics"], "beats_baselines_within_family", "beats_baselines_within_family_holm",
                      none="none") + ".",
              "Abilities (logits): " + ", ".join(f"{k} {v['ability']:+.2f} +- {v['se']:.2f}"
                                                 for k, v in fd["respondents"].items()) + "."]
    t = fd.get("tasks") or {}
    if "n_tasks" in t:
        lines.append(f"Task-level 1PL: {t['n_tasks']} tasks, difficulty sd {t['difficulty_sd']:.2f} logits, share "
                     f"of variance within maps {t['within_map_share_of_variance']:.2f} "
                     f"({t['within_map_share_noise_corrected']:.2f} after the fit's noise).")
    return lines + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stores", nargs="+")
    ap.add_argument("--out", default=str(ROOT / "results" / "study" / "summary.md"))
    ap.add_argument("--bootstrap", type=int, default=1000)
    ap.add_argument("--pool", action="store_true", help="evaluate the stores as one pooled, heterogeneous set")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# Structure study", ""]
    groups = [("pooled", args.stores)] if args.pool else [(Path(s).stem, [s]) for s in args.stores]
    for name, stores in groups:
        rep, _, _ = evaluate_stores(stores, n_boot=args.bootstrap, pool=args.pool)
        (out.parent / f"{name}.report.json").write_text(json.dumps(rep, sort_keys=True))
        if args.pool:
            name = f"pooled: {', '.join(Path(s).stem for s in stores)}"
        lines += summarise(name, rep)
    out.write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
