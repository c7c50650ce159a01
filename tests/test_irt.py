"""The item-response fit (pbdyn.analysis.irt): known abilities and difficulties recovered from outcomes simulated
from the model, within their standard errors; both fits agree; perfect items stay finite; bad input."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.analysis.irt import fit_rasch, fit_rasch_sparse


def _simulate(seed=1, n_items=60, n_resp=5, per=40):
    rng = np.random.default_rng(seed)
    b = rng.normal(0.0, 1.2, n_items)
    b -= b.mean()
    theta = rng.normal(0.3, 1.0, n_resp)
    it = np.repeat(np.arange(n_items), n_resp * per)
    re = np.tile(np.repeat(np.arange(n_resp), per), n_items)
    p = 1.0 / (1.0 + np.exp(-(theta[re] - b[it])))
    y = (rng.random(p.shape) < p).astype(float)
    return [f"map{i:03d}" for i in it], [f"planner{r}" for r in re], y, b, theta


@pytest.mark.parametrize("fit", [fit_rasch, fit_rasch_sparse])
def test_recovers_simulated_difficulties_and_abilities_within_their_standard_errors(fit):
    items, resp, y, b, theta = _simulate()
    res = fit(items, resp, y)
    assert res.converged and res.items == tuple(f"map{i:03d}" for i in range(60))
    z = (res.difficulty - b) / res.difficulty_se
    assert np.mean(np.abs(z) < 1.96) >= 0.88 and 0.6 < np.mean(np.abs(z)) < 1.0   # ~N(0, 1): 95%, mean 0.80
    assert abs(np.mean(res.difficulty)) < 1e-9
    # abilities on the same (centred) scale as the true ones, whose difficulties were centred too
    zt = (res.ability - theta) / res.ability_se
    assert np.all(np.abs(zt) < 3.5)
    assert np.all(res.difficulty_se > 0) and np.all(res.ability_se > 0)
    assert res.item_trials.tolist() == [200] * 60 and res.respondent_trials.tolist() == [2400] * 5
    # a wrong model (difficulties shuffled) is far outside the errors
    zs = (res.difficulty - np.random.default_rng(0).permutation(b)) / res.difficulty_se
    assert np.mean(np.abs(zs) < 1.96) < 0.5


def test_the_two_fits_agree_and_are_deterministic():
    items, resp, y, _, _ = _simulate(seed=4, n_items=30, n_resp=4, per=30)
    a = fit_rasch(items, resp, y)
    b = fit_rasch_sparse(items, resp, y)
    assert np.max(np.abs(a.difficulty - b.difficulty)) < 0.1
    assert np.max(np.abs(a.difficulty_se - b.difficulty_se) / a.difficulty_se) < 0.1
    again = fit_rasch(items, resp, y)
    assert np.array_equal(a.difficulty, again.difficulty) and np.array_equal(a.ability_se, again.ability_se)
    # the order of the trials does not matter
    perm = np.random.default_rng(2).permutation(len(y))
    shuffled = fit_rasch([items[i] for i in perm], [resp[i] for i in perm], y[perm])
    np.testing.assert_allclose(shuffled.difficulty, a.difficulty, atol=1e-9)


def test_items_everyone_passed_or_failed_stay_finite_and_ordered():
    items, resp, y, _, _ = _simulate(seed=5, n_items=20, n_resp=3, per=20)
    y = y.copy()
    items = np.asarray(items)
    y[items == "map000"] = 1.0                     # everybody succeeded: the easiest
    y[items == "map001"] = 0.0                     # everybody failed: the hardest
    for fit in (fit_rasch, fit_rasch_sparse):
        res = fit(items.tolist(), resp, y)
        assert np.all(np.isfinite(res.difficulty)) and np.all(np.isfinite(res.difficulty_se))
        assert res.difficulty[0] == res.difficulty.min() and res.difficulty[1] == res.difficulty.max()
        assert res.difficulty_se[0] > np.median(res.difficulty_se)      # less information at the extremes


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="one entry per trial"):
        fit_rasch(["a", "b"], ["r"], np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="0 or 1"):
        fit_rasch(["a"], ["r"], np.array([0.5]))
    with pytest.raises(ValueError, match="prior_sd"):
        fit_rasch_sparse(["a"], ["r"], np.array([1.0]), prior_sd=0.0)
