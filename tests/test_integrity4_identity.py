"""Integrity round 4: code identity by content (docs/design.md "Code identity").

Every test that edits pbdyn works on a copy of the checkout (pbdyn/, urdf/, scenarios/, setup.cfg) run with
``python -m pbdyn`` or ``python -c`` from the copy's folder, never on the repository's own files; each edit is
reverted byte for byte to show that the old identity, and the values cached under it, come back."""

from __future__ import annotations

import gzip
import json
import os
import random
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import copy_checkout

ROOT = Path(__file__).resolve().parents[1]

SCENARIO = """
name = "idcheck"
[world]
dims = 2
time_limit = 20.0
[obstacles]
count = [6]
radius = 1.0
speed = 2.0
maps_per_setup = 2
root_seed = 11
[drone]
v_max = [4.0]
[task]
candidates = [[4.0, 4.0], [46.0, 46.0], [4.0, 46.0]]
[[planners]]
trajectory = "straight_line"
gaze = "lookahead"
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
"""


@pytest.fixture(scope="module")
def checkout(tmp_path_factory):
    dest = copy_checkout(tmp_path_factory.mktemp("idcheckout"))
    cache = tmp_path_factory.mktemp("idcache")
    return dest, cache


def _env(cache: Path, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env.update(PYTHONHASHSEED="0", PBDYN_CACHE=str(cache), **extra)
    return env


def _py(checkout, code: str, **extra) -> str:
    dest, cache = checkout
    res = subprocess.run([sys.executable, "-c", code], cwd=dest, env=_env(cache, **extra), capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert res.stderr == "", res.stderr
    return res.stdout.strip()


def _cli(checkout, *args, **extra) -> subprocess.CompletedProcess:
    dest, cache = checkout
    return subprocess.run([sys.executable, "-m", "pbdyn", *map(str, args)], cwd=dest, env=_env(cache, **extra),
                          capture_output=True, text=True, timeout=600)


class _Edit:
    """Append text to a file of the copy; restore its bytes (and modification time) on exit."""

    def __init__(self, path: Path, text: str = "\n# an edit: the same behaviour, other code\n"):
        self.path, self.text = path, text

    def __enter__(self):
        self.old = self.path.read_bytes()
        self.stat = self.path.stat()
        self.path.write_bytes(self.old + self.text.encode())
        return self

    def __exit__(self, *exc):
        self.path.write_bytes(self.old)
        os.utime(self.path, ns=(self.stat.st_atime_ns, self.stat.st_mtime_ns + 1))


FPS = ("from pbdyn.planning.registry import planner_fingerprint as f; from pbdyn import codeid; "
       "import json; print(json.dumps({n: f(n) for n in ('lookahead', 'straight_line', 'local_primitives', 'mpc')}"
       " | {'core': codeid.core_identity()}))")


def test_editing_a_builtin_planner_changes_its_fingerprint_and_reverting_restores_it(checkout):
    dest, _ = checkout
    before = json.loads(_py(checkout, FPS))
    assert all(v.startswith("pbdyn:") for k, v in before.items() if k != "core")
    with _Edit(dest / "pbdyn" / "planning" / "gaze" / "rules.py"):
        edited = json.loads(_py(checkout, FPS))
    assert edited["lookahead"] != before["lookahead"]
    assert {k: edited[k] for k in ("straight_line", "mpc", "core")} == \
        {k: before[k] for k in ("straight_line", "mpc", "core")}
    with _Edit(dest / "pbdyn" / "planning" / "trajectory.py"):       # used by every trajectory planner
        edited = json.loads(_py(checkout, FPS))
    assert all(edited[k] != before[k] for k in ("straight_line", "local_primitives", "mpc"))
    assert json.loads(_py(checkout, FPS)) == before


def test_a_resumed_batch_refuses_rows_flown_by_an_edited_core_and_resumes_after_the_revert(checkout, tmp_path):
    dest, _ = checkout
    sc = tmp_path / "idcheck.toml"
    sc.write_text(SCENARIO)
    out = tmp_path / "core.sqlite"
    args = ["batch", sc, "--out", out, "--workers", "1", "--no-metrics", "--json"]
    res = _cli(checkout, *args, "--limit", "2")
    assert res.returncode == 0, res.stderr
    with sqlite3.connect(out) as c:
        first = {r[0] for r in c.execute("SELECT planner_fingerprint FROM trials")}
    with _Edit(dest / "pbdyn" / "sim" / "collision.py"):
        res = _cli(checkout, *args, "--limit", "4")
        assert res.returncode == 2
        line = res.stderr.strip()
        assert "\n" not in line and "--rerun-changed" in line and "planner code changed" in line
        assert "Traceback" not in res.stderr
    res = _cli(checkout, *args, "--limit", "4")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["ran"] == 2
    with sqlite3.connect(out) as c:
        fps = {r[0] for r in c.execute("SELECT planner_fingerprint FROM trials")}
    assert fps == first and all("+core:" in f for f in fps)     # the revert flies the first rows' code again


ROLLOUT_KEYS = """
import json
import pbdyn
from pbdyn.world.maps import enumerate_maps
from pbdyn.world.rollout import default_horizon, rollout_key
out = {}
for motion in ("cvm", "rvo"):
    sc = pbdyn.load_scenario({"obstacles": {"count": 5, "motion": motion}})
    out[motion] = rollout_key(sc, enumerate_maps(sc)[0], default_horizon(sc))
print(json.dumps(out))
"""


def test_an_edited_motion_model_changes_the_rollouts_of_its_own_maps_only(checkout):
    dest, _ = checkout
    before = json.loads(_py(checkout, ROLLOUT_KEYS))
    with _Edit(dest / "pbdyn" / "motion" / "rvo.py"):
        edited = json.loads(_py(checkout, ROLLOUT_KEYS))
    assert edited["rvo"] != before["rvo"] and edited["cvm"] == before["cvm"]
    with _Edit(dest / "pbdyn" / "world" / "maps.py"):                 # every generated map is spawned there
        edited = json.loads(_py(checkout, ROLLOUT_KEYS))
    assert edited["rvo"] != before["rvo"] and edited["cvm"] != before["cvm"]
    assert json.loads(_py(checkout, ROLLOUT_KEYS)) == before


def _density(checkout) -> dict:
    res = _cli(checkout, "metrics", "quickstart", "--map", "0", "--metric", "density", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    return doc["metrics"]["density"] if "metrics" in doc else doc["density"]


def test_the_metric_cache_never_serves_a_value_computed_by_other_code(checkout):
    dest, _ = checkout
    first = _density(checkout)
    again = _density(checkout)
    assert again["cached"] is True and again["value"] == first["value"]
    path = dest / "pbdyn" / "metrics" / "density.py"
    text = path.read_text()
    assert "def density(" in text
    doubled = text + ("\n\nimport functools\n_density_as_shipped = density\n\n\n"
                      "@functools.wraps(_density_as_shipped)\ndef density(rollout, **kw):\n"
                      "    res = _density_as_shipped(rollout, **kw)\n"
                      "    return type(res)(**{**vars(res), 'value': 2 * res.value})\n")
    with _Edit(path, doubled[len(text):]):
        edited = _density(checkout)
    assert edited["cached"] is False and edited["value"] == pytest.approx(2 * first["value"])
    back = _density(checkout)
    assert back["cached"] is True and back["value"] == first["value"]


def test_a_store_refuses_metrics_of_edited_metric_code_and_merge_refuses_two_versions(checkout, tmp_path):
    dest, _ = checkout
    sc = tmp_path / "idcheck.toml"
    sc.write_text(SCENARIO.replace("maps_per_setup = 2", "maps_per_setup = 1"))
    out = tmp_path / "metrics.sqlite"
    args = ["batch", sc, "--out", out, "--workers", "1", "--json"]
    res = _cli(checkout, *args, "--limit", "1")
    assert res.returncode == 0, res.stderr
    with sqlite3.connect(out) as c:
        (code,) = c.execute("SELECT metrics_code FROM maps").fetchone()
    assert code and len(code) == 16
    with _Edit(dest / "pbdyn" / "metrics" / "traversability.py"):   # a metric the trials do not use
        res = _cli(checkout, *args, "--limit", "2")
        assert res.returncode == 2
        line = res.stderr.strip()
        assert "\n" not in line and "metric's code changed" in line and "--rerun-changed" in line
        res = _cli(checkout, *args, "--limit", "2", "--rerun-changed")
        assert res.returncode == 0, res.stderr
        with sqlite3.connect(out) as c:
            (new_code,) = c.execute("SELECT metrics_code FROM maps").fetchone()
        assert new_code != code
    other = tmp_path / "other.sqlite"
    shutil.copy(out, other)
    with sqlite3.connect(other) as c:
        c.execute("UPDATE maps SET metrics_code = ?", (code,))
    res = _cli(checkout, "merge", out, other, "--out", tmp_path / "merged.sqlite")
    assert res.returncode == 2
    assert "\n" not in res.stderr.strip() and "were computed by code" in res.stderr
    assert not (tmp_path / "merged.sqlite").exists()


PLUGIN_FP = ("import sys; sys.path.insert(0, {path!r}); from pbdyn.planning.registry import planner_fingerprint; "
             "print(planner_fingerprint({name!r}))")


def test_a_plugin_is_identified_by_its_package_or_the_user_modules_it_imports(checkout, tmp_path):
    pkg = tmp_path / "user" / "vopkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "geometry.py").write_text("GAP = 1.0\n")
    (pkg / "planner.py").write_text("from pbdyn.planning.straight_line import StraightLine\n\n\n"
                                    "class VO(StraightLine):\n    pass\n")
    (tmp_path / "user" / "lone_helper.py").write_text("SCALE = 2.0\n")
    (tmp_path / "user" / "lone_plan.py").write_text(
        "import lone_helper\nfrom pbdyn.planning.straight_line import StraightLine\n\n\n"
        "class Lone(StraightLine):\n    pass\n")
    path = str(tmp_path / "user")

    def fp(name):
        return _py(checkout, PLUGIN_FP.format(path=path, name=name))

    pkg_before, lone_before = fp("vopkg.planner:VO"), fp("lone_plan:Lone")
    assert pkg_before.startswith("sha256:") and lone_before.startswith("sha256:")
    with _Edit(pkg / "geometry.py", "GAP = 2.0\n"):                   # a file of the package the planner lives in
        assert fp("vopkg.planner:VO") != pkg_before
    with _Edit(tmp_path / "user" / "lone_helper.py", "SCALE = 3.0\n"):  # a user module the plug-in imports
        assert fp("lone_plan:Lone") != lone_before
    with _Edit(checkout[0] / "pbdyn" / "planning" / "straight_line.py"):  # the pbdyn code it builds on
        assert fp("lone_plan:Lone") != lone_before and fp("vopkg.planner:VO") != pkg_before
    assert (fp("vopkg.planner:VO"), fp("lone_plan:Lone")) == (pkg_before, lone_before)


LOADED = """
import json, sys
import pbdyn
from pbdyn import codeid
from pbdyn.planning.registry import _entry_module
from pbdyn.world.rollout import rollout_code
traj, gaze = sys.argv[1:3]
from pbdyn.sim.trial import run_trial
from pbdyn.sim.spec import make_trial_spec
from pbdyn.world.maps import get_map
sc = pbdyn.load_scenario({"world": {"time_limit": 6.0}, "obstacles": {"count": 8},
                          "planners": [{"trajectory": traj, "gaze": gaze}]})
ro = pbdyn.rollout(sc, map=0)
before = {m for m in sys.modules if m.startswith("pbdyn")}
run_trial(make_trial_spec(sc, get_map(sc, 0), planner=sc.planners[0].label, start=(4.0, 4.0), goal=(46.0, 46.0)), ro)
loaded = {m for m in sys.modules if m.startswith("pbdyn")} - before
covered = set(codeid.pbdyn_closure(codeid.CORE_ROOTS, codeid.MOTION_MODELS))
covered |= set(codeid.pbdyn_closure([_entry_module(traj)])) | set(codeid.pbdyn_closure([_entry_module(gaze)]))
print(json.dumps(sorted(loaded - covered)))
"""


@pytest.mark.parametrize("traj, gaze", [("local_primitives", "lookahead"), ("global_primitives", "owl"),
                                        ("mpc", "finean"), ("local_primitives_minjerk", "lookgoal_unexplored"),
                                        ("straight_line", "rotating")])
def test_every_module_a_trial_loads_is_part_of_the_identity_of_its_rows(checkout, traj, gaze):
    """The identity is read from import statements; a trial must load no pbdyn module outside it."""
    dest, _ = checkout
    res = subprocess.run([sys.executable, "-c", LOADED, traj, gaze], cwd=dest, env=_env(checkout[1]),
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == []


def test_the_motion_models_listed_for_identities_are_the_registrys():
    from pbdyn import codeid
    from pbdyn.motion.registry import MODELS

    assert sorted(codeid.MOTION_MODELS) == sorted({type(m).__module__ for m in MODELS.values()})


def test_the_identity_record_is_cached_per_build_and_a_touch_changes_nothing(checkout):
    dest, cache = checkout
    before = json.loads(_py(checkout, FPS))
    records = list((cache / "code").glob("files-*.json"))
    assert len(records) == 1
    doc = json.loads(records[0].read_text())
    assert str(dest / "pbdyn" / "sim" / "trial.py") in doc
    p = dest / "pbdyn" / "sim" / "trial.py"
    st = p.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000))      # the same bytes, a new time: read again
    assert json.loads(_py(checkout, FPS)) == before


@pytest.mark.fuzz
def test_fuzz_an_edit_of_any_module_in_an_identity_changes_it_and_a_revert_restores_it(checkout):
    """Code edits in a copied checkout: seeded random pbdyn modules of the core's and the planners' identities
    get a comment; every identity whose closure holds the module changes, the others do not; the revert restores
    all of them."""
    dest, _ = checkout
    closures = json.loads(_py(checkout, (
        "import json; from pbdyn import codeid; from pbdyn.planning.registry import _entry_module as e; "
        "print(json.dumps({'core': codeid.pbdyn_closure(codeid.CORE_ROOTS, codeid.MOTION_MODELS), "
        "**{n: codeid.pbdyn_closure([e(n)]) for n in ('lookahead', 'straight_line', 'local_primitives', 'mpc')}}))")))
    modules = sorted(set().union(*closures.values()))
    before = json.loads(_py(checkout, FPS))
    rng = random.Random(41)
    for name in rng.sample(modules, 6):
        parts = name.split(".")[1:]
        path = dest.joinpath("pbdyn", *parts, "__init__.py")
        if not path.is_file():
            path = dest.joinpath("pbdyn", *parts[:-1], parts[-1] + ".py") if parts else dest / "pbdyn" / "__init__.py"
        with _Edit(path):
            edited = json.loads(_py(checkout, FPS))
        for key, closure in closures.items():
            assert (edited[key] != before[key]) == (name in closure), (name, key)
    assert json.loads(_py(checkout, FPS)) == before


# ------------------------------------------------------------------------------------- a suite's references
MINI = "pbdyn-2d-mini"


@pytest.fixture
def suite_copy(tmp_path):
    from pbdyn.benchmark.suite import load_suite

    folder = tmp_path / "suite"
    shutil.copytree(load_suite(MINI).folder, folder)
    return folder


def _bench(folder: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pbdyn", "bench", "straight_line", "--suite", str(folder), "--out",
                           str(out)], capture_output=True, text=True, timeout=600, cwd=ROOT)


def _rewrite(path: Path, change) -> None:
    doc = json.loads(gzip.decompress(path.read_bytes()))
    change(doc)
    path.write_bytes(gzip.compress(json.dumps(doc).encode()))


@pytest.mark.parametrize("case", ["tampered", "truncated", "foreign", "malformed", "missing"])
def test_a_bad_references_file_is_one_line_and_exit_2_before_anything_flies(suite_copy, tmp_path, case):
    from pbdyn.benchmark.suite import load_suite

    ref = suite_copy / "reference.json.gz"
    if case == "tampered":                       # one outcome changed, the suite's hash left as it was
        def flip(doc):
            doc["rows"][0][doc["columns"].index("outcome")] = "success"
        _rewrite(ref, flip)
    elif case == "truncated":
        ref.write_bytes(ref.read_bytes()[:200])
    elif case == "foreign":                      # another suite's references
        shutil.copy(load_suite("pbdyn-2d-v1").folder / "reference.json.gz", ref)
    elif case == "malformed":
        _rewrite(ref, lambda doc: doc.update(rows=[["x"]]))
    else:
        ref.unlink()
    out = tmp_path / "bench"
    res = _bench(suite_copy, out)
    assert res.returncode == 2, res.stderr
    line = res.stderr.strip()
    assert "\n" not in line and line.startswith("pbdyn: error: reference") and "Traceback" not in res.stderr
    assert str(ref) in line
    assert not out.exists() or not any(out.iterdir())


def test_the_shipped_manifests_record_their_references_digest_and_v1_hashes_stay():
    from pbdyn.benchmark.run import load_references
    from pbdyn.benchmark.suite import REFERENCES_DIGEST, load_suite, references_digest, suite_names

    fixed = {"pbdyn-2d-mini": "1ebf60b5ddf4", "pbdyn-2d-v1": "cdf42b856533", "pbdyn-3d-v1": "46f419e083d6"}
    for name in suite_names():
        s = load_suite(name)
        doc = json.loads(gzip.decompress((s.folder / "reference.json.gz").read_bytes()))
        assert s.doc[REFERENCES_DIGEST] == references_digest(doc)
        assert load_references(s)
        if name in fixed:
            assert s.hash.startswith(fixed[name])


def test_a_v2_manifest_hash_covers_the_references_digest(suite_copy):
    from pbdyn.benchmark.suite import REFERENCES_DIGEST, load_suite

    man = json.loads((suite_copy / "suite.json").read_text())
    h1 = load_suite(suite_copy).hash
    man[REFERENCES_DIGEST] = "0" * 64
    (suite_copy / "suite.json").write_text(json.dumps(man))
    assert load_suite(suite_copy).hash == h1                       # v1: the digest is checked at load only
    man["format"] = "pbdyn-suite/2"
    (suite_copy / "suite.json").write_text(json.dumps(man))
    h2 = load_suite(suite_copy).hash
    man[REFERENCES_DIGEST] = "1" * 64
    (suite_copy / "suite.json").write_text(json.dumps(man))
    assert load_suite(suite_copy).hash != h2


def test_the_card_says_whether_this_pbdyn_flies_the_references_code():
    from pbdyn.benchmark.card import code_provenance
    from pbdyn.planning.registry import pair_fingerprint

    now = pair_fingerprint("local_primitives", "lookahead")
    refs = {"a": {"meta": {"trajectory": "local_primitives", "gaze": "lookahead", "fingerprint": now}},
            "b": {"meta": {"trajectory": "mpc", "gaze": "lookahead", "fingerprint": "builtin:1+builtin:1"}}}
    doc = code_provenance({"fingerprint": now}, {"a": refs["a"]})
    assert doc["references"] == {"a": "same"} and "flies the references' code" in doc["statement"]
    doc = code_provenance({"fingerprint": now}, {"b": refs["b"]})
    assert doc["references"] == {"b": "not recorded"} and "unknown" in doc["statement"]
    stale = {"meta": {**refs["a"]["meta"], "fingerprint": now.replace("+core:", "+core:0")[:len(now)]}}
    doc = code_provenance({"fingerprint": now}, {"a": refs["a"], "c": stale})
    assert doc["references"] == {"a": "same", "c": "other"} and "1 of 2 references" in doc["statement"]


# ------------------------------------------------------------------------------------- the calibration's code
def test_the_calibration_records_its_code_and_says_whether_this_pbdyn_flies_it(tmp_path, monkeypatch):
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import fit_anchors as fa
    finally:
        sys.path.remove(str(ROOT / "tools"))
    from pbdyn.analysis.scale import PANEL, Anchors, load_anchors
    from pbdyn.experiments.runner import BatchOptions, run_batch
    from pbdyn.planning.registry import pair_fingerprint

    import pbdyn
    sc = pbdyn.load_scenario({"name": "calcode", "world": {"time_limit": 5.0}, "obstacles": {"count": 3},
                              "drone": {"v_max": [4.0]},
                              "planners": [{"trajectory": e.trajectory, "gaze": e.gaze} for e in PANEL]})
    store = tmp_path / "cal.sqlite"
    run_batch(sc, store, BatchOptions(workers=1, metrics=False, limit=len(PANEL) * 2))
    monkeypatch.setattr(fa, "DATA", tmp_path / "data")
    fa.export([store])
    code = json.loads((tmp_path / "data" / fa.CODE_FILE).read_text())["2d"]
    assert set(code) <= {e.label for e in PANEL} and code
    assert all(fps == [pair_fingerprint(e.trajectory, e.gaze)] for e in PANEL for fps in [code.get(e.label)] if fps)
    assert fa._recorded_code("2d") == {"code": code}
    shipped = load_anchors()
    assert shipped.code_status(pair_fingerprint) == "not recorded"   # fitted before pbdyn recorded code identities
    now = {e.label: [pair_fingerprint(e.trajectory, e.gaze)] for e in PANEL}
    assert Anchors(shipped.version, shipped.abilities, code=now).code_status(pair_fingerprint) == "same"
    stale = {**now, PANEL[0].label: ["sha256:0+pbdyn:0+core:0"]}
    assert Anchors(shipped.version, shipped.abilities, code=stale).code_status(pair_fingerprint) == "other"


def test_identifying_a_plugin_imports_nothing(checkout, tmp_path):
    """Its imports are read, not run: a module it names only inside a function stays unloaded."""
    (tmp_path / "lazy_plan.py").write_text(
        "from pbdyn.planning.straight_line import StraightLine\n\n\ndef later():\n    import gymnasium.spaces\n"
        "    import lazy_helper.deep\n\n\nclass Lazy(StraightLine):\n    pass\n")
    (tmp_path / "lazy_helper").mkdir()
    (tmp_path / "lazy_helper" / "__init__.py").write_text("raise RuntimeError('imported')\n")
    (tmp_path / "lazy_helper" / "deep.py").write_text("X = 1\n")
    code = (f"import sys; sys.path.insert(0, {str(tmp_path)!r}); import lazy_plan; "
            "from pbdyn.codeid import user_identity; a = user_identity('lazy_plan'); "
            "print(a, 'gymnasium' in sys.modules, 'lazy_helper' in sys.modules)")
    fp, gym, helper = _py(checkout, code).split()
    assert (gym, helper) == ("False", "False")
    with _Edit(tmp_path / "lazy_helper" / "deep.py", "X = 2\n"):     # the helper package it names counts
        assert _py(checkout, code).split()[0] != fp


def test_a_freeze_records_the_fingerprint_its_rows_were_flown_with(tmp_path):
    """tools/make_suites.py freeze takes each reference's fingerprint from its flight stores, not from the code at
    hand, and refuses rows flown by two versions of the code."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import make_suites
    finally:
        sys.path.remove(str(ROOT / "tools"))
    import pbdyn
    from pbdyn.experiments.runner import BatchOptions, run_batch
    from pbdyn.planning.registry import pair_fingerprint

    sc = pbdyn.load_scenario({"name": "frz", "world": {"time_limit": 5.0}, "obstacles": {"count": 3},
                              "planners": [{"trajectory": "straight_line", "gaze": "lookahead"}]})
    flights = tmp_path / "straight_line" / "flights"
    flights.mkdir(parents=True)
    run_batch(sc, flights / "generated.sqlite", BatchOptions(workers=1, metrics=False, limit=2))
    label = "lookahead+straight_line"
    assert make_suites._flown_fingerprint(tmp_path / "straight_line", label) == \
        pair_fingerprint("straight_line", "lookahead")
    with sqlite3.connect(flights / "generated.sqlite") as c:
        c.execute("UPDATE trials SET planner_fingerprint = 'pbdyn:0+pbdyn:0+core:0' WHERE rowid = 1")
    with pytest.raises(SystemExit, match="2 code fingerprints"):
        make_suites._flown_fingerprint(tmp_path / "straight_line", label)
