"""Gaze planners (thesis 4-1-2): LookAhead (eq. 4-1, 4-2) and FullRange. Yaw only; in 3D the x-y components count."""

from __future__ import annotations

import math

import numpy as np

from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View

_EPS = 1e-6


def wrap_angle(x: float) -> float:
    """Angle x (rad) wrapped into (-pi, pi]."""
    return math.pi - (math.pi - x) % (2.0 * math.pi)


def _heading(vec: np.ndarray) -> float | None:
    """Heading (rad) of the x-y part of vec, or None when it is shorter than 1e-6."""
    x, y = float(vec[0]), float(vec[1])
    if math.hypot(x, y) < _EPS:
        return None
    return math.atan2(y, x)


class LookAhead:
    """Yaw toward the MAV's velocity (registry name "lookahead"; thesis eq. 4-1, 4-2).

    rate = clip(wrap(heading - yaw) * gain, +-yaw_rate limit), so the MAV turns the shortest way and reaches the
    heading in one step whenever the limit allows (default gain 1 / dt). The heading is that of the velocity; when
    |v| < 1e-6 m/s, that of the plan's velocity at the next step, else the direction to the plan's last point, else
    the direction to the goal; with none of them the rate is 0.
    """

    def __init__(self, context: PlannerContext, *, gain: float | None = None):
        if gain is not None and gain <= 0:
            raise ValueError(f"gain must be > 0, got {gain}")
        self.limit = float(context.limits.yaw_rate)
        self.gain = 1.0 / float(context.dt) if gain is None else float(gain)

    def target_heading(self, view: View, trajectory: Trajectory | None) -> float | None:
        """The heading (rad) the MAV should look along, or None if no direction is defined."""
        h = _heading(view.velocity)
        if h is None and trajectory is not None:
            k = min(max(trajectory.index_at(view.t + view.dt), 0), trajectory.n_samples - 1)
            h = _heading(trajectory.v[k])
            if h is None:
                h = _heading(trajectory.p[-1] - view.position)
        if h is None:
            h = _heading(view.goal - view.position)
        return h

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Yaw rate (rad/s) for the step view.t -> view.t + dt."""
        h = self.target_heading(view, trajectory)
        if h is None:
            return 0.0
        return float(np.clip(wrap_angle(h - view.yaw) * self.gain, -self.limit, self.limit))


class FullRange:
    """A 360-degree sensor and no yaw control (registry name "fullrange")."""

    fov_deg = 360.0

    def __init__(self, context: PlannerContext):
        self.context = context

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Always 0 rad/s."""
        return 0.0
