"""pbdyn.planning."""
