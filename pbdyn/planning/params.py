"""Range checks of the built-in planners' constructor parameters.

Every check is written so that NaN fails it (``not lo < x`` rather than ``x <= lo``) and infinities are refused:
a non-finite parameter must never reach a plan. They raise ValueError("<name> must be ..., got <value>"), which
pbdyn.planning.registry.build_planner reports as a ConfigError naming the scenario field.
"""

from __future__ import annotations

import math
import numbers


def number(name: str, value, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False) -> float:
    """``value`` as a float; ValueError unless it is a finite real number (not a bool) in the given range."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    v = float(value) if ok else math.nan
    ok = ok and math.isfinite(v)
    if ok and lo is not None:
        ok = v > lo if lo_open else v >= lo
    if ok and hi is not None:
        ok = v < hi if hi_open else v <= hi
    if not ok:
        parts = []
        if lo is not None:
            parts.append(f"{'>' if lo_open else '>='} {lo:g}")
        if hi is not None:
            parts.append(f"{'<' if hi_open else '<='} {hi:g}")
        raise ValueError(f"{name} must be a finite number{' ' if parts else ''}{' and '.join(parts)}, got {value!r}")
    return v


def positive(name: str, value) -> float:
    """``value`` as a float; ValueError unless finite and > 0."""
    return number(name, value, lo=0.0, lo_open=True)


def non_negative(name: str, value) -> float:
    """``value`` as a float; ValueError unless finite and >= 0."""
    return number(name, value, lo=0.0)


def integer(name: str, value, *, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int; ValueError unless it is an integer (an integral float is accepted) in [lo, hi]."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    ok = ok and math.isfinite(float(value)) and float(value) == int(value)
    if ok and lo is not None:
        ok = int(value) >= lo
    if ok and hi is not None:
        ok = int(value) <= hi
    if not ok:
        bounds = " and ".join(x for x in (f">= {lo}" if lo is not None else "", f"<= {hi}" if hi is not None else "")
                              if x)
        raise ValueError(f"{name} must be an integer{' ' if bounds else ''}{bounds}, got {value!r}")
    return int(value)
