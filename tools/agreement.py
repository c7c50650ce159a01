"""Agreement of pbdyn's pooled outcome rates with reference rates (the thesis program's), used by tools/reproduce.py.

A *cell* is one (combo, MAV speed). pbdyn's rate of an outcome in a cell is the share of the cell's flown trials
(rows whose outcome is "error" are left out) that ended with that outcome, pooled over maps, setups and start/goal
pairs -- the reference's definition ("pooled success / dynamic collision / deadlock rates per MAV speed").

Sampling noise. A cell's trials are not independent: the 72 flights on one map share its obstacles, and trials
are deterministic given the map, so the noise is that of drawing maps (seeds) within each fixed setup. pbdyn's 95%
interval is therefore a bootstrap over maps, stratified by setup (count, radius, speed), with the Rao-Wu rescaling
for m_s - 1 draws (McCarthy and Snowden 1985; Rao and Wu 1988): each replicate draws m_s - 1 of a setup's m_s maps
with replacement and weighs each drawn map by m_s / (m_s - 1), which makes the bootstrap variance of a pooled
(linear) rate unbiased even for m_s = 2 or 3 maps per setup. A cell where some setup has a single map cannot be
stratified; its maps are then resampled as one stratum (M - 1 of M maps), which also counts the between-setup
spread as noise: a conservative (wider) interval, marked "unstratified". The interval is the 2.5/97.5 percentile
of the replicates; se is their standard deviation. Replicates are drawn from numpy.random.default_rng(SeedSequence(
[seed, crc32 of the cell's name])): the same numbers in any order or subset of cells.

Design effect: deff = se^2 / (p (1 - p) / n), pbdyn's variance over the binomial one of n independent trials
(above 1 from clustering by map, below 1 where the setups, fixed by design, explain part of the spread). The
reference pools n_ref trials (tools/reproduce.py REFERENCE_TRIALS) of the same design (the 27 setups, 72 pairs per
map and speed; 20 maps per setup), so its standard error is taken as se_ref = sqrt(deff p_ref (1 - p_ref) / n_ref)
with pbdyn's deff of the same cell; where pbdyn's rate is 0 or 1 the deff is undefined and the median deff of the
combo's other cells is used, else 1. (An unstratified cell's deff also counts the between-setup spread, so it
overstates the reference's noise as well: conservative.)

The reference's own maps (a column "seed" naming each trial's map id where pbdyn flew the program's own maps,
obstacles.layout = "program"): the program seeded every setup's map j with the same id j, so its maps of one id
share their draws across setups and the trials cluster by id, not by map. Such a cell is bootstrapped over its
m ids (Rao-Wu, m - 1 of m, every map of a drawn id with it; method "seeds"), and since the reference pools the same
ids 0..M-1 (M = ref_seeds) that include pbdyn's m, the noise of the difference is that of drawing m of the M ids
without replacement: se_diff = se sqrt(1 - m / M), se_ref = 0 (on all M ids the difference has no sampling noise
at all, and a disagreement is the implementation's). A cell with a single id cannot estimate the between-id spread;
it keeps the stratified map bootstrap (which understates it) and is marked "one seed".

Verdict ("within sampling noise"): |p - p_ref| <= Z sqrt(se^2 + se_ref^2) + ROUNDING -- the two-sided 5% test of
equal rates with both samples' noise, plus half a unit of the reference's third decimal (it is given rounded).
Rates of 0 or 1 have no binomial variance, so binomial standard errors use p clipped to [0.5 / n, 1 - 0.5 / n]
(half a trial), and pbdyn's se is at least sqrt(deff) times that (a cell with no event still has noise). "ref in
CI" reports separately whether the reference lies inside pbdyn's interval (widened by ROUNDING). With many cells,
about 1 in 20 falls outside noise by chance alone.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from pbdyn.outcome import Outcome

RATE_OUTCOMES: tuple[str, ...] = tuple(o.value for o in Outcome if o is not Outcome.ERROR)
"""Outcomes whose pooled rate is reported (every outcome of a flown trial)."""

Z = 1.959963984540054
"""Two-sided 95% normal quantile."""

ROUNDING = 0.0005
"""Half a unit of the reference's last (third) decimal."""

COLUMNS = ("combo", "label", "mav_speed", "outcome", "map", "setup")
"""Columns of the trial table agreement() takes (one row per trial)."""


def replicate_weights(strata: Sequence, n_boot: int, rng: np.random.Generator) -> tuple[np.ndarray | None, str]:
    """Rao-Wu (m - 1) bootstrap weights [n_boot, M] over M maps labelled by ``strata`` (see the module docstring):
    per stratum of m maps, multinomial(m - 1) multiplicities times m / (m - 1). Strata with one map make the whole
    set one stratum ("unstratified"); fewer than 2 maps give (None, "none")."""
    strata = np.asarray([str(s) for s in strata])
    m_total = len(strata)
    if m_total < 2 or n_boot < 2:
        return None, "none"
    _, groups, sizes = np.unique(strata, return_inverse=True, return_counts=True)
    method = "stratified"
    if sizes.min() < 2:
        groups, sizes, method = np.zeros(m_total, dtype=np.int64), np.array([m_total]), "unstratified"
    w = np.zeros((n_boot, m_total))
    for g, m in enumerate(sizes):
        idx = np.flatnonzero(groups == g)
        w[:, idx] = rng.multinomial(m - 1, np.full(m, 1.0 / m), size=n_boot) * (m / (m - 1.0))
    return w, method


def _cell_rng(seed: int, combo: str, speed: float) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(f"{combo}|{speed:g}".encode())]))


def _binomial_se(p: float, n: float) -> float:
    """sqrt(p (1 - p) / n) with p clipped to [0.5 / n, 1 - 0.5 / n] (half a trial; see the module docstring)."""
    if not n > 0 or not math.isfinite(p):
        return math.nan
    pc = min(max(p, 0.5 / n), 1.0 - 0.5 / n)
    return math.sqrt(pc * (1.0 - pc) / n)


def cell_rates(cell: pd.DataFrame, n_boot: int, rng: np.random.Generator) -> dict:
    """Pooled rate, bootstrap 95% CI, se and design effect of every outcome in RATE_OUTCOMES for one cell's trials
    (columns outcome, map, setup; "error" rows are left out), and each setup's pooled rates ("per_setup", no
    interval); see the module docstring."""
    flown = cell[cell["outcome"].to_numpy() != Outcome.ERROR.value]
    maps, mi = np.unique(flown["map"].to_numpy().astype(str), return_inverse=True)
    seeds = None
    if "seed" in flown.columns and len(flown) and (flown["seed"].astype(str) != "").all():
        seeds = flown["seed"].astype(str).to_numpy()
    oi = pd.Index(RATE_OUTCOMES).get_indexer(flown["outcome"])
    if (oi < 0).any():
        raise ValueError(f"unknown outcome {flown['outcome'].to_numpy()[oi < 0][0]!r}")
    counts = np.zeros((len(maps), len(RATE_OUTCOMES)))
    np.add.at(counts, (mi, oi), 1.0)
    n_map = counts.sum(axis=1)
    _, first = np.unique(mi, return_index=True)
    strata = flown["setup"].to_numpy().astype(str)[first]
    n = float(n_map.sum())
    p = counts.sum(axis=0) / n if n > 0 else np.full(len(RATE_OUTCOMES), np.nan)
    n_seeds = 0
    if seeds is not None:
        map_seed = seeds[first]
        ids, seed_of_map = np.unique(map_seed, return_inverse=True)
        n_seeds = len(ids)
    if n_seeds >= 2:
        ws, _ = replicate_weights(np.zeros(n_seeds), n_boot, rng)
        w, method = ws[:, seed_of_map], "seeds"
    else:
        w, method = replicate_weights(strata, n_boot, rng)
        if n_seeds == 1:
            method = "one seed"
    if w is not None:
        reps = (w @ counts) / (w @ n_map)[:, None]
        lo, hi = np.quantile(reps, [0.025, 0.975], axis=0)
        se = reps.std(axis=0, ddof=1)
    else:
        lo = hi = se = np.full(len(RATE_OUTCOMES), np.nan)
    setups, si = np.unique(strata, return_inverse=True)
    per_setup = np.zeros((len(setups), len(RATE_OUTCOMES)))
    np.add.at(per_setup, si, counts)
    out = {"n_trials": int(n), "n_errors": int(len(cell) - len(flown)), "n_maps": len(maps), "n_seeds": n_seeds,
           "n_setups": len(setups), "method": method, "rates": {},
           "per_setup": {str(k): {"n_trials": int(row.sum()), "n_maps": int((si == i).sum()),
                                  **{o: float(x / row.sum()) if row.sum() else math.nan
                                     for o, x in zip(RATE_OUTCOMES, row)}}
                         for i, (k, row) in enumerate(zip(setups, per_setup))}}
    for j, o in enumerate(RATE_OUTCOMES):
        sb = _binomial_se(float(p[j]), n)
        defined = 0.0 < p[j] < 1.0 and math.isfinite(se[j])
        out["rates"][o] = {"rate": float(p[j]), "ci95": [float(lo[j]), float(hi[j])], "se": float(se[j]),
                           "deff": float(se[j] ** 2 / sb ** 2) if defined and sb > 0 else None}
    return out


def _verdict(r: dict, n: int, ref: float, ref_trials: int, deff: float, shared: float | None = None) -> dict:
    """The comparison of one pbdyn rate ``r`` (from ``n`` trials) with the reference rate ``ref``. ``shared``: for
    a cell flown on the reference's own maps, the share m / M of the reference's map ids it flew (module
    docstring); None for independent maps."""
    p = r["rate"]
    se_ref = math.sqrt(deff) * _binomial_se(ref, ref_trials)
    se = r["se"] if math.isfinite(r["se"]) else 0.0
    se = max(se, math.sqrt(deff) * _binomial_se(p, n))
    if shared is not None:
        se, se_ref = se * math.sqrt(max(0.0, 1.0 - shared)), 0.0
    bound = Z * math.hypot(se, se_ref) + ROUNDING
    lo, hi = r["ci95"]
    in_ci = bool(math.isfinite(lo) and lo - ROUNDING <= ref <= hi + ROUNDING)
    return {"reference": ref, "diff": p - ref, "se_used": se, "se_reference": se_ref, "deff_used": deff,
            "noise_bound": bound, "within_noise": bool(abs(p - ref) <= bound), "ref_in_ci": in_ci}


def agreement(trials: pd.DataFrame, reference: Mapping[str, Mapping[float, Mapping[str, float]]], *,
              ref_trials: int, n_boot: int = 1000, seed: int = 0, ref_seeds: int | None = None) -> dict:
    """Compare pbdyn's pooled rates with ``reference`` (combo -> MAV speed [m/s] -> outcome name -> rate, each from
    ``ref_trials`` trials). ``trials``: one row per trial with COLUMNS (combo: the reference's name of the
    planner combination; label: pbdyn's planner_label; map: a map key; setup: its setup key) and optionally
    "seed" (the program's map id where the map is the reference's own; ``ref_seeds``: the reference's number of
    ids, 0..ref_seeds-1; see the module docstring). Returns a JSON-able
    dict: "cells" (one per combo and speed present in ``trials``, reference combos first in their order) with
    per-outcome pbdyn statistics and, where the reference has the outcome, its comparison; "summary" counts."""
    missing = set(COLUMNS) - set(trials.columns)
    if missing:
        raise ValueError(f"trials lacks columns {sorted(missing)}")
    order = {c: i for i, c in enumerate(reference)}
    keys = sorted(trials.groupby(["combo", "mav_speed"]).groups,
                  key=lambda k: (order.get(k[0], len(order)), k[0], float(k[1])))
    cells = []
    for combo, speed in keys:
        sub = trials[(trials["combo"] == combo) & (trials["mav_speed"] == speed)]
        c = cell_rates(sub, n_boot, _cell_rng(seed, combo, float(speed)))
        c.update({"combo": combo, "labels": sorted(sub["label"].unique().tolist()), "mav_speed": float(speed)})
        cells.append(c)
    for combo in sorted({c["combo"] for c in cells}):     # the reference's deff: pbdyn's, else the combo's median
        mine = [c for c in cells if c["combo"] == combo]
        known = [r["deff"] for c in mine for r in c["rates"].values() if r["deff"] is not None]
        fallback = float(np.median(known)) if known else 1.0
        for c in mine:
            ref = _speed_lookup(reference.get(combo, {}), c["mav_speed"])
            for o, r in c["rates"].items():
                if ref is not None and o in ref:
                    deff = fallback if r["deff"] is None else r["deff"]
                    shared = (c["n_seeds"] / ref_seeds if c["method"] == "seeds" and ref_seeds else None)
                    r.update(_verdict(r, c["n_trials"], float(ref[o]), ref_trials, deff, shared))
    compared = [r for c in cells for r in c["rates"].values() if "within_noise" in r]
    summary = {"cells": len(cells), "comparisons": len(compared),
               "within_noise": sum(r["within_noise"] for r in compared),
               "ref_in_ci": sum(r["ref_in_ci"] for r in compared),
               "combos_without_reference": sorted({c["combo"] for c in cells} - set(reference)),
               "reference_cells_without_data": [f"{k} @ {v:g} m/s" for k, per in reference.items() for v in per
                                                if not any(c["combo"] == k and c["mav_speed"] == float(v)
                                                           for c in cells)]}
    return {"n_boot": int(n_boot), "seed": int(seed), "reference_trials_per_cell": int(ref_trials),
            "z": Z, "rounding": ROUNDING, "cells": cells, "summary": summary}


def _speed_lookup(per_speed: Mapping, speed: float):
    for v, ref in per_speed.items():
        if abs(float(v) - speed) < 1e-9:
            return ref
    return None


def json_ready(obj):
    """``obj`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj


# ----------------------------------------------------------------------------------------------- formatting
def _f(x, spec: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def short(outcome: str) -> str:
    """A short column label of an outcome name ("dynamic_collision" -> "dynamic coll.")."""
    return outcome.replace("_collision", " coll.").replace("_", " ")


def format_markdown(result: dict, compared: Sequence[str], *, title: str, notes: Sequence[str] = ()) -> str:
    """agreement.md: ``title``, ``notes`` (one paragraph each), then one table row per cell: per outcome in
    ``compared`` pbdyn's rate [95% CI], the reference, the difference (marked "!" outside sampling noise); the
    other outcomes' pbdyn rates; the design effect of success; the verdicts."""
    others = [o for o in RATE_OUTCOMES if o not in compared]
    head = ["combo", "pbdyn label", "MAV [m/s]", "trials (maps)"]
    for o in compared:
        head += [f"{short(o)} pbdyn [95% CI]", "ref", "diff"]
    head += [short(o) for o in others] + ["deff", "within noise"]
    lines = [f"# {title}", ""] + [x for n in notes for x in (n, "")]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in result["cells"]:
        row = [c["combo"], ", ".join(c["labels"]), f"{c['mav_speed']:g}", f"{c['n_trials']} ({c['n_maps']})"]
        verdicts = []
        for o in compared:
            r = c["rates"][o]
            row.append(f"{_f(r['rate'])} [{_f(r['ci95'][0])}, {_f(r['ci95'][1])}]")
            if "within_noise" in r:
                row += [_f(r["reference"]), _f(r["diff"], "+.3f") + ("" if r["within_noise"] else " !")]
                verdicts.append("yes" if r["within_noise"] else "no")
            else:
                row += ["-", "-"]
        row += [_f(c["rates"][o]["rate"]) for o in others]
        row.append(_f(c["rates"][Outcome.SUCCESS.value]["deff"], ".1f"))
        row.append("/".join(verdicts) or "-")
        row[3] += {"unstratified": " u", "none": " n", "seeds": " s", "one seed": " 1"}.get(c["method"], "")
        lines.append("| " + " | ".join(row) + " |")
    s = result["summary"]
    lines += ["", f"{s['within_noise']} of {s['comparisons']} compared rates are within sampling noise "
              f"({s['ref_in_ci']} references inside pbdyn's 95% CI); by chance alone about 5% fall outside."]
    methods = {c["method"] for c in result["cells"]}
    if "unstratified" in methods:
        lines.append("\"u\": a setup of this cell has one map, so its maps were resampled unstratified (a "
                     "conservative, wider interval that counts the between-setup spread as noise).")
    if "none" in methods:
        lines.append("\"n\": a single map: no interval; the verdict uses the binomial se alone.")
    if "seeds" in methods:
        lines.append("\"s\": flown on the program's own maps: the interval resamples its map ids (every setup's map "
                     "of one id together), and the noise of the difference is that of m of the reference's ids, "
                     "se sqrt(1 - m / M) (tools/agreement.py).")
    if "one seed" in methods:
        lines.append("\"1\": the program's maps of a single id: the between-id spread cannot be estimated; the "
                     "interval resamples maps within setups and understates it.")
    if s["reference_cells_without_data"]:
        lines.append("Reference cells without pbdyn trials: " + ", ".join(s["reference_cells_without_data"]) + ".")
    return "\n".join(lines) + "\n"


def _srcc_cell(row: dict | None, mean: str, std: str, ci: str | None = None) -> str:
    if not row or row.get(mean) is None:
        return "-"
    text = f"{_f(row[mean])} +- {_f(row.get(std))}"
    if ci and row.get(ci):
        text += f" [{_f(row[ci][0])}, {_f(row[ci][1])}]"
    return text


def _rates_cell(agree: dict | None, combo: str, speed: float, compared: Sequence[str]) -> str:
    for c in (agree or {}).get("cells", ()):
        if c["combo"] == combo and abs(c["mav_speed"] - speed) < 1e-9:
            rs = [c["rates"][o] for o in compared]
            ok = [r["within_noise"] for r in rs if "within_noise" in r]
            text = " / ".join(_f(r["rate"]) for r in rs)
            return text + (f" ({sum(ok)}/{len(ok)} within noise)" if ok else "")
    return "-"


def format_side_by_side(reports: Mapping[str, dict | None], agreements: Mapping[str, dict | None],
                        thesis_table: Mapping[str, Sequence[float]],
                        reference: Mapping[str, Mapping[float, Mapping[str, float]]],
                        compared: Sequence[str]) -> str:
    """side_by_side.md: thesis table 4-5 rows (SRCC and CV of each metric: the thesis' value, then each profile's
    report.json in ``reports``: profile -> report or None) and the pooled rates of ``compared`` outcomes per
    reference combo and MAV speed (the reference, then each profile's agreement.json in ``agreements``)."""
    profiles = list(reports)
    lines = ["## Table 4-5 under both profiles", "",
             "SRCC (mean +- std over planner pairs [bootstrap 95% CI]) and CV (mean +- std) of each metric against "
             "the success rate; thesis = the thesis' table 4-5.", ""]
    head = ["metric", "SRCC thesis"] + [f"SRCC {p}" for p in profiles] + ["CV thesis"] + [f"CV {p}" for p in profiles]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    names = list(thesis_table)
    for rep in reports.values():
        names += [n for n in (rep or {}).get("metrics", {}) if n not in names]
    for name in names:
        th = thesis_table.get(name)
        rows = [(rep or {}).get("metrics", {}).get(name) for rep in reports.values()]
        cells = [name, f"{th[0]:.3f} +- {th[1]:.3f}" if th else "-"]
        cells += [_srcc_cell(r, "srcc_mean", "srcc_std", "srcc_ci95") for r in rows]
        cells += [f"{th[2]:.3f} +- {th[3]:.3f}" if th else "-"]
        cells += [_srcc_cell(r, "cv_mean", "cv_std") for r in rows]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "## Pooled outcome rates per combo and MAV speed", "",
              f"{' / '.join(short(o) for o in compared)} rates pooled over maps, setups and start/goal pairs; the "
              "program's reference against pbdyn under each profile (physical: the combos' physical counterparts); "
              "within noise: see agreement.md.", ""]
    head = ["combo", "MAV [m/s]", "program (reference)"] + [f"pbdyn {p}" for p in profiles]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for combo, per in reference.items():
        for speed, ref in per.items():
            cells = [combo, f"{float(speed):g}", " / ".join(_f(float(ref[o])) for o in compared)]
            cells += [_rates_cell(agreements.get(p), combo, float(speed), compared) for p in profiles]
            lines.append("| " + " | ".join(cells) + " |")
    lines += figure_sections(reports)
    return "\n".join(lines) + "\n"


def _rate_cells(row: Sequence[dict]) -> list[str]:
    return [f"{c['rate']:.2f}" if c.get("n") else "" for c in row]


def figure_sections(reports: Mapping[str, dict | None]) -> list[str]:
    """Markdown tables of figs 5-9, 5-10 and 5-14 (report["figures"], pbdyn.analysis.figure_tables) per profile:
    success rates per survivability difficulty level (0 = easiest) or velocity ratio; empty cells: no trials."""
    lines: list[str] = []
    figs = {p: (rep or {}).get("figures") for p, rep in reports.items()}
    if not any(figs.values()):
        return lines
    levels = next(f["levels"] for f in figs.values() if f)
    head = ["profile", "planner"] + [str(k) for k in levels]
    lines += ["", "## Figure 5-9: success (deadlock) rate per survivability difficulty level", "",
              "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p, f in figs.items():
        for traj, series in ((f or {}).get("fig_5_9") or {}).items():
            cells = [f"{a} ({b})" if a else "" for a, b in zip(_rate_cells(series["success"]),
                                                              _rate_cells(series["deadlock"]))]
            lines.append("| " + " | ".join([p, traj] + cells) + " |")
    lines += ["", "## Figure 5-10: success rate per gaze planner and survivability difficulty level", "",
              "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p, f in figs.items():
        for traj, per in ((f or {}).get("fig_5_10") or {}).items():
            for gaze, row in per.items():
                lines.append("| " + " | ".join([p, f"{gaze} + {traj}"] + _rate_cells(row)) + " |")
    for p, f in figs.items():
        fig = (f or {}).get("fig_5_14") or {}
        if not fig.get("ratios"):
            continue
        head = ["pair"] + [f"{x:g}" for x in fig["ratios"]]
        lines += ["", f"## Figure 5-14 ({p}): success rate per velocity ratio v_obs / v_max", "",
                  "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for pair, row in fig["success"].items():
            lines.append("| " + " | ".join([pair] + _rate_cells(row)) + " |")
    return lines
