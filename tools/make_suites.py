"""Build the frozen benchmark suites and their reference results (docs/benchmark.md "How the suites were built").

Three steps, each a sub-command:

  draft NAME     choose the suite's maps from the calibration sets (pbdyn/analysis/data/calibration_*.csv.gz: the
                 reference panel's flights of every calibration map) and extra generated maps (--extra FILE: scenario
                 files written by `pbdyn generate --success` or `measured`), imported worlds (the bundled 2D set, and
                 --world FILE: measured by `pbdyn calibrate`), levelled by the panel's success (level_of of
                 pbdyn.benchmark.levels), MAPS_PER_LEVEL maps per level, families mixed (choose()); writes
                 scenarios/suites/NAME/ with the manifest (no measured difficulty yet) and the generated maps' part.
  fly NAME DIR   fly every built-in trajectory planner (with its thesis gaze) on the draft into DIR/<planner>/
                 (the bench runner's flights; resumable).
  freeze NAME DIR  measure every map's difficulty from the reference panel's flights in DIR on exactly the suite's
                 tasks (pbdyn.analysis.scale.measure_difficulties: the numbers `pbdyn calibrate` gives), assign the
                 levels, write the final manifest and the reference results (reference.json.gz) with the suite's hash.

Hard maps beyond the calibration sets' range (the 3D sets reach reference success 0.54 only) come from a pool:

  pool FILE --dims D   write a pool scenario of POOL_MAPS maps per generator family (walls aside) with (n, r, v)
                 from a seeded Latin hypercube over POOL_BOX (denser, larger obstacles than the calibration box),
                 whose experiment is the reference panel's flights (as the calibration sets');
  measured FILE STORE OUT  after `pbdyn batch FILE --store STORE`, write OUT: FILE's maps with each map's measured
                 reference success (the panel's share of successes on its reference tasks), an --extra for draft.

The v2 suites choose and level their maps on held-out tasks (docs/benchmark.md "Levels"):

  candidates FOLDER --dims D [--extra FILE] [--world NAME] [--exclude SUITE]  a draft suite of every candidate map
                 (the calibration set, every map of each extra file, each imported world; less the maps of the
                 excluded suites, whose held-out flights exist), not bundled;
  fly-heldout NAME DIR   fly the reference panel on the held-out tasks of a suite's maps (the start/goal candidates
                 the suite's tasks leave out) into DIR/heldout/<planner>/;
  draft-v2 NAME --candidates C --heldout H ...   level every candidate by the panel's held-out success and choose
                 MAPS_PER_LEVEL maps per level (choose()); the suite's tasks are the candidates';
  fly NAME DIR, then freeze NAME DIR --heldout H ...   the references on the suite's tasks; the level and the
                 difficulty from the held-out flights (plus one link offset common to every map);
  bias NAME HELDOUT   measure a v1 suite's selection bias: per level, the panel on the suite's tasks against the
                 held-out ones.

The mini suite is drafted from a full suite (draft-mini NAME FROM): MINI_LEVELS' first map of each of those
levels that is neither a walls map nor an imported world, MINI_PAIRS pairs, at MINI_SPEED only.
"""

from __future__ import annotations

import argparse
import copy
import gzip
import json
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbdyn.benchmark.levels import LEVEL_EDGES, level_of, level_ranges  # noqa: E402

DATA = ROOT / "pbdyn" / "analysis" / "data"
SUITES = ROOT / "scenarios" / "suites"
MAPS_PER_LEVEL = 4
MINI_LEVELS = (1, 4, 7, 9)
MINI_PAIRS = 3
MINI_SPEED = 4.0
CALIBRATION = {2: ("calibration_2d", "scenarios/calibration/calibration_2d.toml", "worlds/imported_2d"),
               3: ("calibration_3d", "scenarios/calibration/calibration_3d.toml", None)}


POOL_MAPS = 6
POOL_SEED = 2027
POOL_BOX = {"count": (30, 160), "radius": (0.8, 2.0), "speed": (2.5, 6.0)}
"""The pool's (n, r, v) box: up to ~25x the flux of the thesis' box, where 3D maps get hard."""


def choose(candidates: list[dict], k: int, used: dict) -> list[dict]:
    """Up to ``k`` candidates of one level: at most one per kind (generator family or world family) while other
    kinds remain, the kinds the suite has used least so far (``used``: kind -> count, updated) first, then the map
    whose success lies nearest the level's centre; then the nearest of the rest."""
    if not candidates:
        return []
    lv = candidates[0]["level"]
    centre = 0.5 * (LEVEL_EDGES[lv - 1] + LEVEL_EDGES[lv])
    near = sorted(candidates, key=lambda c: (abs(c["success"] - centre), c["key"]))
    best = {}
    for c in near:
        best.setdefault(c["kind"], c)
    firsts = sorted(best.values(), key=lambda c: (used.get(c["kind"], 0), abs(c["success"] - centre), c["key"]))
    chosen = firsts[:k]
    for c in near:
        if len(chosen) < k and c not in chosen:
            chosen.append(c)
    for c in chosen:
        used[c["kind"]] = used.get(c["kind"], 0) + 1
    return sorted(chosen, key=lambda c: c["key"])


def _success_per_map(path: Path) -> dict:
    import pandas as pd

    d = pd.read_csv(path)
    return {str(k): float(v) for k, v in d.groupby("map_id").success.mean().items()}


def _world_candidates(worlds: list[Path]) -> list[dict]:
    """Imported worlds given by file (--world): each world's map 0 with its reference success as `pbdyn calibrate`
    measures it (the panel's flights in calibrate's default store: flown once, then read)."""
    from pbdyn.api import calibrate

    out = []
    for path in worlds:
        path = path.resolve()
        rel = path.relative_to(ROOT / "scenarios").with_suffix("").as_posix()
        m = calibrate(path, maps=[0], workers=2, progress=True)[0]
        out.append({"key": f"world/{path.stem}", "kind": "world:" + path.stem.rstrip("_0123456789"),
                    "success": m.success, "part": path.stem, "map_id": m.map_id, "scenario": rel})
    return out


def _candidates(dims: int, extra: list[Path], world_files: list[Path] = ()) -> tuple[list[dict], dict, dict]:
    """Every candidate map (key, kind, success, part, map id), the generated maps' TOML entries by key, and each
    generated part's base document (world, root seed): the calibration maps make part "generated", each --extra file
    a part of its own ("extra<i>"; its maps' seeds follow its root seed)."""
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps

    name, scen, worlds = CALIBRATION[dims]
    out, entries, bases = [], {}, {}
    cal = load_scenario(ROOT / scen)
    doc = tomllib.loads((ROOT / scen).read_text())
    bases["generated"] = {"world": doc["world"], "root_seed": doc["obstacles"]["root_seed"]}
    success = _success_per_map(DATA / f"calibration_{dims}d.csv.gz")
    for m, entry in zip(enumerate_maps(cal), doc["obstacles"]["maps"]):
        if m.map_id in success:
            key = f"gen/{m.map_id}"
            out.append({"key": key, "kind": entry["structure"], "success": success[m.map_id], "part": "generated",
                        "map_id": m.map_id})
            entries[key] = entry
    for i, path in enumerate(extra):
        sc = load_scenario(path)
        edoc = tomllib.loads(path.read_text())
        part = f"extra{i + 1}"
        bases[part] = {"world": edoc["world"], "root_seed": edoc["obstacles"]["root_seed"]}
        for m, entry in zip(enumerate_maps(sc), edoc["obstacles"]["maps"]):
            s = (entry.get("measured") or {}).get("reference_success")
            if s is None:
                raise SystemExit(f"{path}: map {m.index} records no reference success")
            key = f"{part}/{m.map_id}"
            out.append({"key": key, "kind": entry.get("structure", "uniform"), "success": float(s), "part": part,
                        "map_id": m.map_id})
            entries[key] = {k: entry[k] for k in ("count", "radius", "speed", "structure", "replicate", "seed")
                            if k in entry}
    if worlds is not None:
        ws = _success_per_map(DATA / "calibration_worlds.csv.gz")
        for mid, s in sorted(ws.items()):
            world, map_id = mid.split("/")
            out.append({"key": f"world/{world}", "kind": "world:" + world.rstrip("_0123456789"), "success": s,
                        "part": world, "map_id": map_id, "scenario": f"{worlds}/{world}"})
    out += _world_candidates(list(world_files))
    for c in out:
        c["level"] = level_of(c["success"])
    return out, entries, bases


def draft(name: str, dims: int, extra: list[Path], worlds: list[Path] = ()) -> Path:
    """Write the draft suite NAME (module doc; ``worlds``: imported world files beside the bundled 2D set)."""
    from pbdyn.analysis.scale import PANEL_SPEEDS
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps

    cands, entries, bases = _candidates(dims, extra, worlds)
    chosen, used = [], {}
    for lv in range(1, len(LEVEL_EDGES)):
        chosen += choose([c for c in cands if c["level"] == lv], MAPS_PER_LEVEL, used)
    folder = SUITES / name
    folder.mkdir(parents=True, exist_ok=True)
    parts, index = [], {}
    for part, base in bases.items():
        gen = [c for c in chosen if c["part"] == part]
        if not gen:
            continue
        gen_doc = {"name": f"{name}.{part}", "world": base["world"], "obstacles": {
            "root_seed": base["root_seed"], "maps": [entries[c["key"]] for c in gen]}}
        part_file = folder / f"{part}.toml"
        part_file.write_text(_toml(gen_doc, f"pbdyn benchmark suite {name}: generated maps, written by "
                                            "tools/make_suites.py; do not edit by hand (the suite's hash covers it)."))
        ids = [m.map_id for m in enumerate_maps(load_scenario(part_file))]
        if ids != [c["map_id"] for c in gen]:
            raise SystemExit(f"{part_file}: its map ids differ from the source maps' (world settings differ?)")
        index.update({(part, mid): i for i, mid in enumerate(ids)})
        parts.append({"name": part, "scenario": part_file.name})
    parts += [{"name": c["part"], "scenario": c["scenario"]} for c in chosen if "scenario" in c]
    maps = [{"part": c["part"], "map_index": index.get((c["part"], c["map_id"]), 0), "map_id": c["map_id"],
             "family": c["kind"], "level": None, "calibration_success": round(c["success"], 6), "difficulty": None}
            for c in chosen]
    manifest = {"format": "pbdyn-suite/1", "name": name, "version": "1", "dims": dims,
                "speeds": list(PANEL_SPEEDS), "levels": level_ranges(), "parts": parts,
                "maps": sorted(maps, key=lambda m: (m["part"], m["map_index"]))}
    (folder / "suite.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return folder


def draft_mini(name: str, source: str) -> Path:
    """Write the draft mini suite NAME from the (draft or frozen) suite ``source`` (module doc; levels by the maps'
    calibration success)."""
    from pbdyn.benchmark.suite import load_suite

    src = load_suite(source)
    picked = []
    for lv in MINI_LEVELS:
        ok = [m for m in src.maps if level_of(m["calibration_success"]) == lv and m["part"] == "generated"
              and m["family"] != "walls"]
        if ok:
            picked.append(ok[0])
    folder = SUITES / name
    folder.mkdir(parents=True, exist_ok=True)
    part = src.part("generated")
    doc = copy.deepcopy(part.doc)
    doc["name"] = f"{name}.generated"
    doc["obstacles"]["maps"] = [part.doc["obstacles"]["maps"][m["map_index"]] for m in picked]
    (folder / "generated.toml").write_text(_toml(doc, f"pbdyn benchmark suite {name} (a smoke-test cut of "
                                                      f"{source}), written by tools/make_suites.py; do not edit."))
    maps = [{**{k: v for k, v in m.items() if k not in ("difficulty", "difficulty_ci95", "reference_success",
                                                       "reference_success_ci95", "level", "tasks")},
             "map_index": i, "level": None, "difficulty": None} for i, m in enumerate(picked)]
    pairs = [list(part.pairs[i * len(part.pairs) // MINI_PAIRS]) for i in range(MINI_PAIRS)]   # spread over the starts
    manifest = {"format": "pbdyn-suite/1", "name": name, "version": "1", "dims": src.dims, "speeds": [MINI_SPEED],
                "levels": level_ranges(), "parts": [{"name": "generated", "scenario": "generated.toml",
                                                   "pairs_flown": pairs}], "maps": maps,
                "cut_from": src.name}
    (folder / "suite.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return folder


def pool(path: Path, dims: int) -> Path:
    """Write the pool scenario ``path`` (module doc): POOL_MAPS maps per non-walls family, (n, r, v) from a seeded
    Latin hypercube over POOL_BOX, in the calibration set's world, explicit seeds, the panel's flights."""
    import numpy as np

    from pbdyn.analysis.scale import reference_document
    from pbdyn.config import BUILTIN_STRUCTURES, parse_scenario
    from pbdyn.world.maps import enumerate_maps

    base_doc = tomllib.loads((ROOT / CALIBRATION[dims][1]).read_text())
    maps = []
    for f, family in enumerate(s for s in BUILTIN_STRUCTURES if s != "walls"):
        rng = np.random.default_rng([POOL_SEED, dims, f])
        pts = {}
        for key, (lo, hi) in POOL_BOX.items():
            u = (rng.permutation(POOL_MAPS) + rng.uniform(size=POOL_MAPS)) / POOL_MAPS
            vals = lo + u * (hi - lo)
            pts[key] = [int(round(x)) for x in vals] if key == "count" else [round(float(x), 2) for x in vals]
        maps += [{"count": pts["count"][k], "radius": pts["radius"][k], "speed": pts["speed"][k],
                  "structure": family, "replicate": k} for k in range(POOL_MAPS)]
    base = {"name": f"pool_{dims}d", "world": base_doc["world"], "obstacles": {"root_seed": POOL_SEED, "maps": maps}}
    doc = reference_document(base, parse_scenario(base).task.candidates)
    for entry, spec in zip(doc["obstacles"]["maps"], enumerate_maps(parse_scenario(doc))):
        entry["seed"] = spec.seed
    path.write_text(_toml(doc, f"pbdyn benchmark pool {dims}D, written by tools/make_suites.py pool: hard "
                               "candidate maps for the suites' upper levels; the experiment is the panel's flights."))
    return path


def measured(path: Path, store: Path, out: Path) -> Path:
    """Write ``out``: the pool ``path`` with every map's measured reference success from the panel's flights in
    ``store`` (module doc); a map the store does not hold in full stops the tool."""
    from pbdyn.config import load_scenario
    from pbdyn.analysis.scale import panel_counts
    from pbdyn.experiments.store import ResultsStore
    from pbdyn.world.maps import enumerate_maps

    st = ResultsStore.open(store)
    try:
        rows = st.results()
    finally:
        st.close()
    counts = panel_counts(rows)
    doc = tomllib.loads(path.read_text())
    for spec, entry in zip(enumerate_maps(load_scenario(path)), doc["obstacles"]["maps"]):
        m = counts.get(spec.map_id)
        if m is None or int(m["trials"].sum()) != 180:
            raise SystemExit(f"{store}: map {spec.index} ({spec.map_id}) is not flown in full")
        entry["measured"] = {"reference_success": round(float(m["success"].sum() / m["trials"].sum()), 6)}
    out.write_text(_toml(doc, f"{path.name} with each map's measured reference success (tools/make_suites.py "
                              "measured)"))
    return out


def fly_references(name: str, out: Path, planners: list[str], workers: int) -> None:
    """Fly the built-in planners (or ``planners``) on suite NAME into out/<trajectory>/."""
    from pbdyn.benchmark.run import THESIS_GAZE, _check_marker, fly_suite, planner_entry
    from pbdyn.benchmark.suite import load_suite

    suite = load_suite(SUITES / name)
    for traj in planners or list(THESIS_GAZE):
        entry = planner_entry(traj)
        folder = out / traj
        _check_marker(folder, suite, entry)
        fly_suite(suite, entry, folder, workers=workers, progress=True, command=f"tools/make_suites.py fly {name}")


def heldout_pairs(candidates) -> list[tuple[int, int]]:
    """The held-out tasks of a map: every ordered (start, goal) pair of the candidates the reference pairs leave out
    (pbdyn.analysis.scale.reference_candidates; on the default 3 x 3 grid the four edge midpoints: 12 pairs, no
    start or goal in common with the suite's tasks). A map's level is measured on these (docs/benchmark.md)."""
    from pbdyn.analysis.scale import reference_candidates

    used = set(reference_candidates(candidates))
    rest = [i for i in range(len(candidates)) if i not in used]
    return [(i, j) for i in rest for j in rest if i != j]


def heldout_suite(suite):
    """``suite`` with every part's pairs replaced by its held-out pairs (the manifest's ``pairs_leveled``, else
    heldout_pairs of the part's candidates): the tasks its levels are measured on."""
    import dataclasses

    from pbdyn.config import parse_scenario

    parts = []
    for p in suite.parts:
        pairs = p.level_pairs or tuple(heldout_pairs(parse_scenario(p.doc, p.path).task.candidates))
        if len(pairs) < 2:
            raise SystemExit(f"{suite.name}: part {p.name} has too few candidates for held-out tasks")
        parts.append(dataclasses.replace(p, pairs=tuple(pairs)))
    return dataclasses.replace(suite, parts=tuple(parts))


LEVELS_FROM_TEXT = (
    "levels and difficulties were measured from the reference panel's flights ({panel}; at {speeds} m/s) on held-out "
    "tasks of each map: the ordered pairs of the start/goal candidates the suite's tasks leave out (on the default "
    "3 x 3 grid the four edge midpoints: 12 pairs, {per_map} tasks per map), which share no start or goal with the "
    "suite's tasks; the reference results a card compares against were flown separately on the suite's tasks "
    "(docs/benchmark.md#levels)")


MAP_KEYS = ("count", "radius", "speed", "structure", "replicate", "seed")
"""The keys of a generated map's entry a suite part keeps (its setup values, replicate and seed)."""


def candidate_suite(folder: Path, dims: int, extra: list[Path], worlds: list[str], exclude=()) -> Path:
    """Write a draft suite of every candidate map into ``folder`` (not a bundled suite; no levels): part "generated"
    = the calibration set's maps, "extra<i>" = every map of each ``extra`` scenario file (generated maps with
    explicit seeds: a pool, `pbdyn generate` output), and each imported world of ``worlds`` (bundled scenario names)
    as a part of its own, less the maps of the suites ``exclude`` (their held-out flights exist already: draft-v2
    takes several candidate suites). fly-heldout flies the panel on its held-out tasks; draft-v2 chooses from it."""
    from pbdyn.analysis.scale import PANEL_SPEEDS
    from pbdyn.config import load_scenario
    from pbdyn.world.maps import enumerate_maps

    from pbdyn.benchmark.suite import load_suite
    from pbdyn.config import parse_scenario

    skip = set()
    for name in exclude:
        ex = load_suite(SUITES / name if (SUITES / name).is_dir() else name)
        specs = {p.name: enumerate_maps(parse_scenario(p.doc, p.path)) for p in ex.parts}
        skip |= {specs[m["part"]][m["map_index"]].map_id for m in ex.maps}
    folder.mkdir(parents=True, exist_ok=True)
    sources = [("generated", ROOT / CALIBRATION[dims][1])] + [(f"extra{i + 1}", p) for i, p in enumerate(extra)]
    parts, maps = [], []
    for part, path in sources:
        src = tomllib.loads(path.read_text())
        ids = [m.map_id for m in enumerate_maps(load_scenario(path))]
        entries = [{k: e[k] for k in MAP_KEYS if k in e} for e, mid in zip(src["obstacles"]["maps"], ids)
                   if mid not in skip]
        if not entries:
            continue
        doc = {"name": f"{folder.name}.{part}", "world": src["world"], "obstacles": {
            "root_seed": src["obstacles"]["root_seed"], "maps": entries}}
        (folder / f"{part}.toml").write_text(_toml(doc, f"candidate maps ({path.name}), tools/make_suites.py"))
        specs = enumerate_maps(load_scenario(folder / f"{part}.toml"))
        if [m.map_id for m in specs] != [mid for mid in ids if mid not in skip]:
            raise SystemExit(f"{path}: its map ids change in a suite part (world settings or seeds differ?)")
        parts.append({"name": part, "scenario": f"{part}.toml"})
        maps += [{"part": part, "map_index": m.index, "map_id": m.map_id, "family": e.get("structure", "uniform"),
                  "level": None, "calibration_success": None, "difficulty": None}
                 for m, e in zip(specs, entries)]
    for w in worlds:
        sc = load_scenario(w)
        part = Path(w).name
        if enumerate_maps(sc)[0].map_id in skip:
            continue
        parts.append({"name": part, "scenario": w})
        maps.append({"part": part, "map_index": 0, "map_id": enumerate_maps(sc)[0].map_id,
                     "family": "world:" + part.rstrip("_0123456789"), "level": None, "calibration_success": None,
                     "difficulty": None})
    manifest = {"format": "pbdyn-suite/2", "name": folder.name, "version": "candidates", "dims": dims,
                "speeds": list(PANEL_SPEEDS), "levels": level_ranges(), "parts": parts, "maps": maps}
    (folder / "suite.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return folder


def draft_v2(name: str, candidates, heldout) -> Path:
    """Write the draft suite NAME, chosen and levelled on held-out tasks (docs/benchmark.md "Levels"): every map of
    the suite ``candidates`` (a candidate_suite folder, or any suite) gets its level from the panel's flights on
    its held-out tasks in ``heldout``/<trajectory>/ (fly-heldout), and each level takes up to MAPS_PER_LEVEL maps
    by the rule of choose(); the suite's tasks stay the candidates' (each part's pairs_flown, default the reference
    pairs), its maps are named by content ids and each part records its held-out pairs (``pairs_leveled``). No
    flight on the suite's own tasks enters the choice. ``candidates`` and ``heldout`` may be lists (pairwise: each
    candidate suite with its flights' folder; a part of one name is one part of the draft)."""
    from pbdyn.analysis.scale import PANEL, PANEL_SPEEDS
    from pbdyn.benchmark.suite import LEVELS_FROM, SUITE_FORMAT, load_suite
    from pbdyn.config import load_scenario, parse_scenario
    from pbdyn.world.maps import enumerate_maps

    sources = [load_suite(c) for c in (candidates if isinstance(candidates, (list, tuple)) else [candidates])]
    folders = heldout if isinstance(heldout, (list, tuple)) else [heldout]
    if len(folders) != len(sources):
        raise SystemExit("draft-v2: give one held-out folder per candidate suite")
    pool, seen = [], set()
    for cand, folder in zip(sources, folders):
        counts = _per_map_counts([r for rows in heldout_rows(cand, folder).values() for r in rows])
        specs = {p.name: enumerate_maps(parse_scenario(p.doc, p.path)) for p in cand.parts}
        for m in cand.maps:
            spec = specs[m["part"]][m["map_index"]]
            if spec.map_id in seen:
                continue
            seen.add(spec.map_id)
            k, n = counts[(m["part"], m["map_id"])]
            pool.append({"key": f"{m['part']}/{spec.map_id}", "kind": m["family"], "success": k / n,
                         "level": level_of(k / n), "entry": m, "spec": spec, "part": cand.part(m["part"]),
                         "part_entry": next(e for e in cand.doc["parts"] if e["name"] == m["part"]),
                         "source": cand})
    chosen, used = [], {}
    for lv in range(1, len(LEVEL_EDGES)):
        chosen += choose([c for c in pool if c["level"] == lv], MAPS_PER_LEVEL, used)
    folder = SUITES / name
    folder.mkdir(parents=True, exist_ok=True)
    parts, maps = [], []
    names = list(dict.fromkeys(c["part"].name for c in pool))      # the parts in the candidates' order
    for pname in names:
        mine = [c for c in chosen if c["part"].name == pname]
        if not mine:
            continue
        mine.sort(key=lambda c: (sources.index(c["source"]), c["entry"]["map_index"]))
        first = mine[0]
        new = {k: v for k, v in first["part_entry"].items() if k != "pairs_leveled"}
        if (first["source"].folder / first["part_entry"]["scenario"]).is_file():   # generated maps move in
            doc = copy.deepcopy(first["part"].doc)
            doc["name"] = f"{name}.{pname}"
            doc["obstacles"]["maps"] = [{k: v for k, v in c["part"].doc["obstacles"]["maps"][c["entry"]["map_index"]]
                                         .items() if k != "measured"} for c in mine]
            for c in mine:
                if c["part"].doc["world"] != doc["world"] or \
                        c["part"].doc["obstacles"]["root_seed"] != doc["obstacles"]["root_seed"]:
                    raise SystemExit(f"{name}: candidates of part {pname} come from different worlds or seeds")
            (folder / f"{pname}.toml").write_text(_toml(doc, f"pbdyn benchmark suite {name}: generated maps, "
                                                             "written by tools/make_suites.py; do not edit by "
                                                             "hand (the suite's hash covers it)."))
            new["scenario"] = f"{pname}.toml"
            ids = [m.map_id for m in enumerate_maps(load_scenario(folder / new["scenario"]))]
        else:
            ids = [c["spec"].map_id for c in mine]
        if ids != [c["spec"].map_id for c in mine]:
            raise SystemExit(f"{name}: part {pname}'s map ids differ from the candidates' (world settings?)")
        sc = parse_scenario(first["part"].doc, first["part"].path)
        new["pairs_leveled"] = [list(q) for q in heldout_pairs(sc.task.candidates)]
        parts.append(new)
        maps += [{"part": pname, "map_index": i, "map_id": c["spec"].map_id, "family": c["kind"], "level": None,
                  "heldout_success": round(c["success"], 6), "difficulty": None} for i, c in enumerate(mine)]
    cand = sources[0]
    per_map = len(parts[0]["pairs_leveled"]) * len(cand.speeds)
    text = LEVELS_FROM_TEXT.format(panel=", ".join(e.label for e in PANEL),
                                   speeds=", ".join(f"{v:g}" for v in PANEL_SPEEDS), per_map=per_map)
    manifest = {"format": SUITE_FORMAT, "name": name, "version": name.rsplit("-v", 1)[-1], "dims": cand.dims,
                "speeds": list(cand.speeds), "levels": level_ranges(), "parts": parts,
                "maps": sorted(maps, key=lambda m: (m["part"], m["map_index"])),
                LEVELS_FROM: {"tasks": "held-out", "panel": [e.label for e in PANEL], "text": text,
                              "candidates": len(pool)}}
    (folder / "suite.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return folder


def _per_map_counts(rows: list[dict], keep=None) -> dict:
    """(part, map id) -> [successes, tasks] over ``rows`` (those ``keep(row)`` accepts)."""
    out: dict = {}
    for r in rows:
        if keep is not None and not keep(r):
            continue
        c = out.setdefault((r["part"], r["map_id"]), [0, 0])
        c[0] += r["outcome"] == "success"
        c[1] += 1
    return out


def _level_differences(level: dict, a: dict, b: dict, seed: int, n_boot: int = 2000) -> list[dict]:
    """Per level (``level``: map -> level), the success of flights ``a`` and ``b`` (map -> [k, n]) pooled over the
    level's maps, and b - a with a 95% interval from resampling the level's maps."""
    import numpy as np

    out = []
    for lv in sorted(set(level.values())):
        maps = sorted(m for m in level if level[m] == lv)
        ka, na = np.array([a[m][0] for m in maps], float), np.array([a[m][1] for m in maps], float)
        kb, nb = np.array([b[m][0] for m in maps], float), np.array([b[m][1] for m in maps], float)
        rng = np.random.default_rng([seed, lv])
        w = rng.multinomial(len(maps), np.full(len(maps), 1.0 / len(maps)), size=n_boot).astype(float)
        d = (w @ kb) / (w @ nb) - (w @ ka) / (w @ na)
        out.append({"level": lv, "maps": len(maps), "a": ka.sum() / na.sum(), "b": kb.sum() / nb.sum(),
                    "b_minus_a": kb.sum() / nb.sum() - ka.sum() / na.sum(),
                    "ci95": [float(np.quantile(d, 0.025)), float(np.quantile(d, 0.975))]})
    return out


def _tilt_interval(level: dict, a: dict, b: dict, seed: int, n_boot: int = 2000) -> tuple[float, list[float]]:
    """The tilt of b's success minus a's across the levels (``level``: map -> level; a, b: map -> [k, n]; _tilt_draws)
    and its 95% interval from resampling the suite's maps."""
    import numpy as np

    maps = sorted(level)
    col = lambda c, i: np.array([[c[m][i] for m in maps]], float)      # noqa: E731  (one split x maps)
    w = np.vstack([np.ones(len(maps)), np.random.default_rng(seed).multinomial(
        len(maps), np.full(len(maps), 1.0 / len(maps)), size=n_boot)]).astype(float)
    t = _tilt_draws(np.array([[level[m] for m in maps]]), col(a, 0), col(a, 1), col(b, 0), col(b, 1), w)[:, 0]
    boot = t[1:][np.isfinite(t[1:])]
    return float(t[0]), [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))]


SPLITS = 50
"""Random halvings of the suite's tasks the same-skill check averages over (bias)."""


def _tilt_draws(levels, ka, na, kb, nb, w):
    """The tilt (per level, least squares weighted by maps) of b's success minus a's over the levels, for every
    map-weight draw and split at once: ``levels``, ``ka``, ``na``, ``kb``, ``nb`` (splits x maps), ``w`` (draws x
    maps) -> (draws x splits)."""
    import numpy as np

    lv = np.arange(1, len(LEVEL_EDGES))
    onehot = (levels[..., None] == lv).astype(float)                    # split x map x level
    sums = [np.einsum("dm,sml,sm->dsl", w, onehot, v) for v in (ka, na, kb, nb)]
    cnt = np.einsum("dm,sml->dsl", w, onehot)
    with np.errstate(invalid="ignore", divide="ignore"):
        y = np.where(cnt > 0, sums[2] / sums[3] - sums[0] / sums[1], 0.0)
    sw = cnt.sum(-1, keepdims=True)
    xm = (cnt * lv).sum(-1, keepdims=True) / sw
    ym = (cnt * y).sum(-1, keepdims=True) / sw
    num, den = (cnt * (lv - xm) * (y - ym)).sum(-1), (cnt * (lv - xm) ** 2).sum(-1)
    return np.divide(num, den, out=np.full(num.shape, np.nan), where=den > 0)   # one level only: no tilt


def _same_skill(s_rows: list[dict], level_h: dict, seed: int, n_boot: int = 2000) -> dict:
    """A planner of the panel's skill against the references: each map's unordered start/goal pairs are halved at
    random (SPLITS times); the panel's flights on one half play the references, those on the other half a planner
    of exactly the panel's skill (the halves are exchangeable). The tilt of its lead over the references across the
    levels, with the levels (a) from the references' own half (as v1 assigned them) and (b) from the held-out
    flights (``level_h``: map -> level), averaged over the splits, with a 95% interval from resampling maps."""
    import numpy as np

    from pbdyn.world.maps import stable_hash64

    maps = sorted(level_h)
    pair = lambda r: tuple(sorted((tuple(r["start"]), tuple(r["goal"]))))      # noqa: E731
    per = {m: {} for m in maps}
    for r in s_rows:
        c = per[(r["part"], r["map_id"])].setdefault(pair(r), [0, 0])
        c[0] += r["outcome"] == "success"
        c[1] += 1
    shape = (SPLITS, len(maps))
    ka, na, kb, nb = (np.zeros(shape) for _ in range(4))
    for j, m in enumerate(maps):
        pairs = sorted(per[m])
        k = np.array([per[m][q][0] for q in pairs], float)
        n = np.array([per[m][q][1] for q in pairs], float)
        rng = np.random.default_rng([seed, stable_hash64(f"{m[0]}/{m[1]}")])
        for sp in range(SPLITS):
            half = np.zeros(len(pairs), bool)
            half[rng.permutation(len(pairs))[:len(pairs) // 2]] = True
            ka[sp, j], na[sp, j], kb[sp, j], nb[sp, j] = k[half].sum(), n[half].sum(), k[~half].sum(), n[~half].sum()
    own = np.vectorize(level_of)(ka / na)
    held = np.broadcast_to(np.array([level_h[m] for m in maps]), shape)
    w = np.vstack([np.ones(len(maps)), np.random.default_rng(seed).multinomial(
        len(maps), np.full(len(maps), 1.0 / len(maps)), size=n_boot)]).astype(float)
    out = {}
    for key, lv in (("levels_from_references", own), ("levels_from_heldout", held)):
        t = _tilt_draws(lv, ka, na, kb, nb, w)
        ok = np.isfinite(t)
        t = np.divide(np.where(ok, t, 0.0).sum(1), ok.sum(1), out=np.full(len(t), np.nan),
                      where=ok.sum(1) > 0)                                 # draw (0: the data) -> mean over splits
        boot = t[1:][np.isfinite(t[1:])]
        out[key] = {"tilt_per_level": float(t[0]),
                    "ci95": [float(np.quantile(boot, q)) for q in (0.025, 0.975)] if boot.size else [None, None]}
        per_level = []
        for L in range(1, len(LEVEL_EDGES)):
            sel = lv == L
            if not sel.any():
                continue
            with np.errstate(invalid="ignore", divide="ignore"):
                d = (np.where(sel, kb, 0).sum(1) / np.where(sel, nb, 0).sum(1)
                     - np.where(sel, ka, 0).sum(1) / np.where(sel, na, 0).sum(1))
            per_level.append({"level": L, "maps_mean": float(sel.sum(1).mean()),
                              "b_minus_a_mean": float(np.nanmean(d))})
        out[key]["levels"] = per_level
    out["splits"] = SPLITS
    return out


def bias(name: str, heldout, json_out: Path | None = None) -> dict:
    """Measure the selection bias of suite NAME's levels (docs/benchmark.md "Levels"), from its shipped references
    (the panel's flights on the suite's tasks, S) and the panel's flights on held-out tasks of the same maps (H, in
    ``heldout``/<trajectory>/, fly-heldout):

    1. per level of the suite: the panel's success on S against H (the levels came from S: selection pulls S
       below H at the hard levels and above it at the easy ones; H's own tasks are easier or harder on the whole,
       an offset common to every level), and the tilt of the difference across the levels;
    2. a planner of the panel's skill against the references (_same_skill: random halves of the suite's tasks),
       with levels from the references' own flights, as v1 did, and from the held-out flights.
    Prints Markdown tables; writes them as JSON to ``json_out`` if given."""
    from pbdyn.analysis.scale import PANEL
    from pbdyn.benchmark.run import load_references
    from pbdyn.benchmark.suite import load_suite

    suite = load_suite(SUITES / name if (SUITES / name).is_dir() else name)
    refs = load_references(suite)
    s_rows = [r for e in PANEL for r in refs[e.label]["rows"]]
    h_rows = [r for rows in heldout_rows(suite, heldout).values() for r in rows]
    S, H = _per_map_counts(s_rows), _per_map_counts(h_rows)
    suite_level = {(m["part"], m["map_id"]): int(m["level"]) for m in suite.maps}
    out = {"suite": name, "hash": suite.hash, "maps": len(suite.maps), "panel": [e.label for e in PANEL],
           "tasks_per_map": {"suite": S[next(iter(S))][1], "heldout": H[next(iter(H))][1]},
           "suite_vs_heldout": _level_differences(suite_level, S, H, 1)}
    tot = lambda c: sum(k for k, _ in c.values()) / sum(n for _, n in c.values())   # noqa: E731
    out["overall"] = {"suite": tot(S), "heldout": tot(H)}
    out["suite_vs_heldout_tilt_per_level"], out["suite_vs_heldout_tilt_ci95"] = _tilt_interval(suite_level, S, H, 10)
    out["same_skill"] = _same_skill(s_rows, {m: level_of(k / n) for m, (k, n) in H.items()}, 11)
    print(f"{name} ({suite.hash[:12]}): panel success on the suite's tasks {out['overall']['suite']:.3f}, "
          f"held out {out['overall']['heldout']:.3f}")
    lo, hi = out["suite_vs_heldout_tilt_ci95"]
    print(f"\nsuite vs held-out (tilt {out['suite_vs_heldout_tilt_per_level']:+.4f} per level, 95% interval "
          f"[{lo:+.4f}, {hi:+.4f}])\n")
    print("| level | maps | suite's tasks | held-out tasks | difference | 95% interval (maps) |\n|---|---|---|---|---|---|")
    for r in out["suite_vs_heldout"]:
        print(f"| {r['level']} | {r['maps']} | {r['a']:.3f} | {r['b']:.3f} | {r['b_minus_a']:+.3f} | "
              f"[{r['ci95'][0]:+.3f}, {r['ci95'][1]:+.3f}] |")
    for key in ("levels_from_references", "levels_from_heldout"):
        ss = out["same_skill"][key]
        print(f"\nsame skill, {key}: tilt {ss['tilt_per_level']:+.4f} per level [{ss['ci95'][0]:+.4f}, "
              f"{ss['ci95'][1]:+.4f}]; per level " + " ".join(f"{r['level']}:{r['b_minus_a_mean']:+.3f}"
                                                               for r in ss["levels"]))
    if json_out is not None:
        json_out.write_text(json.dumps(out, indent=1) + "\n")
    return out


def fly_heldout(name: str, out: Path, planners: list[str], workers: int) -> None:
    """Fly the reference panel (or ``planners``) on the held-out tasks of suite NAME's maps into
    out/heldout/<trajectory>/."""
    from pbdyn.analysis.scale import PANEL
    from pbdyn.benchmark.run import _check_marker, fly_suite, planner_entry
    from pbdyn.benchmark.suite import load_suite

    suite = heldout_suite(load_suite(SUITES / name if (SUITES / name).is_dir() else name))
    for traj in planners or [e.trajectory for e in PANEL]:
        entry = planner_entry(traj)
        folder = out / "heldout" / traj
        _check_marker(folder, suite, entry)
        fly_suite(suite, entry, folder, workers=workers, progress=True,
                  command=f"tools/make_suites.py fly-heldout {name}")


def _panel_measure(suite, flown_rows: dict) -> dict:
    """The panel's measurement of every map from its flights (``flown_rows``: panel label -> task rows): map
    "part/id" -> (success, success ci, difficulty, difficulty ci, tasks per respondent), by the same code as
    `pbdyn calibrate`, from the respondents at the suite's speeds."""
    from pbdyn.analysis.scale import PANEL, load_anchors, measure_difficulties, panel_counts

    panel_rows = []
    for e in PANEL:
        for r in flown_rows[e.label]:
            panel_rows.append({**r, "map_id": f"{r['part']}/{r['map_id']}", "planner_label": e.label,
                               "map_index": None})
    return {m.map_id: (m.success, list(m.success_ci), m.difficulty, list(m.difficulty_ci), m.tasks)
            for m in measure_difficulties(panel_counts(panel_rows), load_anchors(), dims=suite.dims,
                                          speeds=suite.speeds)}


def link_offset(suite_measure: dict, heldout_measure: dict) -> float:
    """The one logit offset that puts difficulties measured on the held-out tasks onto the scale of the suite's
    tasks: the median over maps of (difficulty on the suite's tasks - difficulty on the held-out ones), over the
    maps where neither success is 0 or 1 (0 if none). It is common to every map, so it moves no level and no
    comparison; it keeps a card's ability on the anchored scale of the suite's tasks (docs/benchmark.md "Levels")."""
    import numpy as np

    d = [suite_measure[k][2] - heldout_measure[k][2] for k in sorted(suite_measure)
         if 0.0 < suite_measure[k][0] < 1.0 and 0.0 < heldout_measure[k][0] < 1.0]
    return float(np.median(d)) if d else 0.0


def heldout_rows(suite, folder) -> dict:
    """The panel's task rows on the held-out tasks of ``suite`` (heldout_suite) in ``folder``/<trajectory>/ (the
    flights of fly-heldout): panel label -> rows; a panel planner not flown in full stops the tool."""
    from pbdyn.analysis.scale import PANEL
    from pbdyn.benchmark.card import task_key
    from pbdyn.benchmark.run import read_rows

    held = heldout_suite(suite)
    folders = folder if isinstance(folder, (list, tuple)) else [folder]
    out = {}
    for e in PANEL:
        rows = list({task_key(r): r for f in folders for r in read_rows(held, Path(f) / e.trajectory, e.label)}
                    .values())
        if len(rows) != held.n_tasks():
            raise SystemExit(f"{', '.join(str(f) for f in folders)} ({e.trajectory}): {len(rows)} of "
                             f"{held.n_tasks()} held-out tasks flown; "
                             "fly them first (tools/make_suites.py fly-heldout)")
        out[e.label] = rows
    return out


def freeze(name: str, out: Path, heldout: Path | None = None) -> None:
    """Measure, level and freeze suite NAME from the reference flights in ``out`` (module doc); a suite whose
    manifest holds levels_from takes its levels and difficulties from the panel's held-out flights in ``heldout``
    (default out/heldout), its reference success from the suite's tasks."""
    import platform
    from datetime import datetime, timezone

    import pbdyn
    from pbdyn.analysis.scale import PANEL
    from pbdyn.benchmark.card import machine
    from pbdyn.benchmark.run import REFERENCE_FILE, THESIS_GAZE, read_rows, reference_document
    from pbdyn.benchmark.suite import LEVELS_FROM, REFERENCES_DIGEST, SUITE_FORMAT, load_suite, references_digest
    from pbdyn.analysis.scale import load_anchors
    from pbdyn.planning.registry import pair_fingerprint

    folder = SUITES / name
    suite = load_suite(folder)
    flown = {}
    for traj, gaze in THESIS_GAZE.items():
        rows = read_rows(suite, out / traj)
        if len(rows) != suite.n_tasks():
            raise SystemExit(f"{out / traj}: {len(rows)} of {suite.n_tasks()} tasks flown; fly them first")
        label = f"{gaze}+{traj}"
        flown[label] = {"rows": rows, "meta": {"trajectory": traj, "gaze": gaze,
                                               "fingerprint": _flown_fingerprint(out / traj, label)}}
        if flown[label]["meta"]["fingerprint"] != pair_fingerprint(traj, gaze):
            print(f"note: {label} was flown by other code than this checkout's (its rows record "
                  f"{flown[label]['meta']['fingerprint']}); the references record the code that flew them")
    res = _panel_measure(suite, {k: v["rows"] for k, v in flown.items()})
    doc = json.loads((folder / "suite.json").read_text())
    held = None
    if LEVELS_FROM in doc:
        hdirs = list(heldout) if isinstance(heldout, (list, tuple)) else [heldout or out / "heldout"]
        held = _panel_measure(heldout_suite(suite), heldout_rows(suite, hdirs))
        doc[LEVELS_FROM]["fingerprints"] = {e.label: _flown_fingerprint([h / e.trajectory for h in hdirs], e.label)
                                            for e in PANEL}
        doc[LEVELS_FROM]["offset_logits"] = round(link_offset(res, held), 6)
    for m in doc["maps"]:
        key = f"{m['part']}/{m['map_id']}"
        got = res[key][0]
        if "cut_from" not in doc and m.get("calibration_success") is not None \
                and abs(got - m["calibration_success"]) > 5e-7:
            print(f"note: map {key}: measured success {got:.6f}, its source recorded "
                  f"{m['calibration_success']:.6f}")
        s, s_ci, b, b_ci, tasks = res[key]
        m.update({"reference_success": round(s, 6), "reference_success_ci95": [round(x, 6) for x in s_ci],
                  "tasks": tasks * len(suite.speeds)})
        if held is not None:            # the level and difficulty from the held-out flights (module doc)
            s, s_ci, b, b_ci, tasks = held[key]
            m.update({"level_success": round(s, 6), "level_success_ci95": [round(x, 6) for x in s_ci],
                      "level_tasks": tasks * len(suite.speeds)})
            b, b_ci = b + doc[LEVELS_FROM]["offset_logits"], [x + doc[LEVELS_FROM]["offset_logits"] for x in b_ci]
        m.update({"level": level_of(s), "difficulty": round(b, 6), "difficulty_ci95": [round(x, 6) for x in b_ci]})
    doc["maps"] = sorted(doc["maps"], key=lambda m: (m["level"], m["part"], m["map_index"]))
    if "cut_from" in doc:     # a cut keeps only the levels its maps fall in
        doc["levels"] = [lv for lv in doc["levels"] if any(m["level"] == lv["level"] for m in doc["maps"])]
    doc["built"] = {"tool": "tools/make_suites.py", "pbdyn": pbdyn.__version__,
                    "scale": f"anchored/{load_anchors().version}"}
    doc["format"] = SUITE_FORMAT                # the hash covers the references' digest (suite.py module doc)
    doc.pop(REFERENCES_DIGEST, None)
    (folder / "suite.json").write_text(json.dumps(doc, indent=1) + "\n")
    suite = load_suite(folder)
    date = datetime.now(timezone.utc).replace(microsecond=0).isoformat()
    for v in flown.values():
        v["meta"].update({"pbdyn": pbdyn.__version__, "machine": machine(), "date": date,
                          "python": platform.python_version()})
    doc[REFERENCES_DIGEST] = references_digest(reference_document(suite, flown))
    (folder / "suite.json").write_text(json.dumps(doc, indent=1) + "\n")
    suite = load_suite(folder)
    ref = reference_document(suite, flown)
    (folder / REFERENCE_FILE).write_bytes(gzip.compress(json.dumps(ref, separators=(",", ":")).encode(), mtime=0))
    print(f"{name}: hash {suite.hash}; levels " + " ".join(
        f"{lv['level']}:{sum(m['level'] == lv['level'] for m in doc['maps'])}" for lv in doc["levels"]))


def _flown_fingerprint(folder, label: str) -> str:
    """The one code fingerprint the rows of ``label`` in a bench folder's flight stores (or several folders')
    were flown with."""
    from pbdyn.experiments.store import ResultsStore

    fps = set()
    folders = folder if isinstance(folder, list) else [folder]
    for path in sorted(p for f in folders for p in (Path(f) / "flights").glob("*.sqlite")):
        st = ResultsStore.open(path)
        try:
            fps |= {fp for lab, fp, _ in st.fingerprint_counts() if lab == label}
        finally:
            st.close()
    if len(fps) != 1:
        raise SystemExit(f"{folder}: the rows of {label} were flown with {len(fps)} code fingerprints "
                         f"({', '.join(sorted(map(str, fps)))}); fly them with one code")
    return fps.pop()


def _toml(doc: dict, comment: str) -> str:
    """A scenario document as TOML (tomli_w) under a comment line."""
    import tomli_w

    return f"# {comment}\n" + tomli_w.dumps(doc)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("draft")
    d.add_argument("name")
    d.add_argument("--dims", type=int, default=2)
    d.add_argument("--extra", type=Path, action="append", default=[])
    d.add_argument("--world", type=Path, action="append", default=[])
    dm = sub.add_parser("draft-mini")
    dm.add_argument("name")
    dm.add_argument("source")
    f = sub.add_parser("fly")
    f.add_argument("name")
    f.add_argument("out", type=Path)
    f.add_argument("--planner", action="append", default=[])
    f.add_argument("--workers", type=int, default=2)
    fh = sub.add_parser("fly-heldout")
    fh.add_argument("name")
    fh.add_argument("out", type=Path)
    fh.add_argument("--planner", action="append", default=[])
    fh.add_argument("--workers", type=int, default=2)
    z = sub.add_parser("freeze")
    z.add_argument("name")
    z.add_argument("out", type=Path)
    z.add_argument("--heldout", type=Path, action="append", default=None)
    d2 = sub.add_parser("draft-v2")
    d2.add_argument("name")
    d2.add_argument("--candidates", action="append", required=True)
    d2.add_argument("--heldout", type=Path, action="append", required=True)
    ca = sub.add_parser("candidates")
    ca.add_argument("folder", type=Path)
    ca.add_argument("--dims", type=int, default=2)
    ca.add_argument("--extra", type=Path, action="append", default=[])
    ca.add_argument("--world", action="append", default=[])
    ca.add_argument("--exclude", action="append", default=[])
    bi = sub.add_parser("bias")
    bi.add_argument("name")
    bi.add_argument("heldout", type=Path)
    bi.add_argument("--json", type=Path, default=None)
    pl = sub.add_parser("pool")
    pl.add_argument("file", type=Path)
    pl.add_argument("--dims", type=int, default=3)
    me = sub.add_parser("measured")
    me.add_argument("file", type=Path)
    me.add_argument("store", type=Path)
    me.add_argument("out", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "pool":
        print(pool(a.file, a.dims))
    elif a.cmd == "measured":
        print(measured(a.file, a.store, a.out))
    elif a.cmd == "draft":
        print(draft(a.name, a.dims, a.extra, a.world))
    elif a.cmd == "draft-v2":
        print(draft_v2(a.name, a.candidates, a.heldout))
    elif a.cmd == "candidates":
        print(candidate_suite(a.folder, a.dims, a.extra, a.world, a.exclude))
    elif a.cmd == "bias":
        bias(a.name, a.heldout, a.json)
    elif a.cmd == "draft-mini":
        print(draft_mini(a.name, a.source))
    elif a.cmd == "fly-heldout":
        fly_heldout(a.name, a.out, a.planner, a.workers)
    elif a.cmd == "fly":
        fly_references(a.name, a.out, a.planner, a.workers)
    else:
        freeze(a.name, a.out, a.heldout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
