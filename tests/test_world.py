"""The PyBullet world: URDF models and scaling, body layout, walls, ray tests, static clearance, quiet stdout."""

from __future__ import annotations

import math
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pbdyn.errors import ConfigError
from pbdyn.world.bullet import PyBulletWorld, RAY_BATCH, what_if_pose
from pbdyn.world.geometry import StaticBody
from pbdyn.world.imported.urdf_loading import load_scaled_urdf, scale_urdf_text, urdf_path


@pytest.fixture
def world2d():
    w = PyBulletWorld(dims=2, arena_size=(20.0, 10.0), flight_height=2.0, mav_radius=0.5,
                      obstacle_radii=[1.0, 0.5],
                      static_bodies=[StaticBody("pillar", (15.0, 5.0), radius=1.0),
                                     StaticBody("box", (5.0, 5.0), size=(2.0, 4.0))])
    yield w
    w.close()


def _ray(world, start, end):
    ids, frac, pts = world.ray_test(np.asarray([start], float), np.asarray([end], float))
    return int(ids[0]), float(frac[0]), pts[0]


# ------------------------------------------------------------------------------------------ URDF models
def test_quadrotor_urdf_is_an_x_frame_with_one_unit_collision_sphere():
    root = ET.parse(urdf_path("quadrotor")).getroot()
    collisions = list(root.iter("collision"))
    assert len(collisions) == 1
    sphere = collisions[0].find("geometry/sphere")
    assert sphere is not None and float(sphere.get("radius")) == 1.0
    assert np.allclose([float(x) for x in collisions[0].find("origin").get("xyz").split()], 0.0)
    assert float(root.find("link/inertial/mass").get("value")) > 0
    arm_angles = sorted(round(math.degrees(float(v.find("origin").get("rpy").split()[2])))
                        for v in root.iter("visual") if v.find("geometry/box") is not None
                        and float(v.find("geometry/box").get("size").split()[0]) == 0.6)
    assert arm_angles == [45, 135, 225, 315]
    rotors = [v for v in root.iter("visual") if v.find("geometry/cylinder") is not None]
    assert len(rotors) == 4


@pytest.mark.parametrize("name, tag, attrs", [("pillar", "cylinder", {"radius": 1.0, "length": 1.0}),
                                              ("box", "box", {"size": "1 1 1"}),
                                              ("sphere", "sphere", {"radius": 1.0})])
def test_obstacle_urdfs_are_unit_static_shapes(name, tag, attrs):
    root = ET.parse(urdf_path(name)).getroot()
    assert float(root.find("link/inertial/mass").get("value")) == 0.0
    geom = root.find("link/collision/geometry")[0]
    assert geom.tag == tag
    for key, value in attrs.items():
        got = geom.get(key)
        assert (np.allclose([float(x) for x in got.split()], 1.0) if isinstance(value, str)
                else float(got) == value)


def test_scale_urdf_text_rewrites_every_size_and_origin(tmp_path):
    text = """<robot name="t"><link name="a">
      <visual><origin xyz="1 2 3"/><geometry><box size="1 2 3"/></geometry></visual>
      <visual><origin xyz="0 0 1"/><geometry><cylinder radius="0.5" length="2"/></geometry></visual>
      <visual><geometry><mesh filename="meshes/m.obj" scale="1 1 2"/></geometry></visual>
      <collision><origin xyz="0 0 -1"/><geometry><cylinder radius="1" length="1"/></geometry></collision>
    </link></robot>"""
    out = ET.fromstring(scale_urdf_text(text, (2.0, 2.0, 3.0), tmp_path))
    origins = [[float(x) for x in o.get("xyz").split()] for o in out.iter("origin")]
    assert origins == [[2.0, 4.0, 9.0], [0.0, 0.0, 3.0], [0.0, 0.0, -3.0]]
    assert [float(x) for x in out.find(".//box").get("size").split()] == [2.0, 4.0, 9.0]
    cyl = out.findall(".//cylinder")
    assert (float(cyl[0].get("radius")), float(cyl[0].get("length"))) == (1.0, 6.0)
    mesh = out.find(".//mesh")
    assert [float(x) for x in mesh.get("scale").split()] == [2.0, 2.0, 6.0]
    assert mesh.get("filename") == str((tmp_path / "meshes/m.obj").resolve())
    # The 2D slice-equivalent form: the collision cylinder becomes a sphere of the scaled radius; visuals stay.
    fast = ET.fromstring(scale_urdf_text(text, (2.0, 2.0, 3.0), tmp_path, cylinders_as_spheres=True))
    assert float(fast.find("link/collision/geometry/sphere").get("radius")) == 2.0
    assert fast.find("link/collision/geometry/cylinder") is None
    assert len(fast.findall(".//visual/geometry/cylinder")) == 1
    with pytest.raises(ValueError, match="uniform"):
        scale_urdf_text(open(urdf_path("sphere")).read(), (1.0, 1.0, 2.0))
    with pytest.raises(ValueError, match="equal x and y"):
        scale_urdf_text(open(urdf_path("pillar")).read(), (1.0, 2.0, 2.0))


def test_load_scaled_urdf_gives_the_scaled_collision_shapes(world2d):
    c = world2d.client
    box = load_scaled_urdf(c, urdf_path("box"), (2.0, 3.0, 4.0), (100.0, 100.0, 0.0))
    assert np.allclose(c.getCollisionShapeData(box, -1)[0][3], (2.0, 3.0, 4.0))
    mav = c.getCollisionShapeData(world2d.mav_id, -1)
    assert len(mav) == 1 and mav[0][2] == c.GEOM_SPHERE and math.isclose(mav[0][3][0], 0.5)
    assert c.getDynamicsInfo(world2d.mav_id, -1)[0] > 0
    lo, hi = c.getAABB(box)
    assert np.allclose(np.subtract(hi, lo), (2.0, 3.0, 4.0), atol=0.1)


# ------------------------------------------------------------------------------------------ layout
def test_body_layout_and_kind_lookup(world2d):
    w = world2d
    assert w.mav_id == 0 and w.obstacle_ids.tolist() == [1, 2] and w.obstacle_ids.dtype == np.int64
    assert w.static_ids.tolist() == [3, 4] and w.wall_ids.tolist() == [5, 6, 7, 8]
    assert w.body_kind(0) == ("mav", 0)
    assert w.body_kind(2) == ("dynamic", 1)
    assert w.body_kind(4) == ("static", 1)
    assert w.body_kind(8) == ("wall", 3)
    assert w.body_kind(-1) == ("none", -1) and w.body_kind(99) == ("none", -1)
    ids = np.array([-1, 0, 1, 2, 3, 5])
    assert w.dynamic_index_of[ids].tolist() == [-1, -1, 0, 1, -1, -1]
    assert w.is_static_body[ids].tolist() == [False, False, False, False, True, True]
    assert np.allclose(w.to_world3([[1.0, 2.0], [3.0, 4.0]]), [[1, 2, 2], [3, 4, 2]])


def test_walls_close_the_arena_and_span_the_band(world2d):
    w = world2d
    h = w.flight_height
    cases = [((10, 9), (-5, 9), (0, 9)), ((10, 9), (25, 9), (20, 9)), ((10, 9), (10, -5), (10, 0)),
             ((10, 9), (10, 15), (10, 10)), ((2, 2), (-5, -5), (0, 0)), ((18, 8), (25, 15), (20, 10))]
    for start, end, expect in cases:   # the last two go diagonally into the corners
        body, _, pt = _ray(w, (*start, h), (*end, h))
        assert w.body_kind(body)[0] == "wall", (start, end)
        assert np.allclose(pt, (*expect, h), atol=1e-6), (start, end, pt)
    # The band: a vertical ray just inside the west wall hits its top at z = 2h.
    body, _, pt = _ray(w, (-0.5, 5.0, 10.0), (-0.5, 5.0, -1.0))
    assert w.body_kind(body)[0] == "wall" and math.isclose(pt[2], 2 * h, abs_tol=1e-6)


def test_pillars_hit_in_the_plane_like_true_cylinders():
    """The default 2D slice-equivalent pillars and exact cylinders give the same ray hits in the flight plane.

    (Rays starting inside a body differ -- a sphere reports a hit at fraction 0, a cylinder none -- and are left
    out: a MAV centre inside a body ends the trial before it senses.)"""
    radii = [1.0, 1.5]
    statics = [StaticBody("pillar", (14.0, 4.0), radius=0.8)]
    kwargs = dict(dims=2, arena_size=(20.0, 10.0), mav_radius=0.5, obstacle_radii=radii, static_bodies=statics)
    rng = np.random.default_rng(3)
    origins = np.c_[rng.uniform(0.5, 19.5, (600, 2)), np.full(600, 2.0)]
    inside = np.zeros(600, bool)
    for centre, r in [((5.0, 5.0), 1.0), ((10.0, 3.0), 1.5), ((14.0, 4.0), 0.8)]:
        inside |= np.hypot(origins[:, 0] - centre[0], origins[:, 1] - centre[1]) <= r
    origins = origins[~inside]
    ang = rng.uniform(0, 2 * np.pi, origins.shape[0])
    ends = origins + 12.0 * np.c_[np.cos(ang), np.sin(ang), np.zeros(origins.shape[0])]
    out = []
    for exact in (False, True):
        with PyBulletWorld(**kwargs, exact_pillars=exact) as w:
            w.set_obstacle_positions([[5.0, 5.0], [10.0, 3.0]])
            out.append(w.ray_test(origins, ends))
            if exact:
                lo, hi = w.client.getAABB(int(w.obstacle_ids[0]))
                assert math.isclose(lo[2], 0.0, abs_tol=0.05) and math.isclose(hi[2], 4.0, abs_tol=0.05)
    assert np.array_equal(out[0][0], out[1][0])
    assert (out[0][0] >= 0).sum() > 100
    # Bullet's GJK ray casts against curved shapes are accurate to ~1 mm (always hitting early, never late).
    assert np.allclose(out[0][1] * 12.0, out[1][1] * 12.0, atol=2e-3)
    # The hit points are on the analytic circles.
    pts, ids = out[0][2], out[0][0]
    for body, centre, r in [(1, (5.0, 5.0), 1.0), (2, (10.0, 3.0), 1.5), (3, (14.0, 4.0), 0.8)]:
        sel = ids == body
        assert sel.any()
        dist = np.hypot(pts[sel, 0] - centre[0], pts[sel, 1] - centre[1])
        assert np.all(dist >= r - 1e-9) and np.all(dist <= r + 2e-3)


def test_set_obstacle_positions_moves_what_rays_see(world2d):
    w = world2d
    w.set_obstacle_positions([[10.0, 2.0], [10.0, 8.0]])
    assert np.array_equal(w.obstacle_positions, [[10.0, 2.0], [10.0, 8.0]])
    body, _, pt = _ray(w, (10.0, 5.0, 2.0), (10.0, -1.0, 2.0))
    assert w.body_kind(body) == ("dynamic", 0) and math.isclose(pt[1], 3.0, abs_tol=1e-6)
    w.set_obstacle_positions([[10.0, 8.0], [17.0, 2.0]])
    body, _, pt = _ray(w, (10.0, 5.0, 2.0), (10.0, 20.0, 2.0))
    assert w.body_kind(body) == ("dynamic", 0) and math.isclose(pt[1], 7.0, abs_tol=1e-6)
    body, _, _ = _ray(w, (10.0, 5.0, 2.0), (10.0, -1.0, 2.0))
    assert w.body_kind(body) == ("wall", 2)


def test_rays_never_report_the_mav_and_its_pose_is_kept(world2d):
    w = world2d
    w.set_mav_pose([10.0, 8.5], 0.7)
    # From the MAV centre, and straight through the MAV from outside: both reach the wall at x = 20.
    for start in ((10.0, 8.5, 2.0), (8.0, 8.5, 2.0)):
        body, _, pt = _ray(w, start, (30.0, 8.5, 2.0))
        assert w.body_kind(body)[0] == "wall" and math.isclose(pt[0], 20.0, abs_tol=1e-6)
    pos, orn = w.client.getBasePositionAndOrientation(w.mav_id)
    assert np.allclose(pos, (10.0, 8.5, 2.0)) and np.allclose(orn, (0, 0, math.sin(0.35), math.cos(0.35)))
    with what_if_pose(w, [3.0, 3.0], 0.0):
        assert np.allclose(w.client.getBasePositionAndOrientation(w.mav_id)[0], (3.0, 3.0, 2.0))
    assert np.allclose(w.client.getBasePositionAndOrientation(w.mav_id)[0], (10.0, 8.5, 2.0))
    assert np.allclose(w.mav_position, (10.0, 8.5)) and w.mav_yaw == 0.7


def test_ray_test_chunks_large_batches(world2d):
    n = RAY_BATCH + 3000
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    origins = np.tile([10.0, 5.0, 2.0], (n, 1))
    ends = origins + 30.0 * np.c_[np.cos(ang), np.sin(ang), np.zeros(n)]
    ids, frac, pts = world2d.ray_test(origins, ends)
    assert ids.shape == (n,) and np.all(ids >= 0)          # the arena is closed: every ray hits something
    assert np.all(frac < 1.0) and pts.shape == (n, 3)
    empty = world2d.ray_test(np.zeros((0, 3)), np.zeros((0, 3)))
    assert [a.shape[0] for a in empty] == [0, 0, 0]


def test_static_clearance_is_the_true_signed_distance(world2d):
    w = world2d   # mav radius 0.5; pillar r=1 at (15, 5); box 2x4 at (5, 5); walls at x=0,20 / y=0,10
    assert math.isclose(w.static_clearance([18.0, 5.0], 5.0), 1.5, abs_tol=1e-3)      # wall at x = 20
    assert math.isclose(w.static_clearance([15.0, 7.5], 5.0), 1.0, abs_tol=1e-3)      # pillar: 2.5 - 1 - 0.5
    assert math.isclose(w.static_clearance([8.0, 5.0], 5.0), 1.5, abs_tol=1e-3)       # box face at x = 6
    assert math.isclose(w.static_clearance([15.0, 6.2], 5.0), -0.3, abs_tol=1e-3)     # penetrating the pillar
    assert w.static_clearance([10.0, 5.0], 0.5) == 0.5                                # nothing within 0.5 m
    d, body = w.nearest_static([1.0, 9.0], 5.0)
    assert math.isclose(d, 0.5, abs_tol=1e-3) and w.body_kind(body)[0] == "wall"
    w.set_obstacle_positions([[10.0, 8.0], [17.0, 2.0]])
    got = w.clearance_to_bodies([10.0, 5.0], w.obstacle_ids, 100.0)
    assert np.allclose(got, [3.0 - 1.5, math.hypot(7.0, 3.0) - 1.0], atol=1e-3)
    # The MAV body itself was not moved by these queries.
    assert np.allclose(w.client.getBasePositionAndOrientation(w.mav_id)[0], (10.0, 5.0, 2.0))  # centre, unmoved


def test_3d_world_spheres_pillars_boxes_and_six_walls():
    statics = [StaticBody("pillar", (5.0, 5.0), radius=1.0), StaticBody("box", (15.0, 5.0, 3.0), size=(2, 2, 2))]
    with PyBulletWorld(dims=3, arena_size=(20.0, 10.0, 8.0), mav_radius=0.5, obstacle_radii=[1.5],
                       static_bodies=statics) as w:
        assert len(w.wall_ids) == 6
        w.set_obstacle_positions([[10.0, 5.0, 6.0]])
        body, _, pt = _ray(w, (10.0, 5.0, 1.0), (10.0, 5.0, 20.0))
        assert w.body_kind(body) == ("dynamic", 0) and math.isclose(pt[2], 4.5, abs_tol=1e-6)
        body, _, pt = _ray(w, (12.0, 5.0, 4.0), (12.0, 5.0, -5.0))                # floor
        assert w.body_kind(body)[0] == "wall" and math.isclose(pt[2], 0.0, abs_tol=1e-6)
        body, _, pt = _ray(w, (12.0, 5.0, 4.0), (12.0, 5.0, 15.0))                # ceiling
        assert w.body_kind(body)[0] == "wall" and math.isclose(pt[2], 8.0, abs_tol=1e-6)
        for z in (0.3, 7.7):                                                       # pillar spans the full height
            body, _, pt = _ray(w, (2.0, 5.0, z), (9.0, 5.0, z))
            assert w.body_kind(body) == ("static", 0) and math.isclose(pt[0], 4.0, abs_tol=1e-6)
        body, _, pt = _ray(w, (15.0, 5.0, 7.5), (15.0, 5.0, 0.5))                  # box top at z = 4
        assert w.body_kind(body) == ("static", 1) and math.isclose(pt[2], 4.0, abs_tol=1e-6)
        assert math.isclose(w.static_clearance([15.0, 5.0, 6.0], 5.0), 1.5, abs_tol=1e-3)
        assert np.allclose(w.to_world3([[1.0, 2.0, 3.0]]), [[1, 2, 3]])


def test_add_static_urdf_registers_an_imported_static_body(world2d):
    w = world2d
    body = w.add_static_urdf(urdf_path("box"), (10.0, 8.5, 2.0), scale_xyz=(1.0, 1.0, 4.0))
    assert w.body_kind(body) == ("static", 2) and bool(w.is_static_body[body])
    hit, _, pt = _ray(w, (10.0, 5.0, 2.0), (10.0, 12.0, 2.0))
    assert hit == body and math.isclose(pt[1], 8.0, abs_tol=1e-6)
    d, near = w.nearest_static([10.0, 7.0], 3.0)
    assert near == body and math.isclose(d, 0.5, abs_tol=1e-3)


def test_bad_world_parameters_are_config_errors():
    base = dict(dims=2, arena_size=(10.0, 10.0), mav_radius=0.5, obstacle_radii=[1.0])
    for change, field in [({"dims": 4}, "dims"), ({"arena_size": (10.0,)}, "arena_size"),
                          ({"obstacle_radii": [-1.0]}, "obstacle_radii"), ({"mav_radius": 0.0}, "mav_radius"),
                          ({"static_bodies": [StaticBody("cone", (1, 1))]}, "static_bodies[0].kind"),
                          ({"static_bodies": [StaticBody("box", (1, 1), size=(1.0,))]}, "static_bodies[0]"),
                          ({"mav_urdf": "/nonexistent/mav.urdf"}, "mav_urdf")]:
        with pytest.raises(ConfigError) as err:
            PyBulletWorld(**{**base, **change}).close()
        assert err.value.field == field


def test_a_subprocess_building_a_world_prints_nothing_on_stdout():
    code = ("import numpy as np\n"
            "from pbdyn.world.bullet import PyBulletWorld\n"
            "from pbdyn.world.geometry import StaticBody\n"
            "w = PyBulletWorld(dims=2, arena_size=(20, 10), mav_radius=0.5, obstacle_radii=[1.0],\n"
            "                  static_bodies=[StaticBody('pillar', (5, 5), radius=1.0)])\n"
            "w.set_obstacle_positions([[10.0, 5.0]])\n"
            "print(int(w.ray_test([[1.0, 5.0, 2.0]], [[19.0, 5.0, 2.0]])[0][0]), file=__import__('sys').stderr)\n"
            "w.close()\n"
            "w2 = PyBulletWorld(dims=3, arena_size=(5, 5, 5), mav_radius=0.5, obstacle_radii=[1.0])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout == ""
    assert "2" in out.stderr.split()   # the ray hit the static pillar (body 2); PyBullet's chatter went here too


@pytest.mark.parametrize("dims", [2, 3])
def test_nearest_static_equals_bullets_broad_phase_choice(dims):
    """nearest_static asks Bullet only about the static bodies and walls whose AABB meets the query box; the answer
    equals the one with Bullet's own broad phase choosing the bodies (_nearest_static_broadphase), at points near and
    inside pillars, yawed boxes, walls and corners, with moving obstacles around and any query distance."""
    rng = np.random.default_rng(30 + dims)
    size = np.array([24.0, 16.0, 10.0][:dims])
    statics = [StaticBody("pillar", (6.0, 8.0), radius=0.7),
               StaticBody("box", (16.0, 5.0, 5.0)[:dims], size=(2.0, 1.0, 3.0)[:dims], yaw=0.5),
               StaticBody("box", (12.0, 14.5, 5.0)[:dims], size=(8.0, 0.3, 3.0)[:dims])]
    with PyBulletWorld(dims=dims, arena_size=size, mav_radius=0.4, obstacle_radii=np.ones(8),
                       static_bodies=statics) as w:
        kinds = set()
        for _ in range(400):
            w.set_obstacle_positions(rng.uniform(0.0, size, (8, dims)))
            p = rng.uniform(-0.5, size + 0.5)
            md = float(rng.choice([0.3, 1.0, 5.0, 30.0]))
            got = w.nearest_static(p, md)
            p3 = w.to_world3(p).tolist()
            reach = w.mav_radius + md + 1e-6
            want = w._nearest_static_broadphase(p3, md, [x - reach for x in p3], [x + reach for x in p3])
            assert got == want
            kinds.add(w.body_kind(got[1])[0] if got[1] >= 0 else "none")
        assert kinds == {"static", "wall", "none"}
