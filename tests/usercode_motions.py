"""Misbehaving motion functions and planners for the user-code boundary tests (tests/test_usercode.py).

Each is named in a world file as "tests.usercode_motions:<name>" (run from the repository root)."""

from __future__ import annotations

import math
import sys
import time


class CustomBase(BaseException):
    """A BaseException that is not an Exception (user code may define such things)."""


def good(t, *, center=(25.0, 25.0, 2.0)):
    return [center[0] + math.cos(t), center[1] + math.sin(t), center[2]]


def returns_string(t, **_):
    return "twelve"


def returns_string_tuple(t, **_):
    return ("1", "2", "3")


def returns_complex(t, **_):
    return [25.0 + 1j, 25.0, 2.0]


def returns_none(t, **_):
    return None


def returns_dict(t, **_):
    return {"x": 1.0}


def returns_short(t, **_):
    return [25.0, 25.0]


def returns_nan(t, **_):
    return [25.0, float("nan") if t > 0.5 else 25.0, 2.0]


def returns_inf(t, **_):
    return [float("inf"), 25.0, 2.0]


def returns_bool(t, **_):
    return [True, False, True]


def returns_zero_quat(t, **_):
    return [25.0, 25.0, 2.0], [0.0, 0.0, 0.0, 0.0]


def returns_nan_quat(t, **_):
    return [25.0, 25.0, 2.0], [0.0, 0.0, float("nan"), 1.0]


def returns_huge_quat(t, **_):
    return [25.0, 25.0, 2.0], [0.0, 0.0, 1e300, 1e300]


def returns_short_quat(t, **_):
    return [25.0, 25.0, 2.0], [0.0, 0.0, 1.0]


def returns_huge_int(t, **_):
    return [2 ** 2000, 25.0, 2.0]


def returns_multiline_array(t, **_):
    import numpy as np
    return np.arange(200.0).reshape(20, 10)


class _BadFloat:
    def __float__(self):
        raise SystemExit(5)


def returns_bad_float(t, **_):
    return [_BadFloat(), 25.0, 2.0]


def raises_system_exit(t, **_):
    sys.exit(3)


def raises_system_exit_text(t, **_):
    sys.exit("bye\nnow")


def raises_generator_exit(t, **_):
    raise GeneratorExit


def raises_custom_base(t, **_):
    raise CustomBase("not an Exception")


def raises_value_error(t, **_):
    raise ValueError("line one\nline two")


class _Unprintable(Exception):
    def __str__(self):
        raise RuntimeError("no str for you")


def raises_unprintable(t, **_):
    raise _Unprintable()


def sleeps(t, *, seconds=3600.0):
    time.sleep(seconds)
    return [25.0, 25.0, 2.0]


def busy(t, **_):
    while True:
        pass


def swallows(t, **_):
    """Sleeps forever, swallowing every exception (even the budget's) -- the budget must still stop it."""
    while True:
        try:
            time.sleep(3600.0)
        except BaseException:
            pass


def slow(t, *, seconds=0.05):
    time.sleep(seconds)
    return [25.0, 25.0, 2.0]


def prints(t, **_):
    print(f"hello from the motion function at t = {t}")
    sys.stdout.write("more chatter\n")
    return [25.0 + math.cos(t), 25.0 + math.sin(t), 2.0]


def prints_c_level(t, **_):
    import os
    os.write(1, b"raw fd 1 chatter\n")
    return [25.0, 25.0, 2.0]


def interrupts(t, **_):
    raise KeyboardInterrupt


# ------------------------------------------------------------------------------------------------ planners
from pbdyn.planning.gaze.rules import FullRange  # noqa: E402
from pbdyn.planning.straight_line import StraightLine  # noqa: E402


class PrintingPlanner(StraightLine):
    """The straight-line planner, chatty on stdout in __init__, replan_check and plan (Python and C level)."""

    def __init__(self, context, **kw):
        print("PrintingPlanner.__init__ says hello")
        import os
        os.write(1, b"PrintingPlanner.__init__ fd 1\n")
        super().__init__(context, **kw)

    def replan_check(self, view):
        print("replan_check?")
        return super().replan_check(view)

    def plan(self, view):
        sys.stdout.write(f"planning at t = {view.t}\n")
        return super().plan(view)


class PrintingGaze(FullRange):
    def yaw_rate(self, view, trajectory):
        print("gaze!")
        return super().yaw_rate(view, trajectory)


def returns_far(t, *, x=1e300):
    """Finite but absurd positions (far outside any arena)."""
    return [x * (1.0 + t), 25.0, 2.0]


class ExitingPlanner(StraightLine):
    """plan() calls sys.exit (a planner plug-in's BaseException)."""

    def plan(self, view):
        sys.exit(7)


class RaisingPlanner(StraightLine):
    def plan(self, view):
        raise RuntimeError("planner bug")
