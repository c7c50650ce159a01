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

HERE = Path(__file__).resolve().parent


def _children(pid: int) -> list[int]:
    """The pids of ``pid``'s child processes (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(d.name))
    return out


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _still_running(kids: list[int], within: float) -> list[int]:
    deadline = time.monotonic() + within
    while any(_running(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return [k for k in kids if _running(k)]


def _start_generate(tmp_path: Path) -> tuple[subprocess.Popen, list[int]]:
    """A `pbdyn generate` on 2 workers that runs for minutes (a tight tolerance, many maps), once its workers are
    measuring; (the process, its children: 2 workers and multiprocessing's resource tracker)."""
    proc = subprocess.Popen(pbdyn_cmd() + ["generate", "--metric", "survivability", "--target", "5.0", "--tolerance",
                                           "0.01", "--count", "500", "--workers", "2", "--out", "gen.toml"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while len(_children(proc.pid)) < 3:
        assert proc.poll() is None and time.monotonic() < deadline, "generate ended or never started its workers"
        time.sleep(0.05)
    time.sleep(1.5)                  # the workers are measuring the pilot's candidates
    return proc, _children(proc.pid)


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
