"""pbdyn.analysis."""
