"""Trajectory planners that break the plan contract, each in one way (used by tests/test_contract.py)."""

from __future__ import annotations

import numpy as np

from pbdyn.planning.trajectory import Trajectory


class _Base:
    def __init__(self, context, **params):
        self.ctx = context

    def replan_check(self, view) -> bool:
        return True

    def hover(self, view, k: int = 5) -> Trajectory:
        """A valid plan: braking to rest from the current state (here: at rest, so staying put)."""
        p = np.repeat(view.position[None], k, axis=0)
        v = np.repeat(view.velocity[None], k, axis=0)
        return Trajectory(view.t, view.dt, p, v, np.zeros_like(p))


class OverSpeed(_Base):
    """Straight at the goal at twice v_max (consistent p, v, a except the speed)."""

    def plan(self, view):
        u = view.goal - view.position
        u /= np.linalg.norm(u)
        speed = 2.0 * view.limits.v_max
        k = np.arange(30)[:, None]
        p = view.position + u * speed * k * view.dt
        v = np.repeat((u * speed)[None], 30, axis=0)
        p[0], v[0] = view.position, view.velocity
        return Trajectory(view.t, view.dt, p, v, np.zeros_like(p))


class Teleport(_Base):
    """Sample 1 is the goal, at rest."""

    def plan(self, view):
        p = np.stack([view.position, view.goal])
        v = np.stack([view.velocity, np.zeros_like(view.velocity)])
        return Trajectory(view.t, view.dt, p, v, np.zeros_like(p))


class WrongT0(_Base):
    """A valid hover plan stamped one step in the past."""

    def plan(self, view):
        h = self.hover(view)
        return Trajectory(view.t - view.dt, h.dt, h.p, h.v, h.a)


class StartOff(_Base):
    """Sample 0 is 0.1 m away from the MAV."""

    def plan(self, view):
        h = self.hover(view)
        p = h.p.copy()
        p[:, 0] += 0.1
        return Trajectory(h.t0, h.dt, p, h.v, h.a)


class NotATrajectory(_Base):
    """Returns a tuple of arrays instead of a Trajectory."""

    def plan(self, view):
        h = self.hover(view)
        return (h.p, h.v, h.a)


class LateCheat(_Base):
    """Flies a valid constant-acceleration plan toward the goal, then at t >= 0.5 s jumps 5 m ahead."""

    def plan(self, view):
        u = view.goal - view.position
        u /= np.linalg.norm(u)
        a = u * view.limits.a_max * 0.5
        k = np.arange(2)[:, None] * view.dt
        p = view.position + view.velocity * k + 0.5 * a * k * k
        v = view.velocity + a * k
        if view.t >= 0.5 - 1e-9:
            p = p.copy()
            p[1] += 5.0 * u
        return Trajectory(view.t, view.dt, p, v, np.repeat(a[None], 2, axis=0))
