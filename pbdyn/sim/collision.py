"""Collision checks of one trial step t_k -> t_k+1 (docs/design.md "One trial step", step (7)).

Swept checks (the default): within a step every motion is taken as linear. Dynamic obstacles: the first contact
time is solved exactly from the relative motion. Static geometry: conservative advancement against PyBullet's
true geometry (walls, static bodies), never the perceived grid. Sampled checks reproduce the thesis' per-step test
(overlap at t_k+1 only; thesis 5-1: centre distance < r_obstacle + r_MAV).

In 2D all distances are planar (pillars span the flight band); in 3D Euclidean (spheres). Clearances are signed
distances between surfaces (m): negative means overlap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DynamicContact:
    """hit: the MAV overlaps an obstacle during the step. fraction: first contact time as a fraction of the step
    (0 if already overlapping at its start; 1.0 when no hit). index: obstacle hit first (-1 if none).
    min_clearance: the minimum over the step and over obstacles of centre distance - r_i - r_MAV (m; +inf if N = 0).
    """

    hit: bool
    fraction: float
    index: int
    min_clearance: float


@dataclass(frozen=True)
class StaticContact:
    """hit: the MAV sphere reaches a static body or wall during the step. fraction: when (1.0 if no hit).
    min_clearance: smallest clearance observed (m; capped by the query distance, see swept_static).
    body_id: PyBullet body hit (-1 if none).
    """

    hit: bool
    fraction: float
    min_clearance: float
    body_id: int


_NO_DYNAMIC = DynamicContact(False, 1.0, -1, math.inf)


def swept_dynamic(mav_p0, mav_p1, obs_p0, obs_p1, radii, mav_radius: float) -> DynamicContact:
    """Exact swept MAV-vs-obstacles check for one step with linear motion of every body.

    mav_p0, mav_p1: MAV centre [d] at the step's start and end; obs_p0, obs_p1: obstacle centres [N, d]; radii [N];
    mav_radius (all m). With dp(s) = dp0 + s w the relative position, contact is |dp(s)| = r_i + r_MAV; the first
    contact time is the smaller root of that quadratic in [0, 1]. A hit means the distance drops strictly below
    r_i + r_MAV within the step (touching is not a collision, as in the sampled test).
    """
    p0 = np.asarray(obs_p0, dtype=float)
    if p0.shape[0] == 0:
        return _NO_DYNAMIC
    m0 = np.asarray(mav_p0, dtype=float)
    m1 = np.asarray(mav_p1, dtype=float)
    dp0 = m0 - p0                                                   # [N, d]
    w = (m1 - m0) - (np.asarray(obs_p1, dtype=float) - p0)          # relative displacement over the step
    reach = np.asarray(radii, dtype=float) + float(mav_radius)
    a = np.einsum("ij,ij->i", w, w)
    b = np.einsum("ij,ij->i", dp0, w)                               # half the linear coefficient
    c = np.einsum("ij,ij->i", dp0, dp0) - reach * reach
    moving = a > 0.0
    s_star = np.zeros_like(a)
    np.divide(-b, a, out=s_star, where=moving)
    np.clip(s_star, 0.0, 1.0, out=s_star)
    closest = dp0 + s_star[:, None] * w
    clearance = np.sqrt(np.einsum("ij,ij->i", closest, closest)) - reach
    hit = clearance < 0.0
    min_clearance = float(clearance.min())
    if not hit.any():
        return DynamicContact(False, 1.0, -1, min_clearance)
    # Smaller root of a s^2 + 2 b s + c = 0, in the cancellation-free form c / (-b + sqrt(b^2 - a c)).
    disc = np.sqrt(np.maximum(b * b - a * c, 0.0))
    denom = -b + disc
    frac = np.zeros_like(a)
    np.divide(c, denom, out=frac, where=(c > 0.0) & (denom > 0.0))
    np.clip(frac, 0.0, 1.0, out=frac)
    frac = np.where(hit, frac, np.inf)
    i = int(np.argmin(frac))
    return DynamicContact(True, float(frac[i]), i, min_clearance)


def swept_dynamic_many(mav_p0, mav_p1, obs_p0, obs_p1, radii, mav_radius: float) -> list[DynamicContact]:
    """swept_dynamic for T MAVs (mav_p0, mav_p1 [T, d]) against the same obstacles in the same step (lockstep
    trials): the same float operations, evaluated for all MAVs x obstacles at once; the contact details of a MAV
    that hits are taken from swept_dynamic itself."""
    p0 = np.asarray(obs_p0, dtype=float)
    m0 = np.asarray(mav_p0, dtype=float)
    m1 = np.asarray(mav_p1, dtype=float)
    if p0.shape[0] == 0:
        return [_NO_DYNAMIC] * m0.shape[0]
    p1 = np.asarray(obs_p1, dtype=float)
    dp0 = m0[:, None, :] - p0                                       # [T, N, d]
    w = (m1 - m0)[:, None, :] - (p1 - p0)
    reach = np.asarray(radii, dtype=float) + float(mav_radius)
    a = np.einsum("tij,tij->ti", w, w)
    b = np.einsum("tij,tij->ti", dp0, w)
    moving = a > 0.0
    s_star = np.zeros_like(a)
    np.divide(-b, a, out=s_star, where=moving)
    np.clip(s_star, 0.0, 1.0, out=s_star)
    closest = dp0 + s_star[:, :, None] * w
    clearance = np.sqrt(np.einsum("tij,tij->ti", closest, closest)) - reach
    lowest = clearance.min(axis=1).tolist()
    hits = (clearance < 0.0).any(axis=1).tolist()
    return [swept_dynamic(m0[i], m1[i], p0, p1, radii, mav_radius) if hit else DynamicContact(False, 1.0, -1, low)
            for i, (hit, low) in enumerate(zip(hits, lowest))]


SHAPE_STEP_M = 0.05
"""Largest relative displacement (m) between two real-shape samples of one step (shape_dynamic)."""

MAX_SHAPE_SAMPLES = 64
"""Most real-shape samples per step and body."""


def shape_dynamic(field, bodies: np.ndarray, base0: np.ndarray, base1: np.ndarray, mav_p0, mav_p1, step1: int,
                  mav_radius: float, to3, swept: bool) -> DynamicContact:
    """Contact of the MAV ball with moving bodies of an imported world by their real shapes (pbdyn.world.shapes
    .ShapeField): ``bodies`` [M] body indices, base0/base1 [M, 3] their base positions at t_k and t_k+1 (m),
    ``step1`` the rollout step of t_k+1, ``to3`` maps MAV points [.., d] to 3D (2D: the flight plane). Sampled: the
    signed distance at t_k+1 only. Swept: samples along the step no more than SHAPE_STEP_M of relative motion apart
    (at most MAX_SHAPE_SAMPLES), each body translated linearly between its poses (its orientation at t_k+1): the
    signed distance of the MAV centre shifted by the body's remaining displacement to the body at t_k+1.
    fraction: the first sample in contact (1.0 when none); min_clearance: distance - r_MAV (m)."""
    if len(bodies) == 0:
        return _NO_DYNAMIC
    p0 = to3(np.asarray(mav_p0, dtype=float))
    p1 = to3(np.asarray(mav_p1, dtype=float))
    best = (math.inf, -1)                     # (first contact fraction, body row)
    clearance = math.inf
    for j, b in enumerate(np.asarray(bodies).tolist()):
        move = base1[j] - base0[j]
        if swept:
            rel = float(np.linalg.norm((p1 - p0) - move))
            n = int(min(MAX_SHAPE_SAMPLES, max(1, math.ceil(rel / SHAPE_STEP_M))))
            s = np.arange(1, n + 1) / n
        else:
            s = np.ones(1)
        pts = p0[None, :] + s[:, None] * (p1 - p0)[None, :] + (1.0 - s)[:, None] * move[None, :]
        d = field.body_distance(b, pts, step1) - float(mav_radius)
        clearance = min(clearance, float(d.min()))
        hit = np.flatnonzero(d < 0.0)
        if hit.size and s[hit[0]] < best[0]:
            best = (float(s[hit[0]]), j)
    if best[1] < 0:
        return DynamicContact(False, 1.0, -1, clearance)
    return DynamicContact(True, best[0] if swept else 1.0, best[1], clearance)


def sampled_dynamic(mav_p1, obs_p1, radii, mav_radius: float) -> DynamicContact:
    """The thesis' per-step check: overlap at the sample t_k+1 only (centre distance < r_i + r_MAV).

    On a hit, index is the most deeply overlapped obstacle and fraction 1.0 (the collision is seen at t_k+1).
    """
    p1 = np.asarray(obs_p1, dtype=float)
    if p1.shape[0] == 0:
        return _NO_DYNAMIC
    rel = np.asarray(mav_p1, dtype=float) - p1
    clearance = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - (np.asarray(radii, dtype=float) + float(mav_radius))
    i = int(np.argmin(clearance))
    hit = bool(clearance[i] < 0.0)
    return DynamicContact(hit, 1.0, i if hit else -1, float(clearance[i]))


def swept_static(world, mav_p0, mav_p1, *, eps: float = 1e-4, margin: float = 5.0) -> StaticContact:
    """Swept MAV-vs-static check by conservative advancement on PyBullet's true static geometry.

    world: a PyBulletWorld; mav_p0, mav_p1: MAV centre [d] (m) at t_k and t_k+1. With L = |p1 - p0| and the
    clearance d(s) at p(s) = p0 + s (p1 - p0): starting at s = 0, a hit is declared when d <= eps (fraction = s,
    at most eps / L early), else s += d / L (the MAV cannot reach anything within d), until s >= 1. Broad phase:
    when d(0) > L + eps nothing is reachable and the loop is skipped. Queries use max_dist = L + margin, so
    min_clearance -- the smallest clearance observed (always at p0 and p1, plus the advancement's samples; between
    samples it is only bounded below by what the advancement visited) -- is capped at L + margin.
    Each step moves >= eps / L, so the loop is bounded; it is slow only when grazing a surface closely.
    """
    p0 = np.asarray(mav_p0, dtype=float)
    p1 = np.asarray(mav_p1, dtype=float)
    delta = p1 - p0
    length = math.sqrt(float(delta @ delta))       # (np.sqrt's value: both round the square root correctly)
    max_dist = length + float(margin)
    d, body = world.nearest_static(p0, max_dist)
    if d <= eps:
        return StaticContact(True, 0.0, d, body)
    lowest = d
    if d > length + eps or length == 0.0:
        d1, _ = world.nearest_static(p1, max_dist)
        return StaticContact(False, 1.0, min(lowest, d1), -1)
    s = 0.0
    while True:
        s += d / length
        if s >= 1.0:
            break
        d, body = world.nearest_static(p0 + s * delta, max_dist)
        lowest = min(lowest, d)
        if d <= eps:
            return StaticContact(True, s, lowest, body)
    d1, body1 = world.nearest_static(p1, max_dist)
    lowest = min(lowest, d1)
    if d1 <= eps:  # s jumped past 1 on a bound; the end point itself is the (last possible) contact
        return StaticContact(True, 1.0, lowest, body1)
    return StaticContact(False, 1.0, lowest, -1)


def sampled_static(world, mav_p1, *, margin: float = 5.0) -> StaticContact:
    """The per-step static check at t_k+1 only: a hit if the clearance at p1 is < 0 (min_clearance capped at margin)."""
    d, body = world.nearest_static(np.asarray(mav_p1, dtype=float), float(margin))
    hit = d < 0.0
    return StaticContact(hit, 1.0, d, body if hit else -1)
