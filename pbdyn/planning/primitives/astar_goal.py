"""The goal test the global motion primitives planner's two searches share (global_astar's Python search and its
compiled twin, compiled.astar): a sample reaches the goal ball only GOAL_TOL inside its radius."""

GOAL_TOL = 1e-9
"""m: goal samples must be this far inside the goal ball (the trial tests the same samples)."""
