"""Maps and rollouts: closed-form CVM with exact reflections, spawn rules, value-keyed seeds, files and cache."""

from __future__ import annotations

import numpy as np
import pytest

from pbdyn.config import load_scenario, parse_scenario
from pbdyn.errors import HorizonError
from pbdyn.motion.cvm import cvm_fold
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import Rollout, build_rollout, cache_dir, get_rollout, rollout_key
from tests.conftest import SCENARIOS


def _event_driven(p0, v0, r, size, t_end):
    """Reference: integrate one obstacle by jumping from wall hit to wall hit (independent of the fold)."""
    p, v, t = np.array(p0, float), np.array(v0, float), 0.0
    lo, hi = r, np.asarray(size, float) - r
    while True:
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hit = np.where(v > 0, (hi - p) / v, np.where(v < 0, (lo - p) / v, np.inf))
        k = int(np.argmin(t_hit))
        if t + t_hit[k] >= t_end:
            return p + v * (t_end - t)
        p = p + v * t_hit[k]
        p[k] = lo if v[k] < 0 else hi[k]
        t += t_hit[k]
        v[k] = -v[k]


def test_cvm_matches_event_driven_reference():
    rng = np.random.default_rng(3)
    size = np.array([50.0, 30.0])
    n = 6
    radii = rng.uniform(0.5, 1.5, n)
    p0 = rng.uniform(radii[:, None], size - radii[:, None], (n, 2))
    v0 = rng.uniform(-6, 6, (n, 2))
    times = np.array([0.0, 0.1, 3.7, 12.25, 79.9, 1000.3])
    pos, vel = cvm_fold(p0, v0, radii, size, times)
    for i in range(n):
        for j, t in enumerate(times):
            np.testing.assert_allclose(pos[j, i], _event_driven(p0[i], v0[i], radii[i], size, t), atol=1e-9)
    assert np.all(np.abs(vel) == np.abs(v0)[None])


def test_reflection_is_exact_at_a_known_time():
    pos, vel = cvm_fold(np.array([[1.5, 10.0]]), np.array([[-1.0, 0.0]]), np.array([1.0]), np.array([20.0, 20.0]),
                        np.array([0.25, 0.5, 1.0]))
    np.testing.assert_allclose(pos[:, 0, 0], [1.25, 1.0, 1.5], atol=1e-12)
    assert vel[2, 0, 0] == 1.0


def test_rollout_stays_in_arena_and_spawns_clear():
    sc = load_scenario(SCENARIOS / "controlled_2d.toml")
    maps = enumerate_maps(sc)
    for spec in (maps[0], maps[-1], maps[270]):
        ro = build_rollout(sc, spec)
        r = ro.radii
        assert ro.positions.shape == (ro.n_steps, spec.setup["count"], 2)
        assert np.all(ro.positions >= r[None, :, None] - 1e-9)
        assert np.all(ro.positions <= 50.0 - r[None, :, None] + 1e-9)
        p = ro.positions[0]
        dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
        np.fill_diagonal(dist, np.inf)
        assert np.all(dist >= r[:, None] + r[None, :])
        cands = np.asarray(sc.task.candidates)
        dc = np.linalg.norm(p[:, None] - cands[None], axis=-1)
        assert np.all(dc >= r[:, None] + sc.drone.radius + sc.task.spawn_clearance)
        assert np.all(np.abs(np.linalg.norm(ro.velocities, axis=-1) - spec.setup["speed"]) < 1e-9)
        assert np.all(np.abs(r - spec.setup["radius"]) <= 0.2 + 1e-12)


def test_headings_are_random_not_evenly_spaced():
    sc = parse_scenario({"obstacles": {"count": 30, "speed": 2.0}})
    ro = build_rollout(sc, enumerate_maps(sc)[0])
    ang = np.sort(np.arctan2(ro.velocities[0, :, 1], ro.velocities[0, :, 0]))
    gaps = np.diff(ang)
    assert gaps.std() > 0.01  # 2*pi*k/N headings (the program's defect) would give equal gaps


def test_same_setup_values_give_same_map_when_grid_grows():
    small = parse_scenario({"obstacles": {"count": [10, 20], "speed": 2.0, "maps_per_setup": 2}})
    big = parse_scenario({"obstacles": {"count": [5, 10, 20, 30], "speed": [2.0, 4.0], "maps_per_setup": 3}})
    small_maps = {m.key: m for m in enumerate_maps(small)}
    big_maps = {m.key: m for m in enumerate_maps(big)}
    assert set(small_maps) <= set(big_maps)
    for key, m in small_maps.items():
        a = build_rollout(small, m)
        b = build_rollout(big, big_maps[key])
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.radii, b.radii)
    # and different replicates differ
    ms = enumerate_maps(small)
    assert not np.array_equal(build_rollout(small, ms[0]).positions, build_rollout(small, ms[1]).positions)


def test_map_enumeration_order():
    sc = parse_scenario({"obstacles": {"speed": [2.0, 4.0], "count": [10, 20], "maps_per_setup": 2}})
    maps = enumerate_maps(sc)
    # file order: speed first (slowest), then count, replicates fastest
    assert [(m.setup["speed"], m.setup["count"], m.replicate) for m in maps[:4]] == [
        (2.0, 10, 0), (2.0, 10, 1), (2.0, 20, 0), (2.0, 20, 1)]
    assert [m.index for m in maps] == list(range(8))


def test_npz_roundtrip_documented_arrays(tmp_path):
    sc = parse_scenario({"static_obstacles": [{"kind": "pillar", "center": [25, 10], "radius": 1.0},
                                              {"kind": "box", "center": [10, 30], "size": [2, 4], "yaw_deg": 30}]})
    ro = build_rollout(sc, enumerate_maps(sc)[0])
    path = tmp_path / "r.npz"
    ro.save(path)
    with np.load(path) as z:
        assert {"times", "positions", "velocities", "radii", "arena_size", "dt", "static_kind", "static_center",
                "static_radius", "static_size", "static_yaw", "meta"} <= set(z.files)
    back = Rollout.load(path)
    assert np.array_equal(back.positions, ro.positions) and back.static == ro.static and back.meta == ro.meta
    assert list(tmp_path.iterdir()) == [path]  # no temp files left behind


def test_horizon_error():
    sc = parse_scenario({"world": {"time_limit": 1.0}})
    ro = build_rollout(sc, enumerate_maps(sc)[0], horizon=1.1)
    assert ro.n_steps == 12
    ro.at(11)
    with pytest.raises(HorizonError):
        ro.at(12)
    # by default a rollout covers the trial and the default metrics (global survivability: 20 s + 24 s)
    assert build_rollout(sc, enumerate_maps(sc)[0]).horizon >= 44.0


def test_cache_is_keyed_and_reused():
    sc = parse_scenario({"world": {"time_limit": 5.0}})
    spec = enumerate_maps(sc)[0]
    ro = get_rollout(sc, spec)
    path = cache_dir() / "rollouts" / f"{rollout_key(sc, spec, 44.1)}.npz"
    assert path.is_file()
    again = get_rollout(sc, spec)
    assert np.array_equal(again.positions, ro.positions)
    other = parse_scenario({"world": {"time_limit": 5.0}, "obstacles": {"radius_jitter": 0.1}})
    assert rollout_key(other, enumerate_maps(other)[0], 44.1) != rollout_key(sc, spec, 44.1)
