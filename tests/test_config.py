"""Scenario validation: defaults, grids, and one-line errors naming field and value."""

from __future__ import annotations

import pytest

from pbdyn.config import Range, load_scenario, parse_scenario
from pbdyn.errors import ConfigError
from tests.conftest import SCENARIOS


def test_defaults_match_the_design():
    sc = parse_scenario({})
    assert sc.world.size == (50.0, 50.0) and sc.world.dt == 0.1 and sc.world.time_limit == 80.0
    assert sc.drone.radius == 1.0 and sc.drone.a_max == 4.0 and sc.drone.v_max == (2.0, 4.0, 6.0)
    assert sc.drone.yaw_rate_limit == 1.4
    assert sc.sensor.fov_deg == 90.0 and sc.sensor.range == 8.0 and sc.sensor.resolution_deg == 1.0
    assert len(sc.task.candidates) == 9 and len(sc.task.pairs()) == 72
    assert {c[0] for c in sc.task.candidates} == {4.0, 25.0, 46.0}
    assert sc.collision_check == "swept"
    assert sc.tracking.q == 1e-5 and sc.tracking.r == 0.0 and sc.tracking.drop_pos_var == 1.5


def test_3d_defaults():
    sc = parse_scenario({"world": {"dims": 3}})
    assert sc.world.size == (50.0, 50.0, 20.0)
    assert all(len(c) == 3 and c[2] == 10.0 for c in sc.task.candidates)


def test_controlled_dataset_has_540_maps():
    sc = load_scenario(SCENARIOS / "controlled_2d.toml")
    setups = sc.setups()
    assert len(setups) == 27
    assert sc.obstacles.maps_per_setup == 20
    assert sc.obstacles.radius_jitter == 0.2
    assert setups[0] == {"count": 10, "radius": 0.5, "speed": 2.0}
    assert setups[1] == {"count": 10, "radius": 0.5, "speed": 4.0}  # last field fastest


def test_range_values_and_resolved_dict_roundtrip():
    sc = parse_scenario({"obstacles": {"speed": {"min": 2.0, "max": 6.0}, "radius": [0.5, 1.0]}})
    assert sc.obstacles.speed == (Range(2.0, 6.0),)
    assert sc.setups()[0]["speed"] == {"min": 2.0, "max": 6.0}
    d = sc.to_dict()
    assert d["obstacles"]["speed"] == [{"min": 2.0, "max": 6.0}]


@pytest.mark.parametrize("doc, field, value", [
    ({"world": {"sise": [50, 50]}}, "world.sise", None),
    ({"bogus": 1}, "bogus", None),
    ({"world": {"dt": "fast"}}, "world.dt", "'fast'"),
    ({"obstacles": {"radius": -1.0}}, "obstacles.radius", "-1.0"),
    ({"obstacles": {"radius": [1.0, -0.5]}}, "obstacles.radius[1]", "-0.5"),
    ({"obstacles": {"count": 2000, "radius": 1.5}}, "obstacles.count", "2000"),
    ({"obstacles": {"count": 2.5}}, "obstacles.count", "2.5"),
    ({"obstacles": {"speed": {"min": 3.0}}}, "obstacles.speed", None),
    ({"obstacles": {"motion": "teleport"}}, "obstacles.motion", "'teleport'"),
    ({"task": {"candidates": [[4, 4], [60, 25]]}}, "task.candidates[1]", "[60.0, 25.0]"),
    ({"task": {"candidates": [[4, 4], [0.5, 25]]}}, "task.candidates[1]", "[0.5, 25.0]"),
    ({"drone": {"radius": 0}}, "drone.radius", "0"),
    ({"sensor": {"fov_deg": 400}}, "sensor.fov_deg", "400"),
    ({"collision_check": "maybe"}, "collision_check", "'maybe'"),
    ({"static_obstacles": [{"kind": "cone", "center": [5, 5]}]}, "static_obstacles[0].kind", "'cone'"),
    ({"static_obstacles": [{"kind": "pillar", "center": [5, 5]}]}, "static_obstacles[0].radius", None),
    ({"planners": []}, "planners", None),
])
def test_bad_values_name_field_and_value(doc, field, value):
    with pytest.raises(ConfigError) as exc:
        parse_scenario(doc)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(field + ":"), msg
    if value is not None:
        assert value in msg, msg


def test_malformed_toml_and_missing_file(write_scenario, tmp_path):
    bad = write_scenario("[world\ndims = 2\n")
    with pytest.raises(ConfigError, match="malformed TOML"):
        load_scenario(bad)
    with pytest.raises(ConfigError, match="file not found"):
        load_scenario(tmp_path / "nope.toml")


def test_bundled_scenarios_load():
    for path in sorted(SCENARIOS.glob("*.toml")):
        load_scenario(path)


def test_sensor_resolution_must_resolve_the_smallest_obstacle():
    # 0.3 m obstacles at 8 m span 4.3 deg: 5 deg rays could miss them
    with pytest.raises(ConfigError, match=r"sensor.resolution_deg: rays 5 deg apart can miss .* radius 0.3"):
        parse_scenario({"world": {"dims": 3}, "obstacles": {"radius": 0.5, "radius_jitter": 0.2},
                        "sensor": {"resolution_deg": 5.0}})
    sc = parse_scenario({"world": {"dims": 3}, "obstacles": {"radius": 0.5, "radius_jitter": 0.2}})
    assert sc.sensor.resolution_deg == 2.0 and sc.sensor.vfov_deg == 60.0
    with pytest.raises(ConfigError, match="sensor.vfov_deg: is only used in 3D"):
        parse_scenario({"sensor": {"vfov_deg": 60.0}})
