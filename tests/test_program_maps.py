"""The thesis program's own maps (obstacles.layout = "program") and its wall turn (obstacles.wall_turn = "program")."""

from __future__ import annotations

import math
import random
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.motion.cvm import cvm_fold, cvm_program_turn
from pbdyn.world.maps import PROGRAM_METRICS_START, enumerate_maps, program_stream, spawn_obstacles
from pbdyn.world.rollout import build_rollout, rollout_key

ROOT = Path(__file__).resolve().parents[1]
CONTROLLED = ROOT / "scenarios" / "thesis" / "controlled_2d.toml"


def _controlled(**obstacles):
    doc = tomllib.loads(CONTROLLED.read_text())
    doc["obstacles"].update(obstacles)
    return parse_scenario(doc)


def _program_spawn(map_id: int, n: int, r_px: float, start_px) -> np.ndarray:
    """The program's procedure, step by step in its pixels with Python's random (docs/thesis-program.md): per
    attempt x, y uniform in [20, 480] px, then the radius uniform in [r - 2, r + 2] px; rejected when within the sum
    of radii of an accepted centre or within 80 px (MAV radius + 7 m) of the start. Rows (x, y, r) px."""
    rnd = random.Random(map_id)
    out: list[tuple[float, float, float]] = []
    while len(out) < n:
        x, y = rnd.uniform(20, 480), rnd.uniform(20, 480)
        rad = rnd.uniform(r_px - 2, r_px + 2)
        if all(math.hypot(a[0] - x, a[1] - y) > a[2] + rad for a in out) and \
                math.hypot(x - start_px[0], y - start_px[1]) > 80:
            out.append((x, y, rad))
    return np.array(out)


def test_program_stream_is_pythons_random_for_the_seed():
    for seed in (0, 1, 7, 19, 2**40 + 3):
        rnd = random.Random(seed)
        assert program_stream(seed).random(2000).tolist() == [rnd.random() for _ in range(2000)]


def test_program_layout_draws_the_programs_maps_around_the_flown_start():
    sc = _controlled()
    assert (sc.obstacles.layout, sc.obstacles.wall_turn) == ("program", "program")
    maps = enumerate_maps(sc)
    checked = 0
    for spec in list(maps)[::5]:
        for start in ((3.0, 3.0), (24.0, 45.0), (45.0, 24.0)):
            c, v, r = spawn_obstacles(sc, spec, (np.array([start]), 7.0))
            ref = _program_spawn(spec.replicate, spec.setup["count"], 10 * spec.setup["radius"],
                                 (10 * (start[0] + 1), 10 * (start[1] + 1)))
            np.testing.assert_allclose(np.c_[10 * (c + 1), 10 * r], ref, rtol=0, atol=1e-9)
            k = np.arange(spec.setup["count"])
            ang = 2 * np.pi * k / spec.setup["count"]
            np.testing.assert_allclose(v, -spec.setup["speed"] * np.c_[np.cos(ang), np.sin(ang)], atol=1e-12)
            checked += 1
    assert checked >= 60
    # a metrics map (no flown start) is the program's map around its metrics start
    spec = maps[0]
    c, _, r = spawn_obstacles(sc, spec)
    ref = _program_spawn(0, spec.setup["count"], 10 * spec.setup["radius"],
                         [10 * (x + 1) for x in PROGRAM_METRICS_START])
    np.testing.assert_allclose(np.c_[10 * (c + 1), 10 * r], ref, rtol=0, atol=1e-9)


def test_program_maps_share_their_draws_across_setups():
    sc = _controlled()
    by_setup = {}
    for spec in enumerate_maps(sc):
        if spec.replicate == 2:
            by_setup[(spec.setup["count"], spec.setup["radius"], spec.setup["speed"])] = spec
    start = (np.array([[24.0, 24.0]]), 7.0)
    c10, _, r10 = spawn_obstacles(sc, by_setup[(10, 1.0, 2.0)], start)
    c30, _, r30 = spawn_obstacles(sc, by_setup[(30, 1.0, 6.0)], start)
    np.testing.assert_array_equal(c30[:10], c10)      # the first ten obstacles are the same draws
    np.testing.assert_array_equal(r30[:10], r10)
    other = spawn_obstacles(sc, next(s for s in enumerate_maps(sc) if s.replicate == 3), start)[0]
    assert not np.allclose(other[:10], c10)


def test_program_turn_steps_like_the_program():
    rng = np.random.default_rng(5)
    n, size, dt = 12, np.array([48.0, 48.0]), 0.1
    radii = rng.uniform(0.3, 1.7, n)
    p0 = rng.uniform(radii[:, None] + 0.6, size - radii[:, None] - 0.6, (n, 2))
    v0 = rng.uniform(-6, 6, (n, 2))
    times = np.arange(400) * dt
    pos, vel = cvm_program_turn(p0, v0, radii, size, times)
    # by hand, one obstacle at a time as the program's Agent.step did: the next centre is tested, and the turn
    # changes the very velocity it moves with (its velocity and preferred velocity were one array)
    for i in range(n):
        p, v = p0[i].copy(), v0[i].copy()
        for k in range(times.size):
            ahead = p + v * dt
            for a in range(2):
                if ahead[a] < radii[i]:
                    v[a] = abs(v[a])
                elif ahead[a] > size[a] - radii[i]:
                    v[a] = -abs(v[a])
            np.testing.assert_allclose(pos[k, i], p, atol=1e-9)
            np.testing.assert_array_equal(vel[k, i], v)
            p = p + v * dt
    # it turns before the line r from a wall, by up to one step, where the specular fold touches it
    gap = np.minimum(pos - radii[None, :, None], (size - radii[:, None])[None] - pos)
    assert gap.min() >= 0 and np.abs(vel).max() * dt > gap.min()
    fpos, _ = cvm_fold(p0, v0, radii, size, times)
    fgap = np.minimum(fpos - radii[None, :, None], (size - radii[:, None])[None] - fpos)
    assert fgap.min() >= -1e-9
    assert not np.allclose(pos, fpos)


def test_program_rollouts_use_the_late_turn_and_their_own_cache_key():
    sc, plain = _controlled(), _controlled(layout="pbdyn", wall_turn="specular")
    spec = enumerate_maps(sc)[40]
    keep = (np.array([[3.0, 45.0]]), 7.0)
    ro = build_rollout(sc, spec, 20.0, keep_out=keep)
    c, v, r = spawn_obstacles(sc, spec, keep)
    pos, vel = cvm_program_turn(c, v, r, np.array(sc.world.size), ro.times)
    np.testing.assert_array_equal(ro.positions, pos)
    assert rollout_key(sc, spec, 20.0) != rollout_key(plain, spec, 20.0)


@pytest.mark.parametrize("edit, field", [
    ({"layout": "program", "headings": "uniform"}, "obstacles.layout"),
    ({"layout": "program", "speed": {"min": 2.0, "max": 6.0}}, "obstacles.layout"),
    ({"layout": "grid"}, "obstacles.layout"),
    ({"wall_turn": "program", "motion": "rvo"}, "obstacles.wall_turn"),
    ({"wall_turn": "late"}, "obstacles.wall_turn"),
])
def test_bad_program_layout_fields_name_the_field(edit, field):
    doc = tomllib.loads(CONTROLLED.read_text())
    doc["obstacles"].update(edit)
    with pytest.raises(ConfigError) as exc:
        parse_scenario(doc)
    assert exc.value.field == field


def test_program_layout_is_2d_only():
    doc = {"world": {"dims": 3, "size": [48.0, 48.0, 20.0]},
           "obstacles": {"count": 5, "radius": 1.0, "speed": 2.0, "headings": "even", "layout": "program"},
           "planners": [{"trajectory": "local_primitives", "gaze": "fullrange"}]}
    with pytest.raises(ConfigError) as exc:
        parse_scenario(doc)
    assert exc.value.field == "obstacles.layout"


def test_the_new_fields_leave_the_keys_of_trials_that_do_not_use_them_as_they_were():
    """layout, wall_turn and track_radius at their defaults are not part of a trial's key: the keys below were
    written by the version before these fields, so existing stores keep resuming."""
    from pbdyn.config import load_scenario
    from pbdyn.experiments.tasks import trial_spec
    from pbdyn.world.maps import enumerate_maps

    def key(name, **obstacles):
        sc = load_scenario(name)
        if obstacles:
            doc = tomllib.loads(Path(name).read_text())
            doc["obstacles"].update(obstacles)
            sc = parse_scenario(doc)
        m = enumerate_maps(sc)[1]
        return trial_spec(sc, m, sc.planners[0], sc.drone.v_max[0], sc.task.candidates[0],
                          sc.task.candidates[-1]).config_hash

    assert key("quickstart") == "8aeb3ee2749ce59ef1e97fb966eaafbb04e9ded9ae032e05b365de128a4fca50"
    plain = str(ROOT / "scenarios" / "datasets" / "controlled_2d.toml")
    assert key(plain) == "ce03e649987ccf4a74b7a8f879162bed83f2b07a4150a4f7cf9e030c7e69af4a"
    assert key(plain, wall_turn="program") != key(plain)
