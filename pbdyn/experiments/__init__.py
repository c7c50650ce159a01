"""pbdyn.experiments."""
