"""Reproduce the thesis' table 4-5 (and tables 4-6..4-8, 5-4, figures 4-5..4-12, 5-9, 5-10, 5-14), and compare
pbdyn's outcome rates with the thesis program's.

    .venv/bin/python tools/reproduce.py --scale quick   [--out results/reproduce-quick] [--workers N]
    .venv/bin/python tools/reproduce.py --scale full    [--out results/reproduce-full] [--scheduler tcp://HOST:8786]
    .venv/bin/python tools/reproduce.py --scale compare [--combos A,B] [--skip-uncontrolled]
    .venv/bin/python tools/reproduce.py --profile thesis_program --scale compare
    .venv/bin/python tools/reproduce.py --side-by-side DIR_PHYSICAL DIR_THESIS [--out DIR]

Profiles. ``--profile physical`` (default) flies scenarios/datasets/*.toml; ``--profile thesis_program`` flies
scenarios/thesis/*_2d.toml: the same grids and seeds in the program's 48 m arena with `profile = "thesis_program"`
(the program's sensor, start clearance, planner and metric parameters) and the planner combinations named as the
program named them ("<Gaze>+<Trajectory>", COMBOS). ``--dims 3`` uses the 3D counterparts (physical profile, quick
and full only).

Scales:
- ``full`` flies the thesis' datasets as shipped (the controlled set, 540 maps x 18 combos x 216 trials, and the
  three uncontrolled sets, 45 maps x 3 combos x 216 trials).
- ``quick`` flies a reduced grid derived from the same files: controlled, all 27 setups x QUICK_MAPS maps (>= 3, so
  the within-setup SRCC exists), the combos QUICK_COMBOS, MAV speed QUICK_VMAX, start/goal candidates
  QUICK_CANDIDATES (20 ordered pairs): 8100 trials; each uncontrolled set, its 9 setups x QUICK_UNCONTROLLED_MAPS
  maps, its combos that are in QUICK_COMBOS, the same speed and candidates: 1080 trials each.
- ``compare`` (per-setup comparison with the program): controlled, all 27 setups x COMPARE_MAPS maps, all 72
  start/goal pairs, MAV speeds COMPARE_VMAX, the combos COMPARE_COMBOS (69,984 trials), and a second store
  (NAME_compare_more) with COMPARE_MORE_COMBOS on COMPARE_MORE_MAPS map per setup (11,664 trials; its maps are the
  first replicates of the main store's); each uncontrolled set, its 9 setups x COMPARE_UNCONTROLLED_MAPS maps with
  all 72 pairs and the three speeds, so its per-map rates pool the same trials as the controlled maps' (11,664
  trials each).
Reduced documents are written next to the results (scenarios/ in the output folder). ``--combos`` flies only the
named combos (thesis names; e.g. the local-primitive combos first): a store left without combos is skipped, and a
later run with more combos adds them to the existing stores (pbdyn batch --extend, planners appended).

Every store is one `pbdyn batch` (resumable: re-run the same command after an interruption; ``--limit N`` flies
only the first N trials of each, for smoke runs). Then `pbdyn evaluate`
of the controlled store with the uncontrolled stores (every store of the scale present in the folder; the
compare_more store is left out: it repeats maps of the main store) writes table.txt, report.json and figures/, and
the agreement report (tools/agreement.py) compares the controlled stores' pooled outcome rates per combo and MAV
speed with the program's (REFERENCE_RATES; the physical profile compares the combos' physical counterparts):
agreement.md and agreement.json. Both tables are printed. ``--side-by-side`` writes side_by_side.md from two such
folders (table 4-5 and the pooled rates under both profiles).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pbdyn.config import parse_scenario  # noqa: E402
from pbdyn.errors import ConfigError  # noqa: E402
from pbdyn.experiments.evaluate import evaluate_stores  # noqa: E402
from pbdyn.experiments.runner import BatchOptions, run_batch  # noqa: E402
from pbdyn.experiments.signals import BatchInterrupted  # noqa: E402
from pbdyn.experiments.store import ResultsStore  # noqa: E402
from pbdyn.metrics.catalog import TABLE_ORDER  # noqa: E402
from pbdyn.outcome import Outcome  # noqa: E402
from tools.agreement import agreement, format_markdown, format_side_by_side, json_ready  # noqa: E402

DATASETS = ROOT / "scenarios" / "datasets"
THESIS = ROOT / "scenarios" / "thesis"
PROFILES = {"physical": DATASETS, "thesis_program": THESIS}
"""Profile -> the folder of its scenario files (NAME_2d.toml, and for physical NAME_3d.toml)."""
SETS = ("controlled", "uncontrolled_speed", "uncontrolled_size", "uncontrolled_rvo")
SCALES = ("quick", "full", "compare")

# ------------------------------------------------------------------------------------------------ combos
GAZES = {"LookAhead": "lookahead", "NoControl": "fullrange", "LookGoal": "lookgoal_unexplored",
         "Rotating": "rotating", "Oxford": "finean", "Owl": "owl"}
"""The program's gaze planner names -> pbdyn's (the same under both profiles; LookGoal is the program's
look-at-the-first-unexplored-sample rule, docs/thesis-program.md)."""
TRAJECTORIES = {"Jerk_Primitive": {"physical": "local_primitives", "thesis_program": "local_primitives_minjerk"},
                "Primitive": {"physical": "global_primitives", "thesis_program": "global_primitives"},
                "MPC": {"physical": "mpc", "thesis_program": "mpc"}}
"""The program's trajectory planner names -> pbdyn's per profile (physical: the norm-bounded counterparts)."""
COMBOS = tuple(f"{g}+{t}" for g in GAZES for t in TRAJECTORIES)
"""Every program combination "<Gaze>+<Trajectory>" (18)."""


def planner_of(combo: str, profile: str) -> tuple[str, str]:
    """(gaze, trajectory) registry names of the program combination ``combo`` under ``profile``."""
    gaze, traj = combo.split("+")
    return GAZES[gaze], TRAJECTORIES[traj][profile]


def label_of(combo: str, profile: str) -> str:
    """The planner_label rows of ``combo`` carry under ``profile``: the combo's name in the thesis files, pbdyn's
    default "gaze+trajectory" label in the physical files."""
    return combo if profile == "thesis_program" else "+".join(planner_of(combo, profile))


def combo_of(label: str, profile: str) -> str | None:
    """The program combination of a stored planner_label (None: not one of COMBOS)."""
    return next((c for c in COMBOS if label_of(c, profile) == label), None)


def entry_combo(entry: dict, profile: str) -> str | None:
    """The program combination of a [[planners]] entry (by its label: name, else gaze+trajectory)."""
    return combo_of(entry.get("name") or f"{entry.get('gaze')}+{entry.get('trajectory')}", profile)


QUICK_MAPS = 5
QUICK_UNCONTROLLED_MAPS = 2
QUICK_COMBOS = ("NoControl+Jerk_Primitive", "Oxford+Primitive", "LookAhead+MPC")
"""The thesis' three combinations of the uncontrolled sets (thesis 4-3-1: best, worst and a third)."""
QUICK_PAIRS = tuple(planner_of(c, "physical") for c in QUICK_COMBOS)
"""QUICK_COMBOS as physical (gaze, trajectory) pairs."""
QUICK_VMAX = (4.0,)
QUICK_CANDIDATES = ((4.0, 4.0), (4.0, 46.0), (46.0, 4.0), (46.0, 46.0), (25.0, 25.0))
"""The four corner candidates and the centre: 20 ordered start/goal pairs, every flight crossing the arena (3D: at
z = 10 m, the default candidates' height)."""

COMPARE_MAPS = 3
COMPARE_MORE_MAPS = 1
COMPARE_UNCONTROLLED_MAPS = 2
COMPARE_VMAX = (2.0, 4.0, 6.0)
COMPARE_COMBOS = ("LookAhead+Jerk_Primitive", "NoControl+Jerk_Primitive", "NoControl+Primitive", "NoControl+MPC")
"""The four main combinations of the comparison, on COMPARE_MAPS maps per setup."""
COMPARE_MORE_COMBOS = ("Owl+Jerk_Primitive", "Oxford+Primitive")
"""Two more, at reduced scale (COMPARE_MORE_MAPS map per setup, a second store)."""

# ------------------------------------------------------------------------------------------------ reference
REFERENCE_SOURCE = ("issue 13: the thesis program's pooled success / dynamic collision / deadlock rates per MAV "
                    "speed, 20 maps x 27 setups x 72 pairs each (the controlled map dataset)")
REFERENCE_MAPS_PER_SETUP = 20
"""The program's maps per setup behind the reference rates: map ids 0..19, the same ids for every setup."""
REFERENCE_TRIALS = REFERENCE_MAPS_PER_SETUP * 27 * 72
"""Trials behind each reference rate (one combo, one MAV speed)."""
REFERENCE_OUTCOMES = (Outcome.SUCCESS, Outcome.DYNAMIC_COLLISION, Outcome.DEADLOCK)
REFERENCE_SPEEDS = (2.0, 4.0, 6.0)
REFERENCE_RATES = {
    # combo: per MAV speed in REFERENCE_SPEEDS, the rates of REFERENCE_OUTCOMES
    "LookAhead+Jerk_Primitive": ((0.399, 0.575, 0.026), (0.706, 0.291, 0.002), (0.782, 0.216, 0.000)),
    "NoControl+Jerk_Primitive": ((0.511, 0.402, 0.087), (0.803, 0.193, 0.003), (0.868, 0.128, 0.000)),
    "NoControl+Primitive": ((0.356, 0.326, 0.318), (0.450, 0.324, 0.226), (0.529, 0.407, 0.061)),
    "NoControl+MPC": ((0.527, 0.426, 0.047), (0.519, 0.427, 0.054), (0.405, 0.546, 0.038)),
    "Owl+Jerk_Primitive": ((0.380, 0.591, 0.029), (0.650, 0.347, 0.001), (0.651, 0.348, 0.000)),
    "Oxford+Primitive": ((0.244, 0.616, 0.140), (0.329, 0.559, 0.111), (0.452, 0.511, 0.032)),
}
"""The program's pooled rates (REFERENCE_SOURCE)."""


def reference_table() -> dict[str, dict[float, dict[str, float]]]:
    """REFERENCE_RATES as combo -> MAV speed -> outcome name -> rate (tools/agreement.py's input)."""
    return {combo: {v: {o.value: r for o, r in zip(REFERENCE_OUTCOMES, rates)}
                    for v, rates in zip(REFERENCE_SPEEDS, per)} for combo, per in REFERENCE_RATES.items()}


THESIS_TABLE_4_5 = ((0.501, 0.068, 0.571, 0.193), (0.511, 0.068, 0.568, 0.184), (0.551, 0.073, 0.516, 0.173),
                    (0.932, 0.023, 0.230, 0.095), (0.941, 0.025, 0.211, 0.087), (0.607, 0.044, 0.242, 0.078),
                    (0.651, 0.077, 0.461, 0.161), (0.658, 0.077, 0.473, 0.165))
"""Thesis table 4-5: (SRCC mean, std, CV mean, std) of its rows, in row order (pbdyn.metrics.catalog.TABLE_ORDER)."""


# ------------------------------------------------------------------------------------------------ documents
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def to_toml(doc: dict) -> str:
    """A small TOML writer for scenario documents (tables, arrays of tables, scalars, arrays, inline tables)."""
    lines = []
    for k, v in doc.items():
        if not isinstance(v, (dict, list)) or (isinstance(v, list) and not any(isinstance(x, dict) for x in v)):
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"\n[{k}]")
            lines += [f"{a} = {_toml_value(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines.append(f"\n[[{k}]]")
                lines += [f"{a} = {_toml_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


def dataset_path(name: str, profile: str = "physical") -> Path:
    """The shipped scenario file of dataset ``name`` (e.g. "controlled_2d") under ``profile``."""
    return PROFILES[profile] / f"{name}.toml"


def dataset_doc(name: str, profile: str = "physical") -> dict:
    """The shipped scenario document of dataset ``name`` under ``profile``."""
    return tomllib.loads(dataset_path(name, profile).read_text())


def select(doc: dict, combos, profile: str, *, in_given_order: bool) -> list[dict]:
    """The [[planners]] entries of ``doc`` whose program combination is in ``combos`` (in the order of ``combos``
    with ``in_given_order``, else the document's)."""
    entries = [(entry_combo(e, profile), e) for e in doc["planners"]]
    if in_given_order:
        return [e for c in combos for k, e in entries if k == c]
    return [e for k, e in entries if k in combos]


def quick_candidates(doc: dict) -> list[list[float]]:
    """The quick scale's start/goal candidates of a dataset document: of its 9 candidates (given or default), the
    four corners and the centre, in QUICK_CANDIDATES' order ({4, 46}^2 and (25, 25) in the 50 m arena; in the thesis
    files' 48 m arena {3, 45}^2 and (24, 24))."""
    cands = np.asarray(parse_scenario({k: v for k, v in doc.items() if k != "planners"}).task.candidates, float)
    lo, hi = cands[:, :2].min(axis=0), cands[:, :2].max(axis=0)
    mid = (lo + hi) / 2.0
    corner_of = {(4.0, 4.0): (lo[0], lo[1]), (4.0, 46.0): (lo[0], hi[1]), (46.0, 4.0): (hi[0], lo[1]),
                 (46.0, 46.0): (hi[0], hi[1]), (25.0, 25.0): (mid[0], mid[1])}
    out = []
    for q in QUICK_CANDIDATES:
        xy = np.array(corner_of[q])
        out.append(cands[int(np.argmin(np.linalg.norm(cands[:, :2] - xy, axis=1)))].tolist())
    return out


def quick_doc(name: str, profile: str = "physical", combos=None) -> dict:
    """The reduced scenario document of dataset ``name`` at scale quick (see the module docstring); ``combos``
    (None: all) restricts its planners."""
    doc = dataset_doc(name, profile)
    controlled = name.startswith("controlled")
    doc["name"] = f"{doc['name']}_quick"
    doc["obstacles"]["maps_per_setup"] = QUICK_MAPS if controlled else QUICK_UNCONTROLLED_MAPS
    doc["drone"]["v_max"] = list(QUICK_VMAX)
    doc["task"] = {**doc.get("task", {}), "candidates": quick_candidates(doc)}
    wanted = [c for c in QUICK_COMBOS if combos is None or c in combos]
    if controlled:
        doc["planners"] = select(doc, wanted, profile, in_given_order=True)
    else:
        keep = select(doc, wanted, profile, in_given_order=False)
        if not keep and combos is None:
            keep = select(doc, QUICK_COMBOS[:1], profile, in_given_order=True)
        doc["planners"] = keep
    return doc


def compare_docs(name: str, profile: str = "physical", combos=None, maps: int | None = None) -> list[tuple[str, dict]]:
    """(role, document) of the stores of dataset ``name`` at scale compare (see the module docstring): the
    controlled set gives ("controlled", NAME_compare) and ("controlled_more", NAME_compare_more), an uncontrolled
    set ("uncontrolled", NAME_compare). ``combos`` (None: all) restricts their planners; ``maps`` (None:
    COMPARE_MAPS) sets the main controlled store's maps per setup (another number: store NAME_compare_mapsN)."""
    base = dataset_doc(name, profile)
    out = []
    if name.startswith("controlled"):
        main = "compare" if maps in (None, COMPARE_MAPS) else f"compare_maps{maps}"
        parts = (("controlled", main, maps or COMPARE_MAPS, COMPARE_COMBOS),
                 ("controlled_more", "compare_more", COMPARE_MORE_MAPS, COMPARE_MORE_COMBOS))
    else:
        parts = (("uncontrolled", "compare", COMPARE_UNCONTROLLED_MAPS, None),)
    for role, suffix, maps, own in parts:
        doc = json.loads(json.dumps(base))
        doc["name"] = f"{base['name']}_{suffix}"
        doc["obstacles"]["maps_per_setup"] = maps
        doc["drone"]["v_max"] = list(COMPARE_VMAX)
        # the file's own [task] stays: its 9 candidates, 72 ordered pairs (the thesis files: the 48 m arena's 3, 24, 45)
        wanted = [c for c in (own or COMBOS) if combos is None or c in combos]
        doc["planners"] = select(doc, wanted, profile, in_given_order=own is not None)
        out.append((role, doc))
    return out


@dataclass(frozen=True)
class StoreJob:
    """One store of a run: role ("controlled", "controlled_more" or "uncontrolled"), its scenario document, and
    the shipped file it is exactly (scale full, no --combos), else None (the document is written out)."""

    role: str
    doc: dict
    shipped: Path | None = None

    @property
    def name(self) -> str:
        """The scenario's name (the store is NAME.sqlite)."""
        return self.doc["name"]


def store_jobs(profile: str, scale: str, dims: int = 2, combos=None, maps: int | None = None) -> list[StoreJob]:
    """Every store of ``scale`` under ``profile`` (``combos``: None = all; stores left without planners are
    dropped; ``maps``: compare_docs), controlled first."""
    jobs = []
    for name in (f"{s}_{dims}d" for s in SETS):
        role = "controlled" if name.startswith("controlled") else "uncontrolled"
        if scale == "quick":
            jobs.append(StoreJob(role, quick_doc(name, profile, combos)))
        elif scale == "full":
            doc = dataset_doc(name, profile)
            if combos is None:
                jobs.append(StoreJob(role, doc, dataset_path(name, profile)))
            else:
                doc["planners"] = select(doc, combos, profile, in_given_order=False)
                jobs.append(StoreJob(role, doc))
        else:
            jobs += [StoreJob(r, d) for r, d in compare_docs(name, profile, combos, maps)]
    return [j for j in jobs if j.doc["planners"]]


def _label(entry: dict) -> str:
    return entry.get("name") or f"{entry.get('gaze')}+{entry.get('trajectory')}"


def stored_scenario(store: Path) -> dict | None:
    """The resolved scenario a store was made with (None: no store yet, or none recorded)."""
    if not store.is_file() or store.stat().st_size == 0:
        return None
    st = ResultsStore.open(store, field="out")
    try:
        raw = st.get_meta("scenario")
    finally:
        st.close()
    return json.loads(raw) if raw else None


def reconcile(doc: dict, store: Path) -> tuple[dict, bool]:
    """(document, grows): ``doc`` with its planners ordered as the existing ``store`` holds them, the new ones
    after (pbdyn batch accepts appended planners with --extend); grows = it adds planners. ConfigError if the store
    holds combos ``doc`` lacks (a narrower --combos than an earlier run)."""
    old = stored_scenario(store)
    if old is None:
        return doc, False
    stored = [_label(e) for e in old.get("planners", [])]
    by_label = {_label(e): e for e in doc["planners"]}
    lacking = [s for s in stored if s not in by_label]
    if lacking:
        raise ConfigError("combos", f"{store.name} already holds {', '.join(lacking)}; include them (their finished "
                          "trials are not flown again) or use another --out folder", show_value=False)
    new = [e for e in doc["planners"] if _label(e) not in stored]
    planners = [by_label[s] for s in stored] + new
    return (doc if planners == doc["planners"] else {**doc, "planners": planners}), bool(new)


# ------------------------------------------------------------------------------------------------ the report
def trial_table(stores: list[Path], profile: str) -> pd.DataFrame:
    """One row per stored trial of ``stores`` with tools/agreement.py's COLUMNS: combo (the program's name of the
    row's planner_label under ``profile``, else the label itself), label, mav_speed, outcome, map (map_key) and
    setup ("count|radius|speed")."""
    if not stores:
        raise ConfigError("RESULTS", "no store to compare", [])
    frames = []
    for path in stores:
        st = ResultsStore.open(path)
        try:
            names, rows = st.trial_rows(["planner_label", "mav_speed", "outcome", "map_key", "obstacle_count",
                                         "obstacle_radius", "obstacle_speed"])
            obstacles = json.loads(st.get_meta("scenario") or "{}").get("obstacles", {})
        finally:
            st.close()
        frame = pd.DataFrame(rows, columns=names)
        if obstacles.get("layout") == "program":     # the program's own maps: its map id (tools/agreement.py)
            root = int(obstacles.get("root_seed", 0))
            frame["seed"] = [str(root + json.loads(k)["replicate"]) for k in frame["map_key"]]
        else:
            frame["seed"] = ""
        frames.append(frame)
    df = pd.concat(frames, ignore_index=True)
    out = pd.DataFrame({"label": df["planner_label"].astype(str), "mav_speed": df["mav_speed"].astype(float),
                        "outcome": df["outcome"].astype(str), "map": df["map_key"].astype(str),
                        "setup": df["obstacle_count"].astype(str) + "|" + df["obstacle_radius"].astype(str) + "|"
                        + df["obstacle_speed"].astype(str), "seed": df["seed"].astype(str)})
    combos = {lab: combo_of(lab, profile) or lab for lab in out["label"].unique()}
    out.insert(0, "combo", out["label"].map(combos))
    return out


def agreement_notes(profile: str, scale: str, stores: list[Path]) -> list[str]:
    """The paragraphs above the agreement table: what is compared with what, and how."""
    notes = [f"pbdyn profile **{profile}**, scale {scale}; stores: {', '.join(p.name for p in stores)}.",
             f"Reference: {REFERENCE_SOURCE}; {REFERENCE_TRIALS} trials per combo and MAV speed."]
    if profile == "physical":
        notes.append("The pbdyn rows are the **physical counterparts** of the program's combos (labels "
                     "gaze+trajectory: Jerk_Primitive = local_primitives, Primitive = global_primitives, "
                     "NoControl = fullrange, Oxford = finean), flown under pbdyn's physical profile; the reference "
                     "is the program's.")
    if scale == "quick":
        notes.append(f"Scale quick flies {len(QUICK_CANDIDATES) * (len(QUICK_CANDIDATES) - 1)} start/goal pairs "
                     f"(corners and centre) at MAV {', '.join(f'{v:g}' for v in QUICK_VMAX)} m/s, not the "
                     "reference's 72 pairs: the comparison is indicative only.")
    notes.append("pbdyn's 95% CI: Rao-Wu bootstrap over maps stratified by setup (maps cluster trials). Within "
                 "sampling noise: |diff| <= 1.96 sqrt(se^2 + se_ref^2) + 0.0005, with se_ref the reference's binomial "
                 "se times pbdyn's design effect (deff) of the cell; on the program's own maps (\"s\") the "
                 "bootstrap resamples map ids and se_ref = 0, se scaled by sqrt(1 - m / 20) for m of the "
                 "reference's 20 ids; see tools/agreement.py.")
    return notes


def write_agreement(out: Path, stores: list[Path], profile: str, scale: str, n_boot: int) -> str:
    """Compute the agreement of ``stores`` with the reference, write agreement.md and agreement.json into ``out``
    and return the markdown."""
    result = agreement(trial_table(stores, profile), reference_table(), ref_trials=REFERENCE_TRIALS,
                       ref_seeds=REFERENCE_MAPS_PER_SETUP,
                       n_boot=n_boot, seed=0)
    notes = agreement_notes(profile, scale, stores)
    result.update({"profile": profile, "scale": scale, "stores": [p.name for p in stores],
                   "reference_source": REFERENCE_SOURCE,
                   "reference_outcomes": [o.value for o in REFERENCE_OUTCOMES], "notes": notes,
                   "stored_profiles": sorted({str((stored_scenario(p) or {}).get("profile", "not recorded"))
                                              for p in stores})})
    title = "pbdyn against the thesis program: pooled outcome rates per combo and MAV speed"
    md = format_markdown(result, [o.value for o in REFERENCE_OUTCOMES], title=title, notes=notes)
    (out / "agreement.json").write_text(json.dumps(json_ready(result), sort_keys=True, indent=1, allow_nan=False))
    (out / "agreement.md").write_text(md)
    return md


def side_by_side(dir_physical: Path, dir_thesis: Path, out: Path) -> str:
    """Write side_by_side.md into ``out`` from two output folders' report.json and agreement.json (either may be
    missing) and return it."""
    def load(path: Path):
        return json.loads(path.read_text()) if path.is_file() else None

    dirs = {"physical": dir_physical, "thesis_program": dir_thesis}
    md = (f"# pbdyn under the physical and thesis_program profiles\n\nphysical: {dir_physical}; thesis_program: "
          f"{dir_thesis}.\n\n") + format_side_by_side(
        {p: load(d / "report.json") for p, d in dirs.items()}, {p: load(d / "agreement.json") for p, d in dirs.items()},
        dict(zip(TABLE_ORDER, THESIS_TABLE_4_5)), reference_table(), [o.value for o in REFERENCE_OUTCOMES])
    out.mkdir(parents=True, exist_ok=True)
    (out / "side_by_side.md").write_text(md)
    return md


# ------------------------------------------------------------------------------------------------ the command
def _combos_arg(text: str) -> tuple[str, ...]:
    names = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in names if c not in COMBOS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"unknown combo {', '.join(bad) or repr(text)} (known: {', '.join(COMBOS)})")
    return names


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", choices=tuple(PROFILES), default="physical")
    ap.add_argument("--scale", choices=SCALES, default="quick")
    ap.add_argument("--dims", type=int, choices=(2, 3), default=2, help="the 2D datasets (default) or their 3D counterparts")
    ap.add_argument("--out", help="output folder (default results/reproduce[-PROFILE]-SCALE)")
    ap.add_argument("--workers", type=int, help="local worker processes (default: CPU count)")
    ap.add_argument("--scheduler", help="Dask scheduler address")
    ap.add_argument("--bootstrap", type=int, default=1000)
    ap.add_argument("--extend", action="store_true", help="accept grown grids in existing stores (pbdyn batch --extend)")
    ap.add_argument("--combos", type=_combos_arg, help="fly only these program combos (comma-separated, e.g. "
                    "LookAhead+Jerk_Primitive,NoControl+Jerk_Primitive)")
    ap.add_argument("--skip-uncontrolled", action="store_true", help="fly the controlled set only")
    ap.add_argument("--maps", type=int, help="compare: maps per setup of the main controlled store (default "
                    f"{COMPARE_MAPS}; another number writes NAME_compare_mapsN)")
    ap.add_argument("--limit", type=int, help="fly only the first N trials of each store (smoke runs)")
    ap.add_argument("--side-by-side", nargs=2, metavar=("DIR_PHYSICAL", "DIR_THESIS"),
                    help="write side_by_side.md (into --out, default DIR_THESIS) from two output folders and stop")
    args = ap.parse_args(argv)
    if args.dims == 3 and (args.profile != "physical" or args.scale == "compare"):
        ap.error("--dims 3 exists for the physical profile at scales quick and full (the program and its "
                 "reference rates are 2D)")
    return args


def default_out(profile: str, scale: str, dims: int) -> Path:
    """results/reproduce-SCALE (physical) or results/reproduce-thesis_program-SCALE, "-3d" for --dims 3."""
    tag = "" if profile == "physical" else f"{profile}-"
    return ROOT / "results" / f"reproduce-{tag}{scale}{'' if dims == 2 else '-3d'}"


def main(argv: list[str] | None = None) -> int:
    """Run the command (see the module docstring); returns the exit status (2: bad input, one line on stderr)."""
    args = parse_args(argv)
    if args.side_by_side:
        phys, thesis = (Path(d) for d in args.side_by_side)
        missing = [str(d) for d in (phys, thesis) if not d.is_dir()]
        if missing:
            sys.stderr.write(f"reproduce: --side-by-side: not a folder: {', '.join(missing)}\n")
            return 2
        sys.stdout.write(side_by_side(phys, thesis, Path(args.out) if args.out else thesis))
        return 0
    try:
        return _run(args)
    except ConfigError as exc:
        sys.stderr.write(f"reproduce: {exc}\n")
        return 2
    except BatchInterrupted as exc:
        sys.stderr.write(f"reproduce: {exc}\n")
        return exc.exit_status


def _run(args: argparse.Namespace) -> int:
    """The batches, then table 4-5 and the agreement report of every store of the scale in the output folder."""
    if args.maps is not None and (args.scale != "compare" or args.maps < 1):
        raise ConfigError("maps", "is an integer >= 1 and only for --scale compare", args.maps)
    out = Path(args.out) if args.out else default_out(args.profile, args.scale, args.dims)
    out.mkdir(parents=True, exist_ok=True)
    command = f"tools/reproduce.py --profile {args.profile} --scale {args.scale}"
    t0 = time.perf_counter()
    every = store_jobs(args.profile, args.scale, args.dims, maps=args.maps)
    run = [j for j in store_jobs(args.profile, args.scale, args.dims, args.combos, args.maps)
           if not (args.skip_uncontrolled and j.role == "uncontrolled")]
    for job in run:
        store = out / f"{job.name}.sqlite"
        doc, grows = reconcile(job.doc, store)
        path = job.shipped if job.shipped is not None and doc is job.doc else out / "scenarios" / f"{job.name}.toml"
        if path != job.shipped:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(to_toml(doc))
        scenario = parse_scenario(tomllib.loads(path.read_text()), str(path))
        sys.stderr.write(f"reproduce: {scenario.name} -> {store}{' (adding combos)' if grows else ''}\n")
        s = run_batch(scenario, store, BatchOptions(workers=args.workers, scheduler=args.scheduler,
                                                    extend=args.extend or grows, limit=args.limit), command=command)
        sys.stderr.write(f"reproduce: {scenario.name}: {s.total} trials ({s.ran} run now, {s.errors} errors) in "
                         f"{s.wall_time_s:.0f} s\n")
    present = {j.role: [] for j in every}
    for j in every:
        if (out / f"{j.name}.sqlite").is_file():
            present[j.role].append(out / f"{j.name}.sqlite")
    status = 0
    if present.get("controlled"):
        stores = present["controlled"] + present.get("uncontrolled", [])
        try:
            report, table, figures = evaluate_stores(stores, plots=out / "figures", n_boot=args.bootstrap)
        except ConfigError as exc:
            sys.stderr.write(f"reproduce: evaluate: {exc}\n")
            status = 1
        else:
            (out / "report.json").write_text(json.dumps(report, sort_keys=True, indent=1, allow_nan=False))
            header = (f"pbdyn reproduction of thesis table 4-5, profile {args.profile}, scale {args.scale}: "
                      f"{', '.join(p.stem for p in stores)}; {time.perf_counter() - t0:.0f} s wall for this "
                      "invocation\n")
            (out / "table.txt").write_text(header + table)
            sys.stdout.write(header + table.rstrip("\n") + "\n")
            sys.stderr.write(f"reproduce: table.txt, report.json and {len(figures)} figures in {out}\n")
    else:
        sys.stderr.write("reproduce: no controlled store yet: table 4-5 not evaluated\n")
    controlled = present.get("controlled", []) + present.get("controlled_more", [])
    if controlled and args.dims == 2:
        md = write_agreement(out, controlled, args.profile, args.scale, args.bootstrap)
        sys.stdout.write("\n" + md)
        sys.stderr.write(f"reproduce: agreement.md and agreement.json in {out}\n")
    return status


if __name__ == "__main__":
    sys.exit(main())
