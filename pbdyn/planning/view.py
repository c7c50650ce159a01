"""The read-only snapshot a planner sees each step (docs/design.md "Planner protocols").

Planners never see the rollout: only the MAV's own state, its occupancy grid, the active Kalman tracks, the goal
and the time. Arrays in a View are read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pbdyn.perception.tracks import Tracks, readonly  # Tracks: re-exported for planners
from pbdyn.planning.trajectory import Trajectory

if TYPE_CHECKING:  # pragma: no cover
    from pbdyn.perception.grid import OccupancyGrid


@dataclass(frozen=True)
class MAVLimits:
    """The MAV's physical limits. v_max (m/s) and a_max (m/s^2) bound Euclidean norms; yaw_rate (rad/s)."""

    radius: float
    v_max: float
    a_max: float
    yaw_rate: float


_ARRAYS = ("position", "velocity", "acceleration", "goal", "bounds_lo", "bounds_hi")


@dataclass(frozen=True)
class View:
    """What the MAV knows at time t (all SI, world frame, z-up; d = 2 or 3).

    Attributes:
        t: time (s) of this step.
        dt: world step (s).
        position, velocity, acceleration: MAV state [d] (m, m/s, m/s^2).
        yaw: MAV heading (rad, counter-clockwise from +x).
        goal: goal position [d] (m); goal_radius (m) ends the trial on success.
        limits: the MAV's radius and limits.
        bounds_lo, bounds_hi: arena box [d] (m); the border is a wall.
        grid: the MAV's occupancy grid (read it, never write it).
        tracks: active Kalman tracks.
        trajectory: the plan currently being executed, or None.
        fov_deg: the sensor's horizontal field of view (deg); range_m: its range (m); vfov_deg: its vertical field
            of view (deg; 3D only, None in 2D).
    """

    t: float
    dt: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    yaw: float
    goal: np.ndarray
    goal_radius: float
    limits: MAVLimits
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    grid: "OccupancyGrid"
    tracks: Tracks
    trajectory: Trajectory | None = None
    fov_deg: float = 90.0
    range_m: float = 8.0
    vfov_deg: float | None = None
    extras: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in _ARRAYS:
            object.__setattr__(self, name, readonly(np.array(getattr(self, name), dtype=float)))

    @classmethod
    def of_owned(cls, t: float, dt: float, position, velocity, acceleration, yaw: float, goal: np.ndarray,
                 goal_radius: float, limits: MAVLimits, bounds_lo: np.ndarray, bounds_hi: np.ndarray, grid, tracks,
                 trajectory: "Trajectory | None", fov_deg: float, range_m: float, vfov_deg: float | None) -> "View":
        """The View View(...) makes of the same values (the environment's per-step view, without the dataclass
        __init__'s per-field cost): position, velocity and acceleration [d] are copied read-only as there; goal,
        bounds_lo and bounds_hi must already be read-only float arrays [d] that nobody writes (they are shared,
        not copied)."""
        view = object.__new__(cls)
        view.__dict__.update(t=t, dt=dt, position=readonly(np.array(position, dtype=float)),
                             velocity=readonly(np.array(velocity, dtype=float)),
                             acceleration=readonly(np.array(acceleration, dtype=float)), yaw=yaw, goal=goal,
                             goal_radius=goal_radius, limits=limits, bounds_lo=bounds_lo, bounds_hi=bounds_hi,
                             grid=grid, tracks=tracks, trajectory=trajectory, fov_deg=fov_deg, range_m=range_m,
                             vfov_deg=vfov_deg, extras={})
        return view

    @property
    def dims(self) -> int:
        """Spatial dimension d."""
        return int(self.position.shape[0])
