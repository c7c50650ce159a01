"""Imported worlds: [[bodies]] parsing, body motion, rollouts of poses, metrics on real shapes (bullet vs mesh vs
bounding spheres), trials among real static shapes, and bad input."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import ROOT, SCENARIOS, pbdyn_cmd
from pbdyn.config import load_scenario, parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.metrics.registry import compute
from pbdyn.world.imported.bodies import waypoint_loop
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import Rollout, build_rollout, rollout_key

WORLDS = SCENARIOS / "worlds"
BOX = str(ROOT / "urdf" / "box.urdf")


def world(bodies: list[dict], dims: int = 2, **extra):
    """A world scenario (time limit 20 s) with the given [[bodies]] tables."""
    doc = {"world": {"dims": dims, "time_limit": 20.0}, "bodies": bodies,
           "planners": [{"trajectory": "straight_line", "gaze": "fullrange"}]}
    doc.update(extra)
    return parse_scenario(doc)


def rollout_of(scenario) -> Rollout:
    return build_rollout(scenario, enumerate_maps(scenario)[0])


# ------------------------------------------------------------------------------------------------ motion
def test_waypoint_loop_matches_hand_computation():
    w = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])           # legs 4, 3, 5 m
    speeds = np.array([2.0, 1.0, 5.0])                            # 2 s, 3 s, 1 s -> period 6 s
    pos, vel = waypoint_loop(w, speeds, np.array([0.0, 1.0, 2.5, 5.5, 6.0, 7.0]))
    np.testing.assert_allclose(pos, [[0, 0], [2, 0], [4, 0.5], [2, 1.5], [0, 0], [2, 0]], atol=1e-12)
    np.testing.assert_allclose(vel[2], [0.0, 1.0])
    np.testing.assert_allclose(vel[3], [-4.0, -3.0])


def test_body_motions_give_the_poses_they_promise():
    sc = world([
        {"name": "still", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [10.0, 40.0]},
        {"name": "cv", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [45.0, 10.0],
         "motion": "constant_velocity", "velocity": [4.0, 0.0]},
        {"name": "loop", "urdf": BOX, "motion": "waypoints", "waypoints": [[10.0, 20.0], [30.0, 20.0]], "speed": 5.0},
        {"name": "orbit", "urdf": BOX, "motion": "pbdyn.world.motions:circle",
         "params": {"center": [25.0, 35.0, 2.0], "radius": 3.0, "period": 8.0}},
    ])
    ro = rollout_of(sc)
    b = ro.bodies
    assert b.names == ("still", "cv", "loop", "orbit") and b.moving.tolist() == [False, True, True, True]
    assert ro.n_obstacles == 3                                   # the moving bodies' bounding spheres
    np.testing.assert_allclose(b.position[:, 0], np.tile([10.0, 40.0, 2.0], (ro.n_steps, 1)))
    # constant velocity: the bounding sphere (radius = half x-y diagonal of 2 x 1) reflects at x = 50 - r
    r = math.hypot(1.0, 0.5)
    assert ro.radii[0] == pytest.approx(r)
    k = ro.step_index(1.0)                                       # 45 + 4 = 49 > 50 - r: reflected
    assert ro.positions[k, 0, 0] == pytest.approx(2 * (50 - r) - 49.0)
    assert ro.velocities[k, 0, 0] == pytest.approx(-4.0)
    # waypoint loop: out and back at 5 m/s, period 8 s
    k = ro.step_index(6.0)
    np.testing.assert_allclose(b.position[k, 2], [20.0, 20.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(ro.velocities[k, 1], [-5.0, 0.0])
    # motion function: exactly what the function returns
    from pbdyn.world.motions import circle

    for t in (0.0, 3.3, 7.9):
        pos, quat = circle(t, center=[25.0, 35.0, 2.0], radius=3.0, period=8.0)
        k = ro.step_index(t)
        np.testing.assert_allclose(b.position[k, 3], pos, atol=1e-12)
        np.testing.assert_allclose(b.orientation[k, 3], quat, atol=1e-12)
    # orbit speed from central differences of the sphere centres: the chord speed w r sin(w dt) / (w dt)
    speeds = np.linalg.norm(ro.velocities[5:-5, 2], axis=1)
    w = 2 * math.pi / 8
    np.testing.assert_allclose(speeds, 3 * math.sin(w * 0.1) / 0.1, rtol=1e-9)


def test_world_rollout_round_trips_and_its_key_follows_the_urdf(tmp_path):
    urdf = tmp_path / "crate.urdf"
    urdf.write_text(open(BOX).read())
    doc = {"world": {"time_limit": 20.0}, "bodies": [
        {"urdf": str(urdf), "scale": 2.0, "position": [20.0, 20.0], "motion": "constant_velocity",
         "velocity": [1.0, 2.0]}]}
    sc = parse_scenario(doc)
    spec = enumerate_maps(sc)[0]
    ro = build_rollout(sc, spec)
    ro.save(tmp_path / "r.npz")
    back = Rollout.load(tmp_path / "r.npz")
    for name in ("position", "orientation", "sphere_radius", "scale"):
        np.testing.assert_array_equal(getattr(back.bodies, name), getattr(ro.bodies, name))
    assert back.bodies.urdf == ro.bodies.urdf and back.bodies.names == ro.bodies.names
    np.testing.assert_array_equal(back.positions, ro.positions)
    key = rollout_key(sc, spec, 30.0)
    urdf.write_text(open(BOX).read().replace('size="1 1 1"', 'size="1 1 2"', 1))
    assert rollout_key(sc, spec, 30.0) != key


# ------------------------------------------------------------------------------------------------ metrics
def moving_box_world():
    """A 4 x 1 x 3 m box moving +x at 2 m/s along y = 25 from x = 10 (its bounding disc: radius sqrt(4.25))."""
    return world([{"name": "box", "urdf": BOX, "scale": [4.0, 1.0, 3.0], "position": [10.0, 25.0],
                   "motion": "constant_velocity", "velocity": [2.0, 0.0]}])


def test_moving_box_survival_hand_computed_bullet_and_mesh_agree_spheres_differ():
    ro = rollout_of(moving_box_world())
    pts = np.array([[20.0, 26.2], [20.0, 27.2], [5.0, 25.0]])
    # (20, 26.2): 0.7 m above the box's face; overlap once the right face passes x = 20 - sqrt(1 - 0.7^2)
    t_contact = (20.0 - math.sqrt(1 - 0.7 ** 2) - 12.0) / 2.0        # 3.643 s
    expect = [math.ceil(t_contact / 0.1) * 0.1, 12.0, 12.0]
    from pbdyn.metrics.analytic import survival_times
    from pbdyn.metrics.bullet_backend import survival_times_bullet
    from pbdyn.metrics.mesh_backend import survival_times_mesh

    bullet = survival_times_bullet(ro, pts)
    mesh = survival_times_mesh(ro, pts)
    np.testing.assert_allclose(bullet, expect, atol=1e-9)
    np.testing.assert_allclose(mesh, expect, atol=1e-9)
    spheres = survival_times(ro, pts)                               # the bounding disc reaches both points
    assert spheres[0] < expect[0] and spheres[1] < 12.0


def test_bullet_and_mesh_agree_on_the_mesh_world():
    sc = load_scenario(WORLDS / "mixed_3d.toml")
    ro = rollout_of(sc)
    assert any(u.endswith("gem.urdf") for u in np.array(ro.bodies.urdf)[ro.bodies.moving_index])
    a = compute(ro, "survivability_dense", backend="bullet", n_jitter=0, spacing=4.0)
    b = compute(ro, "survivability_dense", backend="mesh", n_jitter=0, spacing=4.0)
    same = a.per_sample == b.per_sample
    assert a.n_samples == b.n_samples > 300
    assert same.mean() >= 0.99
    assert np.all(np.abs(a.per_sample - b.per_sample)[~same] <= ro.dt + 1e-9)
    g1 = compute(ro, "global_survivability", backend="bullet", n_jitter=0)
    g2 = compute(ro, "global_survivability", backend="mesh", n_jitter=0)
    np.testing.assert_allclose(g1.per_sample, g2.per_sample, atol=ro.dt + 1e-9)


def test_gem_mesh_distance_against_its_closed_form():
    from pbdyn.world.shapes import body_primitives, body_sdf

    prims = body_primitives(WORLDS / "urdf" / "gem.urdf", (2.0, 2.0, 2.0))
    # along +z the apex is at 2 m; along +x a hexagon vertex at 2 m; a face centre of the upper pyramid lies at
    # distance 2 * sin(atan) ... checked by points straight out from the apex and the vertex
    d = body_sdf(prims, np.array([[0.0, 0.0, 3.0], [3.5, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    assert d[0] == pytest.approx(1.0, abs=1e-5) and d[1] == pytest.approx(1.5, abs=1e-5)
    assert d[2] < 0


def test_density_and_corridor_traversability_from_real_shapes():
    # two static 40 x 2 x 4 m walls with a 6 m corridor between them (y in [22, 28]) and a moving 2 x 2 x 2 box
    sc = world([{"name": "south", "urdf": BOX, "scale": [40.0, 2.0, 4.0], "position": [25.0, 21.0, 2.0]},
                {"name": "north", "urdf": BOX, "scale": [40.0, 2.0, 4.0], "position": [25.0, 29.0, 2.0]},
                {"name": "cube", "urdf": BOX, "scale": 2.0, "position": [45.0, 45.0],
                 "motion": "constant_velocity", "velocity": [0.0, -1.0]}],
               task={"candidates": [[4.0, 4.0], [46.0, 4.0]]})
    ro = rollout_of(sc)
    dens = compute(ro, "density")
    assert dens.value == pytest.approx((2 * 80.0 + 4.0) / 2500.0, rel=1e-3)
    assert compute(ro, "density", include_static=False).value == pytest.approx(4.0 / 2500.0, rel=1e-3)
    res = compute(ro, "traversability", starts=np.array([[25.0, 25.0]]))
    # 8 directions from the corridor's centre, MAV radius 1: +-x to the walls at x = 1 / 49 (24 m), +-y 2 m,
    # diagonals until the disc touches a corridor wall: 2 * sqrt(2)
    d = res.per_sample.reshape(-1)
    expect = {0: 24.0, 90: 2.0, 180: 24.0, -90: 2.0, 45: 2 * math.sqrt(2), 135: 2 * math.sqrt(2),
              -45: 2 * math.sqrt(2), -135: 2 * math.sqrt(2)}
    from pbdyn.metrics.traversability import unit_directions

    u = unit_directions(2)
    for i in range(u.shape[0]):
        ang = int(round(math.degrees(math.atan2(u[i, 1], u[i, 0]))))
        assert d[i] == pytest.approx(expect[ang if ang != -180 else 180], abs=2e-4), ang
    # samples overlapping the walls' real shapes are left out
    surv = compute(ro, "survivability", n_jitter=0, points=np.array([[25.0, 21.5], [25.0, 25.0]]))
    assert surv.n_excluded == 1 and surv.n_samples == 1


def test_three_d_world_is_the_extrusion_of_the_two_d_one():
    # tall static boxes spanning the whole 3D volume vs the same footprints in 2D: per-layer metrics agree
    bodies2 = [{"name": "a", "urdf": BOX, "scale": [6.0, 2.0, 40.0], "position": [20.0, 30.0, 10.0]},
               {"name": "b", "urdf": BOX, "scale": [2.0, 8.0, 40.0], "position": [33.0, 15.0, 10.0]}]
    bodies3 = [dict(b) for b in bodies2]
    sc2 = world(bodies2)
    sc3 = world(bodies3, dims=3)
    r2, r3 = rollout_of(sc2), rollout_of(sc3)
    t2 = compute(r2, "traversability", starts=np.array([[25.0, 25.0], [10.0, 30.0]]))
    t3 = compute(r3, "traversability", starts=np.array([[25.0, 25.0, 10.0], [10.0, 30.0, 10.0]]), horizontal=True)
    np.testing.assert_allclose(t2.per_sample, t3.per_sample, atol=2e-4)


# ------------------------------------------------------------------------------------------------ trials
def test_trial_collides_with_a_static_shape_and_flies_around_it():
    from pbdyn.sim.trial import make_trial_spec, run_trial

    sc = world([{"name": "wall", "urdf": BOX, "scale": [2.0, 4.0, 4.0], "position": [25.0, 25.0, 2.0]}],
               planners=[{"trajectory": "straight_line", "gaze": "fullrange"},
                         {"trajectory": "local_primitives", "gaze": "fullrange"}],
               drone={"v_max": [4.0]}, task={"candidates": [[4.0, 25.0], [46.0, 25.0]]})
    ro = rollout_of(sc)
    spec = enumerate_maps(sc)[0]
    straight = run_trial(make_trial_spec(sc, spec, planner="fullrange+straight_line", start=(4.0, 25.0),
                                         goal=(46.0, 25.0)), ro)
    assert straight.outcome == "static_collision"
    # the face is at x = 24: the MAV (radius 1) stops at x = 23 give or take one step of 0.4 m
    local = run_trial(make_trial_spec(sc, spec, planner="fullrange+local_primitives", start=(4.0, 25.0),
                                      goal=(46.0, 25.0)), ro)
    assert local.outcome == "success" and local.min_clearance_m >= 0.0
    assert local.motion_profile == "imported" and local.obstacle_count == 0


@pytest.mark.parametrize("name", ["warehouse_2d", "mixed_3d"])
def test_example_worlds_fly_and_measure_deterministically(name, tmp_path):
    env = dict(os.environ, PBDYN_CACHE=str(tmp_path / "cache"))
    docs = []
    for seed in ("1", "77"):
        env["PYTHONHASHSEED"] = seed
        out = subprocess.run(pbdyn_cmd() + ["metrics", str(WORLDS / f"{name}.toml"), "--json",
                                            "--metric", "density", "survivability", "traversability"],
                             capture_output=True, text=True, env=env, timeout=300)
        assert out.returncode == 0, out.stderr
        doc = json.loads(out.stdout)
        for m in doc["metrics"].values():
            m.pop("wall_time_s", None), m.pop("cached", None), m.pop("elapsed_s", None)
        docs.append(doc)
        env["PBDYN_CACHE"] = str(tmp_path / "cache2")          # the second process computes afresh
    assert docs[0] == docs[1]
    assert docs[0]["backend"] == "bullet"
    surv = docs[0]["metrics"]["survivability"]
    assert 0.0 < surv["value"] <= 12.0 and surv["stderr"] > 0
    text = subprocess.run(pbdyn_cmd() + ["metrics", str(WORLDS / f"{name}.toml"), "--metric", "density"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert text.returncode == 0 and text.stdout.startswith(f"world {name}:") and "density:" in text.stdout
    run = subprocess.run(pbdyn_cmd() + ["run", str(WORLDS / f"{name}.toml"), "--json", "--planner",
                                        "lookahead+local_primitives"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    res = json.loads(run.stdout)
    assert res["motion_profile"] == "imported" and res["obstacle_count"] >= 2


# ------------------------------------------------------------------------------------------------ bad input
NO_COLLISION = """<?xml version="1.0"?>
<robot name="ghost"><link name="base"><visual><geometry><box size="1 1 1"/></geometry></visual></link></robot>
"""


@pytest.mark.parametrize("body, needle", [
    ({"urdf": "missing.urdf", "position": [10.0, 10.0]}, "bodies[0].urdf: file not found"),
    ({"urdf": "ghost.urdf", "position": [10.0, 10.0]}, "bodies[0].urdf: has no collision geometry"),
    ({"urdf": BOX, "position": [10.0, 10.0], "motion": "teleport"}, "bodies[0].motion"),
    ({"urdf": BOX, "motion": "waypoints", "waypoints": [[1.0, 2.0]], "speed": 1.0}, "bodies[0].waypoints"),
    ({"urdf": BOX, "motion": "waypoints", "waypoints": [[5.0, 5.0], [9.0, 5.0], [9.0, 9.0]], "speed": [1.0, 2.0]},
     "bodies[0].speed"),
    ({"urdf": BOX, "position": [10.0, 10.0], "motion": "constant_velocity"}, "bodies[0].velocity"),
    ({"urdf": BOX, "motion": "no_such_module_x:f"}, "cannot import module"),
    ({"urdf": BOX, "motion": "pbdyn.world.motions:circle", "params": {"radius": 1.0}}, "motion function raised"),
    ({"urdf": BOX, "position": [10.0, 10.0], "scale": -1.0}, "bodies[0].scale"),
    ({"urdf": BOX, "position": [10.0, 10.0], "scale": 1e300}, "bodies[0].scale: must be within"),
    ({"urdf": BOX, "position": [10.0, 10.0], "scale": 1e8}, "bodies[0]: the body's collision geometry (scaled) must"),
    ({"urdf": BOX, "position": [80.0, 10.0]}, "bodies[0].position: must lie inside the arena"),
    ({"urdf": BOX, "position": [10.0, 10.0], "colour": "red"}, "bodies[0]"),
])
def test_bad_world_files_exit_2_with_one_line(tmp_path, body, needle):
    (tmp_path / "ghost.urdf").write_text(NO_COLLISION)
    lines = ["[world]", "time_limit = 10.0", "[[bodies]]"]
    for k, v in body.items():
        lines.append(f"{k} = {json.dumps(v) if not isinstance(v, dict) else '{ ' + ', '.join(f'{a} = {json.dumps(b)}' for a, b in v.items()) + ' }'}")
    path = tmp_path / "world.toml"
    path.write_text("\n".join(lines) + "\n")
    for cmd in (["metrics", str(path), "--metric", "density"], ["run", str(path)]):
        out = subprocess.run(pbdyn_cmd() + cmd, capture_output=True, text=True, timeout=120)
        assert out.returncode == 2, (out.stdout, out.stderr)
        err = out.stderr.strip().splitlines()
        assert len(err) == 1 and needle in err[0] and "Traceback" not in out.stderr


def test_obstacles_table_and_candidates_inside_a_body_are_rejected():
    with pytest.raises(ConfigError, match="obstacles"):
        parse_scenario({"obstacles": {"count": 3}, "bodies": [{"urdf": BOX, "position": [10.0, 10.0]}]})
    sc = world([{"name": "slab", "urdf": BOX, "scale": [6.0, 6.0, 4.0], "position": [25.0, 25.0]}])
    with pytest.raises(ConfigError, match=r"task.candidates\[4\].*slab"):
        rollout_of(sc)


def test_world_file_text_is_documented_in_the_readme():
    readme = (ROOT / "docs" / "scenarios.md").read_text()
    for needle in ("[[bodies]]", "warehouse_2d.toml", "mixed_3d.toml", "constant_velocity", "waypoints",
                   "package.module:function", "--backend"):
        assert needle in readme


def test_a_sphere_body_flies_exactly_like_a_generated_obstacle_of_its_radius():
    """Bounding spheres reach the real shape's farthest point: a moving sphere body of radius 1 m is a disc of
    radius 1 m (not its box's half-diagonal), so a trial among it equals one among a generated obstacle there."""
    from pbdyn.sim.trial import make_trial_spec, run_trial
    from tests.helpers import handmade_rollout

    sphere = BOX.replace("box.urdf", "sphere.urdf")
    planners = [{"trajectory": "local_primitives", "gaze": "fullrange"}]
    sc_w = world([{"name": "ball", "urdf": sphere, "position": [25.0, 30.0, 2.0], "motion": "constant_velocity",
                   "velocity": [0.0, -2.0]}], planners=planners)
    ro_w = rollout_of(sc_w)
    assert ro_w.radii.tolist() == [1.0]
    sc_g = parse_scenario({"world": {"dims": 2, "time_limit": 20.0}, "obstacles": {"count": 0},
                           "planners": planners})
    ro_g = handmade_rollout(sc_g, [[25.0, 30.0]], [[0.0, -2.0]], [1.0])
    np.testing.assert_array_equal(ro_w.positions, ro_g.positions)
    rows = []
    for sc, ro in ((sc_w, ro_w), (sc_g, ro_g)):
        spec = make_trial_spec(sc, enumerate_maps(sc)[0], start=(4.0, 25.0), goal=(46.0, 25.0))
        rows.append(run_trial(spec, ro).to_dict())
    keys = ("outcome", "reason", "steps", "flight_time_s", "min_clearance_m", "planning_failures",
            "obstacles_tracked", "tracked_time_s", "grid_discovered", "task_survivability_s", "task_flux_per_s")
    assert {k: rows[0][k] for k in keys} == {k: rows[1][k] for k in keys}
    assert rows[0]["min_clearance_m"] < 3.0          # the MAV really met the obstacle on its way


@pytest.mark.parametrize("offset, collides", [(1.8, False), (1.3, True)])
def test_trials_collide_with_moving_bodies_by_their_real_shapes(offset, collides):
    """A 2 x 1 m cart passes the MAV's straight path 1.8 m (or 1.3 m) to the side: its 1.12 m bounding circle would
    touch the MAV (r 1 m) either way, its real shape only at 1.3 m (clearance 1.8 - 0.5 - 1 = 0.3 m)."""
    from pbdyn.sim.trial import make_trial_spec, run_trial

    planners = [{"trajectory": "straight_line", "gaze": "fullrange"}]
    sc = world([{"name": "cart", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [40.0, 25.0 + offset, 1.5],
                 "motion": "constant_velocity", "velocity": [-3.0, 0.0]}], planners=planners,
               drone={"v_max": 4.0})
    ro = rollout_of(sc)
    assert ro.radii[0] == pytest.approx(math.hypot(1.0, 0.5))
    spec = make_trial_spec(sc, enumerate_maps(sc)[0], start=(4.0, 25.0), goal=(46.0, 25.0))
    res = run_trial(spec, ro)
    assert (res.outcome == "dynamic_collision") == collides
    if not collides:
        assert res.outcome == "success" and res.min_clearance_m == pytest.approx(0.3, abs=0.02)


def test_rays_see_moving_bodies_by_their_real_shapes():
    """A ray that passes inside the cart's bounding circle but beside the cart misses it; one through it hits."""
    from pbdyn.sim.state import make_world
    from pbdyn.sim.trial import make_trial_spec

    sc = world([{"name": "cart", "urdf": BOX, "scale": [2.0, 1.0, 3.0], "position": [25.0, 25.0, 1.5],
                 "motion": "constant_velocity", "velocity": [1.0, 0.0]}])
    ro = rollout_of(sc)
    spec = make_trial_spec(sc, enumerate_maps(sc)[0])
    w = make_world(spec, ro)
    try:
        b = ro.bodies
        w.set_obstacle_positions(ro.positions[0], (b.position[0, b.moving_index], b.orientation[0, b.moving_index]))
        origin = np.array([15.0, 25.0])
        ids, frac = w.cast_fan(origin, np.array([[1.0, 0.0], [1.0, 0.08]]) / np.array([[1.0], [math.hypot(1, 0.08)]]),
                               12.0)
        # along y = 25 the ray meets the cart's face at x = 24; the tilted one passes y = 25.8 at x = 25
        assert w.dynamic_index_of[ids[0]] == 0 and frac[0] * 12.0 == pytest.approx(9.0, abs=1e-3)
        assert w.dynamic_index_of[ids[1]] == -1
    finally:
        w.close()


def test_imported_world_set_is_what_its_tool_writes_clear_of_the_candidates_and_flies():
    """scenarios/worlds/imported_2d (the heterogeneous study's imported worlds) are exactly what tools/make_worlds.py
    writes; every world keeps its static bodies' real shapes >= 3 m from every start/goal candidate, has moving
    bodies, and one world of each family flies a trial to an outcome."""
    from pbdyn.experiments.tasks import trial_spec
    from pbdyn.outcome import Outcome
    from pbdyn.sim.trial import run_trial

    out = subprocess.run([sys.executable, str(ROOT / "tools" / "make_worlds.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    files = sorted((SCENARIOS / "worlds" / "imported_2d").glob("*.toml"))
    assert len(files) == 12
    flown = set()
    for f in files:
        sc = load_scenario(f)
        m = enumerate_maps(sc)[0]
        ro = build_rollout(sc, m)
        field = ro.bodies.field()
        assert field.indices("moving")
        cands = np.array(sc.task.candidates, dtype=float)
        pts = np.concatenate([cands, np.full((cands.shape[0], 1), sc.world.flight_height)], axis=1)
        for b in field.indices("static"):
            assert field.body_distance(b, pts, 0).min() >= 3.0 - 1e-9, (f.name, ro.bodies.names[b])
        family = f.stem.rsplit("_", 1)[0]
        if family not in flown:
            flown.add(family)
            spec = trial_spec(sc, m, sc.planners[0], sc.drone.v_max[0], sc.task.candidates[0], sc.task.candidates[-1])
            r = run_trial(spec, ro)
            assert r.outcome in {o.value for o in Outcome} - {"error", "invalid_plan"} and r.steps > 0
    assert flown == {"warehouse", "plaza", "office", "orbits"}


WORLDS_3D = sorted((SCENARIOS / "worlds" / "imported_3d").glob("*.toml"))


def test_imported_3d_world_set_is_what_its_tool_writes_and_check_sees_a_change(tmp_path):
    """scenarios/worlds/imported_3d is exactly what tools/make_worlds.py --dims 3 writes (nine worlds, three per
    family); --check fails on an edited file, and --out needs --dims."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    tool = [sys.executable, str(ROOT / "tools" / "make_worlds.py")]
    out = subprocess.run(tool + ["--check", "--dims", "3"], capture_output=True, text=True, cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr
    assert [f.stem for f in WORLDS_3D] == [f"{fam}_{i}" for fam in ("atrium", "hangar", "orbits") for i in range(3)]
    copy = tmp_path / "w3"
    assert subprocess.run(tool + ["--dims", "3", "--out", str(copy)], capture_output=True, cwd=ROOT,
                          env=env).returncode == 0
    assert sorted(p.name for p in copy.glob("*.toml")) == [f.name for f in WORLDS_3D]
    edited = copy / "atrium_1.toml"
    edited.write_text(edited.read_text() + "# edited by hand\n")
    out = subprocess.run(tool + ["--check", "--dims", "3", "--out", str(copy)], capture_output=True, text=True,
                         cwd=ROOT, env=env)
    assert out.returncode == 1 and "atrium_1.toml" in out.stderr
    out = subprocess.run(tool + ["--check", "--out", str(copy)], capture_output=True, text=True, cwd=ROOT, env=env)
    assert out.returncode == 2 and "--dims" in out.stderr


def test_imported_3d_worlds_load_clear_of_the_candidates_span_easy_to_hard_and_fly_deterministically(monkeypatch):
    """Every 3D imported world loads as a 50 x 50 x 20 m world flown at the panel's speeds, keeps its static bodies'
    real shapes >= 3 m from every start/goal candidate and every body inside the arena, has more and faster movers
    from world 0 to world 2 of a family, and flies one short trial (6 m/s, candidate 0 -> 1) to an outcome, twice
    alike. The trials' task metrics (the equivalent radii of the movers on 5 cm cells: seconds per hard world) are
    computed for world 0 of each family only, to keep the test short."""
    from pbdyn.experiments.tasks import trial_spec
    from pbdyn.sim import trial as trial_mod
    from pbdyn.outcome import Outcome

    real_task_metrics = trial_mod.task_metrics
    movers: dict[str, list] = {}
    for f in WORLDS_3D:
        sc = load_scenario(f)
        assert sc.world.dims == 3 and sc.world.size == (50.0, 50.0, 20.0) and sc.world.time_limit == 80.0
        assert sc.drone.v_max == (2.0, 4.0, 6.0)
        m = enumerate_maps(sc)[0]
        ro = build_rollout(sc, m)
        field = ro.bodies.field()
        moving = field.indices("moving")
        cands = np.array(sc.task.candidates, dtype=float)
        assert cands.shape == (9, 3)
        for b in field.indices("static"):
            assert field.body_distance(b, cands, 0).min() >= 3.0 - 1e-9, (f.name, ro.bodies.names[b])
        size = np.array(sc.world.size)
        for k in range(0, ro.n_steps, 100):
            for b in field.indices("all") if k == 0 else moving:
                lo, hi = field.world_bounds(b, k)
                assert lo.min() >= -1e-9 and (hi <= size + 1e-9).all(), (f.name, ro.bodies.names[b], k)
        family, level = f.stem.rsplit("_", 1)
        movers.setdefault(family, []).append((len(moving), float(np.linalg.norm(ro.velocities[0], axis=-1).mean())))
        if level == "0":
            monkeypatch.setattr(trial_mod, "task_metrics", real_task_metrics)
        else:
            monkeypatch.setattr(trial_mod, "task_metrics",
                                lambda *a, **k: {"task_survivability_s": None, "task_flux_per_s": None})
        spec = trial_spec(sc, m, sc.planners[0], 6.0, sc.task.candidates[0], sc.task.candidates[1])
        rows = []
        for _ in range(2):
            d = trial_mod.run_trial(spec, ro).to_dict()
            rows.append({k: v for k, v in d.items() if not k.startswith("wall")})
        assert rows[0] == rows[1], f.name
        assert rows[0]["outcome"] in {o.value for o in Outcome} - {"error", "invalid_plan"} and rows[0]["steps"] > 0
        assert rows[0]["motion_profile"] == "imported" and rows[0]["obstacle_count"] == len(moving)
        assert (rows[0]["task_flux_per_s"] is not None) == (level == "0")
    assert sorted(movers) == ["atrium", "hangar", "orbits"]
    for family, rows in movers.items():
        (n0, v0), (n1, v1), (n2, v2) = rows
        assert n0 < n1 < n2 and n2 >= 2 * n0 and v0 < v1 < v2, (family, rows)
