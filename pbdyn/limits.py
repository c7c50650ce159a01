"""Resource limits checked when a scenario or world file is loaded (docs/scenarios.md "Scenario reference").

A scenario that passes every other check can still ask for more memory or time than any machine has (a map count
of 2**63, a step of a microsecond, an arena of a million metres at a 1 m grid, ten thousand obstacles). Such a
file is refused when it is loaded, before anything is allocated, with a ConfigError naming the field, its value
and the limit. The limits are generous: every bundled scenario and dataset uses a small fraction of each.

- MAX_MAPS_PER_SETUP = 100 000: obstacles.maps_per_setup.
- MAX_SETUPS = 100 000: setups, the product of the grid fields' lengths (count x radius x speed).
- MAX_OBSTACLES = 2 000: every obstacles.count value; the number of [[bodies]] and of [[static_obstacles]].
- MAX_STEPS = 1 000 000: steps of a rollout, (max(world.time_limit, METRICS_HORIZON_S) + dt) / dt.
- MAX_ROLLOUT_BYTES = 2 GiB: a rollout's arrays, steps x obstacles x d x 8 bytes x 2 (positions, velocities);
  an imported world adds steps x bodies x 7 x 8 bytes (poses).
- MAX_GRID_CELLS = 100 000 000: occupancy-grid cells, prod(world.size / world.grid_resolution + 2).
- MAX_SENSOR_RAYS = 100 000: rays of one scan at 360 deg (a gaze planner may widen the fov to 360 deg).
- MAX_SENSOR_MARCH_POINTS = 1 000 000: march points of one scan of the marching sensor (rays x range /
  march_step).
- MAX_RVO_CANDIDATES = 100 000: obstacles.rvo n_headings x n_speeds.
- MAX_RVO_CONTACT_ITERATIONS = 1 000: obstacles.rvo.contact_iterations.
- MAX_NESTING = 32: levels of tables and arrays in a scenario document.
- MAX_MAGNITUDE = 1e9: the absolute value of any number in a scenario (m, m/s, s, ...; integers such as seeds
  excepted), so that no arithmetic on it overflows.
- Built-in planner parameters (checked when a planner is built, naming planners[i].trajectory_params.<key>):
  MAX_PLAN_HORIZON_S = 1 000 s for any planning/prediction horizon or primitive duration, MAX_PLAN_COUNT =
  100 000 for counts of candidates, expansions, tracks, cells or rates, and MAX_PLAN_DISTANCE_M = 10 000 m for a
  primitive's length; a local primitive whose duration would exceed MAX_PLAN_HORIZON_S is not built.
- MAX_START_WAIT_S = 1 000 s: task.start_window_s and task.start_wait_max_s.
- MAX_METRIC_SAMPLES = 10 000 000: points or cells of a metric's sample grid over the arena (checked when the metric
  runs: its spacing / cell is a metric parameter, named in the error).
- Gymnasium observations (pbdyn.gym, checked when an environment or policy planner is built, naming the argument):
  MAX_GYM_TRACKS = 1 000 tracks (K), MAX_GYM_RAYS = 10 000 depth bins (B), MAX_GYM_PATCH_CELLS = 1 048 576 cells
  of the occupancy patch (P^d: P <= 1023 in 2D, P <= 101 in 3D).
- Command-line numbers (pbdyn/cli.py; an error names the flag): MAX_FLAG_COUNT = 1 000 000 for --lockstep,
  --every and demo's --maps and --pairs; MAX_BOOTSTRAP = 100 000 for evaluate --bootstrap; MAX_INDEX = 2**63 - 1
  for --map, --limit and --seed (the largest integer a results store or a TOML file holds); MAX_MAGNITUDE for
  generate's --target, --tolerance, --radius and --speed; MAX_OBSTACLES for generate's --obstacles; --workers at
  most pbdyn.experiments.runner.MAX_WORKERS_PER_CPU (4) x the CPU count.

The number of trials a batch would fly (setups x maps_per_setup x ordered start/goal pairs x v_max values x
planner entries) is not limited: a batch is resumable and may be sharded; ``Scenario.n_trials()`` reports it.
"""

from __future__ import annotations

import math

from pbdyn.errors import ConfigError

MAX_MAPS_PER_SETUP = 100_000
MAX_SETUPS = 100_000
MAX_OBSTACLES = 2_000
MAX_STEPS = 1_000_000
MAX_ROLLOUT_BYTES = 2 * 1024 ** 3
MAX_GRID_CELLS = 100_000_000
MAX_SENSOR_RAYS = 100_000
MAX_SENSOR_MARCH_POINTS = 1_000_000
MAX_RVO_CANDIDATES = 100_000
MAX_RVO_CONTACT_ITERATIONS = 1_000
MAX_MAGNITUDE = 1e9
MAX_PLAN_HORIZON_S = 1_000.0
MAX_PLAN_COUNT = 100_000
MAX_PLAN_DISTANCE_M = 10_000.0
MAX_NESTING = 32
MAX_METRIC_SAMPLES = 10_000_000
MAX_START_WAIT_S = 1_000.0
MAX_GYM_TRACKS = 1_000
"""Tracks (K) a Gymnasium observation may hold: K x (2d + 3) <= 9 000 entries."""
MAX_GYM_RAYS = 10_000
"""Depth bins (B) a Gymnasium observation may hold."""
MAX_GYM_PATCH_CELLS = 2 ** 20
"""Cells (P^d) of a Gymnasium observation's occupancy patch: 4 MiB of float32; P <= 1023 in 2D, P <= 101 in 3D."""

MAX_FLAG_COUNT = 1_000_000
MAX_BOOTSTRAP = 100_000
MAX_INDEX = 2 ** 63 - 1

CHUNK_ELEMENTS = 4_000_000
"""Upper bound on the elements of one temporary array of a vectorised computation (a metric's samples x obstacles x
steps, a marching scan's rays x points x obstacles): larger ones are computed in chunks of at most this many."""

METRICS_HORIZON_S = 44.0
"""Seconds the default metrics need: global survivability's last start (20 s) + its T_max (24 s). A map's rollout
covers max(world.time_limit, METRICS_HORIZON_S) + dt (pbdyn.world.rollout.default_horizon)."""


def check_limit(field: str, what: str, amount: float, limit: float, value: object) -> None:
    """ConfigError naming ``field`` and ``value`` when ``amount`` (a count of ``what``; "bytes" are shown in GiB)
    exceeds ``limit``."""
    if not amount <= limit:
        if what == "bytes":
            need, cap = f"{amount / 1024 ** 3:.3g} GiB", f"{limit / 1024 ** 3:g} GiB"
        else:
            need, cap = f"{_fmt(amount)} {what}", _fmt(limit)
        raise ConfigError(field, f"would need {need}, more than the limit of {cap} (pbdyn.limits)", value)


def grid_count(size, spacing: float) -> float:
    """Cells of a grid of ``spacing`` m over an arena of extents ``size`` (m), as a float (never overflows)."""
    return math.prod(float(math.ceil(float(s) / float(spacing) - 1e-9)) for s in size)


def _fmt(x: float) -> str:
    return f"{int(x):,}" if float(x).is_integer() and abs(x) < 1e15 else f"{x:.3g}"
