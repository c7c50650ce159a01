"""The shipped anchors of the difficulty scale (pbdyn/analysis/data/anchors.json) reproduce from the shipped
calibration outcomes (tools/fit_anchors.py), fix the scale's zero at the 2D calibration maps' mean difficulty, and
are what calibrate and evaluate read."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from pbdyn.analysis.scale import RESPONDENTS, SCALE_VERSION, load_anchors
from tests.conftest import ROOT

sys.path.insert(0, str(ROOT))
import tools.fit_anchors as fa  # noqa: E402

DATA = ROOT / "pbdyn" / "analysis" / "data"


def test_the_shipped_anchors_reproduce_from_the_shipped_calibration_outcomes():
    shipped = json.loads((DATA / "anchors.json").read_text())
    outcomes = fa.read_outcomes(DATA / "calibration_2d.csv.gz")
    assert len({r["map_id"] for r in outcomes}) == 56 and len(outcomes) == 56 * 180
    refit = fa.fit(outcomes)
    assert refit["abilities"] == pytest.approx(shipped["abilities"], abs=1e-6)
    assert shipped["version"] == SCALE_VERSION
    diffs = fa.map_difficulties(outcomes, shipped["abilities"])
    assert diffs == pytest.approx(shipped["difficulties"]["2"], abs=1e-6)
    assert abs(float(np.mean(diffs))) < 1e-3                # the scale's zero: the 2D calibration maps' mean


def test_calibrate_and_evaluate_read_the_shipped_anchors():
    anchors = load_anchors()
    assert anchors is not None and set(anchors.abilities) >= set(RESPONDENTS)
    theta = anchors.theta()
    assert np.all(np.isfinite(theta))
    assert anchors.percentile(-50.0, 2) == 0.0 and anchors.percentile(50.0, 2) == 100.0
    assert anchors.success(-10.0) > 0.99 and anchors.success(10.0) < 0.01


def test_evaluate_places_panel_stores_on_the_shipped_scale_and_says_when_it_cannot(tmp_path):
    import subprocess

    import tomli_w

    import pbdyn
    from tests.conftest import pbdyn_cmd

    small = {"name": "anchored_small", "world": {"time_limit": 25.0},
             "obstacles": {"count": [8], "radius": 1.0, "speed": 3.0, "maps_per_setup": 2, "root_seed": 11},
             "task": {"candidates": [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0]]}}
    res = pbdyn.calibrate(small, store=tmp_path / "panel.sqlite", workers=2)
    other = dict(small, name="other", planners=[{"trajectory": "straight_line", "gaze": "fullrange"}],
                 drone={"v_max": [3.0]})
    (tmp_path / "other.toml").write_text(tomli_w.dumps(other))
    out = subprocess.run(pbdyn_cmd() + ["batch", str(tmp_path / "other.toml"), "--out", str(tmp_path / "other.sqlite"),
                                        "--workers", "1"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    out = subprocess.run(pbdyn_cmd() + ["evaluate", str(tmp_path / "panel.sqlite"), str(tmp_path / "other.sqlite"),
                                        "--json"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    section = json.loads(out.stdout)["anchored_scale"]
    assert section["anchored"] and section["scale"].startswith(f"anchored-{SCALE_VERSION}/")
    placed = [d for d in section["datasets"].values() if d["placed"]]
    refused = [d for d in section["datasets"].values() if not d["placed"]]
    assert len(placed) == 1 and len(refused) == 1 and "cannot be placed on the anchored scale" in refused[0]["why"]
    # the store's maps get the difficulty calibrate gives them: the same fixed abilities, no re-centring
    by_id = {r.map_id: r.difficulty for r in res}
    got = {k.rsplit("/", 1)[-1]: v for k, v in placed[0]["difficulty"].items()}     # dataset/map_id
    assert set(got) == set(by_id)
    for mid, d in got.items():
        assert d["logit"] == pytest.approx(by_id[mid], abs=1e-9)
    text = subprocess.run(pbdyn_cmd() + ["evaluate", str(tmp_path / "panel.sqlite"), str(tmp_path / "other.sqlite")],
                          capture_output=True, text=True, timeout=600).stdout
    assert "Anchored scale (anchored-" in text and "cannot be placed" in text
