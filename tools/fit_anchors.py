"""Fit the anchored difficulty scale from the calibration flights and write what pbdyn ships (pbdyn/analysis/data/).

    .venv/bin/pbdyn batch scenarios/calibration/calibration_2d.toml --out results/calibration/calibration_2d.sqlite
    .venv/bin/python tools/fit_anchors.py --export results/calibration/calibration_2d.sqlite   # outcomes -> data/
    .venv/bin/python tools/fit_anchors.py                                                     # anchors.json

--export writes the panel's outcomes of a calibration store as a compact CSV (calibration_<dims>d.csv.gz: map,
family, setup, task, respondent, success), the data the anchors are fitted on and that the tests refit. The fit:
a 1PL model (pbdyn.analysis.irt.fit_rasch, statsmodels GLM, PRIOR_TRIALS pseudo-trials per map) of the 2D
calibration set's outcomes, items = maps, respondents = panel pair x MAV speed; the abilities are shipped, which
fixes the scale's zero (the mean difficulty of the 2D calibration maps) and unit (a logit). The calibration maps'
difficulties per dims (for percentiles) are then each map's difficulty with the shipped abilities fixed.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import io
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pbdyn.analysis.scale import (ANCHORS_FILE, PANEL, PRIOR_TRIALS, RESPONDENTS, SCALE_VERSION,  # noqa: E402
                                  difficulty_given_abilities, respondent)

DATA = ROOT / "pbdyn" / "analysis" / "data"
CODE_FILE = "calibration_code.json"
"""Per exported kind (2d, 3d, worlds), panel label -> the code fingerprints its calibration rows were flown with
(pbdyn.planning.registry.pair_fingerprint); fit() records the 2D set's in anchors.json ("code")."""
FIELDS = ("map_id", "map_index", "family", "count", "radius", "speed", "start", "goal", "respondent", "success")


def store_outcomes(store: Path) -> tuple[str, list[tuple]]:
    """(kind, rows) of the panel's outcomes in a calibration store: kind "2d"/"3d" for generated maps, "worlds" for
    an imported world (its family is the world's name, its map id prefixed by it: "office_0/<map id>")."""
    from pbdyn.experiments.store import ResultsStore

    st = ResultsStore.open(store)
    try:
        rows, doc = st.results(), json.loads(st.get_meta("scenario") or "{}")
    finally:
        st.close()
    world = bool(doc.get("bodies"))
    kind = "worlds" if world else f"{int(doc.get('world', {}).get('dims', 2))}d"
    name = str(doc.get("name", store.stem)).removesuffix("_reference")
    out = []
    for r in rows:
        who = respondent(r.get("planner_label") or "", r.get("mav_speed") or 0.0)
        if who not in RESPONDENTS:
            continue
        if r.get("outcome") == "error":
            raise SystemExit(f"{store}: an error row on map {r.get('map_index')}; re-fly it first")
        family = name if world else json.loads(r.get("map_key") or "{}").get("setup", {}).get("structure", "")
        out.append((f"{name}/{r['map_id']}" if world else r["map_id"], r["map_index"], family, r["obstacle_count"], r["obstacle_radius"],
                    r["obstacle_speed"], " ".join(f"{x:g}" for x in r["start"]), " ".join(f"{x:g}" for x in r["goal"]),
                    who, int(r["outcome"] == "success")))
    return kind, out


def store_code(store: Path) -> dict[str, list[str]]:
    """Panel label -> the sorted code fingerprints its rows in ``store`` were flown with."""
    from pbdyn.experiments.store import ResultsStore

    st = ResultsStore.open(store)
    try:
        counts = st.fingerprint_counts()
    finally:
        st.close()
    out: dict[str, set] = {}
    for label, fp, _ in counts:
        if label in {e.label for e in PANEL}:
            out.setdefault(label, set()).add(fp or "not recorded")
    return {k: sorted(v) for k, v in sorted(out.items())}


def export(stores: list[Path]) -> list[Path]:
    """Write the panel's outcomes of ``stores`` to DATA/calibration_<kind>.csv.gz (one file per kind: 2d, 3d,
    worlds -- the stores of one kind together); returns the paths written."""
    import collections

    per: dict[str, list] = {}
    code: dict[str, dict] = {}
    for store in stores:
        kind, rows = store_outcomes(store)
        for label, fps in store_code(store).items():
            code.setdefault(kind, {}).setdefault(label, set()).update(fps)
        counts = collections.Counter(r[0] for r in rows)
        full = max(counts.values()) if counts else 0
        partial = sorted(m for m, c in counts.items() if c < full)
        if partial:       # a map the panel has not finished is left out: its outcomes would be a biased sample
            print(f"{store}: left out {len(partial)} map(s) not fully flown: " + ", ".join(
                f"{m} ({counts[m]} of {full} trials)" for m in partial))
            rows = [r for r in rows if r[0] not in partial]
        per.setdefault(kind, []).extend(rows)
    paths = []
    for kind, rows in per.items():
        rows.sort()
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(FIELDS)
        w.writerows(rows)
        path = DATA / f"calibration_{kind}.csv.gz"
        DATA.mkdir(parents=True, exist_ok=True)
        path.write_bytes(gzip.compress(buf.getvalue().encode(), mtime=0))
        paths.append(path)
    code_path = DATA / CODE_FILE
    recorded = json.loads(code_path.read_text()) if code_path.is_file() else {}
    recorded.update({kind: {k: sorted(v) for k, v in sorted(c.items())} for kind, c in code.items()})
    code_path.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
    paths.append(code_path)
    return paths


def read_outcomes(path: Path) -> list[dict]:
    """The rows of an exported outcomes file."""
    with gzip.open(path, "rt") as f:
        return list(csv.DictReader(f))


def fit(outcomes_2d: list[dict]) -> dict:
    """The anchors document from the 2D calibration outcomes (module doc)."""
    from pbdyn.analysis.irt import fit_rasch

    items = [r["map_id"] for r in outcomes_2d]
    resp = [r["respondent"] for r in outcomes_2d]
    y = np.array([int(r["success"]) for r in outcomes_2d], float)
    res = fit_rasch(items, resp, y, prior_trials=PRIOR_TRIALS)
    missing = [r for r in RESPONDENTS if r not in res.respondents]
    if missing:
        raise SystemExit(f"the calibration outcomes lack {', '.join(missing)}")
    abilities = {r: round(float(a), 6) for r, a in zip(res.respondents, res.ability)}
    return {"version": SCALE_VERSION, "abilities": {r: abilities[r] for r in RESPONDENTS},
            "ability_se": {r: round(float(s), 6) for r, s in zip(res.respondents, res.ability_se)},
            "source": f"fit_rasch (statsmodels GLM, {PRIOR_TRIALS:g} pseudo-trial per map) on calibration_2d: "
                      f"{len(res.items)} maps, {int(y.size)} trials",
            "converged": bool(res.converged), **_recorded_code("2d")}


def _recorded_code(kind: str) -> dict:
    """{"code": panel label -> fingerprints} of the exported ``kind`` where the export recorded it, else {}."""
    path = DATA / CODE_FILE
    code = json.loads(path.read_text()).get(kind) if path.is_file() else None
    return {"code": code} if code else {}


def map_difficulties(outcomes: list[dict], abilities: dict) -> list[float]:
    """Each map's difficulty with ``abilities`` fixed, in map order."""
    theta = np.array([abilities[r] for r in RESPONDENTS])
    col = {r: j for j, r in enumerate(RESPONDENTS)}
    per: dict[str, np.ndarray] = {}
    for r in outcomes:
        a = per.setdefault(r["map_id"], np.zeros((2, len(RESPONDENTS))))
        a[0, col[r["respondent"]]] += int(r["success"])
        a[1, col[r["respondent"]]] += 1
    return [round(float(difficulty_given_abilities(theta, a[0], a[1])), 6) for _, a in sorted(per.items())]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--export", nargs="+", type=Path, help="calibration stores to export (then stop)")
    args = ap.parse_args(argv)
    if args.export:
        for path in export(args.export):
            print(f"wrote {path.relative_to(ROOT)}")
        return 0
    doc = fit(read_outcomes(DATA / "calibration_2d.csv.gz"))
    doc["difficulties"] = {}
    for dims in (2, 3):
        p = DATA / f"calibration_{dims}d.csv.gz"
        if p.is_file():
            doc["difficulties"][str(dims)] = map_difficulties(read_outcomes(p), doc["abilities"])
    (DATA / ANCHORS_FILE).write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    print(json.dumps(doc["abilities"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
