"""Shared by the benchmark scripts: a one-line description of the machine, the best time of a call, the native
library shared with an old revision's worktree."""

from __future__ import annotations

import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np


def machine() -> str:
    """One line naming the CPU, core count and the Python / numpy versions."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), cpu)
    except OSError:
        pass
    return f"machine: {cpu} ({platform.machine()}), cpus={os.cpu_count()}, python={platform.python_version()}, " \
           f"numpy={np.__version__}"


def best_time(fn, rounds: int) -> float:
    """The shortest wall time (s) of ``rounds`` calls of fn()."""
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


_ROOT = Path(__file__).resolve().parents[2]


def share_native_library(old_tree: Path) -> str:
    """Give the old tree this checkout's built native library (git does not hold it) when both trees build it from
    the same source, so that old and new fly with the same ruckig calculator; what was done, as a line."""
    new_src = next(_ROOT.joinpath("pbdyn").rglob("ruckig_batch.cpp"), None)
    old_src = next(old_tree.joinpath("pbdyn").rglob("ruckig_batch.cpp"), None)
    if new_src is None or old_src is None:
        return "no native library in one of the trees"
    if new_src.read_bytes() != old_src.read_bytes():
        return "native library sources differ: the old tree flies without it"
    copied = []
    for f in new_src.parent.glob("_ruckig_batch.so*"):
        shutil.copy2(f, old_src.parent / f.name)
        copied.append(f.name)
    return f"this checkout's native library copied ({', '.join(sorted(copied)) or 'none built'})"
