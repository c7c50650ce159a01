"""Print the tables of the thesis program's local primitives that depend on its numpy version's floating point.

    python tools/program_tables.py          # run with numpy 1.23.4, the program's version

1. PROGRAM_SAMPLE_COUNTS: per MAV speed (2, 4, 6 m/s) and candidate, how many samples the program checked:
   floor(max(1.2 |d| / v_max, 0.5) / dt) with |d| = numpy.linalg.norm of the candidate's 3 m offset in its pixels;
   that norm's last bit (numpy 1.23.4's dot product) decides whether T / dt floors to 5 or 6 at 6 m/s (8 candidates
   check 6) and to 7 or 8 / 8 or 9 at 2 and 4 m/s, and later numpy versions round differently.
2. PROGRAM_TIE_ORDERS: the program ranked its 72 candidates (theta = 0, 5, ..., 355 deg) by the squared angle
   between theta and the goal direction phi = degrees(atan2(dy, dx)) with numpy's default argsort (an unstable
   introsort in numpy 1.23), so where two candidates lie equally far on either side of phi -- exactly when phi is a
   multiple of 45 deg: the MAV on a row, column or diagonal of the goal on the program's pixel grid -- the order of
   each tied pair is that sort's; numpy >= 1.25 (SIMD sorting) orders ties differently.

The tool rebuilds both as the program computed them (docs/thesis-program.md "Trajectory planners") and prints them;
pbdyn.planning.primitives.minjerk holds its output. It refuses to run under another numpy version.
"""

from __future__ import annotations

import math
import sys

import numpy as np

PHIS = (0.0, 45.0, 90.0, 135.0, 180.0, -45.0, -90.0, -135.0)
"""Goal directions (deg, the program's atan2 range) at which costs tie: dy = 0, dx = 0 or |dx| = |dy|."""


def program_costs(phi: float) -> np.ndarray:
    """The program's cost per candidate (deg^2): the squared wrapped difference of theta % 360 and phi % 360."""
    theta = np.arange(0, 360, 5)
    diff = np.abs(theta % 360 - phi % 360)
    return np.where(diff <= 180, diff, 360 - diff) ** 2


def sample_counts(v_max_px: int) -> list[int]:
    """The program's checked samples per candidate at MAV speed v_max_px (px/s; dt 0.1 s, step 30 px)."""
    out = []
    for theta in np.arange(0, 360, 5):
        offset = np.array([30 * np.cos(math.radians(theta)), 30 * np.sin(math.radians(theta))])
        t = 1.2 * np.linalg.norm(offset) / np.linalg.norm(v_max_px)
        out.append(int(np.floor(max(t, 0.5) / 0.1)))
    return out


def main() -> int:
    if np.__version__ != "1.23.4":
        print(f"program_tables: error: needs numpy 1.23.4 (the program's), found {np.__version__}",
              file=sys.stderr)
        return 2
    print("PROGRAM_SAMPLE_COUNTS = {")
    for v in (2, 4, 6):
        print(f"    {float(v)!r}: ({', '.join(str(c) for c in sample_counts(10 * v))}),")
    print("}")
    print("PROGRAM_TIE_ORDERS = {")
    for phi in PHIS:
        cost = np.zeros((72, 2))
        cost[:, 0] = program_costs(phi)
        cost[:, 1] = np.arange(0, 360, 5)
        order = cost[:, 0].argsort()          # the program sorted column 0 of this [72, 2] array
        print(f"    {phi!r}: ({', '.join(str(int(i)) for i in order)}),")
    print("}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
