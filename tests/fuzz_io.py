"""Seeded fuzz cases for pbdyn's files and arguments (tests/test_fuzz_io.py): crafted trace files, output paths,
Python API argument types and merge inputs.

Each class draws its cases from ``numpy.random.default_rng([FUZZ_IO_SEED, class number, index])``:

- ``trace``: a real trace (`pbdyn run --trace`) rewritten with one or two mutations (a required array removed,
  reshaped to 1-D, 3-D or empty, filled with NaN or inf, given another dtype (strings, objects, complex); dt 0,
  negative or NaN; arena bounds swapped; the file truncated, replaced by random bytes, emptied; a zip bomb (a
  member that inflates to hundreds of MB); an .npy header declaring a huge shape), then `pbdyn replay` on it;
- ``outpath``: one command writing one output (replay --out, metrics --plot, export --csv/--parquet, evaluate
  --plots/--html, rollout --out, run --trace, merge --out, batch --out) at a path of one category (an existing
  folder, a file's parent that is a file, an empty path, names of 250-256 bytes, control characters, a trailing
  slash, missing parents);
- ``merge``: `pbdyn merge` of inputs drawn from good stores, truncated or random files, a folder, a missing file, a
  foreign SQLite file, another scenario's store, a newer schema, the output itself, the same store twice, into a
  new, an existing or a non-store output;
- ``api``: a public API function called with a parameter of a wrong type or value (tuples of the wrong length,
  numbers for paths, strings for numbers, NaN, objects).

The oracle (``verdict``) is the CLI contract: exit 0 with the promised output, or exit 2 with exactly one stderr
line "pbdyn: error: ..." and nothing written (no new file or folder anywhere in the case folder, an existing
output unchanged); for the API, a return or a pbdyn error (PbdynError) naming the parameter, never another
exception. Never a traceback, a warning, or more than the case's time bound.

    python -m tests.fuzz_io CLASS INDEX       # the case, run, with the verdict
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import signal
import sqlite3
import sys
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.fuzz_cases import (CaseTimeout, Outcome, _memory_headroom, basic_problem, exit2_problem,
                              shown_warnings)

ROOT = Path(__file__).resolve().parent.parent
FUZZ_IO_SEED = 20261127
CLASSES = ("trace", "outpath", "merge", "api")

SMALL_SCENARIO = """name = "fuzzio"
[world]
time_limit = 3.0
[obstacles]
count = 6
maps_per_setup = 2
root_seed = 5
[drone]
v_max = [4.0]
[task]
candidates = [[4.0, 4.0], [46.0, 46.0]]
[[planners]]
trajectory = "local_primitives"
gaze = "lookahead"
"""
"""A small experiment (2 maps x 2 trials, 3 s time limit) whose store and trace the cases start from."""


# ------------------------------------------------------------------------------------------------ fixtures
@dataclass
class Assets:
    """Files every case may copy: the scenario, a trace, a results store and another scenario's store."""

    folder: Path
    scenario: Path
    trace: Path
    store: Path
    other_store: Path


def cli(argv: list[str], cwd: Path | None = None) -> tuple[object, str, str, list[str]]:
    """(exit status, stdout, stderr, warnings) of ``pbdyn.cli.main(argv)`` in this process."""
    from pbdyn import cli as pbdyn_cli

    out, err = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr
    old_cwd = os.getcwd()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sys.stdout, sys.stderr = out, err
        try:
            if cwd is not None:
                os.chdir(cwd)
            code = pbdyn_cli.main(argv)
        except SystemExit as exc:
            code = exc.code
        except BaseException as exc:  # anything escaping main breaks the contract
            code = f"{type(exc).__name__} escaped main: {exc}"
        finally:
            os.chdir(old_cwd)
            sys.stdout, sys.stderr = old
    return code, out.getvalue(), err.getvalue(), shown_warnings(caught)


def make_assets(folder: Path) -> Assets:
    """Build the shared inputs once: a trace of a 3 s trial, a 4-trial store with metrics, and the store of a
    scenario with another seed."""
    folder.mkdir(parents=True, exist_ok=True)
    sc = folder / "fuzzio.toml"
    sc.write_text(SMALL_SCENARIO)
    trace = folder / "trace.npz"
    code, _, err, _ = cli(["run", str(sc), "--trace", str(trace), "--json"])
    assert code == 0, err
    store = folder / "store.sqlite"
    code, _, err, _ = cli(["batch", str(sc), "--out", str(store), "--workers", "1", "--json"])
    assert code == 0, err
    other_sc = folder / "other.toml"
    other_sc.write_text(SMALL_SCENARIO.replace("root_seed = 5", "root_seed = 6"))
    other = folder / "other.sqlite"
    code, _, err, _ = cli(["batch", str(other_sc), "--out", str(other), "--workers", "1", "--no-metrics",
                           "--limit", "1", "--json"])
    assert code == 0, err
    return Assets(folder, sc, trace, store, other)


# ------------------------------------------------------------------------------------------------ cases
@dataclass
class Case:
    """One case: its class and index, what was mutated (in words), and how to run it in a folder."""

    kind: str
    index: int
    mutations: list[str] = field(default_factory=list)
    argv: list[str] = field(default_factory=list)       # CLI cases (paths relative to the case folder)
    output: str | None = None                           # the CLI output that exit 0 must create
    output_is_folder: bool = False                      # ... a folder (evaluate --plots), else a file
    call: tuple | None = None                           # API cases: (function name, args, kwargs, parameter)

    def describe(self) -> str:
        return f"fuzz-io {self.kind} {self.index}: {'; '.join(self.mutations)}"


def _rng(kind: str, index: int) -> np.random.Generator:
    return np.random.default_rng([FUZZ_IO_SEED, CLASSES.index(kind), index])


_ZIP_BOMB: dict = {}


def _zip_bomb(n_bytes: int = 400 << 20) -> bytes:
    """An .npz whose "p" member inflates to ``n_bytes`` of zeros (compressed: a few hundred kB)."""
    if n_bytes not in _ZIP_BOMB:
        buf = io.BytesIO()
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                      "shape": (n_bytes // 16, 2)})
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
            with z.open("p.npy", "w", force_zip64=True) as f:
                f.write(header.getvalue())
                chunk = bytes(1 << 20)
                for _ in range(n_bytes >> 20):
                    f.write(chunk)
        _ZIP_BOMB[n_bytes] = buf.getvalue()
    return _ZIP_BOMB[n_bytes]


def _huge_header_npy() -> bytes:
    """An .npy member whose header declares a 10^6 x 10^6 float64 array but holds 16 bytes."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**6, 10**6)})
    return header.getvalue() + bytes(16)


TRACE_FILE_MUTATIONS = ("truncate", "random_bytes", "empty", "zip_bomb", "huge_header", "not_a_zip_member")
TRACE_ARRAY_MUTATIONS = ("drop", "one_d", "three_d", "empty", "nan", "inf", "strings", "objects", "complex",
                         "scalar", "huge_scalar")
TRACE_SCALARS = {"dt": (0.0, -0.1, float("nan"), float("inf"), 1e300), "fov_deg": (-90.0, 0.0, 1e9, float("nan")),
                 "range_m": (0.0, -8.0, float("inf")), "goal_radius": (-1.0, float("nan")),
                 "mav_radius": (0.0, -1.0, 1e12)}


def trace_case(index: int, assets: Assets) -> tuple[Case, bytes]:
    """A mutated trace and the replay command on it."""
    from pbdyn.analysis.replay import REQUIRED

    rng = _rng("trace", index)
    case = Case("trace", index)
    with np.load(assets.trace, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data_bytes = None
    for _ in range(1 if rng.random() < 0.8 else 2):
        r = rng.random()
        if r < 0.2:
            kind = str(rng.choice(TRACE_FILE_MUTATIONS))
            case.mutations.append(f"file:{kind}")
            buf = io.BytesIO()
            np.savez(buf, **data)
            raw = buf.getvalue()
            if kind == "truncate":
                data_bytes = raw[:int(rng.integers(1, len(raw)))]
            elif kind == "random_bytes":
                data_bytes = rng.bytes(int(rng.integers(1, 5000)))
            elif kind == "empty":
                data_bytes = b""
            elif kind == "zip_bomb":
                data_bytes = _zip_bomb()
            elif kind == "huge_header":
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w") as z:
                    for k, v in data.items():
                        if k != "p":
                            b = io.BytesIO()
                            np.save(b, v, allow_pickle=False)
                            z.writestr(f"{k}.npy", b.getvalue())
                    z.writestr("p.npy", _huge_header_npy())
                data_bytes = buf.getvalue()
            else:
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w") as z:
                    for k, v in data.items():
                        b = io.BytesIO()
                        np.save(b, v, allow_pickle=False)
                        z.writestr(f"{k}.npy", b.getvalue() if k != "t" else b"not an npy member")
                data_bytes = buf.getvalue()
        elif r < 0.45:
            key = str(rng.choice(sorted(TRACE_SCALARS)))
            value = TRACE_SCALARS[key][int(rng.integers(len(TRACE_SCALARS[key])))]
            data[key] = np.asarray(value)
            case.mutations.append(f"scalar:{key}={value}")
        elif r < 0.55:
            lo, hi = data["arena_lo"].copy(), data["arena_hi"].copy()
            what = int(rng.integers(3))
            if what == 0:
                data["arena_lo"], data["arena_hi"] = hi, lo
            elif what == 1:
                data["arena_hi"] = np.full_like(hi, np.nan)
            else:
                data["arena_lo"] = lo[:1]
            case.mutations.append(f"arena:{('swapped', 'nan', 'short')[what]}")
        else:
            key = str(rng.choice(REQUIRED))
            kind = str(rng.choice(TRACE_ARRAY_MUTATIONS))
            a = np.asarray(data[key])
            if kind == "drop":
                data.pop(key)
            elif kind == "one_d":
                data[key] = a.reshape(-1)
            elif kind == "three_d":
                data[key] = a.reshape(a.shape + (1,))
            elif kind == "empty":
                data[key] = np.zeros((0,) + a.shape[1:], dtype=a.dtype) if a.ndim else np.zeros(0)
            elif kind == "nan" and a.dtype.kind == "f":
                b = a.copy()
                b.reshape(-1)[int(rng.integers(max(b.size, 1)))] = np.nan if b.size else 0
                data[key] = b
            elif kind == "inf" and a.dtype.kind == "f":
                data[key] = np.full_like(a, np.inf)
            elif kind == "strings":
                data[key] = np.full(a.shape or (1,), "x")
            elif kind == "objects":
                data[key] = np.array([1, "two", None], dtype=object)
            elif kind == "complex":
                data[key] = a.astype(complex) if a.dtype.kind in "fiu" else np.asarray([1j])
            elif kind == "scalar":
                data[key] = np.asarray(3.0)
            else:
                data[key] = np.asarray(1e308)
            case.mutations.append(f"array:{key}:{kind}")
    if data_bytes is None:
        buf = io.BytesIO()
        try:
            np.savez(buf, **data)
        except ValueError:      # object arrays cannot be saved without pickle: save them with it
            buf = io.BytesIO()
            np.savez(buf, **{k: v for k, v in data.items()})
        data_bytes = buf.getvalue()
    suffix = str(rng.choice([".png", ".png", ".gif"]))
    case.argv = ["replay", "case.npz", "--out", f"out{suffix}"] + (["--every", "20"] if suffix == ".gif" else [])
    case.output = f"out{suffix}"
    return case, data_bytes


def _long_name(n_bytes: int, suffix: str) -> str:
    return "n" * (n_bytes - len(suffix)) + suffix


PATH_CATEGORIES = ("existing_folder", "parent_is_file", "empty", "name_250", "name_255", "name_256",
                   "control_chars", "trailing_slash", "missing_parents", "unicode", "dot")


def _outpath(category: str, suffix: str) -> str:
    return {"existing_folder": "afolder", "parent_is_file": "afile/out" + suffix, "empty": "",
            "name_250": _long_name(250, suffix), "name_255": _long_name(255, suffix),
            "name_256": _long_name(256, suffix), "control_chars": "out\n\x1b[31m" + suffix,
            "trailing_slash": "out" + suffix + "/", "missing_parents": "a/b/c/out" + suffix,
            "unicode": "ausgabe-\u00e4\u00f6\u00fc" + suffix, "dot": "."}[category]


def outpath_case(index: int, assets: Assets) -> Case:
    """One output-writing command with an output path of one category."""
    commands = ("replay", "plot", "csv", "parquet", "plots", "html", "rollout", "trace", "merge", "batch")
    # 10 commands x 11 categories: indices 0..109 give every pair once (10 and 11 are coprime), so the default run's
    # first 11 cases already try every command and every category
    cmd = commands[index % len(commands)]
    category = PATH_CATEGORIES[index % len(PATH_CATEGORIES)]
    suffix = {"replay": ".png", "plot": ".png", "csv": ".csv", "parquet": ".parquet", "plots": "", "html": ".html",
              "rollout": ".npz", "trace": ".npz", "merge": ".sqlite", "batch": ".sqlite"}[cmd]
    out = _outpath(category, suffix)
    sc, store, trace = str(assets.scenario), str(assets.store), str(assets.trace)
    argv = {"replay": ["replay", trace, "--out", out], "plot": ["metrics", sc, "--metric", "density", "--plot", out],
            "csv": ["export", store, "--csv", out], "parquet": ["export", store, "--parquet", out],
            "plots": ["evaluate", store, "--plots", out, "--bootstrap", "10"],
            "html": ["evaluate", store, "--html", out, "--bootstrap", "10"],
            "rollout": ["rollout", sc, "--out", out], "trace": ["run", sc, "--trace", out, "--json"],
            "merge": ["merge", store, "--out", out], "batch": ["batch", sc, "--out", out, "--limit", "1",
                                                                "--workers", "1", "--no-metrics"]}[cmd]
    return Case("outpath", index, [f"{cmd}:{category}"], argv, out, output_is_folder=cmd == "plots")


MERGE_INPUTS = ("good", "truncated", "random_bytes", "empty", "folder", "missing", "foreign_sqlite", "other_scenario",
                "newer_schema", "output_itself", "same_twice", "csv_file", "no_scenario")
MERGE_OUTPUTS = ("new", "existing_store", "not_a_store", "existing_other_scenario")


def merge_case(index: int, assets: Assets) -> Case:
    """`pbdyn merge` of one or two drawn inputs into a drawn output (files made by prepare_merge)."""
    rng = _rng("merge", index)
    inputs = [str(rng.choice(MERGE_INPUTS)) for _ in range(int(rng.integers(1, 3)))]
    output = str(rng.choice(MERGE_OUTPUTS))
    case = Case("merge", index, [f"inputs:{','.join(inputs)}", f"output:{output}"])
    names = []
    for i, kind in enumerate(inputs):
        if kind == "output_itself":
            names.append("out.sqlite")
        elif kind == "same_twice":
            names += ["in_good.sqlite", "in_good.sqlite"]
        else:
            names.append(f"in{i}_{kind}.sqlite" if kind != "folder" else f"in{i}_folder")
    case.argv = ["merge", *names, "--out", "out.sqlite", "--json"]
    case.output = "out.sqlite"
    return case


def prepare_merge(case: Case, folder: Path, assets: Assets) -> None:
    """Write the files a merge case names into its folder."""
    rng = _rng("merge", case.index)
    good = assets.store.read_bytes()
    for name in sorted(set(case.argv[1:-3]) - {"out.sqlite"}):
        p = folder / name
        kind = name.split("_", 1)[1].rsplit(".", 1)[0] if "_" in name else "good"
        if kind == "good":
            p.write_bytes(good)
        elif kind == "truncated":
            p.write_bytes(good[:int(rng.integers(1, len(good)))])
        elif kind == "random_bytes":
            p.write_bytes(rng.bytes(4096))
        elif kind == "empty":
            p.write_bytes(b"")
        elif kind == "folder":
            p.mkdir()
        elif kind == "missing":
            pass
        elif kind == "foreign_sqlite":
            with contextlib.closing(sqlite3.connect(p)) as c:
                c.execute("CREATE TABLE t (x)")
                c.commit()
        elif kind == "other_scenario":
            p.write_bytes(assets.other_store.read_bytes())
        elif kind == "newer_schema":
            p.write_bytes(good)
            with contextlib.closing(sqlite3.connect(p)) as c:
                c.execute("UPDATE meta SET value = '999' WHERE key = 'schema_version'")
                c.commit()
        elif kind == "csv_file":
            p.write_text("a,b\n1,2\n")
        elif kind == "no_scenario":
            p.write_bytes(good)
            with contextlib.closing(sqlite3.connect(p)) as c:
                c.execute("DELETE FROM meta WHERE key = 'scenario'")
                c.commit()
    output = case.mutations[1].split(":")[1]
    out = folder / "out.sqlite"
    if output == "existing_store":
        out.write_bytes(good)
    elif output == "not_a_store":
        out.write_text("not a store\n")
    elif output == "existing_other_scenario":
        out.write_bytes(assets.other_store.read_bytes())


API_VALUES = (123, 2.5, -1, 0, None, "", "abc", (4.0, 4.0, 4.0), (4.0,), [], {}, float("nan"), True, b"bytes",
              object(), np.zeros((2, 2)), ("a", "b"))
API_CALLS = (("run_trial", "start"), ("run_trial", "goal"), ("run_trial", "map"), ("run_trial", "v_max"),
             ("run_trial", "planner"), ("run_trial", "gaze"), ("run_trial", "observers"), ("run_trial", "trace"),
             ("compute_metrics", "map"), ("compute_metrics", "metrics"), ("compute_metrics", "backend"),
             ("map_info", "map"), ("rollout", "map"), ("rollout", "horizon"), ("open_results", "path"),
             ("replay", "trace"), ("replay", "out"), ("replay", "fps"), ("replay", "every"),
             ("merge_results", "out"), ("merge_results", "inputs"), ("check_planner", "maps"),
             ("check_planner", "pairs"), ("check_planner", "v_max"), ("check_planner", "planner"),
             ("export_results", "results"), ("export_results", "path"), ("evaluate", "results"),
             ("evaluate", "n_boot"), ("load_scenario", "scenario"))


def api_case(index: int, assets: Assets) -> Case:
    """One public API function called with one parameter of a drawn wrong type or value."""
    rng = _rng("api", index)
    fn, param = API_CALLS[int(rng.integers(len(API_CALLS)))]
    value = API_VALUES[int(rng.integers(len(API_VALUES)))]
    case = Case("api", index, [f"{fn}({param}={value!r})"[:120]])
    case.call = (fn, param, value)
    return case


def _api_args(fn: str, param: str, value, folder: Path, assets: Assets) -> tuple[tuple, dict]:
    """Valid arguments for ``fn`` with ``param`` replaced by ``value`` (outputs inside ``folder``)."""
    sc = str(assets.scenario)
    base = {"run_trial": ((sc,), {}), "compute_metrics": ((sc,), {"metrics": "density"}), "map_info": ((sc,), {}),
            "rollout": ((sc,), {}), "open_results": ((), {"path": str(assets.store)}),
            "replay": ((), {"trace": str(assets.trace), "out": str(folder / "r.png")}),
            "merge_results": ((), {"out": str(folder / "m.sqlite"), "inputs": [str(assets.store)]}),
            "check_planner": ((), {"planner": "straight_line", "scenario": sc, "maps": 1, "pairs": 1}),
            "export_results": ((), {"results": str(assets.store), "path": str(folder / "e.csv")}),
            "evaluate": ((), {"results": str(assets.store), "n_boot": 10}),
            "load_scenario": ((), {"scenario": sc})}[fn]
    args, kwargs = base
    kwargs = dict(kwargs)
    kwargs[param] = value
    return args, kwargs


# ------------------------------------------------------------------------------------------------ running
def _snapshot(folder: Path) -> dict[str, str]:
    """relative path -> content digest ("dir" for folders) of everything under ``folder``, hidden files included."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        for d in dirnames:
            out[os.path.relpath(os.path.join(dirpath, d), folder)] = "dir"
        for f in filenames:
            p = os.path.join(dirpath, f)
            try:
                with open(p, "rb") as fh:
                    out[os.path.relpath(p, folder)] = hashlib.sha256(fh.read()).hexdigest()
            except OSError:
                out[os.path.relpath(p, folder)] = "unreadable"
    return out


@contextlib.contextmanager
def _alarm(seconds: float, fired: list):
    def on_alarm(signum, frame):
        fired.append(True)
        raise CaseTimeout(f"ran past {seconds:g} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)


def run_case(case: Case, folder: Path, assets: Assets, *, timeout_s: float = 60.0,
             memory_bytes: int = 4 << 30, data: bytes | None = None) -> Outcome:
    """Run a case in ``folder`` (created), this process, with its wall time and address space bounded."""

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "afolder").mkdir()
    (folder / "afile").write_text("a file\n")
    if case.kind == "trace":
        (folder / "case.npz").write_bytes(data)
    elif case.kind == "merge":
        prepare_merge(case, folder, assets)
    before = _snapshot(folder)
    fired: list = []
    old_cache = os.environ.get("PBDYN_CACHE")
    os.environ["PBDYN_CACHE"] = str(assets.folder / "cache")
    t0 = time.monotonic()
    exc_out = None
    try:
        with _memory_headroom(memory_bytes):
            if case.kind == "api":
                code, stdout, stderr, shown, exc_out = _run_api(case, folder, assets, timeout_s, fired)
            else:
                with _alarm(timeout_s, fired):
                    code, stdout, stderr, shown = cli(case.argv, cwd=folder)
    except CaseTimeout:
        code, stdout, stderr, shown = None, "", "", []
    finally:
        if old_cache is None:
            os.environ.pop("PBDYN_CACHE", None)
        else:
            os.environ["PBDYN_CACHE"] = old_cache
    seconds = time.monotonic() - t0
    after = _snapshot(folder)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    target = folder / case.output if case.output else None
    try:
        made = target is not None and (target.is_dir() if case.output_is_folder else target.is_file())
    except OSError:        # a name too long to exist
        made = False
    return Outcome(code, stdout, stderr, seconds, changed, made, shown, bool(fired), exc_out)


def _run_api(case: Case, folder: Path, assets: Assets, timeout_s: float, fired: list):
    import pbdyn

    fn, param, value = case.call
    args, kwargs = _api_args(fn, param, value, folder, assets)
    exc_out = None
    out, err = io.StringIO(), io.StringIO()
    old = sys.stdout, sys.stderr
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sys.stdout, sys.stderr = out, err
        try:
            with _alarm(timeout_s, fired):
                result = getattr(pbdyn, fn)(*args, **kwargs)
                if fn == "open_results":
                    with result as r:
                        r.trials()
        except CaseTimeout:
            raise
        except BaseException as exc:  # judged by the oracle
            exc_out = exc
        finally:
            sys.stdout, sys.stderr = old
    shown = shown_warnings([w for w in caught if "pbdyn" not in w.category.__module__])
    return 0 if exc_out is None else 2, out.getvalue(), err.getvalue(), shown, exc_out


def verdict(case: Case, out: Outcome, time_bound_s: float) -> str | None:
    """None if the case kept the contract, else what broke."""
    problem = basic_problem(out, time_bound_s)
    if problem:
        return problem
    if case.kind == "api":
        from pbdyn.errors import PbdynError

        fn, param, _ = case.call
        if out.exception is None:
            return None
        if not isinstance(out.exception, PbdynError):
            return f"raised {type(out.exception).__name__}: {str(out.exception)[:200]}"
        if param not in str(out.exception) and not (param == "path" and "RESULTS" in str(out.exception)):
            return f"a pbdyn error not naming {param!r}: {str(out.exception)[:200]}"
        if "\n" in str(out.exception):
            return "an error message of several lines"
        return None
    if out.code == 0:
        if case.output is not None and not out.out_exists:
            return f"exit 0 but no output at {case.output!r}"
        return None
    if out.code == 2:
        problem = exit2_problem(out.stdout, out.stderr)
        if problem:
            return problem
        if out.leftovers:
            return f"exit 2 but files changed or were left behind: {out.leftovers[:5]}"
        return None
    return f"exit {out.code}: {out.stderr.strip()[-400:]!r}"


def make(kind: str, index: int, assets: Assets) -> tuple[Case, bytes | None]:
    """Case ``index`` of class ``kind`` (and a trace case's file bytes)."""
    if kind == "trace":
        return trace_case(index, assets)
    return {"outpath": outpath_case, "merge": merge_case, "api": api_case}[kind](index, assets), None


def main(argv: list[str]) -> int:
    import tempfile

    if len(argv) < 2 or argv[0] not in CLASSES or not argv[1].isdigit():
        print(__doc__)
        return 2
    with tempfile.TemporaryDirectory(prefix="pbdyn-fuzzio-") as tmp:
        assets = make_assets(Path(tmp) / "assets")
        case, data = make(argv[0], int(argv[1]), assets)
        print(f"# {case.describe()}\n# argv: {case.argv or case.call}")
        out = run_case(case, Path(tmp) / "case", assets, data=data)
        print(f"# exit {out.code} in {out.seconds:.2f} s; stdout {out.stdout[:300]!r}; stderr {out.stderr[-800:]!r}; "
              f"exception {out.exception!r}; changed {out.leftovers[:5]}")
        print(f"# verdict: {verdict(case, out, 60.0) or 'ok'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
