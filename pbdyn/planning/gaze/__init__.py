"""Gaze planners (where the MAV looks: a yaw rate in rad/s per step; docs/planners.md "Gaze planners"): the rule-based
ones (rules), Finean et al. (finean), Owl (owl), and the yaw arithmetic they share (yaw)."""
