"""pbdyn.metrics."""
