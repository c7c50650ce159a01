"""The model predictive control trajectory planner (thesis A-3): the planner (planner) and its fixed-structure convex
problem with its two solver paths (problem)."""
