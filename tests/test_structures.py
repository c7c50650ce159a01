"""Structured worlds (pbdyn.world.structure, obstacles.structure): each generator makes what it claims -- clustering,
flows crossing the start/goal lines, passable wall gaps, static shares, size and speed spreads, RVO -- in 2D and
3D, reproducibly, without changing maps that have no structure."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pbdyn.config import parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import build_rollout, rollout_key

ALL = ["uniform", "clustered", "crossing", "walls", "mixed", "spread", "rvo"]


def scenario(dims=2, structure=ALL, count=30, maps=4, **extra):
    doc = {"world": {"dims": dims, "time_limit": 30.0},
           "obstacles": {"count": count, "radius": 1.0, "speed": 4.0, "structure": structure,
                         "maps_per_setup": maps},
           "drone": {"v_max": 4.0}}
    for k, v in extra.items():
        doc.setdefault(k, {}).update(v) if isinstance(v, dict) else doc.update({k: v})
    return parse_scenario(doc)


def rollouts(sc, name):
    return [build_rollout(sc, m) for m in enumerate_maps(sc) if m.setup["structure"] == name]


def clark_evans(p: np.ndarray, size: np.ndarray) -> float:
    """Mean nearest-neighbour distance over its expectation for uniform points (2D: 0.5 / sqrt(density))."""
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(d.min(axis=1).mean() / (0.5 / np.sqrt(p.shape[0] / np.prod(size))))


def test_structure_config_names_tables_and_errors():
    sc = scenario(structure=["uniform", "dense_clusters"],
                  obstacles={"structures": {"dense_clusters": {"layout": "clustered", "clusters": 2,
                                                               "cluster_spread": 2.5}}})
    assert sc.obstacles.grid_order[-1] == "structure" and sc.obstacles.structure == ("uniform", "dense_clusters")
    st = sc.obstacles.structure_of("dense_clusters")
    assert (st.layout, st.clusters, st.cluster_spread) == ("clustered", 2, 2.5)
    assert [m.setup["structure"] for m in enumerate_maps(sc)][::4] == ["uniform", "dense_clusters"]
    # a built-in name can be overridden by a table
    assert scenario(structure=["walls"], obstacles={"structures": {"walls": {"walls": 3}}}) \
        .obstacles.structure_of("walls").walls == 3
    for bad, field in ((["nope"], "obstacles.structure[0]"), ([], "obstacles.structure"),
                       (["uniform", "uniform"], "obstacles.structure")):
        with pytest.raises(ConfigError, match=field.replace("[", r"\[").replace("]", r"\]")):
            scenario(structure=bad)
    with pytest.raises(ConfigError, match=r"obstacles.structures.walls.wall_gap"):
        scenario(structure=["walls"], obstacles={"structures": {"walls": {"wall_gap": 2.5}}})
    with pytest.raises(ConfigError, match=r"obstacles.structures.extra"):
        scenario(structure=["uniform"], obstacles={"structures": {"extra": {"walls": 1}}})
    with pytest.raises(ConfigError, match=r"obstacles.structures.w.static_fraction"):
        scenario(structure=["w"], obstacles={"structures": {"w": {"static_fraction": 1.5}}})
    with pytest.raises(ConfigError, match=r"obstacles.structures.w.colour"):
        scenario(structure=["w"], obstacles={"structures": {"w": {"colour": "red"}}})


def test_maps_without_a_structure_are_unchanged():
    plain = parse_scenario({"obstacles": {"count": 30, "radius": 1.0, "speed": 4.0, "maps_per_setup": 2}})
    assert "structure" not in plain.to_dict()["obstacles"] and plain.obstacles.grid_order == ("count", "radius",
                                                                                             "speed")
    m = enumerate_maps(plain)[1]
    assert m.setup == {"count": 30, "radius": 1.0, "speed": 4.0}
    # the "uniform" structure draws the same obstacles as a map without one (its own map key, same rule)
    ro = build_rollout(plain, m)
    assert ro.static == () and ro.meta["motion"] == "cvm"


@pytest.mark.parametrize("dims", [2, 3])
def test_clustered_positions_cluster_and_uniform_do_not(dims):
    sc = scenario(dims=dims, structure=["uniform", "clustered"], count=40, maps=5)
    size = np.asarray(sc.world.size)
    if dims == 3:       # the clustering index of the x-y projection
        size = size[:2]
    ce = {name: np.mean([clark_evans(ro.positions[0][:, :2], size) for ro in rollouts(sc, name)])
          for name in ("uniform", "clustered")}
    assert ce["clustered"] < 0.85 and ce["uniform"] > 1.0 and ce["uniform"] - ce["clustered"] > 0.3


def _crosses(p, v, a, g, window):
    """True when the path p + v tau, tau in [0, window], meets the segment a-g (2D: exact intersection; 3D:
    closest approach of the two segments below 1e-6 m)."""
    d = v * window
    e = g - a
    if p.shape[0] == 2:
        den = d[0] * e[1] - d[1] * e[0]
        if abs(den) < 1e-12:
            return False
        w = a - p
        t = (w[0] * e[1] - w[1] * e[0]) / den
        u = (w[0] * d[1] - w[1] * d[0]) / den
        return -1e-9 <= t <= 1 + 1e-9 and -1e-9 <= u <= 1 + 1e-9
    ts = np.linspace(0, 1, 2001)
    path = p + ts[:, None] * d
    seg = a + np.clip(((path - a) @ e) / (e @ e), 0, 1)[:, None] * e
    return np.min(np.linalg.norm(path - seg, axis=1)) < 0.02


@pytest.mark.parametrize("dims", [2, 3])
def test_crossing_flows_are_aimed_across_the_start_goal_lines(dims):
    """Every crossing obstacle's straight path crosses a candidate segment within the window, heading exactly
    across it; uniformly random headings are (almost surely) never exactly across the segments they cross."""
    sc = scenario(dims=dims, structure=["uniform", "crossing"], count=25, maps=3)
    cands = np.asarray(sc.task.candidates)
    window = sc.obstacles.structure_of("crossing").crossing_window_s
    segments = list(itertools.combinations(range(len(cands)), 2))
    aimed = {}
    for name in ("uniform", "crossing"):
        flags = []
        for ro in rollouts(sc, name):
            p, v = ro.positions[0], ro.velocities[0]
            for i in range(ro.n_obstacles):
                across = [abs(np.dot(cands[g] - cands[a], v[i])) / np.linalg.norm(cands[g] - cands[a])
                          for a, g in segments if _crosses(p[i], v[i], cands[a], cands[g], window)]
                flags.append(bool(across) and min(across) < 1e-9)
        aimed[name] = np.mean(flags)
    assert aimed["crossing"] == 1.0 and aimed["uniform"] == 0.0


@pytest.mark.parametrize("dims", [2, 3])
def test_wall_gaps_are_passable_and_walls_keep_off_the_candidates(dims):
    sc = scenario(dims=dims, structure=["walls"], count=15, maps=4,
                  obstacles={"structures": {"walls": {"walls": 3, "gaps_per_wall": 2}}})
    r = sc.drone.radius
    st = sc.obstacles.structure_of("walls")
    cands = np.asarray(sc.task.candidates)
    for ro in rollouts(sc, "walls"):
        walls = ro.static
        assert len(walls) >= 3 * 2 and all(b.kind == "box" for b in walls)
        if dims == 3:
            assert all(abs(b.size[2] - sc.world.size[2]) < 1e-9 for b in walls)
        d = np.min([b.footprint_distance(cands) for b in walls], axis=0)
        assert np.all(d >= r + sc.task.spawn_clearance - 1e-9)
        # every wall line: the gaps between its segments are wall_gap wide, and the MAV disc plus 0.5 m passes
        # through the middle of each gap, from one side of the wall to the other, without touching any static body
        lines: dict = {}
        for b in walls:
            across = int(np.argmin(b.size[:2]))
            lines.setdefault((across, round(b.center[across], 9)), []).append(b)
        assert len(lines) == 3 and len({a for a, _ in lines}) == 1         # parallel: no enclosed region
        for (across, c), segs in lines.items():
            along = 1 - across
            spans = sorted((s.center[along] - s.size[along] / 2, s.center[along] + s.size[along] / 2) for s in segs)
            gaps = [(a1, b0) for (_, a1), (b0, _) in zip(spans, spans[1:])]
            assert len(gaps) == 2 and all(abs((b0 - a1) - st.wall_gap) < 1e-9 for a1, b0 in gaps)
            for a1, b0 in gaps:
                reach = 0.5 * st.wall_thickness + r + 0.5
                for off in np.linspace(-reach, reach, 13):
                    q = np.zeros(dims)
                    q[along], q[across] = 0.5 * (a1 + b0), c + off
                    if dims == 3:
                        q[2] = 10.0
                    assert min(float(s.footprint_distance(q[None])[0]) for s in walls) >= r + 0.5 - 1e-9
        # obstacles spawn off the walls
        for b in walls:
            assert np.all(b.footprint_distance(ro.positions[0]) >= ro.radii - 1e-9)


def test_mixed_spread_and_rvo_structures():
    sc = scenario(structure=["mixed", "spread", "rvo"], count=40, maps=6)
    for ro in rollouts(sc, "mixed"):
        speed = np.linalg.norm(ro.velocities[0], axis=1)
        assert np.sum(speed == 0.0) == 20 and np.allclose(speed[speed > 0], 4.0)
        assert np.allclose(ro.positions[-1][speed == 0], ro.positions[0][speed == 0])
    r = np.concatenate([ro.radii for ro in rollouts(sc, "spread")])
    v = np.concatenate([np.linalg.norm(ro.velocities[0], axis=1) for ro in rollouts(sc, "spread")])
    assert abs(r.mean() - 1.0) < 0.08 and abs(r.std() / r.mean() - 0.5) < 0.1
    assert abs(v.mean() - 4.0) < 0.35 and abs(v.std() / v.mean() - 0.5) < 0.1
    assert all(ro.meta["motion"] == "rvo" for ro in rollouts(sc, "rvo"))


def test_structured_maps_are_reproducible_and_independent_of_the_grid():
    sc = scenario(structure=ALL, count=20, maps=1)
    one = {m.setup["structure"]: build_rollout(sc, m) for m in enumerate_maps(sc)}
    again = {m.setup["structure"]: build_rollout(sc, m) for m in enumerate_maps(sc)}
    for name in ALL:
        assert np.array_equal(one[name].positions, again[name].positions) and one[name].static == again[name].static
    # the same structure in a scenario with fewer structures: the same map, the same rollout key
    small = scenario(structure=["walls", "crossing"], count=20, maps=1)
    for m in enumerate_maps(small):
        full = next(x for x in enumerate_maps(sc) if x.setup == m.setup)
        assert rollout_key(small, m, 10.0) == rollout_key(sc, full, 10.0)
        assert np.array_equal(build_rollout(small, m).positions, one[m.setup["structure"]].positions)


def test_a_structured_batch_stores_every_trial_with_its_structure(tmp_path):
    from pbdyn.api import open_results, run_batch
    from pbdyn.sim.spec import make_trial_spec

    doc = ('[world]\ntime_limit = 20.0\n[obstacles]\ncount = 8\nradius = 1.0\nspeed = 3.0\n'
           'structure = ["walls", "crossing", "mixed"]\n[task]\ncandidates = [[4.0, 25.0], [46.0, 25.0]]\n'
           '[[planners]]\ntrajectory = "local_primitives"\ngaze = "fullrange"\n')
    path = tmp_path / "st.toml"
    path.write_text(doc)
    run_batch(str(path), tmp_path / "st.sqlite", workers=1)
    with open_results(tmp_path / "st.sqlite") as r:
        rows = r.trials()
        maps = r.maps()
    assert len(rows) == 3 * 2 * 3 and set(rows["outcome"]) <= {"success", "dynamic_collision", "static_collision",
                                                      "deadlock", "freezing"}
    assert sorted(maps["setup_structure"]) == ["crossing", "mixed", "walls"]
    share = dict(zip(maps["setup_structure"], maps["metric_static_share"]))
    assert share["walls"] > 0 and share["crossing"] == share["mixed"] == 0.0
    # the stored key is the trial's own config hash, which includes its structure's settings
    sc = parse_scenario(__import__("tomllib").loads(doc))
    m = enumerate_maps(sc)[0]
    spec = make_trial_spec(sc, m, start=(4.0, 25.0), goal=(46.0, 25.0))
    assert spec.resolved()["map"]["structure"]["walls"] == 2 and spec.config_hash in set(rows["trial_key"])
