"""User planner plug-ins: the shipped template (tools/templates/my_planner.py) loaded by "module:Class" from a
scenario really flies and avoids, in-process and through the CLI; bad plug-in names are one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT, pbdyn_cmd
from tests.helpers import first_map, handmade_rollout, open_scenario

TEMPLATES = ROOT / "tools" / "templates"
PLUGIN = {"trajectory": "my_planner:GoalSeeker", "gaze": "fullrange", "name": "mine"}


@pytest.fixture
def template_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(TEMPLATES))
    sys.modules.pop("my_planner", None)


@pytest.mark.parametrize("dims", [2, 3])
def test_template_avoids_a_head_on_obstacle_that_straight_line_hits(template_on_path, dims):
    from pbdyn.sim.trial import make_trial_spec, run_trial

    sc = open_scenario(dims, planners=[PLUGIN, {"trajectory": "straight_line", "gaze": "fullrange"}])
    z = [10.0] if dims == 3 else []
    start, goal = (4.0, 25.0, *z), (46.0, 25.0, *z)
    ro = handmade_rollout(sc, [[40.0, 25.0, *z]], [[-3.0, 0.0, *([0.0] if dims == 3 else [])]], [1.0])
    results = {}
    for label in ("mine", "fullrange+straight_line"):
        spec = make_trial_spec(sc, first_map(sc), planner=label, start=start, goal=goal)
        results[label] = run_trial(spec, ro)
    assert results["fullrange+straight_line"].outcome == "dynamic_collision"
    assert results["mine"].outcome == "success" and results["mine"].min_clearance_m >= 0.0
    assert results["mine"].planner == "my_planner:GoalSeeker"


def test_template_runs_from_a_scenario_file_through_the_cli(write_scenario):
    path = write_scenario(
        '[world]\ntime_limit = 40.0\n[obstacles]\ncount = 10\nradius = 0.5\nspeed = 2.0\nroot_seed = 5\n'
        '[drone]\nv_max = [4.0]\n[[planners]]\ntrajectory = "my_planner:GoalSeeker"\ngaze = "lookahead"\n'
        'trajectory_params = { horizon_s = 1.5, n_headings = 9 }\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TEMPLATES), str(ROOT)]))
    out = subprocess.run(pbdyn_cmd() + ["run", str(path), "--json"], capture_output=True, text=True, env=env,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["planner"] == "my_planner:GoalSeeker" and res["outcome"] in ("success", "deadlock", "freezing",
                                                                           "dynamic_collision")
    assert res["steps"] > 10
    bad = write_scenario('[obstacles]\ncount = 0\n[[planners]]\ntrajectory = "my_planner:GoalSeeker"\n'
                         'trajectory_params = { n_headings = 0 }\n', "bad.toml")
    out = subprocess.run(pbdyn_cmd() + ["run", str(bad)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 2 and "n_headings" in out.stderr and len(out.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("name, needle", [
    ("no_such_module_zz:Planner", "cannot import module"),
    ("my_planner:NoSuchClass", "has no attribute"),
    ("tests.helpers:open_scenario", "missing method(s) replan_check, plan"),
])
def test_bad_plugins_are_one_line_errors(write_scenario, name, needle):
    path = write_scenario(f'[obstacles]\ncount = 0\n[[planners]]\ntrajectory = "{name}"\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TEMPLATES), str(ROOT)]))
    out = subprocess.run(pbdyn_cmd() + ["run", str(path)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "planners[0].trajectory" in lines[0]
