"""Planner plug-ins used by the batch tests (loaded as "tests.batch_plugins:Class")."""

from __future__ import annotations

from pbdyn.planning.local_primitives import LocalPrimitives


class FlakyPlanner(LocalPrimitives):
    """Local primitives that raise on every trial starting at x > 40 m (to test "error" rows)."""

    def plan(self, view):
        if view.t == 0.0 and view.position[0] > 40.0:
            raise RuntimeError("flaky planner: start x > 40 m")
        return super().plan(view)
