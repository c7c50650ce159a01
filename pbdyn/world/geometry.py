"""Geometry shared by rollouts, the PyBullet world and collision queries (static bodies), the MAV's state and the
gaze planners (angle wrapping)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def wrap_angle(angle):
    """``angle`` (rad; a float or an array) wrapped into [-pi, pi): (angle + pi) mod 2 pi - pi."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class StaticBody:
    """One static obstacle (world frame, SI).

    kind: "pillar" (vertical cylinder spanning the flight band; in 3D it spans the whole volume height) or "box".
    center: [x, y] or [x, y, z] (m); for a 2D box or pillar z is ignored (it spans the flight band).
    radius: pillar radius (m); ignored for boxes.
    size: box full extents [sx, sy] or [sx, sy, sz] (m); ignored for pillars. In 2D a box spans the flight band.
    yaw: rotation about z (rad).
    """

    kind: str
    center: tuple[float, ...]
    radius: float = 0.0
    size: tuple[float, ...] = ()
    yaw: float = 0.0

    def footprint_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) from points [K, d] to this body's surface (negative inside), in the body's d.

        Pillars are infinite vertical cylinders (distance in the x-y plane); 2D boxes are rectangles; 3D boxes cuboids.
        """
        pts = np.asarray(points, dtype=float)
        d = pts.shape[-1]
        c = np.asarray(self.center, dtype=float)[:d]
        if self.kind == "pillar":
            rel = pts[..., :2] - c[:2]
            return np.sqrt(np.sum(rel * rel, axis=-1)) - self.radius
        rel = pts - c
        cy, sy = np.cos(self.yaw), np.sin(self.yaw)
        local = rel.copy()
        local[..., 0] = cy * rel[..., 0] + sy * rel[..., 1]
        local[..., 1] = -sy * rel[..., 0] + cy * rel[..., 1]
        half = np.asarray(self.size, dtype=float)[:d] / 2.0
        q = np.abs(local) - half
        outside = np.sqrt(np.sum(np.maximum(q, 0.0) ** 2, axis=-1))
        inside = np.minimum(np.max(q, axis=-1), 0.0)
        return outside + inside
