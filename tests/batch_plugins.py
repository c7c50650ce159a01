"""Planner plug-ins used by the batch tests (loaded as "tests.batch_plugins:Class")."""

from __future__ import annotations

import time

from pbdyn.planning.primitives.local import LocalPrimitives


class FlakyPlanner(LocalPrimitives):
    """Local primitives that raise on every trial starting at x > 40 m (to test "error" rows)."""

    def plan(self, view):
        if view.t == 0.0 and view.position[0] > 40.0:
            raise RuntimeError("flaky planner: start x > 40 m")
        return super().plan(view)


class SlowPlanner(LocalPrimitives):
    """Local primitives that wait 2 ms before every plan (the same plans): a batch that lasts long enough to be
    signalled while both workers fly, however fast the built-in planner has become."""

    def plan(self, view):
        time.sleep(0.002)
        return super().plan(view)
