"""Motion-primitive trajectory planners (docs/planners.md): local primitives on ruckig trajectories (local) and on
minimum-jerk polynomials (minjerk), global A* over constant-acceleration primitives (global_astar) with its
heuristic (astar_heuristic) and occupied-cell screen (astar_static); their numba fast paths live in compiled/, the
C++ ruckig batch in native/ (docs/architecture.md "Fast paths and their reference twins")."""
