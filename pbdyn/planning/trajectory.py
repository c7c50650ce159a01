"""The trajectory every planner returns (docs/design.md "Trajectory")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trajectory:
    """A trajectory sampled at the world step.

    Attributes:
        t0: absolute time of sample 0 (s); sample 0 is the MAV state when the plan was made.
        dt: sample spacing (s), equal to the world dt.
        p: positions [K, d] (m, world frame).
        v: velocities [K, d] (m/s).
        a: accelerations [K, d] (m/s^2).
    """

    t0: float
    dt: float
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def __post_init__(self) -> None:
        for name in ("p", "v", "a"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.ndim != 2:
                raise ValueError(f"Trajectory.{name} must be [K, d], got shape {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if not (self.p.shape == self.v.shape == self.a.shape) or self.p.shape[0] < 1:
            raise ValueError("Trajectory p, v, a must share one non-empty [K, d] shape")

    @classmethod
    def of_owned(cls, t0: float, dt: float, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> "Trajectory":
        """The Trajectory Trajectory(...) makes of float arrays p, v, a [K, d] (K >= 1, one shape) that nobody else
        writes (e.g. a planner's fresh samples): made read-only in place, without the dataclass __init__'s per-field
        cost and the checks (the caller guarantees them)."""
        for x in (p, v, a):
            x.setflags(write=False)
        traj = object.__new__(cls)
        traj.__dict__.update(t0=t0, dt=dt, p=p, v=v, a=a)
        return traj

    @property
    def n_samples(self) -> int:
        """Number of samples K."""
        return self.p.shape[0]

    @property
    def t_end(self) -> float:
        """Absolute time of the last sample (s)."""
        return self.t0 + (self.n_samples - 1) * self.dt

    @property
    def times(self) -> np.ndarray:
        """Absolute sample times [K] (s)."""
        return self.t0 + self.dt * np.arange(self.n_samples)

    def index_at(self, t: float) -> int:
        """Index of the sample at absolute time t (rounded to the nearest step); may be >= K."""
        return int(round((t - self.t0) / self.dt))

    def covers(self, t: float) -> bool:
        """True if the trajectory has a sample at absolute time t."""
        k = self.index_at(t)
        return 0 <= k < self.n_samples

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p, v, a) of the sample at absolute time t; raises IndexError past the end."""
        k = self.index_at(t)
        if not 0 <= k < self.n_samples:
            raise IndexError(f"trajectory has no sample at t={t:.3f} s (covers {self.t0:.3f}..{self.t_end:.3f})")
        return self.p[k], self.v[k], self.a[k]

    def remaining(self, t: float) -> "Trajectory":
        """The part of the trajectory from absolute time t on (sample at t becomes sample 0)."""
        k = max(self.index_at(t), 0)
        k = min(k, self.n_samples - 1)
        return Trajectory(self.t0 + k * self.dt, self.dt, self.p[k:], self.v[k:], self.a[k:])
