"""Difficulty judged one trial at a time: how well a metric predicts whether a trial succeeds.

For each predictor (a map metric's difficulty joined to the trials on that map, a task metric of the trial itself,
or a baseline), a logistic regression of success on [the predictor (standardised), one indicator per respondent
(planner pair at one MAV speed)] is fitted with scikit-learn and scored on held-out maps (GroupKFold by map, so no
map is both fitted and scored): the area under the ROC curve (AUC) and the mean log-loss (nats per trial) of the
held-out predictions. The reference "planners only" model has the respondent indicators alone; a predictor helps
where it lowers the log-loss below that reference. AUC pools every respondent, so it also credits telling the
planners apart; the log-loss gain over the reference isolates what the predictor adds. Gains and differences of
two predictors come with 95% intervals from a bootstrap over maps of the per-trial held-out log-losses (paired:
the same trials, the same resampled maps).
"""

from __future__ import annotations

import warnings

import numpy as np

from pbdyn.analysis.srcc import percentile_ci
from pbdyn.analysis.validation import grouped_mean_draws, one_sided_p

N_FOLDS = 5
"""Held-out folds (maps grouped)."""

REFERENCE = "planners only"
"""Name of the model without a predictor."""


def _design(values: np.ndarray | None, resp: np.ndarray, n_resp: int) -> np.ndarray:
    onehot = np.zeros((resp.shape[0], n_resp))
    onehot[np.arange(resp.shape[0]), resp] = 1.0
    if values is None:
        return onehot
    v = np.asarray(values, dtype=float)
    sd = float(v.std())
    z = (v - float(v.mean())) / sd if sd > 0 else np.zeros_like(v)
    return np.concatenate([z[:, None], onehot], axis=1)


def held_out_scores(x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> dict:
    """AUC and mean log-loss of held-out predictions of y [T] from x [T, k] (GroupKFold over ``groups``)."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import log_loss, roc_auc_score
    from sklearn.model_selection import GroupKFold

    n_groups = np.unique(groups).size
    folds = min(N_FOLDS, n_groups)
    pred = np.full(y.shape[0], np.nan)
    for train, test in GroupKFold(n_splits=folds).split(x, y, groups):
        if np.unique(y[train]).size < 2:
            pred[test] = float(y[train].mean())
            continue
        clf = LogisticRegression(C=1e4, fit_intercept=False, solver="lbfgs", max_iter=2000, tol=1e-8)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            clf.fit(x[train], y[train])
        pred[test] = clf.predict_proba(x[test])[:, 1]
    both = np.unique(y).size == 2
    p = np.clip(pred, 1e-12, 1 - 1e-12)
    return {"auc": float(roc_auc_score(y, pred)) if both else None,
            "log_loss": float(log_loss(y, p, labels=[0, 1])), "n_trials": int(y.size),
            "_loss": -(y * np.log(p) + (1.0 - y) * np.log(1.0 - p))}


def loss_difference_draws(a: np.ndarray, b: np.ndarray, groups: np.ndarray, n_boot: int = 1000,
                          seed: int = 0) -> np.ndarray:
    """Bootstrap draws of mean(a - b) over trials when the groups (maps) are resampled with replacement (a, b:
    per-trial losses [T] of two models on the same trials; numpy.random.default_rng(seed))."""
    keys, inv = np.unique(groups, return_inverse=True)
    sums = np.bincount(inv, weights=a - b, minlength=keys.size)
    return grouped_mean_draws(sums, np.bincount(inv, minlength=keys.size).astype(float), n_boot, seed)


def loss_difference_ci(a: np.ndarray, b: np.ndarray, groups: np.ndarray, n_boot: int = 1000,
                       seed: int = 0) -> list[float]:
    """95% percentile interval of loss_difference_draws."""
    return list(percentile_ci(loss_difference_draws(a, b, groups, n_boot, seed)))


def trial_level(success: np.ndarray, respondent: np.ndarray, map_idx: np.ndarray,
                predictors: dict[str, np.ndarray]) -> dict:
    """Held-out AUC and log-loss per predictor (module doc). success [T] (0/1), respondent [T] (int codes), map_idx
    [T] (the grouping), predictors: name -> values [T] (trials where a predictor is not finite are left out of its
    model and of its own reference, reported as "n_trials"). Returns name -> {auc, log_loss, n_trials,
    log_loss_gain (reference minus model, on the same trials; > 0 = the predictor helps)} with REFERENCE first."""
    y = np.asarray(success, dtype=float)
    resp = np.asarray(respondent, dtype=np.int64)
    groups = np.asarray(map_idx)
    n_resp = int(resp.max()) + 1 if resp.size else 0
    out = {REFERENCE: held_out_scores(_design(None, resp, n_resp), y, groups)}
    out[REFERENCE]["log_loss_gain"] = 0.0
    for name, v in predictors.items():
        v = np.asarray(v, dtype=float)
        ok = np.isfinite(v)
        if ok.sum() < 2 or np.unique(groups[ok]).size < 2:
            continue
        model = held_out_scores(_design(v[ok], resp[ok], n_resp), y[ok], groups[ok])
        ref = out[REFERENCE] if ok.all() else held_out_scores(_design(None, resp[ok], n_resp), y[ok], groups[ok])
        model["log_loss_gain"] = ref["log_loss"] - model["log_loss"]
        model["log_loss_gain_ci95"] = loss_difference_ci(ref["_loss"], model["_loss"], groups[ok])
        model["_ok"] = ok
        out[name] = model
    return out


def compare_predictors(scores: dict, a: str, b: str, groups: np.ndarray, n_boot: int = 1000, seed: int = 0) -> dict:
    """Log-loss of b minus log-loss of a on the trials both predict (> 0: a predicts better), with its 95% interval
    and one-sided bootstrap p-value of "<= 0" (loss_difference_draws); ``scores`` from trial_level (before
    public())."""
    ok = scores[a]["_ok"] & scores[b]["_ok"]
    la = np.full(ok.shape, np.nan)
    lb = la.copy()
    la[scores[a]["_ok"]] = scores[a]["_loss"]
    lb[scores[b]["_ok"]] = scores[b]["_loss"]
    draws = loss_difference_draws(lb[ok], la[ok], np.asarray(groups)[ok], n_boot, seed)
    return {"diff": float(np.mean(lb[ok] - la[ok])), "ci95": list(percentile_ci(draws)), "p": one_sided_p(draws)}


def public(scores: dict) -> dict:
    """trial_level's scores without the per-trial arrays (JSON-able)."""
    return {k: {kk: vv for kk, vv in v.items() if not kk.startswith("_")} for k, v in scores.items()}
