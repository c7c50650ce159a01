"""Predicted reference success: the anchored scale's difficulty from metrics alone (docs/difficulty-scale.md).

The anchored scale (pbdyn.analysis.scale) is measured by flying the reference panel (`pbdyn calibrate`). The
predictor estimates the same number -- the panel's expected success on a map's reference tasks -- from features
computed in about a second, so `pbdyn metrics` can print it for any map:

    logit P(success of a panel trial on map i) = beta_0 + sum_f beta_f z_f(i)

a binomial GLM (statsmodels; successes of the 180 panel trials per calibration map) on standardised features
z_f = (x_f - mean_f) / sd_f. The candidate features (pbdyn.metrics.features, which computes them) are map
metrics -- survivability (s, thesis eq. 3-6), the log of the closed-form flux (1/s), the log density, the static
share -- and task metrics along the static-free route between the map's reference start/goal pairs (route detour,
route survivability, log route flux; pbdyn.metrics.route), which see walls, corridors and pillars. The shipped
model (pbdyn/analysis/data/predictor.json) names the features the leave-one-family-out study chose
(tools/fit_predictor.py --study, docs/difficulty-scale.md). Its 95% interval for one
map combines the coefficients' uncertainty (covariance scaled by the Pearson chi^2 dispersion) with the spread
of real maps around the model (``sigma``: the map-level standard deviation on the logit scale beyond binomial
noise, a moment estimate), so it is meant to cover a map's measured reference success, not only its mean.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbdyn.analysis.scale import sigmoid
from pbdyn.errors import ConfigError
from pbdyn.metrics.features import FEATURES

PREDICTOR_FILE = "predictor.json"
PREDICTOR_VERSION = "1"
Z95 = 1.959963984540054


# ------------------------------------------------------------------------------------------------ the model
@dataclass(frozen=True)
class Predictor:
    """A fitted predictor (module doc): ``features`` (names), their training ``mean`` and ``sd``, ``coef``
    (intercept first) and its covariance ``cov``, ``sigma`` (logits), the calibration maps' measured reference
    successes per dims (``calibration``, for percentiles), the dims it was fitted on, version and source."""

    features: tuple
    mean: tuple
    sd: tuple
    coef: tuple
    cov: tuple
    sigma: float
    dims: tuple
    calibration: dict = field(default_factory=dict)
    version: str = PREDICTOR_VERSION
    source: str = ""

    def design(self, rows: list[dict]) -> np.ndarray:
        """The design matrix [N, 1 + F] (intercept, standardised features) of feature rows."""
        x = np.array([[float(r[f]) for f in self.features] for r in rows], float).reshape(len(rows), -1)
        z = (x - np.asarray(self.mean, float)) / np.asarray(self.sd, float)
        return np.column_stack([np.ones(len(rows)), z])

    def predict(self, rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(success [N], lower [N], upper [N]): the predicted reference success of each feature row and its 95%
        interval for one map (module doc)."""
        x = self.design(rows)
        eta = x @ np.asarray(self.coef, float)
        var = np.einsum("ni,ij,nj->n", x, np.asarray(self.cov, float), x) + self.sigma ** 2
        half = Z95 * np.sqrt(var)
        return sigmoid(eta), sigmoid(eta - half), sigmoid(eta + half)

    def percentile(self, success: float, dims: int) -> float | None:
        """The share (%) of the ``dims``-D calibration maps easier (higher measured reference success) than
        ``success`` -- the same sense as the measured difficulty's percentile; None without such maps."""
        ref = self.calibration.get(str(dims))
        if not ref:
            return None
        ref = np.asarray(ref, float)
        return float(100.0 * (np.sum(ref > success) + 0.5 * np.sum(ref == success)) / ref.size)

    def to_dict(self) -> dict:
        """JSON-able form (the shipped file)."""
        return {"version": self.version, "features": list(self.features), "mean": list(self.mean),
                "sd": list(self.sd), "coef": list(self.coef), "cov": [list(r) for r in self.cov],
                "sigma": self.sigma, "dims": list(self.dims), "calibration": self.calibration,
                "source": self.source}


def fit_predictor(rows: list[dict], features, *, source: str = "", calibration: dict | None = None) -> Predictor:
    """Fit the predictor on calibration rows ({feature: value, "k": successes, "n": trials, "dims": d}) with the
    named ``features`` (a subset of FEATURES, may be empty: a constant): statsmodels binomial GLM (module doc)."""
    import statsmodels.api as sm

    features = tuple(features)
    unknown = [f for f in features if f not in FEATURES]
    if unknown:
        raise ConfigError("features", f"unknown (known: {', '.join(FEATURES)})", ", ".join(unknown))
    x = np.array([[float(r[f]) for f in features] for r in rows], float).reshape(len(rows), len(features))
    k = np.array([float(r["k"]) for r in rows])
    n = np.array([float(r["n"]) for r in rows])
    mean = x.mean(axis=0) if len(features) else np.zeros(0)
    sd = x.std(axis=0) if len(features) else np.zeros(0)
    sd = np.where(sd > 0, sd, 1.0)
    design = np.column_stack([np.ones(len(rows)), (x - mean) / sd])
    model = sm.GLM(np.column_stack([k, n - k]), design, family=sm.families.Binomial())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = model.fit(tol=1e-12, maxiter=200, scale="X2")
    coef = np.asarray(res.params, float)
    cov = np.asarray(res.cov_params(), float)
    sigma = map_sigma(k, n, design @ coef)
    dims = tuple(sorted({int(r.get("dims", 2)) for r in rows}))
    if calibration is None:
        calibration = {}
        for d in dims:
            calibration[str(d)] = sorted(round(float(r["k"]) / float(r["n"]), 6) for r in rows
                                         if int(r.get("dims", 2)) == d)
    return Predictor(features, tuple(float(v) for v in mean), tuple(float(v) for v in sd),
                     tuple(float(v) for v in coef), tuple(tuple(float(v) for v in r) for r in cov), float(sigma),
                     dims, calibration, PREDICTOR_VERSION, source)


def map_sigma(k, n, eta) -> float:
    """The map-level spread (logits) of measured success around the linear predictor ``eta`` beyond binomial
    noise: sqrt(max(0, mean(resid^2 - 1 / (n p (1 - p))))), resid = empirical logit (k + 1/2) / (n + 1) minus eta,
    p = sigmoid(eta) (method of moments)."""
    k, n, eta = (np.asarray(a, float) for a in (k, n, eta))
    emp = np.log((k + 0.5) / (n - k + 0.5))
    p = sigmoid(eta)
    noise = 1.0 / np.maximum(n * p * (1.0 - p), 1e-12)
    return float(math.sqrt(max(0.0, float(np.mean((emp - eta) ** 2 - noise)))))


def _from_dict(d: dict) -> Predictor:
    return Predictor(tuple(d["features"]), tuple(d["mean"]), tuple(d["sd"]), tuple(d["coef"]),
                     tuple(tuple(r) for r in d["cov"]), float(d["sigma"]), tuple(d["dims"]),
                     d.get("calibration", {}), str(d.get("version", PREDICTOR_VERSION)), d.get("source", ""))


def load_predictors(path: str | Path | None = None) -> dict[int, Predictor]:
    """The predictors shipped with pbdyn (pbdyn/analysis/data/predictor.json) or at ``path``: dims -> Predictor,
    one model per dims fitted on that dims' calibration maps ({} if there are none)."""
    p = Path(path) if path is not None else Path(__file__).resolve().parent / "data" / PREDICTOR_FILE
    if not p.is_file():
        return {}
    doc = json.loads(p.read_text())
    return {int(k): _from_dict(v) for k, v in sorted(doc.get("models", {}).items())}


def load_predictor(dims: int = 2, path: str | Path | None = None) -> Predictor | None:
    """The shipped predictor of ``dims``-D maps, or None."""
    return load_predictors(path).get(int(dims))


def predicted_success(predictors: dict, feats: dict, dims: int) -> dict:
    """One map's predicted reference success from the predictor of its ``dims`` among ``predictors`` (dims ->
    Predictor): {"success", "ci": [lo, hi], "percentile", "features"} or, without a predictor for those dims,
    {"why": ...}."""
    predictor = predictors.get(dims)
    if predictor is None:
        have = "/".join(f"{d}D" for d in sorted(predictors)) or "no"
        return {"why": f"the shipped predictors cover {have} maps; {dims}D maps are not predicted (no {dims}D "
                       "calibration flights shipped)"}
    p, lo, hi = predictor.predict([feats])
    return {"success": float(p[0]), "ci": [float(lo[0]), float(hi[0])],
            "percentile": predictor.percentile(float(p[0]), dims), "features": dict(feats)}


def format_prediction(pred: dict) -> str:
    """The `pbdyn metrics` line."""
    if "why" in pred:
        return f"predicted reference success: none ({pred['why']})\n"
    pct = f", percentile {pred['percentile']:.0f} of the bundled calibration set" \
        if pred.get("percentile") is not None else ""
    note = f"; {pred['note']}" if pred.get("note") else ""
    return (f"predicted reference success {pred['success']:.2f} [{pred['ci'][0]:.2f}, {pred['ci'][1]:.2f}]{pct} "
            f"(higher percentile = harder; pbdyn calibrate measures it{note})\n")


# ------------------------------------------------------------------------------------------------ validation
def leave_one_group_out(rows: list[dict], features, groups: list[str]) -> np.ndarray:
    """Predicted success [N] of each row by a predictor fitted without its group (leave-one-family-out)."""
    groups = np.asarray(groups)
    out = np.full(len(rows), np.nan)
    for g in sorted(set(groups.tolist())):
        train = [r for r, h in zip(rows, groups) if h != g]
        test = [i for i, h in enumerate(groups) if h == g]
        model = fit_predictor(train, features)
        out[test] = model.predict([rows[i] for i in test])[0]
    return out


def split_half_reliability(task_success: list[np.ndarray], rng: np.random.Generator, n_splits: int = 200) -> float:
    """Spearman-Brown corrected split-half reliability of the maps' measured success: tasks of each map split at
    random into halves, SRCC of the halves' success rates over the maps, averaged over ``n_splits`` splits and
    corrected to full length (2 rho / (1 + rho)). ``task_success``: per map, an array [T, 2] of (successes,
    trials) per reference task."""
    from pbdyn.analysis.srcc import spearman

    rhos = []
    for _ in range(n_splits):
        a, b = [], []
        for ts in task_success:
            t = ts.shape[0]
            perm = rng.permutation(t)
            h1, h2 = perm[: t // 2], perm[t // 2:]
            a.append(ts[h1, 0].sum() / ts[h1, 1].sum())
            b.append(ts[h2, 0].sum() / ts[h2, 1].sum())
        rhos.append(float(spearman(np.array(a), np.array(b))))
    rho = float(np.nanmean(rhos))
    return 2.0 * rho / (1.0 + rho) if rho > -1.0 else float("nan")
