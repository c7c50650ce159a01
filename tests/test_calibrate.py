"""`pbdyn calibrate` and the anchored scale's arithmetic (pbdyn.analysis.scale, pbdyn.experiments.calibrate): real
panel flights into results stores, a map's difficulty with fixed abilities against statsmodels, the same difficulty
for the same map from two stores."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

import pbdyn
from pbdyn.analysis.scale import (PANEL, PANEL_SPEEDS, RESPONDENTS, Anchors, ability_given_difficulties,
                                  difficulty_given_abilities, sigmoid)
from pbdyn.experiments.calibrate import measure_store
from tests.conftest import pbdyn_cmd

SMALL = {"name": "cal_small", "world": {"time_limit": 25.0},
         "obstacles": {"count": [8, 16], "radius": 1.0, "speed": 3.0, "maps_per_setup": 2, "root_seed": 11},
         "task": {"candidates": [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0]]}}
ANCHORS = Anchors("test", {r: a for r, a in zip(RESPONDENTS, np.linspace(2.0, -1.0, len(RESPONDENTS)))},
                  {"2": list(np.linspace(-2.0, 2.0, 41))})


def test_a_maps_difficulty_with_fixed_abilities_matches_statsmodels():
    import statsmodels.api as sm

    rng = np.random.default_rng(3)
    theta = rng.normal(0.0, 1.0, 9)
    n = np.full(9, 40)
    for b in (-1.5, 0.2, 2.5):
        k = rng.binomial(n, sigmoid(theta - b))
        ref = sm.GLM(np.stack([k, n - k], 1), -np.ones((9, 1)), family=sm.families.Binomial(),
                     offset=theta).fit(tol=1e-12).params[0]
        assert difficulty_given_abilities(theta, k, n, prior_trials=0) == pytest.approx(ref, abs=1e-8)
    bs = rng.normal(0.0, 1.0, 7)
    m = np.full(7, 50)
    k = rng.binomial(m, sigmoid(0.4 - bs))
    ref = sm.GLM(np.stack([k, m - k], 1), np.ones((7, 1)), family=sm.families.Binomial(),
                 offset=-bs).fit(tol=1e-12).params[0]
    assert ability_given_difficulties(bs, k, m, prior_trials=0) == pytest.approx(ref, abs=1e-8)
    # every trial succeeded: finite with the prior, and easier than any map with a failure
    all_ok = difficulty_given_abilities(theta, n, n)
    assert np.isfinite(all_ok) and all_ok < difficulty_given_abilities(theta, n - 1, n)


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    res = pbdyn.calibrate(SMALL, maps=[1, 2], store=d / "a.sqlite", workers=2)
    return d, res


def test_calibrate_flies_the_panel_on_the_reference_tasks(flown):
    d, res = flown
    assert [r.map_index for r in res] == [1, 2]
    for r in res:
        assert r.trials == len(PANEL) * len(PANEL_SPEEDS) * 6 and r.tasks == 6
        assert 0.0 <= r.success_ci[0] <= r.success <= r.success_ci[1] <= 1.0
    with pbdyn.open_results(d / "a.sqlite") as results:
        t = results.trials()
    assert set(t["planner_label"]) == {e.label for e in PANEL} and set(t["mav_speed"]) == set(PANEL_SPEEDS)
    assert set(t["map_index"]) == {0, 1}                     # the reference scenario lists the two maps


def test_the_same_map_has_the_same_difficulty_from_two_stores(flown, tmp_path):
    d, res = flown
    other = pbdyn.calibrate(SMALL, maps=[2], store=tmp_path / "b.sqlite", workers=1)
    a = measure_store(d / "a.sqlite", anchors=ANCHORS)
    b = measure_store(tmp_path / "b.sqlite", anchors=ANCHORS)
    by_id = {r.map_id: r for r in a}
    assert other[0].map_id == res[1].map_id and b[0].map_id in by_id
    ra, rb = by_id[b[0].map_id], b[0]
    assert (ra.success, ra.success_ci, ra.difficulty, ra.difficulty_ci, ra.percentile) == \
        (rb.success, rb.success_ci, rb.difficulty, rb.difficulty_ci, rb.percentile)
    assert ra.difficulty_ci[0] <= ra.difficulty <= ra.difficulty_ci[1]
    assert abs(ANCHORS.success(ra.difficulty) - ra.success) < 0.15


def test_calibrate_on_the_command_line_resumes_and_prints_json(flown, tmp_path):
    d, res = flown
    store = tmp_path / "c.sqlite"
    store.write_bytes((d / "a.sqlite").read_bytes())
    path = tmp_path / "small.toml"
    import tomli_w

    path.write_text(tomli_w.dumps(SMALL))
    out = subprocess.run(pbdyn_cmd() + ["calibrate", str(path), "--map", "1", "--map", "2", "--store", str(store),
                                        "--json"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert [m["map_index"] for m in doc["maps"]] == [1, 2] and "already" not in out.stdout
    assert [m["success"] for m in doc["maps"]] == [r.success for r in res]
    bad = subprocess.run(pbdyn_cmd() + ["calibrate", str(path), "--map", "9"], capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--map" in bad.stderr
