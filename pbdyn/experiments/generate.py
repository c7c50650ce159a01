"""`pbdyn generate --metric`: maps of a chosen difficulty, as in the thesis' use case 5-2-2 (eqs. 5-1 to 5-7).

The thesis fits a linear model of survivability on the obstacle count, radius and speed (eq. 5-1) and picks the
setup whose prediction is closest to the target (eq. 5-2 under the bounds 5-3 to 5-6). A prediction is not a
measurement: maps of one setup differ by their seed (docs/scenarios.md "Structured worlds"), so pbdyn measures every candidate
with the real metric and keeps only those within the tolerance. The search, for one generator family (a structure:
uniform, clustered, crossing, walls, mixed, spread, rvo) in 2D or 3D:

1. pilot: the 8 corners of the (n, r, v) box (n integer in [10, 30], r in [0.5, 1.5] m, v in [2, 6] m/s unless
   fixed or narrowed) twice and PILOT_INTERIOR points drawn uniformly inside, each a fresh map; their measured
   range is what the family reaches (a target outside it is refused, naming the range);
2. rounds of ROUND candidates: (n, r) drawn uniformly (or fixed), v solved from a linear model of the metric on
   (n, r, v) (eq. 5-1) fitted by weighted least squares to every candidate measured so far, the weights falling
   with the distance of the measured value from the target (a local fit of the target's level set); v is varied
   by a small random step (or n or r, when v is fixed), and every candidate is a new map (its own replicate);
3. a candidate within the tolerance is kept; the search stops at ``count`` kept maps, or refuses after
   MAX_CANDIDATES_PER_MAP x count candidates (the target lies where few maps of the family fall).

Every map is identified as a grid map is (setup values, replicate, obstacles.root_seed: pbdyn.world.maps.MapSpec),
so the written scenario's ``[[obstacles.maps]]`` gives exactly the measured maps. Candidates are measured in a
process pool in rounds of a fixed size and the model is refitted between rounds: the result does not depend on the
number of workers. Everything random comes from one Generator seeded by the request.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import math
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pbdyn.config import BUILTIN_STRUCTURES, Scenario, canonical_json, parse_scenario
from pbdyn.errors import ConfigError
from pbdyn.metrics.catalog import INFO, NAMES

FAMILIES = tuple(BUILTIN_STRUCTURES)
"""The generator families: pbdyn's built-in structures (docs/scenarios.md "Structured worlds")."""

BOX = {"count": (10, 30), "radius": (0.5, 1.5), "speed": (2.0, 6.0)}
"""The setup bounds of thesis eqs. 5-4 to 5-6: obstacle count (integer), radius (m), speed (m/s)."""

PILOT_INTERIOR = 16
ROUND = 16
MAX_CANDIDATES_PER_MAP = 40
DECIMALS = {"radius": 2, "speed": 2}
"""Radii and speeds of generated maps are rounded to this many decimals (readable files)."""

METRICS = NAMES
"""Every map metric can be a target (pbdyn.metrics.catalog)."""
PREDICTED = "predicted_reference_success"
"""The value success mode searches on: the shipped predictor's reference success (pbdyn.analysis.predict)."""
MEASURED = "reference_success"
"""The value success mode keeps maps by: the reference panel's measured success (pbdyn calibrate)."""
PROPOSE_SHARE = 0.5
"""Success mode flies a candidate only if its predicted success lies within this share of the tolerance."""
FLY_ROUND = 4
"""Success mode flies at most this many candidates at once (one batch of 180 trials each)."""
MAX_FLOWN_PER_MAP = 6
"""Success mode refuses after flying this many candidates per requested map."""
BIAS_PRIOR = 2.0
"""Success mode: pseudo-candidates with zero residual that shrink the learnt bias of the predictor."""


@dataclass(frozen=True)
class MetricTarget:
    """What `pbdyn generate --metric` asks for: ``count`` maps whose ``metric`` lies within ``tolerance`` of
    ``target`` (the metric's unit), of generator ``family`` in ``dims`` D, built on ``base`` (the world, MAV,
    sensor, task and planners of the written scenario; obstacles' grid fields are replaced). ``fixed``: setup
    values held fixed ({"count": 10} as in fig. 5-12a); ``bounds``: the (lo, hi) box per setup field (BOX by
    default); ``seed``: the written scenario's obstacles.root_seed and the search's seed."""

    metric: str
    target: float
    tolerance: float
    count: int
    family: str = "uniform"
    dims: int = 2
    base: dict = field(default_factory=dict)
    fixed: dict = field(default_factory=dict)
    bounds: dict = field(default_factory=lambda: dict(BOX))
    seed: int = 0


@dataclass
class Candidate:
    """A measured map: setup values, replicate and the metric's value."""

    count: int
    radius: float
    speed: float
    replicate: int
    value: float = math.nan
    seed: int = 0
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class GeneratedMaps:
    """The result: the kept maps (in the order found), the scenario document that lists them, and how the search
    went (candidates measured, pilot range, the last model's coefficients, wall time s)."""

    maps: tuple
    document: dict
    candidates: int
    reachable: tuple
    coefficients: tuple
    wall_time_s: float
    flown: int = 0

    def summary(self) -> dict:
        """JSON-able facts of the run (success mode: ``flown`` candidates flown by the panel, ``measured`` their
        reference successes)."""
        out = {"maps": len(self.maps), "candidates": self.candidates, "reachable": list(self.reachable),
               "coefficients": list(self.coefficients), "wall_time_s": self.wall_time_s,
               "seconds_per_map": self.wall_time_s / max(len(self.maps), 1),
               "values": [c.value for c in self.maps]}
        if self.flown:
            out["flown"] = self.flown
            out["measured"] = [c.extra.get(MEASURED) for c in self.maps]
        return out


# ------------------------------------------------------------------------------------------------ checking
def check_target(req: MetricTarget) -> MetricTarget:
    """``req`` with its values checked (ConfigError naming the flag's parameter otherwise)."""
    if req.metric == PREDICTED:
        if isinstance(req.target, bool) or not isinstance(req.target, (int, float)) or not 0.0 <= req.target <= 1.0:
            raise ConfigError("success", "must be a success rate in [0, 1]", req.target)
        if isinstance(req.tolerance, (int, float)) and not isinstance(req.tolerance, bool) and req.tolerance >= 0.5:
            raise ConfigError("tolerance", "must be < 0.5 for a success target", req.tolerance)
    elif req.metric not in METRICS:
        raise ConfigError("metric", f"cannot generate by this metric (one of {', '.join(METRICS)})", req.metric)
    for name in ("target", "tolerance"):
        v = getattr(req, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(name, "must be a finite number", v)
    if req.tolerance <= 0:
        raise ConfigError("tolerance", "must be > 0", req.tolerance)
    if isinstance(req.count, bool) or not isinstance(req.count, int) or not 1 <= req.count <= 10000:
        raise ConfigError("count", "must be an integer in [1, 10000]", req.count)
    if req.family not in FAMILIES:
        raise ConfigError("family", f"unknown generator family (one of {', '.join(FAMILIES)})", req.family)
    if req.dims not in (2, 3):
        raise ConfigError("dims", "must be 2 or 3", req.dims)
    if isinstance(req.seed, bool) or not isinstance(req.seed, int) or req.seed < 0:
        raise ConfigError("seed", "must be an integer >= 0", req.seed)
    bounds = {}
    for key, (lo, hi) in {**BOX, **req.bounds}.items():
        if key not in BOX:
            raise ConfigError("bounds", f"unknown setup field {key!r} (count, radius, speed)", key)
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi or lo < (0 if key != "radius" else 1e-3):
            raise ConfigError(f"bounds.{key}", "must be finite with 0 <= lo <= hi (radius > 0)", [lo, hi])
        bounds[key] = (int(lo), int(hi)) if key == "count" else (float(lo), float(hi))
    for key, v in req.fixed.items():
        if key not in BOX:
            raise ConfigError("fixed", f"unknown setup field {key!r} (count, radius, speed)", key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or \
                (key == "count" and (v != int(v) or v < 1)) or (key == "radius" and v <= 0):
            raise ConfigError(f"fixed.{key}", "must be a number > 0 (count: an integer >= 1)", v)
    if len(req.fixed) == 3:
        raise ConfigError("fixed", "fixes every setup value; leave at least one to search", dict(req.fixed))
    return replace(req, bounds=bounds, fixed={k: (int(v) if k == "count" else float(v)) for k, v in req.fixed.items()})


# ------------------------------------------------------------------------------------------------ documents
def scenario_document(req: MetricTarget, maps: list[Candidate] = ()) -> dict:
    """The scenario (as a TOML-shaped dict) that lists ``maps``: ``req.base`` with its obstacles' grid fields
    replaced by the explicit list and root_seed = req.seed."""
    doc = copy.deepcopy(req.base)
    doc.setdefault("name", f"generated_success_{req.target:g}" if req.metric == PREDICTED else
                   f"generated_{req.metric}_{req.target:g}")
    if req.dims == 3:
        doc.setdefault("world", {})["dims"] = 3
    obst = {k: v for k, v in doc.get("obstacles", {}).items()
            if k not in ("count", "radius", "speed", "maps_per_setup", "structure", "maps", "root_seed")}
    obst["root_seed"] = req.seed
    obst["maps"] = [_entry(req, c) for c in maps] or [_entry(req, Candidate(10, 1.0, 2.0, 0))]
    doc["obstacles"] = obst
    return doc


def _entry(req: MetricTarget, c: Candidate) -> dict:
    out = {"count": c.count, "radius": c.radius, "speed": c.speed, "structure": req.family, "replicate": c.replicate}
    if c.seed:
        out["seed"] = c.seed
    if math.isfinite(c.value):
        out["measured"] = {req.metric: c.value, **c.extra}
    return out


# ------------------------------------------------------------------------------------------------ measuring
def measure_metric(scenario: Scenario, metric: str, entries: list[tuple[int, dict, int]]) -> list[tuple[int, float, int]]:
    """(index, the metric's value, the map's seed) of each (index, setup values, replicate) map of ``scenario``:
    its rollout over the metric's horizon, then the metric as `pbdyn metrics` computes it (the scenario's MAV
    radius and backend)."""
    from pbdyn.metrics.cached import resolve_backend, run_metric
    from pbdyn.world.maps import MapSpec, world_digest
    from pbdyn.world.rollout import build_rollout

    backend = resolve_backend(scenario, "auto")
    out = []
    if metric == PREDICTED:
        from pbdyn.analysis.scale import reference_pairs
        from pbdyn.metrics.features import MAP_METRICS, ROUTE_HORIZON_S, rollout_features

        predictor = shipped_predictor(scenario.world.dims)
        horizon = max([INFO[m].horizon_s for m in MAP_METRICS] + [ROUTE_HORIZON_S]) + scenario.world.dt
        pairs = reference_pairs(scenario.task.candidates)
        for i, setup, rep in entries:
            spec = MapSpec(i, setup, rep, scenario.obstacles.root_seed, world_digest(scenario, setup))
            feats = rollout_features(scenario, build_rollout(scenario, spec, horizon), pairs, backend)
            out.append((i, float(predictor.predict([feats])[0][0]), spec.seed))
        return out
    horizon = INFO[metric].horizon_s + scenario.world.dt
    for i, setup, rep in entries:
        spec = MapSpec(i, setup, rep, scenario.obstacles.root_seed, world_digest(scenario, setup))
        ro = build_rollout(scenario, spec, horizon)
        out.append((i, float(run_metric(scenario, ro, metric, backend).value), spec.seed))
    return out


def shipped_predictor(dims: int):
    """The shipped predictor of ``dims``-D maps, else ConfigError naming --success."""
    from pbdyn.analysis.predict import load_predictors

    predictors = load_predictors()
    if dims not in predictors:
        have = "/".join(f"{d}D" for d in sorted(predictors)) or "no"
        raise ConfigError("success", f"needs the reference-success predictor of {dims}D maps (shipped: {have}); use "
                          "`metric`", dims, show_value=False)
    return predictors[dims]


def _measure_task(args):
    doc, metric, entries = args
    return measure_metric(parse_scenario(doc), metric, entries)


class _Measurer:
    """Measures candidates in this process (workers = 1) or on the batch runner's local worker pool
    (pbdyn.experiments.pool.WorkerPool: spawned workers that ignore SIGINT and exit when this process is gone), in
    submission order. A pool whose worker died is restarted and the round measured again (at most
    MAX_POOL_RESTARTS times in a row); close(terminate=True) ends the workers at once (SIGTERM/SIGINT)."""

    def __init__(self, doc: dict, metric: str, workers: int):
        self.doc, self.metric, self.workers = doc, metric, workers
        self.scenario = parse_scenario(doc)
        self.pool = None
        if workers > 1:
            from pbdyn.experiments.pool import WorkerPool

            self.pool = WorkerPool(workers, None, what="generate_maps")

    def __call__(self, family: str, cands: list[Candidate]) -> None:
        entries = [(i, {"count": c.count, "radius": c.radius, "speed": c.speed, "structure": family}, c.replicate)
                   for i, c in enumerate(cands)]
        if self.pool is None:
            results = measure_metric(self.scenario, self.metric, entries)
        else:
            results = self._measure_in_pool(entries)
        for i, value, seed in results:
            cands[i].value, cands[i].seed = value, seed

    def _measure_in_pool(self, entries: list) -> list:
        from concurrent.futures.process import BrokenProcessPool

        from pbdyn.errors import PbdynError
        from pbdyn.experiments.dispatch import MAX_POOL_RESTARTS

        chunks = [entries[k::self.workers] for k in range(self.workers)]
        for attempt in range(MAX_POOL_RESTARTS + 1):
            try:
                futures = [self.pool.submit(_measure_task, (self.doc, self.metric, ch)) for ch in chunks if ch]
                return [r for f in futures for r in f.result()]
            except BrokenProcessPool:
                self.pool.check_broken()     # a worker re-imported a script calling generate_maps at its top level
                if attempt == MAX_POOL_RESTARTS:
                    raise PbdynError(f"worker processes died {attempt + 1} times measuring one round of candidates "
                                     "(re-run the same command)") from None
                sys.stderr.write(f"pbdyn generate: a worker died; restarting the pool ({attempt + 1}/"
                                 f"{MAX_POOL_RESTARTS}) and measuring the round again\n")
                self.pool.restart()
        raise AssertionError("unreachable")  # pragma: no cover

    def close(self, terminate: bool = False) -> None:
        """Shut the pool down: wait for its workers, or with ``terminate`` end them at once."""
        if self.pool is not None:
            self.pool.close(terminate=terminate)
            self.pool = None

    def __enter__(self) -> "_Measurer":
        return self

    def __exit__(self, exc_type, *_) -> None:
        self.close(terminate=exc_type is not None)   # an error or SIGTERM/SIGINT (BaseException): at once


# ------------------------------------------------------------------------------------------------ the search
def _design_matrix(c: list[Candidate]) -> np.ndarray:
    return np.array([[1.0, x.count, x.radius, x.speed] for x in c])


def fit_linear(cands: list[Candidate], target: float | None = None, scale: float = 1.0) -> np.ndarray:
    """Coefficients (beta_0 .. beta_3) of the metric ~ beta_0 + beta_1 n + beta_2 r + beta_3 v (thesis eq. 5-1),
    least squares; with ``target``, weighted by exp(-((value - target) / scale)^2 / 2) + 0.05 (a local fit of the
    target's level set). A tiny ridge keeps it defined when a setup field is fixed."""
    x = _design_matrix(cands)
    y = np.array([c.value for c in cands])
    w = np.ones_like(y) if target is None else np.exp(-0.5 * ((y - target) / scale) ** 2) + 0.05
    sw = np.sqrt(w)
    a = x * sw[:, None]
    ridge = 1e-6 * np.eye(4)
    ridge[0, 0] = 0.0
    return np.linalg.solve(a.T @ a + ridge * len(y), a.T @ (y * sw))


def _rounded(req: MetricTarget, n: float, r: float, v: float) -> tuple[int, float, float]:
    (nlo, nhi), (rlo, rhi), (vlo, vhi) = req.bounds["count"], req.bounds["radius"], req.bounds["speed"]
    n = req.fixed.get("count", int(np.clip(round(n), nlo, nhi)))
    r = req.fixed.get("radius", float(np.clip(round(r, DECIMALS["radius"]), rlo, rhi)))
    v = req.fixed.get("speed", float(np.clip(round(v, DECIMALS["speed"]), vlo, vhi)))
    return int(n), float(r), float(v)


def _pilot(req: MetricTarget, rng: np.random.Generator, next_rep) -> list[Candidate]:
    b = req.bounds
    out = []
    for _ in range(2):
        for n in b["count"]:
            for r in b["radius"]:
                for v in b["speed"]:
                    out.append(Candidate(*_rounded(req, n, r, v), next_rep()))
    for _ in range(PILOT_INTERIOR):
        out.append(Candidate(*_rounded(req, rng.uniform(*b["count"]), rng.uniform(*b["radius"]),
                                       rng.uniform(*b["speed"])), next_rep()))
    return out


def _run_pilot(req: MetricTarget, rng: np.random.Generator, next_rep, measurer) -> tuple[list, float, float]:
    """The pilot's candidates (_pilot), measured, and the (min, max) of their values: the family's reach."""
    measured = _pilot(req, rng, next_rep)
    measurer(req.family, measured)
    values = [c.value for c in measured]
    return measured, float(min(values)), float(max(values))


def _propose(req: MetricTarget, beta: np.ndarray, rng: np.random.Generator, n_new: int, next_rep,
             spread: float) -> list[Candidate]:
    """``n_new`` candidates on (near) the model's level set of the target."""
    b = req.bounds
    free = [k for k in ("speed", "radius", "count") if k not in req.fixed]
    solve = free[0]          # the value solved from the model: speed unless fixed, then radius, then count
    idx = {"count": 1, "radius": 2, "speed": 3}
    out = []
    for _ in range(n_new):
        vals = {k: req.fixed.get(k, rng.uniform(*b[k])) for k in ("count", "radius", "speed")}
        coef = beta[idx[solve]]
        rest = beta[0] + sum(beta[idx[k]] * vals[k] for k in idx if k != solve)
        if abs(coef) > 1e-9:
            vals[solve] = (req.target - rest) / coef
        lo, hi = b[solve]
        vals[solve] += rng.normal(0.0, spread * (hi - lo))
        vals[solve] = float(np.clip(vals[solve], lo, hi))
        out.append(Candidate(*_rounded(req, vals["count"], vals["radius"], vals["speed"]), next_rep()))
    return out


def _round(aim: MetricTarget, beta: np.ndarray, rng: np.random.Generator, next_rep, spread: float, measurer,
           measured: list, scale: float, band: float) -> tuple[list, np.ndarray, float]:
    """One round of the search: ROUND candidates proposed around ``aim.target`` and measured (added to
    ``measured``); (them, the model refitted, the next spread: narrower when a quarter landed within ``band``)."""
    batch = _propose(aim, beta, rng, ROUND, next_rep, spread)
    measurer(aim.family, batch)
    measured += batch
    hits = sum(abs(c.value - aim.target) <= band for c in batch)
    return batch, fit_linear(measured, aim.target, scale), 0.02 if hits >= ROUND // 4 else min(0.15, spread * 1.5)


def generate_by_metric(req: MetricTarget, *, workers: int = 1, progress: bool = False) -> GeneratedMaps:
    """Search maps whose measured ``req.metric`` lies within the tolerance of the target (module doc); ConfigError
    naming "target" if the family's pilot maps do not reach it, or if too few candidates land within the
    tolerance."""
    req = check_target(req)
    t0 = time.perf_counter()
    doc = scenario_document(req)
    parse_scenario(doc)                                  # the base must hold before anything is measured
    from pbdyn.world.maps import stable_hash64

    rng = np.random.default_rng([req.seed, stable_hash64(canonical_json(
        {"metric": req.metric, "target": req.target, "tolerance": req.tolerance, "family": req.family,
         "dims": req.dims, "fixed": req.fixed, "bounds": req.bounds}))])
    next_rep = itertools.count().__next__                 # replicates 0, 1, 2, ...: every candidate a new map
    measurer = _Measurer(doc, req.metric, workers)
    shown = _Progress(req.count, progress)
    with shown, measurer:                  # the workers end first, at once on an error or SIGTERM/SIGINT
        measured, lo, hi = _run_pilot(req, rng, next_rep, measurer)
        if req.target + req.tolerance < lo or req.target - req.tolerance > hi:
            raise ConfigError("target", f"{req.metric} {req.target:g} is outside what family {req.family!r} reaches "
                              f"in {req.dims}D ({_box_text(req)}): {lo:.3g} to {hi:.3g} on "
                              f"{len(measured)} pilot maps", req.target, show_value=False)
        kept = [c for c in measured if abs(c.value - req.target) <= req.tolerance][:req.count]
        scale = max(req.tolerance * 4.0, 0.05 * (hi - lo))
        beta = fit_linear(measured, req.target, scale)
        budget = MAX_CANDIDATES_PER_MAP * req.count + len(measured)
        spread = 0.05
        shown.update(len(kept), len(measured))
        while len(kept) < req.count:
            if len(measured) >= budget:
                raise ConfigError("target", f"only {len(kept)} of {req.count} maps of family {req.family!r} came "
                                  f"within {req.tolerance:g} of {req.metric} {req.target:g} after {len(measured)} "
                                  f"candidates (reached: {lo:.3g} to {hi:.3g}); widen `tolerance` or move the target "
                                  "inside the range", req.target, show_value=False)
            batch, beta, spread = _round(req, beta, rng, next_rep, spread, measurer, measured, scale, req.tolerance)
            kept += [c for c in batch if abs(c.value - req.target) <= req.tolerance][:req.count - len(kept)]
            shown.update(len(kept), len(measured))
    wall = time.perf_counter() - t0
    return GeneratedMaps(tuple(kept), scenario_document(req, kept), len(measured), (lo, hi),
                         tuple(float(x) for x in fit_linear(measured)), wall)


def generate_by_success(req: MetricTarget, *, workers: int = 1, progress: bool = False) -> GeneratedMaps:
    """Maps whose reference success, flown by the reference panel (pbdyn calibrate), lies within the tolerance of
    the target (``req.metric`` = PREDICTED, ``req.target`` = the success rate). The predictor proposes: the search
    of generate_by_metric runs on the predicted success (the pilot's predicted range is the family's reachable
    range); candidates predicted within PROPOSE_SHARE of the tolerance are flown, closest first, FLY_ROUND at a
    time, and kept when their measured success is within the tolerance. The predictor's bias on this family is
    learnt as it flies: the mean logit residual of the flown candidates (measured minus predicted, shrunk towards 0
    by BIAS_PRIOR pseudo-candidates) shifts the predicted success the search aims at. The flights are stored in the
    cache
    (pbdyn.experiments.calibrate.default_store), so repeating a request reuses them; ConfigError naming "success"
    when the target is outside the predicted range or after MAX_FLOWN_PER_MAP x count flown candidates."""
    from pbdyn.experiments.calibrate import calibrate
    from pbdyn.world.maps import stable_hash64

    req = check_target(replace(req, metric=PREDICTED))
    t0 = time.perf_counter()
    doc = scenario_document(req)
    shipped_predictor(parse_scenario(doc).world.dims)
    rng = np.random.default_rng([req.seed, stable_hash64(canonical_json(
        {"success": req.target, "tolerance": req.tolerance, "family": req.family, "dims": req.dims,
         "fixed": req.fixed, "bounds": req.bounds}))])
    next_rep = itertools.count().__next__
    measurer = _Measurer(doc, PREDICTED, workers)
    shown = _Progress(req.count, progress, "flown")
    kept: list[Candidate] = []
    flown = 0
    with shown, measurer:                  # the workers end first, at once on an error or SIGTERM/SIGINT
        measured, lo, hi = _run_pilot(req, rng, next_rep, measurer)
        pilot_size = len(measured)
        if req.target + req.tolerance < lo or req.target - req.tolerance > hi:
            raise ConfigError("success", f"reference success {req.target:g} is outside what family {req.family!r} "
                              f"reaches in {req.dims}D ({_box_text(req)}): {lo:.2f} to {hi:.2f} predicted on "
                              f"{len(measured)} pilot maps", req.target, show_value=False)
        scale = max(req.tolerance * 4.0, 0.05 * (hi - lo))
        beta = fit_linear(measured, req.target, scale)
        budget = MAX_FLOWN_PER_MAP * req.count + FLY_ROUND
        spread = 0.05
        tried: set[int] = set()
        residuals: list[float] = []
        aim = replace(req)                          # the predicted success searched for (target minus the bias)
        while len(kept) < req.count:
            near = sorted((c for c in measured if c.replicate not in tried and
                           abs(c.value - aim.target) <= PROPOSE_SHARE * req.tolerance),
                          key=lambda c: (abs(c.value - aim.target), c.replicate))
            if near:
                if flown >= budget:
                    raise ConfigError("success", f"only {len(kept)} of {req.count} maps of family {req.family!r} "
                                      f"flew within {req.tolerance:g} of reference success {req.target:g} after "
                                      f"{flown} flown candidates (predicted range {lo:.2f} to {hi:.2f}); widen "
                                      "`tolerance` or move the target", req.target, show_value=False)
                batch = near[:min(FLY_ROUND, req.count - len(kept), budget - flown)]
                tried.update(c.replicate for c in batch)
                res = calibrate(scenario_document(req, batch), workers=workers)
                by_index = {r.map_index: r for r in res}
                flown += len(batch)
                for i, c in enumerate(batch):
                    r = by_index[i]
                    c.extra = {MEASURED: r.success, f"{MEASURED}_lo": r.success_ci[0],
                               f"{MEASURED}_hi": r.success_ci[1]}
                    if abs(r.success - req.target) <= req.tolerance and len(kept) < req.count:
                        kept.append(c)
                    k = r.success * r.trials
                    residuals.append(_logit((k + 0.5) / (r.trials + 1.0)) - _logit(c.value))
                bias = float(np.clip(sum(residuals) / (len(residuals) + BIAS_PRIOR), -2.0, 2.0))
                aim = replace(req, target=float(_sigmoid(_logit(req.target) - bias)))
                beta = fit_linear(measured, aim.target, scale)
                shown.update(len(kept), flown)
                continue
            if len(measured) >= MAX_CANDIDATES_PER_MAP * req.count + pilot_size:
                raise ConfigError("success", f"the predictor proposed too few maps of family {req.family!r} near "
                                  f"reference success {req.target:g} after {len(measured)} candidates (predicted "
                                  f"range {lo:.2f} to {hi:.2f}); widen `tolerance`", req.target, show_value=False)
            _, beta, spread = _round(aim, beta, rng, next_rep, spread, measurer, measured, scale,
                                     PROPOSE_SHARE * req.tolerance)
    wall = time.perf_counter() - t0
    return GeneratedMaps(tuple(kept), scenario_document(req, kept), len(measured), (lo, hi),
                         tuple(float(x) for x in fit_linear(measured)), wall, flown)


def _logit(p: float) -> float:
    p = min(max(float(p), 1e-6), 1.0 - 1e-6)
    return math.log(p / (1.0 - p))


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


def _box_text(req: MetricTarget) -> str:
    parts = []
    for key, unit in (("count", ""), ("radius", " m"), ("speed", " m/s")):
        if key in req.fixed:
            parts.append(f"{key} {req.fixed[key]:g}{unit}")
        else:
            lo, hi = req.bounds[key]
            parts.append(f"{key} {lo:g}-{hi:g}{unit}")
    return ", ".join(parts)


class _Progress:
    """A progress line on stderr when it is a terminal: maps kept, candidates measured, seconds per kept map."""

    def __init__(self, total: int, enabled: bool, what: str = "candidates"):
        self.total, self.enabled, self.what = total, enabled and sys.stderr.isatty(), what
        self.t0 = time.perf_counter()

    def update(self, kept: int, tried: int) -> None:
        if self.enabled:
            dt = time.perf_counter() - self.t0
            per = f", {dt / kept:.2f} s per map" if kept else ""
            sys.stderr.write(f"\rpbdyn generate: {kept}/{self.total} maps, {tried} {self.what}{per}   ")
            sys.stderr.flush()

    def __enter__(self) -> "_Progress":
        return self

    def __exit__(self, *_) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


@contextlib.contextmanager
def stop_on_signals_cleanly(out) -> Iterator[None]:
    """The block of `pbdyn generate` (the search and the writing of ``out``) under SIGTERM and SIGINT: the first
    one raises BatchInterrupted (exit status 143 / 130 on the command line) saying that ``out`` was not written;
    the workers are ended on the way out (_Measurer.close) and ``out`` is written atomically, so nothing partial
    is left (pbdyn.experiments.signals)."""
    from pbdyn.experiments.signals import BatchInterrupted, stop_on_signals

    with stop_on_signals():
        try:
            yield
        except BatchInterrupted as exc:
            what = f"{Path(out).name} not written" if out is not None else "no maps returned"
            raise BatchInterrupted(exc.signum, f"generate stopped by {signal.Signals(exc.signum).name}: "
                                   f"{what}") from None


def write_scenario(path: str | Path, doc: dict, header: str = "") -> Path:
    """Write a scenario document as TOML (atomically, the user's umask), after checking that it loads."""
    import tomli_w

    from pbdyn.files import atomic_write_text

    parse_scenario(doc)
    return atomic_write_text(path, "".join(f"# {line}\n" for line in header.splitlines()) + tomli_w.dumps(doc))
