"""Paired comparisons of two planners on identical tasks, and success-rate intervals.

Two planner pairs that flew the same tasks (same map, start, goal and MAV speed) are compared task by task: the
discordant counts (tasks only one of them succeeded on) give the exact McNemar test (a two-sided binomial test of
the discordant split against 1/2), and the difference of their success rates gets a 95% interval from a paired
bootstrap that resamples maps (a map's tasks stay together: they share obstacles, so they are not independent).
Success rates of one planner get Wilson score intervals (trials taken as independent). Score cards test the
difference with clustered_paired_test instead (a cluster-robust Wald t-test with maps as clusters, which respects
that a map's tasks share obstacles) and adjust the p-values of a card's comparisons with holm_adjust; format_p prints
a p-value to the card's floor (P_FLOOR).

`pbdyn evaluate` reports both (its "paired" and "success_by_group" keys): paired_table compares every two planner
pairs on the tasks they both flew, success_by_group gives each pair's success per map setup and, for stores flown
from a benchmark suite, per level; format_paired and format_success_by_group lay them out as text.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.analysis.html_kit import interval, num
from pbdyn.errors import ConfigError

Z95 = 1.959963984540054
"""The standard normal quantile of a two-sided 95% interval."""


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (default 95%) of a success rate ``successes`` / ``trials``; (nan, nan) without
    trials."""
    if trials <= 0:
        return (math.nan, math.nan)
    p = successes / trials
    den = 1.0 + z * z / trials
    centre = (p + z * z / (2.0 * trials)) / den
    half = z * math.sqrt(p * (1.0 - p) / trials + z * z / (4.0 * trials * trials)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def mcnemar_exact(a_only: int, b_only: int) -> float:
    """Two-sided exact McNemar p-value from the discordant counts (tasks only A, only B succeeded on): the binomial
    test of a_only successes in a_only + b_only trials at 1/2; 1.0 without discordant tasks."""
    n = int(a_only) + int(b_only)
    if n == 0:
        return 1.0
    from scipy.stats import binomtest

    return float(binomtest(int(a_only), n, 0.5).pvalue)


def paired_comparison(a, b, clusters, *, n_boot: int = 2000, seed: int = 0) -> dict:
    """Compare planner A with planner B on the same T tasks: ``a``, ``b`` [T] success (0/1) aligned task by task;
    ``clusters`` [T]: each task's map (resampled together). Returns tasks, both, a_only, b_only, neither, the
    success rates, difference = rate_a - rate_b with its 95% paired-bootstrap interval (maps resampled with
    replacement, ``n_boot`` draws from numpy.random.default_rng(seed); (nan, nan) with n_boot = 0) and the exact
    McNemar p-value."""
    if int(n_boot) < 0:
        raise ConfigError("n_boot", "must be >= 0", n_boot)
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError("a and b must be 1-D and aligned task by task")
    t = int(a.size)
    out = {"tasks": t, "both": int(np.sum(a & b)), "a_only": int(np.sum(a & ~b)), "b_only": int(np.sum(~a & b)),
           "neither": int(np.sum(~a & ~b))}
    if t == 0:
        return {**out, "success_a": math.nan, "success_b": math.nan, "difference": math.nan,
                "difference_ci95": [math.nan, math.nan], "mcnemar_p": 1.0}
    diff = a.astype(float) - b.astype(float)
    labels, inverse = np.unique(np.asarray(clusters).astype(str), return_inverse=True)
    k = labels.size
    sums = np.bincount(inverse, weights=diff, minlength=k)
    counts = np.bincount(inverse, minlength=k).astype(float)
    lo = hi = math.nan
    if n_boot > 0:
        rng = np.random.default_rng(seed)
        w = rng.multinomial(k, np.full(k, 1.0 / k), size=int(n_boot)).astype(float)   # [B, K] map weights
        boot = (w @ sums) / (w @ counts)
        lo, hi = np.quantile(boot, [0.025, 0.975])
    return {**out, "success_a": float(a.mean()), "success_b": float(b.mean()), "difference": float(diff.mean()),
            "difference_ci95": [float(lo), float(hi)], "mcnemar_p": mcnemar_exact(out["a_only"], out["b_only"])}


# --------------------------------------------------------------------------------------- the clustered paired test
P_FLOOR = 1e-6
"""The smallest p-value a score card prints or stores as a number: below it, "< 1e-6" (format_p)."""


def clustered_paired_test(a, b, clusters) -> dict:
    """The cluster-robust Wald t-test of the success difference of planner A and planner B on the same T tasks
    (``a``, ``b`` [T] success 0/1 aligned task by task; ``clusters`` [T] each task's map): the paired differences
    d = a - b are regressed on an intercept, so the estimate is mean(d), with the map-clustered sandwich variance
    SE^2 = G / (G - 1) * sum_g (sum_{i in g} (d_i - mean d))^2 / T^2 over the G maps, and t = mean(d) / SE is
    referred to Student's t with G - 1 degrees of freedom (two-sided). This is statsmodels'
    ``OLS(d, ones).fit(cov_type="cluster", cov_kwds={"groups": maps}, use_t=True)`` (its small-sample factor
    (T - 1) / (T - K) is 1 with the intercept alone), written with numpy and scipy.

    Returns {"estimate", "se", "t", "df", "p", "maps", "tasks"}. Edge cases: without tasks every number is nan;
    every difference 0: t = 0 and p = 1 (nothing to test; statsmodels gives nan); one map (and a difference):
    se, t, p nan (no degree of freedom; statsmodels divides by zero); SE 0 (every map's differences sum to its share
    of the mean, e.g. every task the same difference): t = +-inf and p = 0 with a nonzero estimate (statsmodels
    gives an SE of rounding size and a p-value below any floor), t = 0 and p = 1 with a zero one."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError("a and b must be 1-D and aligned task by task")
    t_n = int(a.size)
    labels, inverse = np.unique(np.asarray(clusters).astype(str), return_inverse=True)
    if len(inverse) != t_n:
        raise ValueError("clusters must name one map per task")
    g = int(labels.size)
    nan = math.nan
    if t_n == 0:
        return {"estimate": nan, "se": nan, "t": nan, "df": 0, "p": nan, "maps": 0, "tasks": 0}
    d = a - b
    est = float(d.mean())
    if not np.any(d):
        return {"estimate": 0.0, "se": 0.0, "t": 0.0, "df": g - 1, "p": 1.0, "maps": g, "tasks": t_n}
    if g < 2:
        return {"estimate": est, "se": nan, "t": nan, "df": 0, "p": nan, "maps": g, "tasks": t_n}
    scores = np.bincount(inverse, weights=d - est, minlength=g)        # each map's summed residual
    se = math.sqrt(g / (g - 1) * float(np.sum(scores ** 2))) / t_n
    if se <= 1e-12 * max(1.0, abs(est)):                               # rounding of an exact zero
        se = 0.0
    from scipy.stats import t as student_t

    if se == 0.0:                      # every map's differences sum to its share of the mean: no spread left
        t, p = (0.0, 1.0) if est == 0.0 else (math.copysign(math.inf, est), 0.0)
    else:
        t = est / se
        p = float(2.0 * student_t.sf(abs(t), g - 1))
    return {"estimate": est, "se": se, "t": float(t), "df": g - 1, "p": min(1.0, p), "maps": g, "tasks": t_n}


def holm_adjust(pvalues) -> list:
    """Holm's step-down adjustment of a family of p-values (None or nan: not tested, left out of the family and
    returned as None): the i-th smallest of the m tested p-values becomes max over j <= i of min(1, (m - j + 1)
    p_(j)); ties keep their input order."""
    vals = [None if p is None or (isinstance(p, float) and math.isnan(p)) else float(p) for p in pvalues]
    tested = sorted((p, i) for i, p in enumerate(vals) if p is not None)
    m = len(tested)
    out: list = [None] * len(vals)
    running = 0.0
    for j, (p, i) in enumerate(tested):
        running = max(running, min(1.0, (m - j) * p))
        out[i] = running
    return out


def format_p(p) -> str:
    """A p-value as a card prints it: "< 1e-6" below P_FLOOR, else two significant digits ("0.034", "2.3e-5",
    "1"); "n/a" for None or nan."""
    if p is None or (isinstance(p, float) and math.isnan(p)):
        return "n/a"
    if p < P_FLOOR:
        return "< 1e-6"
    text = f"{p:.2g}"
    if "e" in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}e{int(exponent)}"
    return text


# --------------------------------------------------------------------------------------------- evaluate's tables
TASK_DEFINITION = "a task is (map, start->goal, MAV speed); error trials are not flown and enter no comparison"


def task_successes(trials: list[dict]) -> dict[str, dict[tuple, bool]]:
    """pair -> {task (map_id, "start->goal", mav_speed): succeeded} of the flown (not "error") trials that name
    their task (``trials``: pbdyn.experiments.evaluate.load_results rows). A pair flies a task once per store (the
    trial key covers map, start, goal, speed and planner); should a task repeat, its first row counts."""
    out: dict[str, dict[tuple, bool]] = {}
    for t in trials:
        if t.get("outcome") in (None, "error") or t.get("task") is None or t.get("mav_speed") is None:
            continue
        key = (str(t["map_id"]), str(t["task"]), float(t["mav_speed"]))
        out.setdefault(str(t["pair"]), {}).setdefault(key, t["outcome"] == "success")
    return out


def paired_table(trials: list[dict], *, n_boot: int = 1000, seed: int = 0) -> dict:
    """Every two planner pairs (A before B in name order) that flew common tasks, compared on those tasks
    (paired_comparison: counts, success rates, A - B with its paired-bootstrap 95% interval over maps, exact
    McNemar p; plus n_maps, the maps the common tasks lie on). JSON-able apart from NaN (no interval without
    bootstrap draws). ``n_boot`` draws per comparison, each from numpy.random.default_rng(seed)."""
    per_pair = task_successes(trials)
    names = sorted(per_pair)
    rows = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            common = sorted(per_pair[a].keys() & per_pair[b].keys())
            if not common:
                continue
            cmp = paired_comparison([per_pair[a][k] for k in common], [per_pair[b][k] for k in common],
                                    [k[0] for k in common], n_boot=n_boot, seed=seed)
            rows.append({"a": a, "b": b, "n_maps": len({k[0] for k in common}), **cmp})
    return {"method": f"planner pairs compared task by task on the tasks both flew ({TASK_DEFINITION}); "
                      "difference = success A - success B, 95% interval from a paired bootstrap resampling maps; "
                      "p: exact McNemar test of the discordant tasks (A only vs B only)",
            "n_boot": int(n_boot), "seed": int(seed), "comparisons": rows}


def _value_label(v) -> str:
    if isinstance(v, dict) and "min" in v and "max" in v:
        return f"{v['min']:g}-{v['max']:g}"
    return f"{v:g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def setup_label(setup: dict | None) -> str:
    """A map's setup as a short label: "n=<obstacles> r=<radius, m> v=<speed, m/s>" (a range as "min-max"), with
    " structure=<name>" when it has one; "(no setup)" when it has none of them (e.g. an imported world)."""
    s = setup or {}
    parts = [f"{tag}={_value_label(s[key])}" for key, tag in (("count", "n"), ("radius", "r"), ("speed", "v"))
             if s.get(key) is not None]
    if s.get("structure") is not None:
        parts.append(f"structure={s['structure']}")
    return " ".join(parts) or "(no setup)"


def _number(v) -> float:
    if isinstance(v, dict):
        v = v.get("min")
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else -math.inf


def _setup_order(setup: dict | None) -> tuple:
    s = setup or {}
    return (_number(s.get("count")), _number(s.get("radius")), _number(s.get("speed")), str(s.get("structure") or ""))


def _level_order(level) -> tuple:
    """Numeric levels first, in value order, then the others in name order."""
    if isinstance(level, (int, float)) and not isinstance(level, bool):
        return (0, float(level), "")
    return (1, 0.0, str(level))


def _cells(groups: dict) -> dict:
    """pair -> label -> [successes, trials, maps] as pair -> label -> {successes, trials, n_maps, rate, ci95}."""
    out: dict = {}
    for pair in sorted(groups):
        for label, (k, n, maps) in groups[pair].items():
            out.setdefault(pair, {})[label] = {"successes": k, "trials": n, "n_maps": len(maps),
                                               "rate": k / n if n else math.nan, "ci95": list(wilson_interval(k, n))}
    return out


def success_by_group(trials: list[dict], maps: dict[str, dict]) -> dict:
    """Success of each planner pair per setup (setup_label of the map's setup; setups ordered by obstacle count,
    radius, speed, structure) and, when the trials carry a "level" (a benchmark suite's), per level: successes,
    flown trials, maps, rate and its Wilson 95% interval. Flown (not "error") trials of every dataset and MAV speed
    pooled.
    "level" is None when no trial has one. JSON-able apart from NaN."""
    by_setup: dict = {}
    by_level: dict = {}
    order: dict = {}
    levels: dict = {}
    for t in trials:
        if t.get("outcome") in (None, "error"):
            continue
        mid = t["map_id"]
        setup = (maps.get(mid) or {}).get("setup")
        label = setup_label(setup)
        order.setdefault(label, _setup_order(setup))
        hit = int(t["outcome"] == "success")
        for table, key in ((by_setup, label), (by_level, t.get("level"))):
            if key is None:
                continue
            cell = table.setdefault(str(t["pair"]), {}).setdefault(str(key), [0, 0, set()])
            cell[0] += hit
            cell[1] += 1
            cell[2].add(mid)
        if t.get("level") is not None:
            levels.setdefault(str(t["level"]), _level_order(t["level"]))
    for table, rank in ((by_setup, order), (by_level, levels)):
        for pair, cells in table.items():
            table[pair] = dict(sorted(cells.items(), key=lambda kv: (rank[kv[0]], kv[0])))
    return {"method": "success = successes / flown trials (error trials not rated) of each planner pair per group; "
                      "95% Wilson score interval (trials taken as independent)",
            "setup": _cells(by_setup), "level": _cells(by_level) if by_level else None}


def format_success_by_group(section: dict) -> list[str]:
    """Text lines of a success_by_group section: per setup, then per level when present."""
    lines: list[str] = []
    for key, title in (("setup", "setup"), ("level", "level")):
        table = section.get(key)
        if not table:
            continue
        wp = max(len("planner pair"), *(len(p) for p in table))
        wg = max(len(title), *(len(g) for cells in table.values() for g in cells))
        lines += ["", f"Success by {title} per planner pair (Wilson 95% interval; error trials not rated):",
                  f"  {'planner pair':<{wp}}  {title:<{wg}}  {'success':>7}  {'95% CI':>16}  {'trials':>6}  "
                  f"{'maps':>5}"]
        for pair, cells in table.items():
            for group, c in cells.items():
                lines.append(f"  {pair:<{wp}}  {group:<{wg}}  {num(c['rate']):>7}  {interval(c['ci95']):>16}"
                             f"  {c['trials']:>6}  {c['n_maps']:>5}")
    return lines


def format_paired(section: dict) -> list[str]:
    """Text lines of a paired_table section (nothing without comparisons)."""
    rows = section.get("comparisons") or []
    if not rows:
        return []
    wa = max(len("A"), *(len(r["a"]) for r in rows))
    wb = max(len("B"), *(len(r["b"]) for r in rows))
    head = (f"  {'A':<{wa}}  {'B':<{wb}}  {'tasks':>5} {'both':>5} {'A only':>6} {'B only':>6} {'neither':>7}  "
            f"{'succ A':>6} {'succ B':>6}  {'A - B':>6} {'95% CI':>17}  {'McNemar p':>9}")
    lines = ["", "Paired comparisons on the tasks both pairs flew (task = map, start->goal, MAV speed; A - B: "
                 "difference of success, 95% interval from a paired bootstrap over maps; exact McNemar p):", head]
    for r in rows:
        lines.append(f"  {r['a']:<{wa}}  {r['b']:<{wb}}  {r['tasks']:>5} {r['both']:>5} {r['a_only']:>6} "
                     f"{r['b_only']:>6} {r['neither']:>7}  {num(r['success_a']):>6} "
                     f"{num(r['success_b']):>6}  {num(r['difference'], '+.3f'):>6} "
                     f"{interval(r['difference_ci95']):>17}  {num(r['mcnemar_p'], '.4f'):>9}")
    return lines
