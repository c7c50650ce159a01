"""The scenario model: frozen dataclasses of a validated scenario, their defaults and vocabularies, and the values
derived from them: map seeds, canonical JSON, time spans (docs/design.md "Defaults", docs/scenarios.md "Scenario
reference").

Every omitted field takes its default, written once: as the dataclass field's default (a ClassVar for a default
that depends on world.dims or has no field); the parser (pbdyn.config.parser) reads it from there (``_defaults``).
It imports nothing of the package: the parser and compat build on it.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, Mapping

from pbdyn import limits, resources
from pbdyn.errors import ConfigError
from pbdyn.motion.rvo import RVOParams


BODY_MOTIONS = ("static", "constant_velocity", "waypoints")
"""Built-in motions of an imported body; any other value must be "package.module:function"."""
COLLISION_CHECKS = ("swept", "sampled")
PROFILES = ("physical", "thesis_program")
"""Profiles (docs/design.md "Profiles"): "physical" enforces the MAV's limits on every plan; "thesis_program" reproduces
the thesis' program (docs/profiles.md "Profiles")."""
START_RULES = ("first_clear", "immediate", "program")
"""When and where a trial starts (TaskConfig.start_rule; pbdyn.sim.start)."""

PROFILE_DEFAULTS: dict[str, dict[tuple[str, str], Any]] = {
    "physical": {},
    "thesis_program": {
        ("task", "start_rule"): "program",
        ("task", "start_clearance"): 7.0,
        ("sensor", "model"): "marching",
        ("sensor", "rays"): 50,
        ("", "collision_check"): "sampled",
        ("drone", "yaw_rate_limit"): 1.3962634015954636,
        ("sensor", "obstacles_at"): "next",
        ("sensor", "march_rule"): "program",
        ("tracking", "drop_rule"): "program",
        ("task", "start_yaw_deg"): 90.0,
        ("obstacles", "headings"): "even",
        ("tracking", "track_radius"): "setup",
    },
}
"""Per profile, the defaults that replace the dataclass defaults for omitted fields ((section, key) -> value);
docs/profiles.md "Profiles" lists them (tests/test_config_defaults.py). thesis_program: the program spawned its obstacles
outside an 8 m circle around the flown start (7 m beyond the 1 m MAV disc) and limited the yaw rate to 80 deg/s
(the thesis text: 1.4 rad/s); it moved the obstacles to t_k+1 before the MAV sensed at t_k
(sensor.obstacles_at = "next"), dropped a track whose predicted disc of the setup radius reached a wall and restarted
it one step later with the setup radius (tracking.drop_rule = "program"), and started the MAV facing +y (its initial
yaw of -90 deg in its y-down screen frame; task.start_yaw_deg = 90); its obstacle headings were evenly spaced
(obstacles.headings = "even"); when it flew the thesis' trials (its code of May 2023) its planners checked every track
with the setup radius, not the obstacle's own (tracking.track_radius = "setup")."""


@dataclass(frozen=True)
class Range:
    """A closed interval [min, max]; values are drawn uniformly per obstacle."""

    min: float
    max: float

    def to_json(self) -> dict:
        return {"min": self.min, "max": self.max}


GridValue = float | int | Range


@dataclass(frozen=True)
class WorldConfig:
    """World: dims (2|3), size (m per axis), dt (s), time_limit (s), grid_resolution (m), flight_height (m, 2D only)."""

    SIZE_3D: ClassVar[tuple[float, ...]] = (50.0, 50.0, 20.0)
    """Default size with dims = 3 (the field's default is the 2D one)."""

    dims: int = 2
    size: tuple[float, ...] = (50.0, 50.0)
    dt: float = 0.1
    time_limit: float = 80.0
    grid_resolution: float = 1.0
    flight_height: float = 2.0

    @property
    def n_steps(self) -> int:
        """Number of steps in the time limit."""
        return int(round(self.time_limit / self.dt))


@dataclass(frozen=True)
class StructureConfig:
    """How a map is built at fixed (n, r, v) (pbdyn.world.structure; docs/scenarios.md "Structured worlds").

    layout: "uniform" (centres uniform) or "clustered" (centres drawn around ``clusters`` centres uniform in the
    arena, Gaussian with sd ``cluster_spread`` m per axis). headings: None (the scenario's obstacles.headings),
    "uniform", "even" or "crossing" (each moving obstacle is aimed across a start/goal segment: a segment of the
    candidate pairs and a point on it drawn uniformly, a direction across it, and the obstacle placed so that it
    reaches the point after a time uniform in [0, crossing_window_s]). static_fraction: the share of the obstacles
    that do not move (round(static_fraction n) of them, chosen at random); the others keep the setup speed.
    radius_spread, speed_spread: coefficients of variation of mean-preserving gamma distributions of the radii and
    speeds (0: the setup's values and obstacles.radius_jitter). walls: static walls across the arena (boxes
    ``wall_thickness`` m thick, full height in 3D), each split by ``gaps_per_wall`` gaps ``wall_gap`` m wide, placed
    clear of the start/goal candidates. motion: None (the scenario's) or a motion model's name
    (pbdyn.motion.registry.MODELS)."""

    LAYOUTS: ClassVar[tuple[str, ...]] = ("uniform", "clustered")
    HEADINGS: ClassVar[tuple[str, ...]] = ("uniform", "even", "crossing")

    name: str
    layout: str = "uniform"
    clusters: int = 3
    cluster_spread: float = 4.0
    headings: str | None = None
    crossing_window_s: float = 12.0
    static_fraction: float = 0.0
    radius_spread: float = 0.0
    speed_spread: float = 0.0
    walls: int = 0
    wall_gap: float = 4.0
    wall_thickness: float = 0.5
    gaps_per_wall: int = 1
    motion: str | None = None


BUILTIN_STRUCTURES: dict[str, dict] = {
    "uniform": {},
    "clustered": {"layout": "clustered"},
    "crossing": {"headings": "crossing"},
    "walls": {"walls": 2},
    "mixed": {"static_fraction": 0.5},
    "spread": {"radius_spread": 0.5, "speed_spread": 0.5},
    "rvo": {"motion": "rvo"},
}
"""Named structures usable in obstacles.structure without a table of their own (docs/scenarios.md "Structured worlds")."""


@dataclass(frozen=True)
class MapEntry:
    """One map of an explicit map list (``[[obstacles.maps]]``, e.g. written by `pbdyn generate`): its setup values
    (count, radius m, speed m/s, structure or None) and replicate, which with obstacles.root_seed make its seed
    exactly as a grid map's (pbdyn.world.maps.MapSpec); ``seed``: the seed recorded with it (checked at load, so a
    file whose maps would change is refused), ``measured``: values measured when the map was chosen (kept, not
    used)."""

    count: int
    radius: "GridValue"
    speed: "GridValue"
    structure: str | None = None
    replicate: int = 0
    seed: int | None = None
    measured: dict = field(default_factory=dict)

    def setup(self) -> dict:
        """The setup values, as a grid map's setup (structure only when given)."""
        out = {"count": self.count, "radius": _json_default(self.radius) if isinstance(self.radius, Range)
               else self.radius, "speed": _json_default(self.speed) if isinstance(self.speed, Range) else self.speed}
        if self.structure is not None:
            out["structure"] = self.structure
        return out


@dataclass(frozen=True)
class ObstacleConfig:
    """Generated dynamic obstacles. count/radius/speed are grids (tuples); radius/speed entries may be Ranges.
    headings: "uniform" (each obstacle's direction uniformly random) or "even" (the thesis program's: obstacle k of
    N heads along -(cos 2 pi k / N, sin 2 pi k / N); 3D: the negated Fibonacci lattice of N directions).
    layout: "pbdyn" (pbdyn.world.maps.spawn_obstacles) or "program" (the thesis program's own maps: its random stream
    seeded by root_seed + replicate, its draws and rejections; pbdyn.world.maps.spawn_program; 2D, even headings,
    exact speeds, no structures). motion: a motion model's name (pbdyn.motion.registry.MODELS); rvo: the "rvo"
    model's table (pbdyn.motion.rvo.RVOParams). wall_turn (CVM): "specular" (closed-form reflection) or "program" (an
    obstacle whose next centre would cross r from a wall turns away in that step; pbdyn.motion.cvm.cvm_program_turn)."""

    HEADINGS: ClassVar[tuple[str, ...]] = ("uniform", "even")
    LAYOUTS: ClassVar[tuple[str, ...]] = ("pbdyn", "program")
    WALL_TURNS: ClassVar[tuple[str, ...]] = ("specular", "program")

    count: tuple[int, ...] = (10,)
    radius: tuple[GridValue, ...] = (1.0,)
    speed: tuple[GridValue, ...] = (2.0,)
    radius_jitter: float = 0.0
    motion: str = "cvm"
    maps_per_setup: int = 1
    root_seed: int = 0
    grid_order: tuple[str, ...] = ("count", "radius", "speed")
    rvo: RVOParams = RVOParams()
    headings: str = "uniform"
    structure: tuple[str, ...] = ()
    structures: tuple[StructureConfig, ...] = ()
    layout: str = "pbdyn"
    wall_turn: str = "specular"
    maps: tuple[MapEntry, ...] = ()

    def structure_of(self, name: str | None) -> StructureConfig | None:
        """The StructureConfig called ``name`` (None for None)."""
        if name is None:
            return None
        return next(s for s in self.structures if s.name == name)


@dataclass(frozen=True)
class StaticObstacleConfig:
    """A static obstacle: kind pillar|box, center [d] (m), radius (pillar, m), size [d] (box full extents, m), yaw_deg."""

    KINDS: ClassVar[tuple[str, ...]] = ("pillar", "box")
    DEFAULT_KIND: ClassVar[str] = "pillar"

    kind: str
    center: tuple[float, ...]
    radius: float = 0.0
    size: tuple[float, ...] = ()
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class BodyConfig:
    """One body of an imported world (``[[bodies]]``; docs/scenarios.md "Imported worlds").

    name: label (default "body<i>"). urdf: the URDF file as written (relative: the world file's folder, then the
    bundled urdf/). scale: (sx, sy, sz) applied to its geometry. position: the base's initial position (m; 3 values,
    2D worlds default z to the flight height). rpy_deg: the base's fixed roll, pitch, yaw (deg). motion: "static",
    "constant_velocity" (``velocity`` [d] m/s; the bounding sphere reflects at the walls), "waypoints" (the base
    loops through ``waypoints`` [[d] m, ...] back to the first at ``speed`` m/s, one value or one per leg), or
    "package.module:function" called as f(t, **params) -> position [3] or (position [3], quaternion xyzw [4]).
    Joints stay at their zero position.
    """

    DEFAULT_NAME: ClassVar[str] = "body{index}"

    name: str
    urdf: str
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    position: tuple[float, ...] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    motion: str = "static"
    velocity: tuple[float, ...] = ()
    waypoints: tuple[tuple[float, ...], ...] = ()
    speed: tuple[float, ...] = ()
    params: Mapping[str, Any] = field(default_factory=dict)

    @property
    def moving(self) -> bool:
        """True unless the body is static."""
        return self.motion != "static"


@dataclass(frozen=True)
class DroneConfig:
    """The MAV: urdf path, radius (m), a_max (m/s^2), v_max grid (m/s), yaw_rate_limit (rad/s)."""

    urdf: str = "quadrotor.urdf"
    radius: float = 1.0
    a_max: float = 4.0
    v_max: tuple[float, ...] = (2.0, 4.0, 6.0)
    yaw_rate_limit: float = 1.4


@dataclass(frozen=True)
class SensorConfig:
    """Depth sensor: horizontal fov_deg, vertical vfov_deg (3D only), range (m), ray resolution_deg (both axes),
    Gaussian position noise_std (m). 3D defaults: RESOLUTION_3D_DEG, VFOV_3D_DEG (vfov_deg is None in 2D).
    model: "raycast" (PyBullet rays, exact hits) or "marching" (the thesis program's sensor: points every
    march_step m along each ray, the first one inside a body is the hit; pbdyn.perception.perceive); rays: with
    "marching", rays per horizontal fan (None: from resolution_deg; the program used 50). obstacles_at: which
    obstacle poses the scan at t_k sees, "current" (t_k, docs/design.md step order) or "next" (t_k+1: the thesis
    program moved its obstacles before sensing, so its MAV at t_k saw them one step ahead). march_rule
    ("marching" only): "ray" (points march_step apart along each ray, a fan symmetric about the yaw) or
    "program" (the program's stepping along each ray's dominant axis,
    pbdyn.perception.marching.program_march_distances, and in 2D its fan from -fov/2 in fov/rays steps)."""

    RESOLUTION_3D_DEG: ClassVar[float] = 2.0
    VFOV_3D_DEG: ClassVar[float] = 60.0
    MODELS: ClassVar[tuple[str, ...]] = ("raycast", "marching")
    OBSTACLES_AT: ClassVar[tuple[str, ...]] = ("current", "next")
    MARCH_RULES: ClassVar[tuple[str, ...]] = ("ray", "program")

    fov_deg: float = 90.0
    range: float = 8.0
    resolution_deg: float = 1.0
    noise_std: float = 0.0
    vfov_deg: float | None = None
    model: str = "raycast"
    rays: int | None = None
    march_step: float = 0.9
    obstacles_at: str = "current"
    march_rule: str = "ray"


@dataclass(frozen=True)
class TrackingConfig:
    """Kalman filter (thesis eq. 2-1..2-9): Q = q I, R = r I, P0 = diag(p0_pos, p0_vel), drop above drop_pos_var m^2.
    drop_rule (pbdyn.perception.tracker.KalmanTracks): "arena" drops a track whose updated mean leaves the arena;
    "program" (the thesis program) drops a track whose predicted mean comes within the setup radius of a wall,
    before the update, restarts it at the next detection after that step, and gives a restarted track the setup
    radius instead of the obstacle's own. track_radius: the radius a track reports to the planners, "own" (its
    obstacle's) or "setup" (the setup's radius for every track, as the thesis program's planners used it when it flew
    the thesis' trials)."""

    DROP_RULES: ClassVar[tuple[str, ...]] = ("arena", "program")
    TRACK_RADII: ClassVar[tuple[str, ...]] = ("own", "setup")

    MIN_VARIANCE: ClassVar[float] = 1e-12
    """Smallest positive q, r, p0_pos, p0_vel (0 is allowed for q or r, not both): below it a float64 covariance
    underflows and the filter produces NaN."""

    q: float = 1e-5
    r: float = 0.0
    p0_pos: float = 0.01
    p0_vel: float = 0.1
    drop_pos_var: float = 1.5
    drop_rule: str = "arena"
    track_radius: str = "own"


@dataclass(frozen=True)
class TaskConfig:
    """Start/goal candidates [[x, y(, z)], ...] (m; () = default_candidates(world)), pairs_flown (the ordered
    (start, goal) candidate index pairs an experiment flies; () = all), goal_radius (m), spawn_clearance
    (m) around each candidate's MAV disc, deadlock_steps (consecutive planning failures at rest), and the start
    rule (pbdyn.sim.start): start_rule (START_RULES), start_clearance (m between the MAV disc at the start and
    every obstacle; "program": every obstacle centre), start_window_s (s the start must stay clear,
    "first_clear"), start_wait_max_s (s a trial may wait for a clear start, "first_clear"), start_yaw_deg (the
    MAV's yaw at the start, deg in the world frame; None, "goal" in TOML: facing the goal)."""

    candidates: tuple[tuple[float, ...], ...] = ()
    goal_radius: float = 1.0
    spawn_clearance: float = 1.0
    deadlock_steps: int = 10
    start_rule: str = "first_clear"
    start_clearance: float = 1.0
    start_window_s: float = 1.0
    start_wait_max_s: float = 10.0
    start_yaw_deg: float | None = None
    pairs_flown: tuple[tuple[int, int], ...] = ()

    def pairs(self) -> list[tuple[int, int]]:
        """All ordered (start, goal) index pairs with start != goal (72 for 9 candidates)."""
        n = len(self.candidates)
        return [(i, j) for i in range(n) for j in range(n) if i != j]

    def flown_pairs(self) -> list[tuple[int, int]]:
        """The ordered (start, goal) index pairs an experiment flies: pairs_flown, or all of pairs() when it is
        empty. (Maps are built around every candidate either way: the candidates, not the pairs flown, shape
        them.)"""
        return [tuple(p) for p in self.pairs_flown] if self.pairs_flown else self.pairs()


@dataclass(frozen=True)
class PlannerEntry:
    """One (trajectory, gaze) planner pair with their parameter tables (a scenario without [[planners]] has one
    entry of the defaults)."""

    trajectory: str = "local_primitives"
    gaze: str = "lookahead"
    trajectory_params: Mapping[str, Any] = field(default_factory=dict)
    gaze_params: Mapping[str, Any] = field(default_factory=dict)
    name: str = ""

    @property
    def label(self) -> str:
        """A readable label, e.g. 'lookahead+local_primitives'."""
        return self.name or f"{self.gaze}+{self.trajectory}"


@dataclass(frozen=True)
class Scenario:
    """A whole validated scenario (name: the file's stem, else DEFAULT_NAME)."""

    DEFAULT_NAME: ClassVar[str] = "scenario"

    name: str
    world: WorldConfig
    obstacles: ObstacleConfig
    static_obstacles: tuple[StaticObstacleConfig, ...]
    drone: DroneConfig
    sensor: SensorConfig
    tracking: TrackingConfig
    task: TaskConfig
    planners: tuple[PlannerEntry, ...]
    collision_check: str = "swept"
    source: str = ""  # path of the file it was loaded from (not part of the resolved spec)
    bodies: tuple[BodyConfig, ...] = ()
    profile: str = "physical"

    @property
    def physical(self) -> bool:
        """True under the "physical" profile (the plan contract enforces the MAV's limits)."""
        return self.profile == "physical"

    @property
    def is_world(self) -> bool:
        """True for an imported world (a scenario with [[bodies]] instead of generated obstacles)."""
        return bool(self.bodies)

    def resolve_path(self, name: str, field: str = "urdf") -> Path:
        """Absolute path of a file named in the scenario: absolute as is; relative: the scenario's folder if the
        file is there, else the bundled models (pbdyn.resources.models_dir)."""
        p = Path(name)
        if p.is_absolute():
            return p
        if self.source:
            cand = Path(self.source).resolve().parent / p
            try:
                if cand.exists():
                    return cand
            except OSError as exc:   # e.g. a file name longer than the file system allows
                raise ConfigError(field, f"is not a usable path ({exc.strerror})", name) from None
        return resources.models_dir() / p

    def to_dict(self) -> dict:
        """The resolved scenario as plain JSON-able data (no source path; "bodies" only for imported worlds)."""
        d = asdict(self)
        d.pop("source", None)
        if not self.bodies:
            d.pop("bodies", None)
        if not self.obstacles.structure and not self.obstacles.maps:   # (scenarios without structures resolve
            d["obstacles"].pop("structure", None)                       # as before the fields existed)
            d["obstacles"].pop("structures", None)
        if not self.obstacles.maps:
            d["obstacles"].pop("maps", None)
        if not self.task.pairs_flown:
            d["task"].pop("pairs_flown", None)
        return json.loads(json.dumps(d, default=_json_default))

    def setups(self) -> list[dict]:
        """The Cartesian product of the grid fields, in file order (first field slowest); with an explicit map list,
        each listed map's setup values, in file order, once."""
        if self.obstacles.maps:
            out = []
            for m in self.obstacles.maps:
                if m.setup() not in out:
                    out.append(m.setup())
            return out
        grids = {k: getattr(self.obstacles, k) for k in self.obstacles.grid_order}
        out = []
        for combo in itertools.product(*grids.values()):
            out.append({k: _json_default(v) if isinstance(v, Range) else v for k, v in zip(grids, combo)})
        return out

    def n_trials(self) -> int:
        """Trials a batch of this scenario flies: maps (setups x maps_per_setup) x ordered start/goal pairs x v_max
        values x planner entries (not limited; see pbdyn.limits)."""
        n = len(self.task.candidates)
        n_pairs = len(self.task.pairs_flown) or n * (n - 1)
        maps = len(self.obstacles.maps) or (math.prod(len(getattr(self.obstacles, k))
                                                      for k in self.obstacles.grid_order)
                                            * self.obstacles.maps_per_setup)
        return maps * n_pairs * len(self.drone.v_max) * len(self.planners)

    def mav_urdf_path(self) -> Path:
        """Absolute path of the MAV URDF (relative paths: the scenario's folder, then the bundled urdf/)."""
        return self.resolve_path(self.drone.urdf, "drone.urdf")


def default_candidates(world: WorldConfig) -> tuple[tuple[float, ...], ...]:
    """{4, L/2, L-4}^2 (thesis table 4-1: {4, 25, 46} m on the 50 m arena); 3D: the same at z = L_z / 2."""
    xs = [(4.0, world.size[k] / 2.0, world.size[k] - 4.0) for k in range(2)]
    pts = [(x, y) for x in xs[0] for y in xs[1]]
    if world.dims == 3:
        pts = [p + (world.size[2] / 2.0,) for p in pts]
    return tuple(pts)


def _defaults(cls: type) -> dict[str, Any]:
    """Field name -> default of dataclass ``cls`` (the only place defaults are written); fields without one are
    left out."""
    out = {}
    for f in fields(cls):
        if f.default is not MISSING:
            out[f.name] = f.default
        elif f.default_factory is not MISSING:
            out[f.name] = f.default_factory()
    return out


def _json_default(o: Any) -> Any:
    if isinstance(o, Range):
        return o.to_json()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {o!r}")


def stable_hash64(text: str) -> int:
    """A process-independent 64-bit hash of a string (first 8 bytes of its sha256)."""
    import hashlib

    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "big")


def map_seed(root_seed: int, key: str) -> int:
    """A 63-bit integer summarising a map's seed, SeedSequence([root_seed, stable_hash64(key)]) (docs/design.md "Maps
    and seeds"; ``key``: the map's canonical JSON of setup values and replicate)."""
    import numpy as np

    ss = np.random.SeedSequence([root_seed, stable_hash64(key)])
    return int(ss.generate_state(2, np.uint64)[0] >> np.uint64(1))


def canonical_json(obj: Any) -> str:
    """Canonical JSON (sorted keys, no spaces) used for hashes and keys."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_json_default)


def trial_span_s(world: WorldConfig, task: TaskConfig) -> float:
    """Seconds of obstacle motion one trial may need (before the extra step of its last collision check): the time
    limit, and with "first_clear" after at most start_wait_max_s of waiting, or the start rule's look-ahead
    window if that is longer."""
    if task.start_rule == "first_clear":
        return task.start_wait_max_s + max(world.time_limit, task.start_window_s)
    return world.time_limit


def rollout_span_s(world: WorldConfig, task: TaskConfig) -> float:
    """Seconds of obstacle motion a map's default rollout covers (before its extra step): the longest of a trial
    (trial_span_s) and the default metrics (limits.METRICS_HORIZON_S)."""
    return max(trial_span_s(world, task), limits.METRICS_HORIZON_S)
