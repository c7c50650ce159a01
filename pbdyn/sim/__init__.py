"""pbdyn.sim."""
