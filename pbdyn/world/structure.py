"""Maps whose structure varies at fixed (n, r, v): clustered positions, flows aimed across the start/goal lines,
walls with gaps, static shares, size and speed distributions (pbdyn.config.StructureConfig; docs/scenarios.md
"Structured worlds").

Everything is drawn from the map's own Generator (pbdyn.world.maps.MapSpec.rng) in a fixed order, except the walls,
which come from a second stream of the map's seed (SeedSequence([root_seed, key hash, WALL_STREAM])) so that they
never depend on the obstacles. Maps without a structure never reach this module.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.config import Scenario, StructureConfig, stable_hash64
from pbdyn.errors import ConfigError
from pbdyn.world.draws import draw_values, gamma_values
from pbdyn.world.geometry import StaticBody

WALL_STREAM = 1
"""Entropy tag of the walls' Generator."""

MIN_GAMMA_FRACTION = 0.05
"""Gamma-distributed radii are floored at this fraction of their mean (a radius must stay > 0)."""


def structure_of(scenario: Scenario, setup: dict) -> StructureConfig | None:
    """The StructureConfig of a map's setup (None for maps without one)."""
    name = setup.get("structure")
    return None if name is None else scenario.obstacles.structure_of(name)


def wall_rng(spec) -> np.random.Generator:
    """The walls' Generator: SeedSequence([root_seed, key hash, WALL_STREAM])."""
    return np.random.default_rng(np.random.SeedSequence([spec.root_seed, stable_hash64(spec.key), WALL_STREAM]))


def _free_intervals(lo: float, hi: float, blocked: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out = []
    cur = lo
    for a, b in sorted(blocked):
        if a > cur:
            out.append((cur, min(a, hi)))
        cur = max(cur, b)
    if cur < hi:
        out.append((cur, hi))
    return [(a, b) for a, b in out if b > a]


def wall_bodies(scenario: Scenario, spec, st: StructureConfig) -> tuple[StaticBody, ...]:
    """The structure's walls as box StaticBodies: parallel lines across the whole arena (all along x or all along
    y, drawn once per map, so that every strip between two walls is reached through their gaps; 3D: full height),
    each at a coordinate clear of every start/goal candidate's MAV disc plus the spawn clearance and at least
    twice that clearance from the other walls, split by ``gaps_per_wall`` gaps of ``wall_gap`` m (their centres at
    least MAV radius + 1 m inside the ends of the wall, not overlapping). ConfigError when a wall cannot be
    placed."""
    if st.walls == 0:
        return ()
    rng = wall_rng(spec)
    dims = scenario.world.dims
    size = np.asarray(scenario.world.size, dtype=float)
    cands = np.asarray(scenario.task.candidates, dtype=float).reshape(-1, dims)
    half_t = 0.5 * st.wall_thickness
    keep = scenario.drone.radius + scenario.task.spawn_clearance + half_t
    placed: list[float] = []
    out = []
    along = int(rng.integers(0, 2))                   # every wall of the map runs along this axis
    across = 1 - along
    for w in range(st.walls):
        blocked = [(c - keep, c + keep) for c in cands[:, across]]
        blocked += [(c - 2.0 * keep, c + 2.0 * keep) for c in placed]
        free = _free_intervals(keep, size[across] - keep, blocked)
        total = sum(b - a for a, b in free)
        if total <= 0:
            raise ConfigError("obstacles.structures.walls", f"no room for wall {w + 1} of {st.walls} clear of the "
                              "start/goal candidates and the other walls", st.walls)
        u = rng.uniform(0.0, total)
        for a, b in free:
            if u <= b - a:
                c = a + u
                break
            u -= b - a
        placed.append(c)
        length = size[along]
        end = scenario.drone.radius + 1.0 + 0.5 * st.wall_gap
        gaps = []
        for _ in range(1000):
            if len(gaps) == st.gaps_per_wall:
                break
            g = rng.uniform(end, length - end)
            if all(abs(g - h) >= st.wall_gap + st.wall_thickness for h in gaps):
                gaps.append(g)
        if len(gaps) < st.gaps_per_wall:
            raise ConfigError("obstacles.structures.gaps_per_wall", f"{st.gaps_per_wall} gaps of "
                              f"{st.wall_gap:g} m do not fit in a {length:g} m wall", st.gaps_per_wall)
        edges = [0.0] + [x for g in sorted(gaps) for x in (g - 0.5 * st.wall_gap, g + 0.5 * st.wall_gap)] + [length]
        for a, b in zip(edges[0::2], edges[1::2]):
            if b - a <= 1e-9:
                continue
            centre = np.zeros(dims)
            extent = np.zeros(dims)
            centre[along], extent[along] = 0.5 * (a + b), b - a
            centre[across], extent[across] = c, st.wall_thickness
            if dims == 3:
                centre[2], extent[2] = 0.5 * size[2], size[2]
            out.append(StaticBody("box", tuple(float(x) for x in centre), 0.0, tuple(float(x) for x in extent)))
    return tuple(out)


def draw_radii_speeds(scenario: Scenario, spec, st: StructureConfig, rng, n: int) -> tuple:
    """(radii [n], speeds [n]) of a structured map: gamma spreads where set, else the scenario's rule
    (pbdyn.world.draws.draw_values); then round(static_fraction n) obstacles, chosen at random, stop."""
    if st.radius_spread > 0:
        r = spec.setup["radius"]
        mean = 0.5 * (r["min"] + r["max"]) if isinstance(r, dict) else float(r)
        radii = gamma_values(rng, mean, st.radius_spread, n, MIN_GAMMA_FRACTION * mean)
    else:
        radii = draw_values(spec.setup["radius"], rng, n, scenario.obstacles.radius_jitter)
    if st.speed_spread > 0:
        v = spec.setup["speed"]
        mean = 0.5 * (v["min"] + v["max"]) if isinstance(v, dict) else float(v)
        speeds = gamma_values(rng, mean, st.speed_spread, n)
    else:
        speeds = draw_values(spec.setup["speed"], rng, n, 0.0)
    k = int(round(st.static_fraction * n))
    if k:
        speeds = speeds.copy()
        speeds[rng.permutation(n)[:k]] = 0.0
    return radii, speeds


def cluster_centres(scenario: Scenario, st: StructureConfig, rng) -> np.ndarray:
    """The clusters' centres [clusters, d], uniform in the arena shrunk by one cluster_spread."""
    size = np.asarray(scenario.world.size, dtype=float)
    m = np.minimum(st.cluster_spread, 0.25 * size)
    return rng.uniform(m, size - m, size=(st.clusters, size.shape[0]))


def perpendicular(rng, seg: np.ndarray) -> np.ndarray:
    """A unit vector across the segment direction ``seg`` [d]: 2D +-its normal, 3D uniform on the circle across."""
    u = seg / np.linalg.norm(seg)
    if u.shape[0] == 2:
        return np.array([-u[1], u[0]]) * (1.0 if rng.random() < 0.5 else -1.0)
    a = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    th = rng.uniform(0.0, 2.0 * math.pi)
    return math.cos(th) * e1 + math.sin(th) * e2


def proposals(scenario: Scenario, st: StructureConfig, rng, i: int, r: float, speed: float, clusters,
              batch: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``batch`` candidate centres [batch, d] for obstacle i (and, for a crossing flow, their headings [batch, d];
    else None). Uniform, clustered (around cluster i mod K) or crossing (module doc of StructureConfig)."""
    size = np.asarray(scenario.world.size, dtype=float)
    dims = size.shape[0]
    lo, hi = np.full(dims, r), size - r
    headings = st.headings if st.headings is not None else scenario.obstacles.headings
    if headings == "crossing" and speed > 0:
        pairs = scenario.task.pairs()
        cands = np.asarray(scenario.task.candidates, dtype=float).reshape(-1, dims)
        pts = np.empty((batch, dims))
        dirs = np.empty((batch, dims))
        for b in range(batch):
            a, g = pairs[int(rng.integers(0, len(pairs)))]
            seg = cands[g] - cands[a]
            q = cands[a] + rng.uniform(0.0, 1.0) * seg
            d = perpendicular(rng, seg)
            tau = rng.uniform(0.0, st.crossing_window_s)
            pts[b], dirs[b] = q - d * speed * tau, d
        return pts, dirs
    if st.layout == "clustered":
        c = clusters[i % clusters.shape[0]]
        return c[None, :] + rng.normal(0.0, st.cluster_spread, size=(batch, dims)), None
    return rng.uniform(lo, hi, size=(batch, dims)), None
