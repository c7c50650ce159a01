"""Example motion functions for imported bodies (``motion = "pbdyn.world.motions:circle"`` in a world file).

A motion function is called as ``f(t, **params)`` with t in seconds and returns the body's base position [3] (m,
world frame) or (position [3], quaternion xyzw [4]); it must be deterministic (a pure function of t and params).
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def circle(t: float, *, center: Sequence[float], radius: float, period: float, phase_deg: float = 0.0,
           face_motion: bool = True) -> tuple[list[float], list[float]]:
    """A base moving counter-clockwise on a horizontal circle of ``radius`` (m) about ``center`` [3] (m), one lap
    per ``period`` (s; negative: clockwise), starting at angle ``phase_deg``; with ``face_motion`` the body yaws
    to face along its motion, else it keeps the identity orientation."""
    a = math.radians(phase_deg) + 2.0 * math.pi * t / period
    pos = [center[0] + radius * math.cos(a), center[1] + radius * math.sin(a), center[2]]
    yaw = a + math.copysign(math.pi / 2.0, period) if face_motion else 0.0
    return pos, [0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)]


def bob(t: float, *, center: Sequence[float], amplitude: float, period: float) -> list[float]:
    """A base oscillating vertically about ``center`` [3] (m) with ``amplitude`` (m) and ``period`` (s)."""
    return [center[0], center[1], center[2] + amplitude * math.sin(2.0 * math.pi * t / period)]
