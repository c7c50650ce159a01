"""Active Kalman tracks as planners see them (the ``tracks`` of a planning View; thesis 2-4-2).

Lives in perception (which produces tracks) so that perception never imports planning; pbdyn.planning.view
re-exports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only float array view of ``a``."""
    a = np.asarray(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Tracks:
    """Active Kalman tracks of dynamic obstacles (thesis 2-4-2).

    Attributes:
        ids: obstacle index of each track [M] (int; the index into the rollout's obstacles).
        position: estimated centres [M, d] (m, world frame) at the view's time.
        velocity: estimated velocities [M, d] (m/s).
        covariance: state covariances [M, 2d, 2d] over [p, v] (m^2, m^2/s, m^2/s^2).
        radius: obstacle radii [M] (m).
    """

    ids: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    radius: np.ndarray

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=np.int64)
        ids.setflags(write=False)
        object.__setattr__(self, "ids", ids)
        for name in ("position", "velocity", "covariance", "radius"):
            object.__setattr__(self, name, readonly(getattr(self, name)))

    @classmethod
    def of_owned(cls, ids: np.ndarray, position: np.ndarray, velocity: np.ndarray, covariance: np.ndarray,
                 radius: np.ndarray) -> "Tracks":
        """The Tracks Tracks(...) makes of the same arrays, when they are already int64 (ids) and float arrays that
        nobody else holds (e.g. fresh results of fancy indexing): made read-only in place, without the dataclass
        __init__'s per-field cost (the trackers' per-step read-out)."""
        for a in (ids, position, velocity, covariance, radius):
            a.setflags(write=False)
        tracks = object.__new__(cls)
        tracks.__dict__.update(ids=ids, position=position, velocity=velocity, covariance=covariance, radius=radius)
        return tracks

    @classmethod
    def empty(cls, dims: int) -> "Tracks":
        """No tracks, in d dimensions."""
        return cls(np.zeros(0, np.int64), np.zeros((0, dims)), np.zeros((0, dims)),
                   np.zeros((0, 2 * dims, 2 * dims)), np.zeros(0))

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def predict(self, dt_ahead: np.ndarray | float) -> np.ndarray:
        """Constant-velocity predictions of the centres: [M, d] for a scalar, [K, M, d] for times [K] (s ahead)."""
        tau = np.asarray(dt_ahead, dtype=float)
        if tau.ndim == 0:
            return self.position + tau * self.velocity
        return self.position[None, :, :] + tau[:, None, None] * self.velocity[None, :, :]
