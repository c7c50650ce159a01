"""The extension templates of tools/templates/ (docs/architecture.md "Where each extension goes") are real: each is
loaded the way pbdyn loads its kind -- a gaze planner by "module:Class" from a scenario, a metric, a motion model and
a sensor model through their registries -- and flown or computed for real. (The trajectory planner template,
my_planner.py, is tested in tests/test_plugins.py.)"""

from __future__ import annotations

import sys
from types import SimpleNamespace

import numpy as np
import pytest

import pbdyn
from pbdyn.config import SensorConfig
from pbdyn.errors import ConfigError
from pbdyn.metrics.cached import run_metric
from pbdyn.metrics.registry import METRICS, compute
from pbdyn.motion.registry import MODELS
from pbdyn.perception.grid import OccupancyGrid
from pbdyn.perception.perceive import Perception
from pbdyn.perception.registry import SENSORS
from pbdyn.world.bullet import PyBulletWorld
from pbdyn.world.geometry import StaticBody
from tests.conftest import ROOT
from tests.helpers import first_map, handmade_rollout, open_scenario

TEMPLATES = ROOT / "tools" / "templates"


@pytest.fixture
def templates(monkeypatch):
    """tools/templates importable, as PYTHONPATH=tools/templates makes it; each template imported afresh."""
    monkeypatch.syspath_prepend(str(TEMPLATES))
    for name in ("my_gaze", "my_metric", "my_motion", "my_sensor"):
        sys.modules.pop(name, None)


def test_the_gaze_template_watches_the_obstacle_it_meets(templates):
    """Named "my_gaze:WatchNearest" in a scenario's [[planners]], as a user names a plug-in: the trial flies past an
    obstacle coming head-on to the goal; asked alone, it turns toward a near track, else along its plan."""
    from pbdyn.planning.registry import resolve_gaze_planner
    from pbdyn.sim.trial import make_trial_spec, run_trial
    from tests.helpers import make_tracks

    sc = open_scenario(2, planners=[{"trajectory": "local_primitives", "gaze": "my_gaze:WatchNearest",
                                     "gaze_params": {"watch_m": 8.0}, "name": "watch"}])
    ro = handmade_rollout(sc, [[30.0, 30.0]], [[-1.0, -0.4]], [1.0])
    spec = make_trial_spec(sc, first_map(sc), planner="watch", start=(4.0, 25.0), goal=(46.0, 25.0))
    res = run_trial(spec, ro)
    assert res.outcome == "success" and res.gaze == "my_gaze:WatchNearest" and res.steps > 10

    cls = resolve_gaze_planner("my_gaze:WatchNearest")
    gaze = cls(SimpleNamespace(limits=SimpleNamespace(yaw_rate=1.4)), watch_m=5.0)
    view = SimpleNamespace(t=0.0, dt=0.1, position=np.array([10.0, 10.0]), yaw=0.0, goal=np.array([40.0, 10.0]),
                           tracks=make_tracks([[10.0, 13.0]], [[0.0, 0.0]], 1.0))
    assert gaze.yaw_rate(view, None) == 1.4                               # the track on the left: turn left
    view.tracks = make_tracks([[10.0, 16.0]], [[0.0, 0.0]], 1.0)              # too far to watch: the goal ahead
    assert gaze.yaw_rate(view, None) == 0.0
    with pytest.raises(ConfigError, match="watch_m"):
        pbdyn.run_trial(open_scenario(2, planners=[{"trajectory": "straight_line", "gaze": "my_gaze:WatchNearest",
                                                     "gaze_params": {"watch_m": -1.0}}]))


def test_the_metric_template_runs_through_the_metric_runner(templates, monkeypatch):
    """Registered as a built-in metric is (pbdyn.metrics.registry.METRICS), run by the one metric runner with the
    scenario's MAV radius: resting MAVs' clearance, checked against the definition."""
    from my_metric import mean_clearance

    monkeypatch.setitem(METRICS, "mean_clearance", mean_clearance)
    sc = pbdyn.load_scenario({"obstacles": {"count": 12}, "drone": {"radius": 0.5}})
    ro = pbdyn.rollout(sc, map=0)
    res = run_metric(sc, ro, "mean_clearance")
    assert res.name == "mean_clearance" and res.params["mav_radius"] == 0.5 and res.n_samples == 64
    pts = np.array([[2.0 + 6.0 * i, 2.0 + 6.0 * j] for i in range(8) for j in range(8)])
    gap = np.linalg.norm(pts[:, None] - ro.positions[0][None], axis=2) - ro.radii[None] - 0.5
    np.testing.assert_allclose(res.per_sample, np.clip(gap.min(axis=1), 0.0, 10.0))
    assert 0.0 < res.value < 10.0 and res.value == pytest.approx(float(np.mean(res.per_sample)))
    later = compute(ro, "mean_clearance", time=5.0)
    assert later.params["time"] == 5.0 and later.value != res.value


def test_the_motion_template_moves_a_scenarios_obstacles(templates, monkeypatch):
    """Registered as a built-in model is (pbdyn.motion.registry.MODELS), a scenario names it: its rollout stays in
    the arena, stops and goes, and a trial flies on it."""
    from my_motion import StopAndGo

    monkeypatch.setitem(MODELS, "stop_and_go", StopAndGo())
    doc = {"obstacles": {"count": 10, "speed": 3.0, "motion": "stop_and_go"}, "world": {"time_limit": 20.0}}
    sc = pbdyn.load_scenario(doc)
    assert sc.obstacles.motion == "stop_and_go"
    ro = pbdyn.rollout(sc, map=0)
    assert ro.meta["motion"] == "stop_and_go"
    r = ro.radii[None, :, None]
    assert np.all(ro.positions >= r - 1e-9) and np.all(ro.positions <= ro.arena_size - r + 1e-9)
    speed = np.linalg.norm(ro.velocities, axis=2)                              # [T, N]
    standing = speed == 0.0
    assert 0.2 < standing.mean() < 0.45                                       # STOP_S / (GO_S + STOP_S) = 1/3
    step = np.linalg.norm(np.diff(ro.positions, axis=0), axis=2)
    assert np.all(step[standing[:-1] & standing[1:]] == 0.0)                  # a standing obstacle does not move
    assert np.allclose(speed[~standing], 3.0)
    cvm = pbdyn.rollout(pbdyn.load_scenario({**doc, "obstacles": {**doc["obstacles"], "motion": "cvm"}}), map=0)
    np.testing.assert_array_equal(cvm.positions[0], ro.positions[0])           # the same spawn, another motion
    res = pbdyn.run_trial(sc, planner="local_primitives", gaze="lookahead")
    assert res.outcome in ("success", "dynamic_collision", "deadlock", "freezing") and res.steps > 10


def test_the_sensor_template_sees_as_the_raycast_sensor_does(templates, monkeypatch):
    """Registered as a built-in model is (pbdyn.perception.registry.SENSORS, pbdyn.config.SensorConfig.MODELS): a
    Perception built with it detects what Bullet's rays detect, occlusion included, and a scenario that names it
    flies."""
    from my_sensor import DiscCaster

    monkeypatch.setitem(SENSORS, "disc_caster", DiscCaster)
    monkeypatch.setattr(SensorConfig, "MODELS", SensorConfig.MODELS + ("disc_caster",))
    # obstacle 0 ahead of the MAV at (10, 10), 1 behind it, 2 hidden behind 0, 3 to the left, out of a 90 deg fov
    w = PyBulletWorld(dims=2, arena_size=(30.0, 20.0), mav_radius=0.5, obstacle_radii=[1.0, 1.0, 0.5, 0.5])
    try:
        w.set_obstacle_positions([[15.0, 10.0], [5.0, 10.0], [17.0, 10.0], [10.0, 15.0]])
        for fov, yaw, seen in ((90.0, 0.0, [0]), (360.0, 0.0, [0, 1, 3]), (90.0, np.pi, [1]), (90.0, 2.0, [3])):
            scans = {}
            for model in ("raycast", "disc_caster"):
                grid = OccupancyGrid(np.zeros(2), np.array([30.0, 20.0]), 1.0)
                perc = Perception(w, grid, fov_deg=fov, range_m=8.0, resolution_deg=1.0, model=model)
                scans[model] = (perc.sense([10.0, 10.0], yaw), grid)
            (ray, ray_grid), (mine, my_grid) = scans["raycast"], scans["disc_caster"]
            assert mine.ids.tolist() == ray.ids.tolist() == seen
            np.testing.assert_array_equal(mine.hits, ray.hits)
            np.testing.assert_allclose(mine.ranges, ray.ranges, atol=5e-3)        # Bullet: mm on cylinders
            assert np.mean(my_grid.cells == ray_grid.cells) > 0.98
    finally:
        w.close()
    with PyBulletWorld(dims=2, arena_size=(30.0, 20.0), mav_radius=0.5, obstacle_radii=[1.0],
                       static_bodies=[StaticBody("pillar", (5.0, 5.0), radius=1.0)]) as w:
        with pytest.raises(ConfigError, match="static bodies"):
            Perception(w, OccupancyGrid(np.zeros(2), np.array([30.0, 20.0]), 1.0), fov_deg=90.0, range_m=8.0,
                       resolution_deg=1.0, model="disc_caster")
    sc = pbdyn.load_scenario({"obstacles": {"count": 10, "speed": 2.0}, "sensor": {"model": "disc_caster"}})
    res = pbdyn.run_trial(sc, planner="local_primitives", gaze="lookahead")
    assert sc.sensor.model == "disc_caster" and res.steps > 10
    assert res.outcome in ("success", "dynamic_collision", "deadlock", "freezing")


def test_the_sensor_models_are_the_ones_a_scenario_may_name():
    assert tuple(SENSORS) == SensorConfig.MODELS
