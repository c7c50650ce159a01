"""No orphans, clean signals, everywhere (issue 41, point 4): `pbdyn generate` on the batch runner's worker pool
(SIGTERM/SIGINT: one line, exit 143/130, no worker left, no partial output; SIGKILL: no worker outlives it), plug-in
planners that kill their worker process or never return (error rows, the batch completes)."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import pbdyn_cmd
from tests.helpers import child_pids, process_running

HERE = Path(__file__).resolve().parent




def _still_running(kids: list[int], within: float) -> list[int]:
    deadline = time.monotonic() + within
    while any(process_running(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return [k for k in kids if process_running(k)]


def _start_generate(tmp_path: Path) -> tuple[subprocess.Popen, list[int]]:
    """A `pbdyn generate` on 2 workers that runs for minutes (a tight tolerance, many maps), once its workers are
    measuring; (the process, its children: 2 workers and multiprocessing's resource tracker)."""
    proc = subprocess.Popen(pbdyn_cmd() + ["generate", "--metric", "survivability", "--target", "5.0", "--tolerance",
                                           "0.01", "--count", "500", "--workers", "2", "--out", "gen.toml"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while len(child_pids(proc.pid)) < 3:
        assert proc.poll() is None and time.monotonic() < deadline, "generate ended or never started its workers"
        time.sleep(0.05)
    time.sleep(1.5)                  # the workers are measuring the pilot's candidates
    return proc, child_pids(proc.pid)


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_generate_stopped_by_a_signal_says_so_in_one_line_and_leaves_no_worker_or_file(tmp_path, sig, status):
    proc, kids = _start_generate(tmp_path)
    t0 = time.monotonic()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=30)
    assert time.monotonic() - t0 < 10, "generate took too long to stop"
    assert proc.returncode == status, err
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err, err
    assert err == f"pbdyn: generate stopped by {sig.name}: gen.toml not written\n"
    assert _still_running(kids, 5.0) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == []          # no output, no temp file


def test_generate_killed_with_sigkill_leaves_no_worker_running(tmp_path):
    proc, kids = _start_generate(tmp_path)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert _still_running(kids, 5.0) == [], "workers outlived their coordinator"
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_generate_measures_on_the_batch_runners_worker_pool():
    import pbdyn.experiments.generate as generate

    src = Path(generate.__file__).read_text()
    assert "ProcessPoolExecutor" not in src and "WorkerPool" in src


# ------------------------------------------------------------------------------------------------ plug-ins that crash
def _scenario(tmp_path: Path, trajectory: str, gaze: str = "lookahead", maps: int = 1) -> Path:
    """One or two small maps, 6 start/goal pairs (one of them the plug-ins' chosen trial: 46,4 -> 4,46)."""
    sc = tmp_path / "s.toml"
    sc.write_text(f'name = "crash"\n[world]\ntime_limit = 10.0\n[obstacles]\ncount = 6\nmaps_per_setup = {maps}\n'
                  '[drone]\nv_max = [4.0]\n[task]\ncandidates = [[4.0, 4.0], [46.0, 4.0], [4.0, 46.0]]\n'
                  f'[[planners]]\ntrajectory = "{trajectory}"\ngaze = "{gaze}"\n')
    return sc


def _batch(sc: Path, out: Path, misbehave: bool, *extra: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(HERE.parent), PBDYN_TEST_MISBEHAVE="1" if misbehave else "0")
    return subprocess.run(pbdyn_cmd() + ["batch", str(sc), "--out", str(out), "--no-metrics", "--json", *extra],
                          capture_output=True, text=True, timeout=300, env=env)


def _rows(path: Path) -> dict[str, dict]:
    with sqlite3.connect(path) as c:
        c.row_factory = sqlite3.Row
        return {r["trial_key"]: {k: r[k] for k in r.keys() if "wall" not in k and k not in _NOT_FLOWN}
                for r in c.execute("SELECT * FROM trials")}


_NOT_FLOWN = ("result_json", "finished", "planner_fingerprint", "world_fingerprint")
"""Columns that are not the flight's (its JSON copy holds wall times; when it was stored; digests of the code)."""


def _check_isolated(tmp_path: Path, cls: str, reason: str, maps: int = 1, *extra: str) -> None:
    import json

    sc = _scenario(tmp_path, f"tests.integrity4_plugins:{cls}", maps=maps)
    res = _batch(sc, tmp_path / "bad.sqlite", True, *extra)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr and "Error" not in res.stderr, res.stderr
    doc = json.loads(res.stdout)
    assert (doc["ran"], doc["errors"]) == (6 * maps, maps), doc
    bad = _rows(tmp_path / "bad.sqlite")
    errs = {k: r for k, r in bad.items() if r["outcome"] == "error"}
    assert len(errs) == maps
    for r in errs.values():
        assert r["error"] == f"worker process died ({reason}) while flying this trial", r["error"]
        assert json.loads(r["start"]) == [46.0, 4.0] and json.loads(r["goal"]) == [4.0, 46.0]
    ok = _batch(sc, tmp_path / "ok.sqlite", False, *extra)                # the same planner, well-behaved
    assert ok.returncode == 0, ok.stderr
    good = _rows(tmp_path / "ok.sqlite")
    assert set(good) == set(bad)
    assert {k: r for k, r in bad.items() if k not in errs} == {k: r for k, r in good.items() if k not in errs}


def test_a_planner_that_segfaults_its_worker_gives_one_error_row_and_the_batch_completes(tmp_path):
    _check_isolated(tmp_path, "SegfaultPlanner", "exit -11 / signal SIGSEGV", 1, "--workers", "2")


@pytest.mark.slow
def test_a_planner_that_segfaults_through_ctypes_is_isolated_on_each_map(tmp_path):
    _check_isolated(tmp_path, "CtypesSegfaultPlanner", "exit -11 / signal SIGSEGV", 2, "--workers", "2")


@pytest.mark.slow          # the same isolation as the segfault test (16 s): in the slow run
def test_a_planner_that_calls_os_exit_gives_one_error_row_and_the_batch_completes(tmp_path):
    _check_isolated(tmp_path, "ExitPlanner", "exit 3", 1, "--workers", "1", "--lockstep", "1")


# ------------------------------------------------------------------------------------------------ plug-ins that hang
@pytest.mark.parametrize("trajectory, gaze", [("tests.integrity4_plugins:HangingPlanner", "lookahead"),
                                              ("local_primitives", "tests.integrity4_plugins:HangingGaze")])
def test_a_planner_that_never_returns_ends_its_trial_as_an_error_naming_the_budget(tmp_path, trajectory, gaze):
    import json

    sc = _scenario(tmp_path, trajectory, gaze)
    t0 = time.monotonic()
    res = _batch(sc, tmp_path / "hang.sqlite", True, "--workers", "1")
    assert res.returncode == 0, res.stderr
    assert time.monotonic() - t0 < 60
    assert (json.loads(res.stdout)["ran"], json.loads(res.stdout)["errors"]) == (6, 1)
    errs = [r for r in _rows(tmp_path / "hang.sqlite").values() if r["outcome"] == "error"]
    assert len(errs) == 1 and "did not return within its time budget of 0.5 s per decision" in errs[0]["error"]
    assert "PLANNER_CALL_TIMEOUT_S" in errs[0]["error"] and "integrity4_plugins.py:" in errs[0]["error"]


def test_a_hanging_planner_in_run_is_one_line_and_exit_2(tmp_path):
    sc = _scenario(tmp_path, "tests.integrity4_plugins:HangingPlanner")
    env = dict(os.environ, PYTHONPATH=str(HERE.parent), PBDYN_TEST_MISBEHAVE="1")
    res = subprocess.run(pbdyn_cmd() + ["run", str(sc), "--start", "46,4", "--goal", "4,46"], capture_output=True,
                         text=True, timeout=120, env=env)
    assert res.returncode == 2 and res.stdout == "", res.stderr
    assert res.stderr.count("\n") == 1 and "time budget of 0.5 s per decision" in res.stderr


def test_built_in_planners_arm_no_timer_and_plug_ins_arm_one_per_flight(monkeypatch):
    """Built-in pairs pay nothing for the budget; a flight with a plug-in arms one watchdog, not a timer per call."""
    import pbdyn
    from pbdyn import usercode

    calls = []
    real = signal.setitimer
    monkeypatch.setattr(signal, "setitimer", lambda *a: calls.append(a) or real(*a))
    sc = pbdyn.load_scenario({"name": "b", "world": {"time_limit": 5.0}, "obstacles": {"count": 4},
                              "drone": {"v_max": [4.0]}})
    pbdyn.run_trial(sc, map=0, planner="straight_line")
    assert calls == []
    sys.path.insert(0, str(HERE.parent))
    try:
        res = pbdyn.run_trial(sc, map=0, planner="tests.integrity4_plugins:SegfaultPlanner")
    finally:
        sys.path.remove(str(HERE.parent))
    assert res.steps > 10 and len(calls) == 2           # armed once, disarmed once
    assert usercode.watchdog() is None


@pytest.mark.slow          # bench flies through the batch runner the segfault test covers (13 s): in the slow run
def test_a_bench_of_a_planner_that_segfaults_on_some_tasks_completes_with_their_errors_on_its_card(tmp_path):
    import json

    from pbdyn.benchmark.suite import load_suite
    from pbdyn.config import parse_scenario

    (tmp_path / "crashy_planner.py").write_text(
        "import os\nimport signal\n\nfrom my_planner import GoalSeeker\n\n\n"
        "class Crashy(GoalSeeker):\n"
        "    def plan(self, view):\n"
        "        if view.t == 0.0 and view.position[0] > 20.0:\n"
        "            os.kill(os.getpid(), signal.SIGSEGV)\n"
        "        return super().plan(view)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parent / "tools" / "templates"), str(tmp_path),
                                                       str(HERE.parent)]))
    out = tmp_path / "crashy"
    res = subprocess.run(pbdyn_cmd() + ["bench", "crashy_planner:Crashy", "--suite", "pbdyn-2d-mini", "--out",
                                        str(out), "--workers", "2"], capture_output=True, text=True, timeout=600,
                         env=env)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    card = json.loads((out / "card.json").read_text())
    suite = load_suite("pbdyn-2d-mini")

    def start_x(part: str, candidate: int) -> float:
        p = suite.part(part)
        return float(parse_scenario(p.doc, p.path).task.candidates[candidate][0])

    crashing = sum(1 for m in suite.maps for q in suite.part(m["part"]).pairs
                   if suite.part(m["part"]).doc is not None and start_x(m["part"], q[0]) > 20.0)
    assert crashing > 0 and card["outcomes"]["error"] == card["trials"]["errors"] == crashing
    assert card["trials"]["flown"] == card["trials"]["expected"] == suite.n_tasks()


# ------------------------------------------------------------------------------------------------ merge
def _open_inputs(pid: int, folder: Path) -> bool:
    """True if process ``pid`` holds one of the files in ``folder`` open (a merge checking its inputs)."""
    try:
        return any(os.readlink(f"/proc/{pid}/fd/{fd}").startswith(str(folder)) for fd in os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return False


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_merge_stopped_while_it_checks_its_inputs_says_so_in_one_line(tmp_path, sig, status):
    sc = _scenario(tmp_path, "straight_line")
    one = tmp_path / "one.sqlite"
    assert _batch(sc, one, False, "--workers", "1", "--limit", "2").returncode == 0
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    for i in range(300):                           # checking 300 inputs takes long enough to be signalled
        (inputs / f"s{i:03d}.sqlite").write_bytes(one.read_bytes())
    out = tmp_path / "merged.sqlite"
    proc = subprocess.Popen(pbdyn_cmd() + ["merge", *sorted(map(str, inputs.iterdir())), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not _open_inputs(proc.pid, inputs):
        assert proc.poll() is None and time.monotonic() < deadline, "the merge ended before it could be stopped"
        time.sleep(0.002)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert err.count("\n") == 1 and err.startswith(f"pbdyn: merge stopped by {sig.name}: ") and "Traceback" not in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".merged")]
