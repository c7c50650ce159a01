"""Rule-based gaze planners (thesis 4-1-2): LookAhead (eq. 4-1, 4-2), FullRange, LookGoal (eq. 4-3, 4-4) and its
program variant, Rotating. Yaw only; in 3D the x-y components count. Finean et al. and Owl, which score sampled yaw
rates, live in pbdyn.planning.gaze.finean / pbdyn.planning.gaze.owl; the shared yaw arithmetic in
pbdyn.planning.gaze.yaw."""

from __future__ import annotations

import numpy as np

from pbdyn.perception.grid import UNKNOWN
from pbdyn.planning import params
from pbdyn.planning.gaze.yaw import clip_rate, heading
from pbdyn.planning.protocols import PlannerContext
from pbdyn.planning.trajectory import Trajectory
from pbdyn.planning.view import View
from pbdyn.world.geometry import wrap_angle


class LookAhead:
    """Yaw toward the MAV's velocity (registry name "lookahead"; thesis eq. 4-1, 4-2).

    rate = clip(wrap(heading - yaw) * gain, +-yaw_rate limit) with wrap into (-pi, pi] (-wrap_angle(yaw - heading),
    pbdyn.world.geometry), so the MAV turns the shortest way (counter-clockwise when the heading is exactly behind)
    and reaches the heading in one step whenever the limit allows (default gain 1 / dt). The heading is that of the
    velocity; when |v| < 1e-6 m/s, that of the plan's velocity at the next step, else the direction to the plan's
    last point, else the direction to the goal; with none of them the rate is 0. ``at_rest = "hold"`` (the thesis
    program, its PROGRAM_PARAMS): rate 0 whenever |v| < 1e-6 m/s.
    """

    PROGRAM_PARAMS: dict = {"at_rest": "hold"}
    """The thesis_program profile's parameters: the program's LookAhead returned 0 for a MAV at rest."""

    def __init__(self, context: PlannerContext, *, gain: float | None = None, at_rest: str = "plan"):
        if gain is not None:
            gain = params.positive("gain", gain)
        if at_rest not in ("plan", "hold"):
            raise ValueError(f"at_rest must be 'plan' or 'hold', got {at_rest!r}")
        self.at_rest = at_rest
        self.limit = float(context.limits.yaw_rate)
        self.gain = 1.0 / float(context.dt) if gain is None else float(gain)

    def targetheading(self, view: View, trajectory: Trajectory | None) -> float | None:
        """The heading (rad) the MAV should look along, or None if no direction is defined."""
        h = heading(view.velocity)
        if h is None and self.at_rest == "hold":
            return None
        if h is None and trajectory is not None:
            k = min(max(trajectory.index_at(view.t + view.dt), 0), trajectory.n_samples - 1)
            h = heading(trajectory.v[k])
            if h is None:
                h = heading(trajectory.p[-1] - view.position)
        if h is None:
            h = heading(view.goal - view.position)
        return h

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Yaw rate (rad/s) for the step view.t -> view.t + dt."""
        h = self.targetheading(view, trajectory)
        if h is None:
            return 0.0
        return clip_rate((0.0 - wrap_angle(view.yaw - h)) * self.gain, self.limit)   # 0.0 - x: never -0.0


class FullRange:
    """A 360-degree sensor and no yaw control (registry name "fullrange")."""

    fov_deg = 360.0

    def __init__(self, context: PlannerContext):
        self.context = context

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """Always 0 rad/s."""
        return 0.0


class LookGoal(LookAhead):
    """Yaw toward the goal (registry name "lookgoal"; thesis eq. 4-3, 4-4).

    The rate minimising the angle between the next-step yaw direction and the MAV-to-goal direction (x-y part) under
    |rate| <= limit: clip(wrap(heading - yaw) * gain, +-limit) with gain 1 / dt by default, so the MAV turns the
    shortest way (counter-clockwise when the goal is exactly behind). Rate 0 when the goal is within 1e-6 m.
    """

    def targetheading(self, view: View, trajectory: Trajectory | None) -> float | None:
        """The heading (rad) from the MAV to the goal, or None at the goal."""
        return heading(view.goal - view.position)


class LookGoalUnexplored(LookAhead):
    """The thesis program's LookGoal (registry name "lookgoal_unexplored"; docs/thesis-program.md "Gaze planners").

    Yaw toward the first future sample of the plan in execution (times after view.t) whose grid cell is still
    UNKNOWN; if every remaining sample is explored, toward the plan's last sample; without a plan (or when that
    point is within 1e-6 m of the MAV), toward the goal. Same rate law as LookAhead / LookGoal.
    This is the variant that produced the thesis' LookGoal results, so a reproduction of its figures uses it;
    "lookgoal" follows the thesis text (eq. 4-3).
    """

    def targetheading(self, view: View, trajectory: Trajectory | None) -> float | None:
        """The heading (rad) toward the first unexplored plan sample, else the plan's end, else the goal."""
        h = None
        if trajectory is not None:
            k0 = min(max(trajectory.index_at(view.t) + 1, 0), trajectory.n_samples - 1)
            future = trajectory.p[k0:]
            unknown = np.flatnonzero(view.grid.value_at(future) == UNKNOWN)
            target = future[unknown[0]] if unknown.shape[0] else trajectory.p[-1]
            h = heading(target - view.position)
        if h is None:
            h = heading(view.goal - view.position)
        return h


class Rotating:
    """Turn at a constant rate (registry name "rotating"; thesis 4-1-2): rate_fraction * yaw-rate limit.

    The default rate_fraction = 1 turns counter-clockwise at the limit and sweeps 360 deg in 2 pi / limit seconds;
    -1 turns clockwise; 0 keeps the start yaw (a fixed-yaw baseline). rate_fraction must lie in [-1, 1].
    """

    def __init__(self, context: PlannerContext, *, rate_fraction: float = 1.0):
        rate_fraction = params.number("rate_fraction", rate_fraction, lo=-1.0, hi=1.0)
        self.rate = float(rate_fraction) * float(context.limits.yaw_rate)

    def yaw_rate(self, view: View, trajectory: Trajectory | None) -> float:
        """The constant rate (rad/s)."""
        return self.rate
