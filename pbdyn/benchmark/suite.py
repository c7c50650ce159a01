"""Frozen benchmark suites (docs/benchmark.md; docs/benchmark.md).

A suite is a folder of the bundled scenarios, ``suites/<name>/``, holding ``suite.json`` (the manifest) and the
scenario files of its *parts*: one part per scenario file the suite's maps come from (a file of generated maps, or
one imported world). The manifest names the suite and its version, its dims, the MAV speeds every task is flown
at, its difficulty levels and, per map, its part, index and id in that part, its generator family, its level and
its measured difficulty on the anchored scale (pbdyn.analysis.scale: the reference panel's success on exactly the
suite's tasks of that map, with a 95% interval, and the difficulty in logits with its interval). A part's tasks are
the ordered start/goal pairs ``pairs_flown`` of its manifest entry (default: the reference pairs,
pbdyn.analysis.scale.reference_pairs) at each of the suite's speeds.

Levels (docs/benchmark.md "Levels"). A v1 suite measured each map's level and difficulty from the reference panel's
flights on the suite's own tasks, the flights its cards compare against: selection-biased (a map the panel was
unlucky on lands on a harder level, where any other planner then looks better). A suite whose manifest holds
``levels_from`` measures them on held-out tasks instead: the ordered pairs ``pairs_leveled`` of each part's entry
(the start/goal candidates the suite's tasks leave out: no start or goal in common), flown by the panel at the
suite's speeds; the panel's flights on the suite's tasks are flown separately and are the references.

A suite's identity is its content hash (suite_hash): the sha256 of the manifest and of every part's resolved
scenario (canonical JSON), printed on every score card; a test fixes the shipped suites' hashes. The manifest records
the digest of the suite's reference results (``references_sha256``: references_digest of reference.json.gz), which
pbdyn.benchmark.run.load_references checks before a card uses them. A "pbdyn-suite/2" manifest's hash covers that
digest; a "pbdyn-suite/1" manifest's hash leaves it out (the digest was recorded after those suites were frozen, and
their hash, quoted in papers, stays), so a v1 suite's references are checked against the manifest at load only.
"""

from __future__ import annotations

import copy
import hashlib
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

from pbdyn.config import PlannerEntry, Scenario, canonical_json, parse_scenario
from pbdyn.errors import ConfigError

SUITE_FILE = "suite.json"
SUITE_FORMAT = "pbdyn-suite/2"
SUITE_FORMATS = ("pbdyn-suite/1", SUITE_FORMAT)
"""Manifest formats this pbdyn reads: 1 (hash without the references' digest), 2 (module doc)."""
REFERENCES_DIGEST = "references_sha256"
"""The manifest key of the reference results' digest (references_digest)."""
SUITES_FOLDER = "suites"
LEVELS_FROM = "levels_from"
"""The manifest key that says a suite's levels were measured on held-out tasks (module doc)."""
V1_LEVELS_TEXT = ("levels and difficulties were measured from the reference panel's flights on the suite's own tasks, "
                  "the same flights this card compares against: selection-biased (the references' success is "
                  "understated at the hard levels and overstated at the easy ones, so a new planner's lead over "
                  "them grows toward the hard end; docs/benchmark.md#levels)")
"""How a suite without ``levels_from`` assigned its levels."""


@dataclass(frozen=True)
class Part:
    """One scenario file of a suite: ``name``, the scenario ``path``, its document (TOML-shaped dict) and the
    ordered start/goal candidate pairs flown on its maps (``pairs``, candidate indices)."""

    name: str
    path: Path
    doc: dict
    pairs: tuple
    level_pairs: tuple = ()
    """The held-out pairs its maps' levels are measured on (``pairs_leveled``; () when the suite has none)."""


@dataclass(frozen=True)
class Suite:
    """A loaded suite: its manifest (``doc``), folder and parts; ``maps`` are the manifest's map entries."""

    name: str
    version: str
    dims: int
    speeds: tuple
    levels: tuple
    maps: tuple
    parts: tuple
    doc: dict
    folder: Path

    @property
    def hash(self) -> str:
        """The suite's identity (module doc)."""
        return suite_hash(self)

    @property
    def id_rule(self) -> str:
        """The rule its manifest names maps by (pbdyn.world.maps.MAP_ID_RULE): "setup-1" for a pbdyn-suite/1
        manifest (frozen before map ids covered the world: ids may repeat across parts), else "content-1"."""
        return "setup-1" if self.doc.get("format") == "pbdyn-suite/1" else "content-1"

    def row_map_id(self, row: dict) -> str:
        """The id this suite's manifest and references name a flown row's map by (id_rule; a v1 suite's from the
        row's map key)."""
        from pbdyn.world.maps import legacy_map_id

        return legacy_map_id(row["map_key"]) if self.id_rule == "setup-1" else row["map_id"]

    def spec_map_id(self, spec) -> str:
        """The id this suite names a MapSpec by (id_rule)."""
        return spec.setup_id if self.id_rule == "setup-1" else spec.map_id

    def part(self, name: str) -> Part:
        """The part called ``name``."""
        for p in self.parts:
            if p.name == name:
                return p
        raise ConfigError("part", f"is not a part of suite {self.name}", name)

    def map_level(self, part: str, map_id: str) -> int:
        """The level the manifest gives the map ``map_id`` of part ``part`` (a level: pbdyn.benchmark.levels)."""
        for m in self.maps:
            if m["part"] == part and m["map_id"] == map_id:
                return int(m["level"])
        raise ConfigError("map", f"is not a map of part {part} of suite {self.name}", map_id)

    @property
    def levels_text(self) -> str:
        """How the suite's levels were assigned, in one paragraph (module doc)."""
        src = self.doc.get(LEVELS_FROM)
        if isinstance(src, dict) and src.get("text"):
            return str(src["text"])
        return V1_LEVELS_TEXT

    def n_tasks(self) -> int:
        """Tasks (map x pair x speed) in the suite."""
        per_part = {p.name: len(p.pairs) for p in self.parts}
        return sum(per_part[m["part"]] for m in self.maps) * len(self.speeds)


def suites_dir() -> Path:
    """The folder of the bundled suites."""
    from pbdyn import resources

    return resources.scenarios_dir() / SUITES_FOLDER


def suite_names() -> list[str]:
    """Names of the bundled suites."""
    root = suites_dir()
    return sorted(p.parent.name for p in root.glob(f"*/{SUITE_FILE}")) if root.is_dir() else []


def load_suite(name_or_path) -> Suite:
    """The suite ``name_or_path``: a bundled suite's name ("pbdyn-2d-v1") or a suite folder / suite.json path."""
    if not isinstance(name_or_path, (str, Path)) or not str(name_or_path):
        raise ConfigError("suite", "must be a suite name or a suite folder", name_or_path)
    p = Path(name_or_path)
    if p.is_dir():
        p = p / SUITE_FILE
    if not p.is_file():
        bundled = suites_dir() / str(name_or_path) / SUITE_FILE
        if not bundled.is_file():
            raise ConfigError("suite", "is neither a bundled suite (" + ", ".join(suite_names()) +
                              ") nor a suite folder", str(name_or_path))
        p = bundled
    return suite_from_doc(read_versioned_json(p, "suite", "format", SUITE_FORMATS, "manifest"), p.parent)


def read_versioned_json(path: Path, field: str, key: str, version, what: str, shown=None) -> dict:
    """The JSON object in ``path`` whose ``key`` is ``version`` (or one of a tuple of versions); else ConfigError
    naming ``field`` and ``shown`` (default: the path) -- unreadable, or not a ``version`` ``what``."""
    versions = version if isinstance(version, tuple) else (version,)
    shown = str(path) if shown is None else shown
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(field, f"cannot be read ({exc.__class__.__name__})", shown) from None
    if not isinstance(doc, dict) or doc.get(key) not in versions:
        raise ConfigError(field, f"is not a {' or '.join(versions)} {what}", shown)
    return doc


def suite_from_doc(doc: dict, folder: Path) -> Suite:
    """A Suite from a manifest dict whose part files are relative to ``folder`` (or bundled scenario names)."""
    from pbdyn import resources
    from pbdyn.analysis.scale import reference_pairs

    parts = []
    for entry in doc["parts"]:
        path = folder / entry["scenario"]
        if not path.is_file():
            path = resources.find_scenario(entry["scenario"])
        part_doc = tomllib.loads(path.read_text(encoding="utf-8"))
        pairs = entry.get("pairs_flown")
        if pairs is None:
            sc = parse_scenario(part_doc, path)
            pairs = reference_pairs(sc.task.candidates)
        leveled = entry.get("pairs_leveled") or ()
        parts.append(Part(str(entry["name"]), path, part_doc, tuple(tuple(int(i) for i in q) for q in pairs),
                          tuple(tuple(int(i) for i in q) for q in leveled)))
    return Suite(str(doc["name"]), str(doc["version"]), int(doc["dims"]), tuple(float(v) for v in doc["speeds"]),
                 tuple(doc["levels"]), tuple(doc["maps"]), tuple(parts), doc, folder)


def suite_hash(suite: Suite) -> str:
    """sha256 (hex) over the manifest and every part's resolved scenario, in canonical JSON (a v1 manifest without
    its references' digest: module doc)."""
    doc = suite.doc
    if doc.get("format") == "pbdyn-suite/1":
        doc = {k: v for k, v in doc.items() if k != REFERENCES_DIGEST}
    h = hashlib.sha256()
    h.update(canonical_json(doc).encode())
    for part in suite.parts:
        sc = parse_scenario(part.doc, part.path)
        h.update(b"\0" + part.name.encode() + b"\0" + canonical_json(sc.to_dict()).encode())
    return h.hexdigest()


def references_digest(doc: dict) -> str:
    """sha256 (hex) of a reference-results document in canonical JSON, without its "suite_hash" (the suite's hash
    may cover this digest, so the digest cannot cover the hash)."""
    return hashlib.sha256(canonical_json({k: v for k, v in doc.items() if k != "suite_hash"}).encode()).hexdigest()


def flight_levels(paths) -> dict[str, dict[str, int]]:
    """The levels of the suite maps in results stores flown by `pbdyn bench` (flight_document's scenario name
    "<suite>.<part>" of a shipped suite): scenario name -> {the store's map id: level}, for the stores whose flown
    world is the suite part's (the map ids the store holds are among the part's, by the suite's id rule); other
    stores are left out."""
    from pbdyn.experiments.store import ResultsStore

    names = set(suite_names())
    out: dict[str, dict[str, int]] = {}
    for path in paths:
        st = ResultsStore.open(path)
        try:
            name = str(json.loads(st.get_meta("scenario") or "{}").get("name") or "")
            suite_name, _, part = name.rpartition(".")
            if suite_name not in names:          # not a suite's flight store: its rows are not read
                continue
            results = st.results()
        finally:
            st.close()
        suite = load_suite(suite_name)
        levels = {m["map_id"]: int(m["level"]) for m in suite.maps if m["part"] == part and m.get("level")}
        held = {r["map_id"]: suite.row_map_id(r) for r in results}      # the store's id -> the suite's
        if levels and set(held.values()) <= set(levels):
            out[name] = {mid: levels[sid] for mid, sid in held.items()}
    return out


def flight_document(suite: Suite, part: Part, entries) -> dict:
    """The scenario document that flies ``entries`` (PlannerEntry list) on a part's suite maps: the part's
    document with those planners, the suite's speeds and the part's pairs, its maps cut to the suite's (an
    explicit map list keeps each map's setup, replicate and seed), named "<suite>.<part>"."""
    doc = copy.deepcopy(part.doc)
    doc["name"] = f"{suite.name}.{part.name}"
    doc["planners"] = [_entry_table(e) for e in entries]
    doc.setdefault("drone", {})["v_max"] = list(suite.speeds)
    doc.setdefault("task", {})["pairs_flown"] = [list(q) for q in part.pairs]
    return doc


def flight_scenario(suite: Suite, part: Part, entries) -> Scenario:
    """flight_document() parsed (relative paths resolve against the part's file)."""
    return parse_scenario(flight_document(suite, part, entries), part.path)


def _entry_table(e: PlannerEntry) -> dict:
    out = {"trajectory": e.trajectory, "gaze": e.gaze}
    if e.trajectory_params:
        out["trajectory_params"] = dict(e.trajectory_params)
    if e.gaze_params:
        out["gaze_params"] = dict(e.gaze_params)
    if e.name:
        out["name"] = e.name
    return out
