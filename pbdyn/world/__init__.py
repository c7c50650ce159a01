"""pbdyn.world."""
