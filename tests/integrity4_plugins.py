"""Planner plug-ins that misbehave on one trial (loaded as "tests.integrity4_plugins:Class"): they hang, crash the
process with SIGSEGV or leave it with os._exit when the trial starts at x > 40 m and flies to y > 40 m; every other
trial flies as local primitives."""

from __future__ import annotations

import ctypes
import os
import signal
import time

import pbdyn.usercode
from pbdyn.planning.gaze.rules import LookAhead
from pbdyn.planning.primitives.local import LocalPrimitives

HANG_BUDGET_S = 0.5
pbdyn.usercode.PLANNER_CALL_TIMEOUT_S = HANG_BUDGET_S      # a short budget in the processes that import this module


def _chosen(view) -> bool:
    """The misbehaving trial, only with PBDYN_TEST_MISBEHAVE=1 in the environment (without it these planners fly
    as their bases, with the same fingerprint): a decision at x > 40 m with a goal at y > 40 m and x < 10 m (the MAV
    started at x = 46 m: one start/goal pair of the tests' scenario)."""
    return (view.position[0] > 40.0 and view.goal[1] > 40.0 and view.goal[0] < 10.0
            and os.environ.get("PBDYN_TEST_MISBEHAVE") == "1")


class HangingPlanner(LocalPrimitives):
    """plan never returns on the chosen trial (a busy loop that also swallows exceptions)."""

    def plan(self, view):
        if _chosen(view):
            while True:
                try:
                    time.sleep(0.01)
                except Exception:
                    pass
        return super().plan(view)


class HangingGaze(LookAhead):
    """yaw_rate never returns on the chosen trial."""

    def yaw_rate(self, view, trajectory):
        if _chosen(view):
            while True:
                pass
        return super().yaw_rate(view, trajectory)


class SegfaultPlanner(LocalPrimitives):
    """plan crashes its process with SIGSEGV on the chosen trial."""

    def plan(self, view):
        if _chosen(view):
            os.kill(os.getpid(), signal.SIGSEGV)
        return super().plan(view)


class CtypesSegfaultPlanner(LocalPrimitives):
    """plan reads address 0 through ctypes on the chosen trial (a real segmentation fault)."""

    def plan(self, view):
        if _chosen(view):
            ctypes.string_at(0)
        return super().plan(view)


class ExitPlanner(LocalPrimitives):
    """plan ends its process with os._exit(3) on the chosen trial."""

    def plan(self, view):
        if _chosen(view):
            os._exit(3)
        return super().plan(view)
