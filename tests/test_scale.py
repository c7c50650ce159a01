"""The anchored difficulty scale's fixed parts (pbdyn.analysis.scale): the reference panel's tasks of a map, the
documents that fly them without changing the map, task.pairs_flown, and the frozen calibration sets."""

from __future__ import annotations

import subprocess
import sys

import pytest

import pbdyn
from pbdyn.analysis.scale import PANEL, PANEL_SPEEDS, reference_candidates, reference_document, reference_pairs
from pbdyn.experiments.tasks import enumerate_trials
from tests.conftest import ROOT


def test_reference_tasks_are_the_corners_and_centre_of_the_default_candidates():
    for name in ("quickstart", "spheres_3d"):
        sc = pbdyn.load_scenario(name)
        idx = reference_candidates(sc.task.candidates)
        pts = [sc.task.candidates[i][:2] for i in idx]
        assert sorted(pts) == [(4.0, 4.0), (4.0, 46.0), (25.0, 25.0), (46.0, 4.0), (46.0, 46.0)]
        assert len(reference_pairs(sc.task.candidates)) == 20
    assert reference_pairs([(2.0, 2.0), (8.0, 8.0)]) == [(0, 1), (1, 0)]


def test_the_reference_document_flies_the_same_maps_and_trials():
    doc = {"obstacles": {"count": [10, 20], "radius": 1.0, "speed": 3.0, "structure": ["uniform", "crossing"],
                         "root_seed": 4}}
    sc = pbdyn.load_scenario(doc)
    ref = pbdyn.load_scenario(reference_document(doc, sc.task.candidates))
    assert [p.label for p in ref.planners] == [e.label for e in PANEL] and ref.drone.v_max == PANEL_SPEEDS
    for m in range(4):
        a, b = pbdyn.rollout(sc, map=m), pbdyn.rollout(ref, map=m)
        assert (a.positions == b.positions).all() and pbdyn.map_info(sc, m) == pbdyn.map_info(ref, m)
    full = pbdyn.load_scenario({**doc, "planners": [{"trajectory": e.trajectory, "gaze": e.gaze} for e in PANEL],
                                "drone": {"v_max": list(PANEL_SPEEDS)}})
    keys = {t[0] for t in enumerate_trials(full)}
    flown = enumerate_trials(ref)
    assert len(flown) == 4 * 3 * 3 * 20 == ref.n_trials() and all(t[0] in keys for t in flown)
    assert {(t[4], t[5]) for t in flown} == {(sc.task.candidates[i], sc.task.candidates[j])
                                            for i, j in reference_pairs(sc.task.candidates)}


@pytest.mark.parametrize("bad, why", [([[0, 0]], "two different"), ([[0, 9]], "two different"), ([], "non-empty"),
                                      ([[0, 1], [0, 1]], "each pair once"), ([[0, 1.0]], "two different")])
def test_pairs_flown_is_checked(bad, why):
    with pytest.raises(pbdyn.ConfigError, match=why):
        pbdyn.load_scenario({"task": {"pairs_flown": bad}})


def test_the_calibration_sets_are_as_the_tool_writes_them():
    res = subprocess.run([sys.executable, "tools/make_calibration.py", "--check"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    for dims in (2, 3):
        sc = pbdyn.load_scenario(f"calibration/calibration_{dims}d")
        assert len(sc.obstacles.maps) == 56 and sc.world.dims == dims
        assert {m.structure for m in sc.obstacles.maps} == set(pbdyn.config.BUILTIN_STRUCTURES)
