"""The public Python API (pbdyn/api.py): every entry point as a notebook user calls it."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pbdyn
from pbdyn.planning.primitives.local import LocalPrimitives
from tests.conftest import SCENARIOS, pbdyn_cmd


def _core(row: dict) -> dict:
    return {k: v for k, v in row.items() if "wall" not in k and k not in ("config_hash", "planner",
                                                                           "planner_label", "planner_fingerprint")}


def test_import_pbdyn_exports_the_api():
    for name in ("load_scenario", "rollout", "run_trial", "compute_metrics", "run_batch", "open_results",
                 "check_planner", "ConfigError", "TrialResult", "Outcome"):
        assert name in dir(pbdyn) and getattr(pbdyn, name) is not None
    with pytest.raises(AttributeError):
        pbdyn.no_such_thing


def test_run_trial_takes_a_name_a_label_a_plugin_string_a_class_or_an_instance():
    by_name = pbdyn.run_trial("quickstart", planner="local_primitives", gaze="lookahead", map=1)
    by_label = pbdyn.run_trial("quickstart", planner="lookahead+local_primitives", map=1)
    by_plugin = pbdyn.run_trial("quickstart", planner="pbdyn.planning.primitives.local:LocalPrimitives",
                                gaze="lookahead", map=1)
    by_class = pbdyn.run_trial("quickstart", planner=LocalPrimitives, gaze="lookahead", map=1)
    sc = pbdyn.load_scenario("quickstart")
    from pbdyn.sim.agent import planner_context
    from pbdyn.sim.spec import make_trial_spec
    from pbdyn.world.maps import get_map

    spec = make_trial_spec(sc, get_map(sc, 1))
    by_instance = pbdyn.run_trial(sc, planner=LocalPrimitives(planner_context(spec)), gaze="lookahead", map=1)
    assert by_name.to_dict() == {**by_label.to_dict(), **{k: v for k, v in by_name.to_dict().items() if "wall" in k}}
    for other in (by_plugin, by_class, by_instance):
        assert _core(other.to_dict()) == _core(by_name.to_dict())
    assert by_class.planner == by_instance.planner == "pbdyn.planning.primitives.local:LocalPrimitives"
    assert by_class.config_hash != by_name.config_hash


def test_run_trial_matches_the_cli_and_writes_a_trace(tmp_path):
    import subprocess

    res = pbdyn.run_trial(SCENARIOS / "quickstart.toml", planner="straight_line", map=2, start=(4, 4),
                          goal=[46.0, 46.0], trace=tmp_path / "t.npz")
    cli = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--planner", "straight_line", "--map", "2", "--start",
                                        "4,4", "--goal", "46,46", "--json"], capture_output=True, text=True,
                         check=True, cwd=tmp_path)
    assert {k: v for k, v in json.loads(cli.stdout).items() if "wall" not in k} == res.without_wall_times()
    with np.load(tmp_path / "t.npz") as z:
        assert z["p"].shape == (res.steps, 2)


def test_library_errors_name_parameters_and_the_cli_names_flags(tmp_path):
    import subprocess

    for kwargs, field in (({"v_max": -1.0}, "v_max"), ({"start": (0.0, 0.0)}, "start"), ({"map": 99}, "map"),
                          ({"planner": "nope"}, "planner"), ({"trace": tmp_path / "t.txt"}, "trace"),
                          ({"planner": object}, "planner")):
        with pytest.raises(pbdyn.ConfigError) as err:
            pbdyn.run_trial("quickstart", **kwargs)
        assert err.value.field == field
    with pytest.raises(pbdyn.ConfigError) as err:
        pbdyn.compute_metrics("quickstart", metrics=["nope"])
    assert err.value.field == "metrics"
    cli = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--vmax", "4", "--start", "0,0"], capture_output=True,
                         text=True, cwd=tmp_path)
    assert cli.returncode == 2 and cli.stderr.startswith("pbdyn: error: --start:") and cli.stderr.count("\n") == 1


def test_compute_metrics_and_rollout():
    ro = pbdyn.rollout("quickstart", map=3)
    assert ro.n_obstacles == 20 and ro.positions.shape[1:] == (20, 2)
    m = pbdyn.compute_metrics("quickstart", map=3, metrics=["density", "survivability"])
    assert set(m) == {"density", "survivability"} and m["survivability"]["value"] > 0
    again = pbdyn.compute_metrics("quickstart", map=3, metrics="density")
    assert again["density"]["value"] == m["density"]["value"] and again["density"]["cached"]
    assert pbdyn.map_info("quickstart", 3)["setup"]["count"] == 20
    assert pbdyn.metric_backend("quickstart") == "analytic"


def test_run_batch_then_open_results_as_a_dataframe(tmp_path):
    out = tmp_path / "r.sqlite"
    s = pbdyn.run_batch("quickstart", out, workers=1, limit=6, progress=False)
    assert (s.total, s.ran, s.errors) == (6, 6, 0)
    with pbdyn.open_results(out) as results:
        trials = results.trials()
        maps = results.maps()
        assert results.count == 6 and results.scenario["world"]["dims"] == 2
    assert len(trials) == 6 and {"start_x", "start_y", "goal_x", "goal_y"} <= set(trials.columns)
    assert trials["start_x"].dtype == float and "metric_survivability" in trials.columns
    assert trials["metric_survivability"].notna().all()
    assert "metric_survivability" in maps.columns and len(maps) >= 1
    assert pbdyn.export_results(out, tmp_path / "t.csv") == 6
    with pytest.raises(pbdyn.ConfigError) as err:
        pbdyn.export_results(out, tmp_path / "t.xlsx")
    assert err.value.field == "format"


def test_check_planner_from_the_api():
    rep = pbdyn.check_planner("straight_line", "quickstart", maps=2, pairs=2)
    assert rep.ok and rep.trials == 4
    from tests.cheating_planners import Teleport

    bad = pbdyn.check_planner(Teleport, maps=1, pairs=1)
    assert not bad.ok and bad.breaches[0].violations[0].check == "position_step"
