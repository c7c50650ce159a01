"""Errors users can act on (issue "Integrity round 3", item 6): a plug-in planner's failure names the user's file and
line (``pbdyn run``, batch error rows), PBDYN_DEBUG=1 prints the traceback, the Python API refuses wrong types with
its own error naming the parameter, ``--vmax`` obeys drone.v_max's limits, and a MAV speed that cannot stop within
the sensor range is one warning line at load time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import pbdyn
from pbdyn.errors import ConfigError
from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd

PLUGIN = '''\
"""Plug-in planners with bugs (written by tests/test_integrity3_errors.py)."""
import numpy as np


def divide(x):
    return 1.0 / x  # BOOM


class Boom:
    def __init__(self, context, **params):
        self.context = context

    def replan_check(self, view):
        return True

    def plan(self, view):
        return divide(0.0)


class BadInit(Boom):
    def __init__(self, context, **params):
        raise RuntimeError("cannot start")  # INIT


class BadGaze:
    def __init__(self, context, **params):
        pass

    def yaw_rate(self, view, trajectory):
        return float(np.linalg.inv(np.zeros((2, 2)))[0, 0])  # GAZE
'''

MODULE = "i3_bad_plugins"


def _line(marker: str) -> int:
    return next(i for i, text in enumerate(PLUGIN.splitlines(), 1) if text.endswith(f"# {marker}"))


@pytest.fixture(scope="module")
def plugin(tmp_path_factory) -> Path:
    """The plug-in module, written into its own folder and importable in this process and in children."""
    folder = tmp_path_factory.mktemp("userpkg")
    path = folder / f"{MODULE}.py"
    path.write_text(PLUGIN)
    sys.path.insert(0, str(folder))
    yield path
    sys.path.remove(str(folder))
    sys.modules.pop(MODULE, None)


def _env(plugin: Path, **extra) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plugin.parent), str(ROOT)]))
    env.pop("PBDYN_DEBUG", None)
    env.update(extra)
    return env


def _pbdyn(args: list[str], env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(pbdyn_cmd() + args, capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)


# ------------------------------------------------------------------------------ a plug-in planner that raises
def test_run_names_the_plugin_file_and_line(plugin):
    res = _pbdyn(["run", "quickstart", "--planner", f"{MODULE}:Boom"], _env(plugin))
    assert res.returncode == 2, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pbdyn: error: --planner:"), res.stderr
    assert "ZeroDivisionError" in lines[0]
    assert f"(at {plugin}:{_line('BOOM')})" in lines[0]
    assert "agent.py" not in lines[0] and not res.stdout


def test_pbdyn_debug_prints_the_whole_traceback(plugin):
    res = _pbdyn(["run", "quickstart", "--planner", f"{MODULE}:Boom"], _env(plugin, PBDYN_DEBUG="1"))
    assert res.returncode == 2, res.stderr
    assert "Traceback (most recent call last)" in res.stderr
    assert f'File "{plugin}", line {_line("BOOM")}' in res.stderr
    assert res.stderr.splitlines()[-1].startswith("pbdyn: error: --planner:")


def test_a_library_call_in_user_code_is_located_in_user_code(plugin):
    """The innermost frame outside pbdyn *and* outside installed libraries: the user's line, not numpy's."""
    with pytest.raises(ConfigError) as err:
        pbdyn.run_trial("quickstart", gaze=f"{MODULE}:BadGaze")
    assert err.value.field == "planner" and "LinAlgError" in str(err.value)
    assert str(err.value).endswith(f"(at {plugin}:{_line('GAZE')})")


def test_a_plugin_constructor_that_raises_is_located(plugin):
    with pytest.raises(ConfigError) as err:
        pbdyn.run_trial("quickstart", planner=f"{MODULE}:BadInit")
    assert "cannot start" in str(err.value) and f"(at {plugin}:{_line('INIT')})" in str(err.value)


BATCH = """
name = "boom"
[world]
time_limit = 5.0
[obstacles]
count = 0
maps_per_setup = 1
[drone]
v_max = 4.0
[[planners]]
trajectory = "{module}:Boom"
gaze = "lookahead"
"""


@pytest.mark.parametrize("lockstep", ["72", "1"])
def test_batch_error_rows_name_the_plugin_file_and_line(plugin, tmp_path, lockstep):
    sc = tmp_path / "boom.toml"
    sc.write_text(BATCH.format(module=MODULE))
    out = tmp_path / "boom.sqlite"
    res = _pbdyn(["batch", str(sc), "--out", str(out), "--workers", "1", "--limit", "2", "--no-metrics", "--json",
                  "--lockstep", lockstep], _env(plugin))
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["errors"] == 2
    from pbdyn.experiments.store import ResultsStore

    store = ResultsStore.open(out)
    try:
        rows = store.results()
    finally:
        store.close()
    assert len(rows) == 2
    for row in rows:
        assert row["outcome"] == "error"
        assert row["error"].endswith(f"(at {plugin}:{_line('BOOM')})"), row["error"]
        assert "agent.py" not in row["error"]


# ------------------------------------------------------------------------------ Python API types
API_CASES = [
    ("start", lambda tmp: pbdyn.run_trial("quickstart", start=(4, 4, 4))),
    ("start", lambda tmp: pbdyn.run_trial("quickstart", start=(4,))),
    ("goal", lambda tmp: pbdyn.run_trial("quickstart", goal=[4])),
    ("start", lambda tmp: pbdyn.run_trial("quickstart", start=(float("nan"), 4))),
    ("start", lambda tmp: pbdyn.run_trial("quickstart", start=4)),
    ("observers", lambda tmp: pbdyn.run_trial("quickstart", observers=42)),
    ("observers", lambda tmp: pbdyn.run_trial("quickstart", observers=[42])),
    ("path", lambda tmp: pbdyn.open_results(123).__enter__()),
    ("trace", lambda tmp: pbdyn.replay(123, str(tmp / "x.gif"))),
    ("inputs", lambda tmp: pbdyn.merge_results(str(tmp / "m.sqlite"), [123])),
    ("inputs", lambda tmp: pbdyn.merge_results(str(tmp / "m.sqlite"), 123)),
    ("out", lambda tmp: pbdyn.merge_results(123, [str(tmp / "a.sqlite")])),
    ("maps", lambda tmp: pbdyn.check_planner("local_primitives", maps=2.5)),
    ("maps", lambda tmp: pbdyn.check_planner("local_primitives", maps=0)),
    ("maps", lambda tmp: pbdyn.check_planner("local_primitives", maps=[])),
    ("maps", lambda tmp: pbdyn.check_planner("local_primitives", maps=True)),
    ("maps", lambda tmp: pbdyn.check_planner("local_primitives", maps="2")),
    ("v_max", lambda tmp: pbdyn.run_trial("quickstart", v_max=1e300)),
    ("v_max", lambda tmp: pbdyn.run_trial("quickstart", v_max=True)),
    ("v_max", lambda tmp: pbdyn.check_planner("local_primitives", v_max=1e300)),
]


@pytest.mark.parametrize("field,call", API_CASES, ids=[f"{i}-{f}" for i, (f, _) in enumerate(API_CASES)])
def test_api_type_errors_name_the_parameter(tmp_path, field, call):
    with pytest.raises(ConfigError) as err:
        call(tmp_path)
    assert err.value.field == field, str(err.value)
    assert "\n" not in str(err.value)


def test_vmax_limit_is_drone_v_max_limit():
    with pytest.raises(ConfigError) as flag:
        pbdyn.run_trial("quickstart", v_max=2e9)
    with pytest.raises(ConfigError) as field:
        pbdyn.load_scenario({"drone": {"v_max": 2e9}})
    assert flag.value.problem == field.value.problem


def test_cli_vmax_obeys_the_drone_v_max_limit():
    res = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--vmax", "1e300"], capture_output=True, text=True,
                         timeout=600, cwd=ROOT)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pbdyn: error: --vmax:") and "1e300" in lines[0], res.stderr


# ------------------------------------------------------------------------------ speeds that cannot stop in time
def test_cli_warns_once_when_vmax_cannot_stop_within_the_sensor_range():
    res = subprocess.run(pbdyn_cmd() + ["run", "quickstart", "--vmax", "14.4", "--json"], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    json.loads(res.stdout)                       # one JSON document, the warning is not in it
    warned = [line for line in res.stderr.splitlines() if "warning" in line.lower()]
    assert len(warned) == 1, res.stderr
    assert warned[0].startswith("pbdyn: warning: --vmax:") and "14.4" in warned[0] and "8 m" in warned[0]


def test_cli_warns_once_for_a_scenario_speed(tmp_path):
    sc = tmp_path / "fast.toml"
    sc.write_text((SCENARIOS / "quickstart.toml").read_text().replace("v_max = [4.0]", "v_max = [4.0, 14.4]"))
    res = subprocess.run(pbdyn_cmd() + ["run", str(sc), "--vmax", "14.4", "--json"], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    warned = [line for line in res.stderr.splitlines() if "warning" in line.lower()]
    assert len(warned) == 1 and warned[0].startswith("pbdyn: warning: drone.v_max:"), res.stderr


def test_api_warns_for_speeds_that_cannot_stop():
    from pbdyn.errors import PbdynWarning

    with pytest.warns(PbdynWarning, match=r"drone\.v_max.*14\.4") as caught:
        sc = pbdyn.load_scenario({"drone": {"v_max": [4.0, 14.4]}})
    assert len(caught) == 1 and caught[0].message.field == "drone.v_max"
    with pytest.warns(PbdynWarning, match=r"drone\.v_max"):       # a slow MAV brakes too weakly
        pbdyn.load_scenario({"drone": {"v_max": 4.0, "a_max": 0.5}})
    with pytest.warns(PbdynWarning, match=r"drone\.v_max"):       # a short-sighted sensor
        pbdyn.load_scenario({"drone": {"v_max": 4.0}, "sensor": {"range": 2.0}})
    from pbdyn.sim.spec import make_trial_spec
    from pbdyn.world.maps import get_map

    with pytest.warns(PbdynWarning, match=r"^v_max: "):
        make_trial_spec(sc, get_map(sc, 0), v_max=20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make_trial_spec(sc, get_map(sc, 0), v_max=14.4)          # warned when the scenario was loaded
        make_trial_spec(sc, get_map(sc, 0), v_max=7.0)


@pytest.mark.parametrize("path", sorted(SCENARIOS.rglob("*.toml")), ids=lambda p: str(p.relative_to(SCENARIOS)))
def test_bundled_scenarios_load_silently(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pbdyn.load_scenario(path)
