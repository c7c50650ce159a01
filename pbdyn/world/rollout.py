"""Rollouts: every obstacle's state at every step of a map, computed once and cached (docs/design.md "The data flow").

The .npz file holds these arrays (SI units, world frame):
    times [T] (s), positions [T, N, d] (m), velocities [T, N, d] (m/s), radii [N] (m), arena_size [d] (m),
    dt [] (s), static_kind [S] (0 = pillar, 1 = box), static_center [S, d] (m), static_radius [S] (m),
    static_size [S, d] (m, box full extents), static_yaw [S] (rad), meta [] (JSON string: map key, seed, motion,
    model version, scenario name). Imported worlds add the body_* arrays of pbdyn.world.imported.bodies.WorldBodies
    (base poses of every body at every step); their dynamic obstacles are the moving bodies' bounding spheres.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from pbdyn import limits
from pbdyn.config import LATER_FIELDS, Scenario, canonical_json, later_fields, rollout_span_s
from pbdyn.errors import ConfigError, HorizonError
from pbdyn.files import atomic_write, cache_dir
from pbdyn.motion.registry import MODELS, key_params
from pbdyn.world.geometry import StaticBody
from pbdyn.world.imported.bodies import (WorldBodies, bodies_fingerprint, build_world_bodies, check_candidates,
                                         sphere_tracks)
from pbdyn.world.maps import MapSpec, spawn_obstacles, static_bodies
from pbdyn.world.structure import structure_of

STATIC_KINDS = ("pillar", "box")


@dataclass(frozen=True)
class Rollout:
    """Positions and velocities of every obstacle at every step, plus the static geometry of the map."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    radii: np.ndarray
    arena_size: np.ndarray
    dt: float
    static: tuple[StaticBody, ...] = ()
    meta: dict = field(default_factory=dict)
    bodies: WorldBodies | None = None

    def __post_init__(self) -> None:
        for name in ("times", "positions", "velocities", "radii", "arena_size"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def dims(self) -> int:
        """Spatial dimension d."""
        return int(self.arena_size.shape[0])

    @property
    def n_obstacles(self) -> int:
        """Number of dynamic obstacles N."""
        return int(self.radii.shape[0])

    @property
    def n_steps(self) -> int:
        """Number of time samples T."""
        return int(self.times.shape[0])

    @property
    def horizon(self) -> float:
        """Last time covered (s)."""
        return float(self.times[-1])

    def step_index(self, t: float) -> int:
        """Index of the sample at time t (s); HorizonError past the horizon."""
        k = int(round(t / self.dt))
        if k < 0 or k >= self.n_steps:
            raise HorizonError(f"time {t:.3f} s is outside the rollout's horizon [0, {self.horizon:.3f}] s")
        return k

    def at(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions [N, d], velocities [N, d]) at step k; HorizonError past the horizon."""
        if k < 0 or k >= self.n_steps:
            raise HorizonError(f"step {k} is outside the rollout's horizon (0..{self.n_steps - 1})")
        return self.positions[k], self.velocities[k]

    # ------------------------------------------------------------------ files
    def to_arrays(self) -> dict[str, np.ndarray]:
        """The documented .npz arrays."""
        d = self.dims
        s = len(self.static)
        kinds = np.array([STATIC_KINDS.index(b.kind) for b in self.static], dtype=np.int8)
        center = np.array([np.asarray(b.center, float)[:d] for b in self.static]).reshape(s, d)
        size = np.array([np.resize(np.asarray(b.size, float), d) if b.size else np.zeros(d)
                         for b in self.static]).reshape(s, d)
        return {
            "times": self.times, "positions": self.positions, "velocities": self.velocities,
            "radii": self.radii, "arena_size": self.arena_size, "dt": np.array(self.dt),
            "static_kind": kinds, "static_center": center,
            "static_radius": np.array([b.radius for b in self.static], dtype=float),
            "static_size": size, "static_yaw": np.array([b.yaw for b in self.static], dtype=float),
            "meta": np.array(json.dumps(self.meta, sort_keys=True)),
            **(self.bodies.to_arrays() if self.bodies is not None else {}),
        }

    def save(self, path: str | Path) -> None:
        """Write the rollout to an .npz file atomically (pbdyn.files.atomic_write)."""
        def write(tmp: str) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, **self.to_arrays())

        atomic_write(path, write, make_parents=True)

    @classmethod
    def load(cls, path: str | Path) -> "Rollout":
        """Read a rollout written by save()."""
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        static = tuple(
            StaticBody(STATIC_KINDS[int(k)], tuple(map(float, c)), float(r),
                       tuple(map(float, s)) if int(k) == 1 else (), float(y))
            for k, c, r, s, y in zip(a["static_kind"], a["static_center"], a["static_radius"], a["static_size"],
                                     a["static_yaw"]))
        return cls(a["times"], a["positions"], a["velocities"], a["radii"], a["arena_size"], float(a["dt"]),
                   static, json.loads(str(a["meta"])), WorldBodies.from_arrays(a))


def rollout_code(motion: str | None) -> str:
    """The identity of the code that computes a rollout moved by ``motion`` (a registry name; None: an imported
    world's bodies): "code:" + pbdyn.codeid's identity of this module and what it uses, with that motion model's
    module and no other's (docs/design.md "Code identity")."""
    from pbdyn import codeid

    model = type(MODELS[motion]).__module__ if motion in MODELS else None
    others = tuple(m for m in codeid.MOTION_MODELS if m != model)
    return "code:" + codeid.identity((__name__,) + ((model,) if model else ()), others)


def _motion_of(scenario: Scenario, spec: MapSpec) -> str | None:
    """The motion model a map's obstacles move by (its structure's, else obstacles.motion; None: imported)."""
    if scenario.is_world:
        return None
    st = structure_of(scenario, spec.setup)
    return st.motion if st is not None and st.motion is not None else scenario.obstacles.motion


def rollout_key(scenario: Scenario, spec: MapSpec, horizon: float) -> str:
    """sha256 of everything a rollout depends on, with the identity of the code that computes it (rollout_code);
    the motion model's parameters are its key_params (pbdyn.motion.registry.key_params)."""
    w = scenario.world
    payload = {
        "version": rollout_code(_motion_of(scenario, spec)), "map": spec.key, "root_seed": spec.root_seed,
        "world": {"dims": w.dims, "size": w.size, "dt": w.dt},
        "obstacles": {"jitter": scenario.obstacles.radius_jitter, "motion": scenario.obstacles.motion,
                      **key_params(scenario.obstacles)},
        "static": [vars(s) for s in scenario.static_obstacles],
        "spawn": {"candidates": scenario.task.candidates, "mav_radius": scenario.drone.radius,
                  "clearance": scenario.task.spawn_clearance},
        "horizon": round(horizon, 9),
    }
    if scenario.obstacles.headings != "uniform":   # (keys of "uniform" maps stay as they were before the field)
        payload["obstacles"]["headings"] = scenario.obstacles.headings
    used = {k: getattr(scenario.obstacles, k) for k in LATER_FIELDS["obstacles"]}
    used = {k: v for k, v in used.items() if k not in later_fields("obstacles", used)}      # likewise
    if used:
        payload["obstacles"].update(used)
        payload["spawn"]["start_clearance"] = scenario.task.start_clearance
    st = structure_of(scenario, spec.setup)
    if st is not None:                             # (likewise: only maps with a structure carry one)
        payload["structure"] = asdict(st)
    if scenario.is_world:
        payload["bodies"] = bodies_fingerprint(scenario)
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()


def world_description(scenario: Scenario) -> dict:
    """What a scenario's worlds are made of beyond its settings: the rollout model's version and, for an imported
    world, each body's URDF and mesh digests and its motion module's source digest (bodies_fingerprint). Stored
    with a results store (meta "world") so that a changed world can be named (world_changes)."""
    out: dict = {"rollout_model": rollout_code(None if scenario.is_world else scenario.obstacles.motion)}
    if scenario.is_world:
        out["bodies"] = bodies_fingerprint(scenario)
    return out


def world_changes(old: dict, new: dict, scenario: Scenario | None = None) -> list[str]:
    """What differs between two world_description()s, in words ("bodies[2] (crate): motion module
    my_motions"): the rollout model, a body's URDF or meshes, a body's motion module, bodies added or removed."""
    out = []
    if old.get("rollout_model") != new.get("rollout_model"):
        out.append(f"pbdyn's rollout model ({old.get('rollout_model')} -> {new.get('rollout_model')})")
    ob, nb = old.get("bodies") or [], new.get("bodies") or []
    if len(ob) != len(nb):
        out.append(f"the number of bodies ({len(ob)} -> {len(nb)})")
    for i, (a, b) in enumerate(zip(ob, nb)):
        name = b.get("name", "")
        where = scenario.bodies[i] if scenario is not None and i < len(scenario.bodies) else None
        if a.get("urdf_sha256") != b.get("urdf_sha256"):
            out.append(f"bodies[{i}] ({name}): its URDF or meshes" + (f" ({where.urdf})" if where else ""))
        if a.get("function_sha256") != b.get("function_sha256"):
            out.append(f"bodies[{i}] ({name}): its motion module ({b.get('motion')})")
        rest = sorted(k for k in set(a) | set(b) if k not in ("urdf_sha256", "function_sha256")
                      and a.get(k) != b.get(k))
        if rest:
            out.append(f"bodies[{i}] ({name}): {', '.join(rest)}")
    return out


METRICS_HORIZON = limits.METRICS_HORIZON_S
"""Seconds the default metrics need: global survivability's last start (20 s) + its T_max (24 s)."""


def default_horizon(scenario: Scenario) -> float:
    """The longest default consumer plus one step: a trial (its time limit after the start rule's longest wait; the
    collision check at t_k+1 of the last step needs one more sample) or the default metrics (global survivability:
    20 s + 24 s); pbdyn.config.rollout_span_s."""
    return rollout_span_s(scenario.world, scenario.task) + scenario.world.dt


def build_rollout(scenario: Scenario, spec: MapSpec, horizon: float | None = None, *,
                  keep_out: tuple | None = None) -> Rollout:
    """Compute a map's rollout from (scenario, map spec) over [0, horizon] s: the obstacles spawned, then moved by
    the map's motion model (its structure's, else obstacles.motion; pbdyn.motion.registry.MODELS). ``keep_out``:
    (points [m, d], gap m) to spawn around instead of the start/goal candidates (pbdyn.world.maps.spawn_obstacles)."""
    horizon = default_horizon(scenario) if horizon is None else float(horizon)
    if not 0 < horizon < float("inf"):
        raise ConfigError("horizon", "must be a finite number > 0", horizon)
    dt = scenario.world.dt
    limits.check_limit("horizon", "rollout steps", horizon / dt, limits.MAX_STEPS, horizon)
    n = int(spec.setup.get("count", 0)) if not scenario.is_world else len(scenario.bodies)
    limits.check_limit("horizon", "bytes", (horizon / dt + 1) * n * (scenario.world.dims * 16 + 56),
                       limits.MAX_ROLLOUT_BYTES, horizon)
    n_t = int(round(horizon / dt)) + 1
    times = np.arange(n_t) * dt
    size = np.asarray(scenario.world.size, dtype=float)
    if scenario.is_world:
        return _world_rollout(scenario, spec, times, size)
    p0, v0, radii = spawn_obstacles(scenario, spec, keep_out)
    st = structure_of(scenario, spec.setup)
    motion = st.motion if st is not None and st.motion is not None else scenario.obstacles.motion
    model = MODELS[motion]
    pos, vel = model.rollout(p0, v0, radii, size, times, dt, model.params(scenario.obstacles))
    meta = {"map_key": spec.key, "map_index": spec.index, "seed": spec.seed, "motion": motion,
            "version": rollout_code(motion), "scenario": scenario.name}
    return Rollout(times, pos, vel, radii, size, dt, static_bodies(scenario, spec), meta)


def _world_rollout(scenario: Scenario, spec: MapSpec, times: np.ndarray, size: np.ndarray) -> Rollout:
    """The rollout of an imported world: body poses, and the moving bodies' bounding spheres as obstacles."""
    dt = scenario.world.dt
    bodies = build_world_bodies(scenario, times)
    check_candidates(scenario, bodies)
    pos, vel = sphere_tracks(bodies, scenario.world.dims, dt, scenario)
    radii = bodies.sphere_radius[bodies.moving_index]
    meta = {"map_key": spec.key, "map_index": spec.index, "seed": spec.seed, "motion": "imported",
            "version": rollout_code(None), "scenario": scenario.name, "bodies": list(bodies.names),
            "flight_height": scenario.world.flight_height}
    return Rollout(times, pos, vel, radii, size, dt, static_bodies(scenario), meta, bodies)


def rollout_file(scenario: Scenario, spec: MapSpec, horizon: float | None = None, *,
                 fallback_dir: str | Path | None = None) -> tuple[str, Path]:
    """(rollout key, path of its .npz file): the cached file, built and written first if missing (into
    ``fallback_dir``/.pbdyn-rollouts when the cache folder is not writable)."""
    horizon = default_horizon(scenario) if horizon is None else float(horizon)
    key = rollout_key(scenario, spec, horizon)
    path = cache_dir() / "rollouts" / f"{key}.npz"
    if path.is_file():
        return key, path
    ro = build_rollout(scenario, spec, horizon)
    try:
        ro.save(path)
    except OSError:
        if fallback_dir is None:
            raise
        path = Path(fallback_dir) / ".pbdyn-rollouts" / f"{key}.npz"
        ro.save(path)
    return key, path


def get_rollout(scenario: Scenario, spec: MapSpec, horizon: float | None = None, *, use_cache: bool = True) -> Rollout:
    """The map's rollout, from the on-disk cache when present (keyed by rollout_key), else built and cached."""
    horizon = default_horizon(scenario) if horizon is None else float(horizon)
    if not use_cache:
        return build_rollout(scenario, spec, horizon)
    path = cache_dir() / "rollouts" / f"{rollout_key(scenario, spec, horizon)}.npz"
    if path.is_file():
        try:
            return Rollout.load(path)
        except (OSError, ValueError, KeyError):
            path.unlink(missing_ok=True)
    ro = build_rollout(scenario, spec, horizon)
    try:
        ro.save(path)
    except OSError:
        pass  # a read-only cache is not an error: the rollout is still correct
    return ro
