"""The motion-primitive planners' compiled (numba) parts: the global planner's A* (astar), the local planner's
candidate kernels and one-call candidate search (candidate_kernels, candidate_search), and ruckig trajectory
sampling (ruckig_sampling). Each repeats the float operations of a slower reference twin bit for bit
(docs/architecture.md "Fast paths and their reference twins")."""
