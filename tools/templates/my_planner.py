"""A template trajectory planner for pbdyn: copy this file, rename the class, and change ``plan``.

Use it from a scenario (the folder holding this file must be importable, e.g. PYTHONPATH=tools/templates):

    [[planners]]
    trajectory = "my_planner:GoalSeeker"
    gaze = "lookahead"
    trajectory_params = { horizon_s = 2.0, n_headings = 13 }

pbdyn builds the planner once per trial as ``GoalSeeker(context, **trajectory_params)`` and calls, every step,
``replan_check(view)`` and, when that returns True, ``plan(view)`` (docs/planners.md "Your planner, step by step"). The
planner sees only what the MAV knows (``view``): its state, its occupancy grid, the Kalman tracks of the obstacles
it has seen, the goal and the time; never the true obstacle motion.

GoalSeeker is deliberately simple but really flies: it tries headings fanned around the direction to the goal
(nearest first), simulates a double integrator steering toward each at v_max for ``horizon_s`` seconds, and takes
the first whose samples are clear of the walls, the occupied cells and the tracks' constant-velocity predictions.
If none is clear it brakes (and returns None if even braking conflicts, which pbdyn counts as a planning failure).
"""

from __future__ import annotations

import numpy as np

from pbdyn.planning.checks import trajectory_clear
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View


class GoalSeeker:
    """Fan-of-headings planner (see the module docstring).

    Args:
        context: fixed facts of the trial (dims, dt s, limits: radius m, v_max m/s, a_max m/s^2, yaw rate rad/s;
            arena bounds m; a seed for any randomness).
        horizon_s: how far ahead each candidate is simulated and checked (s).
        n_headings: candidate headings, spread over +-90 deg around the goal direction (odd: includes it).
        margin: extra clearance (m) demanded from walls, occupied cells and tracks.
    """

    def __init__(self, context: PlannerContext, *, horizon_s: float = 2.0, n_headings: int = 13,
                 margin: float = 0.3):
        if horizon_s <= 0:
            raise ValueError(f"horizon_s must be > 0 (got {horizon_s})")
        if not isinstance(n_headings, int) or n_headings < 1:
            raise ValueError(f"n_headings must be an integer >= 1 (got {n_headings})")
        if margin < 0:
            raise ValueError(f"margin must be >= 0 (got {margin})")
        self.ctx = context
        self.horizon_s = float(horizon_s)
        self.margin = float(margin)
        offsets = np.radians(np.linspace(-90.0, 90.0, n_headings)) if n_headings > 1 else np.zeros(1)
        self.offsets = offsets[np.argsort(np.abs(offsets), kind="stable")]     # nearest to the goal first

    def replan_check(self, view: View) -> bool:
        """Replan every step (cheap enough); a planner may keep its plan while it stays clear instead."""
        return True

    def _rollout(self, view: View, target_velocity) -> Trajectory:
        """A double integrator from the current state steering toward ``target_velocity`` [d] (m/s) with |a| <= a_max
        (and so |v| <= v_max), sampled at the world step for horizon_s."""
        dt, lim = view.dt, self.ctx.limits
        n = max(2, int(round(self.horizon_s / dt)) + 1)
        p, v = view.position.copy(), view.velocity.copy()
        ps, vs, acc = [p], [v], []
        for k in range(n):
            a = (np.asarray(target_velocity) - v) / dt
            norm = float(np.linalg.norm(a))
            if norm > lim.a_max:
                a = a * (lim.a_max / norm)
            acc.append(a)
            if k == n - 1:
                break
            p = p + v * dt + 0.5 * a * dt * dt
            v = v + a * dt
            ps.append(p)
            vs.append(v)
        return Trajectory(view.t, dt, np.array(ps), np.array(vs), np.array(acc))

    def plan(self, view: View) -> Trajectory | None:
        """The first clear candidate toward the goal, else a braking trajectory, else None."""
        to_goal = view.goal - view.position
        dist = float(np.linalg.norm(to_goal))
        lim = self.ctx.limits
        speed = min(lim.v_max, np.sqrt(2.0 * lim.a_max * dist), dist / view.dt)
        base = np.arctan2(to_goal[1], to_goal[0])
        for off in self.offsets:
            heading = base + off
            direction = np.zeros(view.dims)
            direction[:2] = np.cos(heading), np.sin(heading)
            if view.dims == 3 and dist > 0:           # keep the goal's climb rate along the chosen heading
                direction[2] = to_goal[2] / max(float(np.hypot(to_goal[0], to_goal[1])), 1e-9)
                direction /= np.linalg.norm(direction)
            traj = self._rollout(view, speed * direction)
            if trajectory_clear(view, traj.p, traj.times, self.margin):
                return traj
        brake = self._rollout(view, np.zeros(view.dims))
        return brake if trajectory_clear(view, brake.p, brake.times, 0.0) else None
