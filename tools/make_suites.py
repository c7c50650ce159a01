"""Build the frozen benchmark suites and their reference results (docs/benchmark.md "How the suites were built").

Three steps, each a sub-command:

  draft NAME     choose the suite's maps from the calibration sets (pbdyn/analysis/data/calibration_*.csv.gz: the
                 reference panel's flights of every calibration map) and extra generated maps (--extra FILE: scenario
                 files written by `pbdyn generate --success` or `measured`), imported worlds (the bundled 2D set, and
                 --world FILE: measured by `pbdyn calibrate`), LEVELS_PER_SUITE levels by the panel's success,
                 MAPS_PER_LEVEL maps per level, families mixed (module functions choose and level_of); writes
                 scenarios/suites/NAME/ with the manifest (no measured difficulty yet) and the generated maps' part.
  fly NAME DIR   fly every built-in trajectory planner (with its thesis gaze) on the draft into DIR/<planner>/
                 (the bench runner's flights; resumable).
  freeze NAME DIR  measure every map's difficulty from the reference panel's flights in DIR on exactly the suite's
                 tasks (pbdyn.experiments.calibrate.measure: the same numbers `pbdyn calibrate` gives), assign the
                 levels, write the final manifest and the reference results (reference.json.gz) with the suite's hash.

Hard maps beyond the calibration sets' range (the 3D sets reach reference success 0.54 only) come from a pool:

  pool FILE --dims D   write a pool scenario of POOL_MAPS maps per generator family (walls aside) with (n, r, v)
                 from a seeded Latin hypercube over POOL_BOX (denser, larger obstacles than the calibration box),
                 whose experiment is the reference panel's flights (as the calibration sets');
  measured FILE STORE OUT  after `pbdyn batch FILE --store STORE`, write OUT: FILE's maps with each map's measured
                 reference success (the panel's share of successes on its reference tasks), an --extra for draft.

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

DATA = ROOT / "pbdyn" / "analysis" / "data"
SUITES = ROOT / "scenarios" / "suites"
LEVEL_EDGES = (1.0, 0.85, 0.75, 0.65, 0.55, 0.45, 0.35, 0.25, 0.15, 0.0)
"""Reference-success edges of the levels: level 1 = [0.85, 1], ..., level 9 = [0, 0.15)."""
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


def levels_doc() -> list[dict]:
    """The manifest's levels: number and reference-success range [lo, hi]."""
    return [{"level": i + 1, "success_range": [LEVEL_EDGES[i + 1], LEVEL_EDGES[i]]} for i in range(len(LEVEL_EDGES) - 1)]


def level_of(success: float) -> int:
    """The level of a map whose reference success is ``success``."""
    for i in range(len(LEVEL_EDGES) - 1):
        if success >= LEVEL_EDGES[i + 1]:
            return i + 1
    return len(LEVEL_EDGES) - 1


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
                "speeds": list(PANEL_SPEEDS), "levels": levels_doc(), "parts": parts,
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
                "levels": levels_doc(), "parts": [{"name": "generated", "scenario": "generated.toml",
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
    from pbdyn.experiments.calibrate import panel_counts
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


def fly(name: str, out: Path, planners: list[str], workers: int) -> None:
    """Fly the built-in planners (or ``planners``) on suite NAME into out/<trajectory>/."""
    from pbdyn.benchmark.run import THESIS_GAZE, _check_marker, fly as fly_suite, planner_entry
    from pbdyn.benchmark.suite import load_suite

    suite = load_suite(SUITES / name)
    for traj in planners or list(THESIS_GAZE):
        entry = planner_entry(traj)
        folder = out / traj
        _check_marker(folder, suite, entry)
        fly_suite(suite, entry, folder, workers=workers, progress=True, command=f"tools/make_suites.py fly {name}")


def _measure_subset(counts: dict, speeds: list[float]) -> dict:
    """measure() restricted to the panel respondents at ``speeds``: map id -> (success, ci, b, b_ci)."""
    import numpy as np

    from pbdyn.analysis.scale import difficulty_given_abilities
    from pbdyn.experiments.calibrate import RESPONDENTS, load_anchors
    from pbdyn.world.maps import stable_hash64

    theta_all = load_anchors().theta()
    cols = [j for j, r in enumerate(RESPONDENTS) if float(r.rsplit("@", 1)[1]) in speeds]
    out = {}
    for mid, m in counts.items():
        s, n = m["success"][:, cols], m["trials"][:, cols]
        t = s.shape[0]
        rng = np.random.default_rng([0, stable_hash64(mid)])
        w = rng.multinomial(t, np.full(t, 1.0 / t), size=1000).astype(float)
        ks, ns = w @ s, w @ n
        rate = ks.sum(axis=1) / ns.sum(axis=1)
        b = difficulty_given_abilities(theta_all[cols], s.sum(axis=0), n.sum(axis=0))
        bb = difficulty_given_abilities(theta_all[cols], ks, ns)
        out[mid] = (float(s.sum() / n.sum()), [float(np.quantile(rate, 0.025)), float(np.quantile(rate, 0.975))],
                    float(b), [float(np.quantile(bb, 0.025)), float(np.quantile(bb, 0.975))], t)
    return out


def freeze(name: str, out: Path) -> None:
    """Measure, level and freeze suite NAME from the reference flights in ``out`` (module doc)."""
    import platform
    from datetime import datetime, timezone

    import pbdyn
    from pbdyn.analysis.scale import PANEL, PANEL_SPEEDS
    from pbdyn.benchmark.card import machine
    from pbdyn.benchmark.run import REFERENCE_FILE, THESIS_GAZE, read_rows, reference_document
    from pbdyn.benchmark.suite import REFERENCES_DIGEST, SUITE_FORMAT, load_suite, references_digest
    from pbdyn.experiments.calibrate import load_anchors, measure, panel_counts
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
    panel_rows = []
    for e in PANEL:
        for r in flown[e.label]["rows"]:
            panel_rows.append({**r, "map_id": f"{r['part']}/{r['map_id']}", "planner_label": e.label,
                               "map_index": None})
    counts = panel_counts(panel_rows)
    if sorted(suite.speeds) == sorted(PANEL_SPEEDS):
        res = {m.map_id: (m.success, list(m.success_ci), m.difficulty, list(m.difficulty_ci), m.tasks)
               for m in measure(counts, load_anchors(), dims=suite.dims)}
    else:
        res = _measure_subset(counts, list(suite.speeds))
    doc = json.loads((folder / "suite.json").read_text())
    for m in doc["maps"]:
        got = res[f"{m['part']}/{m['map_id']}"][0]
        if "cut_from" not in doc and abs(got - m["calibration_success"]) > 5e-7:
            print(f"note: map {m['part']}/{m['map_id']}: measured success {got:.6f}, its source recorded "
                  f"{m['calibration_success']:.6f}")
        s, s_ci, b, b_ci, tasks = res[f"{m['part']}/{m['map_id']}"]
        m.update({"level": level_of(s), "reference_success": round(s, 6),
                  "reference_success_ci95": [round(x, 6) for x in s_ci], "difficulty": round(b, 6),
                  "difficulty_ci95": [round(x, 6) for x in b_ci], "tasks": tasks * len(suite.speeds)})
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


def _flown_fingerprint(folder: Path, label: str) -> str:
    """The one code fingerprint the rows of ``label`` in a bench folder's flight stores were flown with."""
    from pbdyn.experiments.store import ResultsStore

    fps = set()
    for path in sorted((folder / "flights").glob("*.sqlite")):
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
    z = sub.add_parser("freeze")
    z.add_argument("name")
    z.add_argument("out", type=Path)
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
    elif a.cmd == "draft-mini":
        print(draft_mini(a.name, a.source))
    elif a.cmd == "fly":
        fly(a.name, a.out, a.planner, a.workers)
    else:
        freeze(a.name, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
