"""What a policy observes of a trial (docs/gym.md "Observation"): what the MAV knows, never the true obstacle states.

The observation is one float32 vector with every entry in [-1, 1] (scaled, then clipped), in the world frame:

    [0, d)            velocity / v_max
    [d, d + 2)        cos(yaw), sin(yaw)
    [d + 2, 2d + 2)   (goal - position) / L            (L: the arena's largest side, m)
    then, for each of the K tracks nearest the MAV (by surface distance; rows of zeros where fewer are tracked):
        (track position - position) / (2 R)           d values (R: the sensor's range, m)
        (track velocity - velocity) / (2 v_max)       d values
        radius / R                                    1
        sqrt(trace of the position covariance) / R    1  (the track's uncertainty, m)
        mask                                          1  (1: a track, 0: padding)
    then, with ``rays`` = B > 0: the last scan's ranges / R, min-pooled into B bins in ray order

so its length is 2d + 2 + K (2d + 3) + B. The tracks are the MAV's Kalman tracks (pbdyn.perception.tracker), so an
obstacle never seen is absent and an occluded one keeps its predicted state and growing uncertainty.
"""

from __future__ import annotations

import math

import numpy as np


def observation_size(dims: int, tracks: int, rays: int) -> int:
    """The length of the observation vector for ``dims`` (2 or 3), K = ``tracks`` and B = ``rays``."""
    return 2 * dims + 2 + tracks * (2 * dims + 3) + rays


def observe(state, tracks: int, rays: int) -> np.ndarray:
    """The observation (float32 [observation_size]) of a trial's state (pbdyn.sim.state.TrialState) after its
    sensing at t_k; see the module docstring for the layout and scales."""
    d = state.dims
    lim = state.limits
    sc = state.spec.scenario
    rng = float(sc.sensor.range)
    arena = float(max(sc.world.size))
    out = np.zeros(observation_size(d, tracks, rays))
    out[:d] = state.velocity / lim.v_max
    out[d] = math.cos(state.yaw)
    out[d + 1] = math.sin(state.yaw)
    out[d + 2:2 * d + 2] = (state.goal - state.position) / arena
    tr = state.tracks
    if tracks and tr is not None and len(tr.ids):
        rel = tr.position - state.position
        gap = np.sqrt(np.einsum("ij,ij->i", rel, rel)) - tr.radius
        near = np.argsort(gap, kind="stable")[:tracks]
        n = near.size
        cov = tr.covariance[near]
        unc = np.sqrt(np.maximum(np.trace(cov[:, :d, :d], axis1=1, axis2=2), 0.0))
        rows = np.concatenate([rel[near] / (2.0 * rng), (tr.velocity[near] - state.velocity) / (2.0 * lim.v_max),
                               (tr.radius[near] / rng)[:, None], (unc / rng)[:, None], np.ones((n, 1))], axis=1)
        start = 2 * d + 2
        out[start:start + n * (2 * d + 3)] = rows.reshape(-1)
    if rays:
        ranges = np.asarray(state.detections.ranges, dtype=float) / rng
        bins = np.array_split(ranges, rays) if ranges.size >= rays else [ranges] * rays
        out[-rays:] = [b.min() if b.size else 1.0 for b in bins]
    return np.clip(out, -1.0, 1.0).astype(np.float32)
