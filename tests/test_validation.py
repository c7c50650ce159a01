"""Issue 12 hardening: no bad input reaches a trial. Every case is refused when the scenario is loaded (or the
planner built), as one ConfigError line naming the field and the value; the CLI exits 2 without a traceback."""

from __future__ import annotations

import math
import os
import subprocess

import numpy as np
import pytest

from pbdyn import limits
from pbdyn.config import load_scenario, parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.planning import registry
from pbdyn.planning.gaze.rules import LookAhead
from pbdyn.planning.primitives.global_astar import GlobalPrimitives
from pbdyn.planning.primitives.local import LocalPrimitives
from pbdyn.planning.mpc.planner import MPC
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.straight_line import StraightLine
from pbdyn.planning.view import MAVLimits
from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd

NAN, INF = math.nan, math.inf
BOX_URDF = """<?xml version="1.0"?>
<robot name="t">
  <link name="base">
    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="0"/>
      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <collision><origin xyz="{xyz}" rpy="{rpy}"/><geometry>{geometry}</geometry></collision>
    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><box size="1 1 1"/></geometry></visual>
  </link>
</robot>
"""


def _cli(args, cwd=ROOT):
    return subprocess.run(pbdyn_cmd() + [str(a) for a in args], capture_output=True, text=True, cwd=cwd,
                          env=dict(os.environ), timeout=300)


def _refused(doc: dict, field: str) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        parse_scenario(doc)
    assert err.value.field == field, str(err.value)
    assert "\n" not in str(err.value)
    return err.value


def _context(dims: int = 2) -> PlannerContext:
    return PlannerContext(dims, 0.1, MAVLimits(1.0, 2.0, 4.0, 1.4), np.zeros(dims), np.full(dims, 50.0), 0)


# ------------------------------------------------------------------------------------------------ 1: numbers
@pytest.mark.parametrize("tracking, field", [
    ({"q": 0.0}, "tracking.q"),                       # Q = R = 0: "Singular matrix" in every trial
    ({"q": 0}, "tracking.q"),
    ({"q": 5e-324}, "tracking.q"),                    # a denormal variance: NaN covariances
    ({"q": 1e-5, "r": 1e-300}, "tracking.r"),
    ({"p0_pos": 0.0}, "tracking.p0_pos"),
    ({"p0_vel": 0.0}, "tracking.p0_vel"),
    ({"p0_vel": 1e-320}, "tracking.p0_vel"),
    ({"drop_pos_var": 0.0}, "tracking.drop_pos_var"),
    ({"q": NAN}, "tracking.q"),
    ({"r": INF}, "tracking.r"),
    ({"q": -1e-5}, "tracking.q"),
])
def test_tracking_values_the_kalman_filter_cannot_use_are_refused(tracking, field):
    _refused({"tracking": tracking}, field)


def test_tracking_allows_zero_process_noise_with_measurement_noise():
    sc = parse_scenario({"tracking": {"q": 0.0, "r": 0.01}})
    assert sc.tracking.q == 0.0 and sc.tracking.r == 0.01


@pytest.mark.parametrize("doc, field", [
    ({"world": {"dt": 0.0}}, "world.dt"),
    ({"world": {"dt": NAN}}, "world.dt"),
    ({"world": {"time_limit": -1.0}}, "world.time_limit"),
    ({"world": {"grid_resolution": 0.0}}, "world.grid_resolution"),
    ({"world": {"size": [50.0, 0.0]}}, "world.size[1]"),
    ({"world": {"flight_height": 0.0}}, "world.flight_height"),
    ({"sensor": {"range": 0.0}}, "sensor.range"),
    ({"sensor": {"resolution_deg": 0.0}}, "sensor.resolution_deg"),
    ({"sensor": {"fov_deg": NAN}}, "sensor.fov_deg"),
    ({"task": {"goal_radius": 0.0}}, "task.goal_radius"),
    ({"drone": {"radius": -1.0}}, "drone.radius"),
    ({"drone": {"a_max": 0.0}}, "drone.a_max"),
    ({"drone": {"yaw_rate_limit": INF}}, "drone.yaw_rate_limit"),
    ({"drone": {"v_max": [2.0, NAN]}}, "drone.v_max[1]"),
])
def test_zero_negative_or_non_finite_numbers_are_refused(doc, field):
    _refused(doc, field)


# ------------------------------------------------------------------------------------------------ 2: planner params
@pytest.mark.parametrize("cls, params, key", [
    (LocalPrimitives, {"step_m": NAN}, "step_m"),
    (LocalPrimitives, {"jerk_max": NAN}, "jerk_max"),
    (LocalPrimitives, {"margin": INF}, "margin"),
    (MPC, {"w_goal": NAN}, "w_goal"),
    (MPC, {"ref_dist": -INF}, "ref_dist"),
    (GlobalPrimitives, {"rho": [1.0, NAN]}, "rho"),
    (StraightLine, {"horizon_s": NAN}, "horizon_s"),
    (LookAhead, {"gain": NAN}, "gain"),
])
def test_build_planner_refuses_non_finite_parameters_naming_the_key(cls, params, key):
    with pytest.raises(ConfigError) as err:
        registry.build_planner(cls, _context(), params, "planners[0].trajectory_params")
    assert err.value.field == f"planners[0].trajectory_params.{key}"


@pytest.mark.parametrize("cls, params", [
    (LocalPrimitives, {"step_m": NAN}), (LocalPrimitives, {"jerk_max": NAN}), (LocalPrimitives, {"margin": NAN}),
    (LocalPrimitives, {"min_duration": NAN}), (LocalPrimitives, {"n_candidates": 2.5}),
    (MPC, {"w_goal": NAN}), (MPC, {"w_acc": NAN}), (MPC, {"wall_margin": NAN}), (MPC, {"max_slack": NAN}),
    (MPC, {"slack_window_s": NAN}), (MPC, {"ref_dist": NAN}), (MPC, {"margin": INF}),
    (GlobalPrimitives, {"max_expansions": INF}), (StraightLine, {"horizon_s": NAN}), (LookAhead, {"gain": NAN}),
])
def test_built_in_planners_check_their_own_ranges_against_nan(cls, params):
    with pytest.raises(ValueError, match=f"^{next(iter(params))} must be"):
        cls(_context(), **params)


class ExplodingPlanner:
    """A plug-in whose constructor fails with something other than TypeError / ValueError."""

    def __init__(self, context, **params):
        raise RuntimeError("boom\nsecond line")

    def replan_check(self, view):
        return True

    def plan(self, view):
        return None


def test_a_plugin_whose_constructor_raises_anything_is_a_config_error():
    with pytest.raises(ConfigError) as err:
        registry.build_planner(ExplodingPlanner, _context(), {}, "planners[1].trajectory_params")
    assert err.value.field == "planners[1].trajectory_params"
    assert "RuntimeError: boom second line" in str(err.value) and "\n" not in str(err.value)


def test_scenario_refuses_non_finite_planner_parameters_at_load_time():
    _refused({"planners": [{"trajectory_params": {"step_m": NAN}}]}, "planners[0].trajectory_params.step_m")
    _refused({"planners": [{}, {"gaze_params": {"gain": INF}, "name": "b"}]}, "planners[1].gaze_params.gain")


def test_cli_run_with_a_nan_gaze_parameter_exits_2(write_scenario):
    path = write_scenario('[[planners]]\ngaze = "lookahead"\ngaze_params = { gain = nan }\n')
    proc = _cli(["run", path])
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == ("pbdyn: error: planners[0].gaze_params.gain: must be finite (no NaN or infinity) "
                                   "(got nan)")


# ------------------------------------------------------------------------------------------------ 3: URDF geometry
def _urdf(tmp_path, geometry="<box size=\"1 1 1\"/>", xyz="0 0 0", rpy="0 0 0", name="body.urdf"):
    p = tmp_path / name
    p.write_text(BOX_URDF.format(geometry=geometry, xyz=xyz, rpy=rpy))
    return str(p)


BAD_GEOMETRY = [
    dict(geometry='<box size="0 1 1"/>'),
    dict(geometry='<box size="-1 1 1"/>'),
    dict(geometry='<box size="nan 1 1"/>'),
    dict(geometry='<box size="1 1"/>'),
    dict(geometry='<sphere radius="0"/>'),
    dict(geometry='<sphere radius="inf"/>'),
    dict(geometry='<cylinder radius="1" length="0"/>'),
    dict(geometry='<cylinder radius="-1" length="1"/>'),
    dict(geometry='<cylinder radius="1"/>'),
    dict(geometry='<mesh filename="missing.obj"/>'),
    dict(geometry='<capsule radius="1" length="1"/>'),
    dict(geometry=''),
    dict(rpy="a b c"),
    dict(xyz="0 nan 0"),
    dict(rpy="0 0"),
]


@pytest.mark.parametrize("bad", BAD_GEOMETRY)
def test_bad_urdf_geometry_of_a_world_body_is_refused_at_load_time(tmp_path, bad):
    path = _urdf(tmp_path, **bad)
    err = _refused({"world": {"time_limit": 20.0}, "bodies": [{"urdf": str(ROOT / "urdf" / "box.urdf"),
                                                               "position": [10.0, 10.0]},
                                                              {"urdf": path, "position": [30.0, 30.0]}]},
                   "bodies[1].urdf")
    assert "body.urdf" in str(err)


@pytest.mark.parametrize("bad", BAD_GEOMETRY[:3] + [dict(rpy="a b c")])
def test_bad_urdf_geometry_of_the_drone_is_refused_at_load_time(tmp_path, bad):
    _refused({"drone": {"urdf": _urdf(tmp_path, **bad)}}, "drone.urdf")


def test_a_missing_drone_urdf_is_refused_at_load_time(tmp_path):
    err = _refused({"drone": {"urdf": str(tmp_path / "nope.urdf")}}, "drone.urdf")
    assert "file not found" in str(err)


def test_a_body_scale_that_breaks_a_sphere_is_refused_at_load_time():
    _refused({"world": {"time_limit": 20.0},
              "bodies": [{"urdf": "sphere.urdf", "scale": [1.0, 2.0, 1.0], "position": [10.0, 10.0]}]},
             "bodies[0].urdf")


def test_a_valid_custom_urdf_is_accepted(tmp_path):
    sc = parse_scenario({"world": {"time_limit": 20.0},
                         "bodies": [{"urdf": _urdf(tmp_path, xyz="0.5 0 0"), "position": [30.0, 30.0]}],
                         "drone": {"urdf": _urdf(tmp_path, geometry='<sphere radius="1"/>', name="mav.urdf")}})
    assert len(sc.bodies) == 1


@pytest.mark.parametrize("command", ["run", "rollout", "metrics"])
def test_cli_refuses_a_nan_body_size_with_exit_2(tmp_path, write_scenario, command):
    path = _urdf(tmp_path, geometry='<box size="nan 1 1"/>')
    scen = write_scenario(f'[world]\ntime_limit = 20.0\n[[bodies]]\nurdf = "{path}"\nposition = [30.0, 30.0]\n')
    args = [command, scen] + (["--out", tmp_path / "r.npz"] if command == "rollout" else [])
    proc = _cli(args)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("pbdyn: error: bodies[0].urdf: body.urdf: link 'base' <collision> <box> size")
    assert len(proc.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------------------------------------ 4: static obstacles
@pytest.mark.parametrize("static", [
    {"kind": "pillar", "center": [4.0, 4.0], "radius": 0.5},
    {"kind": "pillar", "center": [5.5, 25.0], "radius": 1.0},      # 0.5 m from (4, 25): the MAV (1 m) overlaps it
    {"kind": "box", "center": [46.0, 46.0], "size": [3.0, 3.0]},
    {"kind": "box", "center": [25.0, 26.5], "size": [1.0, 1.0], "yaw_deg": 45.0},  # corner 0.79 m from (25, 25)
])
def test_a_static_obstacle_on_a_start_goal_candidate_is_refused(static):
    err = _refused({"static_obstacles": [{"kind": "pillar", "center": [15.0, 15.0], "radius": 1.0}, static]},
                   "static_obstacles[1]")
    assert "task.candidates[" in str(err)


def test_static_obstacles_clear_of_the_candidates_are_accepted():
    sc = parse_scenario({"static_obstacles": [{"kind": "pillar", "center": [15.0, 15.0], "radius": 1.0},
                                              {"kind": "box", "center": [25.0, 29.0], "size": [2.0, 2.0]}]})
    assert len(sc.static_obstacles) == 2


# ------------------------------------------------------------------------------------------------ 5: TOML
def test_deeply_nested_toml_is_one_line_exit_2(write_scenario):
    path = write_scenario("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ConfigError, match=r"^scenario: nested too deeply"):
        load_scenario(path)
    proc = _cli(["metrics", path])
    # the CLI names its SCENARIO argument
    assert proc.returncode == 2 and proc.stderr.startswith("pbdyn: error: SCENARIO: nested too deeply")
    assert "Traceback" not in proc.stderr


def test_moderately_nested_parameters_are_refused_before_they_reach_json():
    params = current = {}
    for _ in range(40):
        current["x"] = {}
        current = current["x"]
    with pytest.raises(ConfigError, match=r"^scenario: nested too deeply"):
        parse_scenario({"planners": [{"trajectory_params": params}]})


def test_binary_or_malformed_toml_is_one_line(write_scenario, tmp_path):
    bad = tmp_path / "bin.toml"
    bad.write_bytes(b"\xff\xfe\x00name = 1\n")
    with pytest.raises(ConfigError, match=r"^scenario: bin.toml is not UTF-8 text$"):
        load_scenario(bad)
    with pytest.raises(ConfigError) as err:
        load_scenario(write_scenario("a = [1,\n"))
    assert err.value.field == "scenario" and "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------------ 6: one line
def test_a_key_with_a_newline_gives_a_one_line_error(write_scenario):
    path = write_scenario('"a\\nb" = 1\n[world]\n"x\\u001b[31my" = 2\n')
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert str(err.value).startswith("a\\nb: unknown key") and "\n" not in str(err.value)
    err = _refused({"world": {"x\x1b[2J\u2028y": 1}}, "world.x\x1b[2J\u2028y")
    assert str(err).startswith("world.x\\x1b[2J\\u2028y: unknown key")
    proc = _cli(["metrics", path])
    assert proc.returncode == 2 and len(proc.stderr.splitlines()) == 1, proc.stderr


def test_config_error_values_with_control_characters_stay_on_one_line():
    e = ConfigError("f\rg", "problem\nhere", "v\n\x00")
    assert str(e) == "f\\rg: problem\\nhere (got 'v\\n\\x00')"


# ------------------------------------------------------------------------------------------------ 7: limits
@pytest.mark.parametrize("doc, field", [
    ({"obstacles": {"maps_per_setup": 2 ** 63 - 1}}, "obstacles.maps_per_setup"),
    ({"world": {"dt": 1e-6}}, "world.dt"),
    ({"world": {"time_limit": 1e9}}, "world.time_limit"),
    ({"world": {"size": [1e6, 1e6]}}, "world.size"),
    ({"world": {"grid_resolution": 1e-4}}, "world.grid_resolution"),
    ({"obstacles": {"count": 10_000, "radius": 0.05}}, "obstacles.count"),
    ({"obstacles": {"count": [10, 10_000], "radius": 0.05}}, "obstacles.count[1]"),
    ({"obstacles": {"count": 2000, "radius": 0.1}, "world": {"dt": 0.001}}, "world.dt"),
    ({"sensor": {"resolution_deg": 1e-4, "fov_deg": 1e-3}, "obstacles": {"count": 0}}, "sensor.resolution_deg"),
    ({"obstacles": {"motion": "rvo", "rvo": {"n_headings": 10 ** 9}}}, "obstacles.rvo.n_headings"),
    ({"obstacles": {"count": list(range(1, 101)), "speed": [float(x) for x in range(1, 101)],
                    "radius": [0.01 * x for x in range(1, 21)]}}, "obstacles"),
])
def test_resource_limits_are_checked_at_load_time(doc, field):
    err = _refused(doc, field)
    assert "pbdyn.limits" in str(err)


def test_world_body_count_is_limited():
    bodies = [{"urdf": "box.urdf", "scale": 0.1, "position": [10.0 + 0.01 * i, 10.0]}
              for i in range(limits.MAX_OBSTACLES + 1)]
    _refused({"bodies": bodies}, "bodies")


def test_maps_per_setup_limit_hangs_no_command(write_scenario):
    path = write_scenario(f"[obstacles]\nmaps_per_setup = {2 ** 63 - 1}\n")
    proc = _cli(["metrics", path])
    assert proc.returncode == 2 and "obstacles.maps_per_setup" in proc.stderr


def test_rollout_horizon_and_metric_sample_grids_are_limited():
    from pbdyn.metrics.sampling import grid_samples
    from pbdyn.world.maps import enumerate_maps
    from pbdyn.world.rollout import build_rollout

    sc = parse_scenario({"obstacles": {"count": 10}})
    with pytest.raises(ConfigError, match=r"^horizon: would need"):
        build_rollout(sc, enumerate_maps(sc)[0], horizon=1e9)
    with pytest.raises(ConfigError, match=r"^horizon: must be a finite number"):
        build_rollout(sc, enumerate_maps(sc)[0], horizon=NAN)
    with pytest.raises(ConfigError, match=r"^spacing: would need"):
        grid_samples((1e6, 1e6), 1.0)


def test_every_bundled_scenario_and_dataset_is_within_the_limits():
    for path in sorted(SCENARIOS.rglob("*.toml")):
        sc = load_scenario(path)
        assert sc.n_trials() > 0
    sc = load_scenario(SCENARIOS / "datasets" / "controlled_2d.toml")
    assert sc.n_trials() == 27 * 20 * 72 * 3 * len(sc.planners)


@pytest.mark.parametrize("entry, key", [
    ({"trajectory": "global_primitives", "trajectory_params": {"horizon_s": 9.2e18}}, "horizon_s"),
    ({"trajectory": "global_primitives", "trajectory_params": {"max_expansions": 2 ** 62}}, "max_expansions"),
    ({"trajectory": "local_primitives", "trajectory_params": {"sphere_spacing_deg": 1e-9}}, "sphere_spacing_deg"),
    ({"trajectory": "local_primitives", "trajectory_params": {"n_candidates": 10 ** 9}}, "n_candidates"),
    ({"trajectory": "local_primitives", "trajectory_params": {"step_m": 1e12}}, "step_m"),
    ({"trajectory": "local_primitives_minjerk", "trajectory_params": {"n_candidates": 10 ** 9}}, "n_candidates"),
    ({"trajectory": "local_primitives_minjerk", "trajectory_params": {"duration": 1e12}}, "duration"),
    ({"trajectory": "mpc", "trajectory_params": {"horizon": 10 ** 6}}, "horizon"),
    ({"trajectory": "straight_line", "trajectory_params": {"horizon_s": 1e9}}, "horizon_s"),
])
def test_planner_parameters_that_would_exhaust_memory_or_time_are_refused(entry, key):
    """Resource limits of built-in planner parameters (pbdyn.limits MAX_PLAN_*): one ConfigError naming the key."""
    import pbdyn

    doc = {"world": {"time_limit": 5.0}, "obstacles": {"count": 0}, "planners": [{"gaze": "lookahead", **entry}]}
    with pytest.raises(pbdyn.ConfigError) as err:
        pbdyn.run_trial(doc)
    assert key in str(err.value) and "\n" not in str(err.value)


def test_a_tiny_jerk_limit_makes_no_endless_primitive():
    """jerk_max 1e-9 would need primitives of ~1e4 s: they are not built (no hang, no memory blow-up)."""
    import pbdyn

    doc = {"world": {"time_limit": 2.0}, "obstacles": {"count": 0},
           "planners": [{"trajectory": "local_primitives", "gaze": "lookahead",
                         "trajectory_params": {"jerk_max": 1e-9}}]}
    res = pbdyn.run_trial(doc)
    assert res.outcome in ("deadlock", "freezing") and res.planning_failures > 0
