"""Scripted policies for the policy-to-planner adapter's tests (tests/test_gym_policy.py; pbdyn.gym.policy_planner):
factories named as "tests.gym_policies:<factory>" in a planner's parameters, each returning a callable
observation -> action on AvoidEnv's spaces (docs/gym.md)."""

from __future__ import annotations

import itertools
import math

import numpy as np


def goal_seeker(dims: int = 2, gain: float = 3.0, tracks: int = 8):
    """A policy that steers toward the goal at full speed, pushed away from the nearest track inside 4 m of it, and
    turns its gaze to the goal: action[:d] = gain (goal direction + push - velocity / v_max), action[d] the heading
    error to the goal (rad) over pi / 4; clipped to [-1, 1]. ``tracks``: K of the observation."""
    d = int(dims)

    def policy(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=float)
        vel = obs[:d]
        to_goal = obs[d + 2:2 * d + 2]
        norm = math.sqrt(float(to_goal @ to_goal))
        want = to_goal / norm if norm > 1e-9 else np.zeros(d)
        start = 2 * d + 2
        if tracks:
            row = obs[start:start + 2 * d + 3]          # the nearest track (the rows are sorted by surface distance)
            if row[-1] > 0.5:
                rel = row[:d]
                dist = math.sqrt(float(rel @ rel))
                if 1e-9 < dist < 0.25:                  # within 4 m for an 8 m sensor range (rel is scaled by 2R)
                    want = want - rel / dist * (0.25 - dist) * 8.0
        cmd = np.clip(gain * (want - vel), -1.0, 1.0)
        heading = math.atan2(obs[d + 1], obs[d])
        err = math.atan2(to_goal[1], to_goal[0]) - heading if norm > 1e-9 else 0.0
        err = (err + math.pi) % (2.0 * math.pi) - math.pi
        return np.concatenate([cmd, [max(-1.0, min(1.0, err / (math.pi / 4.0)))]]).astype(np.float32)

    return policy


def hover(dims: int = 2):
    """A policy that commands zero acceleration and no turn (the MAV stays at rest)."""
    zero = np.zeros(int(dims) + 1, dtype=np.float32)
    return lambda obs: zero


def wall_shy(dims: int = 2, tracks: int = 8, patch: int = 5):
    """goal_seeker's policy, also pushed away from every occupied cell of the observation's occupancy patch (P =
    ``patch``, the last P^d entries): the push of a cell at offset o (cells) is -o / |o|^2."""
    d, seek = int(dims), goal_seeker(dims, tracks=tracks)
    h = patch // 2
    offsets = np.array(list(itertools.product(range(-h, h + 1), repeat=d)), dtype=float)
    norms = np.einsum("ij,ij->i", offsets, offsets)
    norms[norms == 0] = np.inf

    def policy(obs: np.ndarray) -> np.ndarray:
        action = seek(obs).astype(float)
        cells = np.asarray(obs[-patch ** d:], dtype=float)
        occupied = (cells == 1.0) & np.isfinite(norms)
        if occupied.any():
            push = -(offsets[occupied] / norms[occupied, None]).sum(axis=0)
            action[:d] = np.clip(action[:d] + push, -1.0, 1.0)
        return action.astype(np.float32)

    return policy
