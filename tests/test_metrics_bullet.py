"""The bullet survivability backend (pbdyn.metrics.bullet_backend): hand-computed worlds, any shape, independence
from the analytic kernel and agreement with it (issue 4, "Survivability backends")."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import HorizonError
from pbdyn.metrics.bullet_backend import ExtraBody, survival_table_bullet, survival_times_bullet
from pbdyn.metrics.sampling import grid_samples
from pbdyn.world.geometry import StaticBody
from pbdyn.world.imported.urdf_loading import urdf_path
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import Rollout, build_rollout

from tests.conftest import ROOT

DT = 0.1


def linear_rollout(p0, v, radii, *, dims=2, size=50.0, n_steps=300, static=()) -> Rollout:
    """Obstacles moving in straight lines p0 + v t (no reflection), t = k dt."""
    times = np.arange(n_steps) * DT
    p0 = np.asarray(p0, float).reshape(-1, dims)
    v = np.asarray(v, float).reshape(-1, dims)
    pos = p0[None] + times[:, None, None] * v[None]
    vel = np.broadcast_to(v, pos.shape)
    return Rollout(times, pos, vel, np.asarray(radii, float).reshape(-1), np.full(dims, size), DT, tuple(static))


def reference_times(ro: Rollout, pts, *, mav_radius=1.0, t_max=12.0, start_time=0.0) -> np.ndarray:
    """Independent numpy reference: first step k with centre distance < r_i + r_mav, t = k dt, capped at t_max."""
    k0 = int(round(start_time / ro.dt))
    n = int(np.floor(t_max / ro.dt + 1e-9))
    out = np.full(len(pts), float(t_max))
    alive = np.ones(len(pts), dtype=bool)
    for k in range(n + 1):
        d = np.linalg.norm(pts[:, None, :] - ro.positions[k0 + k][None], axis=-1)
        hit = alive & np.any(d < ro.radii[None] + mav_radius, axis=1)
        out[hit] = k * ro.dt
        alive &= ~hit
    return out


def assert_agree(a: np.ndarray, b: np.ndarray, dt: float) -> None:
    """The issue's criterion: >= 99 % identical, the rest one step apart."""
    same = np.isclose(a, b, rtol=0.0, atol=1e-9)
    assert same.mean() >= 0.99, f"{(~same).sum()} of {a.size} differ"
    assert np.all(np.abs(a - b)[~same] <= dt + 1e-9)


# ------------------------------------------------------------------------------------------------ hand-computed
def test_head_on_obstacle_strict_touch():
    # Obstacle r = 1 from x = 5 at 2 m/s toward samples at x = 25: overlap needs 25 - x < 2, i.e. t > 9 s.
    ro = linear_rollout([[5.0, 25.0], [5.05, 10.0]], [[2.0, 0.0], [2.0, 0.0]], [1.0, 1.0])
    assert ro.positions[90, 0, 0] == 23.0          # at k = 90 the first obstacle exactly touches: not a hit
    t = survival_times_bullet(ro, np.array([[25.0, 25.0], [25.0, 10.0]]))
    # first sample: k = 91; second: 5.05 + 2t > 23 -> t > 8.975 -> k = 90
    np.testing.assert_allclose(t, [9.1, 9.0], atol=1e-12)
    # relative to a later start time
    t4 = survival_times_bullet(ro, np.array([[25.0, 10.0]]), start_time=4.0)
    np.testing.assert_allclose(t4, [5.0], atol=1e-12)
    # a shorter horizon caps the value
    np.testing.assert_allclose(survival_times_bullet(ro, np.array([[25.0, 10.0]]), t_max=5.0), [5.0])


def test_pass_by_just_outside_never_hits_and_just_inside_does():
    # Lanes at y offsets 2.01 (= r_i + r_mav + 0.01) and 1.99 from the samples.
    ro = linear_rollout([[5.0, 27.01], [5.0, 11.99]], [[2.0, 0.0], [2.0, 0.0]], [1.0, 1.0])
    t = survival_times_bullet(ro, np.array([[25.0, 25.0], [25.0, 10.0]]), t_max=20.0)
    # inside lane: |x - 25| < sqrt(4 - 1.99^2) -> 5 + 2t > 24.80025 -> t > 9.9001 -> k = 100
    np.testing.assert_allclose(t, [20.0, 10.0], atol=1e-12)


def test_empty_world_and_far_obstacles_give_t_max():
    empty = linear_rollout(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    pts = grid_samples(empty.arena_size, 6.0)
    np.testing.assert_array_equal(survival_times_bullet(empty, pts), np.full(len(pts), 12.0))
    # obstacles (so Bullet does run) that stay in a corner away from every sample
    far = linear_rollout([[49.0, 49.0], [0.5, 49.0]], np.zeros((2, 2)), [0.5, 0.5], n_steps=441)
    np.testing.assert_array_equal(survival_times_bullet(far, pts, t_max=7.0), np.full(len(pts), 7.0))
    np.testing.assert_array_equal(survival_table_bullet(far, pts, [0.0, 4.0, 8.0, 12.0, 16.0, 20.0], t_max=24.0),
                                  np.full((6, len(pts)), 24.0))


def test_query_spheres_ignore_each_other_and_static_bodies():
    # Overlapping query spheres and a static pillar on top of a sample: neither is an obstacle (the caller leaves
    # samples overlapping static geometry out); only the dynamic obstacle counts.
    ro = linear_rollout([[45.0, 45.0]], [[0.0, 0.0]], [1.0], static=(StaticBody("pillar", (10.0, 10.0), 1.0),))
    pts = np.array([[10.0, 10.0], [10.5, 10.0], [11.0, 10.2], [44.0, 44.0]])
    np.testing.assert_array_equal(survival_times_bullet(ro, pts), [12.0, 12.0, 12.0, 0.0])


def test_3d_diagonal_approach_and_pass_by():
    u = np.ones(3) / np.sqrt(3.0)
    s = np.array([20.0, 20.0, 10.0])
    # r = 0.5 from 10 m away at 2 m/s: 10 - 2t < 1.5 -> t > 4.25 -> k = 43; the second passes 1.51 m above sample 2.
    s2 = np.array([30.0, 30.0, 10.0])
    ro = linear_rollout([s - 10.0 * u, s2 + [-10.0, 0.0, 1.51]], [2.0 * u, [2.0, 0.0, 0.0]], [0.5, 0.5], dims=3)
    t = survival_times_bullet(ro, np.stack([s, s2]))
    np.testing.assert_allclose(t, [4.3, 12.0], atol=1e-12)
    np.testing.assert_allclose(t, reference_times(ro, np.stack([s, s2])))


def test_horizon_error():
    ro = linear_rollout([[5.0, 25.0]], [[2.0, 0.0]], [1.0], n_steps=100)    # horizon 9.9 s
    with pytest.raises(HorizonError):
        survival_times_bullet(ro, np.array([[25.0, 25.0]]), t_max=12.0)
    with pytest.raises(HorizonError):
        survival_table_bullet(ro, np.array([[25.0, 25.0]]), (0.0, 5.0), t_max=5.0)


# ------------------------------------------------------------------------------------------------ any shape
def test_moving_box_matches_hand_value_not_bounding_disc():
    # A 2 x 2 m box (2D: spanning [0, 4] m in z) moving +x at 1 m/s along y = 25 from x = 15.05.
    T = 200
    times = np.arange(T) * DT
    empty = linear_rollout(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), n_steps=T)
    poses = np.stack([15.05 + times, np.full(T, 25.0), np.full(T, 2.0)], axis=1)
    box = ExtraBody(urdf_path("box"), (2.0, 2.0, 4.0), poses)
    pts = np.array([[25.0, 25.0], [25.0, 26.99], [25.0, 27.01]])
    t = survival_times_bullet(empty, pts, extra_bodies=[box])
    # face: x_c + 1 > 24 -> t > 7.95 -> 8.0 s; edge y = 26 vs sample at y = 26.99: |x_c + 1 - 25| < sqrt(1 - 0.99^2)
    # -> t > 8.809 -> 8.9 s; at y = 27.01 the box's side (y <= 26) stays 0.01 m away: never.
    np.testing.assert_allclose(t, [8.0, 8.9, 12.0], atol=1e-12)
    # the same box given by a pose function
    moving = ExtraBody(urdf_path("box"), (2.0, 2.0, 4.0), lambda tt: (15.05 + tt, 25.0, 2.0))
    np.testing.assert_allclose(survival_times_bullet(empty, pts[:1], extra_bodies=[moving]), [8.0], atol=1e-12)
    # The bounding disc (radius sqrt 2): |25 - x_c| < sqrt((1 + sqrt 2)^2 - dy^2) -> t > 7.536, 8.583, 8.613 s.
    disc = linear_rollout([[15.05, 25.0]], [[1.0, 0.0]], [np.sqrt(2.0)], n_steps=T)
    b = survival_times_bullet(disc, pts)
    np.testing.assert_allclose(b, reference_times(disc, pts))
    np.testing.assert_allclose(b, [7.6, 8.6, 8.7], atol=1e-12)
    assert np.all(b < t)


# ------------------------------------------------------------------------------------------------ independence
def test_bullet_backend_does_not_need_the_analytic_module(monkeypatch):
    code = textwrap.dedent("""
        import sys, numpy as np
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name == "pbdyn.metrics.analytic":
                    raise ImportError("analytic module blocked")
        sys.meta_path.insert(0, Block())
        sys.modules.pop("pbdyn.metrics.analytic", None)
        from pbdyn.world.rollout import Rollout
        from pbdyn.metrics.bullet_backend import survival_times_bullet
        T = 150; t = np.arange(T) * 0.1
        pos = np.stack([5.05 + 2 * t, np.full(T, 10.0)], 1)[:, None, :]
        ro = Rollout(t, pos, np.zeros_like(pos), np.ones(1), np.array([50.0, 50.0]), 0.1)
        assert "pbdyn.metrics.analytic" not in sys.modules
        print(survival_times_bullet(ro, np.array([[25.0, 10.0]]))[0])
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "9.0"
    # in-process: the analytic functions raising, or its module entry replaced by something that raises
    try:
        import pbdyn.metrics.analytic as analytic
    except ImportError:
        analytic = None
    if analytic is not None:
        for name in ("survival_times", "survivability", "global_survivability"):
            if hasattr(analytic, name):
                monkeypatch.setattr(analytic, name, _raise)

    class Raising:
        def __getattr__(self, name):
            raise RuntimeError("analytic module used")
    monkeypatch.setitem(sys.modules, "pbdyn.metrics.analytic", Raising())
    ro = linear_rollout([[5.05, 10.0]], [[2.0, 0.0]], [1.0])
    np.testing.assert_allclose(survival_times_bullet(ro, np.array([[25.0, 10.0]])), [9.0], atol=1e-12)


def _raise(*args, **kwargs):
    raise RuntimeError("analytic survivability called")


# ------------------------------------------------------------------------------------------------ agreement
@pytest.fixture(scope="module")
def maps():
    """Two generated 2D maps (30 obstacles, r 1 m, 4 m/s) with the dense grid, one 3D map with the 6 m grid."""
    out = []
    sc = parse_scenario({"obstacles": {"count": 30, "radius": 1.0, "speed": 4.0, "maps_per_setup": 2}})
    for spec in enumerate_maps(sc):
        ro = build_rollout(sc, spec, horizon=30.0)
        out.append((ro, grid_samples(ro.arena_size, 3.0)))
    sc3 = parse_scenario({"world": {"dims": 3}, "obstacles": {"count": 30, "radius": 1.0, "speed": 4.0}})
    ro = build_rollout(sc3, enumerate_maps(sc3)[0], horizon=30.0)
    out.append((ro, grid_samples(ro.arena_size, 6.0)))
    return out


@pytest.fixture(scope="module")
def bullet_times(maps):
    return [{st: survival_times_bullet(ro, pts, start_time=st) for st in (0.0, 10.0)} for ro, pts in maps]


def test_agrees_with_independent_reference(maps, bullet_times):
    for (ro, pts), times in zip(maps, bullet_times):
        for st, t in times.items():
            ref = reference_times(ro, pts, start_time=st)
            assert_agree(t, ref, ro.dt)
            assert 0.0 < t.mean() < 12.0 and np.any(t == 0.0) and np.any(t == 12.0)  # a non-trivial map


def test_agrees_with_analytic_kernel(maps, bullet_times):
    analytic = pytest.importorskip("pbdyn.metrics.analytic")
    for (ro, pts), times in zip(maps, bullet_times):
        for st, t in times.items():
            assert_agree(t, analytic.survival_times(ro, pts, start_time=st, mode="sampled"), ro.dt)


def test_exact_pillars_agree_with_pillar_spheres(maps, bullet_times):
    ro, pts = maps[0]
    assert_agree(survival_times_bullet(ro, pts, exact_pillars=True), bullet_times[0][0.0], ro.dt)


def test_global_survival_is_the_first_hit_of_any_point(maps):
    ro, _ = maps[1]
    pts = np.array([[14.0, 14.0], [14.0, 36.0], [36.0, 14.0], [36.0, 36.0], [25.0, 25.0]])
    starts = (0.0, 2.0, 4.0)
    g = survival_table_bullet(ro, pts, starts, t_max=12.0).min(axis=1)          # global survivability's times
    for j, st in enumerate(starts):
        single = survival_times_bullet(ro, pts, t_max=12.0, start_time=st)
        assert g[j] == pytest.approx(single.min(), abs=1e-12)
        assert g[j] == pytest.approx(reference_times(ro, pts, t_max=12.0, start_time=st).min(), abs=1e-12)
    assert np.all(g < 12.0) and np.any(g > 0.0)


def test_bad_extra_body_input(tmp_path):
    from pbdyn.errors import ConfigError
    empty = linear_rollout(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    pts = np.array([[25.0, 25.0]])
    with pytest.raises(ConfigError, match="urdf"):
        survival_times_bullet(empty, pts, extra_bodies=[ExtraBody(tmp_path / "missing.urdf", pose=np.zeros((300, 3)))])
    with pytest.raises(ConfigError, match="pose"):
        survival_times_bullet(empty, pts, extra_bodies=[ExtraBody(urdf_path("box"))])
