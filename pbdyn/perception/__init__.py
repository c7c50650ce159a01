"""pbdyn.perception."""
