"""A template gaze planner for pbdyn: copy this file, rename the class, and change ``yaw_rate``.

Use it from a scenario (the folder holding this file must be importable, e.g. PYTHONPATH=tools/templates):

    [[planners]]
    trajectory = "local_primitives"
    gaze = "my_gaze:WatchNearest"
    gaze_params = { watch_m = 6.0 }

pbdyn builds the planner once per trial as ``WatchNearest(context, **gaze_params)`` and calls ``yaw_rate(view,
trajectory)`` every step (pbdyn.planning.protocols.GazePlanner; docs/planners.md "Your planner, step by step").

Inputs (world frame, z up, SI units; d = 2 or 3):
    context (pbdyn.planning.protocols.PlannerContext): dims d; dt (s); limits.yaw_rate (rad/s), radius (m), v_max
        (m/s), a_max (m/s^2); bounds_lo, bounds_hi [d] (m); seed (int).
    view (pbdyn.planning.view.View), what the MAV knows at view.t (s): position, velocity [d] (m, m/s); yaw (rad,
        counter-clockwise from +x); goal [d] (m); tracks (pbdyn.planning.view.Tracks: ids [M], position [M, d] (m),
        velocity [M, d] (m/s), radius [M] (m) of the obstacles it has seen); grid (its occupancy grid); fov_deg,
        range_m (deg, m) of its sensor.
    trajectory (pbdyn.planning.trajectory.Trajectory or None while braking): the plan in execution, samples
        p, v [K, d] (m, m/s) from t0 (s) every dt (s).
Output: the yaw rate (rad/s, counter-clockwise positive) for the step view.t -> view.t + dt; pbdyn clips it to
    +-limits.yaw_rate. An optional attribute ``fov_deg`` (deg) would impose a sensor field of view.

WatchNearest is deliberately simple but really flies: it looks at the nearest tracked obstacle within ``watch_m``
metres (so the tracker keeps seeing it), else along the plan's velocity one step ahead, else at the goal.
"""

from __future__ import annotations

import math

import numpy as np

from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View


class WatchNearest:
    """Look at the nearest track within watch_m (m), else where the plan goes, else at the goal.

    Args:
        context: fixed facts of the trial (see the module docstring).
        watch_m: tracks whose centre is closer than this (m) are watched.
    """

    def __init__(self, context: PlannerContext, *, watch_m: float = 6.0):
        if not watch_m > 0:
            raise ValueError(f"watch_m must be > 0 (got {watch_m})")
        self.watch_m = float(watch_m)
        self.limit = float(context.limits.yaw_rate)

    def _target(self, view: View, trajectory: Trajectory | None) -> np.ndarray:
        """The direction [d] (world frame) to look along."""
        tracks = view.tracks
        if len(tracks):
            offsets = tracks.position - view.position                       # [M, d] (m)
            dist = np.linalg.norm(offsets[:, :2], axis=1)
            i = int(np.argmin(dist))
            if dist[i] < self.watch_m:
                return offsets[i]
        if trajectory is not None:
            k = min(max(trajectory.index_at(view.t + view.dt), 0), trajectory.n_samples - 1)
            if np.hypot(*trajectory.v[k][:2]) > 1e-6:
                return trajectory.v[k]
        return view.goal - view.position

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Turn toward the target direction's heading as fast as allowed (rad/s); 0 when it has no heading."""
        target = self._target(view, trajectory)
        if math.hypot(target[0], target[1]) < 1e-6:
            return 0.0
        turn = math.remainder(math.atan2(target[1], target[0]) - view.yaw, 2.0 * math.pi)   # rad, in [-pi, pi]
        return max(-self.limit, min(self.limit, turn / view.dt))
