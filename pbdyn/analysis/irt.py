"""Difficulty fitted to trial outcomes: a one-parameter item-response (Rasch / 1PL) model.

    P(success of respondent r on item i) = sigmoid(ability_r - difficulty_i)        (logits)

Items are maps, or tasks (map, start, goal); respondents are planners (pbdyn uses a planner pair at one MAV speed).
A map's fitted difficulty is the success it allows once the mix of planners that flew it is accounted for, and a
planner's ability is a score comparable across maps of different difficulty (docs/design.md "Difficulty: what counts as
evidence"). Identification: difficulties are centred to mean 0 over the items, abilities on the same scale.

Two fits, both with a maintained library:
- fit_rasch (statsmodels GLM, binomial, logit link) on the (item, respondent) success counts, standard errors from
  the model's covariance. Items every trial of which succeeded (or failed) have no finite maximum-likelihood
  difficulty, so each item gets ``prior_trials`` pseudo-trials, half successes, flown by the average respondent (a
  data-augmentation prior, like a normal prior of about 2 / sqrt(prior_trials) logits around the mean difficulty).
- fit_rasch_sparse (scikit-learn LogisticRegression, L2 = a normal prior of sd ``prior_sd`` on every parameter) for
  many items (tasks), on a sparse design; standard errors from the diagonal of the penalised information (each
  parameter's curvature with the others held at the fit: sqrt(1 / (sum n p (1 - p) + 1 / prior_sd^2))).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


PRIOR_SD = 2.0
"""Default standard deviation (logits) of fit_rasch_sparse's normal prior."""


@dataclass(frozen=True)
class RaschFit:
    """A fitted 1PL model. items [I] and respondents [R] (labels, sorted); difficulty, difficulty_se [I] and
    ability, ability_se [R] (logits; difficulties centred to mean 0); item_trials [I] and respondent_trials [R]
    (real trials, not pseudo-trials); method ("statsmodels GLM" or "scikit-learn L2"); converged."""

    items: tuple[str, ...]
    difficulty: np.ndarray
    difficulty_se: np.ndarray
    respondents: tuple[str, ...]
    ability: np.ndarray
    ability_se: np.ndarray
    item_trials: np.ndarray
    respondent_trials: np.ndarray
    method: str
    converged: bool

    def as_dict(self) -> dict:
        """JSON-able summary."""
        return {"method": self.method, "converged": bool(self.converged), "n_items": len(self.items),
                "respondents": {r: {"ability": float(a), "se": float(s), "trials": int(n)}
                                for r, a, s, n in zip(self.respondents, self.ability, self.ability_se,
                                                      self.respondent_trials)},
                "items": {i: {"difficulty": float(b), "se": float(s), "trials": int(n)}
                          for i, b, s, n in zip(self.items, self.difficulty, self.difficulty_se, self.item_trials)}}


def _cells(items: Sequence[str], respondents: Sequence[str], success: np.ndarray):
    """(item labels, respondent labels, cell item index, cell respondent index, successes, trials) of the observed
    (item, respondent) cells, labels sorted."""
    it_labels, it = np.unique(np.asarray(items, dtype=str), return_inverse=True)
    re_labels, re = np.unique(np.asarray(respondents, dtype=str), return_inverse=True)
    y = np.asarray(success, dtype=float).reshape(-1)
    if not (it.shape[0] == re.shape[0] == y.shape[0]):
        raise ValueError("items, respondents and success must have one entry per trial")
    if not np.isin(y, (0.0, 1.0)).all():
        raise ValueError("success must be 0 or 1 per trial")
    cell = it * len(re_labels) + re
    keys, inv = np.unique(cell, return_inverse=True)
    k = np.bincount(inv, weights=y)
    n = np.bincount(inv).astype(float)
    return (tuple(it_labels.tolist()), tuple(re_labels.tolist()), keys // len(re_labels), keys % len(re_labels),
            k, n)


def _trials_per(idx: np.ndarray, n: np.ndarray, size: int) -> np.ndarray:
    return np.bincount(idx, weights=n, minlength=size).astype(np.int64)


def fit_rasch(items: Sequence[str], respondents: Sequence[str], success: np.ndarray, *,
              prior_trials: float = 1.0) -> RaschFit:
    """1PL fit by statsmodels' binomial GLM (module doc). ``items``, ``respondents``: one label per trial;
    ``success``: 0/1 per trial; ``prior_trials`` (>= 0) pseudo-trials per item (0: plain maximum likelihood, which
    diverges for items that every respondent passed or failed)."""
    import statsmodels.api as sm

    if not prior_trials >= 0:
        raise ValueError(f"prior_trials must be >= 0, got {prior_trials!r}")
    it_labels, re_labels, ci, cr, k, n = _cells(items, respondents, success)
    n_i, n_r = len(it_labels), len(re_labels)
    n_cols = n_r + n_i - 1                                      # abilities, then difficulties of items 1.. (b_0 = 0)
    rows = ci.shape[0] + (n_i if prior_trials > 0 else 0)
    x = np.zeros((rows, n_cols))
    x[np.arange(ci.shape[0]), cr] = 1.0
    sel = ci > 0
    x[np.flatnonzero(sel), n_r + ci[sel] - 1] = -1.0
    succ, fail = k, n - k
    if prior_trials > 0:
        base = ci.shape[0]
        x[base:, :n_r] = 1.0 / n_r
        x[base + np.arange(1, n_i), n_r + np.arange(n_i - 1)] = -1.0
        half = np.full(n_i, 0.5 * prior_trials)
        succ, fail = np.concatenate([succ, half]), np.concatenate([fail, half])
    model = sm.GLM(np.stack([succ, fail], axis=1), x, family=sm.families.Binomial())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = model.fit(tol=1e-10, maxiter=200)
    beta = np.asarray(res.params, dtype=float)
    cov = np.asarray(res.cov_params(), dtype=float)
    # centre: b_c = b - mean(b), theta_c = theta - mean(b); b_0 = 0 is the first item
    expand = np.zeros((n_r + n_i, n_cols))                         # [theta; b_0..b_I-1] = expand @ beta
    expand[np.arange(n_r), np.arange(n_r)] = 1.0
    expand[n_r + np.arange(1, n_i), n_r + np.arange(n_i - 1)] = 1.0
    mean_b = expand[n_r:].mean(axis=0)
    t = expand - mean_b[None, :]
    est = t @ beta
    se = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", t, cov, t), 0.0))
    return RaschFit(it_labels, est[n_r:], se[n_r:], re_labels, est[:n_r], se[:n_r],
                    _trials_per(ci, n, n_i), _trials_per(cr, n, n_r), "statsmodels GLM",
                    bool(getattr(res, "converged", True)))


def fit_rasch_sparse(items: Sequence[str], respondents: Sequence[str], success: np.ndarray, *,
                     prior_sd: float = PRIOR_SD) -> RaschFit:
    """1PL fit by scikit-learn's L2 logistic regression on a sparse design (module doc), for many items (tasks).
    ``prior_sd`` (logits, > 0): the normal prior's standard deviation on every parameter."""
    from scipy import sparse
    from sklearn.linear_model import LogisticRegression

    if not prior_sd > 0:
        raise ValueError(f"prior_sd must be > 0, got {prior_sd!r}")
    it_labels, re_labels, ci, cr, k, n = _cells(items, respondents, success)
    n_i, n_r = len(it_labels), len(re_labels)
    m = ci.shape[0]
    rows = np.repeat(np.arange(2 * m), 2)
    cols = np.tile(np.stack([cr, n_r + ci], axis=1), (2, 1)).reshape(-1)
    vals = np.tile([1.0, -1.0], 2 * m)
    x = sparse.csr_matrix((vals, (rows, cols)), shape=(2 * m, n_r + n_i))
    y = np.concatenate([np.ones(m), np.zeros(m)])
    w = np.concatenate([k, n - k])
    keep = w > 0
    c = float(prior_sd) ** 2
    clf = LogisticRegression(C=c, fit_intercept=False, solver="lbfgs", tol=1e-10, max_iter=5000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clf.fit(x[keep], y[keep], sample_weight=w[keep])
    beta = clf.coef_.reshape(-1)
    theta, b = beta[:n_r], beta[n_r:]
    p = 1.0 / (1.0 + np.exp(-(theta[cr] - b[ci])))
    info = n * p * (1.0 - p)
    b_se = 1.0 / np.sqrt(np.bincount(ci, weights=info, minlength=n_i) + 1.0 / c)
    t_se = 1.0 / np.sqrt(np.bincount(cr, weights=info, minlength=n_r) + 1.0 / c)
    shift = float(b.mean())
    converged = bool(np.all(clf.n_iter_ < clf.max_iter))
    return RaschFit(it_labels, b - shift, b_se, re_labels, theta - shift, t_se, _trials_per(ci, n, n_i),
                    _trials_per(cr, n, n_r), "scikit-learn L2", converged)
