"""pbdyn.motion: obstacle motion models, one module each, and their registry (pbdyn/motion/registry.py)."""
