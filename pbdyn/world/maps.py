"""Map enumeration, seeds and obstacle spawning (docs/design.md "Maps and seeds", thesis 2-3).

A map is identified by its setup values (count, radius, speed — each a number or a {min, max} range) and its
replicate number, never by a position in a list, so adding a grid value adds maps without changing existing ones.
Its seed comes from that key and the scenario's root seed. Its id (MapSpec.map_id, MAP_ID_RULE) is derived from
everything that makes the map: the key and the scenario's world digest (world_digest: root seed, arena, obstacle
settings, structures, static geometry, spawn rules, an imported world's bodies and their files' digests), so two
different maps never share an id (docs/design.md "Maps and seeds").
"""

from __future__ import annotations

import hashlib
import itertools
import math
import operator
import random
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pbdyn.config import Range, Scenario, canonical_json, map_seed, stable_hash64
from pbdyn.errors import ConfigError
from pbdyn.motion.rvo import candidate_directions
from pbdyn.world.draws import draw_values, random_unit_vectors
from pbdyn.world.geometry import StaticBody
from pbdyn.world.structure import (cluster_centres, draw_radii_speeds, proposals, structure_of,
                                   wall_bodies)

MAX_SPAWN_ATTEMPTS = 20000

MAP_ID_RULE = "content-1"
"""How map ids are made: "content-1", the first 12 hex digits of sha256(key, world_digest) (MapSpec.map_id). The rule
before, "setup-1" (MapSpec.setup_id: the key alone), gave every map of the same setup and replicate one id, whatever
its world: the nine imported worlds of pbdyn-2d-v1 share one. Frozen pbdyn-suite/1 suites name their maps by it;
a results store records the rule its rows were made with (meta "map_ids")."""

PROGRAM_PX_PER_M = 10.0
"""The thesis program's unit: 10 pixels per metre."""
PROGRAM_WALL_M = 1.0
"""The program's wall cells: its outermost 1 m, so its pixel frame starts 1 m outside pbdyn's arena (whose origin is
the walls' inner corner, scenarios/thesis)."""
PROGRAM_SPAWN_PX = 20.0
"""The program drew obstacle centres uniformly in [20, W - 20] px (1 m inside its wall cells, whatever the radius)."""
PROGRAM_METRICS_START = (4.0, 4.0)
"""Where the program's MAV stood when it computed a map's metrics (its default start, 50 px, 50 px), in pbdyn's frame:
the obstacles of a metrics map were spawned around it."""


def sequence_index(index, n: int, what: str) -> int:
    """``index`` (an int, negative counting from the end) as a position in a sequence of ``n``; IndexError naming
    ``what`` if out of range (the lazy map and trial enumerations)."""
    i = operator.index(index)
    if i < 0:
        i += n
    if not 0 <= i < n:
        raise IndexError(f"{what} index out of range")
    return i


@dataclass(frozen=True)
class MapSpec:
    """One map: its setup values, replicate, position in the enumeration and seed entropy."""

    index: int
    setup: dict
    replicate: int
    root_seed: int
    world: str = ""
    """The scenario's world_digest (enumerate_maps fills it in): part of the map's id, not of its key or seed."""

    @cached_property
    def key(self) -> str:
        """Canonical JSON of (setup values, replicate): the map's identity (computed once per MapSpec)."""
        return canonical_json({"setup": self.setup, "replicate": self.replicate})

    @cached_property
    def map_id(self) -> str:
        """The map's id (MAP_ID_RULE): the first 12 hex digits of the sha256 of its key and its scenario's world
        digest. A MapSpec made without the world digest has none (ValueError)."""
        if not self.world:
            raise ValueError("a MapSpec made without its scenario's world digest has no map id "
                             "(pbdyn.world.maps.enumerate_maps makes them with it)")
        return hashlib.sha256(canonical_json({"map": self.key, "world": self.world}).encode()).hexdigest()[:12]

    @cached_property
    def setup_id(self) -> str:
        """The map's id by the rule before (MAP_ID_RULE "setup-1"; the ids of pbdyn-suite/1 suites): the first 12
        hex digits of the key's sha256 (legacy_map_id)."""
        return legacy_map_id(self.key)

    def seed_sequence(self) -> np.random.SeedSequence:
        """SeedSequence([root_seed, stable hash of the key])."""
        return np.random.SeedSequence([self.root_seed, stable_hash64(self.key)])

    @cached_property
    def seed(self) -> int:
        """A 63-bit integer summarising the map's seed (for the record; pbdyn.config.map_seed)."""
        return map_seed(self.root_seed, self.key)

    def rng(self) -> np.random.Generator:
        """The map's Generator."""
        return np.random.default_rng(self.seed_sequence())


def legacy_map_id(key: str) -> str:
    """A map's id by the "setup-1" rule from its key (MapSpec.key, a row's map_key): sha256(key)[:12]."""
    return hashlib.sha256(key.encode()).hexdigest()[:12]


def world_digest(scenario: Scenario, setup: dict | None = None) -> str:
    """sha256 (16 hex digits) of what makes a scenario's maps besides each map's setup and replicate: the root seed,
    the arena (dims, size, dt, flight height), the obstacles' settings outside the grid (jitter, motion model and its
    table, headings, layout, ...), static obstacles, the spawn rules (start/goal candidates, MAV radius, clearances),
    an imported world's bodies with the digests of their URDF, mesh and motion-module files
    (pbdyn.world.imported.bodies.bodies_fingerprint), and, given a map's ``setup``, the definition of the structure
    it names. Not the time limit, planners, sensor or MAV limits: those change the trials on a map, not the map."""
    from dataclasses import asdict

    from pbdyn.motion.registry import other_tables

    st = structure_of(scenario, setup) if setup is not None else None
    if st is not None:
        return hashlib.sha256(canonical_json({"world": world_digest(scenario), "structure": asdict(st)})
                              .encode()).hexdigest()[:16]
    sc = scenario.to_dict()
    motion = sc["obstacles"]["motion"]
    skip = {"count", "radius", "speed", "structure", "structures", "maps_per_setup", "maps",   # per map: its key
            "grid_order"}                                                                     # and its structure
    skip |= other_tables(motion)
    payload = {
        "world": {k: sc["world"][k] for k in ("dims", "size", "dt", "flight_height")},
        "obstacles": {k: v for k, v in sc["obstacles"].items() if k not in skip and v not in (None, [], {})},
        "static": sc["static_obstacles"],
        "spawn": {"candidates": sc["task"]["candidates"], "mav_radius": sc["drone"]["radius"],
                  "clearance": sc["task"]["spawn_clearance"], "start_clearance": sc["task"]["start_clearance"]},
    }
    if scenario.is_world:
        from pbdyn.world.imported.bodies import bodies_fingerprint

        payload["bodies"] = bodies_fingerprint(scenario)
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()[:16]


class MapSequence(Sequence):
    """Every map of a scenario, lazily: setups in file order (first grid field slowest), replicates fastest; or the
    maps of an explicit list (obstacles.maps), in file order.

    ``len``, indexing (index arithmetic: no other map is built), slices (lists) and iteration; the same MapSpecs,
    in the same order, as building the whole list."""

    def __init__(self, scenario: Scenario):
        self._grids = [(k, tuple(getattr(scenario.obstacles, k))) for k in scenario.obstacles.grid_order]
        self._reps = int(scenario.obstacles.maps_per_setup)
        self._root_seed = scenario.obstacles.root_seed
        self._n_setups = math.prod(len(v) for _, v in self._grids)
        self._listed = tuple(scenario.obstacles.maps)     # an explicit map list replaces the grid
        self._scenario = scenario
        self._worlds: dict = {}

    def world(self, setup: dict) -> str:
        """world_digest of a map of this setup (computed once per structure name)."""
        name = setup.get("structure")
        got = self._worlds.get(name)
        if got is None:
            got = self._worlds[name] = world_digest(self._scenario, setup)
        return got

    def __len__(self) -> int:
        return len(self._listed) if self._listed else self._n_setups * self._reps

    @staticmethod
    def _setup(keys, combo) -> dict:
        return {k: v.to_json() if isinstance(v, Range) else v for k, v in zip(keys, combo)}

    def setup(self, s: int) -> dict:
        """The setup values of setup number ``s`` (mixed radix, first grid field slowest)."""
        combo = []
        for _, values in reversed(self._grids):
            s, d = divmod(s, len(values))
            combo.append(values[d])
        return self._setup([k for k, _ in self._grids], reversed(combo))

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = sequence_index(index, len(self), "map")
        if self._listed:
            m = self._listed[i]
            setup = m.setup()
            return MapSpec(i, setup, m.replicate, self._root_seed, self.world(setup))
        s, rep = divmod(i, self._reps)
        setup = self.setup(s)
        return MapSpec(i, setup, rep, self._root_seed, self.world(setup))

    def __iter__(self) -> Iterator[MapSpec]:
        if self._listed:
            yield from (self[i] for i in range(len(self._listed)))
            return
        keys = [k for k, _ in self._grids]
        i = 0
        for combo in itertools.product(*(v for _, v in self._grids)):
            setup = self._setup(keys, combo)
            world = self.world(setup)
            for rep in range(self._reps):
                yield MapSpec(i, setup, rep, self._root_seed, world)
                i += 1


def enumerate_maps(scenario: Scenario) -> MapSequence:
    """All maps, lazily (a Sequence: len, index, slice, iterate): setups in file order (first grid field slowest),
    replicates fastest."""
    return MapSequence(scenario)


def get_map(scenario: Scenario, index: int) -> MapSpec:
    """The map with enumeration index ``index`` (built alone, by index arithmetic); ConfigError if out of range."""
    maps = MapSequence(scenario)
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(maps):
        raise ConfigError("map", f"must be an index in [0, {len(maps) - 1}]", index)
    return maps[index]


def static_bodies(scenario: Scenario, spec: MapSpec | None = None) -> tuple[StaticBody, ...]:
    """The scenario's static obstacles as geometry, plus (given the map ``spec``) its structure's walls
    (pbdyn.world.structure)."""
    out = tuple(StaticBody(s.kind, tuple(s.center), s.radius, tuple(s.size), float(np.deg2rad(s.yaw_deg)))
                for s in scenario.static_obstacles)
    st = structure_of(scenario, spec.setup) if spec is not None else None
    if st is not None and st.walls:
        out += wall_bodies(scenario, spec, st)
    return out


def _admissible(pts: np.ndarray, ok: np.ndarray, placed: np.ndarray, placed_r: np.ndarray, r: float,
                cands: np.ndarray, gap: float, centre_rule: bool, bodies) -> np.ndarray:
    """``ok`` [P] narrowed to the proposed centres pts [P, d] of an obstacle of radius r that overlap no placed
    obstacle (centres [i, d], radii [i]), keep clear of the candidates (centre_rule: centres more than ``gap``
    away; else discs ``gap`` clear) and of the static bodies."""
    if placed.shape[0]:
        dist = np.linalg.norm(pts[:, None, :] - placed[None, :, :], axis=-1)
        ok &= np.all(dist >= placed_r[None, :] + r, axis=1)
    if cands.size:
        dist = np.linalg.norm(pts[:, None, :] - cands[None, :, :], axis=-1)
        ok &= np.all(dist > gap, axis=1) if centre_rule else np.all(dist >= r + gap, axis=1)
    for b in bodies:
        ok &= b.footprint_distance(pts) >= r
    return ok


def spawn_obstacles(scenario: Scenario, spec: MapSpec,
                    keep_out: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Initial centres [N, d] (m), velocities [N, d] (m/s) and radii [N] (m) of a map's obstacles.

    Radii: setup radius +- radius_jitter (uniform) or drawn from a range; speeds: exactly the setup speed or drawn
    from a range; headings uniform (obstacles.headings = "even": the program's evenly spaced ones); centres uniform
    inside the walls, rejection-sampled so that no obstacle overlaps
    another, a static body, or any start/goal candidate's MAV disc plus the spawn clearance (thesis 2-3; unlike the
    thesis' program, the layout never depends on which start is flown). ``keep_out`` = (points [m, d], gap m)
    replaces the candidates and spawn_clearance: obstacle CENTRES stay more than the MAV radius + ``gap`` m from
    each point, whatever the obstacle's radius (the "program" start rule, pbdyn.sim.start: the program rejected a
    centre within drone radius + 7 m = 8 m of the start). Radii, speeds and headings are drawn before the centres,
    so they do not depend on keep_out.
    """
    st = structure_of(scenario, spec.setup)
    if st is not None:
        return _spawn_structured(scenario, spec, st, keep_out)
    if scenario.obstacles.layout == "program":
        return spawn_program(scenario, spec, keep_out)
    rng = spec.rng()
    dims = scenario.world.dims
    size = np.asarray(scenario.world.size, dtype=float)
    n = int(spec.setup["count"])
    radii = draw_values(spec.setup["radius"], rng, n, scenario.obstacles.radius_jitter)
    speeds = draw_values(spec.setup["speed"], rng, n, 0.0)
    dirs = random_unit_vectors(rng, n, dims)     # drawn in both modes: the centres below stay the same
    if scenario.obstacles.headings == "even":     # the thesis program's headings (ObstacleConfig)
        dirs = -candidate_directions(dims, n)
    velocities = dirs * speeds[:, None]
    if keep_out is None:
        cands = np.asarray(scenario.task.candidates, dtype=float).reshape(-1, dims)
        keep_out = scenario.drone.radius + scenario.task.spawn_clearance
        centre_rule = False   # the obstacle's disc stays clear
    else:
        cands = np.asarray(keep_out[0], dtype=float).reshape(-1, dims)
        keep_out = scenario.drone.radius + float(keep_out[1])
        centre_rule = True    # the obstacle's centre stays clear (the program's rule)
    bodies = static_bodies(scenario)
    centres = np.zeros((n, dims))
    for i in range(n):
        r = radii[i]
        lo, hi = np.full(dims, r), size - r
        # draw in batches and take the first admissible point: same result as one-by-one rejection, far fewer calls
        placed = False
        for _ in range(MAX_SPAWN_ATTEMPTS // 64):
            pts = rng.uniform(lo, hi, size=(64, dims))
            ok = _admissible(pts, np.ones(64, dtype=bool), centres[:i], radii[:i], r, cands, keep_out, centre_rule,
                             bodies)
            hit = np.flatnonzero(ok)
            if hit.size:
                centres[i] = pts[hit[0]]
                placed = True
                break
        if not placed:
            raise ConfigError("obstacles.count",
                              f"cannot place {n} obstacles (radius ~{float(np.mean(radii)):.2f} m) without overlap "
                              f"(map {spec.index}, obstacle {i})", n)
    return centres, velocities, radii


def program_stream(seed: int) -> np.random.Generator:
    """A numpy Generator whose random() yields the numbers of the thesis program's ``random.seed(seed)`` stream:
    an MT19937 bit generator given the state Python's Mersenne Twister derives from ``seed`` (the program seeded
    Python's ``random`` with its map id and drew its obstacles from it)."""
    state = random.Random(int(seed)).getstate()[1]
    bits = np.random.MT19937()
    bits.state = {"bit_generator": "MT19937",
                  "state": {"key": np.asarray(state[:624], dtype=np.uint32), "pos": int(state[624])}}
    return np.random.Generator(bits)


def spawn_program(scenario: Scenario, spec: MapSpec,
                  keep_out: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The thesis program's obstacles (obstacles.layout = "program"; docs/thesis-program.md "World and obstacles"):
    centres [N, 2] (m), velocities [N, 2] (m/s) and radii [N] (m), drawn as its environment drew them.

    Its stream is Python's ``random`` seeded with the map id (here root_seed + the replicate number), the same for
    every setup, so maps of one replicate share their draws across setups. Per attempt, in its pixel frame (10 px per
    m, the origin 1 m outside pbdyn's, pbdyn.world.maps.PROGRAM_WALL_M), x = 20 + (W - 40) u, y likewise, then the
    radius r_px - j_px + 2 j_px u (a fixed radius r with radius_jitter j; a range: min + (max - min) u); the attempt
    is rejected when its centre is within the sum of the radii of an accepted obstacle's centre or within the MAV
    radius + gap of the start's (``keep_out`` = (start [1, 2], gap m); without one -- a metrics map -- the
    program's metrics start PROGRAM_METRICS_START with the task's start_clearance). Obstacle k of N heads along
    -(cos 2 pi k / N, sin 2 pi k / N) at exactly the setup speed. Distances are compared in pixels, as the program
    did, and the centres converted to metres at the end.
    """
    size = np.asarray(scenario.world.size, dtype=float)
    n = int(spec.setup["count"])
    radius = spec.setup["radius"]
    if isinstance(radius, dict):
        r_lo, r_hi = PROGRAM_PX_PER_M * radius["min"], PROGRAM_PX_PER_M * radius["max"]
    else:
        jitter = PROGRAM_PX_PER_M * scenario.obstacles.radius_jitter
        r_lo, r_hi = PROGRAM_PX_PER_M * radius - jitter, PROGRAM_PX_PER_M * radius + jitter
    width_px = PROGRAM_PX_PER_M * (size + 2.0 * PROGRAM_WALL_M)
    lo_px, span_px = PROGRAM_SPAWN_PX, width_px - 2.0 * PROGRAM_SPAWN_PX
    if keep_out is None:
        start, gap = np.asarray([PROGRAM_METRICS_START], dtype=float), scenario.task.start_clearance
    else:
        start, gap = np.asarray(keep_out[0], dtype=float).reshape(-1, 2), float(keep_out[1])
    start_px = PROGRAM_PX_PER_M * (start + PROGRAM_WALL_M)
    keep_px = PROGRAM_PX_PER_M * (scenario.drone.radius + gap)
    stream = program_stream(spec.root_seed + spec.replicate)
    centres_px, radii_px = np.zeros((n, 2)), np.zeros(n)
    placed, attempts = 0, 0
    while placed < n:
        draws = stream.random((64, 3))
        pts = lo_px + span_px[None, :] * draws[:, :2]
        rads = r_lo + (r_hi - r_lo) * draws[:, 2]
        for p, r in zip(pts, rads):
            attempts += 1
            if attempts > MAX_SPAWN_ATTEMPTS:
                raise ConfigError("obstacles.count", f"cannot place {n} obstacles as the program did (map "
                                  f"{spec.index}, obstacle {placed}, {MAX_SPAWN_ATTEMPTS} attempts)", n)
            if np.any(np.linalg.norm(centres_px[:placed] - p, axis=1) <= radii_px[:placed] + r):
                continue
            if np.any(np.linalg.norm(start_px - p, axis=1) <= keep_px):
                continue
            centres_px[placed], radii_px[placed] = p, r
            placed += 1
            if placed == n:
                break
    speed = float(spec.setup["speed"])
    velocities = -candidate_directions(2, n) * speed
    return centres_px / PROGRAM_PX_PER_M - PROGRAM_WALL_M, velocities, radii_px / PROGRAM_PX_PER_M


def _spawn_structured(scenario: Scenario, spec: MapSpec, st, keep_out) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """spawn_obstacles for a map with a structure (pbdyn.world.structure): radii and speeds (spreads, static
    share), headings, then centres from the structure's proposals, rejection-sampled by the same rules (inside
    the walls, no overlap, clear of the candidates or ``keep_out``, off the static bodies and walls)."""
    rng = spec.rng()
    dims = scenario.world.dims
    size = np.asarray(scenario.world.size, dtype=float)
    n = int(spec.setup["count"])
    radii, speeds = draw_radii_speeds(scenario, spec, st, rng, n)
    dirs = random_unit_vectors(rng, n, dims)
    if (st.headings or scenario.obstacles.headings) == "even":
        dirs = -candidate_directions(dims, n)
    clusters = cluster_centres(scenario, st, rng) if st.layout == "clustered" else None
    if keep_out is None:
        cands = np.asarray(scenario.task.candidates, dtype=float).reshape(-1, dims)
        gap, centre_rule = scenario.drone.radius + scenario.task.spawn_clearance, False
    else:
        cands = np.asarray(keep_out[0], dtype=float).reshape(-1, dims)
        gap, centre_rule = scenario.drone.radius + float(keep_out[1]), True
    bodies = static_bodies(scenario, spec)
    centres = np.zeros((n, dims))
    for i in range(n):
        r = radii[i]
        placed = False
        for _ in range(MAX_SPAWN_ATTEMPTS // 64):
            pts, heads = proposals(scenario, st, rng, i, r, speeds[i], clusters, 64)
            ok = _admissible(pts, np.all((pts >= r) & (pts <= size - r), axis=1), centres[:i], radii[:i], r, cands,
                             gap, centre_rule, bodies)
            hit = np.flatnonzero(ok)
            if hit.size:
                centres[i] = pts[hit[0]]
                if heads is not None:
                    dirs[i] = heads[hit[0]]
                placed = True
                break
        if not placed:
            raise ConfigError("obstacles.count", f"cannot place {n} obstacles of structure {st.name!r} without "
                              f"overlap (map {spec.index}, obstacle {i})", n)
    return centres, dirs * speeds[:, None], radii
