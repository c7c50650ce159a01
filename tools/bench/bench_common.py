"""Shared by the benchmark scripts: a one-line description of the machine, the best time of a call."""

from __future__ import annotations

import os
import platform
import time

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
