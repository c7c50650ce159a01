"""Print the thesis program's candidate order of its local primitives for the goal directions where its costs tie.

    python tools/program_tie_orders.py          # run with numpy 1.23.4, the program's version

The program ranked its 72 candidates (theta = 0, 5, ..., 355 deg) by the squared angle between theta and the goal
direction phi = degrees(atan2(dy, dx)) with numpy's default argsort (an unstable introsort in numpy 1.23), so where
two candidates lie equally far on either side of phi -- exactly when phi is a multiple of 45 deg: the MAV on a row,
column or diagonal of the goal on the program's pixel grid -- the order of each tied pair is that sort's. This tool
rebuilds those cost arrays as the program did (implementation-facts.md "Trajectory planners") and prints numpy's
order for each such phi; pbdyn.planning.local_primitives_minjerk.PROGRAM_TIE_ORDERS holds its output. Other numpy
versions (e.g. numpy >= 1.25 with SIMD sorting) order ties differently, so the tool refuses to run under them.
"""

from __future__ import annotations

import sys

import numpy as np

PHIS = (0.0, 45.0, 90.0, 135.0, 180.0, -45.0, -90.0, -135.0)
"""Goal directions (deg, the program's atan2 range) at which costs tie: dy = 0, dx = 0 or |dx| = |dy|."""


def program_costs(phi: float) -> np.ndarray:
    """The program's cost per candidate (deg^2): the squared wrapped difference of theta % 360 and phi % 360."""
    theta = np.arange(0, 360, 5)
    diff = np.abs(theta % 360 - phi % 360)
    return np.where(diff <= 180, diff, 360 - diff) ** 2


def main() -> int:
    if np.__version__ != "1.23.4":
        print(f"program_tie_orders: error: needs numpy 1.23.4 (the program's), found {np.__version__}",
              file=sys.stderr)
        return 2
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
