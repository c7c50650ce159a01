"""pbdyn: a PyBullet testbed for MAV dynamic obstacle avoidance and environment difficulty."""

__version__ = "0.1.0"
