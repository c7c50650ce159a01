"""Normalisation of a metric to [0, 10] (thesis eq. 4-10) and its reversal into a difficulty (eq. 4-11)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pbdyn.analysis.srcc import mean_std, pair_srcc

SCALE = 10.0
"""Upper end of the normalised range (thesis eq. 4-10)."""


@dataclass(frozen=True)
class Normaliser:
    """Turns raw metric values into a difficulty: eq. 4-10 with (lo, hi), then eq. 4-11 if ``reversed``."""

    lo: float
    hi: float
    reversed: bool

    def normalise(self, values: np.ndarray) -> np.ndarray:
        """m_norm = (m - m_min) / (m_max - m_min) * 10 (thesis eq. 4-10); 0 everywhere if m_max = m_min. Values
        outside [lo, hi] (maps not used for the fit) fall outside [0, 10]; they are not clipped."""
        v = np.asarray(values, float)
        span = self.hi - self.lo
        if not span > 0:
            return np.where(np.isfinite(v), 0.0, np.nan)
        return (v - self.lo) / span * SCALE

    def difficulty(self, values: np.ndarray) -> np.ndarray:
        """m_rev (thesis eq. 4-11): 10 - m_norm for a reversed metric, else m_norm. Higher = harder."""
        n = self.normalise(values)
        return SCALE - n if self.reversed else n

    def as_dict(self) -> dict:
        """JSON form: {"min", "max", "reversed"}."""
        return {"min": self.lo, "max": self.hi, "reversed": self.reversed}

    @classmethod
    def from_dict(cls, d: dict) -> Normaliser:
        """Inverse of ``as_dict``."""
        return cls(float(d["min"]), float(d["max"]), bool(d["reversed"]))


def fit_normaliser(values: np.ndarray, rate: np.ndarray) -> Normaliser:
    """Normaliser of a metric from the fitting maps: (m_min, m_max) over its finite values (thesis eq. 4-10), and
    reversed (eq. 4-11) when the mean over pairs (eq. 3-9) of Srcc(m_norm, SR_j) is > 0, i.e. when higher values
    mean more success. ``values`` [maps], ``rate`` [maps, pairs]."""
    v = np.asarray(values, float)
    fin = v[np.isfinite(v)]
    lo, hi = (float(fin.min()), float(fin.max())) if fin.size else (float("nan"), float("nan"))
    mean, _ = mean_std(pair_srcc(v, rate))
    return Normaliser(lo, hi, bool(mean > 0))
