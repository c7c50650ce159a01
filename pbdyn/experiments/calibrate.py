"""`pbdyn calibrate`: a map's measured difficulty on the anchored scale (pbdyn.analysis.scale).

The reference panel flies the map's reference tasks at the panel speeds (pbdyn.analysis.scale.reference_document)
through the batch runner into a results store (resumable: an interrupted calibration continues where it stopped;
the default store lives in the cache, keyed by what is flown), then each map gets

- its measured reference success: the share of the panel's trials that succeeded, with a 95% interval from
  resampling its reference tasks (BOOTSTRAP resamples; a task's trials by the different respondents stay together);
- its difficulty in logits on the anchored scale: the maximum-likelihood b with the shipped abilities held fixed
  (difficulty_given_abilities), with the interval from the same resamples, and its percentile among the
  calibration set's maps.

A store's trials are read only where they are the panel's (its labels at the panel speeds); a map of a world whose
code changed refuses to extend the store like any batch (pbdyn.experiments.runner).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbdyn.analysis.scale import (ANCHORS_FILE, BOOTSTRAP, PANEL, PANEL_SPEEDS, SCALE_VERSION,
                                  ability_given_difficulties, difficulty_given_abilities, reference_document,
                                  respondent, sigmoid)
from pbdyn.config import Scenario, canonical_json, parse_scenario
from pbdyn.errors import ConfigError

RESPONDENTS = tuple(respondent(e.label, v) for e in PANEL for v in PANEL_SPEEDS)
"""The panel's respondents, in a fixed order."""


@dataclass(frozen=True)
class Anchors:
    """The shipped calibration: ``abilities`` (respondent -> logits), the calibration maps' ``difficulties`` per
    dims ({2: [...], 3: [...]}, logits; for percentiles), its version and where it came from (``source``);
    ``code``: the code fingerprints the calibration was flown with (panel label -> [fingerprints]; {} for anchors
    fitted before pbdyn recorded code identities)."""

    version: str
    abilities: dict
    difficulties: dict = field(default_factory=dict)
    source: str = ""
    code: dict = field(default_factory=dict)

    def code_status(self) -> str:
        """Whether this pbdyn flies the calibration's code (docs/design.md "Code identity"): "same" when every
        panel pair's fingerprint now is the one recorded, "other" when one differs, "not recorded"."""
        from pbdyn.planning.registry import pair_fingerprint

        if not self.code:
            return "not recorded"
        for label, fps in self.code.items():
            gaze, _, traj = label.partition("+")
            if list(fps) != [pair_fingerprint(traj, gaze)]:
                return "other"
        return "same"

    def theta(self) -> np.ndarray:
        """The abilities in RESPONDENTS order."""
        return np.array([self.abilities[r] for r in RESPONDENTS])

    def percentile(self, b: float, dims: int) -> float | None:
        """The share (%) of the ``dims``-D calibration maps easier than difficulty ``b`` (None: no such set)."""
        ref = self.difficulties.get(str(dims)) or self.difficulties.get(dims)
        if not ref:
            return None
        ref = np.asarray(ref, float)
        return float(100.0 * (np.sum(ref < b) + 0.5 * np.sum(ref == b)) / ref.size)

    def success(self, b: float) -> float:
        """The panel's expected success on a map of difficulty ``b`` (mean over the respondents)."""
        return float(np.mean(sigmoid(self.theta() - b)))


def load_anchors(path: str | Path | None = None) -> Anchors | None:
    """The anchors shipped with pbdyn (pbdyn/analysis/data/anchors.json) or at ``path``; None if there are none."""
    p = Path(path) if path is not None else Path(__file__).resolve().parent.parent / "analysis" / "data" / ANCHORS_FILE
    if not p.is_file():
        return None
    doc = json.loads(p.read_text())
    missing = [r for r in RESPONDENTS if r not in doc.get("abilities", {})]
    if missing:
        raise ConfigError("anchors", f"lacks the abilities of {', '.join(missing)}", str(p))
    return Anchors(str(doc["version"]), {k: float(v) for k, v in doc["abilities"].items()},
                   doc.get("difficulties", {}), doc.get("source", ""), dict(doc.get("code") or {}))


@dataclass(frozen=True)
class MapDifficulty:
    """One map's measured difficulty: identity, the panel's trials and reference tasks, the measured reference
    success with its 95% interval, and (when the scale is anchored) the difficulty in logits with its interval
    and percentile among the calibration maps of its dims; ``scale``: SCALE_VERSION/anchors version."""

    map_index: int
    map_id: str
    setup: dict
    trials: int
    tasks: int
    success: float
    success_ci: tuple
    difficulty: float | None
    difficulty_ci: tuple | None
    percentile: float | None
    scale: str

    def to_dict(self) -> dict:
        """JSON-able form."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


# ------------------------------------------------------------------------------------------------ flying
def reference_scenario(scenario, maps=None) -> tuple[Scenario, dict[str, int]]:
    """(the scenario that flies the reference panel on ``scenario``'s maps -- all, or the indices ``maps`` --, map
    id -> the map's index in ``scenario``): its document with the panel, the panel speeds and the reference pairs
    (pbdyn.analysis.scale.reference_document); chosen maps become an explicit map list (the same maps). Relative
    paths resolve against the original file."""
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps

    sc = scenario if isinstance(scenario, Scenario) else parse_scenario(scenario) if isinstance(scenario, dict) \
        else load_scenario(scenario) if isinstance(scenario, (str, Path)) else None
    if isinstance(scenario, (str, Path)) and not isinstance(scenario, Scenario):
        from pbdyn import resources

        doc = tomllib.loads(resources.find_scenario(scenario).read_text(encoding="utf-8"))
    elif isinstance(scenario, dict):
        doc = dict(scenario)
    elif isinstance(scenario, Scenario):
        doc = {"name": scenario.name, **scenario.to_dict()}
    else:
        raise ConfigError("scenario", "must be a path, a bundled scenario name or a dict shaped like the TOML file",
                          scenario)
    all_maps = enumerate_maps(sc)
    index = {m.map_id: m.index for m in (all_maps if maps is None else [])}
    if maps is not None:
        chosen = []
        for m in maps:
            if isinstance(m, bool) or not isinstance(m, int) or not 0 <= m < len(all_maps):
                raise ConfigError("map", f"must be a map index in [0, {len(all_maps) - 1}]", m)
            if m not in chosen:
                chosen.append(m)
                index[all_maps[m].map_id] = m
        if not sc.is_world:
            obst = {k: v for k, v in doc.get("obstacles", {}).items()
                    if k not in ("count", "radius", "speed", "maps_per_setup", "structure", "maps")}
            obst["maps"] = [{**_setup_entry(all_maps[m].setup), "replicate": all_maps[m].replicate} for m in chosen]
            doc = {**doc, "obstacles": obst}
    ref = reference_document(doc, sc.task.candidates)
    ref["name"] = f"{sc.name}_reference"
    return parse_scenario(ref, sc.source), index


def _setup_entry(setup: dict) -> dict:
    return {k: v for k, v in setup.items() if k in ("count", "radius", "speed", "structure")}


def default_store(ref: Scenario) -> Path:
    """Where a calibration is kept unless told: <cache>/calibration/<name>-<hash of what is flown and the code that
    flies it>.sqlite (an edit of pbdyn's code starts another store; reverting it finds the old one)."""
    from pbdyn.planning.registry import pair_fingerprint
    from pbdyn.world.rollout import cache_dir, world_description

    code = [pair_fingerprint(e.trajectory, e.gaze) for e in ref.planners] + [world_description(ref)]
    digest = hashlib.sha256(canonical_json({"scenario": ref.to_dict(), "code": code}).encode()).hexdigest()[:16]
    return cache_dir() / "calibration" / f"{ref.name}-{digest}.sqlite"


def calibrate(scenario, *, maps=None, store=None, workers=None, progress: bool = False,
              anchors: Anchors | None = None, n_boot: int = BOOTSTRAP, seed: int = 0) -> list[MapDifficulty]:
    """Fly the reference panel on the maps (resuming a store that holds part of it) and return each map's measured
    difficulty (module doc). ``store``: the results store (default: default_store); ``anchors``: default the
    shipped ones."""
    from pbdyn.experiments.runner import BatchOptions, run_batch

    ref, index = reference_scenario(scenario, maps)
    path = Path(store) if store is not None else default_store(ref)
    run_batch(ref, path, BatchOptions(workers=workers, metrics=False, progress=progress))
    res = measure_store(path, anchors=load_anchors() if anchors is None else anchors, n_boot=n_boot, seed=seed,
                        dims=ref.world.dims, index=index)
    return [r for r in res if r.map_id in index]


# ------------------------------------------------------------------------------------------------ measuring
def panel_counts(rows: list[dict]) -> dict[str, dict]:
    """map_id -> {"index", "setup", "tasks": [(start, goal)], "success": [T, J] 0/1 counts, "trials": [T, J]}
    from result rows, keeping only the panel's trials (RESPONDENTS); error rows are refused (a calibration with
    failed trials is not a measurement)."""
    col = {r: j for j, r in enumerate(RESPONDENTS)}
    per: dict[str, dict] = {}
    for r in rows:
        name = respondent(r.get("planner_label") or "", r.get("mav_speed") or 0.0)
        if name not in col:
            continue
        if r.get("outcome") == "error":
            raise ConfigError("RESULTS", f"holds an error row of the panel on map {r.get('map_index')} ({name}: "
                              f"{r.get('reason')}); re-fly it (pbdyn batch --retry-errors)", r.get("trial_key"),
                              show_value=False)
        m = per.setdefault(r["map_id"], {"index": r.get("map_index"), "setup": {"count": r.get("obstacle_count"),
                                                                                 "radius": r.get("obstacle_radius"),
                                                                                 "speed": r.get("obstacle_speed")},
                                         "tasks": {}})
        task = (tuple(r["start"]), tuple(r["goal"]))
        cell = m["tasks"].setdefault(task, np.zeros((2, len(RESPONDENTS))))
        cell[0, col[name]] += r.get("outcome") == "success"
        cell[1, col[name]] += 1
    out = {}
    for mid, m in per.items():
        tasks = sorted(m["tasks"])
        arr = np.stack([m["tasks"][t] for t in tasks])                  # [T, 2, J]
        out[mid] = {"index": m["index"], "setup": m["setup"], "tasks": tasks, "success": arr[:, 0, :],
                    "trials": arr[:, 1, :]}
    return out


def measure(counts: dict, anchors: Anchors | None, *, n_boot: int = BOOTSTRAP, seed: int = 0,
            dims: int = 2) -> list[MapDifficulty]:
    """Each map's measured difficulty (module doc) from panel_counts(); resamples drawn from
    numpy.random.default_rng([seed, stable hash of the map id]), so a map's interval depends neither on the other
    maps nor on the store it was read from."""
    from pbdyn.world.maps import stable_hash64

    out = []
    theta = anchors.theta() if anchors is not None else None
    for mid, m in sorted(counts.items(), key=lambda kv: (kv[1]["index"] if kv[1]["index"] is not None else -1,
                                                         kv[0])):
        s, n = m["success"], m["trials"]
        t = s.shape[0]
        rng = np.random.default_rng([seed, stable_hash64(mid)])
        w = rng.multinomial(t, np.full(t, 1.0 / t), size=n_boot).astype(float)   # [B, T]
        ks, ns = w @ s, w @ n                                                      # [B, J]
        rate = ks.sum(axis=1) / ns.sum(axis=1)
        success = float(s.sum() / n.sum())
        ci = (float(np.quantile(rate, 0.025)), float(np.quantile(rate, 0.975)))
        b = b_ci = pct = None
        if theta is not None:
            if not np.all(n.sum(axis=0) > 0):
                missing = [RESPONDENTS[j] for j in np.flatnonzero(n.sum(axis=0) == 0)]
                raise ConfigError("RESULTS", f"map {m['index']} lacks the panel's trials of {', '.join(missing)}",
                                  mid, show_value=False)
            b = difficulty_given_abilities(theta, s.sum(axis=0), n.sum(axis=0))
            bb = difficulty_given_abilities(theta, ks, ns)
            b_ci = (float(np.quantile(bb, 0.025)), float(np.quantile(bb, 0.975)))
            pct = anchors.percentile(b, dims)
        scale = f"anchored-{SCALE_VERSION}/{anchors.version}" if anchors is not None else "unanchored"
        out.append(MapDifficulty(int(m["index"]) if m["index"] is not None else -1, mid, m["setup"], int(n.sum()), t,
                                 success, ci, b, b_ci, pct, scale))
    return out


def measure_store(path, *, anchors: Anchors | None, n_boot: int = BOOTSTRAP, seed: int = 0,
                  dims: int | None = None, index: dict | None = None) -> list[MapDifficulty]:
    """measure() of the panel's trials in the results store ``path``; ``index``: map id -> the map index to report
    (default: the store's)."""
    from pbdyn.experiments.store import ResultsStore

    st = ResultsStore.open(path)
    try:
        rows = st.results()
        doc = json.loads(st.get_meta("scenario") or "{}")
    finally:
        st.close()
    counts = panel_counts(rows)
    for mid, m in counts.items():
        if index and mid in index:
            m["index"] = index[mid]
    if not counts:
        raise ConfigError("RESULTS", "holds no trial of the reference panel", str(path))
    return measure(counts, anchors, n_boot=n_boot, seed=seed,
                   dims=dims or int(doc.get("world", {}).get("dims", 2)))


def format_difficulties(res: list[MapDifficulty]) -> str:
    """A table: one line per map."""
    lines = []
    for r in res:
        head = f"map {r.map_index} ({r.map_id}): reference success {r.success:.2f} [{r.success_ci[0]:.2f}, " \
               f"{r.success_ci[1]:.2f}] ({r.trials} trials, {r.tasks} tasks)"
        if r.difficulty is not None:
            pct = f", percentile {r.percentile:.0f} of the calibration set" if r.percentile is not None else ""
            head += f"; difficulty {r.difficulty:+.2f} logits [{r.difficulty_ci[0]:+.2f}, " \
                    f"{r.difficulty_ci[1]:+.2f}]{pct} (scale {r.scale})"
        else:
            head += "; no anchored scale is shipped with this pbdyn (reference success only)"
        lines.append(head)
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ evaluate
def place_on_scale(trials: list[dict], anchors: Anchors | None, dims: dict | None = None) -> dict:
    """The anchored section of `pbdyn evaluate`: per dataset (store), its maps' difficulties estimated from the
    panel respondents it holds (their shipped abilities fixed) and every respondent's ability given those
    difficulties (logits, standard errors from the likelihood's curvature), or why it cannot be placed (no panel
    pair at a panel speed). ``trials``: pbdyn.experiments.evaluate.load_results rows (map_id, pair, mav_speed,
    outcome, dataset); ``dims``: dataset -> dims (for percentiles). Stores placed are on one scale: linked through
    the fixed abilities, never re-centred."""
    if anchors is None:
        return {"anchored": False, "why": "no anchored scale is shipped with this pbdyn"}
    theta = dict(anchors.abilities)
    out = {"anchored": True, "scale": f"anchored-{SCALE_VERSION}/{anchors.version}", "datasets": {}}
    by_set: dict[str, list[dict]] = {}
    for t in trials:
        by_set.setdefault(t["dataset"], []).append(t)
    for name, rows in by_set.items():
        cells: dict[tuple, list[int]] = {}
        for t in rows:
            c = cells.setdefault((t["map_id"], respondent(t.get("pair") or "", t.get("mav_speed") or 0.0)), [0, 0])
            c[0] += t.get("outcome") == "success"
            c[1] += 1
        panel = sorted({r for (_, r) in cells if r in theta})
        if not panel:
            out["datasets"][name] = {"placed": False, "why": "no trial of a panel pair (" + ", ".join(
                e.label for e in PANEL) + ") at a panel speed (" + "/".join(f"{v:g}" for v in PANEL_SPEEDS) +
                " m/s): its maps and planners cannot be placed on the anchored scale"}
            continue
        maps = sorted({m for (m, _) in cells})
        diff, se = {}, {}
        for m in maps:
            got = [(theta[r], *cells[(m, r)]) for r in panel if (m, r) in cells]
            if not got:
                continue
            th, k, n = (np.array(x, float) for x in zip(*got))
            b = difficulty_given_abilities(th, k, n)
            p = sigmoid(th - b)
            diff[m], se[m] = b, float(1.0 / np.sqrt(np.sum(n * p * (1 - p)) + 1e-12))
        abil = {}
        for r in sorted({r for (_, r) in cells}):
            got = [(diff[m], *cells[(m, r)]) for m in maps if (m, r) in cells and m in diff]
            if not got:
                continue
            b, k, n = (np.array(x, float) for x in zip(*got))
            a = ability_given_difficulties(b, k, n)
            p = sigmoid(a - b)
            abil[r] = {"ability": a, "se": float(1.0 / np.sqrt(np.sum(n * p * (1 - p)) + 1e-12)),
                       "anchor": theta.get(r), "trials": int(n.sum())}
        vals = np.array(list(diff.values()))
        d = (dims or {}).get(name, 2)
        out["datasets"][name] = {
            "placed": True, "panel_respondents": panel, "maps_placed": len(diff), "maps": len(maps),
            "difficulty": {m: {"logit": diff[m], "se": se[m], "percentile": anchors.percentile(diff[m], d)}
                           for m in diff},
            "difficulty_mean": float(vals.mean()), "difficulty_range": [float(vals.min()), float(vals.max())],
            "abilities": abil}
    placed = [n for n, v in out["datasets"].items() if v["placed"]]
    out["one_scale"] = placed
    return out


def format_scale(section: dict) -> str:
    """The anchored section as text lines."""
    if not section.get("anchored"):
        return f"Anchored scale: {section.get('why')}.\n"
    lines = [f"Anchored scale ({section['scale']}; zero = mean difficulty of the 2D calibration maps, unit = 1 "
             "logit; higher = harder). Placed on it (one scale): " + (", ".join(section["one_scale"]) or "none")]
    for name, d in section["datasets"].items():
        if not d["placed"]:
            lines.append(f"  {name}: {d['why']}")
            continue
        lo, hi = d["difficulty_range"]
        lines.append(f"  {name}: {d['maps_placed']} of {d['maps']} maps placed by {len(d['panel_respondents'])} panel "
                     f"respondent(s); difficulty mean {d['difficulty_mean']:+.2f} logits (range {lo:+.2f} to "
                     f"{hi:+.2f})")
        for r, a in d["abilities"].items():
            anchor = f" (anchor {a['anchor']:+.2f})" if a["anchor"] is not None else ""
            lines.append(f"    ability {r:<36} {a['ability']:+.2f} +- {a['se']:.2f}{anchor}  ({a['trials']} trials)")
    return "\n".join(lines) + "\n"
