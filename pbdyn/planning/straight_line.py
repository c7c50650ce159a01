"""Baseline planner: fly straight to the goal at v_max and never avoid anything (registry name "straight_line")."""

from __future__ import annotations

import math

import numpy as np

from pbdyn.limits import MAX_PLAN_HORIZON_S
from pbdyn.planning import params
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View


class StraightLine:
    """Straight-line flight to the goal, replanned every step; ignores tracks and the grid.

    Each plan simulates a double integrator over ``horizon_s`` seconds at the world step: the desired velocity points
    at the goal with speed min(v_max, sqrt(2 a_max d), d / dt) for goal distance d (cruise, then brake to stop at the
    goal without overshoot), and the acceleration (v_desired - v) / dt is clipped to the norm a_max. That corrects a
    velocity that is not aligned with the goal and keeps |v| <= max(|v_0|, v_max) (a convex combination of the current
    and the desired velocity). a[k] is the constant acceleration commanded from sample k to k + 1 (the last sample
    holds the command it would apply next), so sample 0's acceleration is the command for the first step, not the
    MAV's previous acceleration.

    Args:
        context: the trial's fixed facts.
        horizon_s: length of the returned trajectory (s); at least one step.
    """

    def __init__(self, context: PlannerContext, *, horizon_s: float = 1.0):
        horizon_s = params.number("horizon_s", horizon_s, lo=0.0, lo_open=True, hi=MAX_PLAN_HORIZON_S)
        self.dims = int(context.dims)
        self.limits = context.limits
        self.horizon_s = float(horizon_s)

    def replan_check(self, view: View) -> bool:
        """Always True: the baseline replans every step."""
        return True

    def plan(self, view: View) -> Trajectory:
        """The straight-line trajectory from the current state (t0 = view.t, dt = view.dt, K >= 2 samples)."""
        dt = view.dt
        n = max(2, int(round(self.horizon_s / dt)) + 1)
        v_max, a_max = self.limits.v_max, self.limits.a_max
        goal = view.goal.tolist()
        p = view.position.tolist()
        v = view.velocity.tolist()
        d = self.dims
        ps, vs, acc = [p], [v], []
        for _ in range(n):
            e = [goal[i] - p[i] for i in range(d)]
            dist = math.sqrt(sum(x * x for x in e))
            speed = min(v_max, math.sqrt(2.0 * a_max * dist), dist / dt)
            scale = speed / dist if dist > 1e-12 else 0.0
            a = [(e[i] * scale - v[i]) / dt for i in range(d)]
            a_norm = math.sqrt(sum(x * x for x in a))
            if a_norm > a_max:
                a = [x * (a_max / a_norm) for x in a]
            acc.append(a)
            if len(ps) == n:
                break
            p = [p[i] + v[i] * dt + 0.5 * a[i] * dt * dt for i in range(d)]
            v = [v[i] + a[i] * dt for i in range(d)]
            ps.append(p)
            vs.append(v)
        return Trajectory(view.t, dt, np.array(ps), np.array(vs), np.array(acc))
