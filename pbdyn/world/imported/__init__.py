"""Imported worlds: scenarios whose obstacles are URDF bodies (docs/scenarios.md "Imported worlds").

urdf_loading.py reads, scales and loads URDF files into PyBullet (the project's own models too); bodies.py turns a
world file's ``[[bodies]]`` and their scripted motions into poses at every rollout step (WorldBodies), bounding
spheres and fingerprints. The bodies' real shapes as signed-distance fields are pbdyn.world.shapes'; URDF validation
at scenario load is pbdyn.urdf's (below config). The example motion functions stay in pbdyn/world/motions.py: world
files name them as "pbdyn.world.motions:circle", and that name is part of every body's fingerprint, so moving the
module would change the keys of every stored rollout and trial of those worlds.
"""
