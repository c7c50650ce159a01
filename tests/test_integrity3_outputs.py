"""Integrity round 3, outputs: `pbdyn replay --out`, `metrics --plot`, `export --csv/--parquet`, `evaluate --plots`
and `--html` check their output paths before any work -- an existing folder (a file for --plots), a file on the
path, a read-only folder, an empty path, a name over 255 bytes: exit 2, one line, nothing written -- and write names
of 250-255 bytes (the temporary file's name stays within the limit); a results store in a read-only folder is read
by evaluate, export, merge and open_results.

Read-only folders are real: the child runs in a private mount namespace where the folder is bind-mounted read-only
(root cannot write there either); without that the tests are skipped.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

import pbdyn
from pbdyn import cli
from tests.conftest import pbdyn_cmd
from tests.test_batch import small

RO_SCRIPT = 'mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" "$0" && exec "$@"'
"""sh script: bind-mount folder $0 read-only over itself (in the caller's new mount namespace), then run "$@"."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A real trace (quickstart map 4) and a real results store (6 trials and their maps' metrics)."""
    d = tmp_path_factory.mktemp("inputs")
    trace = d / "trace.npz"
    pbdyn.run_trial("quickstart", map=4, trace=trace)
    store = d / "store.sqlite"
    pbdyn.run_batch(str(small(d)), store, workers=1, limit=6, progress=False)
    return trace, store


# command -> (argv for an output target, the target's suffix, "file" or "folder", (module, function) of its work)
COMMANDS = {
    "replay": (lambda tr, st, out: ["replay", str(tr), "--out", out, "--every", "25"], ".gif", "file",
               [("pbdyn.analysis.replay", "load_trace"), ("pbdyn.analysis.replay", "Renderer")]),
    "metrics --plot": (lambda tr, st, out: ["metrics", "quickstart", "--plot", out], ".png", "file",
                       [("pbdyn.world.rollout", "get_rollout"), ("pbdyn.analysis.heatmap", "metric_samples")]),
    "export --csv": (lambda tr, st, out: ["export", str(st), "--csv", out], ".csv", "file",
                     [("pbdyn.experiments.export", "trials_frame")]),
    "export --parquet": (lambda tr, st, out: ["export", str(st), "--parquet", out], ".parquet", "file",
                         [("pbdyn.experiments.export", "trials_frame")]),
    "evaluate --plots": (lambda tr, st, out: ["evaluate", str(st), "--bootstrap", "10", "--plots", out], "",
                         "folder", [("pbdyn.experiments.evaluate", "evaluate_stores")]),
    "evaluate --html": (lambda tr, st, out: ["evaluate", str(st), "--bootstrap", "10", "--html", out], ".html",
                        "file", [("pbdyn.experiments.evaluate", "evaluate_stores")]),
}


def _tree(*roots: Path) -> set[str]:
    """Every path under ``roots`` (hidden ones included)."""
    out: set[str] = set()
    for root in roots:
        for folder, dirs, files in os.walk(root):
            out.update(os.path.join(folder, n) for n in dirs + files)
    return out


def _main(argv: list[str]) -> tuple[int, str, str]:
    """pbdyn.cli.main(argv) in this process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def _bad_target(kind: str, suffix: str, work: Path, case: str) -> str:
    if case == "existing folder":           # a folder where a file goes; a file where the --plots folder goes
        target = work / f"taken{suffix}"
        if kind == "file":
            target.mkdir()
        else:
            target.write_text("not a folder")
        return str(target)
    if case == "parent is a file":
        (work / "afile").write_text("a file")
        return str(work / "afile" / f"out{suffix}")
    if case == "empty":
        return ""
    return str(work / ("a" * (256 - len(suffix)) + suffix))   # one byte over the limit


def _one_error(code: int, err: str, what) -> None:
    assert code == 2, (what, code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pbdyn: error:"), (what, err)
    assert "Traceback" not in err and "internal error" not in err, (what, err)


@pytest.mark.parametrize("case", ["existing folder", "parent is a file", "empty", "name over 255 bytes"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_bad_outputs_are_refused_before_the_work(inputs, tmp_path, monkeypatch, command, case):
    trace, store = inputs
    argv_of, suffix, kind, work_fns = COMMANDS[command]
    work = tmp_path / "work"
    work.mkdir()
    target = _bad_target(kind, suffix, work, case)
    started: list[str] = []
    for module, name in work_fns:
        mod = importlib.import_module(module)

        def refuse(*args, _name=name, **kwargs):
            started.append(_name)
            raise AssertionError(f"{_name} ran before the output was checked")
        monkeypatch.setattr(mod, name, refuse)
    monkeypatch.chdir(work)                                  # an empty path must not mean "here"
    before = _tree(tmp_path)
    code, out, err = _main(argv_of(trace, store, target))
    _one_error(code, err, (command, case))
    assert not started, (command, case, started)
    assert _tree(tmp_path) == before, (command, case, _tree(tmp_path) - before)


def _name_of(n_bytes: int, suffix: str, wide: bool = False) -> str:
    """A file name of exactly n_bytes bytes (UTF-8) ending in ``suffix``; ``wide``: mostly 2-byte characters."""
    budget = n_bytes - len(suffix.encode())
    stem = "é" * (budget // 2) + "a" * (budget % 2) if wide else "a" * budget
    name = stem + suffix
    assert len(name.encode()) == n_bytes
    return name


@pytest.mark.parametrize("n_bytes,wide", [(250, False), (255, False), (255, True)])
def test_export_names_of_250_to_255_bytes_are_written(inputs, tmp_path, n_bytes, wide):
    _, store = inputs
    for flag, suffix in (("--csv", ".csv"), ("--parquet", ".parquet")):
        target = tmp_path / _name_of(n_bytes, suffix, wide)
        code, _, err = _main(["export", str(store), flag, str(target)])
        assert code == 0 and target.stat().st_size > 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        _name_of(n_bytes, s, wide) for s in (".csv", ".parquet"))      # no temporary file left behind


def test_replay_metrics_and_evaluate_write_names_of_255_bytes(inputs, tmp_path):
    trace, store = inputs
    gif, png = tmp_path / _name_of(255, ".gif", wide=True), tmp_path / _name_of(255, ".png")
    plots, html = tmp_path / _name_of(255, ""), tmp_path / _name_of(255, ".html")
    for argv in (["replay", str(trace), "--out", str(gif), "--every", "25"],
                 ["metrics", "quickstart", "--metric", "survivability", "--plot", str(png)],
                 ["evaluate", str(store), "--bootstrap", "10", "--plots", str(plots), "--html", str(html)]):
        code, _, err = _main(argv)
        assert code == 0, (argv[0], err)
    assert gif.stat().st_size > 0 and png.stat().st_size > 0 and html.stat().st_size > 0
    assert any(plots.glob("*.png"))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in (gif, png, plots, html))


def test_html_creates_its_folder_as_plots_does(inputs, tmp_path):
    _, store = inputs
    html = tmp_path / "new" / "deeper" / "report.html"
    code, _, err = _main(["evaluate", str(store), "--bootstrap", "10", "--html", str(html)])
    assert code == 0, err
    assert html.stat().st_size > 0 and sorted(p.name for p in html.parent.iterdir()) == ["report.html"]


# ------------------------------------------------------------------------------------ read-only folders, for real
@pytest.fixture(scope="module")
def readonly_runner(tmp_path_factory):
    """run(folder, argv, cwd) -> CompletedProcess: argv (a pbdyn command, or a Python one with argv[0] "python")
    run with ``folder`` read-only for the child (a read-only bind mount in its own mount namespace)."""
    probe = tmp_path_factory.mktemp("probe")
    res = subprocess.run(["unshare", "-m", "sh", "-c", RO_SCRIPT, str(probe), "sh", "-c",
                          'touch "$0/x" 2>/dev/null && echo writable || echo readonly', str(probe)],
                         capture_output=True, text=True) if shutil.which("unshare") else None
    if res is None or res.returncode != 0 or res.stdout.strip() != "readonly":
        pytest.skip("cannot make a read-only bind mount here (needs unshare -m and mount as root)")

    def run(folder: Path, argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
        cmd = [sys.executable, *argv[1:]] if argv[0] == "python" else pbdyn_cmd() + argv
        return subprocess.run(["unshare", "-m", "sh", "-c", RO_SCRIPT, str(folder), *cmd], capture_output=True,
                              text=True, timeout=600, cwd=cwd)
    return run


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_read_only_output_folder_is_refused_with_one_line(inputs, tmp_path, readonly_runner, command):
    trace, store = inputs
    argv_of, suffix, kind, _ = COMMANDS[command]
    ro = tmp_path / "ro"
    ro.mkdir()
    (ro / "kept.txt").write_text("already here")
    targets = [ro / f"out{suffix}"] + ([ro / "new" / f"out{suffix}"] if kind == "folder" or suffix == ".html"
                                       else [])
    for target in targets:
        before = _tree(tmp_path)
        res = readonly_runner(ro, argv_of(trace, store, str(target)), tmp_path)
        _one_error(res.returncode, res.stderr, (command, target))
        assert "read-only" in res.stderr.lower() or "not writable" in res.stderr or "does not accept" in res.stderr
        assert _tree(tmp_path) == before


def _store_in(folder: Path, store: Path, journal_mode: str | None = None) -> Path:
    """A copy of ``store`` in ``folder`` (created); ``journal_mode``: set on the copy (it stays in the file)."""
    folder.mkdir()
    copy = folder / "store.sqlite"
    shutil.copyfile(store, copy)
    if journal_mode is not None:
        conn = sqlite3.connect(copy)
        assert conn.execute(f"PRAGMA journal_mode={journal_mode}").fetchone()[0] == journal_mode.lower()
        conn.close()
    assert sorted(p.name for p in folder.iterdir()) == ["store.sqlite"]
    return copy


@pytest.mark.parametrize("journal_mode", ["WAL", "DELETE"])
def test_a_store_in_a_read_only_folder_is_read(inputs, tmp_path, readonly_runner, journal_mode):
    """WAL: how pbdyn up to now left its stores (SQLite then needs to create a -shm file to read them)."""
    _, store = inputs
    ro = tmp_path / "ro"
    ro_store = _store_in(ro, store, journal_mode)
    out = tmp_path / "out"
    out.mkdir()
    before = _tree(ro)
    runs = {
        "evaluate": ["evaluate", str(ro_store), "--bootstrap", "10", "--json"],
        "export": ["export", str(ro_store), "--csv", str(out / "trials.csv")],
        "merge": ["merge", str(ro_store), "--out", str(out / "merged.sqlite"), "--json"],
        "open_results": ["python", "-c", "import sys, pbdyn\nwith pbdyn.open_results(sys.argv[1]) as r: "
                                         "print(r.count, len(r.trials()))", str(ro_store)],
    }
    for name, argv in runs.items():
        res = readonly_runner(ro, argv, tmp_path)
        assert res.returncode == 0, (name, res.stderr)
        assert res.stderr.strip() in ("", f"pbdyn export: 6 trials -> {out / 'trials.csv'}"), (name, res.stderr)
    assert (out / "trials.csv").read_text().count("\n") == 7
    assert res.stdout.split() == ["6", "6"]
    assert _tree(ro) == before                                  # only read


def test_a_read_only_store_with_unmerged_wal_changes_is_one_line(inputs, tmp_path, readonly_runner):
    """A -wal journal without its -shm file in a read-only folder: SQLite cannot read the journal's changes, and
    reading the file alone would silently miss them."""
    _, store = inputs
    work = tmp_path / "live"
    live = _store_in(work, store)
    conn = sqlite3.connect(live)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA wal_autocheckpoint=0")
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('note', 'in the journal only')")
    conn.commit()
    ro = tmp_path / "ro"
    ro.mkdir()
    shutil.copyfile(live, ro / "store.sqlite")
    shutil.copyfile(str(live) + "-wal", ro / "store.sqlite-wal")
    conn.close()
    res = readonly_runner(ro, ["export", str(ro / "store.sqlite"), "--csv", str(tmp_path / "x.csv")], tmp_path)
    _one_error(res.returncode, res.stderr, "wal")
    assert "-wal" in res.stderr and not (tmp_path / "x.csv").exists()
